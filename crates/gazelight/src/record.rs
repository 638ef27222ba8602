//! `gazelight record`: a live source → a recording in Pupil's own layout
//! (`.pldata` + `_timestamps.npy` per stream and `info.player.json`); the
//! recording itself is [`gazelight_tracker::record`]. Here: the flags and
//! their bounds, the `--out` rule, the signals (SIGINT, SIGTERM and SIGHUP
//! stop the recording the same way: drained, flushed, `info.player.json`
//! with the real duration) and what is printed.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use gazelight_tracker::record::{
    Event, Losses, RecordOptions, Summary, record_pupil, record_samples,
};
use gazelight_tracker::transport::SourceUri;

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
    let duration = match args.secs {
        Some(s) => Some(crate::bounds::secs("--secs", s)?),
        None => None,
    };
    let connect = crate::bounds::secs("--connect-secs", args.connect_secs)?;
    if args.topics.iter().any(|t| t.trim().is_empty()) {
        bail!("--topics: empty topic prefix");
    }
    let uri =
        SourceUri::parse(&args.source).with_context(|| format!("--source {}", args.source))?;
    let pupil = match &uri {
        SourceUri::Pupil { .. } => Some(
            gazelight_tracker::uri::pupil_config(&args.source)
                .with_context(|| format!("--source {}", args.source))?,
        ),
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
    let opts = RecordOptions {
        source: args.source.clone(),
        out: args.out.clone(),
        software: crate::out_dir::SOFTWARE_NAME,
        topics: args.topics.clone(),
        duration,
        connect,
    };
    let summary = runtime.block_on(async {
        // Registered before anything is written, so no signal leaves a
        // truncated record.
        let signals = crate::shutdown::Signals::new()
            .context("cannot install the SIGINT/SIGTERM/SIGHUP handlers")?;
        // Ctrl-C is SIGINT; the others are named.
        let stop = async move {
            let name = signals.first().await;
            if name == "SIGINT" { "Ctrl-C" } else { name }
        };
        let print = |event: Event<'_>| print_event(&args, event);
        anyhow::Ok(match pupil {
            Some(pupil) => record_pupil(pupil, &opts, stop, print).await?,
            None => record_samples(&uri, &opts, stop, print).await?,
        })
    })?;
    print_summary(&summary, &args.out);
    Ok(())
}

/// Prints what the recording reports while it runs (on stderr).
fn print_event(args: &RecordArgs, event: Event<'_>) {
    match event {
        Event::PupilConnected { version } => eprintln!(
            "recording {} (Pupil {version}) into {}{}",
            args.source,
            args.out.display(),
            for_how_long(args.secs)
        ),
        Event::SourceStarted { describe } => eprintln!(
            "recording {describe} into {}{}",
            args.out.display(),
            for_how_long(args.secs)
        ),
        Event::Lost { reason } => eprintln!(
            "tracker lost ({}); recording continues when it is back",
            reason.unwrap_or("no reason given")
        ),
        Event::Back => eprintln!("tracker back; recording"),
        Event::Progress {
            elapsed,
            datums,
            dropped,
        } => eprintln!(
            "{:.0} s: {datums} datums, {dropped} dropped by the queue",
            elapsed.as_secs_f64()
        ),
    }
}

/// The last line: why it stopped, what it wrote and what it did not.
fn print_summary(summary: &Summary, out: &Path) {
    let head = format!(
        "stopped ({}) after {:.1} s: {} datums ({})",
        summary.reason,
        summary.elapsed.as_secs_f64(),
        summary.datums,
        summary.streams_text()
    );
    match summary.losses {
        Losses::Pupil {
            raw_dropped,
            malformed,
        } => println!(
            "{head}, {raw_dropped} dropped by the queue, {malformed} malformed skipped; wrote {}",
            out.display()
        ),
        Losses::Samples {
            dropped,
            bad,
            losses,
        } => println!(
            "{head}, {dropped} dropped by the source, {bad} bad items skipped, {losses} losses; wrote {}",
            out.display()
        ),
    }
}

/// " for S s" or "; Ctrl-C stops", for the start line.
fn for_how_long(secs: Option<f64>) -> String {
    match secs {
        Some(s) => format!(" for {s:.1} s"),
        None => "; Ctrl-C stops".to_owned(),
    }
}
