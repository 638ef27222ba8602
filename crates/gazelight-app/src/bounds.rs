//! Bounds on the durations, rates and counts a user gives on the command
//! line or in a configuration file, and on the luminance a scene reaches
//! after scaling. Every check names the flag and the valid range, so a
//! value out of range is refused with a sentence instead of a panic deep in
//! a thread (`Duration::from_secs_f64(1e308)`), an allocation abort
//! (`--frames 1000000000`) or silently black frames (`--luminance-scale
//! 1e308`). The limits are listed in `docs/robustness.md`.

use std::time::Duration;

use gazelight_vision::scene::{LuminanceScale, Scene};

/// A number out of its range: the sentence names the flag (or setting),
/// the value and the valid range.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct BoundsError(pub String);

/// The result of a bounds check.
pub type Result<T> = std::result::Result<T, BoundsError>;

macro_rules! refuse {
    ($($arg:tt)*) => {
        return Err(BoundsError(format!($($arg)*)))
    };
}

/// Lowest display / render rate accepted, Hz (one frame every 1000 s).
pub const MIN_FPS: f64 = 0.001;
/// Highest display / render rate accepted, Hz.
pub const MAX_FPS: f64 = 1000.0;
/// Longest duration accepted for `--secs` and the other `*-secs` flags:
/// 30 days. A longer session runs without `--secs` until a signal ends it.
pub const MAX_SECS: f64 = 30.0 * 86_400.0;
/// Most frames `render` / `replay` produce in one invocation (9.3 h at
/// 30 Hz). The per-frame timeline is kept for the plot, so memory grows
/// with the frame count (~200 bytes a frame); this bounds it to ~200 MB.
pub const MAX_FRAMES: usize = 1_000_000;
/// Smallest side of a rendered image, pixels.
pub const MIN_SIDE_PX: usize = 8;
/// Largest side of a rendered image, pixels (an 8192×8192 RGBA f32 frame
/// is 1 GiB; the pipeline holds several).
pub const MAX_SIDE_PX: usize = 8192;
/// Longest time a waiting loop sleeps before it looks at the shutdown flag
/// again: a signal or `--secs` ends a run within this (plus one frame).
pub const SHUTDOWN_POLL: Duration = Duration::from_millis(50);
/// The luminance bounds live in the library every front end links
/// (`gazelight_vision::scene`): `--luminance-scale`, `glare
/// --luminance-factor`, Python's `luminance_scale` and the OpenXR layer's
/// config check the same numbers.
pub use gazelight_vision::scene::{MAX_SCALE_FACTOR, MAX_SCENE_CD_M2, MAX_SCENE_KEY_CD_M2};
/// Brightest scaled scene value that passes without a warning, cd/m²: ten
/// times the sun's disc (≈ 1.6·10⁹ cd/m²). Brighter is physically
/// implausible and almost always a wrong luminance scale.
pub const PLAUSIBLE_SCENE_CD_M2: f64 = 1.6e10;

/// A number as a user would write it: `1e308`, `1e-300`, `-5`, `2.5`
/// (plain for everyday magnitudes, exponent form for extreme ones, so an
/// error message never prints 300 digits).
pub struct Num(pub f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = self.0.abs();
        if a.is_finite() && a != 0.0 && !(1e-4..1e9).contains(&a) {
            write!(f, "{:e}", self.0)
        } else {
            write!(f, "{}", self.0)
        }
    }
}

/// A display / render rate, Hz: `MIN_FPS ≤ fps ≤ MAX_FPS`.
pub fn fps(flag: &str, fps: f64) -> Result<f64> {
    if fps.is_finite() && (MIN_FPS..=MAX_FPS).contains(&fps) {
        Ok(fps)
    } else {
        refuse!(
            "{flag} {}: expected a rate {MIN_FPS} ≤ Hz ≤ {MAX_FPS}",
            Num(fps)
        )
    }
}

/// A positive duration, seconds: `0 < secs ≤ MAX_SECS`.
pub fn secs(flag: &str, secs: f64) -> Result<Duration> {
    if secs.is_finite() && secs > 0.0 && secs <= MAX_SECS {
        // In range, so the conversion cannot fail; keep it fallible anyway.
        Duration::try_from_secs_f64(secs)
            .map_err(|e| BoundsError(format!("{flag} {}: {e}", Num(secs))))
    } else {
        refuse!(
            "{flag} {}: expected a duration 0 < s ≤ {MAX_SECS} (30 days)",
            Num(secs)
        )
    }
}

