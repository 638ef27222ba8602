//! Pupil Labs Neon native recordings.
//!
//! A Neon recording is a directory. Each stream `<name>` has a layout file
//! `<name>.dtype` (a NumPy structured dtype written as a Python list of
//! `("field", "type")` tuples, packed, little-endian), one or more parts
//! `<name> psN.raw` of fixed-size records in that layout, and beside each
//! part `<name> psN.time`, one little-endian `u64` Unix timestamp in
//! nanoseconds per record. `info.json` holds `start_time` (ns).
//!
//! What this importer reads:
//!
//! - `eye_state`: `pupil_diameter_left_mm` / `pupil_diameter_right_mm`
//!   become one [`PupilSample`] per eye (unit mm; eye 1 = left, 0 = right).
//!   Neon reports no pupil confidence and keeps estimating a diameter while
//!   the lid is closed (the demo recording reads 1–2.5 mm during its
//!   blinks), so the **confidence is derived from the eyelid aperture**
//!   (`eyelid_aperture_left_mm` / `_right_mm`) when the layout has it:
//!   0 at or below [`APERTURE_CLOSED_MM`], 1 at or above
//!   [`APERTURE_OPEN_MM`], linear in between. Without eyelid fields the
//!   confidence is 1 for a finite positive diameter.
//! - `gaze` (else `gaze_200hz`): `x`, `y` in scene-camera pixels, divided by
//!   the 1600×1200 scene camera ([`SCENE_CAMERA_PX`]) into top-left-origin
//!   normalised coordinates; binocular, confidence 1 when finite.
//! - `blinks` (optional): `start_timestamp_ns`, `end_timestamp_ns` become
//!   [`BlinkEvent`]s covering both eyes.
//! - per-eye gaze: each `eye_state` row's `optical_axis_{left,right}_*`
//!   (with `eyeball_center_*` checked) becomes a [`GazeEyes::Left`] /
//!   [`GazeEyes::Right`] [`GazeSample`] at the row's time, projected into
//!   the scene image with the intrinsics of `calibration.bin`
//!   ([`scene_camera`]) — see [`PerEyeGaze`] for what is projected and why.
//!   Without `calibration.bin` (a warning) or without the geometry fields
//!   there is binocular gaze only; [`Importer::eye_gaze`] says which.
//!
//! Times are seconds since `info.json`'s `start_time` (or since the first
//! eye-state record when that is missing). The three streams are merged in
//! time order; one `eye_state` row gives the right then the left pupil,
//! then the left and right gaze.

pub mod scene_camera;

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use super::{EyeGazeReport, ImportError, ImportWarnings, Importer, Pending, Position};
use gazelight_eye::sample::{
    BlinkEvent, DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample,
};
pub use scene_camera::SceneCamera;

/// Neon scene camera resolution (px), for gaze normalisation
/// (`gazelight_eye`'s one definition).
pub const SCENE_CAMERA_PX: [f32; 2] = gazelight_eye::sample::NEON_SCENE_CAMERA_PX;
/// Eyelid aperture at or below which the eye counts as closed (confidence 0).
/// Open eyes in the demo recording measure 5–9 mm, closed ones 0–0.5 mm.
pub const APERTURE_CLOSED_MM: f32 = 1.0;
/// Eyelid aperture at or above which the eye counts as fully open
/// (confidence 1).
pub const APERTURE_OPEN_MM: f32 = 3.0;

/// Scalar field types a `.dtype` file may use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl FieldType {
    fn parse(s: &str) -> Option<Self> {
        let s = s.trim_start_matches(['<', '=', '|']);
        Some(match s {
            "int8" | "i1" => Self::I8,
            "uint8" | "u1" => Self::U8,
            "int16" | "i2" => Self::I16,
            "uint16" | "u2" => Self::U16,
            "int32" | "i4" => Self::I32,
            "uint32" | "u4" => Self::U32,
            "int64" | "i8" => Self::I64,
            "uint64" | "u8" => Self::U64,
            "float32" | "f4" => Self::F32,
            "float64" | "f8" => Self::F64,
            _ => return None,
        })
    }

    /// Size in bytes.
    pub fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 | Self::U64 | Self::F64 => 8,
        }
    }

    /// Reads the value at the start of `b` (little-endian) as f64.
    fn read_f64(self, b: &[u8]) -> f64 {
        let mut a8 = [0u8; 8];
        let n = self.size().min(b.len());
        a8[..n].copy_from_slice(&b[..n]);
        match self {
            Self::I8 => a8[0] as i8 as f64,
            Self::U8 => a8[0] as f64,
            Self::I16 => i16::from_le_bytes([a8[0], a8[1]]) as f64,
            Self::U16 => u16::from_le_bytes([a8[0], a8[1]]) as f64,
            Self::I32 => i32::from_le_bytes([a8[0], a8[1], a8[2], a8[3]]) as f64,
            Self::U32 => u32::from_le_bytes([a8[0], a8[1], a8[2], a8[3]]) as f64,
            Self::F32 => f32::from_le_bytes([a8[0], a8[1], a8[2], a8[3]]) as f64,
            Self::I64 => i64::from_le_bytes(a8) as f64,
            Self::U64 => u64::from_le_bytes(a8) as f64,
            Self::F64 => f64::from_le_bytes(a8),
        }
    }

    fn read_i64(self, b: &[u8]) -> i64 {
        match self {
            Self::I64 => {
                let mut a8 = [0u8; 8];
                a8.copy_from_slice(&b[..8]);
                i64::from_le_bytes(a8)
            }
            Self::U64 => {
                let mut a8 = [0u8; 8];
                a8.copy_from_slice(&b[..8]);
                u64::from_le_bytes(a8) as i64
            }
            other => other.read_f64(b) as i64,
        }
    }
}

