//! Neon's scene camera model from a recording's `calibration.bin`.
//!
//! Layout (Pupil Labs' `pl-neon-recording` and their undistortion guide
//! read it as one packed NumPy record, little-endian):
//!
//! | field                             | type          | bytes |
//! |-----------------------------------|---------------|-------|
//! | `version`                         | `u1`          | 1     |
//! | `serial`                          | 6 ASCII bytes | 6     |
//! | `scene_camera_matrix`             | 3×3 `f8`      | 72    |
//! | `scene_distortion_coefficients`   | 8 `f8`        | 64    |
//! | `scene_extrinsics_affine_matrix`  | 4×4 `f8`      | 128   |
//! | `right_camera_matrix`, `…_distortion_coefficients`, `…_extrinsics_affine_matrix` | as above | 264 |
//! | `left_…` (same three)             | as above      | 264   |
//! | `crc`                             | `u4`          | 4     |
//!
//! 803 bytes in all ([`CALIBRATION_BIN_LEN`]). The `crc` is the CRC-32
//! (zlib's, IEEE polynomial) of the 799 bytes before it — not documented by
//! Pupil Labs, but it is what the demo recording's file holds, so a file
//! whose CRC disagrees has been damaged and is refused.
//!
//! The distortion coefficients are OpenCV's rational model
//! `(k1, k2, p1, p2, k3, k4, k5, k6)`; Neon's gaze pixels live in the
//! *distorted* (raw) scene image, so [`SceneCamera::project_normalized`] applies the
//! distortion as `cv2.projectPoints` does. The scene camera frame is
//! OpenCV's: x right, y down, z forward (out of the wearer's face); the
//! scene extrinsics are the identity (the eye-state geometry is already
//! given in this frame) and are not used.

use std::path::Path;

use crate::{ImportError, Position};

/// Size of a Neon `calibration.bin`, bytes.
pub const CALIBRATION_BIN_LEN: usize = 803;
/// The `version` byte this reader knows.
pub const CALIBRATION_BIN_VERSION: u8 = 1;
/// Largest undistorted radius (tan of the angle off the optical axis) ever
/// projected, whatever the distortion model allows (≈ 72°; Neon's scene
/// camera sees 103°×77°).
pub const MAX_TAN_ANGLE: f64 = 3.0;

const OFF_SERIAL: usize = 1;
const OFF_K: usize = 7;
const OFF_DIST: usize = OFF_K + 72;
const OFF_CRC: usize = CALIBRATION_BIN_LEN - 4;

/// The scene camera's intrinsics.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneCamera {
    /// The module serial (`calibration.bin`'s, as text).
    pub serial: String,
    /// `[fx, fy, cx, cy]`, px.
    pub intrinsics: [f64; 4],
    /// OpenCV rational distortion `(k1, k2, p1, p2, k3, k4, k5, k6)`.
    pub distortion: [f64; 8],
    /// Largest undistorted radius up to which the distortion model is
    /// monotonic (beyond it images fold back), capped at [`MAX_TAN_ANGLE`].
    pub max_tan_angle: f64,
}

/// CRC-32 (IEEE, reflected, as zlib's `crc32`).
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

fn f64_at(b: &[u8], off: usize) -> f64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[off..off + 8]);
    f64::from_le_bytes(a)
}

impl SceneCamera {
    /// Reads `calibration.bin`; errors name the file.
    pub fn load(path: &Path) -> Result<Self, ImportError> {
        // A little over the expected size, so a too-long file is reported as
        // one rather than as an I/O error.
        let bytes = gazelight_input::read(path, 4096).map_err(|source| ImportError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&bytes, path)
    }

    /// Parses the bytes of a `calibration.bin`; `path` names it in errors.
    pub fn parse(b: &[u8], path: &Path) -> Result<Self, ImportError> {
        let bad = |reason: String| ImportError::Structure {
            path: path.to_owned(),
            position: Position::File,
            reason,
        };
        if b.len() != CALIBRATION_BIN_LEN {
            return Err(bad(format!(
                "{} bytes; a Neon calibration.bin holds {CALIBRATION_BIN_LEN} (truncated or not \
                 a Neon calibration)",
                b.len()
            )));
        }
        if b[0] != CALIBRATION_BIN_VERSION {
            return Err(bad(format!(
                "version {} (byte 0); only version {CALIBRATION_BIN_VERSION} is known",
                b[0]
            )));
        }
        let stored =
            u32::from_le_bytes([b[OFF_CRC], b[OFF_CRC + 1], b[OFF_CRC + 2], b[OFF_CRC + 3]]);
        let computed = crc32(&b[..OFF_CRC]);
        if stored != computed {
            return Err(bad(format!(
                "CRC-32 mismatch: the file says {stored:#010x}, its bytes give {computed:#010x} \
                 (the file is damaged)"
            )));
        }
        let k: Vec<f64> = (0..9).map(|i| f64_at(b, OFF_K + 8 * i)).collect();
        let mut distortion = [0.0; 8];
        for (i, d) in distortion.iter_mut().enumerate() {
            *d = f64_at(b, OFF_DIST + 8 * i);
        }
        let [fx, s, cx, z0, fy, cy, z1, z2, one] =
            [k[0], k[1], k[2], k[3], k[4], k[5], k[6], k[7], k[8]];
        let plausible = [fx, fy, cx, cy].iter().all(|v| v.is_finite() && *v > 0.0)
            && s == 0.0
            && z0 == 0.0
            && z1 == 0.0
            && z2 == 0.0
            && one == 1.0
            && distortion.iter().all(|d| d.is_finite());
        if !plausible {
            return Err(bad(format!(
                "scene camera matrix {k:?} / distortion {distortion:?} is not a camera model \
                 (expected [[fx,0,cx],[0,fy,cy],[0,0,1]] with positive entries)"
            )));
        }
        let serial = String::from_utf8_lossy(&b[OFF_SERIAL..OFF_K])
            .trim_end_matches('\0')
            .to_owned();
        let mut cam = Self {
            serial,
            intrinsics: [fx, fy, cx, cy],
            distortion,
            max_tan_angle: MAX_TAN_ANGLE,
        };
        cam.max_tan_angle = cam.monotonic_radius();
        if cam.max_tan_angle < 0.5 {
            return Err(bad(format!(
                "scene distortion {distortion:?} folds the image back within {:.1}° of the \
                 optical axis",
                cam.max_tan_angle.atan().to_degrees()
            )));
        }
        Ok(cam)
    }

