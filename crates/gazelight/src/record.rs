//! `gazelight record`: a live Pupil source → a recording in Pupil's own
//! layout (`pupil.pldata` + `pupil_timestamps.npy`, `gaze.pldata` +
//! `gaze_timestamps.npy`, `notify.pldata` … and `info.player.json`), the
//! exact bytes that came off the bus, so Pupil Player, Pupil's
//! `file_methods.load_pldata_file` and `gazelight replay` all read it.
//!
//! Any other live source (a Neon over `neon://`, a hardware URI) is
//! recorded into the same layout from its decoded samples: each pupil and
//! gaze sample encoded as the Pupil datum `gazelight replay` decodes back
//! to the same sample ([`gazelight_tracker::pupil::msg::encode_sample`];
//! pupils in mm as `diameter_3d`), timed on the host clock. Blink events
//! have no Pupil datum and are not written; a replay finds the blinks again
//! from the pupils' confidence.
//!
//! Every received datum is kept: the writers flush at least every second
//! (`PldataWriter` rewrites the `.npy` header in place, so the files are
//! complete after every flush), `info.player.json` is rewritten (write, then
//! rename) with the start time and duration so far at least every second
//! ([`INFO_EVERY`]), so even a recording killed by SIGKILL is complete to
//! within a second, Ctrl-C, SIGTERM and SIGHUP drain what is queued before closing,
//! and a lost tracker only pauses the recording while the client reconnects.
//! Datums the bounded raw queue had to drop (a disk slower than the tracker)
//! are counted and reported, never silently lost.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, bail};
use clap::Args;
use gazelight_tracker::PldataWriter;
use gazelight_tracker::pupil::{PupilClient, PupilConfig, RawDatum, msg};
use gazelight_tracker::transport::{AnySource, SourceUri};
use gazelight_tracker::{Sample, SampleSource, SourceError};

/// Capacity of the raw-datum queue between the client and the writers
/// (≈ 16 s of a binocular 200 Hz tracker with gaze).
const RAW_QUEUE: usize = 16_384;

/// Arguments of `gazelight record`.
#[derive(Args, Debug)]
pub struct RecordArgs {
    /// Tracker source: Pupil Capture's Pupil Remote (its bus bytes are
    /// kept as they are) or any other live source URI, e.g. `neon://HOST`
    /// (its samples are written as Pupil datums).
    #[arg(long, value_name = "URI", default_value = gazelight_tracker::uri::DEFAULT_SOURCE)]
    pub source: String,
    /// Recording directory (created). Refused when it holds another
    /// recording (a Pupil Capture or Neon one) or the replayed input, or a
    /// previous `gazelight record` (unless --force).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Clear a previous `gazelight record` recording in --out first (its
    /// .pldata, _timestamps.npy and info.player.json); a recording made by
    /// another program is never cleared.
    #[arg(long)]
    pub force: bool,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long, value_name = "S")]
    pub secs: Option<f64>,
    /// Topic prefixes to record.
    #[arg(long, value_delimiter = ',', default_value = "pupil.,gaze.,notify.")]
    pub topics: Vec<String>,
    /// Give up when no tracker answers within this time at start, s.
    #[arg(long, value_name = "S", default_value_t = 5.0)]
    pub connect_secs: f64,
}

/// Runs `gazelight record`.
pub fn run(args: RecordArgs) -> anyhow::Result<()> {
    if let Some(s) = args.secs {
        crate::bounds::secs("--secs", s)?;
    }
    crate::bounds::secs("--connect-secs", args.connect_secs)?;
    if args.topics.iter().any(|t| t.trim().is_empty()) {
        bail!("--topics: empty topic prefix");
    }
    let uri =
        SourceUri::parse(&args.source).with_context(|| format!("--source {}", args.source))?;
    let pupil = match &uri {
        SourceUri::Pupil { .. } => {
            let mut pupil = gazelight_tracker::uri::pupil_config(&args.source)
                .with_context(|| format!("--source {}", args.source))?;
            pupil.topics = args.topics.clone();
            pupil.raw_capacity = RAW_QUEUE;
            Some(pupil)
        }
        _ => None,
    };
    let replayed = match &uri {
        SourceUri::Replay { path, .. } => Some(path.as_path()),
        _ => None,
    };
    let inputs: Vec<&Path> = replayed.into_iter().collect();
    crate::out_dir::prepare(
        "record",
        &args.out,
        crate::out_dir::OutKind::Recording,
        &inputs,
        args.force,
    )?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    match pupil {
        Some(pupil) => runtime.block_on(record(args, pupil)),
        None => runtime.block_on(record_samples(args, uri)),
    }
}

