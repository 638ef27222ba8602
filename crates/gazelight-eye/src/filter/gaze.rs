//! Gaze cleaning: outlier rejection, then One Euro smoothing.
//!
//! **Outliers.** A gaze sample is rejected when its confidence is below the
//! gate, it is not finite, it lies further than `margin_uv` outside the
//! image, or it moved from the last accepted sample faster than
//! `jump_tolerance_uv + max_speed_uv_per_s · Δt`. The speed bound: saccade
//! peak velocities saturate around 500–700 °/s (Bahill, Clark & Stark 1975,
//! the "main sequence"); over a ~100° wide scene camera or HMD field that is
//! ≈ 7 image widths per second, so the default 10 uv/s only removes
//! single-frame spikes, never a real saccade. As in the pupil gate, the
//! allowance grows with Δt, so the filter cannot lock out.
//!
//! **One Euro filter** (Casiez, Roussel & Vogel 2012, "1€ Filter: A Simple
//! Speed-based Low-pass Filter for Noisy Input in Interactive Systems",
//! CHI '12): an exponential smoother whose cutoff rises with the filtered
//! speed, `f_c = min_cutoff + β·|ẋ|`, with `α = 1 / (1 + τ/T_e)`,
//! `τ = 1/(2π f_c)`. Slow fixational jitter is smoothed hard (1 Hz), a
//! saccade (several uv/s) opens the cutoff to tens of Hz so the lag stays a
//! few ms.

use crate::setting::SettingError;
use serde::{Deserialize, Serialize};

/// One Euro filter parameters (Casiez et al. 2012).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OneEuroConfig {
    /// Minimum cutoff frequency (Hz). Default 1.0.
    pub min_cutoff_hz: f32,
    /// Speed coefficient β (Hz per uv/s). Default 5.0.
    pub beta: f32,
    /// Cutoff of the derivative's low-pass (Hz). Default 1.0 (the paper's
    /// recommendation).
    pub d_cutoff_hz: f32,
}

impl Default for OneEuroConfig {
    fn default() -> Self {
        Self {
            min_cutoff_hz: 1.0,
            beta: 5.0,
            d_cutoff_hz: 1.0,
        }
    }
}

/// `α = 1 / (1 + τ/T_e)`, `τ = 1/(2π f_c)` (Casiez et al. 2012).
#[inline]
fn smoothing_alpha(dt_secs: f32, cutoff_hz: f32) -> f32 {
    let tau = 1.0 / (2.0 * std::f32::consts::PI * cutoff_hz);
    1.0 / (1.0 + tau / dt_secs)
}

/// A scalar One Euro filter.
#[derive(Clone, Copy, Debug)]
pub struct OneEuro {
    cfg: OneEuroConfig,
    prev: Option<(f64, f32)>,
    dx_prev: f32,
}

impl OneEuro {
    pub fn new(cfg: OneEuroConfig) -> Self {
        Self {
            cfg,
            prev: None,
            dx_prev: 0.0,
        }
    }

    /// Filters `x` at time `t_secs` (Δt ≤ 0 returns the previous output).
    pub fn filter(&mut self, t_secs: f64, x: f32) -> f32 {
        let Some((t0, x_prev)) = self.prev else {
            self.prev = Some((t_secs, x));
            self.dx_prev = 0.0;
            return x;
        };
        let dt = (t_secs - t0) as f32;
        if dt <= 0.0 || !dt.is_finite() {
            return x_prev;
        }
        let dx = (x - x_prev) / dt;
        let a_d = smoothing_alpha(dt, self.cfg.d_cutoff_hz);
        let dx_hat = a_d * dx + (1.0 - a_d) * self.dx_prev;
        let cutoff = self.cfg.min_cutoff_hz + self.cfg.beta * dx_hat.abs();
        let a = smoothing_alpha(dt, cutoff);
        let x_hat = a * x + (1.0 - a) * x_prev;
        self.prev = Some((t_secs, x_hat));
        self.dx_prev = dx_hat;
        x_hat
    }

    /// Forgets the history.
    pub fn reset(&mut self) {
        self.prev = None;
        self.dx_prev = 0.0;
    }
}

/// Gaze filter configuration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GazeConfig {
    /// Minimum confidence of a usable gaze sample. Default 0.6.
    pub min_confidence: f32,
    /// How far outside the [0, 1] image a gaze may lie (uv). Default 0.25.
    pub margin_uv: f32,
    /// Fastest plausible gaze speed (image widths per second). Default 10.
    pub max_speed_uv_per_s: f32,
    /// Noise tolerance of the speed check (uv). Default 0.02.
    pub jump_tolerance_uv: f32,
    /// After a gap this long (s) without accepted gaze the smoother
    /// restarts instead of gliding from the old position. Default 0.25.
    pub reset_after_s: f64,
    /// One Euro smoothing.
    pub one_euro: OneEuroConfig,
}

impl Default for GazeConfig {
    fn default() -> Self {
        Self {
            min_confidence: super::confidence::DEFAULT_MIN_CONFIDENCE,
            margin_uv: 0.25,
            max_speed_uv_per_s: 10.0,
            jump_tolerance_uv: 0.02,
            reset_after_s: 0.25,
            one_euro: OneEuroConfig::default(),
        }
    }
}

