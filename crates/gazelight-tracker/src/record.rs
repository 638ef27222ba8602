//! `gazelight record`: a live Pupil source → a recording in Pupil's own
//! layout (`pupil.pldata` + `pupil_timestamps.npy`, `gaze.pldata` +
//! `gaze_timestamps.npy`, `notify.pldata` … and `info.player.json`), the
//! exact bytes that came off the bus, so Pupil Player, Pupil's
//! `file_methods.load_pldata_file` and `gazelight replay` all read it.
//!
//! Any other live source (a Neon over `neon://`, a hardware URI) is
//! recorded into the same layout from its decoded samples: each pupil and
//! gaze sample encoded as the Pupil datum `gazelight replay` decodes back
//! to the same sample ([`crate::pupil::msg::encode_sample`]; pupils in mm
//! as `diameter_3d`), timed on the host clock. Blink events have no Pupil
//! datum and are not written; a replay finds the blinks again from the
//! pupils' confidence.
//!
//! Every received datum is kept: the writers flush at least every second
//! (`PldataWriter` rewrites the `.npy` header in place, so the files are
//! complete after every flush), `info.player.json` is rewritten (write, then
//! rename) with the start time and duration so far at least every second
//! ([`INFO_EVERY`]), so even a recording killed by SIGKILL is complete to
//! within a second, a stop request (the CLI's Ctrl-C, SIGTERM and SIGHUP)
//! drains what is queued before closing, and a lost tracker only pauses the
//! recording while the client reconnects. Datums the bounded raw queue had
//! to drop (a disk slower than the tracker) are counted and reported, never
//! silently lost.
//!
//! The caller owns the rest: the `--out` rule and creating the directory,
//! the signals (passed in as the `stop` future), and printing (the
//! [`Event`]s while recording and the [`Summary`] at the end).

use std::collections::BTreeMap;
use std::fmt;
use std::future::Future;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::pupil::{PupilClient, PupilConfig, RawDatum, msg};
use crate::transport::{AnySource, SourceUri};
use crate::{PldataWriter, RecordingError, Sample, SampleSource, SourceError};

/// Capacity of the raw-datum queue between the client and the writers
/// (≈ 16 s of a binocular 200 Hz tracker with gaze).
pub const RAW_QUEUE: usize = 16_384;

/// `info.player.json` is rewritten at least this often while recording
/// (when its times changed), so a recording killed by SIGKILL or a power
/// cut has a start time and a duration within this of its data.
pub const INFO_EVERY: Duration = Duration::from_secs(1);

/// Why a recording could not start or go on.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// No Pupil Capture answered within the connect time.
    #[error(transparent)]
    NoTracker(#[from] crate::NoTracker),
    /// The Pupil client was started without its raw channel.
    #[error("internal: the Pupil client has no raw channel")]
    NoRawChannel,
    /// The source URI could not be opened.
    #[error("--source {uri}")]
    Open {
        /// The source URI as given.
        uri: String,
        #[source]
        source: SourceError,
    },
    /// Another source gave no sample within the connect time.
    #[error(
        "no samples from {uri} within {connect_secs:.1} s (--connect-secs): is the tracker on and streaming?"
    )]
    NoSamples {
        /// The source URI as given.
        uri: String,
        /// The connect time, s.
        connect_secs: f64,
    },
    /// The source ended before its first sample.
    #[error("{describe} ended before its first sample")]
    EndedEarly {
        /// The source's description.
        describe: String,
    },
    /// A sample could not be encoded as a Pupil datum.
    #[error("cannot encode a sample of {describe}")]
    Encode {
        /// The source's description.
        describe: String,
        #[source]
        source: rmpv::encode::Error,
    },
    /// The source cannot continue.
    #[error(transparent)]
    Source(SourceError),
    /// A `.pldata` stream could not be written.
    #[error(transparent)]
    Pldata(#[from] RecordingError),
    /// `info.player.json` could not be encoded.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// `info.player.json` could not be written.
    #[error("cannot write {}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// What to record, where, and for how long.
#[derive(Clone, Debug)]
pub struct RecordOptions {
    /// The source URI as given (for messages).
    pub source: String,
    /// The recording directory (already prepared and created).
    pub out: PathBuf,
    /// `info.player.json`'s `recording_software_name`: the name the
    /// `--out` rule knows its own recordings by
    /// (`gazelight_output::out_dir::SOFTWARE_NAME`).
    pub software: &'static str,
    /// Topic prefixes to record.
    pub topics: Vec<String>,
    /// Stop after this long (none: at the stop request).
    pub duration: Option<Duration>,
    /// Give up when no tracker answers (no first sample) within this time.
    pub connect: Duration,
}

/// What a recording reports while it runs (the caller prints it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event<'a> {
    /// Pupil Capture answered; the recording starts.
    PupilConnected {
        /// Pupil Capture's version (empty when it gave none).
        version: &'a str,
    },
    /// Another source gave its first sample; the recording starts.
    SourceStarted {
        /// The source's description.
        describe: &'a str,
    },
    /// The tracker was lost; the recording continues when it is back.
    Lost {
        /// Why, when known.
        reason: Option<&'a str>,
    },
    /// The tracker is back (Pupil only).
    Back,
    /// Progress, every 10 s (Pupil only).
    Progress {
        /// Time since the recording started.
        elapsed: Duration,
        /// Datums written so far.
        datums: u64,
        /// Datums the raw queue dropped so far.
        dropped: u64,
    },
}

