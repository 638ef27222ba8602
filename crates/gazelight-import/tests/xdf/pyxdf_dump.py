"""Dumps what pyxdf's load_xdf (default options) reads from an XDF file as
JSON, for crates/gazelight-import/tests/xdf.rs to compare against.

usage: python3 pyxdf_dump.py FILE.xdf > out.json
"""
import json
import math
import sys

import pyxdf


def num(v):
    v = float(v)
    return None if math.isnan(v) else v


def main():
    streams, _ = pyxdf.load_xdf(sys.argv[1])
    out = []
    for s in sorted(streams, key=lambda s: s["info"]["stream_id"]):
        info = s["info"]
        fmt = info["channel_format"][0]
        series = s["time_series"]
        if fmt == "string":
            values = [list(row) for row in series]
        else:
            values = [[num(v) for v in row] for row in series]
        out.append(
            {
                "id": int(info["stream_id"]),
                "name": info["name"][0],
                "type": info["type"][0] if info["type"] else "",
                "format": fmt,
                "channel_count": int(info["channel_count"][0]),
                "time_stamps": [float(t) for t in s["time_stamps"]],
                "values": values,
                "clock_offsets": len(s["clock_times"]),
            }
        )
    json.dump({"pyxdf": pyxdf.__version__, "streams": out}, sys.stdout)


if __name__ == "__main__":
    main()
