//! XDF recordings (Lab Streaming Layer's LabRecorder): one eye stream of
//! a multi-stream file, replayed as gazelight samples.
//!
//! - [`reader`]: the container, read from the XDF 1.0 specification,
//!   streamed with bounded memory ([`XdfFile::scan`] reads the headers,
//!   footers and clock offsets; [`XdfFile::samples`] streams one stream's
//!   samples);
//! - [`clock`]: the time stamps pyxdf's `load_xdf` gives with its default
//!   options (clock offsets by robust linear fit, clock resets, dejitter);
//! - [`XdfImporter`]: picks the eye stream (`FILE.xdf?stream=NAME`, else
//!   the first stream of type `Gaze` or `Pupil`) and maps its channels
//!   ([`EyeLayout`]) onto [`Sample`]s.
//!
//! Marker (string) streams are listed in the import's notes with their
//! counts; gazelight's [`Sample`] has no event kind: they are read as
//! events by [`crate::events::read`] (`inspect`, `replay`'s `events.csv`,
//! Python's `rec.events`). See `docs/xdf-bids.md` and `docs/events.md`.

pub mod clock;
pub mod reader;
pub mod xml;

use std::path::{Path, PathBuf};

pub use reader::{ChannelFormat, ChannelInfo, StreamInfo, StreamSamples, XdfFile};

use super::{ImportError, ImportWarnings, Importer, Pending, Position};
use gazelight_eye::sample::{BlinkEvent, Sample};

pub use gazelight_eye::channel_layout::{ChannelLayout as EyeLayout, NEON_SCENE_PX};

/// The stream types picked when no `?stream=` is given, in this order of
/// preference (the first stream of either type wins).
pub const EYE_STREAM_TYPES: [&str; 2] = ["Gaze", "Pupil"];

/// A path to an XDF recording with an optional `?stream=NAME`: the file
/// and the stream name.
pub fn split_query(path: &Path) -> Option<(PathBuf, Option<String>)> {
    let s = path.to_str()?;
    let lower = s.to_ascii_lowercase();
    if lower.ends_with(".xdf") {
        return Some((path.to_owned(), None));
    }
    let k = lower.rfind(".xdf?")?;
    let (file, query) = s.split_at(k + 4);
    let query = &query[1..];
    let stream = query
        .split('&')
        .find_map(|kv| kv.strip_prefix("stream="))
        .map(percent_decode);
    Some((PathBuf::from(file), stream))
}

fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && let Some(Ok(v)) = s.get(i + 1..i + 3).map(|h| u8::from_str_radix(h, 16))
        {
            out.push(v);
            i += 3;
            continue;
        }
        out.push(if b[i] == b'+' { b' ' } else { b[i] });
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Why an eye stream's channels match no layout.
pub(crate) fn layout_error(info: &StreamInfo) -> String {
    let labels = info.labels();
    let channels = if labels.iter().all(String::is_empty) {
        format!("{} channels without labels", labels.len())
    } else {
        format!("channels [{}]", labels.join(", "))
    };
    format!(
        "stream `{}` (type {}) has {channels}, none of the layouts gazelight reads: \
         gazelight's gazelight-eye (gaze_x, gaze_y, pupil_right_mm, pupil_left_mm, …), \
         Pupil Capture's LSL relay (norm_pos_x, norm_pos_y, diameter0_3d, …), Neon's \
         (x, y in scene pixels, pupil_diameter_left, pupil_diameter_right) or the generic \
         x, y, pupil (normalised gaze, origin top-left)",
        info.name, info.kind,
    )
}

/// Streaming importer of one eye stream of an XDF file.
pub struct XdfImporter {
    path: PathBuf,
    samples: StreamSamples,
    layout: EyeLayout,
    pending: Pending<4>,
    blink_start: Option<f64>,
    last_t: f64,
    warnings: ImportWarnings,
    done: bool,
}

/// A one-line description of a stream for notes and errors.
fn describe(s: &StreamInfo) -> String {
    let what = if s.format == ChannelFormat::String {
        format!("{} markers", s.sample_count)
    } else {
        format!("{} samples", s.sample_count)
    };
    format!(
        "`{}` (type {}, {} {} channels, {} Hz, {what})",
        s.name,
        if s.kind.is_empty() { "-" } else { &s.kind },
        s.channel_count,
        s.format.name(),
        s.nominal_srate_hz
    )
}

