#!/usr/bin/env python3
"""`gazelight inspect` of a Pupil Core recording vs a plain Python msgpack
loop over the same files, in CPU time (issue 13).

Usage:
    pldata_vs_python.py GAZELIGHT_BIN REC_DIR [--runs N] [--record-secs S]

If REC_DIR holds no `pupil.pldata`, a recording is made first with the real
writer: the Pupil-Capture-like peer (`crates/gazelight-tracker/tests/
pupil_peer.py`, 2D + 3D pupil datums of both eyes and binocular /
monocular gaze with 3D base data, at --rate 1000 Hz per eye) recorded by
`gazelight record --secs S`.

Both sides run as child processes, timed with `os.wait4` (user + sys of
the process, start-up included), N runs each, interleaved; the median is
reported. The Python side reads `pupil.pldata` and `gaze.pldata` the way
Pupil's own `file_methods.load_pldata_file` does (`msgpack.Unpacker` over
the `[topic, payload]` records, `use_list=False, strict_map_key=False`) and
decodes every payload with `msgpack.unpackb` (the C extension), keeping
nothing. `gazelight inspect` decodes the same two files into samples, runs
them through the default filter chain and prints its summary.
"""

import argparse
import os
import pathlib
import statistics
import subprocess
import sys
import time

PY_LOOP = r"""
import sys, msgpack
n = 0
for path in sys.argv[1:]:
    with open(path, "rb") as fh:
        for topic, payload in msgpack.Unpacker(fh, use_list=False, strict_map_key=False):
            datum = msgpack.unpackb(payload, use_list=False, strict_map_key=False)
            n += 1
print(n)
"""

HERE = pathlib.Path(__file__).resolve().parent
PEER = HERE.parent.parent / "gazelight-tracker" / "tests" / "pupil_peer.py"


def cpu_run(argv):
    """Runs argv; returns (user+sys seconds, wall seconds, stdout)."""
    t0 = time.monotonic()
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    out = p.stdout.read()
    _, status, ru = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    wall = time.monotonic() - t0
    if p.returncode != 0:
        sys.exit("%s failed with %d" % (argv[:2], p.returncode))
    return ru.ru_utime + ru.ru_stime, wall, out.decode(errors="replace")


def record(binary, rec_dir, secs):
    peer = subprocess.Popen(
        [sys.executable, str(PEER), "--rate", "1000", "--timeout", str(secs + 30)],
        stdout=subprocess.PIPE,
        text=True,
    )
    line = peer.stdout.readline().split()
    remote = dict(kv.split("=") for kv in line[1:])["remote"]
    subprocess.run(
        [binary, "record", "--source", "pupil://127.0.0.1:%s" % remote,
         "--out", str(rec_dir), "--secs", str(secs)],
        check=True,
    )
    peer.kill()
    peer.wait()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("binary")
    ap.add_argument("rec_dir", type=pathlib.Path)
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--record-secs", type=float, default=10.0)
    args = ap.parse_args()
    if not (args.rec_dir / "pupil.pldata").is_file():
        record(args.binary, args.rec_dir, args.record_secs)
    files = [str(args.rec_dir / f) for f in ("pupil.pldata", "gaze.pldata")
             if (args.rec_dir / f).is_file()]
    size = sum(os.path.getsize(f) for f in files)
    rust, py = [], []
    n_py = None
    for _ in range(args.runs):
        cpu, wall, out = cpu_run([args.binary, "inspect", str(args.rec_dir)])
        rust.append((cpu, wall))
        cpu, wall, out = cpu_run([sys.executable, "-c", PY_LOOP] + files)
        py.append((cpu, wall))
        n_py = int(out.strip())
    _, _, summary = cpu_run([args.binary, "inspect", str(args.rec_dir)])
    r_cpu = statistics.median(c for c, _ in rust)
    p_cpu = statistics.median(c for c, _ in py)
    print("recording: %s (%d records in %s, %.1f MB)"
          % (args.rec_dir, n_py, ", ".join(os.path.basename(f) for f in files), size / 1e6))
    print("gazelight inspect: median CPU %.3f s (wall %.3f s) over %d runs"
          % (r_cpu, statistics.median(w for _, w in rust), args.runs))
    print("python msgpack loop: median CPU %.3f s (wall %.3f s) over %d runs"
          % (p_cpu, statistics.median(w for _, w in py), args.runs))
    print("ratio (python / gazelight, CPU): %.1fx" % (p_cpu / r_cpu))
    print("--- inspect output ---")
    print(summary.strip())


if __name__ == "__main__":
    main()
