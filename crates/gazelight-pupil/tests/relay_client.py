#!/usr/bin/env python3
"""Reads gazelight's Pupil relay with Pupil Labs' official Python client.

Uses `pupil-core-network-client` (PyPI, `pip install
pupil-core-network-client`; tested with 1.0.0a5) exactly as an experiment
script would: `Device(address, port)` (connects to Pupil Remote, asks
PUB_PORT / SUB_PORT, estimates the clock offset with `t`), `subscribe()`,
`recv_new_message()`.

Prints JSON lines on stdout:

* `{"kind": "hello", ...}` once connected and subscribed (version, ports,
  the client's clock-offset statistics);
* `{"kind": "datum", "topic": ..., "payload": {...}}` for every message
  received, until --pupil pupil datums and --gaze gaze datums have arrived
  (or --timeout seconds have passed);
* `{"kind": "end", "t": <Pupil time from `t`>, "complete": bool}`.

Exit status 0 when the counts were reached, 3 on timeout, 2 when the
package is not installed.
"""

import argparse
import json
import sys
import time

try:
    import pupil_labs.pupil_core_network_client as pcnc
except ImportError as e:  # pragma: no cover - reported to the Rust test
    print(json.dumps({"kind": "error", "error": "pupil-core-network-client is not installed: %s" % e}), flush=True)
    sys.exit(2)


def plain(v):
    """msgpack values → JSON-able values (bytes as text)."""
    if isinstance(v, dict):
        return {str(k): plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    return v


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, required=True, help="Pupil Remote port of the relay")
    ap.add_argument("--pupil", type=int, default=100, help="pupil datums to collect")
    ap.add_argument("--gaze", type=int, default=50, help="gaze datums to collect")
    ap.add_argument("--light", type=int, default=0, help="gazelight.pupil_light datums to collect")
    ap.add_argument("--topics", default="pupil.,gaze.", help="comma-separated topic prefixes to subscribe to")
    ap.add_argument("--timeout", type=float, default=20.0)
    args = ap.parse_args()

    device = pcnc.Device(args.host, args.port)
    stats = device.clock_offset_statistics
    sub = device.subscribe([t for t in args.topics.split(",") if t])
    print(
        json.dumps(
            {
                "kind": "hello",
                "client_version": pcnc.__version__,
                "version": device.request_version(),
                "sub_port": device.ipc_sub_port,
                "pub_port": device.ipc_pub_port,
                "clock_offset_mean": stats.mean_offset,
                "clock_offset_std": stats.std_offset,
            }
        ),
        flush=True,
    )
    counts = {"pupil": 0, "gaze": 0, "gazelight": 0}
    deadline = time.monotonic() + args.timeout

    def done():
        return counts["pupil"] >= args.pupil and counts["gaze"] >= args.gaze and counts["gazelight"] >= args.light

    while time.monotonic() < deadline and not done():
        msg = sub.recv_new_message(timeout_ms=200)
        if msg is None:
            continue
        kind = msg.topic.split(".")[0]
        if kind in counts:
            counts[kind] += 1
        # JSON has no NaN (a residual where the pupil is not measured): null.
        payload = json.loads(json.dumps(plain(msg.payload)).replace("NaN", "null"))
        print(json.dumps({"kind": "datum", "topic": msg.topic, "payload": payload}), flush=True)
    complete = done()
    t = device.request_current_pupil_time()
    print(json.dumps({"kind": "end", "t": t, "complete": complete, "counts": counts}), flush=True)
    sub.disconnect()
    device.disconnect()
    sys.exit(0 if complete else 3)


if __name__ == "__main__":
    main()