/// Why no stream of a file could be chosen to replay.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StreamChoiceError {
    #[error("the file holds no stream")]
    NoStreams,
    #[error("no stream named `{name}`; the file has {streams}")]
    NoSuchName {
        name: String,
        /// Every stream of the file, described.
        streams: String,
    },
    #[error(
        "no stream of type Gaze or Pupil (pick one with FILE.xdf?stream=NAME); the file has {streams}"
    )]
    NoEyeStream {
        /// Every stream of the file, described.
        streams: String,
    },
}

/// Which stream of `file` to replay: by name, else the first of type
/// Gaze, else the first of type Pupil.
pub fn choose_stream(file: &XdfFile, name: Option<&str>) -> Result<usize, StreamChoiceError> {
    let list = || {
        file.streams
            .iter()
            .map(describe)
            .collect::<Vec<_>>()
            .join(", ")
    };
    if file.streams.is_empty() {
        return Err(StreamChoiceError::NoStreams);
    }
    if let Some(name) = name {
        return file
            .streams
            .iter()
            .position(|s| s.name == name)
            .ok_or_else(|| StreamChoiceError::NoSuchName {
                name: name.to_owned(),
                streams: list(),
            });
    }
    EYE_STREAM_TYPES
        .iter()
        .find_map(|t| {
            file.streams
                .iter()
                .position(|s| s.kind.eq_ignore_ascii_case(t))
        })
        .ok_or_else(|| StreamChoiceError::NoEyeStream { streams: list() })
}

impl XdfImporter {
    /// Opens `path` (`FILE.xdf` or `FILE.xdf?stream=NAME`).
    pub fn open(path: &Path) -> Result<Self, ImportError> {
        let (file_path, stream) = split_query(path).unwrap_or_else(|| (path.to_owned(), None));
        let file = XdfFile::scan(&file_path)?;
        let structure = |reason: String| ImportError::Structure {
            path: file_path.clone(),
            position: Position::File,
            reason,
        };
        let index =
            choose_stream(&file, stream.as_deref()).map_err(|e| structure(e.to_string()))?;
        let info = &file.streams[index];
        if info.format == ChannelFormat::String {
            return Err(structure(format!(
                "stream {} holds strings (markers), not eye samples; markers are the \
                 recording's events (`inspect` lists them, `replay` writes events.csv)",
                describe(info)
            )));
        }
        let units: Vec<String> = info.channels.iter().map(|c| c.unit.clone()).collect();
        let layout = EyeLayout::detect(&info.labels(), Some(&units), NEON_SCENE_PX)
            .ok_or_else(|| structure(layout_error(info)))?;
        let mut warnings = ImportWarnings::default();
        let others: Vec<String> = file
            .streams
            .iter()
            .enumerate()
            .filter(|(k, _)| *k != index)
            .map(|(_, s)| describe(s))
            .collect();
        let markers: u64 = file
            .streams
            .iter()
            .filter(|s| s.format == ChannelFormat::String)
            .map(|s| s.sample_count)
            .sum();
        let note = format!(
            "XDF stream {} chosen{} (layout {}, {} clock offsets, {} clock range(s), {}){}{}",
            describe(info),
            if stream.is_some() {
                " by name"
            } else {
                " by type"
            },
            layout.kind,
            info.clock_offsets.len(),
            info.clock_ranges,
            if info.dejittered() {
                "dejittered"
            } else {
                "not dejittered"
            },
            if others.is_empty() {
                String::new()
            } else {
                format!("; the other streams: {}", others.join(", "))
            },
            if markers > 0 {
                format!("; the {markers} markers are read as the recording's events")
            } else {
                String::new()
            },
        );
        warnings.note(&file_path, Position::File, note);
        if info.samples_kept < info.sample_count {
            warnings.note(
                &file_path,
                Position::File,
                format!(
                    "stream `{}`: {} samples past the footer's count dropped with a corrupted \
                     last clock offset (as pyxdf does)",
                    info.name,
                    info.sample_count - info.samples_kept
                ),
            );
        }
        let samples = file.samples(index)?;
        if info.clock_offsets_skipped > 0 {
            warnings.note(
                &file_path,
                Position::File,
                format!(
                    "stream `{}`: {} of its {} clock offsets skipped (a collection time or an \
                     offset that is not a finite number within ±{:e} s); the clock fit uses \
                     the other {}",
                    info.name,
                    info.clock_offsets_skipped,
                    info.clock_offsets.len() as u64 + info.clock_offsets_skipped,
                    reader::MAX_CLOCK_SECS,
                    info.clock_offsets.len()
                ),
            );
        }
        let bad_stamps = samples.implausible_stamps();
        if bad_stamps > 0 {
            warnings.note(
                &file_path,
                Position::File,
                format!(
                    "stream `{}`: {bad_stamps} of its {} samples have a time stamp that is not a \
                     finite number within ±{:e} s, left out of the time fits; {}",
                    info.name,
                    info.samples_kept,
                    reader::MAX_CLOCK_SECS,
                    if info.dejittered() {
                        "each takes its dejitter line's time at its index"
                    } else {
                        "the stream is not dejittered, so they are skipped (and counted)"
                    }
                ),
            );
        }
        Ok(Self {
            path: file_path,
            samples,
            layout,
            pending: Pending::new(),
            blink_start: None,
            last_t: f64::NAN,
            warnings,
            done: false,
        })
    }

