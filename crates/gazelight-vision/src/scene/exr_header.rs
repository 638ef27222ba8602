//! A bounds-checked read of an OpenEXR file's header, done before the `exr`
//! crate sees the file, so that nothing is allocated from an unchecked size.
//!
//! OpenEXR layout (openexr.com, "The OpenEXR File Layout"): the magic
//! number `76 2f 31 01`, a 4-byte version field (version 2 in the low
//! byte; flag bits 9 = single-part tiled, 10 = long names, 11 = deep data,
//! 12 = multi-part), then one header per part — a sequence of attributes
//! `name\0 type\0 size:i32 value[size]` closed by a `\0` — (multi-part
//! files close the list of headers with one more `\0`), then one offset
//! table per part with one `u64` per chunk, then the chunks.
//!
//! What is checked here, per part: the `dataWindow` (`box2i`) gives a
//! positive size within [`MAX_SIDE_PX`] per side and [`MAX_PIXELS`] in all;
//! the `compression` is one the `exr` crate decodes (codes 0–9); the
//! `channels` hold R, G and B, or Y; the file is long enough to hold the
//! offset table and the smallest possible chunks; and the uncompressed
//! pixel data is at most [`MAX_COMPRESSION_RATIO`] times the file size.

/// Largest width or height of a scene, pixels.
pub const MAX_SIDE_PX: u64 = 32_768;
/// Largest pixel count of a scene (16k × 8k): 1.5 GiB as linear RGB f32.
pub const MAX_PIXELS: u64 = 16_384 * 8_192;
/// Largest ratio of uncompressed pixel bytes to file bytes believed. zlib
/// (ZIP) tops out near 1032:1; RLE at 64:1; DWA and PIZ lower on real data.
pub const MAX_COMPRESSION_RATIO: u64 = 2_048;

/// Compression codes of OpenEXR and their names; 0–9 are what the `exr`
/// crate decodes.
const COMPRESSION_NAMES: [&str; 10] = [
    "NONE", "RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "B44A", "DWAA", "DWAB",
];

/// Scan lines per chunk of each compression (OpenEXR file layout).
fn lines_per_chunk(compression: u8) -> u64 {
    match compression {
        0..=2 => 1,
        3 | 5 => 16,
        4 | 6..=8 => 32,
        _ => 256, // DWAB
    }
}

/// What the header says about the image (first part; all parts checked).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ExrHeader {
    pub width: u64,
    pub height: u64,
    pub channels: Vec<String>,
    pub compression: u8,
}

impl ExrHeader {
    /// Whether the image has R, G and B channels.
    pub fn has_rgb(&self) -> bool {
        ["R", "G", "B"]
            .iter()
            .all(|c| self.channels.iter().any(|n| n == c))
    }

    /// Whether the image has a Y (luminance) channel.
    pub fn has_y(&self) -> bool {
        self.channels.iter().any(|n| n == "Y")
    }
}

/// Why a header was refused; `unsupported` marks a valid file using a
/// feature the reader lacks (as opposed to a corrupt one).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HeaderProblem {
    pub unsupported: bool,
    pub reason: String,
}

fn corrupt(reason: impl Into<String>) -> HeaderProblem {
    HeaderProblem {
        unsupported: false,
        reason: reason.into(),
    }
}

fn unsupported(reason: impl Into<String>) -> HeaderProblem {
    HeaderProblem {
        unsupported: true,
        reason: reason.into(),
    }
}

struct Cursor<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], HeaderProblem> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.b.len())
            .ok_or_else(|| corrupt(format!("the header ends inside {what} (byte {})", self.at)))?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }

    /// A NUL-terminated string of at most 255 bytes.
    fn cstr(&mut self, what: &str) -> Result<&'a str, HeaderProblem> {
        let rest = &self.b[self.at.min(self.b.len())..];
        let n = rest.iter().take(256).position(|&c| c == 0).ok_or_else(|| {
            corrupt(format!(
                "{what} at byte {} is not a short NUL-terminated name",
                self.at
            ))
        })?;
        let s = std::str::from_utf8(&rest[..n])
            .map_err(|_| corrupt(format!("{what} at byte {} is not text", self.at)))?;
        self.at += n + 1;
        Ok(s)
    }

    fn i32(b: &[u8], at: usize) -> i32 {
        i32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
    }
}