    /// The radial distortion factor at undistorted squared radius `r2`.
    fn radial(&self, r2: f64) -> Option<f64> {
        let [k1, k2, _, _, k3, k4, k5, k6] = self.distortion;
        let num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6));
        (den.abs() >= 1e-12).then(|| num / den)
    }

    /// Distorted normalised coordinates of undistorted `(x, y)`.
    fn distort(&self, x: f64, y: f64) -> Option<[f64; 2]> {
        let [_, _, p1, p2, ..] = self.distortion;
        let r2 = x * x + y * y;
        let radial = self.radial(r2)?;
        Some([
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        ])
    }

    /// The first undistorted radius at which the distorted radius
    /// `r · radial(r²)` stops growing (0.001 steps), or [`MAX_TAN_ANGLE`].
    fn monotonic_radius(&self) -> f64 {
        let mut last = 0.0;
        let steps = (MAX_TAN_ANGLE / 0.001) as usize;
        for i in 1..=steps {
            let r = i as f64 * 0.001;
            match self.radial(r * r).map(|k| r * k) {
                Some(rd) if rd > last => last = rd,
                _ => return r - 0.001,
            }
        }
        MAX_TAN_ANGLE
    }

    /// Scene-image pixel of undistorted normalised coordinates
    /// `(x/z, y/z)`; `None` beyond [`Self::max_tan_angle`].
    pub fn project_normalized(&self, n: [f64; 2]) -> Option<[f64; 2]> {
        if !(n[0].is_finite() && n[1].is_finite()) || n[0].hypot(n[1]) > self.max_tan_angle {
            return None;
        }
        let [xd, yd] = self.distort(n[0], n[1])?;
        let [fx, fy, cx, cy] = self.intrinsics;
        Some([fx * xd + cx, fy * yd + cy])
    }

    /// Scene-image pixel of the direction `d` (scene camera frame, any
    /// length): its vanishing point. `None` for a direction not in front of
    /// the camera or beyond [`Self::max_tan_angle`].
    pub fn project_direction(&self, d: [f64; 3]) -> Option<[f64; 2]> {
        if !(d[2].is_finite() && d[2] > 1e-9) {
            return None;
        }
        self.project_normalized([d[0] / d[2], d[1] / d[2]])
    }

    /// Undistorted normalised coordinates `(x/z, y/z)` of a scene-image
    /// pixel (OpenCV's fixed-point iteration); `None` when it does not
    /// converge to within 0.01 px.
    pub fn unproject(&self, px: [f64; 2]) -> Option<[f64; 2]> {
        let [fx, fy, cx, cy] = self.intrinsics;
        let [k1, k2, p1, p2, k3, k4, k5, k6] = self.distortion;
        let xd = (px[0] - cx) / fx;
        let yd = (px[1] - cy) / fy;
        if !(xd.is_finite() && yd.is_finite()) {
            return None;
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..100 {
            let r2 = x * x + y * y;
            let icdist =
                (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))) / (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)));
            let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            x = (xd - dx) * icdist;
            y = (yd - dy) * icdist;
            if !(x.is_finite() && y.is_finite()) {
                return None;
            }
        }
        let back = self.project_normalized([x, y])?;
        ((back[0] - px[0]).hypot(back[1] - px[1]) < 0.01).then_some([x, y])
    }

    /// Unit ray of a scene-image pixel.
    pub fn ray(&self, px: [f64; 2]) -> Option<[f64; 3]> {
        let [x, y] = self.unproject(px)?;
        let n = (x * x + y * y + 1.0).sqrt();
        Some([x / n, y / n, 1.0 / n])
    }
}

/// The angle between the rays of two scene-image pixels, degrees.
pub fn angle_deg(cam: &SceneCamera, a: [f64; 2], b: [f64; 2]) -> Option<f64> {
    let (ra, rb) = (cam.ray(a)?, cam.ray(b)?);
    let dot = ra[0] * rb[0] + ra[1] * rb[1] + ra[2] * rb[2];
    Some(dot.clamp(-1.0, 1.0).acos().to_degrees())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32_matches_zlib() {
        // zlib.crc32(b"123456789") == 0xCBF43926 (the standard check value).
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }
}
