//! Full-field stray light: the CIE 146:2002 veil of every pixel of the view
//! onto every other pixel at their angle, out to [`FAR_MAX_DEG`], on a
//! coarse angular grid, joined to the windowed kernel of [`crate::glare`]
//! without a seam (issue 46; the bookkeeping is in docs/perception.md,
//! "Energy bookkeeping").
//!
//! # The one rule ([`FarSplit`])
//!
//! The window kernel `K` ([`crate::psf`]) holds the wave-optics near field
//! and CIE 146 tapered by `t(θ)`: 1 to 0.6 of the kernel's radius (12° at
//! the default ±20° field), a smoothstep to 0 at the radius. A source pixel
//! of weight `w` ([`crate::glare::GlareWindow`]: 1 near the gaze, 0 beyond
//! `full_weight_deg + 3σ`) glares through `K` with `w` of its light. The
//! far field adds, for every source pixel, at the angle θ between source and
//! target (cos θ: the illuminance on the target's line of sight, as
//! `gazelight glare` and CIE 146 count it):
//!
//! ```text
//! tail(θ) = CIE146(θ) · (1 − t(τ)) · cos θ            every source
//! near(θ) = CIE146(θ) · t(τ) · h(θ) · cos θ           the (1 − w) share
//! ```
//!
//! with τ the kernel's own measure of θ ([`FarSplit::kernel_angle_deg`]:
//! `tan θ` in a rectilinear view, whose kernel runs in the plane at the
//! centre's `deg_per_px`; θ in a uniform one), so that the kernel's taper
//! and the tail meet where the kernel puts them;
//! for 0 < θ ≤ 90°, with `h` a smoothstep from 0 at [`NEAR_START_DEG`] to 1
//! at [`NEAR_FULL_DEG`] (the coarse grid cannot hold the steep veil next
//! to a source away from the gaze; that light stays in its pixel). A source
//! inside the window so gets `K + tail` = the kernel to its taper, CIE 146
//! beyond it; a source outside gets CIE 146 from [`NEAR_FULL_DEG`] out.
//! Energy: `E_tail = 2π ∫ tail(θ) sin θ dθ` and `E_near` likewise
//! ([`FarSplit::tail_energy`], [`FarSplit::near_energy`]) leave the source
//! pixel: its kept light is `(1 − w)(1 − E_near) − E_tail` (negative near
//! the gaze, where `K`'s core, tens of per cent, gives it back), so a
//! source's light adds up to 1 at every `w`:
//! `(1 − w)(1 − E_near) − E_tail + w + E_tail + (1 − w) E_near = 1`. Light
//! scattered outside the view is lost, as the window's is beyond the image.
//!
//! # On the frame ([`FarField`])
//!
//! The sanitised frame is summed over blocks of about [`FAR_BLOCK_DEG`]
//! (flux `Σ L · Ω_px`, `Ω_px` the pixel's solid angle at the block's
//! centre), the weighted sources `w · L` over the same blocks (from the
//! glare window's own weighted plane), and both are spread bilinearly onto a
//! grid of [`FAR_CELL_DEG`] cells in the azimuthal equidistant projection
//! around the view's axis (angles from the axis exact, others within a few
//! per cent over a 100° view), convolved there with `tail` and `near` by FFT
//! (linear, not circular: the grid is at least the view plus the kernel's
//! reach), read back bilinearly at the block centres and interpolated
//! bilinearly to every pixel. [`far_veil_reference`] is the plain f64 sum
//! over every pair of pixels at their exact angle, for the tests.
//! Everything is allocated when the geometry is set: a frame allocates
//! nothing.

use std::f64::consts::TAU;
use std::ops::Range;
use std::sync::Arc;

use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

use crate::pipeline::sanitize;
use crate::pooling::PlaneAngles;
use crate::psf::FIELD_TAPER_START;
use crate::simd::Simd;
use crate::stray_light::cie146_veil_per_sr;
use crate::{RgbImage, VisionError};

/// Size of one cell of the far field's angular grid, degrees.
pub const FAR_CELL_DEG: f64 = 2.0;
/// Size of one block of display pixels summed as one source, degrees at
/// the view's centre.
pub const FAR_BLOCK_DEG: f64 = 1.0;
/// The far field reaches this far from a source, degrees (CIE 146:2002
/// holds to 100°; light beyond 90° would land behind the line of sight).
pub const FAR_MAX_DEG: f64 = 90.0;
/// A source outside the window scatters from here (`h` = 0), degrees.
pub const NEAR_START_DEG: f64 = 1.5 * FAR_CELL_DEG;
/// … with its full CIE 146 veil from here (`h` = 1), degrees.
pub const NEAR_FULL_DEG: f64 = 3.0 * FAR_CELL_DEG;

type C32 = Complex<f32>;
const ZERO: C32 = Complex::new(0.0, 0.0);

#[inline]
fn smoothstep(x: f64) -> f64 {
    let s = x.clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

/// The split of the CIE 146 veil between the window kernel and the far
/// field (module docs): the one rule, in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FarSplit {
    /// Observer age, years (CIE 146).
    pub age_years: f64,
    /// Ocular pigmentation (CIE 146: 0 very dark … 1.2 very light).
    pub pigmentation: f64,
    /// The window kernel's radius, degrees: its taper `t` is 1 to
    /// [`FIELD_TAPER_START`] of it and falls by a smoothstep to 0 here.
    pub kernel_radius_deg: f64,
    /// The window kernel measures angles in a rectilinear plane
    /// (`deg_per_px` at the view's centre): a pair θ apart on the sphere
    /// lies `tan θ` (in degrees) apart in the kernel's measure around the
    /// view's centre, so its taper is taken there ([`FarField::new`] sets
    /// it from the view's geometry). Without it (a uniform view) the two
    /// measures agree.
    pub planar_taper: bool,
}

