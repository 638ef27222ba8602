"""Compares gazelight's interpolated pupil with MNE-Python's.

Usage: compare_blinks.py RECORDING.asc OURS.csv BUFFER_S

OURS.csv: eye (0 right, 1 left), t_ms (the ASC's own time stamp),
interpolated (NaN where gazelight leaves the sample empty).

MNE reads the ASC with its blink annotations (EyeLink's SBLINK/EBLINK)
and interpolates each blink with `interpolate_blinks(buffer=BUFFER_S)`,
the margins of the guidelines. Prints one JSON line per eye: samples
compared, the pupil's range, and how many agree within 2 % of it.
"""

import json
import sys

import numpy as np
import mne

asc, ours_csv, buffer_s = sys.argv[1], sys.argv[2], float(sys.argv[3])

# The first sample line's time stamp: MNE's times start there.
first_ts = None
with open(asc, encoding="latin-1") as f:
    for line in f:
        head = line.split("\t", 1)[0].strip()
        if head.isdigit():
            first_ts = int(head)
            break
if first_ts is None:
    sys.exit("no sample line in " + asc)

raw = mne.io.read_raw_eyelink(asc, create_annotations=["blinks"], verbose="error")
sfreq = raw.info["sfreq"]
mne.set_log_level("error")
mne.preprocessing.eyetracking.interpolate_blinks(raw, buffer=(buffer_s, buffer_s))

ours = np.loadtxt(ours_csv, delimiter=",", skiprows=1)
for eye, name in ((0, "pupil_right"), (1, "pupil_left")):
    theirs = raw.get_data(picks=[name])[0]
    rows = ours[ours[:, 0] == eye]
    idx = np.rint((rows[:, 1] - first_ts) * sfreq / 1000.0).astype(np.int64)
    ok = (idx >= 0) & (idx < len(theirs))
    idx, mine = idx[ok], rows[ok, 2]
    ref = theirs[idx]
    # Samples MNE has (not an acquisition gap); its blink samples are
    # interpolated, its other lost samples stay 0.
    have = np.isfinite(ref) & (ref > 0)
    span = np.nanmax(ref[have]) - np.nanmin(ref[have])
    diff = np.abs(mine[have] - ref[have])
    agree = np.isfinite(diff) & (diff <= 0.02 * span)
    print(json.dumps({
        "eye": eye,
        "compared": int(have.sum()),
        "range": float(span),
        "agree": int(agree.sum()),
        "ours_empty": int((~np.isfinite(mine[have])).sum()),
        "max_diff": float(np.nanmax(diff)),
    }))
