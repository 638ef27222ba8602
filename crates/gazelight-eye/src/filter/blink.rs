//! Blink detection with debounce, units-agnostic: it looks only at whether
//! each sample of an eye is *closed* (no usable pupil: confidence below the
//! gate, or a diameter ≤ 0 / NaN), so it works the same on raw px, mm or
//! EyeLink area units, before any calibration.
//!
//! Trackers flicker at the edges of a blink: Pupil publishes several onsets
//! per blink (confidence 0 and diameter 0 while the lid is closed, with
//! isolated confident frames in between); Neon's eyelid aperture crosses its
//! threshold several times while the lid reopens. So:
//!
//! - closed runs separated by open gaps shorter than `debounce_gap_s`
//!   (default 50 ms, 10 frames at 200 Hz) are merged into one closure;
//! - a closure is finalised once the eye has stayed open for longer than the
//!   gap;
//! - a closure lasting `min_duration_s..=max_duration_s` (default
//!   30 ms–1.5 s) is a **blink**; shorter or longer closures are
//!   **dropouts** (a lost frame, a lost eye). Blinks last about 100–400 ms
//!   (Caffier et al. 2003, Eur. J. Appl. Physiol.); the lower bound is set
//!   below that because trackers clip the partially-closed start and end
//!   (EyeLink's own parser reports 34 ms blinks in the PSA recording), the
//!   upper bound above slow, voluntary blinks (the same recording has a
//!   696 ms one).

use crate::setting::SettingError;
use serde::{Deserialize, Serialize};

/// Blink detector configuration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BlinkConfig {
    /// Open gaps shorter than this (s) do not end a closure. Default 0.05.
    pub debounce_gap_s: f64,
    /// Shortest closure counted as a blink (s). Default 0.03.
    pub min_duration_s: f64,
    /// Longest closure counted as a blink (s). Default 1.5.
    pub max_duration_s: f64,
}

impl Default for BlinkConfig {
    fn default() -> Self {
        Self {
            debounce_gap_s: 0.05,
            min_duration_s: 0.03,
            max_duration_s: 1.5,
        }
    }
}

impl BlinkConfig {
    /// Checks the durations are positive and ordered; names the field.
    pub fn validate(&self) -> Result<(), SettingError> {
        if !(self.debounce_gap_s.is_finite() && self.debounce_gap_s >= 0.0) {
            return Err(SettingError::new(
                "blink.debounce_gap_s",
                format!("must be ≥ 0, got {}", self.debounce_gap_s),
            ));
        }
        if !(self.min_duration_s.is_finite() && self.min_duration_s >= 0.0) {
            return Err(SettingError::new(
                "blink.min_duration_s",
                format!("must be ≥ 0, got {}", self.min_duration_s),
            ));
        }
        if !(self.max_duration_s.is_finite() && self.max_duration_s > self.min_duration_s) {
            return Err(SettingError::new(
                "blink.max_duration_s",
                format!("must be > min_duration_s, got {}", self.max_duration_s),
            ));
        }
        Ok(())
    }
}

/// What a finished closure was.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClosureKind {
    Blink,
    Dropout,
}

/// A finished closure of one eye.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Closure {
    pub eye: u8,
    /// Time of the first closed sample.
    pub start_t_secs: f64,
    /// Time of the first open sample after the last closed one.
    pub end_t_secs: f64,
    pub kind: ClosureKind,
}

#[derive(Clone, Copy, Debug)]
struct Run {
    start: f64,
    last_closed: f64,
    open_since: Option<f64>,
}

/// One eye's blink detector.
#[derive(Clone, Copy, Debug)]
pub struct BlinkDetector {
    cfg: BlinkConfig,
    eye: u8,
    run: Option<Run>,
}

impl BlinkDetector {
    pub fn new(cfg: BlinkConfig, eye: u8) -> Self {
        Self {
            cfg,
            eye,
            run: None,
        }
    }