#[derive(Default)]
struct Part {
    data_window: Option<[i32; 4]>,
    compression: Option<u8>,
    channels: Option<Vec<(String, i32)>>,
    tiles: Option<(u32, u32)>,
    chunk_count: Option<i32>,
    deep: bool,
}

fn parse_channels(v: &[u8]) -> Result<Vec<(String, i32)>, HeaderProblem> {
    let mut c = Cursor { b: v, at: 0 };
    let mut out = Vec::new();
    loop {
        if c.at >= v.len() {
            return Err(corrupt("the channel list is not closed by a NUL"));
        }
        if v[c.at] == 0 {
            return Ok(out);
        }
        let name = c.cstr("a channel name")?.to_owned();
        let rest = c.take(16, "a channel description")?;
        let pixel_type = Cursor::i32(rest, 0);
        let (xs, ys) = (Cursor::i32(rest, 8), Cursor::i32(rest, 12));
        if !(0..=2).contains(&pixel_type) {
            return Err(corrupt(format!(
                "channel `{name}` has pixel type {pixel_type} (expected 0 uint, 1 half or 2 float)"
            )));
        }
        if xs < 1 || ys < 1 {
            return Err(corrupt(format!("channel `{name}` has sampling {xs}×{ys}")));
        }
        if out.len() >= 1024 {
            return Err(corrupt("more than 1024 channels"));
        }
        out.push((name, pixel_type));
    }
}

