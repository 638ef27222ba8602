"""Hostile paths and values given to the Python API (issue 48): each case
runs in its own subprocess under a time limit, which must exit normally
after printing what it caught (a hang, a panic across the boundary or an
allocation abort fails the case)."""

import json
import os
import subprocess
import sys
import textwrap

import pytest


def _catch(body: str, tmp_path, timeout: float = 60.0) -> dict:
    code = textwrap.dedent(
        """
        import json, os, sys
        import numpy as np
        import gazelight
        TMP = {tmp!r}
        try:
        {body}
            out = {{"type": None}}
        except Exception as e:
            out = {{"type": type(e).__name__, "message": str(e)}}
        print("RESULT " + json.dumps(out))
        """
    ).format(tmp=str(tmp_path), body=textwrap.indent(textwrap.dedent(body), "    "))
    try:
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"did not return within {timeout} s (a blocking open or an endless read)")
    assert p.returncode == 0, f"exit {p.returncode}\n{p.stdout}\n{p.stderr[-4000:]}"
    lines = [l for l in p.stdout.splitlines() if l.startswith("RESULT ")]
    assert lines, p.stdout
    return json.loads(lines[-1][len("RESULT "):])


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_as_trace_or_config_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "gaze.csv"
    os.mkfifo(fifo)  # nobody ever writes to it
    got = _catch("list(gazelight.render(None, os.path.join(TMP, 'gaze.csv'), frames=1))", tmp_path)
    assert got["type"] == "GazelightError", got
    assert "FIFO" in got["message"] and "gaze.csv" in got["message"], got
    got = _catch(
        "import pathlib; gazelight.render(None, None, config=pathlib.Path(TMP, 'gaze.csv'), frames=1)",
        tmp_path,
    )
    assert got["type"] == "GazelightError", got
    assert "FIFO" in got["message"], got


def test_an_endless_device_behind_a_csv_name_is_not_read(tmp_path):
    (tmp_path / "trace.csv").symlink_to("/dev/zero")
    got = _catch("gazelight.render(None, os.path.join(TMP, 'trace.csv'), frames=1)", tmp_path, timeout=30)
    assert got["type"] == "GazelightError", got
    assert "character device" in got["message"], got


def test_a_huge_config_file_is_refused_by_size(tmp_path):
    big = tmp_path / "big.toml"
    with open(big, "wb") as f:
        f.truncate(30_000_000)  # sparse: 30 MB that reads as NUL bytes
    got = _catch("import pathlib; gazelight.render(config=pathlib.Path(TMP, 'big.toml'), frames=1)", tmp_path)
    assert got["type"] == "GazelightError", got
    assert "limit" in got["message"], got


def test_a_csv_trace_is_still_told_from_a_recording(tmp_path):
    (tmp_path / "t.csv").write_text("# a comment\n\nt_secs, gaze_u, gaze_v, pupil_mm\n0,0.5,0.5,4\n1,0.5,0.5,4\n")
    (tmp_path / "p.csv").write_text("timestamp,pupil\n0,4\n")
    got = _catch(
        "assert gazelight._is_trace(os.path.join(TMP, 't.csv'))\n"
        "assert not gazelight._is_trace(os.path.join(TMP, 'p.csv'))\n"
        "assert not gazelight._is_trace(TMP)",
        tmp_path,
    )
    assert got["type"] is None, got


def test_write_png_checks_the_frame_size_before_copying_it(tmp_path):
    # A broadcast view: 4 bytes of memory whose shape claims 160 GB.
    got = _catch(
        "frame = np.broadcast_to(np.zeros((1, 1, 4), np.uint8), (200_000, 200_000, 4))\n"
        "gazelight.write_png(os.path.join(TMP, 'x.png'), frame)",
        tmp_path,
    )
    assert got["type"] == "ValueError", got
    assert "200000×200000" in got["message"], got
    assert not (tmp_path / "x.png").exists()


def test_render_refuses_the_luminance_scale_the_cli_refuses(tmp_path):
    for f in ("1e308", "1e21", "0.0"):
        got = _catch(f"gazelight.render(luminance_scale={f}, frames=1)", tmp_path)
        assert got["type"] == "GazelightError", (f, got)
        assert "1e20" in got["message"], (f, got)
    # A flat Radiance scene of ~4e17 cd/m² scaled by 1e20 passes the factor
    # bound but overflows the scene bound: refused rather than rendered black.
    hdr = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 32 +X 64\n" + bytes([128, 128, 128, 180]) * (64 * 32)
    (tmp_path / "hot.hdr").write_bytes(hdr)
    got = _catch(
        "gazelight.render(os.path.join(TMP, 'hot.hdr'), luminance_scale=1e20, frames=1, size=(16, 16))",
        tmp_path,
    )
    assert got["type"] == "GazelightError" and "overflow" in got["message"], got


def test_render_refuses_the_sizes_rates_and_counts_the_cli_refuses(tmp_path):
    """The bounds are the CLI's by construction (gazelight_app::bounds):
    the values `gazelight render --size/--fps/--frames` refuses, with the
    CLI's ranges in the message (Python accepted 1..=16384 px before)."""
    for call, words in [
        ("size=(4, 4)", "8..=8192"),
        ("size=(8193, 64)", "8..=8192"),
        ("size=(16384, 16384)", "8..=8192"),
        ("config='display.size = \"4x4\"'", "8..=8192"),
        ("fps=1e4", "1000"),
        ("fps=float('nan')", "1000"),
        ("frames=1_000_001", "1000000"),
    ]:
        got = _catch(f"gazelight.render({call}, frames=1)" if "frames" not in call else f"gazelight.render({call})", tmp_path)
        assert got["type"] == "GazelightError", (call, got)
        assert words in got["message"], (call, got)


def test_a_source_and_a_filter_chain_used_from_another_thread_raise_no_panic(tmp_path, data_dir):
    rec = str(data_dir / "eye/piprkit-plr/pupil_trace.csv")
    got = _catch(
        f"""
        import threading
        src = gazelight.Source("replay://" + {rec!r}, timeout=5)
        chain = gazelight.FilterChain()
        seen = []
        def other():
            try:
                with src:
                    seen.append(type(next(src)).__name__)
                seen.append(type(chain.push_pupil(0.0, 0, 4.0)).__name__)
            except Exception as e:  # a Python exception is fine
                seen.append("raised " + type(e).__name__)
            except BaseException as e:  # PanicException is a BaseException
                seen.append("PANIC " + type(e).__name__)
        t = threading.Thread(target=other)
        t.start()
        t.join(30)
        assert not t.is_alive(), "the thread did not end"
        assert not any(s.startswith("PANIC") for s in seen), seen
        assert seen == ["EyeState", "EyeState"], seen
        src.close()
        """,
        tmp_path,
    )
    assert got["type"] is None, got