impl FarSplit {
    /// The split for a kernel of `kernel_radius_deg` and the observer.
    pub fn new(age_years: f64, pigmentation: f64, kernel_radius_deg: f64) -> Self {
        Self {
            age_years,
            pigmentation,
            kernel_radius_deg,
            planar_taper: false,
        }
    }

    /// The kernel's own measure of the angle θ between two directions
    /// (degrees): `tan θ` in a rectilinear plane, θ otherwise.
    pub fn kernel_angle_deg(&self, theta_deg: f64) -> f64 {
        if self.planar_taper && theta_deg < 89.0 {
            theta_deg.to_radians().tan().to_degrees()
        } else if self.planar_taper {
            f64::INFINITY
        } else {
            theta_deg
        }
    }

    /// The window kernel's taper `t(θ)` ([`crate::psf::field_taper`] in
    /// degrees).
    pub fn window_taper(&self, theta_deg: f64) -> f64 {
        let start = FIELD_TAPER_START * self.kernel_radius_deg;
        if theta_deg <= start {
            return 1.0;
        }
        1.0 - smoothstep((theta_deg - start) / (self.kernel_radius_deg - start))
    }

    /// `h(θ)`: 0 to [`NEAR_START_DEG`], smoothstep to 1 at [`NEAR_FULL_DEG`].
    pub fn near_fade(theta_deg: f64) -> f64 {
        smoothstep((theta_deg - NEAR_START_DEG) / (NEAR_FULL_DEG - NEAR_START_DEG))
    }

    fn cie_cos(&self, theta_deg: f64) -> f64 {
        if !(theta_deg > 0.0 && theta_deg <= FAR_MAX_DEG) {
            return 0.0;
        }
        cie146_veil_per_sr(theta_deg, self.age_years, self.pigmentation)
            * theta_deg.to_radians().cos()
    }

    /// `tail(θ)`, sr⁻¹: what every source adds beyond the window kernel.
    pub fn tail_per_sr(&self, theta_deg: f64) -> f64 {
        let t = self.window_taper(self.kernel_angle_deg(theta_deg));
        if t >= 1.0 {
            return 0.0;
        }
        self.cie_cos(theta_deg) * (1.0 - t)
    }

    /// `near(θ)`, sr⁻¹: what the `1 − w` share of a source adds.
    pub fn near_per_sr(&self, theta_deg: f64) -> f64 {
        let h = Self::near_fade(theta_deg);
        if h <= 0.0 {
            return 0.0;
        }
        self.cie_cos(theta_deg) * self.window_taper(self.kernel_angle_deg(theta_deg)) * h
    }

    /// `tail` and `near` (sr⁻¹, f32) at the grid offset (`dx`, `dy`)
    /// cells: the far field's kernels as the CPU and GPU grids sample them.
    /// The tail is sharpened by one Van Cittert step against the grid's own
    /// blur, `2·tail − B∗tail` with `B` the cubic B-spline at the cells
    /// (weights 1/6, 4/6, 1/6 per axis: the bilinear splat and read-back
    /// together, averaged over where a source falls in its cell): the tail
    /// rises steeply from the window kernel's taper (12°) to its radius
    /// (20°) and the blur took up to 6 % off its peak at 17–19°. The sum
    /// over the grid, the tail's light, is unchanged.
    pub fn cell_kernels(&self, dx_cells: f64, dy_cells: f64) -> (f32, f32) {
        let tail = |x: f64, y: f64| self.tail_per_sr(x.hypot(y) * FAR_CELL_DEG);
        // Cubic B-spline at integer offsets (de Boor, A Practical Guide to
        // Splines, ch. IX).
        const B: [(f64, f64); 3] = [(-1.0, 1.0 / 6.0), (0.0, 4.0 / 6.0), (1.0, 1.0 / 6.0)];
        let blurred: f64 = B
            .iter()
            .flat_map(|&(i, wi)| B.iter().map(move |&(j, wj)| (i, j, wi * wj)))
            .map(|(i, j, w)| w * tail(dx_cells + i, dy_cells + j))
            .sum();
        let sharp = 2.0 * tail(dx_cells, dy_cells) - blurred;
        let th = dx_cells.hypot(dy_cells) * FAR_CELL_DEG;
        (sharp as f32, self.near_per_sr(th) as f32)
    }

    /// `2π ∫ f(θ) sin θ dθ` from 0 to [`FAR_MAX_DEG`] (midpoint rule,
    /// 0.001° steps).
    fn energy(f: impl Fn(f64) -> f64) -> f64 {
        let n = (FAR_MAX_DEG * 1000.0) as usize;
        let h = FAR_MAX_DEG / n as f64;
        (0..n)
            .map(|i| {
                let t = (i as f64 + 0.5) * h;
                f(t) * t.to_radians().sin()
            })
            .sum::<f64>()
            * h.to_radians()
            * TAU
    }

    /// `E_tail`: the share of a source's light in `tail`.
    pub fn tail_energy(&self) -> f64 {
        Self::energy(|t| self.tail_per_sr(t))
    }

    /// `E_near`: the share of a source's light in `near`.
    pub fn near_energy(&self) -> f64 {
        Self::energy(|t| self.near_per_sr(t))
    }
}

