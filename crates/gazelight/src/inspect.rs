//! `gazelight inspect`: a summary of a recording (Neon native directory,
//! EyeLink ASC, pupil CSV): rates, pupil ranges per eye, confidence,
//! dropouts, blinks (the recording's own and the filter chain's), warnings.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::import;
use gazelight_tracker::summary::summarize_importer;

/// Arguments of `gazelight inspect`.
#[derive(Args, Debug)]
pub struct InspectArgs {
    /// A recording: a Neon native directory, an EyeLink `.asc`, or a pupil
    /// `.csv` trace.
    pub path: PathBuf,
    /// Print the summary as JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs `gazelight inspect`.
pub fn run(args: InspectArgs) -> anyhow::Result<()> {
    let mut importer = import::open(&args.path)?;
    let summary = summarize_importer(importer.as_mut(), FilterChain::with_defaults())
        .with_context(|| format!("while reading {}", args.path.display()))?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!("{}: {summary}", args.path.display());
    }
    Ok(())
}
