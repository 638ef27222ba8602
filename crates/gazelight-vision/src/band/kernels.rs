//! The band engine's row loops with explicit intrinsics, at two widths
//! from one definition: [`band_kernels!`] writes the maths once over the
//! vector primitives of [`crate::simd::avx2`] / [`crate::simd::avx512`]
//! (which carry the same names) and is expanded in [`avx2`] (blocks of 8)
//! and [`avx512`] (blocks of 16), each function
//! `#[target_feature(enable = …)]` for its width.
//!
//! Each function is the twin of a portable one in the parent module
//! ([`super::load_y`], [`super::to_lightness`], [`super::horizontal`],
//! [`super::vertical`], [`super::cbrt_v`], [`super::exp_v`],
//! [`super::lab_g_v`], [`super::lab_g_inv`]) and computes **the same
//! bits**: the same float operations in the same order (no fused
//! multiply-adds), selects where the portable code has branches. Blocks of
//! 16 instead of 8 change nothing a pixel sees:
//!
//! * a block's tap loop runs to the largest radius of its pixels and every
//!   tap beyond a pixel's own radius adds an exact zero (as for 8);
//! * L\*'s "all linear" shortcut and the select it skips give the same
//!   value per lane;
//! * step 4's shortcut (RGB + white·Δ/κ when all of a block is in L\*'s
//!   linear part) is decided per block of 8 pixels, the block of the
//!   portable loops: at 16 lanes per half, both results computed and
//!   selected per half when the halves differ. This is where the two
//!   widths really differ, written out per width (`step4`).
//!
//! Each row function takes `from`, the first pixel to do (a multiple of
//! the width), does the row's full blocks from there and returns where it
//! stopped: the caller runs AVX-512 first, AVX2 on what is left, the
//! portable loops on the tail. All are called only behind a
//! [`crate::simd::Simd`] of their tier (see the parent module's dispatch).

#![cfg(target_arch = "x86_64")]

/// The per-block weights and gather of [`super::gather_v`] with the pairs
/// `(v(−k), v(k))` = `pair(k)`: a macro, so that the loads inline into the
/// calling `target_feature` function. Uses the primitives and `taps` of
/// the module it is expanded in.
macro_rules! gather {
    ($ctx:expr, $centre:expr, |$k:ident| $pair:expr) => {{
        let centre: V = $centre;
        match taps($ctx, centre) {
            None => centre,
            Some((block_r, e, e2, three_sigma)) => {
                let (mut g, mut q) = (splat(1.0), e);
                let (mut acc, mut norm) = (centre, splat(1.0));
                let two = splat(2.0);
                for $k in 1..=block_r {
                    let (a, b): (V, V) = $pair;
                    let below = splat(($k - 1) as f32);
                    g = mul(g, q);
                    q = mul(q, e2);
                    let gk = keep(lt(below, three_sigma), g);
                    acc = add(acc, mul(gk, add(a, b)));
                    norm = add(norm, mul(two, gk));
                }
                div(acc, norm)
            }
        }
    }};
}