/// The direction of plane point (`x`, `y`) (pixels, y down) of a view of
/// `width × height` pixels, as azimuthal-equidistant coordinates around the
/// view's axis (degrees, x right, y down), and the solid angle of one pixel
/// there (sr). [`PlaneAngles::Uniform`] is taken as angles from the
/// centre, `deg_per_px` per pixel (the glare window's own geometry).
pub fn plane_direction(
    angles: PlaneAngles,
    width: f64,
    height: f64,
    x: f64,
    y: f64,
) -> ([f64; 2], f64) {
    match angles {
        PlaneAngles::Uniform { deg_per_px } => {
            let r = deg_per_px.to_radians();
            let (ax, ay) = (
                (x - 0.5 * width) * deg_per_px,
                (y - 0.5 * height) * deg_per_px,
            );
            // Ω of a pixel at angle θ from the axis in the equidistant
            // projection: (Δ rad)² · sin θ / θ.
            let th = ax.hypot(ay).to_radians();
            let jac = if th > 1e-9 { th.sin() / th } else { 1.0 };
            ([ax, ay], r * r * jac)
        }
        PlaneAngles::Rectilinear {
            tan_lrud: [l, r, u, d],
            extent_px,
        } => {
            let (dtx, dty) = ((r - l) / extent_px[0], (u - d) / extent_px[1]);
            let tx = l + x * dtx;
            let ty = u - y * dty;
            let rho = tx.hypot(ty);
            let th = rho.atan().to_degrees();
            let (cx, cy) = if rho > 1e-12 {
                (tx / rho, -ty / rho)
            } else {
                (0.0, 0.0)
            };
            let q = 1.0 + tx * tx + ty * ty;
            ([th * cx, th * cy], dtx * dty / (q * q.sqrt()))
        }
    }
}

/// The unit vector of azimuthal-equidistant coordinates `ae` (degrees).
fn ae_vector(ae: [f64; 2]) -> [f64; 3] {
    let th = ae[0].hypot(ae[1]).to_radians();
    if th < 1e-15 {
        return [0.0, 0.0, 1.0];
    }
    let s = th.sin() / th;
    [ae[0].to_radians() * s, ae[1].to_radians() * s, th.cos()]
}

/// The far field in f64, every pixel onto every pixel at their exact angle:
/// `veil(t) = Σ_s L_s Ω_s [tail(θ_st) + (1 − w_s) near(θ_st)]`, cd/m² per
/// channel, and the light each pixel keeps, `L (1 − E_tail − (1 − w) E_near)`
/// is left to the caller. `weight(x, y)` is the window weight `w` of a
/// source pixel. O(pixels²): for small test frames.
pub fn far_veil_reference(
    img: &RgbImage,
    angles: PlaneAngles,
    split: &FarSplit,
    weight: impl Fn(usize, usize) -> f64,
) -> Vec<[f64; 3]> {
    let (w, h) = (img.width, img.height);
    let px: Vec<([f64; 3], f64, [f64; 3], f64)> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (ae, omega) =
                plane_direction(angles, w as f64, h as f64, x as f64 + 0.5, y as f64 + 0.5);
            let l = img.pixels[i].map(|v| f64::from(sanitize(v)));
            (ae_vector(ae), omega, l, weight(x, y))
        })
        .collect();
    px.par_iter()
        .map(|(vt, _, _, _)| {
            let mut acc = [0.0f64; 3];
            for (vs, om, l, ws) in &px {
                let c = (vt[0] * vs[0] + vt[1] * vs[1] + vt[2] * vs[2]).clamp(-1.0, 1.0);
                let th = c.acos().to_degrees();
                let k = split.tail_per_sr(th) + (1.0 - ws) * split.near_per_sr(th);
                if k > 0.0 {
                    for ch in 0..3 {
                        acc[ch] += l[ch] * om * k;
                    }
                }
            }
            acc
        })
        .collect()
}

/// Row FFTs of `data` (rows of `n`) over the workers' scratch buffers.
fn rows_fft(fft: &Arc<dyn Fft<f32>>, data: &mut [C32], n: usize, scratch: &mut [Vec<C32>]) {
    let rows = data.len() / n;
    if rows == 0 {
        return;
    }
    let per = rows.div_ceil(scratch.len()).max(1);
    data.par_chunks_mut(per * n)
        .zip(scratch.par_iter_mut())
        .for_each(|(chunk, s)| fft.process_with_scratch(chunk, s));
}

/// `dst[x][y] = src[y][x]`, `n × n`.
fn transpose(src: &[C32], dst: &mut [C32], n: usize) {
    dst.par_chunks_mut(n).enumerate().for_each(|(x, row)| {
        for (y, d) in row.iter_mut().enumerate() {
            *d = src[y * n + x];
        }
    });
}

/// The full-field stray light on a frame (module docs).
pub struct FarField {
    split: FarSplit,
    e_tail: f32,
    e_near: f32,
    width: usize,
    height: usize,
    /// Display block, pixels per side; blocks per row and column.
    block_px: usize,
    bw: usize,
    bh: usize,
    /// Per block: Ω of one pixel at its centre (sr), and its grid cell
    /// (top-left of the bilinear four) with the fractions.
    block_omega: Vec<f32>,
    block_cell: Vec<(u32, f32, f32)>,
    /// Per display column: the block column left of it and the fraction.
    xhat: Vec<(u32, f32)>,
    /// Grid: `n × n` cells, the view within the first `g` rows/columns.
    n: usize,
    g: usize,
    /// Cells per side a linear convolution needs (`g` + the kernel's
    /// reach): any FFT size from here on gives the same veil.
    needed: usize,
    fwd: Arc<dyn Fft<f32>>,
    inv: Arc<dyn Fft<f32>>,
    scratch: Vec<Vec<C32>>,
    tmp: Vec<C32>,
    /// A_R + i A_G, B_R + i B_G, A_B + i B_B (A: every source, B: the
    /// `1 − w` share), then the outputs.
    za1: Vec<C32>,
    zb1: Vec<C32>,
    za2: Vec<C32>,
    /// Spectra of `tail` and `near` on the grid (real: the kernels are even).
    kt: Vec<f32>,
    kn: Vec<f32>,
    /// Block sums of the sanitised frame and of the weighted sources.
    sums: Vec<[f32; 3]>,
    wsums: Vec<[f32; 3]>,
    /// The veil at each block centre, cd/m².
    veil: Vec<[f32; 3]>,
    /// The veil interpolated along x to every column, per block row:
    /// `bh` rows of `width × 3`.
    hrows: Vec<f32>,
    /// Whether [`FarField::prepare`] left a veil to blend.
    ready: bool,
}