/// A packed record layout read from a `.dtype` file.
#[derive(Clone, Debug, PartialEq)]
pub struct Dtype {
    /// `(name, type, byte offset)` per field.
    pub fields: Vec<(String, FieldType, usize)>,
    /// Record size in bytes.
    pub record_size: usize,
}

impl Dtype {
    /// Parses the text of a `.dtype` file; `path` is used in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ImportError> {
        let mut fields = Vec::new();
        let mut offset = 0usize;
        let mut rest = text;
        let line_of = |pos: usize| text[..pos].matches('\n').count() as u64 + 1;
        while let Some(open) = rest.find('(') {
            let abs = text.len() - rest.len() + open;
            let Some(close) = rest[open..].find(')') else {
                return Err(ImportError::Structure {
                    path: path.to_owned(),
                    position: Position::Line(line_of(abs)),
                    reason: "unclosed `(` in dtype".into(),
                });
            };
            let tuple = &rest[open + 1..open + close];
            let quoted: Vec<&str> = tuple.split('"').skip(1).step_by(2).collect();
            let quoted = if quoted.len() == 2 {
                quoted
            } else {
                tuple.split('\'').skip(1).step_by(2).collect()
            };
            if quoted.len() != 2 {
                return Err(ImportError::Structure {
                    path: path.to_owned(),
                    position: Position::Line(line_of(abs)),
                    reason: format!("expected (\"name\", \"type\"), found `({tuple})`"),
                });
            }
            let Some(ty) = FieldType::parse(quoted[1]) else {
                return Err(ImportError::Structure {
                    path: path.to_owned(),
                    position: Position::Line(line_of(abs)),
                    reason: format!("field `{}`: unsupported type `{}`", quoted[0], quoted[1]),
                });
            };
            fields.push((quoted[0].to_owned(), ty, offset));
            offset += ty.size();
            rest = &rest[open + close + 1..];
        }
        if fields.is_empty() {
            return Err(ImportError::Structure {
                path: path.to_owned(),
                position: Position::File,
                reason: "no fields in dtype".into(),
            });
        }
        Ok(Self {
            fields,
            record_size: offset,
        })
    }

    /// Reads and parses a `.dtype` file.
    pub fn load(path: &Path) -> Result<Self, ImportError> {
        let text = gazelight_input::read_to_string(path, gazelight_input::MAX_TEXT_BYTES).map_err(
            |source| ImportError::Io {
                path: path.to_owned(),
                source,
            },
        )?;
        Self::parse(&text, path)
    }

    /// The field named `name`: its type and offset.
    pub fn field(&self, name: &str) -> Option<(FieldType, usize)> {
        self.fields
            .iter()
            .find(|(n, _, _)| n == name)
            .map(|&(_, t, o)| (t, o))
    }

    fn require(&self, name: &str, path: &Path) -> Result<(FieldType, usize), ImportError> {
        self.field(name).ok_or_else(|| ImportError::Structure {
            path: path.to_owned(),
            position: Position::File,
            reason: format!("missing field `{name}`"),
        })
    }
}

/// One stream's parts (`<name> psN.raw` + `.time`), read record by record.
struct BinStream {
    parts: Vec<(PathBuf, PathBuf)>,
    part: usize,
    readers: Option<(BufReader<File>, BufReader<File>)>,
    record_size: usize,
    /// Byte offset of the next record in the current raw part.
    offset: u64,
    buf: Vec<u8>,
}

impl BinStream {
    /// Finds the parts of stream `name` in `dir`, in part order.
    fn find(dir: &Path, name: &str, record_size: usize) -> Result<Option<Self>, ImportError> {
        let mut parts = Vec::new();
        for n in 1..=999u32 {
            let raw = dir.join(format!("{name} ps{n}.raw"));
            if !super::data_file(&raw)? {
                break;
            }
            let time = dir.join(format!("{name} ps{n}.time"));
            if !super::data_file(&time)? {
                return Err(ImportError::Structure {
                    path: time,
                    position: Position::File,
                    reason: format!("missing timestamps for {}", raw.display()),
                });
            }
            parts.push((raw, time));
        }
        if parts.is_empty() {
            // Neon also writes some streams without a part suffix (`gaze_200hz.raw`).
            let raw = dir.join(format!("{name}.raw"));
            let time = dir.join(format!("{name}.time"));
            if super::data_file(&raw)? && super::data_file(&time)? {
                parts.push((raw, time));
            }
        }
        if parts.is_empty() {
            return Ok(None);
        }
        Ok(Some(Self {
            parts,
            part: 0,
            readers: None,
            record_size,
            offset: 0,
            buf: vec![0; record_size],
        }))
    }

