"""One time base (issue 49 item 4), on the shipped Neon recording: Python's
``read()`` and ``inspect`` give times on the recording's clock, the CLI's
``replay`` counts ``timeline.csv``/``events.csv`` from its first frame and
states the offset in ``session.json``; each output says which clock it
uses, and the same sample's or event's time agrees once the stated offset
is applied. The expected times come from the recording's own files (Neon's
int64 ns ``*.time`` stamps less ``info.json``'s ``start_time``), not from
gazelight."""

import csv
import json

import numpy as np

import gazelight
from conftest import inspect_json, run_cli

FROM_SECS = 0.5


def _neon_secs(rec_dir, name):
    start_ns = json.loads((rec_dir / "info.json").read_text())["start_time"]
    ns = np.fromfile(rec_dir / name, dtype="<u8").astype(np.int64)
    return (ns - start_ns) / 1e9


def test_python_inspect_and_replay_share_one_time_base(data_dir, gazelight_bin, tmp_path):
    rec_dir = data_dir / "eye/neon-demo"
    gaze_secs = _neon_secs(rec_dir, "gaze ps1.time")
    event_secs = _neon_secs(rec_dir, "event.time")
    first = float(gaze_secs[0])
    assert 2.2 < first < 2.3  # the recording's clock, not 0

    # Python: the recording's clock, each sample at its own stamp.
    rec = gazelight.read(rec_dir)
    assert abs(rec.first_sample_secs - first) < 1e-6
    # The binocular gaze rows (eyes 0; the per-eye rows share their stamps).
    binocular = np.sort(rec.gaze.t_secs[rec.gaze.eyes == 0])
    assert len(binocular) == len(gaze_secs)
    assert np.max(np.abs(binocular - gaze_secs)) < 1e-6
    assert np.max(np.abs(np.sort(rec.right.t_secs) - _neon_secs(rec_dir, "eye_state ps1.time"))) < 1e-6
    assert np.max(np.abs(np.sort(rec.events.t_secs) - event_secs)) < 1e-6

    # inspect: the same clock, said in its text and JSON.
    assert abs(inspect_json(gazelight_bin, rec_dir)["first_sample_secs"] - first) < 1e-6
    text = run_cli(gazelight_bin, "inspect", str(rec_dir)).stdout
    assert f"times: the recording's clock, s (first sample at {first:.6f} s" in text, text

    # replay: seconds from the first frame, the offset in session.json.
    out = tmp_path / "replay"
    run_cli(
        gazelight_bin, "replay", str(rec_dir), f"--from-secs={FROM_SECS}", "--secs=1",
        "--size=32x24", "--fps=20", "--backend=cpu", "--no-frames", f"--out={out}",
    )
    settings = json.loads((out / "session.json").read_text())["settings"]
    assert "seconds from the first frame" in settings["time.timeline_clock"]["value"]
    offset = settings["time.first_frame_recording_secs"]["value"]
    assert abs(offset - (first + FROM_SECS)) < 1e-6, offset
    with open(out / "timeline.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert float(rows[0]["t_secs"]) == 0.0
    # Frame k at k/20 s from the first frame = first sample + 0.5 + k/20 on
    # the recording's clock.
    for k, r in enumerate(rows):
        assert abs(float(r["t_secs"]) + offset - (first + FROM_SECS + k / 20)) < 1e-4
    # The recording's events: events.csv's t_secs + the offset is each
    # event's stamp in event.time, and Python's time for it.
    with open(out / "events.csv", newline="") as f:
        events = list(csv.DictReader(f))
    assert len(events) == len(event_secs)
    for e, want in zip(events, event_secs):
        assert abs(float(e["t_secs"]) + offset - want) < 1e-5, (e, want)
    for e, py in zip(events, np.sort(rec.events.t_secs)):
        assert abs(float(e["t_secs"]) + offset - py) < 1e-5, (e, py)
