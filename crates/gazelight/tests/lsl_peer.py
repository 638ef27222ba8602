#!/usr/bin/env python3
"""pylsl side of gazelight's LSL tests and benchmark.

read:  resolve streams by name, read them for --secs, print one JSON object:
       per stream the channel labels/units/types from the XML description,
       the samples (values), their LSL timestamps, the receipt times
       (pylsl.local_clock()) and the time correction. With --pupil-remote
       PORT it also subscribes to that Pupil peer's bus and records every
       datum's Pupil timestamp and its receipt time, plus the clock offsets
       (time.time() - local_clock()) so Pupil time can be put on the LSL clock.

relay: a pylsl outlet with Pupil Capture's LSL relay layout (name
       --name, type Gaze, 22 channels labelled as App-PupilLabs'
       pupil_capture_lsl_relay publishes them), or Neon's (--layout neon),
       pushing the fixed values below at --rate Hz for --secs; with
       --vanish-at T --gap G the outlet is destroyed at T s and a new one
       (same name) appears G s later; with --outlier-at T --outlier-secs X
       the one sample pushed first after T s is stamped X s off (the others
       keep the LSL clock); with --scale-at T --scale G every diameter is
       multiplied by G from T s on. Prints READY when the outlet exists.

markers: a string outlet (--name, type Markers, one channel, irregular
       rate) as a stimulus program publishes; prints READY, then on a line
       `go` on stdin waits for a consumer and pushes each of --labels
       (comma-separated) --gap s apart, stamped with local_clock() at the
       push less its --back seconds (comma-separated, default 0), prints
       one JSON list [label, local_clock at the push, stamp] and keeps the
       outlet --linger s.

Run with LSLAPICFG pointing at a machine-only configuration.
"""

import argparse
import json
import math
import sys
import time

import pylsl

RELAY_LABELS = [
    "confidence", "norm_pos_x", "norm_pos_y",
    "gaze_point_3d_x", "gaze_point_3d_y", "gaze_point_3d_z",
    "eye_center0_3d_x", "eye_center0_3d_y", "eye_center0_3d_z",
    "eye_center1_3d_x", "eye_center1_3d_y", "eye_center1_3d_z",
    "gaze_normal0_x", "gaze_normal0_y", "gaze_normal0_z",
    "gaze_normal1_x", "gaze_normal1_y", "gaze_normal1_z",
    "diameter0_2d", "diameter1_2d", "diameter0_3d", "diameter1_3d",
]
# The values the relay mimic publishes (the tests check the same numbers).
RELAY_VALUES = {
    "confidence": 0.93, "norm_pos_x": 0.3, "norm_pos_y": 0.8,
    "gaze_point_3d_x": 12.0, "gaze_point_3d_y": -40.0, "gaze_point_3d_z": 500.0,
    "diameter0_2d": 31.5, "diameter1_2d": 36.25,
    "diameter0_3d": 3.75, "diameter1_3d": 4.25,
}
NEON_LABELS = ["x", "y", "pupil_diameter_left", "pupil_diameter_right"]
NEON_VALUES = {"x": 800.0, "y": 300.0, "pupil_diameter_left": 4.5, "pupil_diameter_right": 3.5}


def describe(info):
    chans = []
    ch = info.desc().child("channels").child("channel")
    while not ch.empty():
        chans.append({
            "label": ch.child_value("label"),
            "unit": ch.child_value("unit"),
            "type": ch.child_value("type"),
            "eye": ch.child_value("eye"),
        })
        ch = ch.next_sibling()
    return {
        "name": info.name(), "type": info.type(), "channels": chans,
        "channel_count": info.channel_count(), "source": info.desc().child_value("source"),
        "manufacturer": info.desc().child_value("manufacturer"),
        "nominal_srate": info.nominal_srate(),
    }