    /// Next `(timestamp_ns, record)`; `None` at the end. Truncated trailing
    /// records and timestamp/record count mismatches are counted warnings.
    fn next_record(
        &mut self,
        warnings: &mut ImportWarnings,
    ) -> Option<Result<(u64, &[u8]), ImportError>> {
        loop {
            if self.part >= self.parts.len() {
                return None;
            }
            if self.readers.is_none() {
                let (raw, time) = &self.parts[self.part];
                let open = |p: &PathBuf| {
                    gazelight_input::open(p)
                        .map(BufReader::new)
                        .map_err(|source| ImportError::Io {
                            path: p.clone(),
                            source,
                        })
                };
                let r = match open(raw) {
                    Ok(r) => r,
                    Err(e) => {
                        self.part = self.parts.len();
                        return Some(Err(e));
                    }
                };
                let t = match open(time) {
                    Ok(t) => t,
                    Err(e) => {
                        self.part = self.parts.len();
                        return Some(Err(e));
                    }
                };
                self.readers = Some((r, t));
                self.offset = 0;
            }
            let (raw_path, time_path) = &self.parts[self.part];
            let (raw, time) = self.readers.as_mut()?;
            let raw_n = read_full(raw, &mut self.buf);
            let mut tb = [0u8; 8];
            let time_n = read_full(time, &mut tb);
            let (raw_n, time_n) = match (raw_n, time_n) {
                (Ok(a), Ok(b)) => (a, b),
                (Err(source), _) => {
                    self.part = self.parts.len();
                    return Some(Err(ImportError::Io {
                        path: raw_path.clone(),
                        source,
                    }));
                }
                (_, Err(source)) => {
                    self.part = self.parts.len();
                    return Some(Err(ImportError::Io {
                        path: time_path.clone(),
                        source,
                    }));
                }
            };
            let full_raw = raw_n == self.record_size;
            let full_time = time_n == 8;
            if full_raw && full_time {
                self.offset += self.record_size as u64;
                return Some(Ok((u64::from_le_bytes(tb), &self.buf[..])));
            }
            // End of this part: report anything left over.
            if raw_n > 0 && !full_raw {
                warnings.skip(
                    raw_path,
                    Position::Byte(self.offset),
                    format!("truncated record: {raw_n} of {} bytes", self.record_size),
                );
            } else if full_raw && !full_time {
                warnings.skip(
                    raw_path,
                    Position::Byte(self.offset),
                    format!("record without a timestamp in {}", time_path.display()),
                );
            } else if !full_raw && full_time {
                warnings.skip(
                    time_path,
                    Position::Byte(self.offset / self.record_size as u64 * 8),
                    format!("timestamp without a record in {}", raw_path.display()),
                );
            }
            self.readers = None;
            self.part += 1;
        }
    }
}

/// Reads until `buf` is full or EOF; returns the bytes read.
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// Offsets of the fields the importer reads from `eye_state`, each pair
/// `[right, left]`.
#[derive(Clone, Copy, Debug)]
struct EyeLayout {
    pupil: [(FieldType, usize); 2],
    aperture: Option<[(FieldType, usize); 2]>,
    /// `eyeball_center_*_{x,y,z}` then `optical_axis_*_{x,y,z}` per eye.
    geometry: Option<[[(FieldType, usize); 6]; 2]>,
}

impl EyeLayout {
    fn read(dtype: &Dtype, path: &Path) -> Result<Self, ImportError> {
        let geometry = |side: &str| -> Option<[(FieldType, usize); 6]> {
            let mut g = [(FieldType::F32, 0); 6];
            for (i, name) in ["eyeball_center", "optical_axis"]
                .iter()
                .flat_map(|what| ["x", "y", "z"].map(|a| format!("{what}_{side}_{a}")))
                .enumerate()
            {
                g[i] = dtype.field(&name)?;
            }
            Some(g)
        };
        Ok(Self {
            pupil: [
                dtype.require("pupil_diameter_right_mm", path)?,
                dtype.require("pupil_diameter_left_mm", path)?,
            ],
            aperture: match (
                dtype.field("eyelid_aperture_right_mm"),
                dtype.field("eyelid_aperture_left_mm"),
            ) {
                (Some(r), Some(l)) => Some([r, l]),
                _ => None,
            },
            geometry: geometry("right").zip(geometry("left")).map(|(r, l)| [r, l]),
        })
    }

    /// One eye's `(pupil mm, lid confidence, geometry)` from a record.
    fn eye(&self, rec: &[u8], eye: usize) -> EyeRow {
        let (ty, off) = self.pupil[eye];
        let lid_confidence = match self.aperture {
            Some(a) => aperture_confidence(a[eye].0.read_f64(&rec[a[eye].1..]) as f32),
            None => 1.0,
        };
        let aperture = self
            .aperture
            .map(|a| a[eye].0.read_f64(&rec[a[eye].1..]) as f32);
        let geometry = self.geometry.map(|g| {
            let v = |i: usize| g[eye][i].0.read_f64(&rec[g[eye][i].1..]);
            ([v(0), v(1), v(2)], [v(3), v(4), v(5)])
        });
        EyeRow {
            pupil_mm: ty.read_f64(&rec[off..]) as f32,
            aperture,
            lid_confidence,
            geometry,
        }
    }
}

/// One eye of an `eye_state` row.
#[derive(Clone, Copy, Debug)]
struct EyeRow {
    pupil_mm: f32,
    aperture: Option<f32>,
    /// From the eyelid aperture; 1 without eyelid fields.
    lid_confidence: f32,
    /// `(eyeball centre mm, optical axis)` in the scene camera frame.
    geometry: Option<([f64; 3], [f64; 3])>,
}

impl EyeRow {
    /// The optical axis, when the row's geometry is usable: all six values
    /// finite, the eyeball centre not the zero vector, the axis of unit
    /// length (±10 %; Neon writes unit vectors, a zero vector means "no
    /// estimate").
    fn axis(&self) -> Option<[f64; 3]> {
        let (c, a) = self.geometry?;
        let finite = c.iter().chain(&a).all(|v| v.is_finite());
        let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        (finite && norm(c) > 0.0 && (norm(a) - 1.0).abs() < 0.1).then_some(a)
    }
}