/// Why a recording stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stop {
    /// The requested duration passed.
    DurationReached,
    /// The Pupil client stopped.
    ClientStopped,
    /// The source ended.
    SourceEnded,
    /// The stop future resolved, with this reason (e.g. `Ctrl-C`).
    Requested(&'static str),
}

impl fmt::Display for Stop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Stop::DurationReached => "duration reached",
            Stop::ClientStopped => "the Pupil client stopped",
            Stop::SourceEnded => "the source ended",
            Stop::Requested(reason) => reason,
        })
    }
}

/// What a finished recording holds.
#[derive(Clone, Debug, PartialEq)]
pub struct Summary {
    /// Why it stopped.
    pub reason: Stop,
    /// How long it recorded (from the first datum written).
    pub elapsed: Duration,
    /// Datums written.
    pub datums: u64,
    /// (stream, records) per stream written.
    pub streams: Vec<(String, u64)>,
    /// The counts of what was not written.
    pub losses: Losses,
}

/// What a recording did not write, by kind of source.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Losses {
    /// A Pupil Capture recording (its bus bytes).
    Pupil {
        /// Datums the bounded raw queue dropped.
        raw_dropped: u64,
        /// Malformed messages skipped.
        malformed: u64,
    },
    /// Another source's decoded samples.
    Samples {
        /// Samples the source itself dropped.
        dropped: u64,
        /// Bad items skipped.
        bad: u64,
        /// Times the tracker was lost.
        losses: u64,
    },
}

impl Summary {
    /// "stream: records, …", or "none".
    pub fn streams_text(&self) -> String {
        if self.streams.is_empty() {
            return "none".to_owned();
        }
        let per_stream: Vec<String> = self
            .streams
            .iter()
            .map(|(n, k)| format!("{n}: {k}"))
            .collect();
        per_stream.join(", ")
    }
}

/// The writers of one recording, one per stream (the topic's first part).
struct Recording {
    dir: PathBuf,
    software: &'static str,
    writers: BTreeMap<String, PldataWriter>,
    first_pupil_t: Option<f64>,
    last_pupil_t: Option<f64>,
    start_system_s: f64,
    uuid: String,
    records: u64,
    /// When `info.player.json` was last written, and with which
    /// (start, last) datum times.
    info_written: Instant,
    info_times: (Option<f64>, Option<f64>),
}

