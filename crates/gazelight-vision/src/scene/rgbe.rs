//! Radiance RGBE pixels, decoded as Radiance decodes them.
//!
//! The `image` crate parses a Radiance picture's header (its size, VIEW=,
//! EXPOSURE=, COLORCORR=, PIXASPECT=), but turns each RGBE pixel into
//! c·2^(e−136), where Radiance's own reader (`colr_color` in
//! `src/common/color.c`, used by rtrace, pcomb and evalglare) takes the
//! centre of the mantissa's step, (c + ½)·2^(e−136). The difference is
//! half a step of 1/256 of the exponent's range: 0.2–0.4 % of a grey pixel
//! (more on a dim channel of a coloured one). gazelight reads the scan
//! lines itself so that a picture's luminance is Radiance's to the bit.
//!
//! Scan line formats (Radiance's `freadcolrs`): a line starting with the
//! bytes (2, 2, hi, lo), hi < 128, holds its four components one after
//! the other, each run-length encoded in chunks (a count byte above 128:
//! the next byte repeated count − 128 times; otherwise count literal
//! bytes), and (hi, lo) must equal the width; any other line is flat RGBE
//! pixels, where a pixel (1, 1, 1, n) after the first repeats the previous
//! pixel n times, consecutive ones counting in further base-256 digits.

/// Radiance's exponent excess (`COLXS` in Radiance's `color.h`).
const EXPONENT_EXCESS: i32 = 128;
/// Bits of an RGBE mantissa (Radiance's `color.h`: `ldexp(c + .5, e − (COLXS + 8))`).
const MANTISSA_BITS: i32 = 8;

/// One RGBE pixel as Radiance's `colr_color` decodes it, in the file's
/// unit (W·sr⁻¹·m⁻² times EXPOSURE): 0 when the exponent byte is 0,
/// otherwise (c + ½)·2^(e − 136) per channel.
pub fn rgbe_to_rgb(rgbe: [u8; 4]) -> [f64; 3] {
    if rgbe[3] == 0 {
        return [0.0; 3];
    }
    let step = 2f64.powi(i32::from(rgbe[3]) - (EXPONENT_EXCESS + MANTISSA_BITS));
    [0, 1, 2].map(|i| (f64::from(rgbe[i]) + 0.5) * step)
}

/// Where the pixels start: after the header's empty line and the
/// resolution line that follows it.
pub(super) fn pixel_data_offset(bytes: &[u8]) -> Option<usize> {
    let header_end = bytes.windows(2).position(|w| w == b"\n\n")? + 2;
    let resolution_len = bytes[header_end..].iter().position(|&b| b == b'\n')?;
    Some(header_end + resolution_len + 1)
}