/// The row loops and their maths for one width, every function
/// `#[target_feature(enable = $features)]`; expanded in a module that
/// imports that width's primitives and defines its `step4`.
macro_rules! band_kernels {
    ($features:literal) => {
        /// `m · p` per lane, each row as `(m₀p₀ + m₁p₁) + m₂p₂`.
        #[inline]
        #[target_feature(enable = $features)]
        fn mat3(m: &[[f32; 3]; 3], p: &[V; 3]) -> [V; 3] {
            map3(*m, |row| {
                add(
                    add(mul(splat(row[0]), p[0]), mul(splat(row[1]), p[1])),
                    mul(splat(row[2]), p[2]),
                )
            })
        }

        /// [`super::super::cbrt_v`]: the exponent-bits guess `bits/3 + B1`,
        /// then three Newton steps.
        #[inline]
        #[target_feature(enable = $features)]
        fn cbrt(t: V) -> V {
            // (127 − 127/3 − 0.0331)·2²³, FreeBSD s_cbrtf.c B1
            const B1: i32 = 709_958_130;
            let mut y = from_bits(add_i(div3_u32(bits(t)), splat_i(B1)));
            let (two_thirds, one_third) = (splat(2.0 / 3.0), splat(1.0 / 3.0));
            let t3 = mul(t, one_third);
            for _ in 0..3 {
                y = add(mul(two_thirds, y), div(t3, mul(y, y)));
            }
            y
        }

        /// [`super::super::lab_g_v`]: κt up to ε, `116∛t − 16` above.
        #[inline]
        #[target_feature(enable = $features)]
        fn lab_g(t: V) -> V {
            let eps = splat(216.0 / 24389.0);
            let linear = mul(splat(24389.0 / 27.0), t);
            let cubic = gt(t, eps);
            if none(cubic) {
                return linear;
            }
            let c = cbrt(max(t, eps));
            let v = sub(mul(splat(116.0), c), splat(16.0));
            select(cubic, v, linear)
        }

        /// [`super::super::lab_g_inv`]: v/κ up to 8, `((v + 16)/116)³` above.
        #[inline]
        #[target_feature(enable = $features)]
        fn lab_g_inv(v: V) -> V {
            let f = div(add(v, splat(16.0)), splat(116.0));
            let cube = mul(mul(f, f), f);
            let linear = mul(v, splat(27.0 / 24389.0));
            select(gt(v, splat(8.0)), cube, linear)
        }

        /// [`super::super::exp_v`] for x in [−87, 0].
        #[inline]
        #[target_feature(enable = $features)]
        fn exp(x: V) -> V {
            const LN2_HI: f32 = 0.693_145_75;
            const LN2_LO: f32 = 1.428_606_8e-6;
            // 1.5·2²³: adding and subtracting it rounds to the nearest integer
            const ROUND: f32 = 12_582_912.0;
            let x = max(x, splat(-87.0));
            let shifted = add(mul(x, splat(std::f32::consts::LOG2_E)), splat(ROUND));
            let n = sub(shifted, splat(ROUND));
            let n_int = sub_i(bits(shifted), splat_i(ROUND.to_bits() as i32));
            let r = sub(sub(x, mul(n, splat(LN2_HI))), mul(n, splat(LN2_LO)));
            let mut p = splat(1.0 / 720.0);
            for c in [1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0] {
                p = add(splat(c), mul(r, p));
            }
            let scale = shl_23(add_i(n_int, splat_i(127)));
            mul(p, from_bits(scale))
        }

        /// [`super::super::sigma_v`].
        #[inline]
        #[target_feature(enable = $features)]
        fn sigma(rule: SigmaRule, l: V, white: f32) -> V {
            match rule {
                SigmaRule::Linear { scale } => {
                    // 001 eq 12; clamp of a value that is never NaN
                    let s = min(max(sub(splat(1.0), l), zero()), splat(1.0));
                    mul(s, splat(scale))
                }
                SigmaRule::Larson { .. } => {
                    let mut v = [0.0f32; W];
                    st(&mut v, 0, l);
                    ld(&v.map(|li| rule.sigma(li, white)), 0)
                }
                SigmaRule::None => zero(),
            }
        }

        /// The per-block setup of [`super::super::gather_v`]: σ of each lane
        /// from `centre`; `None` when no lane blurs, else (tap radius of the
        /// block, e = exp(−1/(2σ²)), e², 3σ (0 for lanes that keep their
        /// value)).
        #[inline]
        #[target_feature(enable = $features)]
        fn taps(ctx: &Ctx, centre: V) -> Option<(usize, V, V, V)> {
            let s = sigma(ctx.rule, centre, ctx.white);
            // σ is never NaN (lightness of sanitised, finite values).
            let sigma_max = hmax(s).max(0.0);
            if sigma_max <= AcuityBlur::MIN_SIGMA_PX {
                return None;
            }
            let block_r = (3.0 * sigma_max).ceil().min(ctx.r as f32) as usize;
            let active = gt(s, splat(AcuityBlur::MIN_SIGMA_PX));
            let s = select(active, s, splat(1.0));
            let e = div(splat(-0.5), mul(s, s));
            let three_sigma = keep(active, mul(splat(3.0), s));
            let e = exp(e);
            Some((block_r, e, mul(e, e), three_sigma))
        }

        /// [`super::super::load_y`] over the row's full blocks from pixel
        /// `from` on; returns (any of those pixels dark, pixels done).
        #[target_feature(enable = $features)]
        pub(in crate::band) fn load_y(
            ctx: &Ctx,
            src: &[[f32; 3]],
            lrow: &mut [f32],
            head: &mut [f32],
            from: usize,
        ) -> (bool, usize) {
            let sh = Shuffles::new();
            let y_row = RGB_TO_XYZ[1];
            let inv_white = splat(1.0 / ctx.white);
            let (c0, c1, c2) = (splat(y_row[0]), splat(y_row[1]), splat(y_row[2]));
            let dark_below = splat(ctx.dark_below);
            let mut dark = no_lanes();
            let full = src.len() / W * W;
            for x in (from.min(full)..full).step_by(W) {
                let [r, g, b] = sh.deinterleave(&src[x..x + W]);
                let y = add(add(mul(c0, r), mul(c1, g)), mul(c2, b));
                let t = mul(y, inv_white);
                st(lrow, ctx.r + x, t);
                st(head, x, mul(max(max(r, g), b), inv_white));
                dark = either(dark, lt(t, dark_below));
            }
            (!none(dark), full)
        }

        /// [`super::super::to_lightness`]'s conversion over the row's full
        /// blocks from pixel `from` on (the caller pads the row); returns
        /// the pixels done.
        #[target_feature(enable = $features)]
        pub(in crate::band) fn to_lightness(ctx: &Ctx, lrow: &mut [f32], from: usize) -> usize {
            let full = ctx.stride_h / W * W;
            for x in (ctx.r + from.min(full)..ctx.r + full).step_by(W) {
                let t = ld(lrow, x);
                st(lrow, x, lab_g(t));
            }
            full
        }

        /// [`super::super::horizontal`] over the row's full blocks from pixel
        /// `from` on; returns the pixels done.
        #[target_feature(enable = $features)]
        pub(in crate::band) fn horizontal(
            ctx: &Ctx,
            lrow: &[f32],
            hrow: &mut [f32],
            from: usize,
        ) -> usize {
            let r = ctx.r;
            let full = ctx.stride_h / W * W;
            for x0 in (from.min(full)..full).step_by(W) {
                let x = r + x0;
                let v = gather!(ctx, ld(lrow, x), |k| (ld(lrow, x - k), ld(lrow, x + k)));
                st(hrow, x0, v);
            }
            full
        }

        /// [`super::super::vertical`] over the row's full blocks from pixel
        /// `from` on; returns (pixels whose lightness changed, pixels done).
        #[target_feature(enable = $features)]
        pub(in crate::band) fn vertical(
            ctx: &Ctx,
            band: &Band,
            up: &[usize],
            down: &[usize],
            y: usize,
            row: &mut [[f32; 3]],
            from: usize,
        ) -> (usize, usize) {
            let sh = Shuffles::new();
            let Ctx { r, .. } = *ctx;
            let ring = 2 * r + 1;
            let hor = &band.hor[..];
            let lrow = &band.lum[(y % ring) * ctx.stride_l + r..];
            let head_row = &band.head[(y % ring) * ctx.stride_h..];
            let wx = map3(WHITE_XYZ, |c| c * ctx.white);
            let kappa = splat(LAB_KAPPA_F32);
            let shift_scale = splat(ctx.white / LAB_KAPPA_F32);
            let mut changed = 0;
            let full = row.len() / W * W;
            for x in (from.min(full)..full).step_by(W) {
                let hv = ld(hor, up[0] + x);
                let l_new = gather!(ctx, hv, |k| (ld(hor, up[k] + x), ld(hor, down[k] + x)));
                let l_old = ld(lrow, x);
                let moved = neq(l_new, l_old);
                if none(moved) {
                    continue;
                }
                let d = sub(l_new, l_old);
                let head = ld(head_row, x);
                let bound = add(mul(head, kappa), max(d, zero()));
                let out = &mut row[x..x + W];
                let p = sh.deinterleave(out);
                let new = step4(
                    le(bound, splat(8.0)),
                    #[inline(always)]
                    || {
                        // RGB' = RGB + (white·Δ/κ)·(1, 1, 1), see the parent
                        // module.
                        let shift = mul(d, shift_scale);
                        map3(p, |c| add(c, shift))
                    },
                    #[inline(always)]
                    || {
                        let xyz = mat3(&RGB_TO_XYZ, &p);
                        let gx = lab_g(div(xyz[0], splat(wx[0])));
                        let gz = lab_g(div(xyz[2], splat(wx[2])));
                        let new = [
                            mul(lab_g_inv(add(gx, d)), splat(wx[0])),
                            mul(lab_g_inv(add(l_old, d)), splat(wx[1])),
                            mul(lab_g_inv(add(gz, d)), splat(wx[2])),
                        ];
                        mat3(&XYZ_TO_RGB, &new)
                    },
                );
                let kept = map3([0, 1, 2], |c| select(moved, new[c], p[c]));
                sh.interleave(kept, out);
                changed += count(moved) as usize;
            }
            (changed, full)
        }

        /// Applies `f` (0 [`cbrt`], 1 [`exp`], 2 [`lab_g`], 3 [`lab_g_inv`])
        /// to `x` block by block into `out` (the tests' access to the maths).
        #[cfg(test)]
        #[target_feature(enable = $features)]
        pub(super) fn maths(f: usize, x: &[f32], out: &mut [f32]) {
            for at in (0..x.len() / W * W).step_by(W) {
                let v = ld(x, at);
                let y = match f {
                    0 => cbrt(v),
                    1 => exp(v),
                    2 => lab_g(v),
                    _ => lab_g_inv(v),
                };
                st(out, at, y);
            }
        }
    };
}

