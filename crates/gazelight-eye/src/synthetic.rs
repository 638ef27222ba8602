//! Deterministic synthetic eye-tracking traces for tests, benchmarks and the
//! demo: fixations and saccades, blinks, tracker dropouts, and a pupil that
//! follows a luminance signal.
//!
//! - **Pupil**: the target is the Watson–Yellott pupil
//!   ([`crate::pupil_model`]) at the luminance `L(t)`; the pupil follows it
//!   with first-order dynamics, constriction faster than dilation (default
//!   τ = 0.3 s and 1.5 s: the light reflex constricts within about a second,
//!   redilation takes several — the piprkit flashes in `shared/data` reach
//!   their minimum ~2 s after onset and recover over tens of seconds).
//! - **Saccades**: duration from the main sequence, D ≈ 2.2 ms/° · A + 21 ms
//!   (Carpenter 1988, *Movements of the Eyes*), minimum-jerk position
//!   profile; fixations last 0.2–0.6 s (uniform), with Gaussian-ish jitter.
//! - **Blinks**: the tracker reports confidence 0 and diameter 0 for the
//!   closed eye (as Pupil Core does); each blink also produces a ground-truth
//!   [`BlinkEvent`] at its end.
//! - **Dropouts**: short losses of one eye with low confidence and a
//!   garbage diameter (0, NaN or a wild value).
//!
//! Everything is driven by a seeded SplitMix64 generator, so a seed always
//! gives the same trace.

use crate::pupil_model::PupilModel;
use crate::sample::{
    BlinkEvent, DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample,
};
use crate::trace::{GazeTrace, TraceSample};

/// Main-sequence saccade duration slope, s per degree (Carpenter 1988).
const SACCADE_S_PER_DEG: f64 = 0.0022;
/// Main-sequence saccade duration intercept, s (Carpenter 1988).
const SACCADE_BASE_S: f64 = 0.021;

/// SplitMix64: small, fast, deterministic.
#[derive(Clone, Copy, Debug)]
pub struct SynthRng(u64);

impl SynthRng {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [a, b).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
    /// Approximately standard normal (sum of 4 uniforms, rescaled).
    pub fn normal(&mut self) -> f64 {
        let s: f64 = (0..4).map(|_| self.uniform()).sum();
        (s - 2.0) * (3.0f64).sqrt()
    }
}

/// First-order pupil dynamics with separate constriction and dilation time
/// constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PupilDynamics {
    pub tau_constriction_s: f64,
    pub tau_dilation_s: f64,
}

impl Default for PupilDynamics {
    fn default() -> Self {
        Self {
            tau_constriction_s: 0.3,
            tau_dilation_s: 1.5,
        }
    }
}

impl PupilDynamics {
    /// One step of `dt` from `pupil_mm` towards `target_mm` (exact
    /// exponential step, stable for any dt).
    pub fn step(&self, pupil_mm: f64, target_mm: f64, dt_secs: f64) -> f64 {
        let tau = if target_mm < pupil_mm {
            self.tau_constriction_s
        } else {
            self.tau_dilation_s
        };
        target_mm + (pupil_mm - target_mm) * (-dt_secs / tau).exp()
    }
}

/// Settings of the random generator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SyntheticConfig {
    pub seed: u64,
    pub rate_hz: f64,
    pub duration_s: f64,
    /// Width of the image in degrees (for saccade durations).
    pub field_width_deg: f64,
    pub fixation_s: [f64; 2],
    /// Blinks per minute (15–20 at rest).
    pub blinks_per_min: f64,
    pub blink_duration_s: [f64; 2],
    /// Dropouts per minute per eye.
    pub dropouts_per_min: f64,
    pub dropout_duration_s: [f64; 2],
    /// Pupil measurement noise (standard deviation, mm).
    pub pupil_noise_mm: f64,
    /// Gaze noise (standard deviation, uv).
    pub gaze_noise_uv: f64,
    /// Raw unit: `Mm`, or `Px` with `px_per_mm`.
    pub unit: PupilUnit,
    pub px_per_mm: f64,
    pub dynamics: PupilDynamics,
    pub model: PupilModel,
}

impl Default for SyntheticConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            rate_hz: 200.0,
            duration_s: 60.0,
            field_width_deg: 100.0,
            fixation_s: [0.2, 0.6],
            blinks_per_min: 17.0,
            blink_duration_s: [0.1, 0.35],
            dropouts_per_min: 4.0,
            dropout_duration_s: [0.01, 0.04],
            pupil_noise_mm: 0.03,
            gaze_noise_uv: 0.002,
            unit: PupilUnit::Mm,
            px_per_mm: 10.0,
            dynamics: PupilDynamics::default(),
            model: PupilModel::default(),
        }
    }
}

