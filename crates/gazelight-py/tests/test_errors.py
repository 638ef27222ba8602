"""Bad input from Python raises a clear exception with the CLI's message
and never takes the interpreter down: each case runs in its own
subprocess, which must exit normally after printing what it caught."""

import json
import subprocess
import sys
import textwrap

import pytest

from conftest import ROOT, run_cli

CASES = {
    # A missing recording: GazelightError with inspect's message.
    "missing_file": "gazelight.read('/nonexistent/recording.csv')",
    # A directory that is no recording.
    "not_a_recording": "gazelight.read('/proc/self')",
    # An XDF file with no eye stream (tests/data/xdf, pyxdf's example).
    "xdf_without_eye_data": "gazelight.read(ROOT + '/tests/data/xdf/minimal.xdf')",
    # Wrong types: TypeError from the argument conversion.
    "path_wrong_type": "gazelight.read(42)",
    "config_wrong_type": "gazelight.FilterChain(config=3.5)",
    "config_value_wrong_type": "gazelight.FilterChain({'confidence': {'min_confidence': object()}})",
    # A NaN configuration value: the filter's own check.
    "nan_config": "gazelight.FilterChain({'confidence': {'min_confidence': float('nan')}})",
    "nan_config_read": "gazelight.read(DATA + '/eye/neon-demo', config={'dropout': {'hold_s': float('nan')}})",
    "bad_toml": "gazelight.FilterChain('confidence = [')",
    "unknown_key": "gazelight.FilterChain({'confidense': {}})",
    "missing_calibration": "gazelight.Calibration.load('/nonexistent/profile.json')",
    "unit": "gazelight.FilterChain().push_pupil(0.0, 0, 4.0, unit='inch')",
    "lengths": "import numpy as np; gazelight.FilterChain().filter_pupils(np.zeros(3), right=np.zeros(2, np.float32))",
    "nan_samples": "import numpy as np; print('OK', gazelight.FilterChain().filter_pupils(np.full(3, np.nan), left=np.full(3, np.nan, np.float32)))",
    "eye_id": "print('OK', gazelight.FilterChain().push_pupil(0.0, 7, 4.0))",
    "nan_psf": "gazelight.psf(float('nan'))",
    "nan_fit": "import numpy as np; gazelight.PupilLightResponse(latency_secs=float('nan'))",
}


def _run(case: str, data_dir) -> dict:
    code = textwrap.dedent(
        f"""
        import json, sys
        import gazelight
        DATA = {str(data_dir)!r}
        ROOT = {str(ROOT)!r}
        try:
            {CASES[case]}
            out = {{"type": None}}
        except Exception as e:
            out = {{"type": type(e).__name__, "message": str(e)}}
        print("RESULT " + json.dumps(out))
        """
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    # A crash (a Rust panic across the boundary, a segfault, an abort)
    # shows as a signal or a non-zero exit.
    assert p.returncode == 0, f"{case}: exit {p.returncode}\n{p.stdout}\n{p.stderr}"
    lines = [l for l in p.stdout.splitlines() if l.startswith("RESULT ")]
    assert lines, p.stdout
    return json.loads(lines[-1][len("RESULT "):])


def _cli_error(stderr: str) -> str:
    lines = [l for l in stderr.splitlines() if l.startswith("error: ")]
    assert lines, stderr
    return lines[-1][len("error: "):]


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_raises(case, data_dir, gazelight_bin, tmp_path):
    got = _run(case, data_dir)
    if case in ("nan_samples", "eye_id"):
        assert got["type"] is None  # eye 7 and NaN samples are data, not errors
        return
    expected_type = {
        "path_wrong_type": "TypeError",
        "config_wrong_type": "TypeError",
        "config_value_wrong_type": "TypeError",
        "unit": "ValueError",
        "lengths": "ValueError",
    }.get(case, "GazelightError")
    assert got["type"] == expected_type, got
    msg = got["message"]
    # The CLI's message for the same input.
    if case == "missing_file":
        cli = run_cli(gazelight_bin, "inspect", "/nonexistent/recording.csv", check=False)
        assert cli.returncode != 0 and _cli_error(cli.stderr) == msg
    elif case == "not_a_recording":
        cli = run_cli(gazelight_bin, "inspect", "/proc/self", check=False)
        assert cli.returncode != 0 and _cli_error(cli.stderr) == msg
    elif case == "xdf_without_eye_data":
        cli = run_cli(gazelight_bin, "inspect", str(ROOT / "tests/data/xdf/minimal.xdf"), check=False)
        assert cli.returncode != 0 and _cli_error(cli.stderr) == msg
    elif case == "missing_calibration":
        rec = str(data_dir / "eye/neon-demo")
        cli = run_cli(gazelight_bin, "inspect", rec, "--calibration", "/nonexistent/profile.json", check=False)
        assert cli.returncode != 0 and _cli_error(cli.stderr) == msg
    elif case in ("nan_config", "nan_config_read"):
        key = "confidence]\nmin_confidence" if case == "nan_config" else "dropout]\nhold_s"
        cfg = tmp_path / "nan.toml"
        cfg.write_text(f"[filter.{key} = nan\n")
        cli = run_cli(gazelight_bin, "replay", str(data_dir / "eye/neon-demo"), "--config", str(cfg),
                      "--out", str(tmp_path / "o"), check=False)
        err = _cli_error(cli.stderr)
        assert cli.returncode != 0 and err.endswith(": " + msg), (err, msg)
        assert "NaN" in msg or "nan" in msg
    else:
        assert msg
