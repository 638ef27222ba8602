#!/usr/bin/env python3
"""Independent reference for the Neon importer's per-eye gaze.

Written from the published conventions, not from the Rust code:

- calibration.bin: the NumPy record Pupil Labs' pl-neon-recording and their
  "undistort gaze" guide use (version u1, serial 6a, scene_camera_matrix
  (3,3)d, scene_distortion_coefficients 8d, ... , crc u4), read here with
  numpy.frombuffer;
- eye_state: eyeball centre (mm) and optical axis (unit vector) in the scene
  camera frame (OpenCV: x right, y down, z forward);
- projection: OpenCV's rational model as documented for cv2.projectPoints
  (x' = X/Z, r^2 = x'^2 + y'^2,
   x'' = x' (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
         + 2 p1 x' y' + p2 (r^2 + 2 x'^2), likewise y'', u = fx x'' + cx);
  the optical axis's vanishing point, i.e. the direction alone;
- gaze_uv = pixel / (1600, 1200), as the importer's binocular gaze;
- kappa correction: per eye, the exact median over rows with the eye open
  (eyelid_aperture >= 3 mm) and a binocular gaze record at the same
  timestamp of (undistorted binocular gaze - x'/y' of the optical axis),
  added to the axis's x'/y' before distortion.

Writes reference.csv (selected rows) and kappa.csv next to this script.
Run: python3 reference.py [recording dir]
"""
import csv
import os
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
# As the Rust tests find it: GAZELIGHT_DATA_DIR, else shared/data beside the workspace root.
DATA = Path(os.environ.get("GAZELIGHT_DATA_DIR") or HERE.parents[3].parent / "shared/data")
REC = Path(sys.argv[1]) if len(sys.argv) > 1 else DATA / "eye/neon-demo"
ROWS = [0, 1, 250, 500, 777, 1000, 1234, 1500, 1787]

calib_dtype = np.dtype([
    ("version", "u1"), ("serial", "S6"),
    ("scene_camera_matrix", "<f8", (3, 3)), ("scene_distortion_coefficients", "<f8", (8,)),
    ("scene_extrinsics_affine_matrix", "<f8", (4, 4)),
    ("right_camera_matrix", "<f8", (3, 3)), ("right_distortion_coefficients", "<f8", (8,)),
    ("right_extrinsics_affine_matrix", "<f8", (4, 4)),
    ("left_camera_matrix", "<f8", (3, 3)), ("left_distortion_coefficients", "<f8", (8,)),
    ("left_extrinsics_affine_matrix", "<f8", (4, 4)),
    ("crc", "<u4"),
])
calib = np.frombuffer((REC / "calibration.bin").read_bytes(), calib_dtype)[0]
K = calib["scene_camera_matrix"]
k1, k2, p1, p2, k3, k4, k5, k6 = calib["scene_distortion_coefficients"]

names = [line.split('"')[1] for line in (REC / "eye_state.dtype").read_text().splitlines() if "(" in line]
eye = np.fromfile(REC / "eye_state ps1.raw", np.dtype([(n, "<f4") for n in names]))
eye_t = np.fromfile(REC / "eye_state ps1.time", "<u8")
gaze = np.fromfile(REC / "gaze ps1.raw", np.dtype([("x", "<f4"), ("y", "<f4")]))
gaze_t = np.fromfile(REC / "gaze ps1.time", "<u8")


def distort(x, y):
    r2 = x * x + y * y
    radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]


def undistort(u, v):
    xd = (u - K[0, 2]) / K[0, 0]
    yd = (v - K[1, 2]) / K[1, 1]
    x, y = xd.copy(), yd.copy()
    for _ in range(100):
        r2 = x * x + y * y
        inv = (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3) / (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3)
        x = (xd - (2 * p1 * x * y + p2 * (r2 + 2 * x * x))) * inv
        y = (yd - (p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)) * inv
    bu, bv = distort(x, y)
    ok = np.hypot(bu - u, bv - v) < 0.01
    return np.where(ok, x, np.nan), np.where(ok, y, np.nan)


# Binocular gaze at each eye_state row's time (the demo's streams share timestamps).
idx = np.searchsorted(gaze_t, eye_t)
idx = np.clip(idx, 0, len(gaze_t) - 1)
paired = np.abs(gaze_t[idx].astype(np.int64) - eye_t.astype(np.int64)) <= 2_500_000
bx, by = undistort(gaze["x"][idx].astype(float), gaze["y"][idx].astype(float))

out = {}
kappa = {}
for side in ["right", "left"]:
    a = np.stack([eye[f"optical_axis_{side}_{c}"] for c in "xyz"], 1).astype(float)
    c = np.stack([eye[f"eyeball_center_{side}_{c}"] for c in "xyz"], 1).astype(float)
    valid = (np.isfinite(a).all(1) & np.isfinite(c).all(1) & (np.linalg.norm(c, axis=1) > 0)
             & (np.abs(np.linalg.norm(a, axis=1) - 1) < 0.1) & (a[:, 2] > 0))
    ax, ay = a[:, 0] / a[:, 2], a[:, 1] / a[:, 2]
    use = valid & paired & (eye[f"eyelid_aperture_{side}_mm"] >= 3.0) & np.isfinite(bx)
    ox, oy = np.median(bx[use] - ax[use]), np.median(by[use] - ay[use])
    kappa[side] = (ox, oy, int(use.sum()))
    u0, v0 = distort(ax, ay)
    u1, v1 = distort(ax + ox, ay + oy)
    out[side] = (valid, u0 / 1600, v0 / 1200, u1 / 1600, v1 / 1200)

with open(HERE / "reference.csv", "w", newline="") as f:
    w = csv.writer(f)
    w.writerow(["row", "t_ns", "eye", "optical_u", "optical_v", "corrected_u", "corrected_v"])
    for r in ROWS:
        for side in ["right", "left"]:
            valid, u0, v0, u1, v1 = out[side]
            vals = [f"{x[r]:.6f}" if valid[r] else "" for x in (u0, v0, u1, v1)]
            w.writerow([r, int(eye_t[r]), side] + vals)
with open(HERE / "kappa.csv", "w", newline="") as f:
    w = csv.writer(f)
    w.writerow(["eye", "offset_x", "offset_y", "rows"])
    for side in ["right", "left"]:
        ox, oy, n = kappa[side]
        w.writerow([side, f"{ox:.6f}", f"{oy:.6f}", n])
print((HERE / "reference.csv").read_text())
print((HERE / "kappa.csv").read_text())
