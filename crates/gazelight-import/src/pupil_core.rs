//! Pupil Core recordings (Pupil Capture's recording directory).
//!
//! A recording directory holds one `<stream>.pldata` per data stream (Pupil
//! Labs' `file_methods.py`: a concatenation of msgpack `[topic, payload]`
//! pairs, see [`gazelight_pupil::recording`]) with a `<stream>_timestamps.npy` beside
//! it, and an `info.player.json` describing the recording. This importer
//! reads `pupil.pldata` (2D and 3D pupil datums of both eyes) and
//! `gaze.pldata` (gaze datums); either may be missing, not both.
//!
//! - **Order**: Pupil writes each stream in the order the datums were
//!   published, which is time order per stream. The importer merges the two
//!   streams while streaming (a two-way merge of their next samples by
//!   `timestamp`; on equal times the pupil sample comes first), so it never
//!   holds more than one pending sample per stream.
//! - **Times** stay in Pupil time (seconds, the datums' `timestamp`), like
//!   a live source before clock alignment. The `_timestamps.npy` files are
//!   a derived index of the same values and are not needed; they are not
//!   read.
//! - **Gaze** datums yield their gaze sample only: their `base_data` are
//!   the same pupil datums `pupil.pldata` already holds.
//! - `info.player.json` is optional; when present it must be a JSON object
//!   (its start times, duration and software version are reported by
//!   [`PupilCoreImporter::info`]), otherwise opening fails naming the file.
//! - **Bad input**: a record whose bytes are not a `[topic, payload]` pair
//!   (the reader resyncs on the next well-formed record) or whose datum does
//!   not decode is skipped and counted in the warnings, naming the file and
//!   the record's byte offset; records with topics the decoder does not
//!   know (notifications, custom plugins) are ignored and counted in
//!   [`PupilCoreImporter::unknown_topics`]. More than a megabyte of
//!   unreadable bytes in a row ([`gazelight_pupil::recording::MAX_GARBAGE_BYTES`])
//!   is not skipped but refused: the import fails naming the file and the
//!   byte offset where the garbage starts, after reading about a megabyte,
//!   whatever the file's size.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::{ImportError, ImportWarnings, Importer, Position};
use gazelight_eye::sample::Sample;
use gazelight_pupil::recording::{PldataReader, PldataSamples, RecordingError, stream_paths};

/// The streams read, in tie-breaking order.
pub const STREAMS: [&str; 2] = ["pupil", "gaze"];

/// What `info.player.json` says about the recording (fields Pupil Capture
/// v2/v3 writes; all optional here).
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
pub struct PupilCoreInfo {
    /// Pupil time at the start of the recording, s.
    #[serde(default)]
    pub start_time_synced_s: Option<f64>,
    /// Wall-clock (Unix) time at the start of the recording, s.
    #[serde(default)]
    pub start_time_system_s: Option<f64>,
    /// Length of the recording, s.
    #[serde(default)]
    pub duration_s: Option<f64>,
    #[serde(default)]
    pub recording_software_name: Option<String>,
    #[serde(default)]
    pub recording_software_version: Option<String>,
    #[serde(default)]
    pub recording_name: Option<String>,
}

struct Stream {
    path: PathBuf,
    samples: PldataSamples,
    /// The next sample of this stream, not yet delivered.
    head: Option<Sample>,
    exhausted: bool,
    /// Skipped regions of the reader already turned into warnings.
    reported: u64,
}

/// Streaming importer of a Pupil Core recording directory.
pub struct PupilCoreImporter {
    streams: Vec<Stream>,
    info: Option<PupilCoreInfo>,
    warnings: ImportWarnings,
    done: bool,
}

impl PupilCoreImporter {
    /// Whether `dir` looks like a Pupil Core recording (holds
    /// `pupil.pldata` or `gaze.pldata`).
    /// A stream file that is there but unreadable (a dangling symlink)
    /// counts: [`Self::open`] then names it.
    pub fn detect(dir: &Path) -> bool {
        STREAMS
            .iter()
            .any(|s| std::fs::symlink_metadata(stream_paths(dir, s).0).is_ok())
    }