impl Recording {
    fn new(dir: &Path, software: &'static str) -> Self {
        Self {
            dir: dir.to_owned(),
            software,
            writers: BTreeMap::new(),
            first_pupil_t: None,
            last_pupil_t: None,
            start_system_s: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64()),
            uuid: new_uuid(),
            records: 0,
            info_written: Instant::now(),
            info_times: (None, None),
        }
    }

    /// Rewrites `info.player.json` when [`INFO_EVERY`] has passed since
    /// the last time (or it has no start yet) and its times changed; the
    /// streams are flushed first, so the file never claims data the
    /// `.pldata` files do not hold.
    fn keep_info_current(&mut self, source: &str) -> Result<(), RecordError> {
        let times = (self.first_pupil_t, self.last_pupil_t);
        let first_start = self.info_times.0.is_none() && times.0.is_some();
        if times == self.info_times || !(first_start || self.info_written.elapsed() >= INFO_EVERY) {
            return Ok(());
        }
        for w in self.writers.values_mut() {
            w.flush()?;
        }
        self.write_info(source)
    }

    fn append(&mut self, d: &RawDatum) -> Result<(), RecordError> {
        self.append_bytes(&d.topic, &d.payload, d.pupil_t_secs)
    }

    /// Appends one datum (`topic`, msgpack `payload`, its time in seconds)
    /// to the stream its topic names.
    fn append_bytes(
        &mut self,
        topic: &str,
        payload: &[u8],
        t_secs: f64,
    ) -> Result<(), RecordError> {
        let stream = topic.split('.').next().unwrap_or_default();
        if stream.is_empty() {
            return Ok(());
        }
        if !self.writers.contains_key(stream) {
            let w = PldataWriter::create(&self.dir, stream)?;
            self.writers.insert(stream.to_owned(), w);
        }
        if let Some(w) = self.writers.get_mut(stream) {
            w.append(topic, payload, t_secs)?;
        }
        if t_secs.is_finite() {
            self.first_pupil_t.get_or_insert(t_secs);
            self.last_pupil_t = Some(t_secs);
        }
        self.records += 1;
        Ok(())
    }

    fn flush_if_due(&mut self) -> Result<(), RecordError> {
        for w in self.writers.values_mut() {
            w.flush_if_due()?;
        }
        Ok(())
    }

    /// `info.player.json` (Pupil Player recording format 2.x).
    fn write_info(&mut self, source: &str) -> Result<(), RecordError> {
        self.info_written = Instant::now();
        self.info_times = (self.first_pupil_t, self.last_pupil_t);
        let start_synced = self.first_pupil_t.unwrap_or(0.0);
        let duration = match (self.first_pupil_t, self.last_pupil_t) {
            (Some(a), Some(b)) => (b - a).max(0.0),
            _ => 0.0,
        };
        let info = serde_json::json!({
            "meta_version": "2.3",
            "min_player_version": "2.0",
            "recording_uuid": self.uuid,
            "recording_name": self.dir.file_name().and_then(|n| n.to_str()).unwrap_or("gazelight"),
            "recording_software_name": self.software,
            "recording_software_version": env!("CARGO_PKG_VERSION"),
            "start_time_system_s": self.start_system_s,
            "start_time_synced_s": start_synced,
            "duration_s": duration,
            "system_info": format!("gazelight record; source {source}"),
        });
        let path = self.dir.join("info.player.json");
        let text = serde_json::to_string_pretty(&info)?;
        // Write then rename, so a crash never leaves half a file.
        let tmp = self.dir.join(".info.player.json.tmp");
        std::fs::write(&tmp, text).map_err(|source| RecordError::Write {
            path: tmp.clone(),
            source,
        })?;
        std::fs::rename(&tmp, &path).map_err(|source| RecordError::Write { path, source })?;
        Ok(())
    }

    /// Writes the final `info.player.json` and closes every stream;
    /// returns the records written and the (stream, records) pairs.
    fn finish(mut self, source: &str) -> Result<(u64, Vec<(String, u64)>), RecordError> {
        for w in self.writers.values_mut() {
            w.flush()?;
        }
        self.write_info(source)?;
        let total = self.records;
        Ok((total, self.close()?))
    }

    /// Closes every stream; returns (stream, records) pairs.
    fn close(self) -> Result<Vec<(String, u64)>, RecordError> {
        let mut out = Vec::new();
        for (name, w) in self.writers {
            out.push((name, w.close()?));
        }
        Ok(out)
    }
}

