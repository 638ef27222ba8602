//! The frame pipeline's per-pixel passes as they were before they were
//! specialised, kept (for the tests only) as the reference the optimised
//! passes are compared against: `FramePipeline` runs them in place of pass
//! A, the band engine and the fused stages 6–8 when its `reference` flag
//! is set.

use super::{DisplayFrame, luminance};
use crate::RgbImage;
use crate::acuity::AcuityModel;
use crate::band::AcuityBlur;
use crate::colour::ColourFrame;
use crate::encode::{SRGB_LUT_SIZE, SrgbLut};
use crate::tone::ToneFrame;

/// The per-pixel passes as they were before they were specialised, kept as
/// the reference the optimised passes are tested against.
pub(super) fn reference_pass_a(
    scene: &RgbImage,
    work: &mut RgbImage,
    small_lum: &mut [f32],
    small_valid: &mut [f32],
    ds: usize,
    small_w: usize,
) {
    fn sanitize(v: f32) -> f32 {
        if v.is_finite() && v >= f32::MIN_POSITIVE {
            v
        } else {
            0.0
        }
    }
    let w = scene.width;
    work.pixels
        .chunks_mut(w * ds)
        .zip(scene.pixels.chunks(w * ds))
        .zip(small_lum.chunks_mut(small_w))
        .zip(small_valid.chunks_mut(small_w))
        .for_each(|(((dst, src), small_row), valid_row)| {
            small_row.fill(0.0);
            valid_row.fill(0.0);
            let rows = src.len() / w;
            for (i, (d, s)) in dst.iter_mut().zip(src).enumerate() {
                let p = [sanitize(s[0]), sanitize(s[1]), sanitize(s[2])];
                *d = p;
                small_row[(i % w) / ds] += luminance(p);
                if !(s[0].is_nan() || s[1].is_nan() || s[2].is_nan()) {
                    valid_row[(i % w) / ds] += 1.0;
                }
            }
            for (bx, (v, a)) in small_row.iter_mut().zip(valid_row.iter_mut()).enumerate() {
                let cols = (w - bx * ds).min(ds);
                *v /= (cols * rows) as f32;
                *a /= (cols * rows) as f32;
            }
        });
}

/// Reference stage 5, written plainly in f64: every pixel's full CIE Lab
/// (IEC 61966-2-1 matrices, D65 white scaled to the Lab white), σ from
/// [`AcuityModel::sigma_px`] of its own lightness, then of its
/// horizontally blurred lightness, Gaussian taps from `exp`, back to RGB
/// with the pixel's a*, b*.
pub(super) fn reference_acuity(model: &AcuityModel, deg_per_px: f64, img: &mut RgbImage) {
    use crate::colour::lightness_to_y;
    const M: [[f64; 3]; 3] = [
        [0.412_456_4, 0.357_576_1, 0.180_437_5],
        [0.212_672_9, 0.715_152_2, 0.072_175],
        [0.019_333_9, 0.119_192, 0.950_304_1],
    ];
    const MI: [[f64; 3]; 3] = [
        [3.240_454_2, -1.537_138_5, -0.498_531_4],
        [-0.969_266, 1.876_010_8, 0.041_556],
        [0.055_643_4, -0.204_025_9, 1.057_225_2],
    ];
    let (w, h) = (img.width, img.height);
    let white = model.lab_white_cd_m2();
    let wn = [0.950_47 * white, white, 1.088_83 * white];
    let f = |t: f64| {
        if t > 216.0 / 24389.0 {
            t.cbrt()
        } else {
            (24389.0 / 27.0 * t + 16.0) / 116.0
        }
    };
    let finv = |v: f64| {
        if v > 6.0 / 29.0 {
            v * v * v
        } else {
            (116.0 * v - 16.0) * 27.0 / 24389.0
        }
    };
    let lab: Vec<[f64; 3]> = img
        .pixels
        .iter()
        .map(|p| {
            let p = p.map(f64::from);
            let xyz = M.map(|r| r[0] * p[0] + r[1] * p[1] + r[2] * p[2]);
            let (fx, fy, fz) = (f(xyz[0] / wn[0]), f(xyz[1] / wn[1]), f(xyz[2] / wn[2]));
            [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
        })
        .collect();
    let sigma = |l: f64| f64::from(model.sigma_px(lightness_to_y(l) * white, deg_per_px));
    let blur = |s: f64, v: &dyn Fn(i64) -> f64| -> f64 {
        if s <= f64::from(AcuityBlur::MIN_SIGMA_PX) {
            return v(0);
        }
        let r = ((3.0 * s).ceil() as i64).min(AcuityBlur::MAX_RADIUS_PX as i64);
        let (mut acc, mut norm) = (0.0f64, 0.0f64);
        for k in -r..=r {
            let g = (-((k * k) as f64) / (2.0 * s * s)).exp();
            acc += g * v(k);
            norm += g;
        }
        acc / norm
    };
    let mut hz = vec![0.0f64; w * h];
    for y in 0..h {
        for x in 0..w {
            let l = lab[y * w + x][0];
            hz[y * w + x] = blur(sigma(l), &|k| {
                lab[y * w + (x as i64 + k).clamp(0, w as i64 - 1) as usize][0]
            });
        }
    }
    for y in 0..h {
        for x in 0..w {
            let hv = hz[y * w + x];
            let l = blur(sigma(hv), &|k| {
                hz[(y as i64 + k).clamp(0, h as i64 - 1) as usize * w + x]
            });
            let [l0, a, b] = lab[y * w + x];
            if l != l0 {
                let fy = (l + 16.0) / 116.0;
                let xyz = [
                    finv(fy + a / 500.0) * wn[0],
                    finv(fy) * wn[1],
                    finv(fy - b / 200.0) * wn[2],
                ];
                img.pixels[y * w + x] =
                    MI.map(|r| (r[0] * xyz[0] + r[1] * xyz[1] + r[2] * xyz[2]) as f32);
            }
        }
    }
}

/// Reference stages 6 + 7 (+ 8): `colour.apply(tone.apply(p))` per pixel.
pub(super) fn reference_pass_c(
    tone: &ToneFrame,
    colour: &ColourFrame,
    work: &RgbImage,
    display: &mut RgbImage,
    out: &mut DisplayFrame,
    lut: &SrgbLut,
    to_display: bool,
) {
    if to_display {
        for (d, s) in display.pixels.iter_mut().zip(&work.pixels) {
            *d = colour.apply(tone.apply(*s)).map(|v| v.clamp(0.0, 1.0));
        }
    } else {
        for (d, s) in out.rgba8.chunks_exact_mut(4).zip(&work.pixels) {
            let idx = |v: f32| {
                ((if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) } * (SRGB_LUT_SIZE - 1) as f32
                    + 0.5) as usize)
                    .min(SRGB_LUT_SIZE - 1)
            };
            let rgb = colour.apply(tone.apply(*s));
            d.copy_from_slice(&[lut[idx(rgb[0])], lut[idx(rgb[1])], lut[idx(rgb[2])], 255]);
        }
    }
}