def read(args):
    names = args.names.split(",")
    deadline = time.monotonic() + args.resolve_secs
    inlets = {}
    # All the names are resolved together, and each inlet is opened as soon
    # as its stream is seen: resolving them one after another left the later
    # streams connected seconds after the first on a loaded machine.
    while len(inlets) < len(names):
        for info in pylsl.resolve_streams(1.0):
            n = info.name()
            if n in names and n not in inlets:
                inlet = pylsl.StreamInlet(info, max_buflen=60, recover=False)
                inlet.open_stream(5.0)
                inlets[n] = inlet
        if len(inlets) < len(names) and time.monotonic() > deadline:
            missing = [n for n in names if n not in inlets]
            print(json.dumps({"error": "streams %s not found" % ",".join(missing)}))
            return 1
    sub = None
    if args.pupil_remote:
        import msgpack
        import zmq
        ctx = zmq.Context.instance()
        req = ctx.socket(zmq.REQ)
        req.connect("tcp://127.0.0.1:%d" % args.pupil_remote)
        req.send_string("SUB_PORT")
        sub_port = int(req.recv_string())
        sub = ctx.socket(zmq.SUB)
        sub.connect("tcp://127.0.0.1:%d" % sub_port)
        sub.setsockopt_string(zmq.SUBSCRIBE, "pupil.0.3d")
    print("READY", file=sys.stderr, flush=True)
    out = {n: {"info": describe(i.info(5.0)), "values": [], "t": [], "rx": []} for n, i in inlets.items()}
    datums = {"pupil_time": [], "rx": []}
    clock_pairs = []
    end = time.monotonic() + args.secs
    quiet_since = None
    lost = set()
    while time.monotonic() < end:
        got = False
        for n, inlet in inlets.items():
            while n not in lost:
                try:
                    s, ts = inlet.pull_sample(timeout=0.0)
                except pylsl.util.LostError:
                    lost.add(n)  # the outlet closed (end of the session)
                    break
                if s is None:
                    break
                got = True
                o = out[n]
                # JSON has no NaN: a not-a-number channel (a residual where
                # the pupil is not measured) becomes null.
                o["values"].append([None if isinstance(x, float) and not math.isfinite(x) else x for x in s])
                o["t"].append(ts)
                o["rx"].append(pylsl.local_clock())
        if sub is not None:
            while sub.poll(0):
                topic, payload = sub.recv_multipart()
                rx = pylsl.local_clock()
                d = msgpack.unpackb(payload, raw=False, strict_map_key=False)
                datums["pupil_time"].append(d["timestamp"])
                datums["rx"].append(rx)
                got = True
        if len(clock_pairs) < 200 or int(time.monotonic() * 10) % 10 == 0:
            a = time.time()
            l = pylsl.local_clock()
            b = time.time()
            clock_pairs.append([(a + b) / 2, l, b - a])
        if got:
            quiet_since = None
        else:
            if args.until_quiet and quiet_since is None:
                quiet_since = time.monotonic()
            if args.until_quiet and any(o["t"] for o in out.values()) and time.monotonic() - quiet_since > args.until_quiet:
                break
            time.sleep(0.0005)
    for n, inlet in inlets.items():
        try:
            out[n]["time_correction"] = inlet.time_correction(1.0)
        except Exception as e:  # lost
            out[n]["time_correction"] = None
    best = min(clock_pairs, key=lambda p: p[2])
    result = {"streams": out, "wall_minus_lsl": best[0] - best[1], "wall_window": best[2]}
    if sub is not None:
        result["pupil_datums"] = datums
    print(json.dumps(result))
    return 0


def make_outlet(args):
    labels = RELAY_LABELS if args.layout == "relay" else NEON_LABELS
    info = pylsl.StreamInfo(args.name, "Gaze", len(labels), args.rate, pylsl.cf_double64, args.name + "-src")
    chans = info.desc().append_child("channels")
    for l in labels:
        c = chans.append_child("channel")
        c.append_child_value("label", l)
    return pylsl.StreamOutlet(info), labels