/// Blocks of 8 (AVX2 + FMA).
pub(super) mod avx2 {
    use super::super::{AcuityBlur, Band, Ctx, SigmaRule};
    use crate::colour::{LAB_KAPPA_F32, RGB_TO_XYZ, WHITE_XYZ, XYZ_TO_RGB};
    use crate::simd::avx2::*;
    use crate::simd::map3;

    /// Step 4 of a block of 8 whose lightness moved: `shifted` (the shift
    /// of RGB along white) when every lane is in L\*'s linear part before
    /// and after (`linear`), else `converted` (through XYZ and Lab).
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn step4(
        linear: M,
        shifted: impl FnOnce() -> [V; 3],
        converted: impl FnOnce() -> [V; 3],
    ) -> [V; 3] {
        if all(linear) { shifted() } else { converted() }
    }

    band_kernels!("avx2,fma");
}

/// Blocks of 16 (AVX-512F, with AVX2 and FMA).
pub(super) mod avx512 {
    use super::super::{AcuityBlur, Band, Ctx, SigmaRule};
    use crate::colour::{LAB_KAPPA_F32, RGB_TO_XYZ, WHITE_XYZ, XYZ_TO_RGB};
    use crate::simd::avx512::*;
    use crate::simd::map3;

    /// Step 4 of a block of 16 whose lightness moved, decided per half of
    /// 8 (the AVX2 and portable block): `shifted` for a half whose lanes
    /// are all in L\*'s linear part (`linear`), `converted` for the others;
    /// both computed and selected per half when the halves differ.
    #[inline]
    #[target_feature(enable = "avx512f,avx2,fma")]
    fn step4(
        linear: M,
        shifted: impl FnOnce() -> [V; 3],
        converted: impl FnOnce() -> [V; 3],
    ) -> [V; 3] {
        let (lo, hi) = (linear & 0x00ff == 0x00ff, linear & 0xff00 == 0xff00);
        match (lo, hi) {
            (true, true) => shifted(),
            (false, false) => converted(),
            _ => {
                let (a, b) = (shifted(), converted());
                let half: M = if lo { 0x00ff } else { 0xff00 };
                map3([0, 1, 2], |c| select(half, a[c], b[c]))
            }
        }
    }

