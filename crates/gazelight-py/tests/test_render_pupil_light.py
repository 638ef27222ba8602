"""gazelight.render of a recording against `gazelight replay`: the pupil
light response columns (`pupil_light_mm`, `pupil_residual_mm`, per view)
of each row equal the CLI's `timeline.csv`, and each view's parameters
(`Render.pupil_light_params`) its `session.json`, for shipped real
recordings: the EyeLink recording in mono with a calibration profile made
from its own dark and bright phases (and the calibration's display
luminances given), the Neon recording in stereo with the default
parameters, and a `pupil_fit` block; a bad `pupil_fit` raises the CLI's
message."""

import csv
import json
import math
from pathlib import Path

import pytest

import gazelight
from conftest import run_cli

# `timeline.csv` writes the pupil light columns with 4 decimals
# (crates/gazelight-output/src/sheet.rs) and leaves a cell empty where the value
# is not defined (NaN).
TOL_MM = 0.51e-4 + 1e-9


def _timeline(path: Path):
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        return reader.fieldnames, list(reader)


def _profile(gazelight_bin, data_dir: Path, tmp_path: Path) -> Path:
    """A calibration profile from the EyeLink recording's own dark and
    bright phases, after the pupil settled (as the CLI's
    crates/gazelight/tests/pupil_light.rs makes it)."""
    profile = tmp_path / "phases.json"
    run_cli(gazelight_bin, "profile", "phases", str(data_dir / "eye/eyelink-psa/both_eyes.asc"),
            "--black", "55..80", "--white", "5..30", "--out", str(profile))
    return profile


def _compare(cli_out: Path, r, suffixes, min_residuals: int):
    """Every row's pupil light columns = the CLI's, to its 4 decimals; NaN
    exactly where the CLI's cell is empty."""
    header, rows = _timeline(cli_out / "timeline.csv")
    cols = [f"{c}{s}" for s in suffixes for c in ("pupil_light_mm", "pupil_residual_mm")]
    assert all(c in header for c in cols), header
    frames = list(r)
    assert len(frames) == len(rows), (len(frames), len(rows))
    residuals = 0
    predicted = {c: [] for c in cols if c.startswith("pupil_light_mm")}
    for i, ((_, got), want) in enumerate(zip(frames, rows)):
        for c in cols:
            g = got[c]
            if want[c] == "":
                assert math.isnan(g), (i, c, g)
                continue
            assert abs(g - float(want[c])) <= TOL_MM, (i, c, g, want[c])
            if c.startswith("pupil_residual_mm"):
                residuals += 1
            else:
                predicted[c].append(g)
    # Not a trivial agreement: measured residuals, and a prediction that
    # moves with the light.
    assert residuals >= min_residuals, residuals
    for c, v in predicted.items():
        assert len(v) == len(rows) and max(v) - min(v) > 0.01, (c, min(v), max(v))


def _compare_params(cli_out: Path, r, suffixes, source: str):
    """`Render.pupil_light_params` = the `pupil_light*` entries of the
    CLI's session.json, value for value."""
    settings = json.loads((cli_out / "session.json").read_text())["settings"]
    params = r.pupil_light_params
    assert [p["view"] for p in params] == [s.lstrip("_") or "both" for s in suffixes]
    for p, s in zip(params, suffixes):
        assert p["source"] == source, p
        keys = ["latency_secs", "constriction_tau_secs", "redilation_tau_secs", "range_scale", "range_offset_mm"]
        if source == "fit":
            keys += ["fit_r_squared", "fit_rms_mm", "fit_samples_used"]
        for k in keys:
            want = settings[f"pupil_light{s}.{k}"]["value"]
            assert p[k] == pytest.approx(want, rel=1e-12, abs=1e-12), (s, k, p[k], want)
        want_source = {"fit": "flag"}.get(source, source)
        assert settings[f"pupil_light{s}.range_scale"]["source"] == want_source


def test_eyelink_mono_with_a_profile_equals_the_cli_replay(data_dir, gazelight_bin, tmp_path):
    """The EyeLink recording (a bright, then a dark screen), 85 s at 1 fps,
    with a calibration profile and the calibration's display luminances
    given (they change the range the profile maps onto the model)."""
    rec = data_dir / "eye/eyelink-psa/both_eyes.asc"
    profile = _profile(gazelight_bin, data_dir, tmp_path)
    out = tmp_path / "cli"
    run_cli(gazelight_bin, "replay", str(rec), "--backend", "cpu", "--calibration", str(profile),
            "--pupil-black-cd-m2", "0.05", "--pupil-white-cd-m2", "200", "--size", "48x40", "--fps", "1",
            "--secs", "85", "--no-frames", "--out", str(out))
    r = gazelight.render(None, rec, backend="cpu", size=(48, 40), fps=1.0, secs=85.0, calibration=profile,
                         pupil_black_cd_m2=0.05, pupil_white_cd_m2=200.0)
    _compare_params(out, r, ("",), "profile")
    _compare(out, r, ("",), min_residuals=50)


