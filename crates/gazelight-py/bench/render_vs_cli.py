"""Benchmark: gazelight.render from Python vs the CLI on the same input,
both writing every frame as PNG (issue 35).

    python render_vs_cli.py GAZELIGHT_BIN [--runs N] [--size WxH] [--fps F]
                            [--recording PATH --secs S [--stereo]]

Without --recording: the embedded demo (`gazelight render`, 12 s); with
it: `gazelight replay RECORDING --secs S`. The CLI runs with
`--backend cpu` (gazelight.render's pipeline); its time is the whole
process (it also writes the contact sheet, the plot, timeline.csv and
session.json). Python's is the loop `for frame, row in render(...):
write_png(...)` in a fresh process, and the whole process apart. Rounds
alternate the two.
"""

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, sys, time
import gazelight
a = json.loads(sys.argv[1])
t = time.perf_counter()
n = 0
for frame, row in gazelight.render(None, a["recording"], size=tuple(a["size"]), fps=a["fps"],
                                   stereo=a["stereo"], **({"secs": a["secs"]} if a["secs"] else {})):
    gazelight.write_png(f"{a['out']}/frame_{n:05d}.png", frame)
    n += 1
print(json.dumps({"loop_s": time.perf_counter() - t, "frames": n}))
"""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("binary")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--size", default="360x400")
    ap.add_argument("--fps", type=float, default=10.0)
    ap.add_argument("--recording")
    ap.add_argument("--secs", type=float)
    ap.add_argument("--stereo", action="store_true")
    a = ap.parse_args()
    w, h = (int(v) for v in a.size.split("x"))
    cli_s, loop_s, proc_s, frames = [], [], [], None
    for i in range(a.runs):
        with tempfile.TemporaryDirectory() as d:
            cmd = [a.binary] + (["replay", a.recording, "--secs", str(a.secs)] if a.recording else ["render"])
            cmd += ["--backend", "cpu", "--size", a.size, "--fps", str(a.fps), "--out", f"{d}/cli"]
            cmd += ["--stereo"] if a.stereo else []
            t = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            cli_s.append(time.perf_counter() - t)
            cli_frames = len(list(Path(d, "cli", "frames").glob("frame_*.png")))
            Path(d, "py").mkdir()
            arg = json.dumps({"recording": a.recording, "size": [w, h], "fps": a.fps, "stereo": a.stereo,
                              "secs": a.secs, "out": f"{d}/py"})
            t = time.perf_counter()
            out = subprocess.run([sys.executable, "-c", CHILD, arg], check=True, capture_output=True, text=True)
            proc_s.append(time.perf_counter() - t)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            loop_s.append(r["loop_s"])
            assert r["frames"] == cli_frames, (r["frames"], cli_frames)
            frames = cli_frames
    mc, ml, mp = statistics.median(cli_s), statistics.median(loop_s), statistics.median(proc_s)
    print(f"{frames} frames at {a.size}{' stereo' if a.stereo else ''}, {a.runs} runs")
    print(f"CLI (whole process): median {mc:.3f} s (runs {', '.join(f'{x:.3f}' for x in cli_s)})")
    print(f"Python render+write_png loop: median {ml:.3f} s (runs {', '.join(f'{x:.3f}' for x in loop_s)})")
    print(f"Python whole process: median {mp:.3f} s")
    print(f"ratio Python loop / CLI: {ml / mc:.2f}; Python process / CLI: {mp / mc:.2f}")


if __name__ == "__main__":
    main()