/// The random generator: an iterator of samples (per tick: right pupil,
/// left pupil, gaze; plus a blink event at each blink's end).
pub struct SyntheticTrace<L: FnMut(f64) -> f64> {
    cfg: SyntheticConfig,
    luminance: L,
    rng: SynthRng,
    tick: u64,
    pupil_mm: f64,
    gaze: [f64; 2],
    sacc: Option<(f64, f64, [f64; 2], [f64; 2])>,
    next_fixation_end: f64,
    blink: Option<(f64, f64)>,
    next_blink: f64,
    dropout: [Option<f64>; 2],
    next_dropout: [f64; 2],
    queue: [Option<Sample>; 4],
    queued: usize,
}

impl<L: FnMut(f64) -> f64> SyntheticTrace<L> {
    /// A generator with luminance signal `luminance(t_secs) → cd/m²`.
    pub fn new(cfg: SyntheticConfig, mut luminance: L) -> Self {
        let mut rng = SynthRng::new(cfg.seed);
        let pupil_mm = cfg.model.pupil_mm(luminance(0.0)) as f64;
        let exp = |rng: &mut SynthRng, per_min: f64| {
            if per_min > 0.0 {
                -(1.0 - rng.uniform()).ln() * 60.0 / per_min
            } else {
                f64::INFINITY
            }
        };
        let next_blink = exp(&mut rng, cfg.blinks_per_min);
        let next_dropout = [
            exp(&mut rng, cfg.dropouts_per_min),
            exp(&mut rng, cfg.dropouts_per_min),
        ];
        Self {
            cfg,
            luminance,
            rng,
            tick: 0,
            pupil_mm,
            gaze: [0.5, 0.5],
            sacc: None,
            next_fixation_end: 0.3,
            blink: None,
            next_blink,
            dropout: [None; 2],
            next_dropout,
            queue: [None; 4],
            queued: 0,
        }
    }

    fn interval(&mut self, per_min: f64) -> f64 {
        if per_min > 0.0 {
            -(1.0 - self.rng.uniform()).ln() * 60.0 / per_min
        } else {
            f64::INFINITY
        }
    }