def test_neon_stereo_equals_the_cli_replay(data_dir, gazelight_bin, tmp_path):
    """The Neon recording in stereo: each eye's columns (`_left`,
    `_right`), 3 s at 10 fps, the default parameters (W&Y)."""
    rec = data_dir / "eye/neon-demo"
    out = tmp_path / "cli"
    run_cli(gazelight_bin, "replay", str(rec), "--backend", "cpu", "--stereo", "--size", "48x40", "--fps", "10",
            "--secs", "3", "--no-frames", "--out", str(out))
    r = gazelight.render(None, rec, backend="cpu", size=(48, 40), fps=10.0, secs=3.0, stereo=True)
    _compare_params(out, r, ("_left", "_right"), "default")
    _compare(out, r, ("_left", "_right"), min_residuals=30)


def test_a_fitted_block_equals_the_cli_replay(data_dir, gazelight_bin, tmp_path):
    """`pupil_fit` (`--pupil-fit 0..20`): the Neon recording's first 9 s
    (the block clamped to its end) on the forest panorama, where the fit
    succeeds; the fitted parameters (with R², rms and the samples used) and
    the columns over 3 s at 5 fps are the CLI's. Given as a tuple."""
    rec = data_dir / "eye/neon-demo"
    scene = data_dir / "hdr/blender-world/forest.exr"
    out = tmp_path / "cli"
    p = run_cli(gazelight_bin, "replay", str(rec), "--scene", str(scene), "--luminance-scale", "1000",
                "--backend", "cpu", "--pupil-fit", "0..20", "--size", "32x24", "--fps", "5", "--secs", "3",
                "--no-frames", "--out", str(out))
    assert "pupil light fit over 0..8.963258 s" in p.stdout, p.stdout
    r = gazelight.render(scene, rec, luminance_scale=1000.0, backend="cpu", size=(32, 24), fps=5.0, secs=3.0, pupil_fit=(0, 20))
    _compare_params(out, r, ("",), "fit")
    _compare(out, r, ("",), min_residuals=10)


def _cli_error(p) -> str:
    assert p.returncode != 0, p.stdout
    lines = [l for l in p.stderr.splitlines() if l.startswith("error: ")]
    assert lines, p.stderr
    return lines[-1][len("error: "):]


@pytest.mark.parametrize("recording,block", [
    ("eye/neon-demo", "5..3"),
    ("eye/neon-demo", "abc"),
    ("eye/neon-demo", "1..x"),
    ("eye/neon-demo", "-2..3"),
    ("eye/neon-demo", "100..110"),
    # The EyeLink recording has no samples between its phases: the fit
    # itself refuses the block.
    ("eye/eyelink-psa/both_eyes.asc", "36.5..46.5"),
])
def test_a_bad_pupil_fit_raises_the_clis_message(recording, block, data_dir, gazelight_bin, tmp_path):
    rec = data_dir / recording
    want = _cli_error(run_cli(gazelight_bin, "replay", str(rec), "--backend", "cpu", f"--pupil-fit={block}",
                              "--size", "32x24", "--fps", "10", "--secs", "1", "--no-frames", "--out",
                              str(tmp_path / "o"), check=False))
    assert f"--pupil-fit {block}" in want, want
    with pytest.raises(gazelight.GazelightError) as e:
        gazelight.render(None, rec, size=(32, 24), fps=10.0, secs=1.0, pupil_fit=block)
    assert str(e.value) == want


def test_pupil_fit_needs_a_recording():
    with pytest.raises(gazelight.GazelightError, match="apply to a recording"):
        gazelight.render(size=(32, 24), frames=1, pupil_fit="0..5")


def test_display_luminances_the_profile_cannot_map_raise_the_clis_message(data_dir, gazelight_bin, tmp_path):
    """A calibration's white darker than its black: the profile's pupils
    cannot be mapped onto the model; the CLI's message, flags and all."""
    rec = data_dir / "eye/eyelink-psa/both_eyes.asc"
    profile = _profile(gazelight_bin, data_dir, tmp_path)
    want = _cli_error(run_cli(gazelight_bin, "replay", str(rec), "--backend", "cpu", "--calibration", str(profile),
                              "--pupil-black-cd-m2", "100", "--pupil-white-cd-m2", "0.1", "--size", "32x24",
                              "--secs", "1", "--no-frames", "--out", str(tmp_path / "o"), check=False))
    assert "cannot be mapped onto the pupil light model" in want, want
    with pytest.raises(gazelight.GazelightError) as e:
        gazelight.render(None, rec, size=(32, 24), secs=1.0, calibration=profile, pupil_black_cd_m2=100.0,
                         pupil_white_cd_m2=0.1)
    assert str(e.value) == want
    # A luminance below 0 is refused before anything is read.
    with pytest.raises(gazelight.GazelightError, match=r"--pupil-white-cd-m2 -1: expected a luminance ≥ 0"):
        gazelight.render(None, rec, pupil_white_cd_m2=-1.0)