/// Records Pupil Capture's bus bytes as they are into `opts.out` until the
/// duration passes, the client stops or `stop` resolves (its output is the
/// reason reported). `config` is the Pupil source; its topics and raw queue
/// are set here. Call inside a tokio runtime with time and I/O enabled.
pub async fn record_pupil(
    mut config: PupilConfig,
    opts: &RecordOptions,
    stop: impl Future<Output = &'static str>,
    mut on_event: impl FnMut(Event<'_>),
) -> Result<Summary, RecordError> {
    config.topics = opts.topics.clone();
    config.raw_capacity = RAW_QUEUE;
    let (client, mut streams) = PupilClient::spawn(config);
    client
        .wait_connected(opts.connect)
        .await
        .map_err(|source| crate::NoTracker {
            uri: opts.source.clone(),
            source,
        })?;
    let Some(mut raw) = streams.raw.take() else {
        return Err(RecordError::NoRawChannel);
    };
    let version = client.stats().version.unwrap_or_default();
    let source_info = format!("Pupil {version}");
    let mut rec = Recording::new(&opts.out, opts.software);
    rec.write_info(&source_info)?;
    on_event(Event::PupilConnected { version: &version });
    let started = Instant::now();
    let deadline = deadline(opts.duration);
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    let mut was_connected = true;
    let mut last_report = Instant::now();
    tokio::pin!(stop);
    let reason = loop {
        tokio::select! {
            d = raw.recv() => match d {
                Some(d) => rec.append(&d)?,
                None => break Stop::ClientStopped,
            },
            // Decoded samples are not recorded (the raw bytes are); keep
            // the channel empty so the client does not count drops.
            _ = streams.samples.recv() => {}
            _ = tick.tick() => {
                rec.flush_if_due()?;
                rec.keep_info_current(&source_info)?;
                let stats = client.stats();
                if was_connected && !stats.connected {
                    on_event(Event::Lost { reason: stats.last_error.as_deref() });
                } else if !was_connected && stats.connected {
                    on_event(Event::Back);
                }
                was_connected = stats.connected;
                if last_report.elapsed() >= Duration::from_secs(10) {
                    last_report = Instant::now();
                    on_event(Event::Progress {
                        elapsed: started.elapsed(),
                        datums: rec.records,
                        dropped: stats.raw_dropped,
                    });
                }
            }
            _ = until(deadline) => break Stop::DurationReached,
            reason = &mut stop => break Stop::Requested(reason),
        }
    };
    // Keep everything that was received: drain the queue before closing.
    while let Ok(d) = raw.try_recv() {
        rec.append(&d)?;
    }
    let stats = client.stats();
    client.shutdown().await;
    let (datums, streams) = rec.finish(&source_info)?;
    Ok(Summary {
        reason,
        elapsed: started.elapsed(),
        datums,
        streams,
        losses: Losses::Pupil {
            raw_dropped: stats.raw_dropped,
            malformed: stats.malformed,
        },
    })
}

/// Records any other live source from its decoded samples (see the module
/// docs): the same writers, flushing, stop and drain as [`record_pupil`].
/// Call inside a tokio runtime with time and I/O enabled.
pub async fn record_samples(
    uri: &SourceUri,
    opts: &RecordOptions,
    stop: impl Future<Output = &'static str>,
    mut on_event: impl FnMut(Event<'_>),
) -> Result<Summary, RecordError> {
    let mut source = crate::transport::open(uri).map_err(|source| RecordError::Open {
        uri: opts.source.clone(),
        source,
    })?;
    let describe = source.describe();
    // The first sample within the connect time, or no recording.
    let first = match tokio::time::timeout(opts.connect, first_sample(&mut source)).await {
        Ok(first) => first?,
        Err(_) => {
            return Err(RecordError::NoSamples {
                uri: opts.source.clone(),
                connect_secs: opts.connect.as_secs_f64(),
            });
        }
    };
    let mut rec = Recording::new(&opts.out, opts.software);
    on_event(Event::SourceStarted {
        describe: &describe,
    });
    let wanted = |topic: &str| opts.topics.iter().any(|p| topic.starts_with(p.as_str()));
    let append = |rec: &mut Recording, sample: &Sample| -> Result<(), RecordError> {
        if let Some((topic, payload)) =
            msg::encode_sample(sample).map_err(|source| RecordError::Encode {
                describe: describe.clone(),
                source,
            })?
            && wanted(&topic)
        {
            rec.append_bytes(&topic, &payload, sample.t_secs())?;
        }
        Ok(())
    };
    append(&mut rec, &first)?;
    rec.write_info(&describe)?;
    let started = Instant::now();
    let deadline = deadline(opts.duration);
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    let (mut losses, mut bad) = (0u64, 0u64);
    tokio::pin!(stop);
    let reason = loop {
        // The pending `next` survives the ticks: a source's `next` is not
        // cancel-safe (a replay's pacing sleep holds a sample already
        // read), so a tick must not drop it — a replay recorded again lost
        // a sample in 2 of 6 runs under load before.
        let next = {
            let next = source.next();
            tokio::pin!(next);
            loop {
                tokio::select! {
                    r = &mut next => break Ok(r),
                    _ = tick.tick() => {
                        rec.flush_if_due()?;
                        rec.keep_info_current(&describe)?;
                    }
                    _ = until(deadline) => break Err(Stop::DurationReached),
                    reason = &mut stop => break Err(Stop::Requested(reason)),
                }
            }
        };
        match next {
            Err(stopped) => break stopped,
            Ok(Ok(Some(sample))) => append(&mut rec, &sample)?,
            Ok(Ok(None)) => break Stop::SourceEnded,
            Ok(Err(e @ SourceError::Fatal { .. })) => return Err(RecordError::Source(e)),
            Ok(Err(SourceError::Disconnected { reason, .. })) => {
                losses += 1;
                on_event(Event::Lost {
                    reason: Some(&reason),
                });
            }
            Ok(Err(_)) => bad += 1,
        }
    };
    let (datums, streams) = rec.finish(&describe)?;
    Ok(Summary {
        reason,
        elapsed: started.elapsed(),
        datums,
        streams,
        losses: Losses::Samples {
            dropped: source.dropped(),
            bad,
            losses,
        },
    })
}

/// The source's first sample; bad items and losses before it are waited
/// out (the caller bounds the wait).
async fn first_sample(source: &mut AnySource) -> Result<Sample, RecordError> {
    loop {
        match source.next().await {
            Ok(Some(s)) => return Ok(s),
            Ok(None) => {
                return Err(RecordError::EndedEarly {
                    describe: source.describe(),
                });
            }
            Err(e @ SourceError::Fatal { .. }) => return Err(RecordError::Source(e)),
            Err(_) => {}
        }
    }
}

/// When the duration ends the recording (none: at the stop request).
fn deadline(duration: Option<Duration>) -> Option<tokio::time::Instant> {
    duration.and_then(|d| tokio::time::Instant::now().checked_add(d))
}

/// Resolves at `deadline`, never without one.
async fn until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d).await,
        None => std::future::pending().await,
    }
}