    band_kernels!("avx512f,avx2,fma");
}

#[cfg(test)]
mod tests {
    use crate::simd::{Simd, Tier, testing};

    /// The kernels' `maths` of one tier.
    type Maths = unsafe fn(usize, &[f32], &mut [f32]);

    #[test]
    fn cbrt_exp_and_lab_match_the_portable_twins_bit_for_bit() {
        let test = "cbrt_exp_and_lab_match_the_portable_twins_bit_for_bit";
        let builds: Vec<(Simd, Maths)> = testing::tiers(test, &[Tier::Avx2, Tier::Avx512])
            .into_iter()
            .map(|s| {
                let f: Maths = if s.has(Tier::Avx512) {
                    super::avx512::maths
                } else {
                    super::avx2::maths
                };
                (s, f)
            })
            .collect();
        let n = 800_000usize;
        let t: Vec<f32> = (0..n)
            .map(|i| f32::from_bits(0x0080_0000 + (i as u32).wrapping_mul(21_473) % 0x7e00_0000))
            .collect();
        let x: Vec<f32> = (0..n).map(|i| -(i as f32) * (90.0 / 8e5)).collect();
        let v: Vec<f32> = (0..n).map(|i| (i as f32 - 1e5) * 1e-3).collect();
        let mut want = vec![vec![0.0f32; n]; 4];
        for at in (0..n).step_by(super::super::LANES) {
            let block = |s: &[f32]| -> super::super::V { std::array::from_fn(|j| s[at + j]) };
            let outs = [
                super::super::cbrt_v(block(&t)),
                super::super::exp_v(block(&x)),
                super::super::lab_g_v(block(&t)),
                block(&v).map(super::super::lab_g_inv),
            ];
            for (w, o) in want.iter_mut().zip(outs) {
                w[at..at + o.len()].copy_from_slice(&o);
            }
        }
        for (simd, maths) in builds {
            let mut differ = 0;
            for (f, input) in [&t, &x, &t, &v].into_iter().enumerate() {
                let mut got = vec![0.0f32; n];
                // SAFETY: `simd` proves the CPU runs this build's tier.
                unsafe { maths(f, input, &mut got) };
                for (i, (a, b)) in got.iter().zip(&want[f]).enumerate() {
                    if a.to_bits() != b.to_bits() {
                        if differ < 10 {
                            eprintln!(
                                "{:?} fn {f} at {i}: {a:e} vs {b:e} (in {:e})",
                                simd, input[i]
                            );
                        }
                        differ += 1;
                    }
                }
            }
            eprintln!("{}: {} lanes differ", simd.tier(), differ);
            assert_eq!(differ, 0, "{}: lanes that differ", simd.tier());
        }
    }
}