    /// The chosen stream.
    pub fn stream(&self) -> &StreamInfo {
        self.samples.info()
    }

    /// The channel layout in use.
    pub fn layout(&self) -> &EyeLayout {
        &self.layout
    }

    fn read_step(&mut self) -> Result<bool, ImportError> {
        let Some(t) = self.samples.next_sample()? else {
            if let Some(start) = self.blink_start.take() {
                self.pending.push(Sample::Blink(BlinkEvent {
                    start_t_secs: start,
                    end_t_secs: self.last_t,
                    eye: None,
                }));
            }
            return Ok(false);
        };
        let v = self.samples.numeric();
        let pending = &mut self.pending;
        self.layout.decode(v, t, &mut |s| pending.push(s));
        if let Some(b) = self.layout.blink {
            let on = v.get(b).is_some_and(|x| *x > 0.5);
            match (on, self.blink_start) {
                (true, None) => self.blink_start = Some(t),
                (false, Some(start)) => {
                    self.blink_start = None;
                    self.pending.push(Sample::Blink(BlinkEvent {
                        start_t_secs: start,
                        end_t_secs: t,
                        eye: None,
                    }));
                }
                _ => {}
            }
        }
        self.last_t = t;
        Ok(true)
    }
}

impl crate::Stepped for XdfImporter {
    fn step(&mut self) -> Result<bool, ImportError> {
        self.read_step()
    }
    fn pop_pending(&mut self) -> Option<Sample> {
        self.pending.pop()
    }
    fn done_mut(&mut self) -> &mut bool {
        &mut self.done
    }
}

impl Iterator for XdfImporter {
    type Item = Result<Sample, ImportError>;

    fn next(&mut self) -> Option<Self::Item> {
        crate::next_stepped(self)
    }
}

impl Importer for XdfImporter {
    fn warnings(&self) -> &ImportWarnings {
        &self.warnings
    }
    fn format(&self) -> &'static str {
        "xdf"
    }
    fn nominal_rate_hz(&self) -> Option<f64> {
        crate::plausible_rate(self.stream().nominal_srate_hz)
    }
    fn device(&self) -> crate::Device {
        let m = self.stream().manufacturer.trim();
        crate::Device {
            manufacturer: (!m.is_empty()).then(|| m.chars().take(64).collect()),
            model: match self.layout.kind {
                "neon" => Some("Neon".into()),
                "pupil-capture-relay" => Some("Pupil Core".into()),
                _ => None,
            },
        }
    }
    fn position(&self) -> Position {
        self.samples.position()
    }
}

impl std::fmt::Debug for XdfImporter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("XdfImporter")
            .field("path", &self.path)
            .field("stream", &self.stream().name)
            .field("layout", &self.layout.kind)
            .finish()
    }
}
