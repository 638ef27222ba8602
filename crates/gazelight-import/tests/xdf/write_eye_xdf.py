"""Stand-in for a public XDF with an eye tracker's stream (none with a
licence was found; see docs/xdf-bids.md): writes an XDF 1.0 file the way
LabRecorder lays one out (file header, stream headers, boundary chunks,
samples in chunks with explicit stamps, a clock offset every 5 s, footers)
holding the real piprkit pupil recording (shared/data/eye/piprkit-plr, MIT)
as an eye stream in one of the LSL layouts gazelight reads, plus its light
flashes (stimuli.csv) as a marker stream.

usage: python3 write_eye_xdf.py LAYOUT pupil_trace.csv stimuli.csv ROWS OUT.xdf [KEY=VALUE ...]
LAYOUT: pupil-capture-relay | gazelight-eye | neon | unknown
KEY=VALUE options (each optional):
  gaze=U,V          the relay's gaze norm_pos (origin bottom-left) on every row
                    (default: NaN, no gaze)
  blink=ROW,N       rows ROW..ROW+N are a blink as Pupil Capture relays one:
                    confidence 0, every diameter 0 (the gaze keeps its position)
  stamp=ROW,VALUE   row ROW's time stamp is VALUE (nan, inf, 1e308, ...)
  offset=K,VALUE    the K-th clock offset of the eye stream has value VALUE
"""
import csv
import math
import struct
import sys

BOUNDARY = bytes.fromhex("43A546DCCBF5410FB30ED5467383CBE4")
LSL_T0 = 3021.5  # the sender's LSL clock at the recording's time 0, s
OFFSET0 = -0.2375  # the recorder's clock minus the sender's, s
DRIFT = 4e-6  # offset drift, s per s


def varlen(n):
    if n < 256:
        return struct.pack("<BB", 1, n)
    if n < 2**32:
        return struct.pack("<BI", 4, n)
    return struct.pack("<BQ", 8, n)


def chunk(tag, content):
    return varlen(len(content) + 2) + struct.pack("<H", tag) + content


def header_xml(name, kind, channels, srate, fmt, manufacturer):
    chans = "".join(
        "<channel><label>%s</label><unit>%s</unit><type>%s</type><eye>%s</eye></channel>"
        % c
        for c in channels
    )
    return (
        '<?xml version="1.0"?>\n<info><name>%s</name><type>%s</type>'
        "<channel_count>%d</channel_count><channel_format>%s</channel_format>"
        "<source_id>%s@standin</source_id><nominal_srate>%s</nominal_srate>"
        "<version>1.100000000000000</version><created_at>%r</created_at>"
        "<uid>standin-%s</uid><session_id>default</session_id>"
        "<desc><manufacturer>%s</manufacturer><channels>%s</channels></desc></info>"
        % (name, kind, len(channels), fmt, name, srate, LSL_T0, name, manufacturer, chans)
    ).encode()


def layout(kind):
    """Channel list and a row -> values function (right, left in mm)."""
    nan = float("nan")
    if kind == "pupil-capture-relay":
        ch = [("confidence", "normalized", "Confidence", "both"),
              ("norm_pos_x", "normalized", "ScreenX", "both"),
              ("norm_pos_y", "normalized", "ScreenY", "both"),
              ("diameter0_2d", "pixels", "Diameter", "right"),
              ("diameter1_2d", "pixels", "Diameter", "left"),
              ("diameter0_3d", "mm", "Diameter", "right"),
              ("diameter1_3d", "mm", "Diameter", "left")]
        gaze = OPTS.get("gaze")
        gx, gy = (float(v) for v in gaze.split(",")) if gaze else (nan, nan)
        return "pupil_capture", "Gaze", "Pupil Labs", ch, lambda r, l: [
            1.0, gx, gy, nan, nan, r, l]
    if kind == "gazelight-eye":
        ch = [("gaze_x", "normalized", "ScreenX", "both"),
              ("gaze_y", "normalized", "ScreenY", "both"),
              ("gaze_valid", "boolean", "Validity", "both"),
              ("pupil_right_mm", "mm", "Diameter", "right"),
              ("confidence_right", "normalized", "Confidence", "right"),
              ("pupil_valid_right", "boolean", "Validity", "right"),
              ("pupil_left_mm", "mm", "Diameter", "left"),
              ("confidence_left", "normalized", "Confidence", "left"),
              ("pupil_valid_left", "boolean", "Validity", "left"),
              ("blink", "boolean", "Blink", "both")]
        return "gazelight-eye", "Gaze", "gazelight", ch, lambda r, l: [
            0.5, 0.5, 1.0, r, 1.0, float(r > 0), l, 1.0, float(l > 0), 0.0]
    if kind == "neon":
        ch = [("x", "pixels", "ScreenX", "both"),
              ("y", "pixels", "ScreenY", "both"),
              ("pupil_diameter_left", "mm", "Diameter", "left"),
              ("pupil_diameter_right", "mm", "Diameter", "right")]
        return "Neon Gaze", "Gaze", "Pupil Labs", ch, lambda r, l: [800.0, 600.0, l, r]
    ch = [("a", "", "", ""), ("b", "", "", "")]
    return "mystery", "Gaze", "", ch, lambda r, l: [r, l]