    /// Opens the recording in `dir`.
    pub fn open(dir: &Path) -> Result<Self, ImportError> {
        let mut streams = Vec::with_capacity(STREAMS.len());
        for name in STREAMS {
            let (path, _) = stream_paths(dir, name);
            // A dangling symlink or a directory in a stream's place is an
            // error naming it, not a stream left out.
            if !super::data_file(&path)? {
                continue;
            }
            let reader = PldataReader::open(&path).map_err(|e| match e {
                RecordingError::Io { path, source } => ImportError::Io { path, source },
                other => ImportError::Structure {
                    path: path.clone(),
                    position: Position::File,
                    reason: other.to_string(),
                },
            })?;
            streams.push(Stream {
                path,
                samples: reader.samples(),
                head: None,
                exhausted: false,
                reported: 0,
            });
        }
        if streams.is_empty() {
            return Err(ImportError::UnknownFormat {
                path: dir.to_owned(),
                reason: "no pupil.pldata or gaze.pldata (Pupil Core recording)".into(),
            });
        }
        let info_path = dir.join("info.player.json");
        let info = if info_path.is_file() {
            let text =
                gazelight_input::read_config(&info_path, gazelight_input::ConfigSyntax::Json)
                    .map_err(|source| ImportError::Io {
                        path: info_path.clone(),
                        source,
                    })?;
            let info: PupilCoreInfo =
                serde_json::from_str(&text).map_err(|e| ImportError::Structure {
                    path: info_path.clone(),
                    position: Position::Line(e.line() as u64),
                    reason: format!("not a valid info.player.json: {e}"),
                })?;
            Some(info)
        } else {
            None
        };
        Ok(Self {
            streams,
            info,
            warnings: ImportWarnings::default(),
            done: false,
        })
    }

    /// The recording's `info.player.json`, when it has one.
    pub fn info(&self) -> Option<&PupilCoreInfo> {
        self.info.as_ref()
    }

    /// Records ignored because the decoder does not know their topic.
    pub fn unknown_topics(&self) -> u64 {
        self.streams
            .iter()
            .map(|s| s.samples.unknown_topics())
            .sum()
    }

    /// Turns the reader's newly skipped regions into counted warnings.
    fn report_skips(stream: &mut Stream, warnings: &mut ImportWarnings) {
        let reader = stream.samples.reader();
        let count = reader.skipped_count();
        while stream.reported < count {
            match reader.skipped().get(stream.reported as usize) {
                Some(s) => warnings.skip(
                    &stream.path,
                    Position::Byte(s.offset),
                    format_args!("{} ({} bytes skipped)", s.reason, s.bytes),
                ),
                // Beyond the reader's kept details: count only.
                None => warnings.skipped_records += 1,
            }
            stream.reported += 1;
        }
    }

    /// Makes `head` hold the stream's next sample unless it is exhausted;
    /// `Err` on an I/O failure.
    fn refill(stream: &mut Stream, warnings: &mut ImportWarnings) -> Result<(), ImportError> {
        while stream.head.is_none() && !stream.exhausted {
            let item = stream.samples.next();
            Self::report_skips(stream, warnings);
            match item {
                None => stream.exhausted = true,
                Some(Ok(s)) => stream.head = Some(s),
                Some(Err(RecordingError::Decode {
                    path,
                    offset,
                    error,
                })) => warnings.skip(&path, Position::Byte(offset), error),
                Some(Err(RecordingError::Io { path, source })) => {
                    stream.exhausted = true;
                    return Err(ImportError::Io { path, source });
                }
                Some(Err(other)) => {
                    stream.exhausted = true;
                    return Err(ImportError::Structure {
                        path: stream.path.clone(),
                        position: Position::File,
                        reason: other.to_string(),
                    });
                }
            }
        }
        Ok(())
    }
}

impl Iterator for PupilCoreImporter {
    type Item = Result<Sample, ImportError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        for stream in &mut self.streams {
            if let Err(e) = Self::refill(stream, &mut self.warnings) {
                self.done = true;
                return Some(Err(e));
            }
        }
        // The earliest head; on equal times the first stream (pupil).
        let mut best: Option<(usize, f64)> = None;
        for (i, s) in self.streams.iter().enumerate() {
            if let Some(h) = &s.head {
                let t = h.t_secs();
                if best.is_none_or(|(_, bt)| t < bt) {
                    best = Some((i, t));
                }
            }
        }
        match best {
            Some((i, _)) => self.streams[i].head.take().map(Ok),
            None => {
                self.done = true;
                None
            }
        }
    }
}

impl Importer for PupilCoreImporter {
    fn warnings(&self) -> &ImportWarnings {
        &self.warnings
    }

    fn data_files(&self) -> Vec<PathBuf> {
        self.streams.iter().map(|s| s.path.clone()).collect()
    }

    fn device(&self) -> super::Device {
        super::Device {
            manufacturer: Some("Pupil Labs".into()),
            model: Some("Pupil Core".into()),
        }
    }
    fn format(&self) -> &'static str {
        "pupil-core"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_eye::sample::{DetectorMethod, PupilUnit};
    use gazelight_eye::synthetic::{SyntheticConfig, SyntheticTrace};
    use gazelight_pupil::msg::encode_sample;
    use gazelight_pupil::recording::PldataWriter;

