#!/usr/bin/env python3
"""Live figures under hostile network input (issue 14, a measurement, not a CI test).

Starts the pyzmq Pupil peer (200 Hz) and `gazelight run --http --relay --out`
on 127.0.0.1, then for ATTACK_SECS attacks the status and relay ports only on
127.0.0.1 with a bounded number of requests: idle connections, random bytes,
oversized and slow ("slowloris") HTTP headers, malformed Pupil Remote
requests and `T 1e308`. Samples the run's resident set every second and, at
the end, reads timeline.csv: frame count and rate, NaN or zero pupils.

usage: attack_live.py GAZELIGHT_BINARY [ATTACK_SECS]
"""
import csv
import os
import random
import socket
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
PEER = os.path.join(HERE, "..", "..", "gazelight-tracker", "tests", "pupil_peer.py")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss_kib(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def connect(port, timeout=1.0):
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    s.settimeout(timeout)
    return s


def attack(http, relay, stop, counts):
    rng = random.Random(14)
    idle = []
    while not stop.is_set():
        kind = rng.randrange(6)
        try:
            if kind == 0 and len(idle) < 300:
                idle.append(connect(http))
            elif kind == 1:
                with connect(http) as s:
                    s.sendall(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 4096))))
            elif kind == 2:
                with connect(http) as s:
                    s.sendall(b"GET /api/status HTTP/1.1\r\nX: " + b"a" * 1_000_000 + b"\r\n\r\n")
            elif kind == 3:
                with connect(http) as s:
                    s.sendall(b"GET / HTTP/1.1\r\n")
                    for _ in range(5):
                        s.sendall(b"X-Slow: 1\r\n")
                        time.sleep(0.05)
            elif kind == 4:
                with connect(relay) as s:
                    s.sendall(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 512))))
            else:
                # A ZMTP greeting followed by garbage, and T 1e308 as text.
                with connect(relay) as s:
                    s.sendall(b"\xff" + b"\x00" * 8 + b"\x7f\x03\x00NULL" + b"\x00" * 48)
                    s.sendall(b"\x00\x07T 1e308")
            counts[kind] += 1
        except OSError:
            counts["refused"] += 1
        time.sleep(0.002)
    for s in idle:
        s.close()


def main():
    binary = sys.argv[1]
    attack_secs = float(sys.argv[2]) if len(sys.argv) > 2 else 20.0
    remote, sub, pub = free_port(), free_port(), free_port()
    peer = subprocess.Popen(
        [sys.executable, PEER, "--remote-port", str(remote), "--sub-port", str(sub),
         "--pub-port", str(pub), "--rate", "200", "--timeout", str(attack_secs + 30)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.5)
    http, relay = free_port(), free_port()
    out = f"/tmp/gazelight-attack-{os.getpid()}"
    run = subprocess.Popen(
        [binary, "run", "--headless", "--backend", "cpu", "--size", "320x256",
         "--secs", str(attack_secs + 6), "--source", f"pupil://127.0.0.1:{remote}",
         "--http", f"127.0.0.1:{http}", "--relay", f"127.0.0.1:{relay}", "--out", out],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env={**os.environ, "RUST_LOG": "error"})
    time.sleep(3)
    stop = threading.Event()
    counts = {k: 0 for k in range(6)}
    counts["refused"] = 0
    threads = [threading.Thread(target=attack, args=(http, relay, stop, counts)) for _ in range(4)]
    for t in threads:
        t.start()
    rss = []
    t0 = time.time()
    while time.time() - t0 < attack_secs:
        r = rss_kib(run.pid)
        if r:
            rss.append(r)
        time.sleep(1)
    stop.set()
    for t in threads:
        t.join()
    summary = run.communicate(timeout=60)[0].decode(errors="replace")
    peer.kill()
    rows = list(csv.DictReader(open(os.path.join(out, "timeline.csv"))))
    pupils = [float(r["pupil_mm"]) for r in rows]
    bad = [p for p in pupils if not (p > 0.0) or p != p]
    t = [float(r["t_secs"]) for r in rows]
    print(f"attacks: idle {counts[0]}, random {counts[1]}, 1 MB header {counts[2]}, "
          f"slowloris {counts[3]}, relay garbage {counts[4]}, ZMTP+T 1e308 {counts[5]}, "
          f"connect failures {counts['refused']}")
    print(f"run exit {run.returncode}; {summary.strip().splitlines()[0] if summary.strip() else ''}")
    print(f"timeline: {len(rows)} frames over {t[-1] - t[0]:.1f} s ({(len(rows) - 1) / (t[-1] - t[0]):.1f} Hz), "
          f"NaN or zero pupils: {len(bad)}, pupil range {min(pupils):.3f}-{max(pupils):.3f} mm")
    print(f"RSS KiB: first {rss[0]}, max {max(rss)}, last {rss[-1]}")
    return 0 if run.returncode == 0 and not bad else 1


if __name__ == "__main__":
    sys.exit(main())
