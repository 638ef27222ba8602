//! `gazelight export --bids DIR RECORDING`: a recording (anything
//! `replay` reads: Neon, Pupil Core, EyeLink `.asc`, pupil `.csv`, `.xdf`,
//! BIDS) written as a BIDS eye-tracking dataset (BIDS 1.11, physio with
//! `PhysioType: "eyetrack"`), with gazelight's filtered pupil and blinks
//! (and, from a replay's `timeline.csv`, the light-driven and residual
//! pupil and the luminance at gaze) in `DIR/derivatives/gazelight/`.
//! The files are described in `docs/xdf-bids.md`; the writing is
//! `gazelight_tracker::import::bids`.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::import;
use gazelight_tracker::import::bids::BidsNames;

/// Arguments of `gazelight export`.
#[derive(Args, Debug)]
pub struct ExportArgs {
    /// Write a BIDS eye-tracking dataset rooted at DIR (created, or added
    /// to: files of the same names are replaced, the dataset's top-level
    /// files kept, the participant added): per eye
    /// `sub-<SUBJECT>/beh/…_recording-eye1|eye2|eye3_physio.tsv.gz` and
    /// `.json` (right, left, binocular gaze), the tracker's blinks as
    /// `…_physioevents`, and `derivatives/gazelight/` with the filtered
    /// pupil and gaze, the filter's blinks and dropouts and, with
    /// --timeline, the replay's per-frame values.
    #[arg(long, value_name = "DIR", required = true)]
    pub bids: PathBuf,
    /// The recording: a Neon or Pupil Core directory, an EyeLink `.asc`, a
    /// pupil `.csv`, an `.xdf` (`FILE.xdf?stream=NAME`) or a BIDS
    /// `*_physio.tsv.gz`.
    pub recording: PathBuf,
    /// BIDS subject label (letters and digits).
    #[arg(long, default_value = "01")]
    pub subject: String,
    /// BIDS session label (letters and digits); none by default.
    #[arg(long)]
    pub session: Option<String>,
    /// BIDS task label (letters and digits).
    #[arg(long, default_value = "replay")]
    pub task: String,
    /// BIDS run index.
    #[arg(long)]
    pub run: Option<u32>,
    /// A `timeline.csv` that `gazelight replay` wrote for this recording:
    /// its per-frame pupil, light-driven pupil, residual and luminances go
    /// into the derivatives.
    #[arg(long, value_name = "FILE")]
    pub timeline: Option<PathBuf>,
    /// Calibration profile (JSON, `gazelight profile schema`) mapping raw
    /// pupils onto mm for the filtered derivative.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
}

/// Runs `gazelight export`.
pub fn run(args: ExportArgs) -> anyhow::Result<()> {
    let names = BidsNames {
        subject: args.subject.clone(),
        session: args.session.clone(),
        task: args.task.clone(),
        run: args.run,
    };
    // Reading a BIDS recording while writing over it would truncate it.
    let file = import::xdf::split_query(&args.recording).map_or(args.recording.clone(), |(f, _)| f);
    if let (Ok(rec), Ok(dir)) = (file.canonicalize(), args.bids.canonicalize())
        && rec.starts_with(&dir)
    {
        anyhow::bail!(
            "export --bids {}: the recording {} is inside it; write to another folder",
            args.bids.display(),
            args.recording.display()
        );
    }
    // Every input is opened before the first file is written: a missing
    // or unreadable --calibration or --timeline is refused with nothing
    // written (it was found after the raw files were).
    let profile = match &args.calibration {
        Some(path) => Some(
            gazelight_tracker::profile::PupilCalibration::load(path)
                .map_err(|e| anyhow::anyhow!("--calibration: {e}"))?,
        ),
        None => None,
    };
    if let Some(path) = &args.timeline {
        gazelight_input::open(path)
            .with_context(|| format!("--timeline: cannot read {}", path.display()))?;
    }
    let mut importer = import::open(&args.recording)?;
    // Every file is staged and moved into place only when all are
    // written: a failure (a full disk, a recording that breaks half-way)
    // leaves the dataset as it was.
    let mut tx = import::bids::Transaction::new(&args.bids, &names)?;
    // The sidecars name the recording by its own name (no path of this
    // machine), its tracker and its stated rate.
    // The recording's events: messages in each eye's physioevents, the
    // trials in the task's _events.tsv (docs/events.md).
    // Events that cannot be read are a warning, not the end of the run
    // (inspect says the same).
    let events = import::events::read(&args.recording).unwrap_or_else(|e| {
        eprintln!(
            "warning: {}: events not read: {e}",
            args.recording.display()
        );
        import::events::RecordingEvents::default()
    });
    let raw = import::bids::export_raw_with_events(
        importer.as_mut(),
        &mut tx,
        &args.recording,
        Some(&events),
    )
    .with_context(|| format!("while writing {}", args.bids.display()))?;
    for (path, rows, rate) in &raw.files {
        println!("{}: {rows} rows, {rate:.2} Hz", path.display());
    }
    if raw.blinks > 0 {
        println!("{} blinks the tracker reported (physioevents)", raw.blinks);
    }
    if raw.messages > 0 {
        println!(
            "{} events of the recording as messages (physioevents), {} trials (_events.tsv)",
            raw.messages, raw.trials
        );
    }
    if raw.unit_mismatch > 0 {
        eprintln!(
            "warning: {} pupil samples in a second unit left out (one unit per eye file)",
            raw.unit_mismatch
        );
    }
    let mut chain = FilterChain::with_defaults();
    if let Some(profile) = profile {
        chain.set_calibration(profile);
    }
    let mut again = import::open(&args.recording)?;
    let der = import::bids::export_derivative(
        again.as_mut(),
        &mut chain,
        &mut tx,
        args.timeline.as_deref(),
    )
    .with_context(|| {
        format!(
            "while writing {}/derivatives/gazelight",
            args.bids.display()
        )
    })?;
    let stale = tx
        .commit()
        .with_context(|| format!("while moving the files into {}", args.bids.display()))?;
    for path in &stale {
        println!(
            "{}: removed (an earlier export's file this recording no longer has)",
            path.display()
        );
    }
    for path in &der.files {
        println!("{}", path.display());
    }
    println!(
        "{} closures (blinks, dropouts) from the filter chain",
        der.closures
    );
    Ok(())
}