/// The block sums of one frame's light ([`FarField::frame_parts`]): taken
/// by [`BlockSums::take`] while the glare window prepares its own part
/// ([`WeightedSums`]) on the other workers.
pub(crate) struct BlockSums<'a> {
    width: usize,
    block_px: usize,
    bw: usize,
    sums: &'a mut [[f32; 3]],
    /// Per block row, `width × 3` accumulators (the far field's `hrows`,
    /// free until [`FarField::compute`]).
    acc: &'a mut [f32],
}

impl BlockSums<'_> {
    /// Sums the sanitised frame `img` (of the far field's size) over the
    /// blocks, block rows in parallel: each block row's pixel rows are
    /// first added column by column into its row of accumulators (one
    /// vector add per sample), then that row is summed over the blocks.
    pub(crate) fn take(&mut self, img: &RgbImage) {
        let (w, bp, bw) = (self.width, self.block_px, self.bw);
        let simd = Simd::host();
        img.pixels
            .par_chunks(w * bp)
            .zip(self.sums.par_chunks_mut(bw))
            .zip(self.acc.par_chunks_mut(w * 3))
            .for_each(|((rows, sums), acc)| {
                // Vectorised for the CPU's tier (the same adds, in the
                // same order: the same bits).
                simd.compiled(
                    #[inline(always)]
                    || {
                        acc.fill(0.0);
                        for row in rows.chunks_exact(w) {
                            for (a, &v) in acc.iter_mut().zip(row.as_flattened()) {
                                *a += sanitize(v);
                            }
                        }
                        for (blk, s) in acc.chunks(bp * 3).zip(sums.iter_mut()) {
                            let mut t = [0.0f32; 3];
                            for p in blk.chunks_exact(3) {
                                t[0] += p[0];
                                t[1] += p[1];
                                t[2] += p[2];
                            }
                            *s = t;
                        }
                    },
                )
            });
    }
}

/// The block sums of one frame's weighted sources `w · L`
/// ([`FarField::frame_parts`]), which the glare window adds from its own
/// weighted plane ([`WeightedSums::add_rows`]).
pub(crate) struct WeightedSums<'a> {
    block_px: usize,
    bw: usize,
    bh: usize,
    wsums: &'a mut [[f32; 3]],
}

impl WeightedSums<'_> {
    /// Display block size, pixels.
    pub(crate) fn block_px(&self) -> usize {
        self.block_px
    }

    /// One block row at a time, in parallel: `f(y, row)` adds row `y`'s
    /// weighted sources to `row` (the block row's sums); rows `y0..y1`.
    pub(crate) fn add_rows(
        &mut self,
        y0: usize,
        y1: usize,
        f: impl Fn(usize, &mut [[f32; 3]]) + Sync,
    ) {
        let (bp, bw) = (self.block_px, self.bw);
        let (j0, j1) = (y0 / bp, y1.div_ceil(bp).min(self.bh));
        if j0 >= j1 {
            return;
        }
        self.wsums[j0 * bw..j1 * bw]
            .par_chunks_mut(bw)
            .enumerate()
            .for_each(|(k, row)| {
                let j = j0 + k;
                for y in (j * bp).max(y0)..((j + 1) * bp).min(y1) {
                    f(y, row);
                }
            });
    }
}