/// Pupil (and per-eye gaze) confidence from the eyelid aperture, mm.
fn aperture_confidence(a: f32) -> f32 {
    if a.is_finite() {
        ((a - APERTURE_CLOSED_MM) / (APERTURE_OPEN_MM - APERTURE_CLOSED_MM)).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// How the importer makes per-eye gaze from each eye's optical axis.
///
/// Neon's `eye_state` gives each eye's **optical axis** (a unit vector from
/// the eyeball centre, scene camera frame: x right, y down, z forward). A
/// ray from an eyeball centre ~35 mm behind and ~31 mm beside the scene
/// camera images as a line in the scene image whose point depends on the
/// (unknown) viewing distance; the importer projects the axis's **vanishing
/// point** (the direction alone, i.e. the ray at infinity). That is
/// parallax-free and, on the demo recording, the choice that agrees best
/// with Neon's binocular gaze (the mean of both eyes lies a median 4.2°
/// from it at infinity, 4.9° at 1 m, 5.7° at 0.5 m). The eyeball centre
/// is only checked (a NaN or zero centre means no eye model: no gaze).
///
/// The optical axis is not the line of sight: the visual axis through the
/// fovea differs from it by the angle kappa (~5°, nasal and often a little
/// up), so the raw optical axes of two eyes fixating one point diverge
/// (on the demo recording the left eye's axis projects a median 6.0° and
/// the right one's 3.0° from the binocular gaze, both below it). For a
/// renderer that places each eye's fovea that is too much, hence the
/// default [`PerEyeGaze::KappaCorrected`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PerEyeGaze {
    /// The optical axis plus a constant per-eye offset: the median, over
    /// the recording's rows where the eye is open and the binocular gaze is
    /// valid, of (binocular gaze − this eye's optical axis) in undistorted
    /// normalised scene coordinates (x/z, y/z). A first streaming pass over
    /// `eye_state` and `gaze` collects the offsets into fixed histograms
    /// ([`KAPPA_BIN`] wide, bounded memory whatever the length) before any
    /// sample is emitted. A constant offset per eye is what kappa is (a
    /// property of the eye, fixed in the eye's frame, nearly fixed in the
    /// scene camera's for gaze within ±30°); it removes each eye's mean
    /// disagreement with Neon's own binocular gaze (which carries the
    /// wearer's offset correction, `info.json` `gaze_offset`) but keeps the
    /// eyes' relative movement, vergence included. With fewer than
    /// [`KAPPA_MIN_ROWS`] usable rows an eye stays uncorrected (reported in
    /// [`EyeGazeReport::correction_deg`]). On the demo recording the
    /// offsets are right (+0.9°, −2.6°), left (+5.0°, −3.4°) (x right,
    /// y down), and the mean of the two eyes then lies a median 1.3° (95th
    /// percentile 3.5°) from the binocular gaze, against 4.2° (6.2°)
    /// uncorrected.
    ///
    /// A median over the whole recording, not a running one, so that early
    /// samples are corrected like late ones; the price is the extra pass at
    /// open (the recording's `eye_state` and `gaze` files read twice).
    #[default]
    KappaCorrected,
    /// The optical axis's vanishing point as Neon reports it.
    OpticalAxis,
    /// Binocular gaze only.
    Off,
}

/// Histogram bin of the kappa offsets, undistorted normalised units
/// (0.0005 ≈ 0.03° ≈ 0.44 px at the image centre).
pub const KAPPA_BIN: f64 = 0.0005;
/// Offsets are histogrammed within ±this (≈ ±31°); beyond it they count in
/// the end bins.
pub const KAPPA_RANGE: f64 = 0.6;
/// Rows an eye needs (open, valid binocular gaze) for a kappa correction.
pub const KAPPA_MIN_ROWS: u64 = 200;
/// An `eye_state` row and a `gaze` row this close in time are one frame, ns.
pub const PAIR_TOLERANCE_NS: u64 = 2_500_000;

/// A fixed histogram for a median of bounded memory.
struct MedianHistogram {
    bins: Vec<u32>,
    count: u64,
}

impl MedianHistogram {
    fn new() -> Self {
        Self {
            bins: vec![0; (2.0 * KAPPA_RANGE / KAPPA_BIN).round() as usize],
            count: 0,
        }
    }

    fn push(&mut self, v: f64) {
        let n = self.bins.len();
        let i = ((v + KAPPA_RANGE) / KAPPA_BIN)
            .floor()
            .clamp(0.0, (n - 1) as f64) as usize;
        self.bins[i] = self.bins[i].saturating_add(1);
        self.count += 1;
    }

    /// The median (centre of the bin holding it).
    fn median(&self) -> Option<f64> {
        if self.count == 0 {
            return None;
        }
        let half = self.count.div_ceil(2);
        let mut seen = 0u64;
        for (i, &c) in self.bins.iter().enumerate() {
            seen += u64::from(c);
            if seen >= half {
                return Some((i as f64 + 0.5) * KAPPA_BIN - KAPPA_RANGE);
            }
        }
        None
    }
}

/// Streaming importer of a Neon native recording directory.
pub struct NeonImporter {
    dir: PathBuf,
    start_ns: Option<u64>,
    eye: Option<BinStream>,
    eye_layout: EyeLayout,
    gaze: Option<BinStream>,
    gaze_xy: [(FieldType, usize); 2],
    blinks: Option<BinStream>,
    blink_fields: [(FieldType, usize); 2],
    peek_eye: Option<(f64, [PupilSample; 2], [Option<GazeSample>; 2])>,
    /// Scene camera and per-eye offset (normalised units) `[right, left]`,
    /// when per-eye gaze is produced.
    eye_gaze_model: Option<EyeGazeModel>,
    eye_gaze: EyeGazeReport,
    peek_gaze: Option<GazeSample>,
    peek_blink: Option<BlinkEvent>,
    duration_secs: Option<f64>,
    /// `info.json`'s `gaze_frequency`, Hz.
    gaze_frequency_hz: Option<f64>,
    pending: Pending<4>,
    warnings: ImportWarnings,
    failed: bool,
}

impl NeonImporter {
    /// Opens a Neon recording directory: reads `info.json` and the layouts;
    /// per-eye gaze [`PerEyeGaze::KappaCorrected`].
    pub fn open(dir: &Path) -> Result<Self, ImportError> {
        Self::open_with(dir, PerEyeGaze::default())
    }

    /// Opens a Neon recording directory with per-eye gaze made as `mode`
    /// says. A `calibration.bin` that is there but unreadable is an error
    /// naming it; one that is missing is a warning (binocular gaze only).
    pub fn open_with(dir: &Path, mode: PerEyeGaze) -> Result<Self, ImportError> {
        let info_path = dir.join("info.json");
        let info_text =
            gazelight_input::read_config(&info_path, gazelight_input::ConfigSyntax::Json).map_err(
                |source| ImportError::Io {
                    path: info_path.clone(),
                    source,
                },
            )?;
        let info: serde_json::Value =
            serde_json::from_str(&info_text).map_err(|e| ImportError::Structure {
                path: info_path.clone(),
                position: Position::Line(e.line() as u64),
                reason: format!("not valid JSON: {e}"),
            })?;
        let start_ns = info.get("start_time").and_then(|v| v.as_u64());
        // The recording's length, when info.json gives it with its start.
        let duration_secs = start_ns
            .and(info.get("duration").and_then(|v| v.as_u64()))
            .map(|ns| ns as f64 * 1e-9);

        let eye_dtype_path = dir.join("eye_state.dtype");
        let eye_dtype = Dtype::load(&eye_dtype_path)?;
        let eye_layout = EyeLayout::read(&eye_dtype, &eye_dtype_path)?;
        let eye = BinStream::find(dir, "eye_state", eye_dtype.record_size)?;
        if eye.is_none() {
            return Err(ImportError::Structure {
                path: dir.join("eye_state ps1.raw"),
                position: Position::File,
                reason: "no eye_state data in the recording".into(),
            });
        }

        let gaze_dtype_path = dir.join("gaze.dtype");
        let (gaze, gaze_xy) = if gaze_dtype_path.is_file() {
            let d = Dtype::load(&gaze_dtype_path)?;
            let xy = [
                d.require("x", &gaze_dtype_path)?,
                d.require("y", &gaze_dtype_path)?,
            ];
            (find_gaze(dir, d.record_size)?, xy)
        } else {
            (None, [(FieldType::F32, 0), (FieldType::F32, 4)])
        };

        let mut warnings = ImportWarnings::default();
        let (eye_gaze_model, eye_gaze) = eye_gaze_model(
            dir,
            mode,
            &eye_layout,
            eye_dtype.record_size,
            gaze.as_ref().map(|g| (g.record_size, gaze_xy)),
            &mut warnings,
        )?;

        let blinks_dtype_path = dir.join("blinks.dtype");
        let (blinks, blink_fields) = if blinks_dtype_path.is_file() {
            let d = Dtype::load(&blinks_dtype_path)?;
            let f = [
                d.require("start_timestamp_ns", &blinks_dtype_path)?,
                d.require("end_timestamp_ns", &blinks_dtype_path)?,
            ];
            (BinStream::find(dir, "blinks", d.record_size)?, f)
        } else {
            (None, [(FieldType::I64, 0), (FieldType::I64, 8)])
        };

        Ok(Self {
            dir: dir.to_owned(),
            start_ns,
            eye,
            eye_layout,
            gaze,
            gaze_xy,
            blinks,
            blink_fields,
            peek_eye: None,
            eye_gaze_model,
            eye_gaze,
            peek_gaze: None,
            peek_blink: None,
            duration_secs,
            gaze_frequency_hz: info
                .get("gaze_frequency")
                .and_then(serde_json::Value::as_f64)
                .and_then(super::plausible_rate),
            pending: Pending::new(),
            warnings,
            failed: false,
        })
    }

    /// The recording directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn secs(&mut self, ns: u64) -> f64 {
        let start = *self.start_ns.get_or_insert(ns);
        (ns as i128 - start as i128) as f64 * 1e-9
    }

    fn secs_i64(&mut self, ns: i64) -> f64 {
        let start = *self.start_ns.get_or_insert(ns.max(0) as u64);
        (ns as i128 - start as i128) as f64 * 1e-9
    }

    fn fill_eye(&mut self) -> Result<(), ImportError> {
        if self.peek_eye.is_some() {
            return Ok(());
        }
        let Some(stream) = self.eye.as_mut() else {
            return Ok(());
        };
        let layout = self.eye_layout;
        let (ns, rows) = match stream.next_record(&mut self.warnings) {
            None => {
                self.eye = None;
                return Ok(());
            }
            Some(Err(e)) => return Err(e),
            Some(Ok((ns, rec))) => (ns, [layout.eye(rec, 0), layout.eye(rec, 1)]),
        };
        let t = self.secs(ns);
        let mk = |eye: u8, row: &EyeRow| {
            let d = row.pupil_mm;
            let valid = d.is_finite() && d > 0.0;
            let confidence = match row.aperture {
                _ if !valid => 0.0,
                Some(a) => aperture_confidence(a),
                None => 1.0,
            };
            PupilSample {
                t_secs: t,
                eye,
                diameter_raw: d,
                unit: PupilUnit::Mm,
                diameter_mm: valid.then_some(d),
                confidence,
                norm_pos: [f32::NAN, f32::NAN],
                method: DetectorMethod::Other,
            }
        };
        let mut gaze = [None; 2];
        if let Some((cam, offsets)) = &self.eye_gaze_model {
            for (eye, which) in [(0usize, GazeEyes::Right), (1, GazeEyes::Left)] {
                let px = rows[eye]
                    .axis()
                    .and_then(|a| eye_gaze_px(cam, a, offsets[eye]));
                match px {
                    Some(px) => {
                        self.eye_gaze.emitted[eye] += 1;
                        gaze[eye] = Some(GazeSample {
                            t_secs: t,
                            gaze_uv: [
                                (px[0] as f32) / SCENE_CAMERA_PX[0],
                                (px[1] as f32) / SCENE_CAMERA_PX[1],
                            ],
                            confidence: rows[eye].lid_confidence,
                            eyes: which,
                        });
                    }
                    None => self.eye_gaze.missing[eye] += 1,
                }
            }
        }
        self.peek_eye = Some((t, [mk(0, &rows[0]), mk(1, &rows[1])], gaze));
        Ok(())
    }

    fn fill_gaze(&mut self) -> Result<(), ImportError> {
        if self.peek_gaze.is_some() {
            return Ok(());
        }
        let Some(stream) = self.gaze.as_mut() else {
            return Ok(());
        };
        let [(tx, ox), (ty, oy)] = self.gaze_xy;
        let (ns, x, y) = match stream.next_record(&mut self.warnings) {
            None => {
                self.gaze = None;
                return Ok(());
            }
            Some(Err(e)) => return Err(e),
            Some(Ok((ns, rec))) => (ns, tx.read_f64(&rec[ox..]), ty.read_f64(&rec[oy..])),
        };
        let t = self.secs(ns);
        let uv = [
            (x as f32) / SCENE_CAMERA_PX[0],
            (y as f32) / SCENE_CAMERA_PX[1],
        ];
        let ok = uv[0].is_finite() && uv[1].is_finite();
        self.peek_gaze = Some(GazeSample {
            t_secs: t,
            gaze_uv: uv,
            confidence: if ok { 1.0 } else { 0.0 },
            eyes: GazeEyes::Binocular,
        });
        Ok(())
    }

    fn fill_blink(&mut self) -> Result<(), ImportError> {
        if self.peek_blink.is_some() {
            return Ok(());
        }
        let Some(stream) = self.blinks.as_mut() else {
            return Ok(());
        };
        let [(ts, os), (te, oe)] = self.blink_fields;
        let (s, e) = match stream.next_record(&mut self.warnings) {
            None => {
                self.blinks = None;
                return Ok(());
            }
            Some(Err(e)) => return Err(e),
            Some(Ok((_, rec))) => (ts.read_i64(&rec[os..]), te.read_i64(&rec[oe..])),
        };
        let start = self.secs_i64(s);
        let end = self.secs_i64(e);
        self.peek_blink = Some(BlinkEvent {
            start_t_secs: start,
            end_t_secs: end,
            eye: None,
        });
        Ok(())
    }
}

