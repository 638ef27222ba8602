#!/usr/bin/env python3
"""A Neon-like Real-time API peer for gazelight's tests (standard library only).

Serves GET /api/status (HTTP) and two RTSP presentations (camera=gaze,
camera=eye_events) played over RTSP/TCP interleaved (RTP on channel 0,
RTCP sender reports on channel 1) or, when SETUP asks for client_port=A-B,
as UDP datagrams to those ports (RTP to A, RTCP to B), as the Companion app
does for the official client. The gaze values are the Neon demo
recording's (DATA/eye/neon-demo: "gaze ps1.raw", "eye_state ps1.raw",
worn_200hz.raw, their .time files), packed big-endian in the layout the
official client's streaming/gaze.py decodes by length; the blinks are the
recording's "blinks ps1.raw" as eye events (!iqq, type 4), with type-5
keepalives between them.

Options choose the layout, the clock rate, the first RTP timestamp (to put a
32-bit wrap mid-stream), how often sender reports go out, whether times are
the recording's own or shifted to start now, malformed packets, and a drop:
after --drop-after packets the RTSP connection is closed and both listeners
refuse connections for --down-secs, then come back.

--clock-offset-ms X makes the phone's clock run X ms ahead of the real
time (packets, sender reports, blinks), and the Time Echo server (on the
port /api/status names as Phone.time_echo_port) answers with that clock.

--bad-sr-at N --bad-sr-secs X sends, with the N-th gaze packet of a
connection, one RTCP sender report whose NTP time is X s off (the RTP
timestamp right); the regular reports (--sr-every) are right.

--time-echo-lie ahead-1e6 | 1970 makes the Time Echo server lie about the
phone's clock: 1e6 s ahead of it, or a clock that says 1970 (the time since
this machine booted); the packets keep the phone's true clock.

--step-mm A,B replaces the recording's pupils by a square wave (both eyes,
A then B mm, --step-secs each, starting at start_unix_ns) to check that
the filters follow step changes.

Prints one line "READY http=PORT rtsp=PORT start_unix_ns=NS" when listening.
"""
import argparse
import json
import os
import socket
import struct
import sys
import threading
import time

NTP_UNIX = 2208988800