/// A duration that may be 0, seconds: `0 ≤ secs ≤ MAX_SECS`.
pub fn secs_or_zero(flag: &str, secs: f64) -> Result<Duration> {
    if secs == 0.0 {
        return Ok(Duration::ZERO);
    }
    if secs.is_finite() && secs > 0.0 && secs <= MAX_SECS {
        Ok(Duration::try_from_secs_f64(secs).unwrap_or(Duration::ZERO))
    } else {
        refuse!(
            "{flag} {}: expected a duration 0 ≤ s ≤ {MAX_SECS} (30 days)",
            Num(secs)
        )
    }
}

/// A frame count: `1 ≤ frames ≤ MAX_FRAMES`. `what` says where the count
/// came from (`--frames 0`, or the recording's span × `--fps`).
pub fn frames(what: &str, frames: usize) -> Result<usize> {
    if frames == 0 {
        refuse!("{what}: nothing to render (0 frames)");
    }
    if frames > MAX_FRAMES {
        refuse!(
            "{what}: {frames} frames is more than the {MAX_FRAMES} one invocation renders; \
             render a part (--frames, or replay --from-secs/--secs) or lower --fps"
        );
    }
    Ok(frames)
}

/// The luminance scale a user asked for, with the flag it came from in the
/// error: factor `0 < f ≤ MAX_SCALE_FACTOR`, key `0 < k ≤ MAX_SCENE_KEY_CD_M2`.
pub fn luminance_scale(scale: LuminanceScale) -> Result<LuminanceScale> {
    match scale {
        LuminanceScale::CdM2PerUnit { factor } => {
            if !(factor.is_finite() && factor > 0.0 && factor <= MAX_SCALE_FACTOR) {
                refuse!(
                    "--luminance-scale {}: expected 0 < cd/m² per unit ≤ {MAX_SCALE_FACTOR:e}",
                    Num(factor)
                );
            }
        }
        LuminanceScale::MedianKey { key_cd_m2 } => {
            if !(key_cd_m2.is_finite() && key_cd_m2 > 0.0 && key_cd_m2 <= MAX_SCENE_KEY_CD_M2) {
                refuse!(
                    "--scene-key-cd-m2 {}: expected 0 < median cd/m² ≤ {MAX_SCENE_KEY_CD_M2:e} \
                     (the sun's disc is ≈ 1.6e9 cd/m²)",
                    Num(key_cd_m2)
                );
            }
        }
    }
    Ok(scale)
}

/// What [`scene_luminance`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRange {
    /// Brightest component after scaling, cd/m².
    pub max_cd_m2: f64,
    /// Components that are not finite after scaling (the scale overflowed
    /// single precision).
    pub overflowed: usize,
    /// The warning a front end shows (once) for an implausibly bright
    /// scene: brighter than [`PLAUSIBLE_SCENE_CD_M2`] after scaling.
    pub warning: Option<String>,
}

/// Measures the scaled scene's range.
pub fn scene_range(scene: &Scene) -> SceneRange {
    let (max_cd_m2, overflowed) = scene.luminance_range();
    let warning = (max_cd_m2 > PLAUSIBLE_SCENE_CD_M2).then(|| {
        format!(
            "scene {}: the brightest value is {max_cd_m2:e} cd/m² after scaling by {:e} cd/m² \
             per unit — brighter than {PLAUSIBLE_SCENE_CD_M2:e} (ten suns); the luminance \
             scale is probably wrong",
            scene.name, scene.cd_m2_per_unit
        )
    });
    SceneRange {
        max_cd_m2,
        overflowed,
        warning,
    }
}

/// Refuses a scaled scene that overflows (or comes so close to `f32::MAX`
/// that the pipeline's sums would); an implausibly bright one passes with
/// [`SceneRange::warning`] set, for the front end to show.
pub fn scene_luminance(scene: &Scene) -> Result<SceneRange> {
    let range = scene_range(scene);
    let total = scene.image.pixels.len() * 3;
    let scale = scene.cd_m2_per_unit;
    if range.overflowed > 0 || range.max_cd_m2 > MAX_SCENE_CD_M2 {
        refuse!(
            "scene {}: after scaling by {scale:e} cd/m² per unit, {} of {total} values overflow \
             single precision and the brightest is {:e} cd/m² (limit {MAX_SCENE_CD_M2:e}): the \
             frames would be black. Lower --luminance-scale / --scene-key-cd-m2 (the sun's disc \
             is ≈ 1.6e9 cd/m²)",
            scene.name,
            range.overflowed,
            range.max_cd_m2
        );
    }
    Ok(range)
}