OPTS = {}


def main():
    kind, trace, stimuli, rows, out = sys.argv[1:6]
    OPTS.update(a.split("=", 1) for a in sys.argv[6:])
    blink = [int(v) for v in OPTS["blink"].split(",")] if "blink" in OPTS else None
    stamp = OPTS.get("stamp", "").split(",") if "stamp" in OPTS else None
    bad_offset = OPTS.get("offset", "").split(",") if "offset" in OPTS else None
    rows = int(rows)
    name, stype, manu, channels, values = layout(kind)
    with open(trace) as f:
        data = [(float(t), float(l or "nan"), float(r or "nan"))
                for t, l, r in list(csv.reader(f))[1 : rows + 1]]
    with open(stimuli) as f:
        flashes = [(float(s), float(e), float(i)) for _, s, e, i in list(csv.reader(f))[1:]]
    t_end = data[-1][0]
    flashes = [fl for fl in flashes if fl[1] <= t_end]
    eye, mk = 1, 2
    b = bytearray(b"XDF:")
    b += chunk(1, b'<?xml version="1.0"?><info><version>1.0</version></info>')
    b += chunk(2, struct.pack("<I", eye) + header_xml(name, stype, channels, 200, "float32", manu))
    b += chunk(2, struct.pack("<I", mk) + header_xml(
        "stimuli", "Markers", [("flash", "", "Marker", "")], 0, "string", "piprkit"))
    b += chunk(5, BOUNDARY)
    nch = len(channels)
    next_offset = 0.0
    n_offsets = 0
    for k in range(0, len(data), 100):
        part = data[k : k + 100]
        body = struct.pack("<I", eye) + varlen(len(part))
        for j, (t, l, r) in enumerate(part):
            row = k + j
            ts = LSL_T0 + t
            if stamp and int(stamp[0]) == row:
                ts = float(stamp[1])
            body += struct.pack("<Bd", 8, ts)
            v = values(r, l)
            if blink and blink[0] <= row < blink[0] + blink[1]:
                # Pupil Capture during a blink: confidence 0, diameters 0.
                v = [0.0 if ch[0] == "confidence" or ch[0].startswith("diameter") else x
                     for ch, x in zip(channels, v)]
            body += struct.pack("<%df" % nch, *v)
        b += chunk(3, body)
        t_now = part[-1][0]
        while next_offset <= t_now:
            recv = LSL_T0 + next_offset
            for sid in (eye, mk):
                value = OFFSET0 + DRIFT * next_offset
                if sid == eye and bad_offset and int(bad_offset[0]) == n_offsets:
                    value = float(bad_offset[1])
                b += chunk(4, struct.pack("<Idd", sid, recv, value))
            n_offsets += 1
            next_offset += 5.0
        if k % 2000 == 0:
            b += chunk(5, BOUNDARY)
    body = struct.pack("<I", mk) + varlen(2 * len(flashes))
    for s, e, i in flashes:
        for what, t in (("flash on %.3f" % i, s), ("flash off", e)):
            raw = what.encode()
            body += struct.pack("<Bd", 8, LSL_T0 + t) + varlen(len(raw)) + raw
    b += chunk(3, body)
    for sid, n in ((eye, len(data)), (mk, 2 * len(flashes))):
        b += chunk(6, struct.pack("<I", sid) + (
            '<?xml version="1.0"?><info><writer>standin</writer><sample_count>%d</sample_count></info>'
            % n).encode())
    with open(out, "wb") as f:
        f.write(b)


if __name__ == "__main__":
    main()
