//! `gazelight inspect`: a summary of a recording (Neon native directory,
//! Pupil Core recording, EyeLink ASC, pupil CSV) or of a live Pupil Remote: rates, pupil ranges per eye, confidence,
//! dropouts, blinks (the recording's own and the filter chain's), warnings;
//! or of a `timeline.csv` gazelight wrote (`inspect_timeline`: the
//! pupil light response's spreads).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::import;
use gazelight_tracker::summary::{summarize_importer, summarize_live};
use std::time::Duration;

/// Arguments of `gazelight inspect`.
#[derive(Args, Debug)]
pub struct InspectArgs {
    /// A recording (a Neon native directory, a Pupil Core recording
    /// directory, an EyeLink `.asc`, a pupil `.csv` trace) or a live
    /// source: a Pupil Remote as `pupil://HOST[:PORT]` (default port 50020),
    /// a Neon as `neon://HOST[:PORT]` (default port 8080), an LSL stream
    /// (`lsl://?name=…`) or a hardware URI (`gazepoint://`, `hid://`,
    /// `usb://`, `serial://`).
    pub path: PathBuf,
    /// For a live source: how long to collect, seconds.
    #[arg(long, default_value_t = 5.0)]
    pub secs: f64,
    /// Print the summary as JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Calibration profile (JSON, `gazelight profile schema`) mapping raw
    /// tracker pupils (px, area units) onto mm before the summary.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<std::path::PathBuf>,
}

impl InspectArgs {
    /// The filter chain the summary runs: the defaults, with the
    /// `--calibration` profile (loaded once per call; small).
    fn chain(&self) -> anyhow::Result<FilterChain> {
        let mut chain = FilterChain::with_defaults();
        if let Some(path) = &self.calibration {
            let profile = gazelight_tracker::profile::PupilCalibration::load(path)
                .map_err(|e| anyhow::anyhow!("--calibration: {e}"))?;
            chain.set_calibration(profile);
        }
        Ok(chain)
    }
}

/// `inspect lsl://?name=…`: reads the stream for `--secs` (from its first
/// sample) with the machine-only LSL configuration (or `LSLAPICFG`).
fn inspect_lsl(uri: &str, args: &InspectArgs) -> anyhow::Result<()> {
    let query = gazelight_tracker::lsl::LslQuery::parse(uri).map_err(|e| anyhow::anyhow!(e))?;
    let runtime = live_runtime(uri, args)?;
    let (summary, facts) = runtime.block_on(gazelight_tracker::lsl::summarize_lsl(
        query,
        gazelight_tracker::lsl::LslConfig::default(),
        Duration::from_secs_f64(args.secs),
        args.chain()?,
    ))?;
    if args.json {
        let mut v = serde_json::to_value(&summary)?;
        if let Some(o) = v.as_object_mut() {
            o.insert("lsl_stream".into(), serde_json::to_value(&facts)?);
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("{uri}: {summary}");
    }
    Ok(())
}

/// The format name of a live source summarised through the generic path
/// (Neon and the hardware transports), or `None`.
fn live_source_kind(uri: &str) -> Option<&'static str> {
    ["neon", "gazepoint", "hid", "usb", "serial"]
        .into_iter()
        .find(|s| uri.starts_with(&format!("{s}://")))
        .map(|s| match s {
            "neon" => "neon-live",
            "gazepoint" => "gazepoint-live",
            "hid" => "hid-live",
            "usb" => "usb-live",
            _ => "serial-live",
        })
}

/// `inspect neon://…` (or a hardware URI): opens the source through the
/// one URI parser, collects `--secs` from its first sample (waiting up to
/// 10 s for it) and summarises.
fn inspect_source(uri: &str, format: &'static str, args: &InspectArgs) -> anyhow::Result<()> {
    let parsed = gazelight_tracker::transport::SourceUri::parse(uri)?;
    let runtime = live_runtime(uri, args)?;
    let mut summary = runtime.block_on(async {
        let mut source = gazelight_tracker::transport::open(&parsed)?;
        let summary = gazelight_tracker::summarize::summarize_source(
            &mut source,
            Duration::from_secs_f64(args.secs),
            Duration::from_secs(10),
            args.chain()?,
            format,
        )
        .await?;
        anyhow::Ok(summary)
    })?;
    if let Some(warning) = crate::input_report::pupil_rejection(&summary.chain) {
        eprintln!("warning: {uri}: {warning}");
        summary.warnings.push(warning);
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!("{uri}: {summary}");
    }
    Ok(())
}

/// Checks `--secs` for a live source and starts the runtime that
/// collects it, saying so on stderr.
fn live_runtime(uri: &str, args: &InspectArgs) -> anyhow::Result<tokio::runtime::Runtime> {
    if !(args.secs.is_finite() && args.secs > 0.0 && args.secs <= 3600.0) {
        anyhow::bail!("--secs {}: expected 0 < secs ≤ 3600", args.secs);
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    eprintln!("collecting from {uri} for {:.1} s ...", args.secs);
    Ok(runtime)
}

/// Runs `gazelight inspect`.
pub fn run(args: InspectArgs) -> anyhow::Result<()> {
    let uri = args.path.to_string_lossy();
    if uri.starts_with("lsl://") {
        return inspect_lsl(&uri, &args);
    }
    if let Some(kind) = live_source_kind(&uri) {
        return inspect_source(&uri, kind, &args);
    }
    if crate::inspect_timeline::is_timeline(&args.path) {
        let summary = crate::inspect_timeline::summarize(&args.path)?;
        if args.json {
            println!("{}", serde_json::to_string_pretty(&summary)?);
        } else {
            println!("{}: {summary}", args.path.display());
        }
        return Ok(());
    }
    let summary = if uri.starts_with("pupil://") {
        let runtime = live_runtime(&uri, &args)?;
        let config = gazelight_tracker::uri::pupil_config(&uri)?;
        runtime.block_on(summarize_live(
            config,
            Duration::from_secs_f64(args.secs),
            args.chain()?,
        ))?
    } else {
        let mut importer = import::open(&args.path)?;
        let summary = summarize_importer(importer.as_mut(), args.chain()?)
            .with_context(|| format!("while reading {}", args.path.display()))?;
        let c = &summary.samples;
        if c.pupil == [0, 0] && c.gaze == 0 && c.gaze_per_eye == 0 && c.blink_events == 0 {
            return Err(crate::input_report::no_samples(
                &args.path,
                importer.warnings(),
                &importer.data_files(),
            ));
        }
        let mut summary = summary;
        // The recording's events: counts per source and kind, the first few.
        match import::events::read(&args.path) {
            Ok(ev) => {
                summary
                    .warnings
                    .extend(ev.warnings.messages.iter().map(|m| format!("events: {m}")));
                summary.events = Some(ev.summary());
            }
            Err(e) => {
                eprintln!("warning: {}: events not read: {e}", args.path.display());
                summary.warnings.push(format!("events not read: {e}"));
            }
        }
        summary
    };
    let mut summary = summary;
    if let Some(warning) = crate::input_report::pupil_rejection(&summary.chain) {
        eprintln!("warning: {}: {warning}", args.path.display());
        summary.warnings.push(warning);
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!("{}: {summary}", args.path.display());
    }
    Ok(())
}
