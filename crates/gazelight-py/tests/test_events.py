"""rec.events: a recording's events as arrays and a DataFrame, equal to what
the CLI writes (replay's events.csv, inspect --json's events) and to the
shipped EyeLink file's MSG lines read here from its text."""

import csv

import numpy as np
import pytest

import gazelight
from conftest import run_cli


def _msg_lines(path):
    """(time ms after SR Research's offset, text) of each MSG line."""
    out = []
    with open(path) as f:
        for line in f:
            if not line.startswith("MSG"):
                continue
            t, _, msg = line[3:].strip().replace("\t", " ", 1).partition(" ")
            msg = msg.strip()
            first, _, rest = msg.partition(" ")
            try:
                offset = int(first)
            except ValueError:
                offset = None
            if offset is not None and rest.strip():
                out.append((float(t) - offset, rest.strip()))
            else:
                out.append((float(t), msg))
    return sorted(out, key=lambda m: m[0])


def test_eyelink_events_are_its_msg_lines(data_dir, gazelight_bin, tmp_path):
    path = data_dir / "eye/eyelink-psa/both_eyes.asc"
    rec = gazelight.read(path)
    ev = rec.events
    truth = _msg_lines(path)
    assert len(ev) == len(truth) == 308
    assert ev.clock.startswith("EyeLink")
    np.testing.assert_array_equal(ev.t_clock, [t for t, _ in truth])
    np.testing.assert_allclose(ev.t_secs, [t * 1e-3 for t, _ in truth], rtol=0, atol=1e-9)
    assert ev.text == [m for _, m in truth]
    assert set(ev.source) == {"MSG"}
    # The samples' clock: the first pupil sample follows the first message.
    assert ev.t_secs[0] < rec.right.t_secs[0] < ev.t_secs[-1]
    # Trials: TRIALID .. TRIAL_RESULT with their TRIAL_VARs.
    assert [t["id"] for t in ev.trials] == ["0", "1", "2", "3"]
    assert [t["vars"]["Trial_Index_"] for t in ev.trials] == ["1", "2", "3", "4"]
    in_trial = ev.trial >= 0
    assert in_trial.sum() > 0
    for k, t in enumerate(ev.trials):
        sel = ev.trial == k
        assert ev.t_secs[sel].min() >= t["start_t_secs"] - 1e-9
        assert ev.t_secs[sel].max() <= t["end_t_secs"] + 1e-9

    df = ev.to_dataframe()
    assert len(df) == 308
    assert list(df.columns[:6]) == ["t_secs", "t_clock", "duration_secs", "source", "text", "trial"]
    assert (df.loc[df.text == "TRIALID 2", "trial"] == "2").all()
    assert (df.loc[df.trial == "3", "Trial_Index_"] == "4").all()

    # The same events as inspect --json's summary and replay's events.csv.
    s = gazelight.inspect(path)
    assert s["events"]["total"] == 308
    out = tmp_path / "replay"
    cfg = tmp_path / "fast.toml"
    cfg.write_text("[pipeline]\nglare = { enabled = false }\n")
    run_cli(gazelight_bin, "replay", str(path), "--size", "32x24", "--fps", "5", "--no-frames",
            "--backend", "cpu", "--config", str(cfg), "--out", str(out))
    with open(out / "events.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["text"] for r in rows] == ev.text
    np.testing.assert_allclose([float(r["recording_t_secs"]) for r in rows], ev.t_secs, atol=1e-6)


def test_a_recording_without_events_has_an_empty_list(data_dir):
    rec = gazelight.read(data_dir / "eye/piprkit-plr/pupil_trace.csv")
    assert len(rec.events) == 0
    assert rec.events.to_dataframe().empty


def test_neon_events(data_dir):
    ev = gazelight.read(data_dir / "eye/neon-demo").events
    assert ev.text == ["recording.begin", "recording.end"]
    np.testing.assert_allclose(ev.t_secs, [0.0, 11.219], atol=1e-9)