    fn generate_tick(&mut self) {
        let dt = 1.0 / self.cfg.rate_hz;
        let t = self.tick as f64 * dt;
        self.tick += 1;
        // Pupil dynamics.
        let target = self.cfg.model.pupil_mm((self.luminance)(t)) as f64;
        self.pupil_mm = self.cfg.dynamics.step(self.pupil_mm, target, dt);
        // Gaze: fixation / saccade.
        if let Some((t0, d, from, to)) = self.sacc {
            let s = ((t - t0) / d).clamp(0.0, 1.0);
            let k = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s); // minimum jerk
            self.gaze = [
                from[0] + (to[0] - from[0]) * k,
                from[1] + (to[1] - from[1]) * k,
            ];
            if s >= 1.0 {
                self.sacc = None;
                self.next_fixation_end = t + self
                    .rng
                    .range(self.cfg.fixation_s[0], self.cfg.fixation_s[1]);
            }
        } else if t >= self.next_fixation_end {
            let to = [self.rng.range(0.1, 0.9), self.rng.range(0.1, 0.9)];
            let amp_deg =
                (to[0] - self.gaze[0]).hypot(to[1] - self.gaze[1]) * self.cfg.field_width_deg;
            let d = SACCADE_BASE_S + SACCADE_S_PER_DEG * amp_deg;
            self.sacc = Some((t, d, self.gaze, to));
        }
        // Blinks.
        let mut blink_end = None;
        match self.blink {
            Some((s, e)) if t >= e => {
                blink_end = Some((s, e));
                self.blink = None;
                self.next_blink = t + self.interval(self.cfg.blinks_per_min);
            }
            None if t >= self.next_blink => {
                let d = self
                    .rng
                    .range(self.cfg.blink_duration_s[0], self.cfg.blink_duration_s[1]);
                self.blink = Some((t, t + d));
            }
            _ => {}
        }
        let closed = self.blink.is_some();
        // Emit.
        for eye in 0..2usize {
            let mut dropout = false;
            match self.dropout[eye] {
                Some(end) if t >= end => {
                    self.dropout[eye] = None;
                    self.next_dropout[eye] = t + self.interval(self.cfg.dropouts_per_min);
                }
                Some(_) => dropout = true,
                None if t >= self.next_dropout[eye] => {
                    let d = self.rng.range(
                        self.cfg.dropout_duration_s[0],
                        self.cfg.dropout_duration_s[1],
                    );
                    self.dropout[eye] = Some(t + d);
                    dropout = true;
                }
                None => {}
            }
            let noise = self.rng.normal() * self.cfg.pupil_noise_mm;
            let mm = self.pupil_mm + noise;
            let scale = if self.cfg.unit == PupilUnit::Mm {
                1.0
            } else {
                self.cfg.px_per_mm
            };
            let (raw, conf) = if closed {
                (0.0, 0.0)
            } else if dropout {
                let garbage = match self.rng.next_u64() % 3 {
                    0 => 0.0,
                    1 => f32::NAN,
                    _ => (self.rng.range(0.0, 30.0) * scale) as f32,
                };
                (garbage, self.rng.range(0.0, 0.4) as f32)
            } else {
                ((mm * scale) as f32, self.rng.range(0.85, 1.0) as f32)
            };
            self.push(Sample::Pupil(PupilSample {
                t_secs: t,
                eye: eye as u8,
                diameter_raw: raw,
                unit: self.cfg.unit,
                diameter_mm: (self.cfg.unit == PupilUnit::Mm && conf > 0.0 && raw > 0.0)
                    .then_some(raw),
                confidence: conf,
                norm_pos: [0.5, 0.5],
                method: DetectorMethod::Other,
            }));
        }
        let gn = self.cfg.gaze_noise_uv;
        let g = [
            (self.gaze[0] + self.rng.normal() * gn) as f32,
            (self.gaze[1] + self.rng.normal() * gn) as f32,
        ];
        self.push(Sample::Gaze(GazeSample {
            t_secs: t,
            gaze_uv: g,
            confidence: if closed { 0.0 } else { 0.95 },
            eyes: GazeEyes::Binocular,
        }));
        if let Some((s, e)) = blink_end {
            self.push(Sample::Blink(BlinkEvent {
                start_t_secs: s,
                end_t_secs: e,
                eye: None,
            }));
        }
    }

    fn push(&mut self, s: Sample) {
        if self.queued < self.queue.len() {
            self.queue[self.queued] = Some(s);
            self.queued += 1;
        }
    }

    /// The true (noise-free) pupil right now, mm.
    pub fn true_pupil_mm(&self) -> f64 {
        self.pupil_mm
    }
}

impl<L: FnMut(f64) -> f64> Iterator for SyntheticTrace<L> {
    type Item = Sample;

    fn next(&mut self) -> Option<Sample> {
        if self.queued == 0 {
            if self.tick as f64 / self.cfg.rate_hz >= self.cfg.duration_s {
                return None;
            }
            self.generate_tick();
            // Serve in emission order.
            self.queue[..self.queued].reverse();
        }
        self.queued -= 1;
        self.queue[self.queued].take()
    }
}

/// A keyframed trace: fixations at given times, blinks at given times, and a
/// luminance that may depend on where the eye looks. The CLI's default demo
/// trace is [`KeyframedTrace::street_lamp_demo`].
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframedTrace {
    /// `(t_secs, gaze_uv)`: the eye arrives at `gaze_uv` at `t_secs` and
    /// fixates there until the next keyframe's saccade. Sorted by time.
    pub keyframes: Vec<(f64, [f32; 2])>,
    /// `(start_t_secs, duration_s)` of each blink.
    pub blinks: Vec<(f64, f64)>,
    pub rate_hz: f64,
    pub duration_s: f64,
    pub field_width_deg: f64,
    pub dynamics: PupilDynamics,
    pub model: PupilModel,
    pub seed: u64,
    /// Gaze jitter during fixations (standard deviation, uv).
    pub gaze_noise_uv: f64,
}

impl KeyframedTrace {
    /// The demo: the eye rests on the dark ground of a night scene, makes a
    /// saccade up to a street lamp, fixates it (the pupil constricts),
    /// blinks, looks back down (the pupil slowly redilates), blinks again.
    pub fn street_lamp_demo() -> Self {
        Self {
            keyframes: vec![
                (0.0, [0.45, 0.80]),
                (2.0, [0.52, 0.78]),
                (4.0, [0.70, 0.32]),
                (7.0, [0.69, 0.34]),
                (9.0, [0.45, 0.80]),
                (14.0, [0.40, 0.78]),
            ],
            blinks: vec![(3.1, 0.15), (6.2, 0.2), (11.5, 0.15)],
            rate_hz: 120.0,
            duration_s: 16.0,
            field_width_deg: 100.0,
            dynamics: PupilDynamics::default(),
            model: PupilModel::default(),
            seed: 7,
            gaze_noise_uv: 0.0015,
        }
    }

