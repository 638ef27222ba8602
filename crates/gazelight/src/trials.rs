//! `gazelight trials`: the per-trial table of a replay
//! (`gazelight_render::trials`, where the logic lives; Python calls the
//! same functions); docs/screen-experiment.md.

use std::path::PathBuf;

use anyhow::Context as _;
use clap::Args;
use gazelight_render::trials::{self, TrialOptions};

/// Arguments of `gazelight trials`.
#[derive(Args, Debug)]
pub struct TrialsArgs {
    /// A replay's output folder (its `timeline.csv` and `events.csv`).
    #[arg(value_name = "REPLAY_DIR")]
    pub dir: PathBuf,
    /// Which events open a trial: `*` matches any run of characters; a
    /// pattern without `*` matches the texts that start with it.
    #[arg(long, value_name = "PATTERN")]
    pub events: String,
    /// The baseline, FROM..TO seconds from each onset (subtractive:
    /// Mathôt et al. 2018).
    #[arg(
        long,
        value_name = "FROM..TO",
        default_value = "-0.2..0",
        allow_hyphen_values = true
    )]
    pub baseline: String,
    /// The analysis window, FROM..TO seconds from each onset.
    #[arg(
        long,
        value_name = "FROM..TO",
        default_value = "0..3",
        allow_hyphen_values = true
    )]
    pub window: String,
    /// A trial is valid when at most this share of its window (and of its
    /// baseline) has no measured pupil.
    #[arg(long, value_name = "FRACTION", default_value_t = 0.5)]
    pub max_invalid: f64,
    /// Which view of a stereo replay: left or right (default: a mono
    /// replay's one view).
    #[arg(long, value_name = "EYE")]
    pub eye: Option<String>,
    /// Where to write the table (default REPLAY_DIR/trials.csv; `-` for
    /// standard output).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

/// Runs `gazelight trials`.
pub fn run(args: TrialsArgs) -> anyhow::Result<()> {
    if !(0.0..=1.0).contains(&args.max_invalid) {
        anyhow::bail!(
            "--max-invalid {}: expected a fraction from 0 to 1",
            args.max_invalid
        );
    }
    let suffix = match args.eye.as_deref() {
        None => "",
        Some("left") => "_left",
        Some("right") => "_right",
        Some(e) => anyhow::bail!("--eye {e}: expected left or right"),
    };
    let options = TrialOptions {
        pattern: args.events.clone(),
        baseline_secs: trials::parse_range("--baseline", &args.baseline)?,
        window_secs: trials::parse_range("--window", &args.window)?,
        max_invalid_fraction: args.max_invalid,
    };
    let (rows, unit) = trials::from_replay_dir(&args.dir, suffix, &options)?;
    if rows.is_empty() {
        anyhow::bail!(
            "{}: no event matches --events {:?} (see its events.csv's text column)",
            args.dir.join("events.csv").display(),
            args.events
        );
    }
    let csv = trials::to_csv(&rows, unit);
    let valid = rows.iter().filter(|r| r.valid).count();
    match args.out.as_deref() {
        Some(p) if p.as_os_str() == "-" => print!("{csv}"),
        out => {
            let path = out.map_or_else(|| args.dir.join("trials.csv"), PathBuf::from);
            std::fs::write(&path, csv).with_context(|| format!("writing {}", path.display()))?;
            println!(
                "wrote {}: {} trials ({valid} valid), pupil in {unit}",
                path.display(),
                rows.len()
            );
        }
    }
    Ok(())
}
