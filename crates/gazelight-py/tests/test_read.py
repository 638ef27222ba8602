"""gazelight.read against the CLI: for each shipped real recording, the
arrays hold the samples, filtered pupils and blinks that `gazelight inspect
--json` and `replay`'s timeline.csv report for the same input."""

import csv
import os
import shutil
import warnings

import numpy as np
import pytest

import gazelight
from conftest import RECORDINGS, inspect_json, run_cli


def _range(values: np.ndarray):
    """min / median / max as inspect computes them (finite values; the
    median of an even count is the mean of the middle two, in f64); None
    when there is none, as inspect's null."""
    v = np.sort(values[np.isfinite(values)]).astype(np.float64)
    n = len(v)
    if n == 0:
        return None
    med = v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])
    return {"min": v[0], "median": med, "max": v[-1]}


def _read(path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = gazelight.read(path)
    return rec, [str(w.message) for w in caught if issubclass(w.category, gazelight.GazelightWarning)]


@pytest.mark.parametrize("name", RECORDINGS)
def test_read_equals_inspect(name, data_dir, gazelight_bin):
    path = data_dir / name
    s = inspect_json(gazelight_bin, path)
    rec, warned = _read(path)

    assert_matches_inspect(rec, s, warned)


def assert_matches_inspect(rec, s, warned):
    """The arrays of `rec` hold what `inspect --json` summarised in `s`."""
    assert rec.format == s["format"]
    # The same samples.
    for e in (0, 1):
        assert len(rec.eyes[e]) == s["samples"]["pupil"][e], f"eye {e}"
    assert int((rec.gaze.eyes == 0).sum()) == s["samples"]["gaze"]
    assert int((rec.gaze.eyes != 0).sum()) == s["samples"]["gaze_per_eye"]
    assert len(rec.recording_blinks["eye"]) == s["samples"]["blink_events"]
    assert sum(len(e) for e in rec.eyes) > 0, "a recording without pupil samples proves nothing"
    # The recording's blink events per eye (right, left, both) and the
    # chain's blinks and dropouts.
    rb = rec.recording_blinks["eye"]
    assert [int((rb == 0).sum()), int((rb == 1).sum()), int((rb == -1).sum())] == s["blinks"]["recording"]
    for e in (0, 1):
        assert len(rec.blinks(e)[0]) == s["blinks"]["detected"][e], f"eye {e} blinks"
        assert len(rec.dropouts(e)[0]) == s["dropouts"][e], f"eye {e} dropouts"
    # The measured (clean) and raw pupils: the same values give the same
    # ranges; mm where the pupil has a physical scale, else the raw unit.
    for e in (0, 1):
        eye, want = rec.eyes[e], s["pupil"][e]
        if len(eye) == 0:
            assert want["filtered_mm"] is None
            continue
        assert want["unit"] == eye.unit
        assert _range(eye.pupil_mm) == want["filtered_mm"], f"eye {e} measured mm"
        raw_clean = eye.measured_value[eye.measured_unit_code != 1]
        assert _range(raw_clean) == want["measured_raw"], f"eye {e} measured raw"
        raw = eye.pupil_raw[(eye.pupil_raw > 0) & np.isfinite(eye.pupil_raw)]
        assert (_range(raw) if len(raw) else None) == want["raw"], f"eye {e} raw"
        conf = eye.confidence[np.isfinite(eye.confidence)].clip(0, 1).astype(np.float64)
        assert conf.sum() / len(eye) == pytest.approx(want["confidence_mean"], rel=1e-9)
        usable = eye.outcome != 2
        m, r = int(eye.measured[usable].sum()), int(eye.dropout[usable].sum())
        want_drop = r / (m + r) if m + r else 1.0
        assert want_drop == pytest.approx(want["dropout_fraction"], rel=1e-12), f"eye {e} dropouts"
    t = np.concatenate([rec.eyes[0].t_secs, rec.eyes[1].t_secs, rec.gaze.t_secs, rec.recording_blinks["start_t_secs"]])
    assert float(t.max() - t.min()) == pytest.approx(s["duration_s"], abs=1e-9)
    # The recording's warnings, as Python warnings, are inspect's (inspect
    # may add its own rejection note after them).
    assert rec.warnings == s["warnings"][: len(rec.warnings)]
    assert warned == [f"{rec.path}: {w}" for w in rec.warnings]
    assert rec.skipped_records == s["skipped_records"]
    assert rec.stats == s["chain"]


def _timeline(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) if r[k] else np.nan for r in rows]) for k in rows[0]}


# (recording, seconds replayed): long recordings are cut to keep CI short.
FPS = 15
# The configuration's default `physio.max_rate_mm_per_s` (`gazelight config
# --print-default`).
MAX_RATE_MM_PER_S = 6.0
REPLAYS = [("eye/neon-demo", None), ("eye/piprkit-plr/pupil_trace.csv", "15")]


@pytest.mark.parametrize("name,secs", REPLAYS)
def test_read_equals_replay_timeline(name, secs, data_dir, gazelight_bin, tmp_path):
    """Each frame of a stereo replay shows the filtered pupil of the last
    sample at or before the frame: the arrays' value there (the timeline
    has 4 decimals)."""
    path = data_dir / name
    args = ["replay", str(path), "--stereo", "--backend", "cpu", "--size", "32x24", "--fps", str(FPS),
            "--no-frames", "--out", str(tmp_path / "out")]
    if secs:
        args += ["--secs", secs]
    run_cli(gazelight_bin, *args)
    tl = _timeline(tmp_path / "out" / "timeline.csv")
    rec, _ = _read(path)
    check_timeline(rec, tl, name, MAX_RATE_MM_PER_S)