def load(data_dir):
    d = os.path.join(data_dir, "eye", "neon-demo")

    def raw(name):
        with open(os.path.join(d, name), "rb") as f:
            return f.read()

    gaze = raw("gaze ps1.raw")
    state = raw("eye_state ps1.raw")
    times = struct.unpack("<%dQ" % (len(raw("eye_state ps1.time")) // 8), raw("eye_state ps1.time"))
    worn = raw("worn_200hz.raw")
    n = min(len(gaze) // 8, len(state) // 80, len(times), len(worn))
    recs = []
    for i in range(n):
        x, y = struct.unpack_from("<2f", gaze, 8 * i)
        es = struct.unpack_from("<20f", state, 80 * i)
        recs.append((times[i], x, y, worn[i], es))
    blinks_raw = raw("blinks ps1.raw")
    blinks = [struct.unpack_from("<iqq", blinks_raw, 20 * i) for i in range(len(blinks_raw) // 20)]
    return recs, blinks


def gaze_payload(layout, rec):
    _, x, y, worn, es = rec
    if layout == 9:
        return struct.pack("!ffB", x, y, worn)
    if layout == 17:
        return struct.pack("!ffBff", x, y, worn, x, y)
    if layout == 25:
        return struct.pack("!ffB4f", x, y, worn, x, y, x, y)
    if layout == 65:
        return struct.pack("!ffB14f", x, y, worn, *es[:14])
    if layout == 89:
        return struct.pack("!ffB20f", x, y, worn, *es)
    if layout == 105:
        return struct.pack("!ffB24f", x, y, worn, *es, x, y, x, y)
    raise SystemExit("unknown layout %d" % layout)


def rtp(seq, ts, payload, pt=99):
    return struct.pack("!BBHII", 0x80, pt, seq & 0xFFFF, ts & 0xFFFFFFFF, 0x4E454F4E) + payload


def sender_report(unix_ns, ts):
    secs = unix_ns // 1_000_000_000 + NTP_UNIX
    frac = ((unix_ns % 1_000_000_000) << 32) // 1_000_000_000
    return struct.pack("!BBHIIIIII", 0x80, 200, 6, 0x4E454F4E, secs, frac, ts & 0xFFFFFFFF, 0, 0)


def frame(channel, data):
    return b"$" + bytes([channel]) + struct.pack("!H", len(data)) + data


class State:
    def __init__(self):
        self.down_until = 0.0
        self.lock = threading.Lock()
        self.sent = 0
        self.gaze_plays = 0

    def down(self):
        return time.time() < self.down_until


def read_request(f):
    lines = []
    while True:
        line = f.readline(4096)
        if not line:
            return None
        line = line.rstrip(b"\r\n").decode("latin-1")
        if not line:
            if lines:
                break
            continue
        lines.append(line)
    method, url, _ = (lines[0].split(" ") + ["", ""])[:3]
    headers = {}
    for l in lines[1:]:
        if ":" in l:
            k, v = l.split(":", 1)
            headers[k.strip().lower()] = v.strip()
    return method, url, headers


class TcpSink:
    """RTP (channel 0) and RTCP (channel 1) interleaved on the RTSP connection."""

    def __init__(self, conn):
        self.conn = conn
        self.closed = False

    def send(self, items):
        self.conn.sendall(b"".join(frame(c, d) for c, d in items))

    def shutdown(self):
        self.conn.shutdown(socket.SHUT_RDWR)


class UdpSink:
    """RTP and RTCP as UDP datagrams to the client's two ports."""

    def __init__(self, sock, rtp_addr, rtcp_addr):
        self.sock, self.addrs = sock, (rtp_addr, rtcp_addr)
        self.closed = False  # set when the RTSP connection ends

    def send(self, items):
        if self.closed:
            raise OSError("the RTSP session ended")
        for c, d in items:
            self.sock.sendto(d, self.addrs[c])

    def shutdown(self):
        self.sock.close()


def serve_rtsp(conn, args, recs, blinks, st, start_unix_ns, rtsp_port):
    f = conn.makefile("rb")
    camera = None
    playing = False
    sink = TcpSink(conn)
    try:
        while not playing:
            req = read_request(f)
            if req is None:
                return
            method, url, h = req
            cseq = h.get("cseq", "0")
            if "camera=" in url:
                camera = url.split("camera=", 1)[1].split("&")[0].split("/")[0]
            rate = args.clock
            if method == "OPTIONS":
                conn.sendall(("RTSP/1.0 200 OK\r\nCSeq: %s\r\nPublic: DESCRIBE, SETUP, PLAY, OPTIONS\r\n\r\n" % cseq).encode())
            elif method == "DESCRIBE":
                enc = "com.pupillabs.gaze1" if camera == "gaze" else "com.pupillabs.eye_events1"
                sdp = ("v=0\r\no=- 0 0 IN IP4 127.0.0.1\r\ns=neon peer\r\nt=0 0\r\n"
                       "m=application 0 RTP/AVP 99\r\na=rtpmap:99 %s/%d\r\na=control:trackID=0\r\n" % (enc, rate))
                conn.sendall(("RTSP/1.0 200 OK\r\nCSeq: %s\r\nContent-Type: application/sdp\r\n"
                              "Content-Base: rtsp://127.0.0.1:%d/?camera=%s\r\nContent-Length: %d\r\n\r\n%s"
                              % (cseq, rtsp_port, camera, len(sdp), sdp)).encode())
            elif method == "SETUP":
                transport = h.get("transport", "")
                ports = [p.split("=", 1)[1] for p in transport.split(";") if p.strip().startswith("client_port=")]
                if ports and "/TCP" not in transport:
                    # RTP over UDP to the client's ports (RTP, RTCP).
                    a, _, b = ports[0].partition("-")
                    a = int(a)
                    b = int(b) if b else a + 1
                    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                    udp.bind(("127.0.0.1", 0))
                    sp = udp.getsockname()[1]
                    peer_ip = conn.getpeername()[0]
                    sink = UdpSink(udp, (peer_ip, a), (peer_ip, b))
                    conn.sendall(("RTSP/1.0 200 OK\r\nCSeq: %s\r\nSession: 12345678;timeout=60\r\n"
                                  "Transport: RTP/AVP;unicast;client_port=%d-%d;server_port=%d-%d\r\n\r\n"
                                  % (cseq, a, b, sp, sp + 1)).encode())
                else:
                    conn.sendall(("RTSP/1.0 200 OK\r\nCSeq: %s\r\nSession: 12345678;timeout=60\r\n"
                                  "Transport: RTP/AVP/TCP;unicast;interleaved=0-1\r\n\r\n" % cseq).encode())
            elif method == "PLAY":
                conn.sendall(("RTSP/1.0 200 OK\r\nCSeq: %s\r\nSession: 12345678\r\n\r\n" % cseq).encode())
                playing = True
            else:
                conn.sendall(("RTSP/1.0 405 Method Not Allowed\r\nCSeq: %s\r\n\r\n" % cseq).encode())
        # Answer keepalives in the background.
        def drain():
            try:
                while True:
                    req = read_request(f)
                    if req is None:
                        sink.closed = True
                        return
                    conn.sendall(("RTSP/1.0 200 OK\r\nCSeq: %s\r\n\r\n" % req[2].get("cseq", "0")).encode())
            except OSError:
                sink.closed = True
                return
        threading.Thread(target=drain, daemon=True).start()
        if camera == "gaze":
            with st.lock:
                replayed = st.gaze_plays > 0
                st.gaze_plays += 1
            if replayed and args.time == "now":
                # A device stamps what it streams with its clock now: a
                # reconnect replays the recording from its start at today's
                # time, not at the time of the first connection.
                start_unix_ns = time.time_ns() + args.clock_offset_ms * 1_000_000
            play_gaze(sink, args, recs, st, start_unix_ns)
        else:
            play_events(sink, args, blinks, recs, st, start_unix_ns)
    except OSError:
        pass
    finally:
        try:
            conn.close()
        except OSError:
            pass


def rec_unix_ns(args, recs, i, start_unix_ns):
    return recs[i][0] - recs[0][0] + start_unix_ns


def play_gaze(sink, args, recs, st, start_unix_ns):
    rate = args.clock
    t0 = time.monotonic()
    n = len(recs)
    i = 0
    k = 0  # packets sent on this connection
    while args.loops == 0 or i < n * args.loops:
        idx = i % n
        lap = i // n
        unix_ns = rec_unix_ns(args, recs, idx, start_unix_ns) + lap * (recs[-1][0] - recs[0][0] + 5_000_000)
        rel_ns = unix_ns - start_unix_ns
        ts = (args.rtp_start + (rel_ns * rate) // 1_000_000_000) & 0xFFFFFFFF
        # Pace on the recording's clock.
        due = t0 + rel_ns / 1e9 / args.speed if args.pace else 0
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        if args.stamp_send:
            # The packet's time is when it leaves (the same linear RTP
            # clock, so the sender reports stay consistent).
            unix_ns = time.time_ns() + args.clock_offset_ms * 1_000_000
            rel_ns = unix_ns - start_unix_ns
            ts = (args.rtp_start + (rel_ns * rate) // 1_000_000_000) & 0xFFFFFFFF
        out = []
        if k == 0 or (args.sr_every > 0 and k % args.sr_every == 0):
            out.append((1, sender_report(unix_ns, ts)))
        if args.bad_sr_at and k == args.bad_sr_at:
            out.append((1, sender_report(unix_ns + int(args.bad_sr_secs * 1e9), ts)))
        if args.malformed_every and k % args.malformed_every == args.malformed_every - 1:
            out.append((0, rtp(i, ts, b"\x00" * 7)))  # a 7-byte gaze payload: no layout
            out.append((0, b"\x80\x63\x00"))  # a 3-byte RTP packet
        rec = recs[idx]
        if args.step_mm:
            a, b = (float(v) for v in args.step_mm.split(","))
            mm = a if int(rel_ns / 1e9 / args.step_secs) % 2 == 0 else b
            es = list(rec[4])
            es[0] = es[7] = mm  # pupil diameters, left and right
            es[16] = es[19] = 10.0  # eyelid apertures: open
            rec = (rec[0], rec[1], rec[2], 255, tuple(es))
        out.append((0, rtp(i, ts, gaze_payload(args.layout, rec))))
        sink.send(out)
        i += 1
        k += 1
        with st.lock:
            st.sent += 1
        if args.drop_after and k == args.drop_after:
            st.down_until = time.time() + args.down_secs
            args.drop_after = 0  # drop once
            sink.shutdown()
            return
    # End of data: keep the connection open but silent (a dead peer).
    time.sleep(3600)


def play_events(sink, args, blinks, recs, st, start_unix_ns):
    rate = args.clock
    t0 = time.monotonic()
    seq = 0
    sent_blinks = set()
    first = True
    while True:
        now_rel_ns = int((time.monotonic() - t0) * 1e9 * args.speed)
        unix_ns = start_unix_ns + now_rel_ns
        ts = (args.rtp_start + (now_rel_ns * rate) // 1_000_000_000) & 0xFFFFFFFF
        out = []
        if first:
            out.append((1, sender_report(unix_ns, ts)))
            first = False
        for j, (etype, s, e) in enumerate(blinks):
            e_unix = e - recs[0][0] + start_unix_ns
            if j not in sent_blinks and e_unix <= unix_ns:
                sent_blinks.add(j)
                out.append((0, rtp(seq, ts, struct.pack("!iqq", etype, s - recs[0][0] + start_unix_ns, e_unix))))
                seq += 1
        out.append((0, rtp(seq, ts, struct.pack("!i", 5))))  # keepalive
        seq += 1
        sink.send(out)
        time.sleep(0.25)


def status_json(rtsp_port, args):
    def sensor(name):
        return {"model": "Sensor", "data": {
            "sensor": name, "conn_type": "DIRECT", "connected": True, "ip": "127.0.0.1",
            "port": rtsp_port, "protocol": "rtsp", "params": "camera=%s&audioenable=on" % name,
            "stream_error": False}}
    # Every field the official client's models require (its Status parser
    # refuses a Phone without them; checked by neon_official_client.py).
    phone = {"battery_level": 87, "battery_state": "OK", "device_id": "gazelight-test-peer",
             "device_name": "Neon Companion (gazelight test peer)", "ip": "127.0.0.1",
             "memory": 64_000_000_000, "memory_state": "OK"}
    if args.time_echo_port:
        phone["time_echo_port"] = args.time_echo_port
    hardware = {"version": "2.0", "glasses_serial": "test", "world_camera_serial": "test",
                "module_serial": "test"}
    result = [{"model": "Phone", "data": phone}, {"model": "Hardware", "data": hardware},
              sensor("gaze")]
    if not args.no_events:
        result.append(sensor("eye_events"))
    return json.dumps({"message": "Success", "result": result}).encode()


def serve_http(conn, rtsp_port, args):
    try:
        f = conn.makefile("rb")
        req = read_request(f)
        if req is None:
            return
        body = status_json(rtsp_port, args) if req[1] == "/api/status" else b"{}"
        code = "200 OK" if req[1] == "/api/status" else "404 Not Found"
        conn.sendall(("HTTP/1.1 %s\r\nContent-Type: application/json\r\nContent-Length: %d\r\n"
                      "Connection: close\r\n\r\n" % (code, len(body))).encode() + body)
    except OSError:
        pass
    finally:
        conn.close()


def serve_time_echo(conn, args):
    """The Time Echo protocol: each 8-byte client time (ms, !Q) is answered
    with itself and the phone's time (ms, !Q), the phone's clock running
    --clock-offset-ms ahead of the real time."""
    try:
        f = conn.makefile("rb")
        while True:
            t1 = f.read(8)
            if len(t1) < 8:
                return
            phone_ms = time.time_ns() // 1_000_000 + args.clock_offset_ms
            if args.time_echo_lie == "ahead-1e6":
                phone_ms += 1_000_000_000
            elif args.time_echo_lie == "1970":
                phone_ms = time.monotonic_ns() // 1_000_000
            conn.sendall(t1 + struct.pack("!Q", phone_ms))
    except OSError:
        pass
    finally:
        conn.close()


def accept_loop(sock, st, handler):
    while True:
        conn, _ = sock.accept()
        if st.down():
            conn.close()  # the phone is "off the network"
            continue
        threading.Thread(target=handler, args=(conn,), daemon=True).start()


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--data", required=True, help="the shared data directory")
    p.add_argument("--layout", type=int, default=89)
    p.add_argument("--clock", type=int, default=90000)
    p.add_argument("--rtp-start", type=lambda s: int(s, 0), default=0)
    p.add_argument("--sr-every", type=int, default=200, help="sender report every N packets (0: only the first)")
    p.add_argument("--time", choices=["recording", "now"], default="now")
    p.add_argument("--speed", type=float, default=1.0)
    p.add_argument("--no-pace", dest="pace", action="store_false")
    p.add_argument("--loops", type=int, default=0, help="0 = loop forever")
    p.add_argument("--malformed-every", type=int, default=0)
    p.add_argument("--drop-after", type=int, default=0)
    p.add_argument("--down-secs", type=float, default=1.0)
    p.add_argument("--no-events", action="store_true")
    p.add_argument("--step-mm", default="", help="A,B: both eyes' pupils alternate between A and B mm "
                   "(a square wave; eyelids open) instead of the recording's")
    p.add_argument("--step-secs", type=float, default=2.0, help="length of each --step-mm plateau, s")
    p.add_argument("--clock-offset-ms", type=int, default=0,
                   help="the phone's clock runs this many ms ahead of the real time (its packets, "
                        "sender reports, blinks and Time Echo answers all say so)")
    p.add_argument("--no-time-echo", action="store_true", help="offer no Time Echo port")
    p.add_argument("--time-echo-lie", choices=["none", "ahead-1e6", "1970"], default="none",
                   help="the Time Echo answers say the phone is 1e6 s ahead, or in 1970")
    p.add_argument("--bad-sr-at", type=int, default=0,
                   help="with this gaze packet (of each connection) send one sender report --bad-sr-secs off")
    p.add_argument("--bad-sr-secs", type=float, default=1e5)
    p.add_argument("--stamp-send", action="store_true",
                   help="time each gaze packet by when it is sent (for latency measurements), "
                        "not by its place in the recording")
    args = p.parse_args()
    recs, blinks = load(args.data)
    start_unix_ns = recs[0][0] if args.time == "recording" else time.time_ns()
    start_unix_ns += args.clock_offset_ms * 1_000_000
    st = State()
    args.time_echo_port = 0
    if not args.no_time_echo:
        es = socket.socket()
        es.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        es.bind(("127.0.0.1", 0))
        es.listen(4)
        args.time_echo_port = es.getsockname()[1]
        threading.Thread(target=accept_loop, args=(es, st, lambda c: serve_time_echo(c, args)), daemon=True).start()
    hs = socket.socket()
    hs.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    hs.bind(("127.0.0.1", 0))
    hs.listen(16)
    rs = socket.socket()
    rs.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    rs.bind(("127.0.0.1", 0))
    rs.listen(16)
    rtsp_port = rs.getsockname()[1]
    threading.Thread(target=accept_loop, args=(hs, st, lambda c: serve_http(c, rtsp_port, args)), daemon=True).start()
    threading.Thread(target=accept_loop, args=(rs, st, lambda c: serve_rtsp(c, args, recs, blinks, st, start_unix_ns, rtsp_port)), daemon=True).start()
    print("READY http=%d rtsp=%d start_unix_ns=%d" % (hs.getsockname()[1], rtsp_port, start_unix_ns), flush=True)
    # Exit when the test closes stdin.
    sys.stdin.read()


if __name__ == "__main__":
    main()