impl NeonImporter {
    /// Skips (and counts) peeked records whose time lies outside the
    /// recording that `info.json` describes (start_time + duration, with
    /// [`RANGE_SLACK_SECS`] either side): a flipped bit in a `.time` file
    /// would otherwise hold back its whole stream in the time merge.
    /// Returns whether anything was skipped.
    fn drop_out_of_range(&mut self) -> bool {
        let Some(d) = self.duration_secs else {
            return false;
        };
        let bad = |t: f64| !(t >= -RANGE_SLACK_SECS && t <= d + RANGE_SLACK_SECS);
        let why = |t: f64| {
            format!(
                "timestamp {t:.6e} s is outside the recording (0 to {d:.3} s after \
                 info.json's start_time)"
            )
        };
        let mut dropped = false;
        if let Some((t, _, gaze)) = self.peek_eye
            && bad(t)
        {
            self.peek_eye = None;
            // Its per-eye gaze is not delivered after all.
            for (eye, g) in gaze.iter().enumerate() {
                if g.is_some() {
                    self.eye_gaze.emitted[eye] -= 1;
                }
            }
            let p = self.dir.join("eye_state ps1.time");
            self.warnings.skip(&p, Position::File, why(t));
            dropped = true;
        }
        if let Some(g) = self.peek_gaze
            && bad(g.t_secs)
        {
            self.peek_gaze = None;
            let p = self.dir.join("gaze ps1.time");
            self.warnings.skip(&p, Position::File, why(g.t_secs));
            dropped = true;
        }
        if let Some(b) = self.peek_blink
            && (bad(b.start_t_secs) || bad(b.end_t_secs))
        {
            self.peek_blink = None;
            let p = self.dir.join("blinks ps1.raw");
            self.warnings.skip(&p, Position::File, why(b.start_t_secs));
            dropped = true;
        }
        dropped
    }
}

