"""Makes a long Pupil Core recording for the read benchmark: a short one
recorded by `gazelight record` from the Pupil peer, tiled in time.

    python3 make_long_pupil.py SHORT_DIR OUT_DIR HOURS

Every datum of SHORT_DIR's .pldata files is repeated with its timestamp
(the payload's `timestamp` and the _timestamps.npy entry) shifted by whole
copies of the recording's span, until OUT_DIR covers HOURS. Needs msgpack
and numpy.
"""

import json
import shutil
import sys
from pathlib import Path

import msgpack
import numpy as np


def main():
    src, out, hours = Path(sys.argv[1]), Path(sys.argv[2]), float(sys.argv[3])
    out.mkdir(parents=True, exist_ok=True)
    streams = sorted(p.stem for p in src.glob("*.pldata"))
    ts = {s: np.load(src / f"{s}_timestamps.npy") for s in streams}
    t0 = min(float(t.min()) for t in ts.values() if len(t))
    t1 = max(float(t.max()) for t in ts.values() if len(t))
    span = (t1 - t0) + 0.005
    copies = int(np.ceil(hours * 3600.0 / span))
    for s in streams:
        records = []
        with open(src / f"{s}.pldata", "rb") as f:
            for topic, payload in msgpack.Unpacker(f, raw=False, use_list=True):
                records.append((topic, msgpack.unpackb(payload, raw=False, strict_map_key=False)))
        all_ts = []
        with open(out / f"{s}.pldata", "wb") as f:
            for k in range(copies):
                shift = k * span
                for topic, d in records:
                    d = dict(d)
                    d["timestamp"] = d["timestamp"] + shift
                    f.write(msgpack.packb([topic, msgpack.packb(d, use_bin_type=True)], use_bin_type=True))
                all_ts.append(ts[s] + shift)
        np.save(out / f"{s}_timestamps.npy", np.concatenate(all_ts) if all_ts else ts[s])
    info = json.loads((src / "info.player.json").read_text())
    info["duration_s"] = copies * span
    (out / "info.player.json").write_text(json.dumps(info))
    print(f"{copies} copies of {span:.3f} s -> {copies * span / 3600:.2f} h in {out}")


if __name__ == "__main__":
    main()
