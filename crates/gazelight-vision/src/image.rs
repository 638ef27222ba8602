//! Linear-light RGB float images and luminance.

use crate::VisionError;

/// Luminance weights for linear sRGB / Rec. 709 primaries.
// 001 eq 1: Y = 0.2125 R + 0.7154 G + 0.0721 B
pub const LUMINANCE_WEIGHTS: [f32; 3] = [0.2125, 0.7154, 0.0721];

/// Luminance Y of a linear RGB triple (001 eq 1). Same unit as the input.
#[inline]
pub fn luminance(rgb: [f32; 3]) -> f32 {
    LUMINANCE_WEIGHTS[0] * rgb[0] + LUMINANCE_WEIGHTS[1] * rgb[1] + LUMINANCE_WEIGHTS[2] * rgb[2]
}

/// Whether a pixel of a view holds "no data" (its direction is outside
/// the scene's field: [`crate::scene::NO_DATA_RGB`]): any channel NaN. A
/// scene is sanitised when it is loaded ([`crate::scene::Scene`]: NaN,
/// infinite and negative values become 0), so NaN in a view marks the
/// pixels the scene does not cover and nothing else. The frame pipeline
/// (CPU and GPU) leaves them out of pooling, counts them as no light in
/// glare, and marks them in its output.
#[inline(always)]
pub fn is_no_data(rgb: [f32; 3]) -> bool {
    rgb[0].is_nan() || rgb[1].is_nan() || rgb[2].is_nan()
}

/// Mean luminance of the pixels of `img` whose centre lies `d` pixels
/// (rounded) from pixel `(cx, cy)`; 0 when none is inside the image. For
/// measuring radial profiles (glare veils) in tests and examples.
pub fn ring_mean_luminance(img: &RgbImage, cx: usize, cy: usize, d: usize) -> f64 {
    let r = d as isize + 1;
    let (mut sum, mut n) = (0.0, 0usize);
    for dy in -r..=r {
        for dx in -r..=r {
            if ((dx * dx + dy * dy) as f64).sqrt().round() as usize != d {
                continue;
            }
            let (x, y) = (cx as isize + dx, cy as isize + dy);
            if x < 0 || y < 0 || x >= img.width as isize || y >= img.height as isize {
                continue;
            }
            sum += f64::from(luminance(img.get(x as usize, y as usize)));
            n += 1;
        }
    }
    if n == 0 { 0.0 } else { sum / n as f64 }
}

/// A linear RGB image, row-major, top row first.
///
/// For scene images the unit is cd/m² (after the scene's luminance scale is
/// applied); for display images it is display-relative [0, 1] linear light.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<[f32; 3]>,
}

impl RgbImage {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            pixels: vec![[0.0; 3]; width * height],
        }
    }

    /// An image from pixels; fails when `pixels.len() != width * height`.
    pub fn from_pixels(
        width: usize,
        height: usize,
        pixels: Vec<[f32; 3]>,
    ) -> Result<Self, VisionError> {
        if pixels.len() != width * height {
            return Err(VisionError::SizeMismatch {
                what: "pixel buffer",
                expected_w: width,
                expected_h: height,
                got_w: pixels.len(),
                got_h: 1,
            });
        }
        Ok(Self {
            width,
            height,
            pixels,
        })
    }

    /// Pixel at (x, y); panics when out of bounds (programming error).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> [f32; 3] {
        self.pixels[y * self.width + x]
    }

    /// Mutable pixel at (x, y).
    #[inline]
    pub fn get_mut(&mut self, x: usize, y: usize) -> &mut [f32; 3] {
        &mut self.pixels[y * self.width + x]
    }

    /// Luminance of every pixel, row-major.
    pub fn luminance_plane(&self) -> Vec<f32> {
        self.pixels.iter().map(|&p| luminance(p)).collect()
    }

    /// Replaces NaN, infinite and negative components by 0 (the shared EXR
    /// files hold negative pixels from lossy compression). Returns how many
    /// components were changed.
    pub fn sanitize(&mut self) -> usize {
        let mut changed = 0;
        for p in &mut self.pixels {
            for c in p.iter_mut() {
                if !c.is_finite() || *c < 0.0 {
                    *c = 0.0;
                    changed += 1;
                } else if *c < f32::MIN_POSITIVE {
                    // Subnormal: physically black, and slow in arithmetic;
                    // flushed to 0 without counting it as a repair.
                    *c = 0.0;
                }
            }
        }
        changed
    }

    /// Multiplies every component by `factor`.
    pub fn scale(&mut self, factor: f32) {
        for p in &mut self.pixels {
            for c in p.iter_mut() {
                *c *= factor;
            }
        }
    }
}

/// Asks the CPU to bring `data` into its caches ahead of a read (one
/// prefetch instruction per 64-byte line; nothing off x86-64). For rows
/// read from memory a little later, after work that keeps the core busy:
/// the lines then arrive while it works instead of stalling the read
/// (the band pass reads each scene row this way, after prefetching it
/// while the row before went through the blur).
#[inline(always)]
pub(crate) fn prefetch<T>(data: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let base = data.as_ptr().cast::<i8>();
        let bytes = std::mem::size_of_val(data);
        let mut at = 0;
        while at < bytes {
            // SAFETY: `base + at` is inside `data`; a prefetch never faults
            // and changes nothing but the caches.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(base.add(at)) };
            at += 64;
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = data;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn luminance_weights_sum_to_one() {
        let y = luminance([1.0, 1.0, 1.0]);
        assert!((y - 1.0).abs() < 1e-6, "{y}");
    }

    #[test]
    fn sanitize_removes_negative_and_nan() {
        let mut img =
            RgbImage::from_pixels(2, 1, vec![[-1.0, f32::NAN, 2.0], [f32::INFINITY, 0.5, 0.0]])
                .unwrap();
        assert_eq!(img.sanitize(), 3);
        assert_eq!(img.pixels, vec![[0.0, 0.0, 2.0], [0.0, 0.5, 0.0]]);
    }

    #[test]
    fn from_pixels_checks_size() {
        assert!(RgbImage::from_pixels(2, 2, vec![[0.0; 3]; 3]).is_err());
    }
}