impl FarField {
    /// A far field for `width × height` frames of the geometry `angles`.
    pub fn new(
        split: FarSplit,
        width: usize,
        height: usize,
        angles: PlaneAngles,
    ) -> Result<Self, VisionError> {
        if width == 0 || height == 0 {
            return Err(VisionError::invalid(
                "far field frame size",
                format!("{width}x{height}"),
                "non-zero",
            ));
        }
        if !(split.kernel_radius_deg.is_finite() && split.kernel_radius_deg > 0.0) {
            return Err(VisionError::invalid(
                "far field kernel radius",
                split.kernel_radius_deg,
                "a finite angle > 0",
            ));
        }
        angles.validate()?;
        let split = FarSplit {
            planar_taper: matches!(angles, PlaneAngles::Rectilinear { .. }),
            ..split
        };
        let (wf, hf) = (width as f64, height as f64);
        // Degrees per pixel at the centre.
        let centre = plane_direction(angles, wf, hf, 0.5 * wf, 0.5 * hf).0;
        let next = plane_direction(angles, wf, hf, 0.5 * wf + 1.0, 0.5 * hf).0;
        let dpp = (next[0] - centre[0]).hypot(next[1] - centre[1]).max(1e-9);
        let block_px = ((FAR_BLOCK_DEG / dpp).round() as usize).clamp(1, width.max(height));
        let (bw, bh) = (width.div_ceil(block_px), height.div_ceil(block_px));
        let mut ae = Vec::with_capacity(bw * bh);
        let mut block_omega = Vec::with_capacity(bw * bh);
        for j in 0..bh {
            for i in 0..bw {
                // Centre of the block's pixels (edge blocks are partial).
                let x0 = (i * block_px) as f64;
                let x1 = ((i + 1) * block_px).min(width) as f64;
                let y0 = (j * block_px) as f64;
                let y1 = ((j + 1) * block_px).min(height) as f64;
                let (a, om) = plane_direction(angles, wf, hf, 0.5 * (x0 + x1), 0.5 * (y0 + y1));
                ae.push(a);
                block_omega.push(om as f32);
            }
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for a in &ae {
            for k in 0..2 {
                lo[k] = lo[k].min(a[k]);
                hi[k] = hi[k].max(a[k]);
            }
        }
        // One cell of margin each side for the bilinear four.
        let origin = [lo[0] - FAR_CELL_DEG, lo[1] - FAR_CELL_DEG];
        let g = (((hi[0] - lo[0]).max(hi[1] - lo[1]) / FAR_CELL_DEG).ceil() as usize) + 3;
        let reach = ((FAR_MAX_DEG / FAR_CELL_DEG).ceil() as usize + 1).min(g);
        let needed = g + reach;
        let n = crate::glare::good_fft_size(needed);
        let block_cell = ae
            .iter()
            .map(|a| {
                let gx = (a[0] - origin[0]) / FAR_CELL_DEG;
                let gy = (a[1] - origin[1]) / FAR_CELL_DEG;
                let (ix, iy) = (gx.floor(), gy.floor());
                (
                    (iy as usize * n + ix as usize) as u32,
                    (gx - ix) as f32,
                    (gy - iy) as f32,
                )
            })
            .collect();
        let xhat = (0..width)
            .map(|x| {
                let b = ((x as f64 + 0.5) / block_px as f64 - 0.5).clamp(0.0, (bw - 1) as f64);
                let i0 = (b.floor() as usize).min(bw.saturating_sub(2));
                ((i0) as u32, (b - i0 as f64) as f32)
            })
            .collect();
        let mut planner = FftPlanner::<f32>::new();
        let fwd = planner.plan_fft_forward(n);
        let inv = planner.plan_fft_inverse(n);
        let workers = rayon::current_num_threads().clamp(1, 8);
        let scratch_len = fwd
            .get_inplace_scratch_len()
            .max(inv.get_inplace_scratch_len());
        let mut far = Self {
            split,
            e_tail: split.tail_energy() as f32,
            e_near: split.near_energy() as f32,
            width,
            height,
            block_px,
            bw,
            bh,
            block_omega,
            block_cell,
            xhat,
            n,
            g,
            needed,
            fwd,
            inv,
            scratch: (0..workers).map(|_| vec![ZERO; scratch_len]).collect(),
            tmp: vec![ZERO; n * n],
            za1: vec![ZERO; n * n],
            zb1: vec![ZERO; n * n],
            za2: vec![ZERO; n * n],
            kt: vec![0.0; n * n],
            kn: vec![0.0; n * n],
            sums: vec![[0.0; 3]; bw * bh],
            wsums: vec![[0.0; 3]; bw * bh],
            veil: vec![[0.0; 3]; bw * bh],
            hrows: vec![0.0; bh * width * 3],
            ready: false,
        };
        // Kernel spectra: the kernels sampled at each cell offset (wrapped).
        for k in 0..2 {
            let split = far.split;
            for iy in 0..n {
                let dy = if iy <= n / 2 {
                    iy as f64
                } else {
                    iy as f64 - n as f64
                };
                for ix in 0..n {
                    let dx = if ix <= n / 2 {
                        ix as f64
                    } else {
                        ix as f64 - n as f64
                    };
                    let (t, q) = split.cell_kernels(dx, dy);
                    let v = if k == 0 { t } else { q };
                    far.za1[iy * n + ix] = Complex::new(v, 0.0);
                }
            }
            far.fft2_forward(0, n);
            let dst = if k == 0 { &mut far.kt } else { &mut far.kn };
            for (d, s) in dst.iter_mut().zip(&far.za1) {
                *d = s.re;
            }
        }
        Ok(far)
    }

    /// The split this far field applies.
    pub fn split(&self) -> FarSplit {
        self.split
    }

    /// `E_tail` and `E_near` ([`FarSplit`]).
    pub fn energies(&self) -> (f32, f32) {
        (self.e_tail, self.e_near)
    }

    /// Display block size, pixels.
    pub fn block_px(&self) -> usize {
        self.block_px
    }

    /// The angular grid's FFT size, cells per side.
    pub fn grid_size(&self) -> usize {
        self.n
    }

    /// The frame size it was built for.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Blocks per row and per column.
    pub fn blocks(&self) -> (usize, usize) {
        (self.bw, self.bh)
    }

    /// Grid cells per side a linear convolution needs: an FFT of any size
    /// from here on gives the same veil (the GPU twin takes the next power
    /// of two).
    pub fn grid_needed(&self) -> usize {
        self.needed
    }

    /// Per block (row-major): Ω of one of its pixels (sr), the grid cell
    /// (column, row) of the top-left of its bilinear four and the fractions
    /// toward the next column and row.
    pub fn block_cells(&self) -> impl Iterator<Item = (f32, [usize; 2], f32, f32)> + '_ {
        let n = self.n;
        self.block_omega
            .iter()
            .zip(&self.block_cell)
            .map(move |(&om, &(c, fx, fy))| (om, [c as usize % n, c as usize / n], fx, fy))
    }

    /// Per display column: the block column left of its centre and the
    /// fraction toward the next.
    pub fn column_hat(&self) -> &[(u32, f32)] {
        &self.xhat
    }

    /// Display row `y`'s two block rows and the fraction toward the second.
    pub fn row_hat(&self, y: usize) -> (usize, usize, f32) {
        let bp = self.block_px as f64;
        let b = ((y as f64 + 0.5) / bp - 0.5).clamp(0.0, (self.bh - 1) as f64);
        let j0 = (b.floor() as usize).min(self.bh.saturating_sub(2));
        let fy = (b - j0 as f64) as f32;
        (j0, (j0 + 1).min(self.bh - 1), fy)
    }

