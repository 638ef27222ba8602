//! Time stamps the way pyxdf's `load_xdf` gives them with its defaults
//! (pyxdf 1.17: `synchronize_clocks=True`, `handle_clock_resets=True`,
//! `dejitter_timestamps=True`, `winsor_threshold=0.0001`), so that a
//! stream read here has the time stamps a Python user of the same file
//! sees:
//!
//! 1. **Corrupted last offset** (pylsl#67, liblsl#246): when a stream holds
//!    more samples than its footer's `sample_count` *and* its last clock
//!    offset is an outlier (its interval over 10× the median interval, or
//!    its value over 10 scaled MADs from the median), that offset and the
//!    extra samples are dropped ([`truncate_corrupted`]).
//! 2. **Clock resets**: the offsets are split where their collection time
//!    goes backwards, or where both the time step and the value step are
//!    outliers (time: > 5 MADs and > 5 s from the median step; value:
//!    > 10 MADs and > 1 s) ([`reset_ranges`]).
//! 3. **Clock offsets**: per range, offset = c₀ + c₁·t is fitted to the
//!    (collection time, offset) pairs with a Huber-loss regression solved
//!    by ADMM (1000 iterations, ρ = 1; [`robust_fit`]); a sample's time t
//!    becomes t + c₀ + c₁·t. With several ranges, a sample belongs to the
//!    current range until it is no closer to the range's last collection
//!    time than to the next range's first ([`ClockMap`]).
//! 4. **Dejitter** (streams with a nominal rate that do not declare
//!    `can_drop_samples`): the stream is cut where consecutive (synced)
//!    stamps are more than max(1 s, 500 sample intervals) apart, and each
//!    piece's stamps are replaced by their least-squares line over the
//!    sample index ([`Segments`]).
//!
//! Everything here works on the clock offsets (one every few seconds,
//! bounded by [`super::MAX_CLOCK_OFFSETS`]) and on running sums; the
//! samples themselves stream past.

/// pyxdf's default `winsor_threshold`: the scale of the robust fit, s.
pub const WINSOR_SECS: f64 = 1e-4;
/// ADMM iterations and augmented Lagrangian parameter of the robust fit.
const ADMM_ITERS: usize = 1000;
const ADMM_RHO: f64 = 1.0;
/// Clock-reset thresholds (pyxdf's defaults): time step MADs and seconds,
/// value step MADs and seconds.
const RESET_TIME_STDS: f64 = 5.0;
const RESET_TIME_SECS: f64 = 5.0;
const RESET_VALUE_STDS: f64 = 10.0;
const RESET_VALUE_SECS: f64 = 1.0;
/// Dejitter breaks: a step above max(this, samples × interval), s.
pub const JITTER_BREAK_SECS: f64 = 1.0;
pub const JITTER_BREAK_SAMPLES: f64 = 500.0;
/// Corrupted-last-offset test: interval ratio and MAD z-score.
const CORRUPT_TIME_RATIO: f64 = 10.0;
const CORRUPT_VALUE_Z: f64 = 10.0;
/// MAD → standard deviation of a normal distribution.
const MAD_TO_SD: f64 = 1.4826;

fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    if v.is_empty() {
        return f64::NAN;
    }
    if v.iter().any(|x| x.is_nan()) {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// Steps that are outliers: more than `stds` MADs *and* `secs` from the
/// median step.
fn glitches(steps: &[f64], stds: f64, secs: f64) -> Vec<bool> {
    let med = median(steps);
    let dev: Vec<f64> = steps.iter().map(|d| (d - med).abs()).collect();
    let mad = median(&dev) + f64::EPSILON;
    steps
        .iter()
        .map(|d| {
            let shift = d - med;
            (shift / mad).abs() > stds && shift.abs() > secs
        })
        .collect()
}

/// Whether the last clock offset is an outlier (pyxdf's
/// `_detect_corrupted_clock_offset`); needs 3 offsets or more.
fn last_offset_corrupted(times: &[f64], values: &[f64]) -> bool {
    let n = times.len();
    if n < 3 {
        return false;
    }
    let intervals: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    let median_interval = median(&intervals[..intervals.len() - 1]);
    let last_interval = intervals[intervals.len() - 1].abs();
    let time_ratio = if median_interval > 0.0 {
        last_interval / median_interval
    } else if last_interval > 0.0 {
        f64::INFINITY
    } else {
        1.0
    };
    let head = &values[..n - 1];
    let med = median(head);
    let dev: Vec<f64> = head.iter().map(|v| (v - med).abs()).collect();
    let mad = median(&dev);
    let z = if mad > f64::EPSILON {
        (values[n - 1] - med).abs() / (MAD_TO_SD * mad)
    } else {
        0.0
    };
    time_ratio > CORRUPT_TIME_RATIO || z > CORRUPT_VALUE_Z
}

/// Step 1: how many samples to keep and whether to drop the last offset.
/// Returns `Some(footer_count)` when the stream is truncated (the offsets
/// are shortened in place).
pub fn truncate_corrupted(
    offsets: &mut Vec<(f64, f64)>,
    samples: u64,
    footer_count: Option<u64>,
) -> Option<u64> {
    let footer = footer_count?;
    if samples <= footer || offsets.len() < 3 {
        return None;
    }
    let (times, values): (Vec<f64>, Vec<f64>) = offsets.iter().copied().unzip();
    if !last_offset_corrupted(&times, &values) {
        return None;
    }
    offsets.pop();
    Some(footer)
}

/// Step 2: inclusive index ranges of the offsets between clock resets.
pub fn reset_ranges(times: &[f64], values: &[f64]) -> Vec<(usize, usize)> {
    let n = times.len();
    if n <= 1 {
        return vec![(0, n.saturating_sub(1))];
    }
    let dt: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    let dv: Vec<f64> = values.windows(2).map(|w| w[1] - w[0]).collect();
    let tg = glitches(&dt, RESET_TIME_STDS, RESET_TIME_SECS);
    let vg = glitches(&dv, RESET_VALUE_STDS, RESET_VALUE_SECS);
    let mut ranges = Vec::new();
    let mut start = 0;
    for k in 0..dt.len() {
        if dt[k] < 0.0 || (tg[k] && vg[k]) {
            ranges.push((start, k));
            start = k + 1;
        }
    }
    ranges.push((start, dt.len()));
    ranges
}

/// Step 3: offset ≈ c₀ + c₁·t by Huber-loss regression (ADMM, after Boyd
/// et al.'s distributed-optimisation codes, as pyxdf's `_robust_fit`), on
/// times and offsets scaled by [`WINSOR_SECS`]. `None` when the normal
/// matrix is not positive definite (all collection times equal).
pub fn robust_fit(times: &[f64], values: &[f64]) -> Option<[f64; 2]> {
    let n = times.len();
    let a1: Vec<f64> = times.iter().map(|t| t / WINSOR_SECS).collect();
    let y: Vec<f64> = values.iter().map(|v| v / WINSOR_SECS).collect();
    let shift = a1.iter().copied().fold(f64::INFINITY, f64::min);
    let a1: Vec<f64> = a1.iter().map(|a| a - shift).collect();
    // AᵀA = [[n, Σa], [Σa, Σa²]], Cholesky L = [[l11, 0], [l21, l22]].
    let (s1, s2) = a1.iter().fold((0.0, 0.0), |(s, q), a| (s + a, q + a * a));
    let l11 = (n as f64).sqrt();
    let l21 = s1 / l11;
    let l22sq = s2 - l21 * l21;
    if l11.is_nan() || l11 <= 0.0 || l22sq.is_nan() || l22sq <= 0.0 {
        return None;
    }
    let l22 = l22sq.sqrt();
    let aty = [
        y.iter().sum::<f64>(),
        a1.iter().zip(&y).map(|(a, y)| a * y).sum::<f64>(),
    ];
    let solve = |v: [f64; 2]| {
        // L w = v, then Lᵀ x = w.
        let w0 = v[0] / l11;
        let w1 = (v[1] - l21 * w0) / l22;
        let x1 = w1 / l22;
        let x0 = (w0 - l21 * x1) / l11;
        [x0, x1]
    };
    let mut z = vec![0.0; n];
    let mut u = vec![0.0; n];
    let mut x = [0.0; 2];
    for _ in 0..ADMM_ITERS {
        let mut rhs = aty;
        for k in 0..n {
            let r = z[k] - u[k];
            rhs[0] += r;
            rhs[1] += a1[k] * r;
        }
        x = solve(rhs);
        for k in 0..n {
            let d = x[0] + a1[k] * x[1] - y[k] + u[k];
            let d_inv = if d != 0.0 { 1.0 / d } else { 0.0 };
            let keep = (1.0 - (1.0 + 1.0 / ADMM_RHO) * d_inv.abs()).max(0.0);
            z[k] = ADMM_RHO / (1.0 + ADMM_RHO) * d + 1.0 / (1.0 + ADMM_RHO) * keep * d;
            u[k] = d - z[k];
        }
    }
    x[0] -= x[1] * shift;
    Some([x[0] * WINSOR_SECS, x[1]])
}

/// Steps 2 and 3 for one stream: the fitted correction per clock range,
/// applied to the stream's samples in order.
#[derive(Clone, Debug, Default)]
pub struct ClockMap {
    /// (c₀, c₁) per range.
    coefs: Vec<[f64; 2]>,
    /// Per range but the last: its last collection time and the next
    /// range's first.
    bounds: Vec<(f64, f64)>,
}

impl ClockMap {
    /// The map of a stream with these (collection time, offset) pairs; no
    /// pairs: no correction.
    pub fn fit(offsets: &[(f64, f64)]) -> Self {
        if offsets.is_empty() {
            return Self::default();
        }
        let (times, values): (Vec<f64>, Vec<f64>) = offsets.iter().copied().unzip();
        let ranges = reset_ranges(&times, &values);
        let coefs = ranges
            .iter()
            .map(|&(a, b)| {
                if a == b {
                    [values[a], 0.0]
                } else {
                    robust_fit(&times[a..=b], &values[a..=b]).unwrap_or([0.0, 0.0])
                }
            })
            .collect();
        let bounds = ranges
            .windows(2)
            .map(|w| (times[w[0].1], times[w[1].0]))
            .collect();
        Self { coefs, bounds }
    }

    /// Number of clock ranges (1 + resets); 0 without clock offsets.
    pub fn ranges(&self) -> usize {
        self.coefs.len()
    }

    /// The synced time of raw stamp `t`; `range` is the caller's cursor
    /// (start at 0), as stamps must come in file order.
    pub fn correct(&self, range: &mut usize, t: f64) -> f64 {
        let coefs = &self.coefs;
        if coefs.is_empty() || !t.is_finite() {
            // A non-finite stamp stays what it is, and moves no cursor.
            return t;
        }
        if coefs.len() > 1 {
            while let Some(&(end, next)) = self.bounds.get(*range) {
                if (t - end).abs() < (t - next).abs() {
                    break;
                }
                *range += 1;
            }
        }
        let [c0, c1] = coefs[(*range).min(coefs.len() - 1)];
        t + (c0 + c1 * t)
    }
}

/// One dejitter piece: its first sample index and the running
/// least-squares sums of its (index, stamp) pairs.
#[derive(Clone, Copy, Debug)]
struct Piece {
    start: u64,
    n: u64,
    mean_i: f64,
    mean_t: f64,
    m_ii: f64,
    c_it: f64,
}

impl Piece {
    fn new(start: u64) -> Self {
        Self {
            start,
            n: 0,
            mean_i: 0.0,
            mean_t: 0.0,
            m_ii: 0.0,
            c_it: 0.0,
        }
    }

    fn add(&mut self, i: u64, t: f64) {
        self.n += 1;
        let x = i as f64;
        let dx = x - self.mean_i;
        self.mean_i += dx / self.n as f64;
        let dt = t - self.mean_t;
        self.mean_t += dt / self.n as f64;
        self.m_ii += dx * (x - self.mean_i);
        self.c_it += dx * (t - self.mean_t);
    }

    fn line(&self, i: u64, t: f64) -> f64 {
        if self.n < 2 || self.m_ii <= 0.0 {
            return t;
        }
        self.mean_t + self.c_it / self.m_ii * (i as f64 - self.mean_i)
    }
}

/// Step 4: the dejitter pieces of one stream, learnt from its synced
/// stamps in a first pass and applied in a second.
#[derive(Clone, Debug, Default)]
pub struct Segments {
    pieces: Vec<Piece>,
    break_secs: f64,
    last: Option<f64>,
    /// Applying: the current piece.
    at: usize,
}

impl Segments {
    /// Pieces for a stream of nominal rate `srate_hz` (> 0).
    pub fn new(srate_hz: f64) -> Self {
        Self {
            pieces: Vec::new(),
            break_secs: JITTER_BREAK_SECS.max(JITTER_BREAK_SAMPLES / srate_hz),
            last: None,
            at: 0,
        }
    }

    /// Learns sample `i`'s synced stamp; `Err` when the pieces would
    /// exceed `max_pieces`.
    pub fn learn(&mut self, i: u64, t: f64, max_pieces: usize) -> Result<(), usize> {
        let new_piece = match self.last {
            None => true,
            // NaN steps never break, as in numpy.
            Some(p) => (t - p).abs() > self.break_secs,
        };
        if new_piece {
            if self.pieces.len() >= max_pieces {
                return Err(max_pieces);
            }
            self.pieces.push(Piece::new(i));
        }
        if let Some(p) = self.pieces.last_mut() {
            p.add(i, t);
        }
        self.last = Some(t);
        Ok(())
    }

    /// Number of pieces.
    pub fn len(&self) -> usize {
        self.pieces.len()
    }

    /// Whether nothing was learnt.
    pub fn is_empty(&self) -> bool {
        self.pieces.is_empty()
    }

    /// The dejittered stamp of sample `i` (synced stamp `t`); samples
    /// must come in order.
    pub fn apply(&mut self, i: u64, t: f64) -> f64 {
        while self
            .pieces
            .get(self.at + 1)
            .is_some_and(|next| next.start <= i)
        {
            self.at += 1;
        }
        self.pieces.get(self.at).map_or(t, |p| p.line(i, t))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robust_fit_recovers_a_line_and_ignores_one_outlier() {
        // offset = 0.25 s + 2e-6·t, one offset every 5 s, one wild value.
        let times: Vec<f64> = (0..40).map(|k| 1000.0 + 5.0 * k as f64).collect();
        let mut values: Vec<f64> = times.iter().map(|t| 0.25 + 2e-6 * t).collect();
        values[17] += 0.010;
        let [c0, c1] = robust_fit(&times, &values).unwrap();
        // Least squares would move the line by 10 ms / 40 = 250 µs at the
        // data's centre; the Huber loss (scale 0.1 ms) keeps it within a
        // few tens of µs.
        let at = |t: f64| c0 + c1 * t;
        let err = (at(1100.0) - (0.25 + 2e-6 * 1100.0)).abs();
        assert!(err < 3e-5, "{c0} {c1}: {err}");
        assert!((c1 - 2e-6).abs() < 1e-7, "{c1}");
        // Equal collection times: no fit.
        assert!(robust_fit(&[5.0, 5.0], &[0.1, 0.2]).is_none());
    }

    #[test]
    fn a_reset_splits_the_offsets() {
        // The sender restarts after 45 s and is back a minute later, its
        // clock 1000 s behind: a time step and an offset step both far
        // out of line.
        let mut times: Vec<f64> = (0..10).map(|k| 5.0 * k as f64).collect();
        let mut values = vec![0.5; 10];
        times.extend((0..10).map(|k| 105.0 + 5.0 * k as f64));
        values.extend(vec![1000.5; 10]);
        assert_eq!(reset_ranges(&times, &values), vec![(0, 9), (10, 19)]);
        let offsets: Vec<(f64, f64)> = times.into_iter().zip(values).collect();
        let map = ClockMap::fit(&offsets);
        let mut r = 0;
        assert!((map.correct(&mut r, 10.0) - 10.5).abs() < 1e-9);
        assert!((map.correct(&mut r, 120.0) - 1120.5).abs() < 1e-9);
    }

    #[test]
    fn dejitter_fits_each_piece_and_breaks_at_gaps() {
        let mut s = Segments::new(100.0);
        // 100 Hz with ±1 ms jitter, then a 10 s gap.
        let stamp = |i: u64| {
            let base = if i < 50 { 0.0 } else { 10.0 };
            base + i as f64 * 0.01 + if i.is_multiple_of(2) { 0.001 } else { -0.001 }
        };
        for i in 0..100 {
            s.learn(i, stamp(i), 10).unwrap();
        }
        assert_eq!(s.len(), 2);
        for i in 0..100 {
            let t = s.apply(i, stamp(i));
            let base = if i < 50 { 0.0 } else { 10.0 };
            assert!((t - (base + i as f64 * 0.01)).abs() < 1e-4, "{i} {t}");
        }
    }
}
