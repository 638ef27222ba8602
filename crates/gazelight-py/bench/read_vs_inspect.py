"""Benchmark: gazelight.read(path) from Python vs `gazelight inspect` on the
same recording (issue 35: read ≤ 1.2× inspect, memory ≤ 2× the arrays).

    python read_vs_inspect.py GAZELIGHT_BIN RECORDING [--runs N]

Rounds alternate the two, each in a fresh process. inspect: the wall time of
the whole process. read: the wall time of the read() call (the interpreter's
start and `import gazelight` are not the recording's cost; they are printed
apart), and its memory: the peak resident size during read() (VmHWM) minus
the resident size before it (VmRSS), against the returned arrays' nbytes.
"""

import argparse
import json
import statistics
import subprocess
import sys
import time

CHILD = r"""
import sys, time, json
import gazelight
def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1]) * 1024
rss0 = status("VmRSS:")
t = time.perf_counter()
rec = gazelight.read(sys.argv[1])
dt = time.perf_counter() - t
nbytes = sum(a.nbytes for e in rec.eyes for a in vars(e).values() if hasattr(a, "nbytes"))
nbytes += sum(a.nbytes for a in vars(rec.gaze).values() if hasattr(a, "nbytes"))
print(json.dumps({"read_s": dt, "peak_minus_before": status("VmHWM:") - rss0, "arrays": nbytes,
                  "samples": [len(e) for e in rec.eyes], "gaze": len(rec.gaze)}))
"""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("binary")
    ap.add_argument("recording")
    ap.add_argument("--runs", type=int, default=5)
    a = ap.parse_args()
    inspect_s, read_s, proc_s, mem = [], [], [], []
    for _ in range(a.runs):
        t = time.perf_counter()
        subprocess.run([a.binary, "inspect", "--json", a.recording], check=True, capture_output=True)
        inspect_s.append(time.perf_counter() - t)
        t = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", CHILD, a.recording], check=True, capture_output=True, text=True)
        proc_s.append(time.perf_counter() - t)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        read_s.append(r["read_s"])
        mem.append(r)
    mi, mr = statistics.median(inspect_s), statistics.median(read_s)
    m = mem[-1]
    print(f"samples per eye {m['samples']}, gaze {m['gaze']}")
    print(f"inspect: median {mi:.3f} s (runs {', '.join(f'{x:.3f}' for x in inspect_s)})")
    print(f"read():  median {mr:.3f} s (runs {', '.join(f'{x:.3f}' for x in read_s)}); "
          f"whole python process {statistics.median(proc_s):.3f} s")
    print(f"ratio read/inspect: {mr / mi:.2f}")
    peak = max(x["peak_minus_before"] for x in mem)
    print(f"arrays {m['arrays'] / 1e6:.1f} MB, peak RSS growth during read {peak / 1e6:.1f} MB "
          f"= {peak / m['arrays']:.2f}x the arrays")


if __name__ == "__main__":
    main()