/// Slack around info.json's recording span within which record times are
/// believed, s.
pub const RANGE_SLACK_SECS: f64 = 1.0;

impl Iterator for NeonImporter {
    type Item = Result<Sample, ImportError>;

    fn next(&mut self) -> Option<Self::Item> {
        if let Some(s) = self.pending.pop() {
            return Some(Ok(s));
        }
        if self.failed {
            return None;
        }
        loop {
            let filled = self
                .fill_eye()
                .and_then(|_| self.fill_gaze())
                .and_then(|_| self.fill_blink());
            if let Err(e) = filled {
                self.failed = true;
                return Some(Err(e));
            }
            if !self.drop_out_of_range() {
                break;
            }
        }
        let te = self.peek_eye.as_ref().map_or(f64::INFINITY, |e| e.0);
        let tg = self.peek_gaze.as_ref().map_or(f64::INFINITY, |g| g.t_secs);
        let tb = self
            .peek_blink
            .as_ref()
            .map_or(f64::INFINITY, |b| b.start_t_secs);
        if te.is_infinite() && tg.is_infinite() && tb.is_infinite() {
            return None;
        }
        if tb <= te && tb <= tg {
            return self.peek_blink.take().map(|b| Ok(Sample::Blink(b)));
        }
        if te <= tg {
            let (_, [r, l], [gr, gl]) = self.peek_eye.take()?;
            self.pending.push(Sample::Pupil(l));
            for g in [gl, gr].into_iter().flatten() {
                self.pending.push(Sample::Gaze(g));
            }
            return Some(Ok(Sample::Pupil(r)));
        }
        self.peek_gaze.take().map(|g| Ok(Sample::Gaze(g)))
    }
}

impl Importer for NeonImporter {
    fn warnings(&self) -> &ImportWarnings {
        &self.warnings
    }
    fn data_files(&self) -> Vec<PathBuf> {
        [&self.eye, &self.gaze, &self.blinks]
            .into_iter()
            .flatten()
            .flat_map(|s| s.parts.iter().map(|(raw, _)| raw.clone()))
            .collect()
    }
    fn format(&self) -> &'static str {
        "neon"
    }
    fn nominal_rate_hz(&self) -> Option<f64> {
        self.gaze_frequency_hz
    }
    fn device(&self) -> super::Device {
        super::Device {
            manufacturer: Some("Pupil Labs".into()),
            model: Some("Neon".into()),
        }
    }
    fn eye_gaze(&self) -> Option<&EyeGazeReport> {
        Some(&self.eye_gaze)
    }
}