    /// Luminance for the demo: a lamp at (0.7, 0.33) of radius ~0.08 uv at
    /// 2000 cd/m² falling off into a 0.05 cd/m² night ground.
    pub fn street_lamp_luminance(gaze_uv: [f32; 2]) -> f64 {
        let d = ((gaze_uv[0] - 0.70) as f64).hypot((gaze_uv[1] - 0.33) as f64);
        0.05 + 2000.0 * (-(d / 0.08).powi(2)).exp()
    }

    /// The gaze (noise-free) at `t_secs`: fixation at the last keyframe, or a
    /// main-sequence saccade into the next one.
    pub fn gaze_at(&self, t_secs: f64) -> [f32; 2] {
        let k = &self.keyframes;
        let Some(first) = k.first() else {
            return [0.5, 0.5];
        };
        let mut cur = first.1;
        for w in k.windows(2) {
            let ((_, from), (t1, to)) = (w[0], w[1]);
            let amp =
                ((to[0] - from[0]) as f64).hypot((to[1] - from[1]) as f64) * self.field_width_deg;
            let d = SACCADE_BASE_S + SACCADE_S_PER_DEG * amp;
            let t0 = t1 - d;
            if t_secs < t0 {
                break;
            }
            let s = ((t_secs - t0) / d).clamp(0.0, 1.0);
            let m = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s);
            cur = [
                from[0] + (to[0] - from[0]) * m as f32,
                from[1] + (to[1] - from[1]) * m as f32,
            ];
        }
        cur
    }

    /// Builds the trace; `luminance(t_secs, gaze_uv) → cd/m²` drives the
    /// pupil. During blinks the pupil is a dropout (empty) with confidence 0.
    pub fn build(&self, mut luminance: impl FnMut(f64, [f32; 2]) -> f64) -> GazeTrace {
        let mut rng = SynthRng::new(self.seed);
        let n = (self.duration_s * self.rate_hz).ceil() as usize;
        let mut samples = Vec::with_capacity(n);
        let g0 = self.gaze_at(0.0);
        let mut pupil = self.model.pupil_mm(luminance(0.0, g0)) as f64;
        let dt = 1.0 / self.rate_hz;
        for i in 0..n {
            let t = i as f64 * dt;
            let g = self.gaze_at(t);
            let target = self.model.pupil_mm(luminance(t, g)) as f64;
            pupil = self.dynamics.step(pupil, target, dt);
            let blinking = self.blinks.iter().any(|&(s, d)| t >= s && t < s + d);
            let jitter = [
                (rng.normal() * self.gaze_noise_uv) as f32,
                (rng.normal() * self.gaze_noise_uv) as f32,
            ];
            samples.push(TraceSample {
                t_secs: t,
                gaze_uv: [g[0] + jitter[0], g[1] + jitter[1]],
                pupil_mm: (!blinking).then_some(pupil as f32),
                confidence: if blinking { 0.0 } else { 0.97 },
            });
        }
        GazeTrace { samples }
    }
}