    /// Forward 2-D FFT of `za1` (rows `0..rows_in` non-zero); the
    /// spectrum, transposed, back in `za1`.
    fn fft2_forward(&mut self, which: usize, rows_in: usize) {
        let n = self.n;
        let buf = match which {
            0 => &mut self.za1,
            1 => &mut self.zb1,
            _ => &mut self.za2,
        };
        rows_fft(&self.fwd, &mut buf[..rows_in * n], n, &mut self.scratch);
        transpose(buf, &mut self.tmp, n);
        rows_fft(&self.fwd, &mut self.tmp, n, &mut self.scratch);
        std::mem::swap(buf, &mut self.tmp);
    }

    /// Inverse of [`FarField::fft2_forward`] (unnormalised); rows
    /// `0..rows_out` of the result are right.
    fn fft2_inverse(&mut self, which: usize, rows_out: usize) {
        let n = self.n;
        let buf = if which == 0 {
            &mut self.za1
        } else {
            &mut self.zb1
        };
        rows_fft(&self.inv, buf, n, &mut self.scratch);
        transpose(buf, &mut self.tmp, n);
        rows_fft(
            &self.inv,
            &mut self.tmp[..rows_out * n],
            n,
            &mut self.scratch,
        );
        std::mem::swap(buf, &mut self.tmp);
    }

    /// Sums the sanitised frame over the blocks and clears the weighted
    /// sums (first step of a frame; [`crate::glare::GlareConvolver::prepare`]
    /// takes the same sums while its window prepares, [`FarField::frame_parts`]).
    pub fn sum_frame(&mut self, img: &RgbImage) {
        if let Some((mut sums, _)) = self.frame_parts(img) {
            sums.take(img);
            self.ready = true;
        }
    }

    /// Starts a frame: clears the weighted sums and hands out the two
    /// parts a frame fills, apart, so that they can be filled at the same
    /// time: the block sums of the frame's light ([`BlockSums::take`]) and
    /// of its weighted sources ([`WeightedSums::add_rows`]). Then
    /// [`FarField::sums_taken`] readies the veil. `None` (no veil this
    /// frame) for a frame of another size.
    pub(crate) fn frame_parts(
        &mut self,
        img: &RgbImage,
    ) -> Option<(BlockSums<'_>, WeightedSums<'_>)> {
        self.ready = false;
        if img.width != self.width || img.height != self.height {
            return None;
        }
        self.wsums.fill([0.0; 3]);
        Some((
            BlockSums {
                width: self.width,
                block_px: self.block_px,
                bw: self.bw,
                sums: &mut self.sums,
                acc: &mut self.hrows,
            },
            WeightedSums {
                block_px: self.block_px,
                bw: self.bw,
                bh: self.bh,
                wsums: &mut self.wsums,
            },
        ))
    }

    /// Both parts of [`FarField::frame_parts`] are filled: the veil can be
    /// computed.
    pub(crate) fn sums_taken(&mut self) {
        self.ready = true;
    }

    /// The block sums of weighted sources, one block row at a time, in
    /// parallel: `f(y, row, block_px)` adds row `y`'s weighted sources to
    /// `row` (the block row's sums); rows `y0..y1`. After
    /// [`FarField::sum_frame`] (which clears them). The tests' way in; a
    /// frame's own go through [`FarField::frame_parts`].
    #[cfg(test)]
    pub(crate) fn add_weighted_rows(
        &mut self,
        y0: usize,
        y1: usize,
        f: impl Fn(usize, &mut [[f32; 3]], usize) + Sync,
    ) {
        let bp = self.block_px;
        let mut part = WeightedSums {
            block_px: bp,
            bw: self.bw,
            bh: self.bh,
            wsums: &mut self.wsums,
        };
        part.add_rows(y0, y1, |y, row| f(y, row, bp));
    }