/// The gaze stream's parts: `gaze psN.raw`, else `gaze_200hz.raw`.
fn find_gaze(dir: &Path, record_size: usize) -> Result<Option<BinStream>, ImportError> {
    let mut s = BinStream::find(dir, "gaze", record_size)?;
    if s.is_none() {
        s = BinStream::find(dir, "gaze_200hz", record_size)?;
    }
    Ok(s)
}

/// Scene pixel of an eye's gaze: the optical axis `a` as undistorted
/// normalised coordinates, plus `offset`, through the camera model.
fn eye_gaze_px(cam: &SceneCamera, a: [f64; 3], offset: [f64; 2]) -> Option<[f64; 2]> {
    if a[2] <= 1e-9 {
        return None;
    }
    cam.project_normalized([a[0] / a[2] + offset[0], a[1] / a[2] + offset[1]])
}

/// The scene camera and each eye's offset (undistorted normalised units),
/// `[right, left]`.
type EyeGazeModel = (SceneCamera, [[f64; 2]; 2]);

/// Decides per-eye gaze at open: loads `calibration.bin` and, for
/// [`PerEyeGaze::KappaCorrected`], runs the offset pass.
fn eye_gaze_model(
    dir: &Path,
    mode: PerEyeGaze,
    layout: &EyeLayout,
    eye_record_size: usize,
    gaze: Option<(usize, [(FieldType, usize); 2])>,
    warnings: &mut ImportWarnings,
) -> Result<(Option<EyeGazeModel>, EyeGazeReport), ImportError> {
    let none = |reason: String| {
        Ok((
            None,
            EyeGazeReport {
                per_eye: false,
                reason: Some(reason),
                ..EyeGazeReport::default()
            },
        ))
    };
    if mode == PerEyeGaze::Off {
        return none("per-eye gaze turned off".into());
    }
    if layout.geometry.is_none() {
        return none("eye_state.dtype has no eyeball_center_* / optical_axis_* fields".into());
    }
    let calib_path = dir.join("calibration.bin");
    if !super::data_file(&calib_path)? {
        let reason = "no calibration.bin (the scene camera intrinsics): per-eye gaze cannot be \
                      projected; the binocular gaze stands in for both eyes";
        warnings.note(&calib_path, Position::File, reason);
        return none(reason.into());
    }
    let cam = SceneCamera::load(&calib_path)?;
    let mut offsets = [[0.0; 2]; 2];
    let mut correction_deg = [None; 2];
    if mode == PerEyeGaze::KappaCorrected {
        match gaze {
            Some((size, xy)) => {
                let found = kappa_offsets(dir, layout, eye_record_size, size, xy, &cam)?;
                for eye in 0..2 {
                    if let Some(o) = found[eye] {
                        offsets[eye] = o;
                        correction_deg[eye] = Some(o.map(|v| v.atan().to_degrees()));
                    } else {
                        let side = ["right", "left"][eye];
                        warnings.note(
                            &dir.join("eye_state ps1.raw"),
                            Position::File,
                            format!(
                                "fewer than {KAPPA_MIN_ROWS} rows with the {side} eye open and \
                                 a valid binocular gaze: its per-eye gaze is the uncorrected \
                                 optical axis"
                            ),
                        );
                    }
                }
            }
            None => warnings.note(
                &dir.join("gaze.dtype"),
                Position::File,
                "no binocular gaze to correct the per-eye gaze by: it is the uncorrected \
                 optical axis",
            ),
        }
    }
    Ok((
        Some((cam, offsets)),
        EyeGazeReport {
            per_eye: true,
            correction_deg,
            ..EyeGazeReport::default()
        },
    ))
}

/// The first pass of [`PerEyeGaze::KappaCorrected`]: per eye `[right,
/// left]`, the median of (binocular − optical axis) in undistorted
/// normalised coordinates over rows paired in time with a gaze record,
/// where the eye is open (lid confidence 1) and both are valid. Streams
/// both files once more; its own warnings are dropped (the main pass
/// counts the same records).
/// Largest step between consecutive stamps of one stream that the kappa
/// pass takes as time passing (a Neon recording runs without pauses).
const KAPPA_MAX_STEP_NS: u64 = 10_000_000_000;

/// Drops single stamps that step more than [`KAPPA_MAX_STEP_NS`] from the
/// last accepted one; two in a row that agree with each other are a real
/// step and re-anchor it.
#[derive(Debug, Default)]
struct StepFilter {
    last: Option<u64>,
    pending: Option<u64>,
}

impl StepFilter {
    fn accept(&mut self, ns: u64) -> bool {
        let near = |a: u64| a.abs_diff(ns) <= KAPPA_MAX_STEP_NS;
        let ok = self.last.is_none_or(near) || self.pending.is_some_and(near);
        if ok {
            self.last = Some(ns);
            self.pending = None;
        } else {
            self.pending = Some(ns);
        }
        ok
    }
}