/// A synthetic black/white calibration session: a pupil in `unit` (px with
/// `px_per_mm`, or mm) that follows the stimulus from `t0` on — black
/// (`black_mm` target) for `phase_s`, then white (`white_mm`) for `phase_s`
/// — with first-order dynamics, noise, and a blink per phase. Both eyes;
/// the left eye's pupil is `anisocoria_mm` larger. 120 Hz.
#[allow(clippy::too_many_arguments)]
pub fn black_white_session(
    seed: u64,
    phase_s: f64,
    black_mm: f64,
    white_mm: f64,
    unit: PupilUnit,
    px_per_mm: f64,
    noise_mm: f64,
    anisocoria_mm: f64,
) -> Vec<Sample> {
    let rate_hz = 120.0;
    let dyn_ = PupilDynamics::default();
    let mut rng = SynthRng::new(seed);
    let scale = if unit == PupilUnit::Mm {
        1.0
    } else {
        px_per_mm
    };
    let n = (2.0 * phase_s * rate_hz) as usize + 12;
    let mut out = Vec::with_capacity(2 * n);
    // Start half-adapted, as after ordinary room light.
    let mut pupil = 0.5 * (black_mm + white_mm);
    for i in 0..n {
        let t = i as f64 / rate_hz;
        let target = if t < phase_s { black_mm } else { white_mm };
        pupil = dyn_.step(pupil, target, 1.0 / rate_hz);
        let in_blink = [0.6 * phase_s, 1.6 * phase_s]
            .iter()
            .any(|&b| t >= b && t < b + 0.2);
        for eye in 0..2u8 {
            let mm = pupil + anisocoria_mm * eye as f64 + rng.normal() * noise_mm;
            let (raw, conf) = if in_blink {
                (0.0, 0.0)
            } else {
                ((mm * scale) as f32, rng.range(0.8, 1.0) as f32)
            };
            out.push(Sample::Pupil(PupilSample {
                t_secs: 100.0 + t,
                eye,
                diameter_raw: raw,
                unit,
                diameter_mm: None,
                confidence: conf,
                norm_pos: [0.5, 0.5],
                method: DetectorMethod::Pupil2d,
            }));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_trace_different_seed_different_trace() {
        let a: Vec<Sample> = SyntheticTrace::new(SyntheticConfig::default(), |_| 10.0)
            .take(5000)
            .collect();
        let b: Vec<Sample> = SyntheticTrace::new(SyntheticConfig::default(), |_| 10.0)
            .take(5000)
            .collect();
        let c: Vec<Sample> = SyntheticTrace::new(
            SyntheticConfig {
                seed: 2,
                ..Default::default()
            },
            |_| 10.0,
        )
        .take(5000)
        .collect();
        // NaN != NaN: compare debug strings.
        assert_eq!(format!("{a:?}"), format!("{b:?}"));
        assert_ne!(format!("{a:?}"), format!("{c:?}"));
    }

    #[test]
    fn pupil_follows_luminance_constricting_faster_than_dilating() {
        let d = PupilDynamics::default();
        let m = PupilModel::default();
        let (dark, bright) = (m.pupil_mm(0.01) as f64, m.pupil_mm(1000.0) as f64);
        // Time to cover 90 % of the step either way.
        let t90 = |from: f64, to: f64| {
            let mut p = from;
            let mut t = 0.0;
            while (p - to).abs() > 0.1 * (from - to).abs() {
                p = d.step(p, to, 0.005);
                t += 0.005;
            }
            t
        };
        let tc = t90(dark, bright);
        let td = t90(bright, dark);
        assert!(tc < 1.0 && td > 2.0 * tc, "constrict {tc} s, dilate {td} s");
    }

    #[test]
    fn generator_has_blinks_dropouts_and_saccades() {
        let cfg = SyntheticConfig {
            duration_s: 120.0,
            ..Default::default()
        };
        let samples: Vec<Sample> =
            SyntheticTrace::new(cfg, |t| if t < 60.0 { 1.0 } else { 300.0 }).collect();
        let blinks = samples
            .iter()
            .filter(|s| matches!(s, Sample::Blink(_)))
            .count();
        assert!((20..=50).contains(&blinks), "~17/min over 2 min: {blinks}");
        let bad = samples
            .iter()
            .filter(|s| matches!(s, Sample::Pupil(p) if p.diameter_raw.is_nan() || p.diameter_raw <= 0.0))
            .count();
        assert!(bad > 100);
        // The gaze moves: its range covers most of the image.
        let us: Vec<f32> = samples
            .iter()
            .filter_map(|s| match s {
                Sample::Gaze(g) if g.confidence > 0.5 => Some(g.gaze_uv[0]),
                _ => None,
            })
            .collect();
        let (lo, hi) = us
            .iter()
            .fold((1.0f32, 0.0f32), |(a, b), &u| (a.min(u), b.max(u)));
        assert!(lo < 0.2 && hi > 0.8);
    }

    #[test]
    fn street_lamp_demo_constricts_at_the_lamp_and_redilates() {
        let k = KeyframedTrace::street_lamp_demo();
        let tr = k.build(|_, g| KeyframedTrace::street_lamp_luminance(g));
        assert_eq!(tr.samples.len(), (16.0 * 120.0) as usize);
        let at = |t: f64| {
            tr.samples
                .iter()
                .filter(|s| (s.t_secs - t).abs() < 0.05)
                .find_map(|s| s.pupil_mm)
                .unwrap()
        };
        let (ground, lamp, back) = (at(1.5), at(8.5), at(15.5));
        assert!(lamp < ground - 2.0, "ground {ground}, lamp {lamp}");
        assert!(back > lamp + 1.0, "redilates: {back}");
        let blinked = tr.samples.iter().filter(|s| s.pupil_mm.is_none()).count();
        assert!(blinked > 50);
        let g = k.gaze_at(8.0);
        assert!((g[0] - 0.69).abs() < 1e-3 && (g[1] - 0.34).abs() < 1e-3);
    }
}