    fn tmp_dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("gazelight-pcore-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// A synthetic trace in px (blinks, dropouts with 0/NaN/garbage
    /// pupils), gaze shifted by half a sample so that the streams
    /// interleave; and the samples a reader must give back, in time order.
    fn synthetic() -> (Vec<Sample>, Vec<Sample>) {
        let cfg = SyntheticConfig {
            seed: 7,
            duration_s: 8.0,
            unit: PupilUnit::Px,
            px_per_mm: 12.0,
            blinks_per_min: 30.0,
            dropouts_per_min: 30.0,
            ..SyntheticConfig::default()
        };
        let half_tick = 0.5 / cfg.rate_hz;
        let written: Vec<Sample> = SyntheticTrace::new(cfg, |_| 100.0)
            .filter(|s| !matches!(s, Sample::Blink(_)))
            .map(|s| match s {
                Sample::Gaze(mut g) => {
                    g.t_secs += half_tick;
                    Sample::Gaze(g)
                }
                other => other,
            })
            .collect();
        let mut expected: Vec<Sample> = written
            .iter()
            .map(|s| match *s {
                // Pupil's 2D datum: the method comes back as 2D.
                Sample::Pupil(mut p) => {
                    p.method = DetectorMethod::Pupil2d;
                    Sample::Pupil(p)
                }
                other => other,
            })
            .collect();
        expected.sort_by(|a, b| a.t_secs().total_cmp(&b.t_secs())); // stable
        (written, expected)
    }

    /// Writes `samples` into the `pupil` and `gaze` streams.
    fn record(dir: &Path, samples: &[Sample]) {
        let mut pupil = PldataWriter::create(dir, "pupil").unwrap();
        let mut gaze = PldataWriter::create(dir, "gaze").unwrap();
        for s in samples {
            let (topic, payload) = encode_sample(s).unwrap().unwrap();
            let w = if matches!(s, Sample::Gaze(_)) {
                &mut gaze
            } else {
                &mut pupil
            };
            w.append(&topic, &payload, s.t_secs()).unwrap();
        }
        pupil.close().unwrap();
        gaze.close().unwrap();
    }

    /// Compares, treating NaN == NaN (dropouts carry NaN pupils).
    fn same(a: &Sample, b: &Sample) -> bool {
        match (a, b) {
            (Sample::Pupil(x), Sample::Pupil(y)) => {
                let mut x = *x;
                let mut y = *y;
                if x.diameter_raw.is_nan() && y.diameter_raw.is_nan() {
                    x.diameter_raw = 0.0;
                    y.diameter_raw = 0.0;
                }
                x == y
            }
            _ => a == b,
        }
    }

    #[test]
    fn merges_pupil_and_gaze_in_time_order_with_exact_values() {
        let dir = tmp_dir("ok");
        let (written, expected) = synthetic();
        record(&dir, &written);
        std::fs::write(
            dir.join("info.player.json"),
            r#"{"duration_s": 8.0, "meta_version": "2.3", "min_player_version": "2.0",
               "recording_name": "synthetic", "recording_software_name": "Pupil Capture",
               "recording_software_version": "3.5.7", "recording_uuid": "x",
               "start_time_synced_s": 0.0, "start_time_system_s": 1700000000.0,
               "system_info": "test"}"#,
        )
        .unwrap();
        let mut imp = match crate::open(&dir) {
            Ok(i) => i,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(imp.format(), "pupil-core");
        let got: Vec<Sample> = imp.by_ref().map(|s| s.unwrap()).collect();
        assert_eq!(got.len(), expected.len());
        assert!(expected.len() > 2000);
        for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
            assert!(same(g, e), "sample {i}: {g:?} != {e:?}");
        }
        assert!(got.windows(2).all(|w| w[0].t_secs() <= w[1].t_secs()));
        assert_eq!(imp.warnings().skipped_records, 0);
        // The trace had dropouts with NaN and 0 pupils: they came through.
        assert!(
            got.iter()
                .any(|s| matches!(s, Sample::Pupil(p) if p.diameter_raw.is_nan()))
        );
        let info = PupilCoreImporter::open(&dir)
            .unwrap()
            .info()
            .cloned()
            .unwrap();
        assert_eq!(info.duration_s, Some(8.0));
        assert_eq!(info.recording_software_version.as_deref(), Some("3.5.7"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_records_are_skipped_with_counted_warnings_naming_file_and_offset() {
        let dir = tmp_dir("bad");
        let (written, expected) = synthetic();
        record(&dir, &written);
        let (pupil_path, _) = stream_paths(&dir, "pupil");
        let mut bytes = std::fs::read(&pupil_path).unwrap();
        // Find the start of the 1000th record: walk the records.
        let offsets: Vec<u64> = PldataReader::open(&pupil_path)
            .unwrap()
            .map(|r| r.unwrap().offset)
            .collect();
        let at = offsets[1000] as usize;
        // 1. A framed record whose payload is not msgpack (0xc1 is never
        //    used), inserted before record 1000.
        let mut garbage = vec![0x92, 0xaa];
        garbage.extend_from_slice(b"pupil.0.2d");
        garbage.extend_from_slice(&[0xc4, 4, 0xc1, 0xc1, 0xc1, 0xc1]);
        bytes.splice(at..at, garbage.iter().copied());
        // 2. Record 2000 (shifted by the insertion) replaced by a
        //    well-formed record whose datum has a confidence of 7.
        let bad_datum = {
            let v = rmpv::Value::Map(vec![
                (rmpv::Value::from("timestamp"), rmpv::Value::from(1.0)),
                (rmpv::Value::from("confidence"), rmpv::Value::from(7.0)),
                (rmpv::Value::from("diameter"), rmpv::Value::from(40.0)),
            ]);
            let mut b = Vec::new();
            rmpv::encode::write_value(&mut b, &v).unwrap();
            b
        };
        let mut rec = vec![0x92, 0xaa];
        rec.extend_from_slice(b"pupil.1.2d");
        rec.push(0xc4);
        rec.push(bad_datum.len() as u8);
        rec.extend_from_slice(&bad_datum);
        let (s2, e2) = (
            offsets[2000] as usize + garbage.len(),
            offsets[2001] as usize + garbage.len(),
        );
        bytes.splice(s2..e2, rec.iter().copied());
        std::fs::write(&pupil_path, &bytes).unwrap();

        let mut imp = PupilCoreImporter::open(&dir).unwrap();
        let got: Vec<Sample> = imp.by_ref().map(|s| s.unwrap()).collect();
        let w = imp.warnings();
        assert_eq!(w.skipped_records, 2, "{w:?}");
        let name = pupil_path.display().to_string();
        assert!(
            w.messages[0].starts_with(&format!("{name} (byte offset {at}): ")),
            "{w:?}"
        );
        assert!(w.messages[0].contains("18 bytes skipped"), "{w:?}");
        assert!(
            w.messages[1].starts_with(&format!("{name} (byte offset {s2}): ")),
            "{w:?}"
        );
        assert!(w.messages[1].contains("confidence"), "{w:?}");
        // Everything else came through, in order: the expected samples less
        // the replaced pupil datum (the 2001st pupil sample written).
        let replaced = written
            .iter()
            .filter(|s| matches!(s, Sample::Pupil(_)))
            .nth(2000)
            .unwrap();
        let mut want = expected.clone();
        let pos = want
            .iter()
            .position(|s| s.t_secs() == replaced.t_secs() && matches!((s, replaced), (Sample::Pupil(a), Sample::Pupil(b)) if a.eye == b.eye))
            .unwrap();
        want.remove(pos);
        assert_eq!(got.len(), want.len());
        assert!(got.iter().zip(&want).all(|(g, e)| same(g, e)));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn missing_streams_and_bad_info_are_clear_errors() {
        let dir = tmp_dir("empty");
        assert!(!PupilCoreImporter::detect(&dir));
        let e = PupilCoreImporter::open(&dir).err().unwrap();
        assert!(matches!(e, ImportError::UnknownFormat { .. }), "{e}");
        // Only a gaze stream: fine.
        let mut w = PldataWriter::create(&dir, "gaze").unwrap();
        let (_, expected) = synthetic();
        let g = expected
            .iter()
            .find(|s| matches!(s, Sample::Gaze(_)))
            .unwrap();
        let (topic, payload) = encode_sample(g).unwrap().unwrap();
        w.append(&topic, &payload, g.t_secs()).unwrap();
        w.close().unwrap();
        assert!(PupilCoreImporter::detect(&dir));
        let got: Vec<Sample> = PupilCoreImporter::open(&dir)
            .unwrap()
            .map(|s| s.unwrap())
            .collect();
        assert_eq!(got, vec![*g]);
        std::fs::write(dir.join("info.player.json"), "{\n\"duration_s\": \"long\"}").unwrap();
        let e = PupilCoreImporter::open(&dir).err().unwrap().to_string();
        assert!(e.contains("info.player.json (line 2)"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