/// A random RFC 4122 v4 UUID from the kernel, or a time-based fallback.
fn new_uuid() -> String {
    if let Ok(s) = std::fs::read_to_string("/proc/sys/kernel/random/uuid") {
        let s = s.trim();
        if s.len() == 36 {
            return s.to_owned();
        }
    }
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    let h = format!("{nanos:032x}");
    format!(
        "{}-{}-4{}-8{}-{}",
        &h[0..8],
        &h[8..12],
        &h[13..16],
        &h[17..20],
        &h[20..32]
    )
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup

    use super::*;
    use crate::{DetectorMethod, PupilSample, PupilUnit};

    /// A fresh, empty directory for one test.
    fn tmp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!(
            "gazelight-tracker-record-{}-{name}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("tmp dir");
        dir
    }

    fn pupil(t_secs: f64, eye: u8) -> Sample {
        Sample::Pupil(PupilSample {
            t_secs,
            eye,
            diameter_raw: 4.0,
            unit: PupilUnit::Mm,
            diameter_mm: Some(4.0),
            confidence: 0.95,
            norm_pos: [0.5, 0.5],
            method: DetectorMethod::Pupil3d,
        })
    }

    /// Writes `n` pupil samples per eye, 10 ms apart, as a recording.
    fn write_recording(dir: &Path, n: usize) -> (u64, Vec<(String, u64)>) {
        let mut rec = Recording::new(dir, "gazelight");
        for i in 0..n {
            for eye in 0..2 {
                let s = pupil(100.0 + i as f64 * 0.01, eye);
                let (topic, payload) = msg::encode_sample(&s).unwrap().unwrap();
                rec.append_bytes(&topic, &payload, s.t_secs()).unwrap();
            }
        }
        rec.finish("test").unwrap()
    }

    fn info(dir: &Path) -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join("info.player.json")).unwrap())
            .unwrap()
    }

    #[test]
    fn a_recording_has_its_streams_and_info_player_json() {
        let dir = tmp_dir("streams");
        let mut rec = Recording::new(&dir, "gazelight");
        // A topic without a stream name is not written.
        rec.append_bytes(".x", b"\x80", 1.0).unwrap();
        assert_eq!(rec.records, 0);
        let (total, streams) = {
            drop(rec);
            write_recording(&dir, 5)
        };
        assert_eq!(total, 10);
        assert_eq!(streams, vec![("pupil".to_owned(), 10)]);
        let info = info(&dir);
        assert_eq!(info["recording_software_name"], "gazelight");
        assert_eq!(info["recording_uuid"].as_str().map(str::len), Some(36));
        assert_eq!(info["start_time_synced_s"], 100.0);
        assert!((info["duration_s"].as_f64().unwrap() - 0.04).abs() < 1e-9);
        assert_eq!(info["system_info"], "gazelight record; source test");
        assert!(!dir.join(".info.player.json.tmp").exists());
        let (pldata, npy) = crate::recording::stream_paths(&dir, "pupil");
        assert_eq!(crate::PldataReader::open(&pldata).unwrap().count(), 10);
        assert_eq!(crate::recording::read_npy_f64(&npy).unwrap().len(), 10);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn info_is_kept_current_once_a_second() {
        let dir = tmp_dir("info");
        let mut rec = Recording::new(&dir, "gazelight");
        rec.write_info("test").unwrap();
        assert_eq!(info(&dir)["duration_s"], 0.0);
        // The first start is written at once.
        rec.append_bytes("gaze.3d.01.", b"\x80", 5.0).unwrap();
        rec.keep_info_current("test").unwrap();
        assert_eq!(info(&dir)["start_time_synced_s"], 5.0);
        // Later times wait for INFO_EVERY.
        rec.append_bytes("gaze.3d.01.", b"\x80", 7.0).unwrap();
        rec.keep_info_current("test").unwrap();
        assert_eq!(info(&dir)["duration_s"], 0.0);
        rec.info_written = Instant::now().checked_sub(INFO_EVERY).unwrap();
        rec.keep_info_current("test").unwrap();
        assert_eq!(info(&dir)["duration_s"], 2.0);
        rec.close().unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn summary_and_stop_texts() {
        let mut summary = Summary {
            reason: Stop::Requested("Ctrl-C"),
            elapsed: Duration::ZERO,
            datums: 0,
            streams: Vec::new(),
            losses: Losses::Pupil {
                raw_dropped: 0,
                malformed: 0,
            },
        };
        assert_eq!(summary.streams_text(), "none");
        summary.streams = vec![("gaze".into(), 3), ("pupil".into(), 7)];
        assert_eq!(summary.streams_text(), "gaze: 3, pupil: 7");
        assert_eq!(summary.reason.to_string(), "Ctrl-C");
        assert_eq!(Stop::DurationReached.to_string(), "duration reached");
        assert_eq!(Stop::ClientStopped.to_string(), "the Pupil client stopped");
        assert_eq!(Stop::SourceEnded.to_string(), "the source ended");
    }

    #[test]
    fn uuids_are_rfc_4122_shaped() {
        let u = new_uuid();
        assert_eq!(u.len(), 36);
        assert_eq!(u.matches('-').count(), 4);
        assert_ne!(u, new_uuid());
    }

    fn options(source: &str, out: &Path) -> RecordOptions {
        RecordOptions {
            source: source.to_owned(),
            out: out.to_owned(),
            software: "gazelight",
            topics: vec!["pupil.".into(), "gaze.".into(), "notify.".into()],
            duration: None,
            connect: Duration::from_millis(300),
        }
    }

    #[tokio::test]
    async fn no_tracker_is_refused_with_the_uri() {
        let dir = tmp_dir("no-tracker");
        let uri = "pupil://127.0.0.1:9";
        let config = crate::uri::pupil_config(uri).unwrap();
        let err = record_pupil(config, &options(uri, &dir), std::future::pending(), |_| {})
            .await
            .unwrap_err();
        assert!(
            err.to_string().starts_with(
                "no tracker at pupil://127.0.0.1:9: is Pupil Capture (or Pupil Service) running"
            ),
            "{err}"
        );
        assert!(!dir.join("info.player.json").exists());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[tokio::test]
    async fn an_unopenable_source_names_the_uri() {
        let dir = tmp_dir("unopenable");
        let text = "synthetic://demo";
        let uri = SourceUri::parse(text).unwrap();
        let err = record_samples(&uri, &options(text, &dir), std::future::pending(), |_| {})
            .await
            .unwrap_err();
        assert_eq!(err.to_string(), "--source synthetic://demo");
        assert!(std::error::Error::source(&err).is_some());
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A recording replayed (`replay://`) and recorded again from its
    /// decoded samples holds every sample, and stops at the source's end.
    #[tokio::test]
    async fn a_replayed_recording_is_recorded_again_whole() {
        let input = tmp_dir("replay-in");
        write_recording(&input, 20);
        let out = tmp_dir("replay-out");
        let text = format!("replay://{}?speed=1000", input.display());
        let uri = SourceUri::parse(&text).unwrap();
        let mut events = Vec::new();
        let summary = record_samples(&uri, &options(&text, &out), std::future::pending(), |e| {
            events.push(format!("{e:?}"))
        })
        .await
        .unwrap();
        assert_eq!(summary.reason, Stop::SourceEnded);
        assert_eq!(summary.datums, 40, "{summary:?}");
        assert_eq!(summary.streams, vec![("pupil".to_owned(), 40)]);
        assert!(
            matches!(
                summary.losses,
                Losses::Samples {
                    bad: 0,
                    losses: 0,
                    ..
                }
            ),
            "{summary:?}"
        );
        assert_eq!(events.len(), 1, "{events:?}");
        assert!(events[0].starts_with("SourceStarted"), "{events:?}");
        assert!((info(&out)["duration_s"].as_f64().unwrap() - 0.19).abs() < 1e-6);
        let _ = std::fs::remove_dir_all(&input);
        let _ = std::fs::remove_dir_all(&out);
    }

    /// The stop future ends a recording like the duration does.
    #[tokio::test]
    async fn the_stop_future_ends_the_recording() {
        let input = tmp_dir("stop-in");
        write_recording(&input, 2000);
        let out = tmp_dir("stop-out");
        // Real time: 20 s of samples, stopped after 0.3 s.
        let text = format!("replay://{}", input.display());
        let uri = SourceUri::parse(&text).unwrap();
        let stop = async {
            tokio::time::sleep(Duration::from_millis(300)).await;
            "Ctrl-C"
        };
        let summary = record_samples(&uri, &options(&text, &out), stop, |_| {})
            .await
            .unwrap();
        assert_eq!(summary.reason, Stop::Requested("Ctrl-C"));
        assert!(summary.datums > 0 && summary.datums < 4000, "{summary:?}");
        let _ = std::fs::remove_dir_all(&input);
        let _ = std::fs::remove_dir_all(&out);
    }
}
