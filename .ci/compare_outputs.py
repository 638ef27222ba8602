"""Compares two gazelight output directories file by file (.ci/compare-outputs).

Every file must exist on both sides and be byte-identical, except:
- timeline.csv: the stage timing columns (`*_ms`, `*_ms_left`, `*_ms_right`) are left out, every other
  column must be equal text;
- session.json: wall-clock and build fields (timings, version, git commit,
  start time, output paths) are left out, the rest must be equal.
Prints each difference and exits 1 if there is any.
"""

import csv
import json
import sys
from pathlib import Path

# session.json keys that differ between two runs of one binary (the wall
# clock) or between two builds (the version), and the outputs' own paths.
VOLATILE_KEYS = {
    "version",
    "git",
    "commit",
    "started",
    "started_utc",
    "finished_utc",
    "wall_secs",
    "elapsed_secs",
    "timings",
    "timing",
    "frame_ms",
    "out",
    "out_dir",
    "argv",
    "command_line",
}


def strip(value):
    if isinstance(value, dict):
        return {
            k: strip(v)
            for k, v in value.items()
            if k not in VOLATILE_KEYS and not k.endswith("_ms")
        }
    if isinstance(value, list):
        return [strip(v) for v in value]
    return value


def is_timing(name):
    """A stage timing column: `glare_ms`, or per view `glare_ms_left`."""
    for suffix in ("", "_left", "_right"):
        if suffix and not name.endswith(suffix):
            continue
        if name[: len(name) - len(suffix)].endswith("_ms"):
            return True
    return False


def timeline(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return [], []
    keep = [i for i, name in enumerate(rows[0]) if not is_timing(name)]
    return [rows[0][i] for i in keep], [[r[i] if i < len(r) else None for i in keep] for r in rows[1:]]


def main(a, b):
    a, b = Path(a), Path(b)
    files_a = {p.relative_to(a) for p in a.rglob("*") if p.is_file()}
    files_b = {p.relative_to(b) for p in b.rglob("*") if p.is_file()}
    bad = []
    for f in sorted(files_a ^ files_b):
        bad.append(f"{f}: only in {'old' if f in files_a else 'new'}")
    for f in sorted(files_a & files_b):
        pa, pb = a / f, b / f
        if f.name.endswith(".log"):
            continue
        if f.name == "timeline.csv":
            ha, ra = timeline(pa)
            hb, rb = timeline(pb)
            if ha != hb:
                bad.append(f"{f}: columns differ: {sorted(set(ha) ^ set(hb))}")
            elif len(ra) != len(rb):
                bad.append(f"{f}: {len(ra)} rows against {len(rb)}")
            else:
                for k, (x, y) in enumerate(zip(ra, rb)):
                    if x != y:
                        cols = [ha[i] for i in range(len(x)) if x[i] != y[i]]
                        bad.append(f"{f}: row {k + 1} differs in {cols}")
                        break
        elif f.name == "session.json":
            ja, jb = strip(json.loads(pa.read_text())), strip(json.loads(pb.read_text()))
            if ja != jb:
                keys = sorted(k for k in set(ja) | set(jb) if ja.get(k) != jb.get(k))
                bad.append(f"{f}: differs in {keys}")
        elif pa.read_bytes() != pb.read_bytes():
            bad.append(f"{f}: bytes differ")
    for line in bad:
        print(f"  {line}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
