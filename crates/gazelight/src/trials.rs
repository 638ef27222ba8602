//! `gazelight trials`: the per-trial table of a replay
//! (`gazelight_batch::trials`, and `gazelight_render::trials` where the
//! logic lives; Python calls the same functions); `batch --trials` uses
//! the same options ([`TrialWindowArgs`]) for every recording;
//! docs/screen-experiment.md. Here only the flags.

use std::path::PathBuf;

use clap::Args;
pub use gazelight_batch::trials::*;

/// The options of a per-trial table besides its events pattern: shared
/// by `gazelight trials` and `gazelight batch --trials`.
#[derive(Args, Clone, Debug)]
pub struct TrialWindowArgs {
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
}

impl TrialWindowArgs {
    /// The library's options.
    pub fn window(&self) -> TrialWindow {
        TrialWindow {
            baseline: self.baseline.clone(),
            window: self.window.clone(),
            max_invalid: self.max_invalid,
            eye: self.eye.clone(),
        }
    }
}

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
    #[command(flatten)]
    pub window: TrialWindowArgs,
    /// Where to write the table (default REPLAY_DIR/trials.csv; `-` for
    /// standard output).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

/// Runs `gazelight trials`.
pub fn run(args: TrialsArgs) -> anyhow::Result<()> {
    Ok(write_table(
        &args.dir,
        &args.events,
        &args.window.window(),
        args.out.as_deref(),
    )?)
}
