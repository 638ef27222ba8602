//! Straight seams in a glare veil: the one detector the glare tests share
//! (issue 39: the veil stopped at the kernel's square edge, a step of a few
//! code values along hundreds of pixels at the same columns).
//!
//! It compares two 8-bit frames of the same view, with glare (`on`) and
//! without (`off`). Their difference, in code values of the channel mean,
//! is the veil as displayed. A **seam** is a straight step in it: across
//! one boundary between two columns (or rows), at least
//! [`SeamRule::run_px`] consecutive pixels along it where the difference
//! jumps by at least [`SeamRule::step`] code values with the same sign.
//!
//! Two conditions keep the scene out of it. Where the veil is strong, the
//! tone curve passes the scene's own texture into the difference (at a
//! veil of 60 code values a scene step of 2 became a difference step of 3
//! on the Neon replay), so a step counts only where the veil on both sides
//! is weak, at most [`SeamRule::max_veil`] code values. And a step counts
//! only where the frame without glare is flat across the boundary, within
//! [`SeamRule::max_scene_step`] (a straight scene edge, the horizon, is
//! not a seam of the glare).

/// What counts as a seam (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeamRule {
    /// Smallest step of the difference across the boundary, code values.
    pub step: f64,
    /// Fewest consecutive pixels along the boundary.
    pub run_px: usize,
    /// Largest |difference| on either side of the step, code values.
    pub max_veil: f64,
    /// Largest step of the frame without glare across the boundary.
    pub max_scene_step: f64,
}

impl Default for SeamRule {
    /// Issue 39's seam: a step of ≥ 1.5 code values along ≥ 40 pixels,
    /// where the veil is at most 20 code values and the scene steps by at
    /// most 3.
    fn default() -> Self {
        Self {
            step: 1.5,
            run_px: 40,
            max_veil: 20.0,
            max_scene_step: 3.0,
        }
    }
}

/// Along which lines a seam runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeamAxis {
    /// Between columns `at` and `at + 1`, along rows `start..start + len`.
    Column,
    /// Between rows `at` and `at + 1`, along columns `start..start + len`.
    Row,
}

/// One seam: the longest run of steps along one boundary.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Seam {
    pub axis: SeamAxis,
    /// The boundary lies between `at` and `at + 1`.
    pub at: usize,
    /// First pixel of the run along the boundary.
    pub start: usize,
    /// Pixels in the run.
    pub len: usize,
    /// Mean step over the run, code values (signed: `on − off` after the
    /// boundary minus before it).
    pub mean_step: f64,
}

impl std::fmt::Display for Seam {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (what, along) = match self.axis {
            SeamAxis::Column => ("columns", "rows"),
            SeamAxis::Row => ("rows", "columns"),
        };
        write!(
            f,
            "step of {:+.2} code values between {what} {} and {} along {along} {}..{} ({} px)",
            self.mean_step,
            self.at,
            self.at + 1,
            self.start,
            self.start + self.len,
            self.len
        )
    }
}

/// An 8-bit frame: `width × height` pixels of `channels` interleaved
/// samples, row-major.
#[derive(Debug, Clone, Copy)]
pub struct Frame<'a> {
    pub pixels: &'a [u8],
    pub width: usize,
    pub height: usize,
    pub channels: usize,
}

impl Frame<'_> {
    /// Mean of the pixel's channels, code values.
    fn mean(&self, x: usize, y: usize) -> f64 {
        let i = (y * self.width + x) * self.channels;
        let p = &self.pixels[i..i + self.channels];
        p.iter().map(|&v| f64::from(v)).sum::<f64>() / self.channels as f64
    }

    fn check(&self, what: &str) {
        assert!(self.channels > 0, "{what}: no channels");
        assert_eq!(
            self.pixels.len(),
            self.width * self.height * self.channels,
            "{what}: {} samples for {}x{}x{}",
            self.pixels.len(),
            self.width,
            self.height,
            self.channels
        );
    }
}

/// Every seam of the glare veil `on − off` under `rule`: per boundary
/// (between two columns, or two rows), its longest run of steps, when that
/// run is at least `rule.run_px` long. Panics when the frames' sizes differ.
pub fn find_seams(on: Frame<'_>, off: Frame<'_>, rule: SeamRule) -> Vec<Seam> {
    on.check("on");
    off.check("off");
    assert_eq!(
        (on.width, on.height),
        (off.width, off.height),
        "frames of different sizes"
    );
    let (w, h) = (on.width, on.height);
    let diff: Vec<f64> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| on.mean(x, y) - off.mean(x, y))
        .collect();
    let scene: Vec<f64> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| off.mean(x, y))
        .collect();
    // The signed step from pixel i to pixel j, or 0 where it does not count.
    let step = |i: usize, j: usize| -> f64 {
        let s = diff[j] - diff[i];
        let counts = s.abs() >= rule.step
            && diff[i].abs().max(diff[j].abs()) <= rule.max_veil
            && (scene[j] - scene[i]).abs() <= rule.max_scene_step;
        if counts { s } else { 0.0 }
    };
    let mut seams = Vec::new();
    // Boundaries between columns x and x + 1, along the rows.
    for x in 0..w.saturating_sub(1) {
        let steps = (0..h).map(|y| step(y * w + x, y * w + x + 1));
        seams.extend(
            longest_run(steps, rule.run_px).map(|(start, len, mean_step)| Seam {
                axis: SeamAxis::Column,
                at: x,
                start,
                len,
                mean_step,
            }),
        );
    }
    // Boundaries between rows y and y + 1, along the columns.
    for y in 0..h.saturating_sub(1) {
        let steps = (0..w).map(|x| step(y * w + x, (y + 1) * w + x));
        seams.extend(
            longest_run(steps, rule.run_px).map(|(start, len, mean_step)| Seam {
                axis: SeamAxis::Row,
                at: y,
                start,
                len,
                mean_step,
            }),
        );
    }
    seams
}