impl GazeConfig {
    /// Checks the values; names the field.
    pub fn validate(&self) -> Result<(), SettingError> {
        let pos = |v: f32, name: &str| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(SettingError::new(
                    format!("gaze.{name}"),
                    format!("must be > 0, got {v}"),
                ))
            }
        };
        if !(0.0..=1.0).contains(&self.min_confidence) {
            return Err(SettingError::new(
                "gaze.min_confidence",
                format!("must be within 0..=1, got {}", self.min_confidence),
            ));
        }
        pos(self.margin_uv, "margin_uv")?;
        pos(self.max_speed_uv_per_s, "max_speed_uv_per_s")?;
        pos(self.jump_tolerance_uv, "jump_tolerance_uv")?;
        pos(self.one_euro.min_cutoff_hz, "one_euro.min_cutoff_hz")?;
        pos(self.one_euro.d_cutoff_hz, "one_euro.d_cutoff_hz")?;
        if !(self.one_euro.beta.is_finite() && self.one_euro.beta >= 0.0) {
            return Err(SettingError::new(
                "gaze.one_euro.beta",
                format!("must be ≥ 0, got {}", self.one_euro.beta),
            ));
        }
        if !(self.reset_after_s.is_finite() && self.reset_after_s > 0.0) {
            return Err(SettingError::new(
                "gaze.reset_after_s",
                format!("must be > 0, got {}", self.reset_after_s),
            ));
        }
        Ok(())
    }
}

/// Outlier rejection + One Euro smoothing of the gaze.
#[derive(Clone, Copy, Debug)]
pub struct GazeFilter {
    cfg: GazeConfig,
    last: Option<(f64, [f32; 2])>,
    smooth: [OneEuro; 2],
}

impl GazeFilter {
    pub fn new(cfg: GazeConfig) -> Self {
        Self {
            cfg,
            last: None,
            smooth: [OneEuro::new(cfg.one_euro); 2],
        }
    }

    /// Feeds one gaze sample; returns the smoothed gaze if it was accepted.
    pub fn update(&mut self, t_secs: f64, gaze_uv: [f32; 2], confidence: f32) -> Option<[f32; 2]> {
        let [u, v] = gaze_uv;
        if confidence.partial_cmp(&self.cfg.min_confidence) == Some(std::cmp::Ordering::Less)
            || confidence.is_nan()
            || !u.is_finite()
            || !v.is_finite()
            || !t_secs.is_finite()
        {
            return None;
        }
        let m = self.cfg.margin_uv;
        if u < -m || u > 1.0 + m || v < -m || v > 1.0 + m {
            return None;
        }
        if let Some((t0, [u0, v0])) = self.last {
            let dt = (t_secs - t0).max(0.0);
            if dt > self.cfg.reset_after_s {
                self.smooth.iter_mut().for_each(OneEuro::reset);
            } else {
                let allowed = self.cfg.jump_tolerance_uv + self.cfg.max_speed_uv_per_s * dt as f32;
                if (u - u0).hypot(v - v0) > allowed {
                    return None;
                }
            }
        }
        self.last = Some((t_secs, gaze_uv));
        Some([
            self.smooth[0].filter(t_secs, u),
            self.smooth[1].filter(t_secs, v),
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_euro_smooths_jitter_and_follows_a_saccade() {
        let mut f = OneEuro::new(OneEuroConfig::default());
        // Deterministic ±0.01 jitter around 0.5 at 200 Hz for 1 s.
        let mut max_dev = 0.0f32;
        for i in 0..200 {
            let x = 0.5 + if i % 2 == 0 { 0.01 } else { -0.01 };
            let y = f.filter(i as f64 * 0.005, x);
            if i > 50 {
                max_dev = max_dev.max((y - 0.5).abs());
            }
        }
        assert!(max_dev < 0.003, "jitter reduced from 0.01 to {max_dev}");
        // A 0.3 uv saccade in 40 ms: within 60 ms of its end the output is
        // within 0.02 of the target.
        let mut y = 0.5;
        for i in 0..8 {
            y = f.filter(1.0 + i as f64 * 0.005, 0.5 + 0.3 * (i as f32 + 1.0) / 8.0);
        }
        for i in 8..20 {
            y = f.filter(1.0 + i as f64 * 0.005, 0.8);
        }
        assert!((y - 0.8).abs() < 0.02, "{y}");
    }

    #[test]
    fn outliers_are_rejected() {
        let mut g = GazeFilter::new(GazeConfig::default());
        assert!(g.update(0.0, [0.5, 0.5], 1.0).is_some());
        assert!(g.update(0.005, [0.5, 0.5], 0.2).is_none(), "low confidence");
        assert!(g.update(0.005, [f32::NAN, 0.5], 1.0).is_none());
        assert!(g.update(0.005, [2.0, 0.5], 1.0).is_none(), "off image");
        assert!(
            g.update(0.005, [0.9, 0.5], 1.0).is_none(),
            "spike: 0.4 uv in 5 ms"
        );
        assert!(g.update(0.010, [0.52, 0.5], 1.0).is_some());
    }
}
