#!/usr/bin/env python3
"""A Pupil-Capture-like peer for gazelight's interop test (pyzmq + msgpack).

It speaks the parts of the Pupil Core Network API that gazelight uses:

* Pupil Remote (REP, --remote-port): `SUB_PORT`, `PUB_PORT`, `t` (Pupil
  time as text), `v` (version); a two-frame request [topic, msgpack] is a
  notification: it is recorded, published on the bus and answered
  "Message forwarded.". `T <time>` sets Pupil time to <time> now, as Pupil
  Capture does (hmd-eyes and many scripts send `T <unix time>`); it is
  counted like every command, so a test can assert that gazelight never
  sends it. Test-only commands: `peer.notifications` (JSON list of the
  notifications received), `peer.counts` (JSON: commands seen, datums
  published), `peer.stimulus` (JSON: the `gazelight.stimulus` colours
  received in order, the pupil targets of each colour, the time constant),
  `peer.outlier <time>` (publishes one `pupil.0.3d` datum stamped <time>,
  with an 8 mm pupil, between the regular ones).
* A simulated pupil light reflex: a `notify.gazelight.stimulus`
  notification with `color` = "black" | "white" | "none" sets the target
  of every published pupil diameter (2D px and 3D mm, both eyes) to its
  resting value times --black-gain, --white-gain or 1, and the published
  diameters follow the target with a first-order response (time constant
  --tau seconds), so a hardware-in-loop calibration can run against the
  peer. Before any stimulus the diameters are exactly the resting values.
* The bus (PUB, --sub-port): 2D and 3D pupil datums for both eyes,
  binocular gaze (`gaze.3d.01.`) and, every fifth cycle, monocular gaze
  (`gaze.3d.0.`, the right eye alone, as Pupil does when the left eye's
  confidence is below 0.6), at --rate Hz; plus, every tenth cycle, one
  datum with an unknown topic (`pupil.0.custom`) and one truncated msgpack
  frame, which a client must count and survive.
* Schedules (for the OpenXR layer's checks): --gaze-at T:U,V[:U0,V0]
  moves the binocular gaze (and eye 0's own, then sent with confidence
  0.9) from T s after the start,
  printed `GAZE <time> U V U0 V0`; --pupil-gain-at T:G sets both pupils'
  target to G x their resting diameters (the same first-order response),
  printed `PUPIL_GAIN <time> G`.
* Blinks (--blink-period P > 0): from P s after the start, every P s, for
  --blink-secs s, both eyes' pupil datums have confidence 0 and diameter 0
  (as Pupil publishes a closed eye) and the gaze datums confidence 0. Each
  blink is printed when it starts, `BLINK_START <start>`, and when it
  ends, `BLINK <start> <end>`, in time.monotonic() seconds
  (CLOCK_MONOTONIC on Linux), flushed.

Pupil time is the host's wall clock plus --offset seconds
(pupil_time = time.time() + offset), so a client can check its clock
offset estimate against a known value.

On start it prints one line, `READY remote=<port> sub=<port> pub=<port>`,
and flushes. Ports given as 0 are chosen free. It exits by itself after
--timeout seconds; all loops are bounded by that deadline.
"""

import argparse
import json
import math
import sys
import time

import msgpack
import zmq

VERSION = "3.5.7-gazelight-peer"

# The values the peer publishes; the interop test checks the same numbers.
PUPIL_2D = {
    0: {"diameter": 31.5, "confidence": 0.91, "norm_pos": [0.41, 0.52]},
    1: {"diameter": 36.25, "confidence": 0.87, "norm_pos": [0.58, 0.49]},
}
PUPIL_3D = {
    0: {"diameter_3d": 3.75, "model_confidence": 0.95, "theta": 1.62, "phi": -1.51},
    1: {"diameter_3d": 4.25, "model_confidence": 0.93, "theta": 1.55, "phi": -1.63},
}
GAZE_BINOCULAR = {"norm_pos": [0.3, 0.8], "confidence": 0.89}
GAZE_MONOCULAR = {"norm_pos": [0.6, 0.1], "confidence": 0.55}


