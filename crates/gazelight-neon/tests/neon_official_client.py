#!/usr/bin/env python3
"""Checks the Neon-like peer (neon_peer.py) against Pupil Labs' official
Python client (`pupil-labs-realtime-api` on PyPI), so the fake the tests
use cannot drift from the reference decoder.

Starts the peer on the shared Neon recording, finds its sensors the way a
user of the official API does (`Device.get_status()`, the gaze and eye
events sensors' URLs), receives gaze with `receive_gaze_data` and eye
events with `receive_eye_events_data` (RTSP over TCP, `rtspt://`, and for
the 89-byte layout also over UDP, `rtsp://`, the client's default), and compares what the official decoder made of the packets with
the recording itself (read here from its raw files, not through the peer):
the packet type for the layout, each eye's pupil diameter, the worn flag,
increasing timestamps from the RTCP sender reports, and the recording's
blinks.

Usage: neon_official_client.py DATA_DIR [--layouts 65,89,105]
Prints PASS/FAIL lines; exits 1 on a FAIL, 2 when the client is missing.
"""
import argparse
import asyncio
import os
import struct
import subprocess
import sys
import time

try:
    from pupil_labs.realtime_api.device import Device
    from pupil_labs.realtime_api.streaming.eye_events import receive_eye_events_data
    from pupil_labs.realtime_api.streaming.gaze import receive_gaze_data
except ImportError as e:  # pragma: no cover
    print(f"SKIP the official client is not installed ({e}): pip install pupil-labs-realtime-api")
    sys.exit(2)

HERE = os.path.dirname(os.path.abspath(__file__))
fails = 0


def check(ok, what):
    global fails
    print(("PASS " if ok else "FAIL ") + what, flush=True)
    if not ok:
        fails += 1


def recording_pupils(data):
    """Each eye_state record's pupil diameters (left, right), in mm: the
    record is 20 little-endian float32s, per eye (left then right) the
    pupil diameter, the eyeball centre xyz, the optical axis xyz, then the
    eyelid angles and apertures (Neon's eye_state.dtype)."""
    path = os.path.join(data, "eye", "neon-demo", "eye_state ps1.raw")
    raw = open(path, "rb").read()
    n = len(raw) // 80
    out = []
    for i in range(n):
        v = struct.unpack_from("<20f", raw, i * 80)
        out.append((v[0], v[7]))
    return out


def recording_blinks_ms(data):
    """The recording's blinks (blinks ps1.raw: little-endian int32 type,
    int64 start ns, int64 end ns per record), as durations in ms."""
    raw = open(os.path.join(data, "eye", "neon-demo", "blinks ps1.raw"), "rb").read()
    return [round((e - s) / 1e6) for _, s, e in
            (struct.unpack_from("<iqq", raw, 20 * i) for i in range(len(raw) // 20))]


def start_peer(data, layout):
    p = subprocess.Popen(
        [sys.executable, os.path.join(HERE, "neon_peer.py"), "--data", data,
         "--layout", str(layout), "--sr-every", "50"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    line = p.stdout.readline()
    fields = dict(w.split("=", 1) for w in line.split()[1:])
    return p, int(fields["http"])


async def take(gen, n, limit_secs):
    out = []
    async def run():
        async for d in gen:
            out.append(d)
            if len(out) >= n:
                break
    try:
        await asyncio.wait_for(run(), limit_secs)
    except asyncio.TimeoutError:
        pass
    return out


async def check_layout(data, layout, pupils):
    peer, http = start_peer(data, layout)
    try:
        async with Device("127.0.0.1", http) as device:
            status = await device.get_status()
        gaze_sensor = status.direct_gaze_sensor()
        events_sensor = status.direct_eye_events_sensor()
        check(gaze_sensor is not None and gaze_sensor.connected,
              f"layout {layout}: /api/status lists a connected gaze sensor ({gaze_sensor.url if gaze_sensor else None})")
        url = gaze_sensor.url.replace("rtsp://", "rtspt://", 1)
        got = await take(receive_gaze_data(url), 300, 20)
        kinds = {type(d).__name__ for d in got}
        want = {65: "EyestateGazeData", 89: "EyestateEyelidGazeData", 105: "EyestateEyelidDualMonoGazeData"}[layout]
        check(len(got) >= 300 and kinds == {want},
              f"layout {layout}: the official client decoded {len(got)} packets as {sorted(kinds)} (expected {want})")
        # Match the decoded pupils to the recording's, in order: the peer
        # plays the records from the first.
        matched = 0
        for d, (left, right) in zip(got, pupils):
            if (abs(d.pupil_diameter_left - left) < 1e-4 and abs(d.pupil_diameter_right - right) < 1e-4):
                matched += 1
        check(matched == len(got),
              f"layout {layout}: {matched} of {len(got)} decoded pupil pairs equal the recording's eye_state records")
        ts = [d.timestamp_unix_seconds for d in got]
        span = ts[-1] - ts[0] if ts else 0.0
        check(all(b > a for a, b in zip(ts, ts[1:])) and abs(time.time() - ts[-1]) < 5.0 and 1.0 < span < 2.0,
              f"layout {layout}: timestamps from the sender reports increase, span {span:.3f} s for {len(ts)} packets at 200 Hz, "
              f"the last {time.time() - ts[-1]:.2f} s before now")
        check(all(d.worn for d in got), f"layout {layout}: the worn flag decodes as worn")
        if layout == 89:
            # The official client's own transport: RTP over UDP (rtsp://).
            udp = await take(receive_gaze_data(gaze_sensor.url), 200, 20)
            same = sum(1 for d, (l, r) in zip(udp, pupils)
                       if abs(d.pupil_diameter_left - l) < 1e-4 and abs(d.pupil_diameter_right - r) < 1e-4)
            check(len(udp) >= 200 and same == len(udp),
                  f"layout 89 over UDP (rtsp://, the official default): {len(udp)} packets, {same} pupil pairs equal the recording's")
            ev_url = events_sensor.url.replace("rtsp://", "rtspt://", 1)
            events = await take(receive_eye_events_data(ev_url), 2, 15)
            names = sorted({type(e).__name__ for e in events})
            durations = [round((e.end_time_ns - e.start_time_ns) / 1e6) for e in events if hasattr(e, "end_time_ns")]
            want_ms = recording_blinks_ms(data)
            check(names == ["BlinkEventData"] and durations == want_ms[:len(durations)] and durations,
                  f"layout 89: eye events decoded as {names}, blink durations {durations} ms "
                  f"(the recording's: {want_ms} ms)")
    finally:
        peer.stdin.close()
        peer.wait(timeout=10)


async def main():
    a = argparse.ArgumentParser()
    a.add_argument("data")
    a.add_argument("--layouts", default="65,89,105")
    args = a.parse_args()
    pupils = recording_pupils(args.data)
    for layout in (int(x) for x in args.layouts.split(",")):
        await check_layout(args.data, layout, pupils)


asyncio.run(main())
sys.exit(1 if fails else 0)
