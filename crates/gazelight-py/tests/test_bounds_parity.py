"""The bounds on size, fps, frames and seconds are the same in both front
ends by construction (issue 44): each value below goes through the CLI
(`gazelight render`/`replay` with GAZELIGHT_PARSE_ONLY=1, the checks it
makes before opening anything) and through Python (`gazelight.check_render`,
the checks `gazelight.render` makes before opening anything), and both
must accept or refuse it as the documented ranges say (docs/robustness.md:
each side 8..=8192 px, 0.001 ≤ fps ≤ 1000, 1..=1000000 frames, 0 < secs ≤
30 days, 0 ≤ from_secs ≤ 30 days). A refusal must give the same rule
sentence in both (the part after the flag or argument's name)."""

import math
import os
import subprocess

import pytest

import gazelight

MAX_SECS = 30 * 86400  # 30 days (docs/robustness.md)

# (name, CLI flags, Python keyword arguments, accepted per the documented range)
RENDER_CASES = [
    ("size 7x7", ["--size", "7x7"], {"size": (7, 7)}, False),
    ("size 8x8", ["--size", "8x8"], {"size": (8, 8)}, True),
    ("size 8192x8192", ["--size", "8192x8192"], {"size": (8192, 8192)}, True),
    ("size 8193x1", ["--size", "8193x1"], {"size": (8193, 1)}, False),
    ("size 8x8193", ["--size", "8x8193"], {"size": (8, 8193)}, False),
    ("size 16384x16384", ["--size", "16384x16384"], {"size": (16384, 16384)}, False),
    ("fps 0", ["--fps", "0"], {"fps": 0.0}, False),
    ("fps -5", ["--fps", "-5"], {"fps": -5.0}, False),
    ("fps 0.0009", ["--fps", "0.0009"], {"fps": 0.0009}, False),
    ("fps 0.001", ["--fps", "0.001"], {"fps": 0.001}, True),
    ("fps 1000", ["--fps", "1000"], {"fps": 1000.0}, True),
    ("fps 1000.5", ["--fps", "1000.5"], {"fps": 1000.5}, False),
    ("fps 1e308", ["--fps", "1e308"], {"fps": 1e308}, False),
    ("fps nan", ["--fps", "NaN"], {"fps": math.nan}, False),
    ("fps inf", ["--fps", "inf"], {"fps": math.inf}, False),
    ("frames 0", ["--frames", "0"], {"frames": 0}, False),
    ("frames 1", ["--frames", "1"], {"frames": 1}, True),
    ("frames 1000000", ["--frames", "1000000"], {"frames": 1_000_000}, True),
    ("frames 1000001", ["--frames", "1000001"], {"frames": 1_000_001}, False),
]

REPLAY_CASES = [
    ("secs 0", ["--secs", "0"], {"secs": 0.0}, False),
    ("secs -1", ["--secs", "-1"], {"secs": -1.0}, False),
    ("secs 0.001", ["--secs", "0.001"], {"secs": 0.001}, True),
    ("secs 30 days", ["--secs", str(MAX_SECS)], {"secs": float(MAX_SECS)}, True),
    ("secs 30 days + 1", ["--secs", str(MAX_SECS + 1)], {"secs": float(MAX_SECS + 1)}, False),
    ("secs 1e308", ["--secs", "1e308"], {"secs": 1e308}, False),
    ("secs nan", ["--secs", "NaN"], {"secs": math.nan}, False),
    ("from_secs 0", ["--from-secs", "0"], {"from_secs": 0.0}, True),
    ("from_secs -1", ["--from-secs", "-1"], {"from_secs": -1.0}, False),
    ("from_secs 30 days", ["--from-secs", str(MAX_SECS)], {"from_secs": float(MAX_SECS)}, True),
    ("from_secs 30 days + 1", ["--from-secs", str(MAX_SECS + 1)], {"from_secs": float(MAX_SECS + 1)}, False),
    ("from_secs inf", ["--from-secs", "inf"], {"from_secs": math.inf}, False),
]

# The size from the configuration file: the same file to both.
CONFIG_SIZES = [("7x7", False), ("8x8", True), ("8192x8192", True), ("8193x1", False)]


def _cli(binary, args):
    env = dict(os.environ, GAZELIGHT_PARSE_ONLY="1")
    p = subprocess.run([str(binary), *args], capture_output=True, text=True, timeout=120, env=env)
    return p.returncode == 0, p.stderr


def _py(**kwargs):
    try:
        gazelight.check_render(**kwargs)
        return True, ""
    except gazelight.GazelightError as e:
        return False, str(e)


def _same_verdict(name, expected, cli, py):
    (cli_ok, cli_err), (py_ok, py_err) = cli, py
    assert cli_ok == expected, f"{name}: the CLI {'refused' if not cli_ok else 'accepted'} it: {cli_err}"
    assert py_ok == expected, f"{name}: Python {'refused' if not py_ok else 'accepted'} it: {py_err}"
    if not expected:
        # The rule's sentence, after the name Python gave the value.
        rule = py_err.split(": ", 1)[1]
        assert rule in cli_err, f"{name}: Python says {py_err!r}, the CLI {cli_err!r}"


def test_render_bounds_are_the_clis(gazelight_bin, tmp_path):
    out = str(tmp_path / "out")
    for name, flags, kwargs, expected in RENDER_CASES:
        cli = _cli(gazelight_bin, ["render", "--out", out, *flags])
        _same_verdict(name, expected, cli, _py(**kwargs))


def test_replay_bounds_are_the_clis(gazelight_bin, data_dir, tmp_path):
    rec = str(data_dir / "eye/piprkit-plr/pupil_trace.csv")
    out = str(tmp_path / "out")
    for name, flags, kwargs, expected in REPLAY_CASES:
        cli = _cli(gazelight_bin, ["replay", rec, "--out", out, *flags])
        _same_verdict(name, expected, cli, _py(trace_or_recording=rec, **kwargs))


def test_config_sizes_are_the_clis(gazelight_bin, tmp_path):
    out = str(tmp_path / "out")
    for size, expected in CONFIG_SIZES:
        cfg = tmp_path / f"size-{size}.toml"
        cfg.write_text(f'[display]\nsize = "{size}"\n')
        cli = _cli(gazelight_bin, ["render", "--out", out, "--config", str(cfg)])
        _same_verdict(f"display.size = {size}", expected, cli, _py(config=cfg))


@pytest.mark.parametrize("bad", ["[display]\nfps = -5.0\n", "[http]\naddr = \"localhost\"\n", "[scene]\nhead = \"spin\"\n"])
def test_a_bad_config_value_is_refused_by_both_in_the_same_words(gazelight_bin, tmp_path, bad):
    """Keys `render` does not use are still checked by the one loader
    (Python ignored them before, the CLI refused them)."""
    cfg = tmp_path / "bad.toml"
    cfg.write_text(bad)
    cli = _cli(gazelight_bin, ["render", "--out", str(tmp_path / "out"), "--config", str(cfg)])
    _same_verdict(bad.strip(), False, cli, _py(config=cfg))
