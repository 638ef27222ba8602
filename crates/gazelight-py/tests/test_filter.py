"""FilterChain and Calibration against the CLI: the same chain over arrays
gives what `read` (checked against inspect and replay) gives; a
calibration profile changes `read` exactly as `--calibration` changes
`inspect`; a configuration changes it as `replay --config` does."""

import json
import warnings

import numpy as np
import pytest

import gazelight
from conftest import inspect_json, run_cli
from test_read import FPS, _timeline, assert_matches_inspect, check_timeline


def test_filter_chain_over_arrays_equals_read(data_dir):
    path = data_dir / "eye/piprkit-plr/pupil_trace.csv"
    # The trace's own columns, read with numpy (time, left, right in mm).
    raw = np.genfromtxt(path, delimiter=",", names=True)
    rec = gazelight.read(path)
    chain = gazelight.FilterChain()
    t = np.ascontiguousarray(raw["time"])
    right, left = chain.filter_pupils(t, right=raw["right"].astype(np.float32), left=raw["left"].astype(np.float32))
    for eye, out in ((0, right), (1, left)):
        assert len(out) == len(rec.eyes[eye]) == len(raw)
        np.testing.assert_array_equal(rec.eyes[eye].t_secs, t)
        np.testing.assert_array_equal(out, rec.eyes[eye].pupil_mm)
        # A clean sample's measured pupil is its own value.
        clean = np.isfinite(out)
        raw_eye = (raw["right"], raw["left"])[eye].astype(np.float32)
        np.testing.assert_array_equal(out[clean], raw_eye[clean])
        assert clean.mean() > 0.95
    # The last state: the aperture is the last clean value (held), the
    # measured pupil the last sample's where it is clean.
    last = [right[np.isfinite(right)][-1], left[np.isfinite(left)][-1]]
    assert chain.state.measured_unit == ("mm", "mm")
    assert abs(chain.state.pupil_mm[0] - last[0]) < 0.5 and abs(chain.state.pupil_mm[1] - last[1]) < 0.5
    assert json.loads(chain.stats_json())["pupil_samples"] == [len(raw), len(raw)]


def _eyelink_profile(tmp_path, data_dir, gazelight_bin):
    # Black and white phases at the recording's own raw extremes (area units).
    s = inspect_json(gazelight_bin, data_dir / "eye/eyelink-psa/both_eyes.asc")
    eyes = {}
    for e, name in ((0, "right"), (1, "left")):
        r = s["pupil"][e]["raw"]
        eyes[name] = {"raw_unit": "arbitrary_area", "raw_black": r["max"], "raw_white": r["min"],
                      "mm_min": 2.0, "mm_max": 8.0}
    p = tmp_path / "eyelink-profile.json"
    p.write_text(json.dumps({"schema": "gazelight.pupil-calibration/2", "eyes": eyes}))
    return p


def test_calibration_changes_read_as_it_changes_inspect(tmp_path, data_dir, gazelight_bin):
    asc = data_dir / "eye/eyelink-psa/both_eyes.asc"
    profile = _eyelink_profile(tmp_path, data_dir, gazelight_bin)
    s = json.loads(run_cli(gazelight_bin, "inspect", "--json", str(asc), "--calibration", str(profile)).stdout)
    cal = gazelight.Calibration.load(profile)
    assert json.loads(cal.to_json())["eyes"]["right"]["mm_max"] == 8.0
    for given in (cal, str(profile), profile):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rec = gazelight.read(asc, calibration=given)
        warned = [str(w.message) for w in caught if issubclass(w.category, gazelight.GazelightWarning)]
        assert_matches_inspect(rec, s, warned)
    # Calibrated or not, the chain measures the raw pupil (no physical
    # scale): most samples are clean, none in mm; the black/white map gives
    # the aperture.
    assert rec.eyes[0].measured.mean() > 0.5
    plain = gazelight.read(asc)
    assert plain.eyes[0].measured.mean() > 0.5
    assert np.all(np.isnan(plain.eyes[0].pupil_mm))
    assert np.all(np.isnan(rec.eyes[0].pupil_mm))


def test_config_changes_read_as_it_changes_replay(tmp_path, data_dir, gazelight_bin):
    rec_path = data_dir / "eye/neon-demo"
    cfg = {"physio": {"max_rate_mm_per_s": 2.0}, "dropout": {"ease_rate_mm_per_s": 1.0},
           "clean": {"margin_before_s": 0.1}}
    toml = tmp_path / "study.toml"
    toml.write_text("[filter.physio]\nmax_rate_mm_per_s = 2.0\n[filter.dropout]\nease_rate_mm_per_s = 1.0\n"
                    "[filter.clean]\nmargin_before_s = 0.1\n")
    run_cli(gazelight_bin, "replay", str(rec_path), "--config", str(toml), "--stereo", "--backend", "cpu",
            "--size", "32x24", "--fps", str(FPS), "--no-frames", "--out", str(tmp_path / "out"))
    tl = _timeline(tmp_path / "out" / "timeline.csv")
    rec = gazelight.read(rec_path, config=cfg)
    default = gazelight.read(rec_path)
    check_timeline(rec, tl, "neon-demo with a config", 2.0, min_exact=0.8)
    for e in (0, 1):
        # And the configuration made a difference: wider margins before the
        # blinks discard more samples.
        assert np.isnan(rec.eyes[e].pupil_mm).sum() > np.isnan(default.eyes[e].pupil_mm).sum()