/// An image size, pixels: each side `MIN_SIDE_PX..=MAX_SIDE_PX`. `what`
/// names where it came from (`--size 4x4`, `size=(4, 4)`).
pub fn size(what: &str, width: usize, height: usize) -> Result<(usize, usize)> {
    let side = MIN_SIDE_PX..=MAX_SIDE_PX;
    if !side.contains(&width) || !side.contains(&height) {
        refuse!("{what}: each side must be {MIN_SIDE_PX}..={MAX_SIDE_PX} pixels");
    }
    Ok((width, height))
}

/// Parses `WIDTHxHEIGHT` (each side `MIN_SIDE_PX..=MAX_SIDE_PX`).
pub fn parse_size(s: &str) -> Result<(usize, usize)> {
    let Some((w, h)) = s.split_once(['x', 'X']) else {
        refuse!("`{s}`: expected WIDTHxHEIGHT, e.g. 720x800");
    };
    let Ok(w) = w.trim().parse::<usize>() else {
        refuse!("`{s}`: width is not a number");
    };
    let Ok(h) = h.trim().parse::<usize>() else {
        refuse!("`{s}`: height is not a number");
    };
    size(&format!("`{s}`"), w, h)
}

/// A time into a recording to start from, seconds: finite and `≥ 0`.
pub fn from_secs(flag: &str, secs: f64) -> Result<f64> {
    if secs.is_finite() && (0.0..=MAX_SECS).contains(&secs) {
        Ok(secs)
    } else {
        refuse!(
            "{flag} {}: expected a time 0 ≤ s ≤ {MAX_SECS} (30 days)",
            Num(secs)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_and_rates_are_bounded() {
        assert!(fps("--fps", 1e-300).is_err());
        assert!(fps("--fps", 0.0).is_err());
        assert!(fps("--fps", f64::NAN).is_err());
        assert!(fps("--fps", 1e4).is_err());
        assert_eq!(fps("--fps", 0.001).unwrap(), 0.001);
        let e = secs("--secs", 1e308).unwrap_err().to_string();
        assert!(e.contains("--secs") && e.contains("2592000"), "{e}");
        assert!(secs("--secs", -1.0).is_err());
        assert!(secs("--secs", 0.0).is_err());
        assert_eq!(secs("--secs", 2.5).unwrap(), Duration::from_millis(2500));
        assert_eq!(secs_or_zero("--x", 0.0).unwrap(), Duration::ZERO);
        assert!(secs_or_zero("--x", -0.5).is_err());
        assert!(frames("--frames 0", 0).is_err());
        let e = frames("--frames 1000000000", 1_000_000_000)
            .unwrap_err()
            .to_string();
        assert!(e.contains("1000000"), "{e}");
        assert_eq!(frames("--frames", 10).unwrap(), 10);
        assert!(from_secs("--from-secs", -1.0).is_err());
        assert!(from_secs("--from-secs", f64::INFINITY).is_err());
        assert_eq!(from_secs("--from-secs", 0.0).unwrap(), 0.0);
    }

    #[test]
    fn sizes_are_bounded() {
        assert_eq!(parse_size("720x800").unwrap(), (720, 800));
        assert_eq!(parse_size("8X8192").unwrap(), (8, 8192));
        for bad in ["7x8", "8x8193", "0x0", "720", "ax8", "16384x16384"] {
            let e = parse_size(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "{bad}: {e}");
        }
        assert!(
            size("size=(1, 1)", 1, 1)
                .unwrap_err()
                .0
                .contains("8..=8192")
        );
    }

    #[test]
    fn luminance_scale_flags_are_bounded() {
        let e = luminance_scale(LuminanceScale::CdM2PerUnit { factor: 1e308 })
            .unwrap_err()
            .to_string();
        assert!(e.contains("--luminance-scale 1e308"), "{e}");
        let e = luminance_scale(LuminanceScale::MedianKey { key_cd_m2: 1e308 })
            .unwrap_err()
            .to_string();
        assert!(e.contains("--scene-key-cd-m2"), "{e}");
        assert!(luminance_scale(LuminanceScale::CdM2PerUnit { factor: 100.0 }).is_ok());
        assert!(luminance_scale(LuminanceScale::MedianKey { key_cd_m2: 20.0 }).is_ok());
    }
}