/// The writers of one recording, one per stream (the topic's first part).
struct Recording {
    dir: PathBuf,
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

/// `info.player.json` is rewritten at least this often while recording
/// (when its times changed), so a recording killed by SIGKILL or a power
/// cut has a start time and a duration within this of its data.
const INFO_EVERY: Duration = Duration::from_secs(1);

impl Recording {
    fn new(dir: &Path) -> Self {
        Self {
            dir: dir.to_owned(),
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
    fn keep_info_current(&mut self, source: &str) -> anyhow::Result<()> {
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

    fn append(&mut self, d: &RawDatum) -> anyhow::Result<()> {
        self.append_bytes(&d.topic, &d.payload, d.pupil_t_secs)
    }

    /// Appends one datum (`topic`, msgpack `payload`, its time in seconds)
    /// to the stream its topic names.
    fn append_bytes(&mut self, topic: &str, payload: &[u8], t_secs: f64) -> anyhow::Result<()> {
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

    fn flush_if_due(&mut self) -> anyhow::Result<()> {
        for w in self.writers.values_mut() {
            w.flush_if_due()?;
        }
        Ok(())
    }

    /// `info.player.json` (Pupil Player recording format 2.x).
    fn write_info(&mut self, source: &str) -> anyhow::Result<()> {
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
            "recording_software_name": crate::out_dir::SOFTWARE_NAME,
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
        std::fs::write(&tmp, text).with_context(|| format!("cannot write {}", tmp.display()))?;
        std::fs::rename(&tmp, &path).with_context(|| format!("cannot write {}", path.display()))?;
        Ok(())
    }

    /// Writes the final `info.player.json` and closes every stream;
    /// returns the records written and a "stream: records, …" summary.
    fn finish(mut self, source: &str) -> anyhow::Result<(u64, String)> {
        for w in self.writers.values_mut() {
            w.flush()?;
        }
        self.write_info(source)?;
        let total = self.records;
        let per_stream: Vec<String> = self
            .close()?
            .iter()
            .map(|(n, k)| format!("{n}: {k}"))
            .collect();
        let streams = if per_stream.is_empty() {
            "none".to_owned()
        } else {
            per_stream.join(", ")
        };
        Ok((total, streams))
    }

    /// Closes every stream; returns (stream, records) pairs.
    fn close(self) -> anyhow::Result<Vec<(String, u64)>> {
        let mut out = Vec::new();
        for (name, w) in self.writers {
            out.push((name, w.close()?));
        }
        Ok(out)
    }
}

async fn record(args: RecordArgs, pupil: PupilConfig) -> anyhow::Result<()> {
    // SIGINT, SIGTERM and SIGHUP stop the recording the same way: drained,
    // flushed, info.player.json with the real duration (registered before
    // anything is written, so no signal leaves a truncated record).
    let signals = crate::shutdown::Signals::new()
        .context("cannot install the SIGINT/SIGTERM/SIGHUP handlers")?;
    let connect = crate::bounds::secs("--connect-secs", args.connect_secs)?;
    let (client, mut streams) = PupilClient::spawn(pupil);
    client
        .wait_connected(connect)
        .await
        .with_context(|| {
            format!(
                "no tracker at {}: is Pupil Capture (or Pupil Service) running with Pupil Remote enabled?",
                args.source
            )
        })?;
    let Some(mut raw) = streams.raw.take() else {
        bail!("internal: the Pupil client has no raw channel");
    };
    let version = client.stats().version.unwrap_or_default();
    let source_info = format!("Pupil {version}");
    let mut rec = Recording::new(&args.out);
    rec.write_info(&source_info)?;
    eprintln!(
        "recording {} (Pupil {version}) into {}{}",
        args.source,
        args.out.display(),
        for_how_long(args.secs)
    );
    let started = Instant::now();
    let deadline = deadline(args.secs)?;
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    let mut was_connected = true;
    let mut last_report = Instant::now();
    let signal = signals.first();
    tokio::pin!(signal);
    let reason = loop {
        tokio::select! {
            d = raw.recv() => match d {
                Some(d) => rec.append(&d)?,
                None => break "the Pupil client stopped",
            },
            // Decoded samples are not recorded (the raw bytes are); keep
            // the channel empty so the client does not count drops.
            _ = streams.samples.recv() => {}
            _ = tick.tick() => {
                rec.flush_if_due()?;
                rec.keep_info_current(&source_info)?;
                let stats = client.stats();
                if was_connected && !stats.connected {
                    eprintln!(
                        "tracker lost ({}); recording continues when it is back",
                        stats.last_error.as_deref().unwrap_or("no reason given")
                    );
                } else if !was_connected && stats.connected {
                    eprintln!("tracker back; recording");
                }
                was_connected = stats.connected;
                if last_report.elapsed() >= Duration::from_secs(10) {
                    last_report = Instant::now();
                    eprintln!(
                        "{:.0} s: {} datums, {} dropped by the queue",
                        started.elapsed().as_secs_f64(),
                        rec.records,
                        stats.raw_dropped
                    );
                }
            }
            _ = until(deadline) => break "duration reached",
            // Ctrl-C is SIGINT; the others are named.
            name = &mut signal => break if name == "SIGINT" { "Ctrl-C" } else { name },
        }
    };
    // Keep everything that was received: drain the queue before closing.
    while let Ok(d) = raw.try_recv() {
        rec.append(&d)?;
    }
    let stats = client.stats();
    client.shutdown().await;
    let (total, streams) = rec.finish(&source_info)?;
    println!(
        "stopped ({reason}) after {:.1} s: {total} datums ({streams}), {} dropped by the queue, {} malformed skipped; wrote {}",
        started.elapsed().as_secs_f64(),
        stats.raw_dropped,
        stats.malformed,
        args.out.display()
    );
    Ok(())
}

/// Records any other live source from its decoded samples (see the module
/// docs): the same writers, flushing, signals and drain as [`record`].
async fn record_samples(args: RecordArgs, uri: SourceUri) -> anyhow::Result<()> {
    let signals = crate::shutdown::Signals::new()
        .context("cannot install the SIGINT/SIGTERM/SIGHUP handlers")?;
    let connect = crate::bounds::secs("--connect-secs", args.connect_secs)?;
    let mut source = gazelight_tracker::transport::open(&uri)
        .with_context(|| format!("--source {}", args.source))?;
    let describe = source.describe();
    // The first sample within --connect-secs, or no recording.
    let first = match tokio::time::timeout(connect, first_sample(&mut source)).await {
        Ok(first) => first?,
        Err(_) => bail!(
            "no samples from {} within {:.1} s (--connect-secs): is the tracker on and streaming?",
            args.source,
            connect.as_secs_f64()
        ),
    };
    let mut rec = Recording::new(&args.out);
    eprintln!(
        "recording {describe} into {}{}",
        args.out.display(),
        for_how_long(args.secs)
    );
    let wanted = |topic: &str| args.topics.iter().any(|p| topic.starts_with(p.as_str()));
    let append = |rec: &mut Recording, sample: &Sample| -> anyhow::Result<()> {
        if let Some((topic, payload)) = msg::encode_sample(sample)
            .with_context(|| format!("cannot encode a sample of {describe}"))?
            && wanted(&topic)
        {
            rec.append_bytes(&topic, &payload, sample.t_secs())?;
        }
        Ok(())
    };
    append(&mut rec, &first)?;
    rec.write_info(&describe)?;
    let started = Instant::now();
    let deadline = deadline(args.secs)?;
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    let (mut losses, mut bad) = (0u64, 0u64);
    let signal = signals.first();
    tokio::pin!(signal);
    let reason = loop {
        tokio::select! {
            next = source.next() => match next {
                Ok(Some(sample)) => append(&mut rec, &sample)?,
                Ok(None) => break "the source ended",
                Err(e @ SourceError::Fatal { .. }) => return Err(e.into()),
                Err(SourceError::Disconnected { reason, .. }) => {
                    losses += 1;
                    eprintln!("tracker lost ({reason}); recording continues when it is back");
                }
                Err(_) => bad += 1,
            },
            _ = tick.tick() => {
                rec.flush_if_due()?;
                rec.keep_info_current(&describe)?;
            }
            _ = until(deadline) => break "duration reached",
            name = &mut signal => break if name == "SIGINT" { "Ctrl-C" } else { name },
        }
    };
    let (total, streams) = rec.finish(&describe)?;
    println!(
        "stopped ({reason}) after {:.1} s: {total} datums ({streams}), {} dropped by the source, {bad} bad items skipped, {losses} losses; wrote {}",
        started.elapsed().as_secs_f64(),
        source.dropped(),
        args.out.display()
    );
    Ok(())
}

/// The source's first sample; bad items and losses before it are waited
/// out (the caller bounds the wait).
async fn first_sample(source: &mut AnySource) -> anyhow::Result<Sample> {
    loop {
        match source.next().await {
            Ok(Some(s)) => return Ok(s),
            Ok(None) => bail!("{} ended before its first sample", source.describe()),
            Err(e @ SourceError::Fatal { .. }) => return Err(e.into()),
            Err(_) => {}
        }
    }
}

/// When `--secs` ends the recording (none: at a signal).
fn deadline(secs: Option<f64>) -> anyhow::Result<Option<tokio::time::Instant>> {
    Ok(match secs {
        Some(s) => tokio::time::Instant::now().checked_add(crate::bounds::secs("--secs", s)?),
        None => None,
    })
}

/// Resolves at `deadline`, never without one.
async fn until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d).await,
        None => std::future::pending().await,
    }
}

/// " for S s" or "; Ctrl-C stops", for the start line.
fn for_how_long(secs: Option<f64>) -> String {
    match secs {
        Some(s) => format!(" for {s:.1} s"),
        None => "; Ctrl-C stops".to_owned(),
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