fn kappa_offsets(
    dir: &Path,
    layout: &EyeLayout,
    eye_record_size: usize,
    gaze_record_size: usize,
    [(tx, ox), (ty, oy)]: [(FieldType, usize); 2],
    cam: &SceneCamera,
) -> Result<[Option<[f64; 2]>; 2], ImportError> {
    let mut scratch = ImportWarnings::default();
    let (Some(mut eyes), Some(mut gaze)) = (
        BinStream::find(dir, "eye_state", eye_record_size)?,
        find_gaze(dir, gaze_record_size)?,
    ) else {
        return Ok([None, None]);
    };
    let mut hist: [[MedianHistogram; 2]; 2] =
        std::array::from_fn(|_| [MedianHistogram::new(), MedianHistogram::new()]);
    let mut gaze_steps = StepFilter::default();
    let mut next_gaze =
        |scratch: &mut ImportWarnings| -> Result<Option<(u64, [f64; 2])>, ImportError> {
            loop {
                match gaze.next_record(scratch) {
                    None => return Ok(None),
                    Some(Err(e)) => return Err(e),
                    Some(Ok((ns, rec))) => {
                        if gaze_steps.accept(ns) {
                            return Ok(Some((
                                ns,
                                [tx.read_f64(&rec[ox..]), ty.read_f64(&rec[oy..])],
                            )));
                        }
                    }
                }
            }
        };
    let mut eye_steps = StepFilter::default();
    let mut g = next_gaze(&mut scratch)?;
    loop {
        let (ns, rows) = match eyes.next_record(&mut scratch) {
            None => break,
            Some(Err(e)) => return Err(e),
            Some(Ok((ns, rec))) => (ns, [layout.eye(rec, 0), layout.eye(rec, 1)]),
        };
        // A row with a corrupt stamp (one flipped bit: years ahead) must
        // not make the pairing skip every gaze record.
        if !eye_steps.accept(ns) {
            continue;
        }
        // Skip gaze records older than this row.
        while let Some((gns, _)) = g {
            if gns + PAIR_TOLERANCE_NS < ns {
                g = next_gaze(&mut scratch)?;
            } else {
                break;
            }
        }
        let Some((gns, px)) = g else { break };
        if gns > ns + PAIR_TOLERANCE_NS {
            continue;
        }
        let Some(nb) = cam.unproject(px) else {
            continue;
        };
        for (eye, row) in rows.iter().enumerate() {
            let Some(a) = row.axis() else { continue };
            if row.lid_confidence < 1.0 || a[2] <= 1e-9 {
                continue;
            }
            hist[eye][0].push(nb[0] - a[0] / a[2]);
            hist[eye][1].push(nb[1] - a[1] / a[2]);
        }
    }
    Ok(std::array::from_fn(|eye| {
        let [hx, hy] = &hist[eye];
        if hx.count < KAPPA_MIN_ROWS {
            return None;
        }
        Some([hx.median()?, hy.median()?])
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The kappa pass's stamp filter: a single flipped-bit stamp (years
    /// ahead) is dropped, the stream goes on; a real step (two stamps that
    /// agree) is taken.
    #[test]
    fn kappa_step_filter_drops_single_outliers_and_follows_steps() {
        let mut f = StepFilter::default();
        let ms = 1_000_000u64;
        assert!(f.accept(1_000 * ms));
        assert!(f.accept(1_005 * ms));
        assert!(!f.accept(1_010 * ms + (1 << 56)));
        assert!(f.accept(1_015 * ms));
        let later = 1_015 * ms + 3_600_000 * ms;
        assert!(!f.accept(later));
        assert!(f.accept(later + 5 * ms));
        assert!(f.accept(later + 10 * ms));
    }

    #[test]
    fn dtype_parses_neon_layout_with_offsets() {
        let text = "[\n(\"event_type\",         \"int32\"),\n(\"start_timestamp_ns\", \"int64\"),\n(\"end_timestamp_ns\",   \"int64\"),\n]\n";
        let d = Dtype::parse(text, Path::new("blinks.dtype")).unwrap();
        assert_eq!(d.record_size, 20);
        assert_eq!(d.field("start_timestamp_ns"), Some((FieldType::I64, 4)));
        assert_eq!(d.field("end_timestamp_ns"), Some((FieldType::I64, 12)));
        assert!(d.field("nope").is_none());
    }

    #[test]
    fn dtype_rejects_unknown_type_naming_field_and_line() {
        let text = "[\n(\"x\", \"float32\"),\n(\"y\", \"complex128\"),\n]";
        let e = Dtype::parse(text, Path::new("gaze.dtype")).unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains("gaze.dtype"), "{msg}");
        assert!(msg.contains("line 3"), "{msg}");
        assert!(msg.contains("`y`"), "{msg}");
    }

    #[test]
    fn truncated_record_is_a_counted_warning() {
        let dir = std::env::temp_dir().join(format!("gazelight-neon-trunc-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("info.json"), r#"{"start_time": 1000000000}"#).unwrap();
        std::fs::write(
            dir.join("eye_state.dtype"),
            "[(\"pupil_diameter_left_mm\", \"float32\"), (\"pupil_diameter_right_mm\", \"float32\")]",
        )
        .unwrap();
        let mut raw = Vec::new();
        let mut time = Vec::new();
        for i in 0..3u64 {
            raw.extend_from_slice(&4.0f32.to_le_bytes());
            raw.extend_from_slice(&3.5f32.to_le_bytes());
            time.extend_from_slice(&(1_000_000_000 + i * 5_000_000).to_le_bytes());
        }
        raw.extend_from_slice(&[1, 2, 3]); // a truncated fourth record
        std::fs::write(dir.join("eye_state ps1.raw"), &raw).unwrap();
        std::fs::write(dir.join("eye_state ps1.time"), &time).unwrap();
        let mut imp = NeonImporter::open(&dir).unwrap();
        let samples: Vec<Sample> = imp.by_ref().map(|s| s.unwrap()).collect();
        assert_eq!(samples.len(), 6);
        assert_eq!(imp.warnings().skipped_records, 1);
        assert!(imp.warnings().messages[0].contains("byte offset 24"));
        match samples[0] {
            Sample::Pupil(p) => {
                assert_eq!(p.eye, 0);
                assert_eq!(p.diameter_raw, 3.5);
                assert_eq!(p.confidence, 1.0);
                assert_eq!(p.t_secs, 0.0);
            }
            other => panic!("{other:?}"),
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