def pupil_time(offset):
    return time.time() + offset


class Pupils:
    """The published diameters: resting values moved by the stimulus with a
    first-order response, d += (target - d) * (1 - exp(-dt / tau))."""

    def __init__(self, black_gain, white_gain, tau):
        self.gain = {"black": black_gain, "white": white_gain, "none": 1.0}
        self.tau = tau
        self.color = "none"
        self.px = {e: PUPIL_2D[e]["diameter"] for e in (0, 1)}
        self.mm = {e: PUPIL_3D[e]["diameter_3d"] for e in (0, 1)}
        self.last = time.monotonic()

    def targets(self, color):
        g = self.gain[color]
        return {
            "px": [PUPIL_2D[e]["diameter"] * g for e in (0, 1)],
            "mm": [PUPIL_3D[e]["diameter_3d"] * g for e in (0, 1)],
        }

    def show(self, color):
        if color not in self.gain:
            return False
        self.advance()
        self.color = color
        return True

    def advance(self):
        now = time.monotonic()
        k = 1.0 - math.exp(-max(0.0, now - self.last) / self.tau)
        self.last = now
        t = self.targets(self.color)
        for e in (0, 1):
            self.px[e] += (t["px"][e] - self.px[e]) * k
            self.mm[e] += (t["mm"][e] - self.mm[e]) * k


PUPILS = None


def pupil_2d(eye, ts):
    v = dict(PUPIL_2D[eye], diameter=PUPILS.px[eye])
    return {
        "topic": "pupil.%d.2d" % eye,
        "id": eye,
        "method": "2d c++",
        "timestamp": ts,
        "confidence": v["confidence"],
        "diameter": v["diameter"],
        "norm_pos": v["norm_pos"],
        "ellipse": {"center": [96.0, 90.5], "axes": [v["diameter"] * 0.92, v["diameter"]], "angle": 21.0},
    }


def pupil_3d(eye, ts):
    d = pupil_2d(eye, ts)
    v = dict(PUPIL_3D[eye], diameter_3d=PUPILS.mm[eye])
    d.update(
        {
            "topic": "pupil.%d.3d" % eye,
            "method": "pye3d 0.3.0 real-time",
            "diameter_3d": v["diameter_3d"],
            "model_confidence": v["model_confidence"],
            "theta": v["theta"],
            "phi": v["phi"],
            "circle_3d": {"center": [1.5, -0.5, 31.0], "normal": [0.05, -0.1, -0.99], "radius": v["diameter_3d"] / 2},
            "sphere": {"center": [1.0, 0.7, 41.0], "radius": 10.39},
            "projected_sphere": {"center": [99.0, 94.0], "axes": [121.0, 121.0], "angle": 0.0},
            "location": [96.0, 90.5],
            "model_id": 1,
        }
    )
    return d


def gaze(topic, values, base, ts):
    return {
        "topic": topic,
        "norm_pos": values["norm_pos"],
        "confidence": values["confidence"],
        "timestamp": ts,
        "base_data": base,
        "gaze_point_3d": [12.0, -40.0, 500.0],
        "eye_centers_3d": {0: [20.0, 15.0, -20.0], 1: [-40.0, 15.0, -20.0]},
        "gaze_normals_3d": {0: [0.0, 0.0, 1.0], 1: [0.1, 0.0, 1.0]},
    }


def schedule(items, parse):
    """[(t, value)] sorted by t from "T:REST" strings."""
    out = []
    for item in items:
        t, rest = item.split(":", 1)
        out.append((float(t), parse(rest)))
    return sorted(out, key=lambda x: x[0])


def at(plan, since, default):
    """The value of the newest schedule entry at or before `since`."""
    value = default
    for t, v in plan:
        if t <= since:
            value = v
    return value