def check_timeline(rec, tl, name, max_rate_mm_per_s, min_exact=0.9):
    """Each frame of a stereo replay's timeline shows the measured pupil of
    the last sample at or before the frame — that sample's own value, never
    rate-limited — where it is measured (`pupil_held` 0), and nothing where
    that sample is not clean. (`max_rate_mm_per_s` bounds only the
    aperture: each frame's `aperture_mm` moves from the previous one's by
    at most it per frame.)"""
    # The timeline's clock starts at the recording's first sample.
    t0 = min(float(a.min()) for a in (rec.eyes[0].t_secs, rec.eyes[1].t_secs, rec.gaze.t_secs) if len(a))
    # Frames sit at t0 + k / fps (the column is rounded to 4 decimals).
    t_frame = t0 + np.arange(len(tl["t_secs"])) / FPS
    np.testing.assert_allclose(t_frame - t0, tl["t_secs"], atol=5.1e-5)
    checked = 0
    for e, suffix in ((0, "_right"), (1, "_left")):
        eye = rec.eyes[e]
        i = np.searchsorted(eye.t_secs, t_frame, side="right") - 1
        ok = (i >= 0) & (tl["pupil_held" + suffix] == 0)
        want = eye.pupil_mm[np.maximum(i, 0)].astype(np.float64)
        # Measured frames show the last sample's own value (4 decimals).
        np.testing.assert_allclose(want[ok], tl["pupil_mm" + suffix][ok], atol=1.01e-4, err_msg=f"{name} eye {e}")
        # A frame whose last sample is not clean is held, not filled.
        assert np.all(np.isnan(tl["pupil_mm" + suffix][(i >= 0) & np.isnan(want)])), f"{name} eye {e}"
        exact = ok.mean()
        assert exact > min_exact * 0.5, f"{name} eye {e}: only {exact:.3f} of the frames measured"
        a = tl["aperture_mm" + suffix]
        assert np.all(np.abs(np.diff(a)) <= max_rate_mm_per_s / FPS + 2.01e-4), f"{name} eye {e} aperture"
        checked += int(ok.sum())
    assert checked > len(tl["t_secs"]), f"only {checked} frames compared"


def test_damaged_recordings_warn_as_inspect_does(tmp_path, data_dir, gazelight_bin):
    """Real recordings made imperfect: a CSV with a malformed row (skipped,
    counted, warned) and a Neon recording without calibration.bin (a note):
    read's Python warnings are inspect's."""
    lines = (data_dir / "eye/piprkit-plr/pupil_trace.csv").read_text().splitlines()[:400]
    lines[100] = lines[100].split(",")[0] + ",abc," + lines[100].split(",")[2]
    csv_path = tmp_path / "damaged.csv"
    csv_path.write_text("\n".join(lines) + "\n")
    neon = tmp_path / "neon-no-calibration"
    shutil.copytree(data_dir / "eye/neon-demo", neon)
    (neon / "calibration.bin").unlink()
    for path in (csv_path, neon):
        s = inspect_json(gazelight_bin, path)
        rec, warned = _read(path)
        assert rec.warnings, f"{path}: no warning to compare"
        assert_matches_inspect(rec, s, warned)


def test_dataframe_holds_both_eyes(data_dir, gazelight_bin):
    if not os.environ.get("CI"):
        pytest.importorskip("pandas")
    path = data_dir / "eye/neon-demo"
    s = inspect_json(gazelight_bin, path)
    df = gazelight.read(path, dataframe=True)
    assert len(df) == sum(s["samples"]["pupil"])
    assert list(df.groupby("eye").size()) == s["samples"]["pupil"]
    assert df["t_secs"].is_monotonic_increasing
    rec = gazelight.read(path)
    for e in (0, 1):
        sub = df[df["eye"] == e].sort_values("t_secs", kind="stable")
        np.testing.assert_array_equal(sub["pupil_mm"].to_numpy(), rec.eyes[e].pupil_mm)
        assert set(sub["unit"].astype(str)) == {s["pupil"][e]["unit"]}
    assert df["blink"].dtype == bool and df["dropout"].dtype == bool


def test_an_uncalibrated_eyelink_pupil_is_warned_about_as_the_cli_does(data_dir, gazelight_bin):
    """Issue 45 item 7: Python says what the CLI says, from the same
    function: an EyeLink file in area units with no physical scale is
    measured in its raw unit (no mm, no made-up 3.85 mm), and read() and
    inspect() warn as `gazelight inspect` does."""
    path = data_dir / "eye/eyelink-psa/both_eyes.asc"
    s = inspect_json(gazelight_bin, path)
    cli = [w for w in s["warnings"] if "no physical scale" in w]
    assert len(cli) == 1, s["warnings"]
    rec, warned = _read(path)
    assert [w for w in warned if "no physical scale" in w] == [f"{rec.path}: {cli[0]}"]
    for eye in rec.eyes:
        assert np.all(np.isnan(eye.pupil_mm)), "no mm without a physical scale"
        clean = np.isfinite(eye.measured_value)
        assert clean.mean() > 0.9
        np.testing.assert_array_equal(eye.measured_value[clean], eye.pupil_raw[clean])
        assert {eye.units[c] for c in eye.measured_unit_code[clean]} == {"arbitrary_area"}
    with pytest.warns(gazelight.GazelightWarning, match="no physical scale"):
        gazelight.inspect(path)