/// Reads and checks the header(s) of an OpenEXR file held in `bytes`.
pub fn check(bytes: &[u8]) -> Result<ExrHeader, HeaderProblem> {
    let mut c = Cursor { b: bytes, at: 0 };
    let magic = c.take(4, "the magic number")?;
    if magic != [0x76, 0x2f, 0x31, 0x01] {
        return Err(corrupt("not an OpenEXR file (magic number)"));
    }
    let v = c.take(4, "the version field")?;
    let version = v[0];
    let flags = u32::from_le_bytes([v[0], v[1], v[2], v[3]]) >> 8;
    if version != 2 {
        return Err(unsupported(format!(
            "OpenEXR format version {version} (expected 2)"
        )));
    }
    let single_tiled = flags & (1 << 1) != 0;
    let deep_flag = flags & (1 << 3) != 0;
    let multi_part = flags & (1 << 4) != 0;

    let mut parts: Vec<Part> = Vec::new();
    loop {
        // Multi-part: an empty header (a lone NUL) ends the list.
        if multi_part && !parts.is_empty() && bytes.get(c.at) == Some(&0) {
            c.at += 1;
            break;
        }
        if parts.len() >= 64 {
            return Err(unsupported("more than 64 parts"));
        }
        let mut part = Part::default();
        loop {
            if bytes.get(c.at) == Some(&0) {
                c.at += 1;
                break;
            }
            let name = c.cstr("an attribute name")?;
            let ty = c.cstr("an attribute type")?;
            let size = Cursor::i32(c.take(4, "an attribute size")?, 0);
            let size = usize::try_from(size)
                .map_err(|_| corrupt(format!("attribute `{name}` has size {size}")))?;
            let value = c.take(size, &format!("attribute `{name}` ({size} bytes)"))?;
            match (name, ty) {
                ("dataWindow", "box2i") if size == 16 => {
                    part.data_window = Some([
                        Cursor::i32(value, 0),
                        Cursor::i32(value, 4),
                        Cursor::i32(value, 8),
                        Cursor::i32(value, 12),
                    ]);
                }
                ("compression", "compression") if size == 1 => part.compression = Some(value[0]),
                ("channels", "chlist") => part.channels = Some(parse_channels(value)?),
                ("tiles", "tiledesc") if size == 9 => {
                    let xs = u32::from_le_bytes([value[0], value[1], value[2], value[3]]);
                    let ys = u32::from_le_bytes([value[4], value[5], value[6], value[7]]);
                    part.tiles = Some((xs, ys));
                }
                ("chunkCount", "int") if size == 4 => {
                    part.chunk_count = Some(Cursor::i32(value, 0))
                }
                ("type", "string") => {
                    part.deep = value.starts_with(b"deep");
                }
                _ => {}
            }
        }
        parts.push(part);
        if !multi_part {
            break;
        }
    }
    if deep_flag || parts.iter().any(|p| p.deep) {
        return Err(unsupported("deep data (a scene must be a flat image)"));
    }

    let mut min_bytes = c.at as u64;
    let mut unpacked_bytes: u64 = 0;
    let mut first: Option<ExrHeader> = None;
    for (i, p) in parts.iter().enumerate() {
        let part = if parts.len() > 1 {
            format!("part {i}: ")
        } else {
            String::new()
        };
        let [x0, y0, x1, y1] = p
            .data_window
            .ok_or_else(|| corrupt(format!("{part}no dataWindow attribute")))?;
        let w = i64::from(x1) - i64::from(x0) + 1;
        let h = i64::from(y1) - i64::from(y0) + 1;
        if w < 1 || h < 1 {
            return Err(corrupt(format!(
                "{part}the data window ({x0},{y0})–({x1},{y1}) is empty"
            )));
        }
        let (w, h) = (w as u64, h as u64);
        if w > MAX_SIDE_PX || h > MAX_SIDE_PX || w * h > MAX_PIXELS {
            return Err(corrupt(format!(
                "{part}the header claims {w}×{h} pixels; a scene may have at most \
                 {MAX_SIDE_PX} per side and {MAX_PIXELS} in all"
            )));
        }
        let compression = p
            .compression
            .ok_or_else(|| corrupt(format!("{part}no compression attribute")))?;
        if usize::from(compression) >= COMPRESSION_NAMES.len() {
            let known = match compression {
                10 | 11 => " (HTJ2K, OpenEXR 3.4)",
                12 => " (ZSTD, OpenEXR 3.4)",
                _ => "",
            };
            return Err(unsupported(format!(
                "{part}unsupported compression: code {compression}{known}; the reader decodes {} — \
                 re-save the file with one of them (e.g. ZIP or PIZ)",
                COMPRESSION_NAMES.join(", ")
            )));
        }
        let channels = p
            .channels
            .as_ref()
            .ok_or_else(|| corrupt(format!("{part}no channels attribute")))?;
        let bytes_per_px: u64 = channels
            .iter()
            .map(|(_, t)| if *t == 1 { 2 } else { 4 })
            .sum();
        let chunks = match (single_tiled || p.tiles.is_some(), p.tiles) {
            (true, Some((tx, ty))) if tx > 0 && ty > 0 => {
                w.div_ceil(u64::from(tx)) * h.div_ceil(u64::from(ty))
            }
            (true, _) => {
                return Err(corrupt(format!(
                    "{part}tiled without a valid tiles attribute"
                )));
            }
            (false, _) => h.div_ceil(lines_per_chunk(compression)),
        };
        if let Some(n) = p.chunk_count
            && (n < 1 || n as u64 > chunks.saturating_mul(64))
        {
            return Err(corrupt(format!(
                "{part}chunkCount {n} does not fit the data window"
            )));
        }
        // The offset table (8 bytes a chunk) and each chunk's own header
        // (at least 8 bytes) must be in the file.
        min_bytes += chunks * 16;
        unpacked_bytes += w * h * bytes_per_px;
        if first.is_none() {
            first = Some(ExrHeader {
                width: w,
                height: h,
                channels: channels.iter().map(|(n, _)| n.clone()).collect(),
                compression,
            });
        }
    }
    let len = bytes.len() as u64;
    if len < min_bytes {
        return Err(corrupt(format!(
            "the file is {len} bytes but its header needs at least {min_bytes} \
             (offset table and chunks): it is truncated or its header lies"
        )));
    }
    if unpacked_bytes > len.saturating_mul(MAX_COMPRESSION_RATIO) {
        return Err(corrupt(format!(
            "the header claims {unpacked_bytes} bytes of pixels in a {len}-byte file \
             (more than {MAX_COMPRESSION_RATIO}:1)"
        )));
    }
    let header = first.ok_or_else(|| corrupt("no header"))?;
    if !header.has_rgb() && !header.has_y() {
        return Err(unsupported(format!(
            "channels [{}]: a scene needs R, G and B (colour) or Y (luminance)",
            header.channels.join(", ")
        )));
    }
    Ok(header)
}