def parse_gaze(rest):
    parts = rest.split(":")
    bino = [float(x) for x in parts[0].split(",")]
    mono = [float(x) for x in parts[1].split(",")] if len(parts) > 1 else GAZE_MONOCULAR["norm_pos"]
    return bino, mono


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--remote-port", type=int, default=0)
    ap.add_argument("--sub-port", type=int, default=0, help="bus port clients subscribe to (SUB_PORT)")
    ap.add_argument("--pub-port", type=int, default=0, help="bus port clients publish to (PUB_PORT)")
    ap.add_argument("--rate", type=float, default=200.0, help="pupil datums per eye per second")
    ap.add_argument("--offset", type=float, default=1234.5, help="pupil time - wall clock, seconds")
    ap.add_argument("--timeout", type=float, default=25.0, help="exit after this many seconds")
    ap.add_argument("--black-gain", type=float, default=1.5, help="pupil under black / resting pupil")
    ap.add_argument("--white-gain", type=float, default=0.6, help="pupil under white / resting pupil")
    ap.add_argument("--tau", type=float, default=0.1, help="time constant of the pupil response, s")
    ap.add_argument("--blink-period", type=float, default=0.0, help="a blink every this many s (0: none)")
    ap.add_argument("--blink-secs", type=float, default=0.2, help="how long each blink lasts, s")
    ap.add_argument(
        "--gaze-at",
        action="append",
        default=[],
        metavar="T:U,V[:U0,V0]",
        help="from T s after the start, the binocular gaze at norm_pos U,V (and eye 0's own gaze at U0,V0); repeatable",
    )
    ap.add_argument(
        "--pupil-gain-at",
        action="append",
        default=[],
        metavar="T:G",
        help="from T s after the start, both pupils move towards G x their resting diameter (first-order, --tau); repeatable",
    )
    args = ap.parse_args()
    global PUPILS
    PUPILS = Pupils(args.black_gain, args.white_gain, args.tau)
    gaze_plan = schedule(args.gaze_at, parse_gaze)
    gain_plan = schedule(args.pupil_gain_at, float)
    gaze_now = (GAZE_BINOCULAR["norm_pos"], GAZE_MONOCULAR["norm_pos"])
    stimuli = []

    ctx = zmq.Context.instance()
    rep = ctx.socket(zmq.REP)
    pub = ctx.socket(zmq.PUB)
    sub_in = ctx.socket(zmq.SUB)  # what clients' PUB sockets would connect to
    for s in (rep, pub, sub_in):
        s.setsockopt(zmq.LINGER, 0)

    def bind(sock, port):
        if port == 0:
            return sock.bind_to_random_port("tcp://127.0.0.1")
        sock.bind("tcp://127.0.0.1:%d" % port)
        return port

    remote_port = bind(rep, args.remote_port)
    sub_port = bind(pub, args.sub_port)
    pub_port = bind(sub_in, args.pub_port)
    print("READY remote=%d sub=%d pub=%d" % (remote_port, sub_port, pub_port), flush=True)

    notifications = []
    commands = {}
    published = 0
    deadline = time.monotonic() + args.timeout
    started = time.monotonic()
    blink_start = None
    period = 1.0 / args.rate
    next_pub = time.monotonic()
    cycle = 0
    poller = zmq.Poller()
    poller.register(rep, zmq.POLLIN)

    def send(topic, datum):
        nonlocal published
        pub.send_multipart([topic.encode(), msgpack.packb(datum, use_bin_type=True)])
        published += 1

    while time.monotonic() < deadline:
        wait_ms = max(0.0, (next_pub - time.monotonic()) * 1000.0)
        events = dict(poller.poll(timeout=min(wait_ms, 50.0)))
        if rep in events:
            frames = rep.recv_multipart()
            if len(frames) == 1:
                cmd = frames[0].decode("utf-8", "replace")
                name = cmd.split(" ", 1)[0]
                commands[name] = commands.get(name, 0) + 1
                if name == "T":
                    try:
                        args.offset = float(cmd.split(" ", 1)[1]) - time.time()
                        reply = "Timesync successful."
                    except (IndexError, ValueError):
                        reply = "Timesync failed."
                elif name == "peer.outlier":
                    d3 = pupil_3d(0, float(cmd.split(" ", 1)[1]))
                    d3["diameter_3d"] = 8.0
                    send("pupil.0.3d", d3)
                    reply = "ok"
                elif cmd == "SUB_PORT":
                    reply = str(sub_port)
                elif cmd == "PUB_PORT":
                    reply = str(pub_port)
                elif cmd == "t":
                    reply = repr(pupil_time(args.offset))
                elif cmd == "v":
                    reply = VERSION
                elif cmd == "peer.notifications":
                    reply = json.dumps(notifications)
                elif cmd == "peer.stimulus":
                    reply = json.dumps(
                        {
                            "log": stimuli,
                            "targets": {c: PUPILS.targets(c) for c in ("black", "white", "none")},
                            "tau_s": PUPILS.tau,
                        }
                    )
                elif cmd == "peer.counts":
                    reply = json.dumps({"commands": commands, "published": published})
                else:
                    reply = "Unknown command."
                rep.send_string(reply)
            else:
                topic = frames[0].decode("utf-8", "replace")
                payload = msgpack.unpackb(frames[1], raw=False, strict_map_key=False)
                notifications.append({"topic": topic, "payload": payload})
                if topic == "notify.gazelight.stimulus" and isinstance(payload, dict):
                    color = payload.get("color")
                    if isinstance(color, str) and PUPILS.show(color):
                        stimuli.append(color)
                pub.send_multipart([frames[0], frames[1]])
                rep.send_string("Message forwarded.")
        now = time.monotonic()
        if now >= next_pub:
            ts = pupil_time(args.offset)
            since = now - started
            if gain_plan:
                g = at(gain_plan, since, 1.0)
                if PUPILS.gain["none"] != g:
                    PUPILS.advance()
                    PUPILS.gain["none"] = g
                    print("PUPIL_GAIN %.6f %.4f" % (now, g), flush=True)
            PUPILS.advance()
            if gaze_plan:
                g = at(gaze_plan, since, gaze_now)
                if g != gaze_now:
                    gaze_now = g
                    print("GAZE %.6f %.4f %.4f %.4f %.4f" % (now, g[0][0], g[0][1], g[1][0], g[1][1]), flush=True)
            closed = (
                args.blink_period > 0
                and since >= args.blink_period
                and since % args.blink_period < args.blink_secs
            )
            if closed and blink_start is None:
                blink_start = now
                print("BLINK_START %.6f" % now, flush=True)
            elif not closed and blink_start is not None:
                print("BLINK %.6f %.6f" % (blink_start, now), flush=True)
                blink_start = None

            def lid(d):
                if closed:
                    d = dict(d, confidence=0.0)
                    for k in ("diameter", "diameter_3d"):
                        if k in d:
                            d[k] = 0.0
                return d

            base = []
            for eye in (0, 1):
                send("pupil.%d.2d" % eye, lid(pupil_2d(eye, ts)))
                d3 = lid(pupil_3d(eye, ts))
                send("pupil.%d.3d" % eye, d3)
                base.append(d3)
            bino = dict(GAZE_BINOCULAR, norm_pos=list(gaze_now[0]))
            # Scheduled: eye 0's own gaze confident enough to be used.
            mono = dict(GAZE_MONOCULAR, norm_pos=list(gaze_now[1]), confidence=0.9 if gaze_plan else GAZE_MONOCULAR["confidence"])
            send("gaze.3d.01.", lid(gaze("gaze.3d.01.", bino, base, ts)))
            if cycle % 5 == 0:
                send("gaze.3d.0.", lid(gaze("gaze.3d.0.", mono, base[:1], ts)))
            if cycle % 10 == 0:
                send("pupil.0.custom", {"timestamp": ts, "anything": 1})
                full = msgpack.packb(pupil_2d(1, ts), use_bin_type=True)
                pub.send_multipart([b"pupil.1.2d", full[: len(full) // 2]])
            cycle += 1
            next_pub += period
            if next_pub < now - 1.0:
                next_pub = now  # fell far behind: do not burst
    for s in (rep, pub, sub_in):
        s.close(0)
    ctx.term()
    return 0


if __name__ == "__main__":
    sys.exit(main())