/// Reads scan lines of a given width from a Radiance picture's pixel data.
pub(super) struct ScanLines<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> ScanLines<'a> {
    pub(super) fn new(data: &'a [u8]) -> Self {
        Self { data, pos: 0 }
    }

    fn byte(&mut self) -> Result<u8, String> {
        let b = self.data.get(self.pos).copied().ok_or_else(|| {
            format!(
                "the pixel data ends after {} bytes, in the middle of a scan line (truncated)",
                self.data.len()
            )
        })?;
        self.pos += 1;
        Ok(b)
    }

    fn pixel(&mut self) -> Result<[u8; 4], String> {
        Ok([self.byte()?, self.byte()?, self.byte()?, self.byte()?])
    }

    /// Fills `line` (its length is the width) with the next scan line.
    pub(super) fn read(&mut self, line: &mut [[u8; 4]]) -> Result<(), String> {
        let width = line.len();
        if width == 0 {
            return Ok(());
        }
        let first = self.pixel()?;
        if first[0] == 2 && first[1] == 2 && first[2] & 0x80 == 0 {
            let claimed = usize::from(first[2]) << 8 | usize::from(first[3]);
            if claimed != width {
                return Err(format!(
                    "a run-length encoded scan line claims {claimed} pixels in a picture {width} wide"
                ));
            }
            for component in 0..4 {
                let mut x = 0;
                while x < width {
                    let code = usize::from(self.byte()?);
                    if code > 128 {
                        let run = code - 128;
                        let value = self.byte()?;
                        let end = x + run;
                        let dst = line.get_mut(x..end).ok_or_else(|| overrun(end, width))?;
                        dst.iter_mut().for_each(|p| p[component] = value);
                        x = end;
                    } else {
                        let end = x + code;
                        if end > width {
                            return Err(overrun(end, width));
                        }
                        for p in &mut line[x..end] {
                            p[component] = self.byte()?;
                        }
                        x = end;
                    }
                }
            }
            return Ok(());
        }
        line[0] = first;
        let mut x = 1;
        let mut shift = 0u32;
        while x < width {
            let p = self.pixel()?;
            if p[..3] == [1, 1, 1] {
                // A repeat count: its byte is the next base-256 digit.
                let count = if shift < usize::BITS - 8 {
                    usize::from(p[3]) << shift
                } else {
                    usize::MAX
                };
                let end = x.saturating_add(count).min(width);
                let previous = line[x - 1];
                line[x..end].iter_mut().for_each(|q| *q = previous);
                x = end;
                shift += 8;
            } else {
                line[x] = p;
                x += 1;
                shift = 0;
            }
        }
        Ok(())
    }
}

fn overrun(end: usize, width: usize) -> String {
    format!("a scan line runs past its end ({end} of {width} pixels)")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Radiance's rule worked by hand: (c + ½)·2^(e − 136).
    #[test]
    fn pixels_decode_to_the_centre_of_their_step() {
        // e = 129: step 2^(129−136) = 2⁻⁷ = 0.0078125; 128 → 128.5 × 2⁻⁷
        // = 1.00390625 (the `image` crate: 1.0).
        assert_eq!(rgbe_to_rgb([128, 128, 128, 129]), [1.00390625; 3]);
        // e = 136: step 1; (200, 0, 255) → (200.5, 0.5, 255.5).
        assert_eq!(rgbe_to_rgb([200, 0, 255, 136]), [200.5, 0.5, 255.5]);
        // e = 0 is black whatever the mantissas.
        assert_eq!(rgbe_to_rgb([5, 6, 7, 0]), [0.0; 3]);
    }

    #[test]
    fn the_three_scan_line_formats_decode() {
        let a = [130, 64, 32, 130];
        let b = [200, 100, 50, 131];
        // Flat, with an old-style repeat (1, 1, 1, 3) of `b`.
        let mut flat = Vec::new();
        for p in [a, b, [1, 1, 1, 3], a] {
            flat.extend_from_slice(&p);
        }
        let mut line = [[0u8; 4]; 6];
        ScanLines::new(&flat).read(&mut line).unwrap();
        assert_eq!(line, [a, b, b, b, b, a]);
        // New style, width 6: per component a run of 5 then one literal.
        let mut rle = vec![2, 2, 0, 6];
        for c in 0..4 {
            rle.extend_from_slice(&[128 + 5, a[c], 1, b[c]]);
        }
        ScanLines::new(&rle).read(&mut line).unwrap();
        assert_eq!(line, [a, a, a, a, a, b]);
        // A wrong width, an overrun and a truncation are errors.
        let mut wrong = rle.clone();
        wrong[3] = 7;
        assert!(ScanLines::new(&wrong).read(&mut line).is_err());
        let mut over = rle.clone();
        over[4] = 128 + 7;
        assert!(ScanLines::new(&over).read(&mut line).is_err());
        assert!(ScanLines::new(&rle[..10]).read(&mut line).is_err());
    }

    #[test]
    fn pixels_start_after_the_resolution_line() {
        let b = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 1\n\x80\x80\x80\x81";
        assert_eq!(pixel_data_offset(b), Some(b.len() - 4));
        assert_eq!(pixel_data_offset(b"#?RADIANCE\n-Y 1 +X 1\n"), None);
    }
}