    /// Whether the eye is closed right now (inside a closure and not in an
    /// open gap).
    pub fn is_closed(&self) -> bool {
        matches!(
            self.run,
            Some(Run {
                open_since: None,
                ..
            })
        )
    }

    /// Feeds one sample: `closed` = no usable pupil. Returns a closure when
    /// one has just been finalised. Times must be non-decreasing (earlier
    /// times are treated as the latest seen).
    pub fn update(&mut self, t_secs: f64, closed: bool) -> Option<Closure> {
        match (&mut self.run, closed) {
            (None, true) => {
                self.run = Some(Run {
                    start: t_secs,
                    last_closed: t_secs,
                    open_since: None,
                });
                None
            }
            (None, false) => None,
            (Some(r), true) => {
                r.last_closed = t_secs.max(r.last_closed);
                r.open_since = None;
                None
            }
            (Some(r), false) => {
                let open_since = *r.open_since.get_or_insert(t_secs.max(r.last_closed));
                if t_secs - r.last_closed > self.cfg.debounce_gap_s {
                    let start = r.start;
                    self.run = None;
                    Some(self.classify(start, open_since))
                } else {
                    None
                }
            }
        }
    }

    /// Ends the stream: finalises a pending closure (one still closed ends
    /// at `t_secs`).
    pub fn flush(&mut self, t_secs: f64) -> Option<Closure> {
        let r = self.run.take()?;
        let end = r.open_since.unwrap_or(t_secs.max(r.last_closed));
        Some(self.classify(r.start, end))
    }

    fn classify(&self, start: f64, end: f64) -> Closure {
        let d = end - start;
        let kind = if d >= self.cfg.min_duration_s && d <= self.cfg.max_duration_s {
            ClosureKind::Blink
        } else {
            ClosureKind::Dropout
        };
        Closure {
            eye: self.eye,
            start_t_secs: start,
            end_t_secs: end,
            kind,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs a 200 Hz closed/open pattern; returns the closures.
    fn run(pattern: &[(bool, usize)]) -> Vec<Closure> {
        let mut d = BlinkDetector::new(BlinkConfig::default(), 0);
        let mut t = 0.0;
        let mut out = Vec::new();
        for &(closed, n) in pattern {
            for _ in 0..n {
                out.extend(d.update(t, closed));
                t += 0.005;
            }
        }
        out.extend(d.flush(t));
        out
    }

    #[test]
    fn flickering_onsets_merge_into_one_blink() {
        // Pupil-style: closed 40 ms, one confident frame, closed 100 ms,
        // two frames, closed 60 ms, then open.
        let c = run(&[
            (false, 20),
            (true, 8),
            (false, 1),
            (true, 20),
            (false, 2),
            (true, 12),
            (false, 40),
        ]);
        assert_eq!(c.len(), 1, "{c:?}");
        assert_eq!(c[0].kind, ClosureKind::Blink);
        assert!((c[0].start_t_secs - 0.100).abs() < 1e-9);
        assert!((c[0].end_t_secs - (0.100 + 43.0 * 0.005)).abs() < 1e-9);
    }

    #[test]
    fn separate_blinks_beyond_the_gap_count_twice() {
        let c = run(&[(true, 30), (false, 20), (true, 30), (false, 20)]);
        assert_eq!(c.iter().filter(|c| c.kind == ClosureKind::Blink).count(), 2);
    }

    #[test]
    fn too_short_and_too_long_closures_are_dropouts() {
        let c = run(&[(false, 5), (true, 2), (false, 30), (true, 400), (false, 30)]);
        assert_eq!(c.len(), 2);
        assert!(c.iter().all(|c| c.kind == ClosureKind::Dropout), "{c:?}");
    }

    #[test]
    fn closed_state_is_visible_while_it_lasts() {
        let mut d = BlinkDetector::new(BlinkConfig::default(), 1);
        assert!(!d.is_closed());
        d.update(0.0, true);
        assert!(d.is_closed());
        d.update(0.005, false);
        assert!(!d.is_closed());
    }
}