/// The longest run of nonzero steps of one sign: `(start, len, mean)`, if
/// it is at least `min_len` long.
fn longest_run(steps: impl Iterator<Item = f64>, min_len: usize) -> Option<(usize, usize, f64)> {
    let mut best: Option<(usize, usize, f64)> = None;
    let (mut start, mut len, mut sum, mut sign) = (0usize, 0usize, 0.0f64, 0.0f64);
    for (i, s) in steps.enumerate() {
        if s != 0.0 && s.signum() == sign {
            len += 1;
            sum += s;
        } else if s != 0.0 {
            (start, len, sum, sign) = (i, 1, s, s.signum());
        } else {
            (len, sign) = (0, 0.0);
        }
        if len > 0 && best.is_none_or(|b| len > b.1) {
            best = Some((start, len, sum / len as f64));
        }
    }
    best.filter(|b| b.1 >= min_len.max(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 160;
    const H: usize = 120;

    /// A dark, textured scene: code values 30..=32 in a fixed pattern
    /// (neighbours differ by at most 2), with a bright horizontal band (a
    /// straight scene edge) at rows 20..30.
    fn scene() -> Vec<u8> {
        let mut px = Vec::with_capacity(W * H * 3);
        for y in 0..H {
            for x in 0..W {
                let v = if (20..30).contains(&y) {
                    200
                } else {
                    30 + ((x / 3 + y / 2) % 3) as u8
                };
                px.extend_from_slice(&[v, v, v]);
            }
        }
        px
    }

    /// `base` plus a veil of `veil(x, y)` code values (saturating).
    fn add(base: &[u8], veil: impl Fn(usize, usize) -> f64) -> Vec<u8> {
        let mut out = base.to_vec();
        for y in 0..H {
            for x in 0..W {
                let v = veil(x, y);
                for c in 0..3 {
                    let i = (y * W + x) * 3 + c;
                    out[i] = (f64::from(base[i]) + v).round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        out
    }

    fn frame(px: &[u8]) -> Frame<'_> {
        Frame {
            pixels: px,
            width: W,
            height: H,
            channels: 3,
        }
    }

    /// A smooth veil around a source at (80, 60) of ~18 code values at its
    /// centre: exp(−d/25), as a glare veil falls with the distance.
    fn smooth(x: usize, y: usize) -> f64 {
        let d = (x as f64 - 80.0).hypot(y as f64 - 60.0);
        18.0 * (-d / 25.0).exp()
    }

    #[test]
    fn a_smooth_veil_has_no_seam() {
        let off = scene();
        let on = add(&off, smooth);
        let seams = find_seams(frame(&on), frame(&off), SeamRule::default());
        assert!(seams.is_empty(), "{:?}", seams.first());
    }

    #[test]
    fn a_veil_cut_at_a_column_and_a_row_has_seams_there() {
        // The same veil, cut where a square kernel field would end: 0 left
        // of column 40 and below row 100, so the steps are 3–6 code values.
        let off = scene();
        let on = add(&off, |x, y| {
            if x < 40 || y >= 100 {
                0.0
            } else {
                3.0 + smooth(x, y)
            }
        });
        let seams = find_seams(frame(&on), frame(&off), SeamRule::default());
        let col = seams
            .iter()
            .find(|s| s.axis == SeamAxis::Column && s.at == 39)
            .unwrap_or_else(|| panic!("no seam at column 39/40: {seams:?}"));
        // Along all of rows 0..100 (the band is horizontal: both sides of
        // the column boundary lie in it or out of it together).
        assert_eq!((col.start, col.len), (0, 100), "{col}");
        assert!(col.mean_step >= 3.0, "{col}");
        let row = seams
            .iter()
            .find(|s| s.axis == SeamAxis::Row && s.at == 99)
            .unwrap_or_else(|| panic!("no seam at row 99/100: {seams:?}"));
        assert_eq!((row.start, row.len), (40, 120), "{row}");
        assert!(row.mean_step <= -3.0, "{row}");
        println!("{col}\n{row}");
    }

    #[test]
    fn a_straight_scene_edge_under_a_veil_is_not_a_seam() {
        // The bright band's edges are straight and the tone of the frame
        // with glare differs there (the band saturates sooner): not a seam
        // of the glare, the scene steps by 170 code values across them.
        let off = scene();
        let on = add(&off, |x, y| {
            let v = smooth(x, y) + 4.0;
            if (20..30).contains(&y) { 2.0 * v } else { v }
        });
        let seams = find_seams(frame(&on), frame(&off), SeamRule::default());
        assert!(seams.is_empty(), "{:?}", seams.first());
    }

    #[test]
    fn a_short_or_weak_step_is_not_a_seam() {
        let off = scene();
        // 3 code values over a 30 × 30 square (edges of 30 px); 1 code
        // value right of column 40 along every row.
        let short = add(&off, |x, y| {
            if (40..70).contains(&x) && (50..80).contains(&y) {
                3.0
            } else {
                0.0
            }
        });
        let weak = add(&off, |x, _| if x >= 40 { 1.0 } else { 0.0 });
        for on in [short, weak] {
            let seams = find_seams(frame(&on), frame(&off), SeamRule::default());
            assert!(seams.is_empty(), "{:?}", seams.first());
        }
    }
}