    /// Convolves the block sums with `tail` and `near` on the grid and
    /// readies the rows for [`FarField::blend_row`].
    pub fn compute(&mut self) {
        if !self.ready {
            return;
        }
        let (n, g) = (self.n, self.g);
        for z in [&mut self.za1, &mut self.zb1, &mut self.za2] {
            z.fill(ZERO);
        }
        // Splat the flux (L Ω) bilinearly.
        for ((s, ws), (&om, &(c, fx, fy))) in self
            .sums
            .iter()
            .zip(&self.wsums)
            .zip(self.block_omega.iter().zip(&self.block_cell))
        {
            let a = s.map(|v| v * om);
            let b = [
                (s[0] - ws[0]).max(0.0) * om,
                (s[1] - ws[1]).max(0.0) * om,
                (s[2] - ws[2]).max(0.0) * om,
            ];
            if a == [0.0; 3] {
                continue;
            }
            let c = c as usize;
            for (idx, wgt) in [
                (c, (1.0 - fx) * (1.0 - fy)),
                (c + 1, fx * (1.0 - fy)),
                (c + n, (1.0 - fx) * fy),
                (c + n + 1, fx * fy),
            ] {
                self.za1[idx] += Complex::new(a[0] * wgt, a[1] * wgt);
                self.zb1[idx] += Complex::new(b[0] * wgt, b[1] * wgt);
                self.za2[idx] += Complex::new(a[2] * wgt, b[2] * wgt);
            }
        }
        let rows = g + 1;
        self.fft2_forward(0, rows);
        self.fft2_forward(1, rows);
        self.fft2_forward(2, rows);
        // o1 = Za1 Kt + Zb1 Kn (R, G); o2 = A_B ∗ tail + i B_B ∗ near
        // from Za2 = A_B + i B_B: Za2(k) P + conj(Za2(−k)) M,
        // P = (Kt + Kn)/2, M = (Kt − Kn)/2.
        {
            let (za1, zb1, za2, kt, kn) =
                (&mut self.za1, &mut self.zb1, &self.za2, &self.kt, &self.kn);
            za1.par_chunks_mut(n)
                .zip(zb1.par_chunks_mut(n))
                .enumerate()
                .for_each(|(r, (a1, b1))| {
                    let rm = (n - r) % n;
                    for c in 0..n {
                        let i = r * n + c;
                        let cm = (n - c) % n;
                        let (t, q) = (kt[i], kn[i]);
                        a1[c] = a1[c] * t + b1[c] * q;
                        let z = za2[i];
                        let zm = za2[rm * n + cm].conj();
                        b1[c] = z * (0.5 * (t + q)) + zm * (0.5 * (t - q));
                    }
                });
        }
        self.fft2_inverse(0, rows);
        self.fft2_inverse(1, rows);
        // Read back at the block centres.
        let scale = 1.0 / (n * n) as f32;
        let (za1, zb1) = (&self.za1, &self.zb1);
        for (v, &(c, fx, fy)) in self.veil.iter_mut().zip(&self.block_cell) {
            let c = c as usize;
            let mut acc = [0.0f32; 3];
            for (idx, wgt) in [
                (c, (1.0 - fx) * (1.0 - fy)),
                (c + 1, fx * (1.0 - fy)),
                (c + n, (1.0 - fx) * fy),
                (c + n + 1, fx * fy),
            ] {
                let (o1, o2) = (za1[idx], zb1[idx]);
                acc[0] += o1.re * wgt;
                acc[1] += o1.im * wgt;
                acc[2] += (o2.re + o2.im) * wgt;
            }
            *v = acc.map(|x| (x * scale).max(0.0));
        }
        // Along x to every column, per block row.
        let (w, bw) = (self.width, self.bw);
        let (veil, xhat) = (&self.veil, &self.xhat);
        self.hrows
            .par_chunks_mut(w * 3)
            .enumerate()
            .for_each(|(j, row)| {
                let vr = &veil[j * bw..(j + 1) * bw];
                for (o, &(i0, fx)) in row.chunks_exact_mut(3).zip(xhat) {
                    let i0 = i0 as usize;
                    let a = vr[i0];
                    let b = vr[(i0 + 1).min(bw - 1)];
                    for ch in 0..3 {
                        o[ch] = a[ch] + (b[ch] - a[ch]) * fx;
                    }
                }
            });
    }

    /// Whether a veil is ready to blend.
    pub fn is_ready(&self) -> bool {
        self.ready
    }

    /// What a pixel of window weight `w` keeps of its own light:
    /// `(1 − w)(1 − E_near) − E_tail`.
    #[inline]
    pub fn keep(&self, w: f32) -> f32 {
        (1.0 - w) * (1.0 - self.e_near) - self.e_tail
    }

    /// Adds the veil to row `y` (after the pixels' own light was scaled by
    /// [`FarField::keep`]).
    pub fn add_row(&self, y: usize, row: &mut [[f32; 3]]) {
        self.blend_cols(y, row, 1.0, 0..self.width);
    }

    /// Columns `cols` of row `y` made from the scene row `src`: each
    /// pixel's sanitised light times `keep`, plus the veil — the values of
    /// sanitising, then [`FarField::blend_cols`], in one pass. Without a
    /// veil (not ready, a row outside the frame) only sanitised.
    #[inline(always)]
    pub fn fill_cols(
        &self,
        y: usize,
        src: &[[f32; 3]],
        row: &mut [[f32; 3]],
        keep: f32,
        cols: Range<usize>,
    ) {
        let cols = cols.start.min(row.len()).min(src.len())..cols.end.min(row.len()).min(src.len());
        if cols.is_empty() {
            return;
        }
        let (dst, src) = (&mut row[cols.clone()], &src[cols.clone()]);
        if !self.ready || y >= self.height || cols.end > self.width {
            for (d, s) in dst.as_flattened_mut().iter_mut().zip(src.as_flattened()) {
                *d = sanitize(*s);
            }
            return;
        }
        let (j0, j1, fy) = self.row_hat(y);
        let w3 = self.width * 3;
        let (c0, c1) = (cols.start * 3, cols.end * 3);
        let lo = &self.hrows[j0 * w3 + c0..j0 * w3 + c1];
        let hi = &self.hrows[j1 * w3 + c0..j1 * w3 + c1];
        for (((p, &s), &a), &c) in dst
            .as_flattened_mut()
            .iter_mut()
            .zip(src.as_flattened())
            .zip(lo)
            .zip(hi)
        {
            *p = sanitize(s) * keep + (a + (c - a) * fy);
        }
    }