def relay(args):
    outlet, labels = make_outlet(args)
    values_of = RELAY_VALUES if args.layout == "relay" else NEON_VALUES
    values = [values_of.get(l, float("nan")) for l in labels]
    print("READY", flush=True)
    start = time.monotonic()
    period = 1.0 / args.rate
    next_t = start
    pushed = 0
    vanished = False
    outlier_sent = False
    scaled = False
    while time.monotonic() - start < args.secs:
        now = time.monotonic()
        if args.vanish_at and not vanished and now - start >= args.vanish_at:
            del outlet
            vanished = True
            time.sleep(args.gap)
            outlet, _ = make_outlet(args)
            next_t = time.monotonic()
            continue
        if now >= next_t:
            if args.scale_at and not scaled and now - start >= args.scale_at:
                scaled = True
                values = [v * args.scale if l.startswith(("diameter", "pupil_diameter")) else v
                          for l, v in zip(labels, values)]
            stamp = pylsl.local_clock()
            if args.outlier_at and not outlier_sent and now - start >= args.outlier_at:
                outlier_sent = True
                stamp += args.outlier_secs
            outlet.push_sample(values, stamp)
            pushed += 1
            next_t += period
        else:
            time.sleep(min(next_t - now, 0.01))
    print("PUSHED %d" % pushed, flush=True)
    return 0


def markers(args):
    info = pylsl.StreamInfo(args.name, "Markers", 1, pylsl.IRREGULAR_RATE, pylsl.cf_string, args.name + "-src")
    outlet = pylsl.StreamOutlet(info)
    print("READY", flush=True)
    if sys.stdin.readline().strip() != "go":
        return 1
    if not outlet.wait_for_consumers(20.0):
        print(json.dumps({"error": "no consumer within 20 s"}), flush=True)
        return 1
    labels = args.labels.split(",")
    backs = [float(b) for b in args.back.split(",")] if args.back else [0.0] * len(labels)
    out = []
    for label, back in zip(labels, backs):
        now = pylsl.local_clock()
        stamp = now - back
        outlet.push_sample([label], stamp)
        out.append([label, now, stamp])
        time.sleep(args.gap)
    print(json.dumps(out), flush=True)
    time.sleep(args.linger)
    return 0


def main():
    ap = argparse.ArgumentParser()
    sp = ap.add_subparsers(dest="cmd", required=True)
    r = sp.add_parser("read")
    r.add_argument("--names", required=True)
    r.add_argument("--secs", type=float, default=5.0)
    r.add_argument("--resolve-secs", type=float, default=20.0)
    r.add_argument("--until-quiet", type=float, default=0.0, help="stop after this long without samples")
    r.add_argument("--pupil-remote", type=int, default=0)
    p = sp.add_parser("relay")
    p.add_argument("--name", required=True)
    p.add_argument("--layout", choices=["relay", "neon"], default="relay")
    p.add_argument("--rate", type=float, default=120.0)
    p.add_argument("--secs", type=float, default=6.0)
    p.add_argument("--vanish-at", type=float, default=0.0)
    p.add_argument("--gap", type=float, default=1.5)
    p.add_argument("--outlier-at", type=float, default=0.0)
    p.add_argument("--outlier-secs", type=float, default=1e5)
    p.add_argument("--scale-at", type=float, default=0.0)
    p.add_argument("--scale", type=float, default=1.0)
    m = sp.add_parser("markers")
    m.add_argument("--name", required=True)
    m.add_argument("--labels", required=True)
    m.add_argument("--back", default="")
    m.add_argument("--gap", type=float, default=0.3)
    m.add_argument("--linger", type=float, default=5.0)
    args = ap.parse_args()
    run = {"read": read, "relay": relay, "markers": markers}[args.cmd]
    sys.exit(run(args))


if __name__ == "__main__":
    main()