    /// Columns `cols` of row `y`: each pixel's own light times `keep`, plus
    /// the veil. Always inlined: the band pass's row source compiles it
    /// inside its AVX-512 and AVX2 twins (a call ran it on SSE's 4 lanes).
    #[inline(always)]
    pub fn blend_cols(&self, y: usize, row: &mut [[f32; 3]], keep: f32, cols: Range<usize>) {
        if !self.ready || y >= self.height || row.len() < self.width || cols.is_empty() {
            return;
        }
        let cols = cols.start.min(self.width)..cols.end.min(self.width);
        let (j0, j1, fy) = self.row_hat(y);
        let w3 = self.width * 3;
        let (c0, c1) = (cols.start * 3, cols.end * 3);
        let lo = &self.hrows[j0 * w3 + c0..j0 * w3 + c1];
        let hi = &self.hrows[j1 * w3 + c0..j1 * w3 + c1];
        for ((p, &a), &c) in row[cols].as_flattened_mut().iter_mut().zip(lo).zip(hi) {
            *p = *p * keep + (a + (c - a) * fy);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cie(t: f64, a: f64, p: f64) -> f64 {
        // CIE 146:2002 General Disability Glare equation, written out.
        10.0 / t.powi(3) + (5.0 / t.powi(2) + 0.1 * p / t) * (1.0 + (a / 62.5).powi(4)) + 0.0025 * p
    }

    #[test]
    fn split_adds_up_to_cie_146_beyond_the_window() {
        let s = FarSplit::new(25.0, 0.5, 20.0);
        for th in [6.5, 10.0, 13.0, 16.0, 19.0, 25.0, 60.0, 89.0] {
            let t = s.window_taper(th);
            let all = s.tail_per_sr(th) + s.near_per_sr(th);
            let want = cie(th, 25.0, 0.5) * th.to_radians().cos();
            assert!((all - want).abs() <= 1e-12 * want, "{th}");
            let windowed = cie(th, 25.0, 0.5) * t + s.tail_per_sr(th);
            // Inside the window the kernel has no cos θ: between the two.
            let bare = cie(th, 25.0, 0.5);
            assert!(windowed >= want * (1.0 - 1e-12) && windowed <= bare * (1.0 + 1e-12));
        }
        assert_eq!(s.tail_per_sr(91.0), 0.0);
        assert_eq!(s.near_per_sr(2.0), 0.0);
        // Energies: a few per cent of a source's light (docs/perception.md).
        let (et, en) = (s.tail_energy(), s.near_energy());
        eprintln!("E_tail {et:.5}, E_near {en:.5}");
        assert!(et > 0.01 && et < 0.06, "{et}");
        assert!(en > 0.005 && en < 0.05, "{en}");
    }

    /// In a rectilinear view the kernel (a convolution on the plane at the
    /// centre's degrees per pixel) puts a direction θ from the centre at
    /// tan θ (in degrees): its taper there, t = 1 − smoothstep((τ − 12)/8)
    /// for the ±20° kernel, written out here; the tail and near parts still
    /// add up to CIE 146 · cos θ beyond the window.
    #[test]
    fn a_rectilinear_split_tapers_at_the_planes_angle() {
        let s = FarSplit {
            planar_taper: true,
            ..FarSplit::new(25.0, 0.5, 20.0)
        };
        for th in [12.0f64, 14.0, 16.0, 17.4, 18.0, 19.0, 25.0, 60.0, 89.0] {
            let tau = th.to_radians().tan().to_degrees();
            let x = ((tau - 12.0) / 8.0).clamp(0.0, 1.0);
            let t = 1.0 - x * x * (3.0 - 2.0 * x);
            let full = cie(th, 25.0, 0.5) * th.to_radians().cos();
            let tail = s.tail_per_sr(th);
            assert!(
                (tail - full * (1.0 - t)).abs() <= 1e-12 * full,
                "{th}: {tail}"
            );
            let all = tail + s.near_per_sr(th);
            assert!((all - full).abs() <= 1e-12 * full, "{th}");
        }
        // 17.4° on the sphere is 17.96° on the plane.
        assert!((s.kernel_angle_deg(17.4) - 17.96).abs() < 0.01);
        assert_eq!(FarSplit::new(25.0, 0.5, 20.0).kernel_angle_deg(17.4), 17.4);
        // A rectilinear view's far field takes the plane's measure.
        let far = FarField::new(
            FarSplit::new(25.0, 0.5, 20.0),
            64,
            48,
            PlaneAngles::symmetric(90.0, 64, 48),
        )
        .unwrap();
        assert!(far.split().planar_taper);
    }

    /// The FFT on the grid against the plain f64 sum over every pair of
    /// pixels: a lamp and a dim field in a 100° view.
    #[test]
    fn grid_matches_the_direct_sum() {
        let (w, h) = (96usize, 80usize);
        for angles in [
            PlaneAngles::Uniform { deg_per_px: 1.1 },
            PlaneAngles::symmetric(100.0, w, h),
        ] {
            let mut img = RgbImage::new(w, h);
            for (i, p) in img.pixels.iter_mut().enumerate() {
                *p = [0.02, 0.03, 0.01 * (i % 7) as f32];
            }
            *img.get_mut(30, 40) = [2e5, 1e5, 5e4];
            *img.get_mut(31, 40) = [2e5, 1e5, 5e4];
            let split = FarSplit::new(25.0, 0.5, 20.0);
            let weight = |x: usize, _y: usize| if x < 20 { 1.0 } else { 0.0 };
            let mut far = FarField::new(split, w, h, angles).unwrap();
            // The split as the view's geometry sets it (the taper in the
            // plane's measure for the rectilinear view).
            let want = far_veil_reference(&img, angles, &far.split(), weight);
            far.sum_frame(&img);
            far.add_weighted_rows(0, h, |y, row, bp| {
                for x in 0..20 {
                    let p = img.get(x, y);
                    for ch in 0..3 {
                        row[x / bp][ch] += p[ch];
                    }
                }
            });
            far.compute();
            let mut worst = 0.0f64;
            for y in (0..h).step_by(3) {
                let mut row = vec![[0.0f32; 3]; w];
                far.add_row(y, &mut row);
                for x in (0..w).step_by(3) {
                    let (g, r) = (row[x][0] as f64, want[y * w + x][0]);
                    // Within 2° of the lamp the grid holds no veil (h).
                    let d = (x as f64 - 30.5).hypot(y as f64 - 40.0) * 1.1;
                    if d < 12.0 {
                        continue;
                    }
                    worst = worst.max((g / r - 1.0).abs());
                }
            }
            eprintln!("{angles:?}: worst relative error {worst}");
            assert!(worst < 0.12, "{angles:?}: worst relative error {worst}");
        }
    }
}
