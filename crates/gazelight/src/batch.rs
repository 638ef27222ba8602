//! `gazelight batch MANIFEST`: many replays from one list (docs/batch.md),
//! run by `gazelight_batch` (the manifest, the rows' child replays, their
//! records, the summary, Slurm arrays). Here only what is clap's: the
//! batch's flags ([`BatchArgs`]) and `replay`'s own parser, with which the
//! batch checks and reads each row's replay options ([`ReplayParser`]).

use std::path::PathBuf;

use clap::{Args, CommandFactory, Parser};
use gazelight_batch::manifest::{Flag, Row};
use gazelight_batch::{BatchOptions, ReplayCommand, ReplayInputs};

use crate::replay::ReplayArgs;

/// Arguments of `gazelight batch`.
#[derive(Args, Debug)]
pub struct BatchArgs {
    /// The manifest: a CSV or TOML list of recordings with per-row replay
    /// options, or a BIDS dataset's root folder (one row per eye-tracking
    /// recording) (docs/batch.md).
    #[arg(value_name = "MANIFEST")]
    pub manifest: PathBuf,
    /// With a BIDS dataset root: a TOML file whose `[defaults]` table (as
    /// in a TOML manifest) gives every recording's replay options.
    #[arg(long, value_name = "FILE", conflicts_with = "slurm")]
    pub defaults: Option<PathBuf>,
    /// After each row's replay, export its recording and timeline into the
    /// BIDS dataset DIR (as `gazelight export --bids DIR REC --timeline
    /// OUT/ID/timeline.csv`), with the row's `subject`, `session`, `task`,
    /// `run` (a BIDS root's rows: their own entities).
    #[arg(long, value_name = "DIR", conflicts_with_all = ["slurm", "task"])]
    pub bids: Option<PathBuf>,
    /// Output folder: one folder per row (`OUT/ID`), `OUT/summary.csv`,
    /// and the batch's records and logs in `OUT/_batch/`. Default: beside
    /// the manifest, its name with `-out` (`study.csv` → `study-out/`).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Replays run at once (each its own process).
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub jobs: usize,
    /// Run only slice K of `--tasks N` (rows K, K + N, K + 2N, … counted
    /// from 0): one task of a Slurm job array. No summary is written; run
    /// `--collect` when every task has ended.
    #[arg(long, value_name = "K", requires = "tasks", conflicts_with_all = ["slurm", "collect"])]
    pub task: Option<usize>,
    /// The number of slices (`--task`), or of the array's tasks (`--slurm`;
    /// default one per row, at most 1000).
    #[arg(long, value_name = "N")]
    pub tasks: Option<usize>,
    /// Write a Slurm job-array script (`OUT/_batch/batch.sbatch`) whose
    /// tasks run the slices; nothing is replayed here.
    #[arg(long, conflicts_with = "collect")]
    pub slurm: bool,
    /// With `--slurm`: submit the script with `sbatch`.
    #[arg(long, requires = "slurm")]
    pub submit: bool,
    /// With `--slurm`: an extra `#SBATCH` option for the script (e.g.
    /// `--sbatch=--partition=short`); repeatable.
    #[arg(
        long = "sbatch",
        value_name = "OPTION",
        requires = "slurm",
        allow_hyphen_values = true
    )]
    pub sbatch: Vec<String>,
    /// Merge the rows' records into `OUT/summary.csv` (after a Slurm
    /// array); nothing is replayed. Exits with status 1 when a row failed
    /// or has not run.
    #[arg(long)]
    pub collect: bool,
    /// Per-trial tables: which events open a trial (as `gazelight trials
    /// --events`). Each finished recording's table goes to OUT/ID/trials.csv
    /// and all of them to OUT/trials.csv (a `recording` and a
    /// `participant` column first), at the end of the batch or with
    /// `--collect`.
    #[arg(long, value_name = "PATTERN")]
    pub trials: Option<String>,
    #[command(flatten)]
    pub trial_window: crate::trials::TrialWindowArgs,
}

impl BatchArgs {
    /// The library's options.
    fn options(&self) -> BatchOptions {
        BatchOptions {
            manifest: self.manifest.clone(),
            defaults: self.defaults.clone(),
            bids: self.bids.clone(),
            out: self.out.clone(),
            jobs: self.jobs,
            task: self.task,
            tasks: self.tasks,
            slurm: self.slurm,
            submit: self.submit,
            sbatch: self.sbatch.clone(),
            collect: self.collect,
            trials: self.trials.clone(),
            trial_window: self.trial_window.window(),
        }
    }
}

/// `gazelight replay`'s arguments, parsed as the subcommand would be.
#[derive(Parser, Debug)]
#[command(name = "replay")]
struct ReplayCli {
    #[command(flatten)]
    replay: ReplayArgs,
}

/// `replay`'s clap parser and flag checks, as the batch uses them.
struct ReplayParser;

impl ReplayCommand for ReplayParser {
    fn flags(&self) -> Vec<Flag> {
        ReplayCli::command()
            .get_arguments()
            .filter_map(|a| {
                let long = a.get_long()?.to_owned();
                let takes_value = a.get_action().takes_values();
                let path = a
                    .get_value_names()
                    .is_some_and(|n| n.iter().any(|v| v == "FILE" || v == "DIR"));
                Some(Flag {
                    long,
                    takes_value,
                    path,
                })
            })
            .collect()
    }

    fn parse(&self, argv: &[String]) -> Result<ReplayInputs, String> {
        let args = ReplayCli::try_parse_from(argv)
            .map_err(|e| first_line(&e.to_string()))?
            .replay;
        Ok(ReplayInputs {
            recording: args.recording,
            config: args.render.config,
            calibration: args.calibration,
            from_secs: args.from_secs,
        })
    }

    fn check(&self, argv: &[String]) -> Result<(), String> {
        let args = match ReplayCli::try_parse_from(argv) {
            Ok(c) => c.replay,
            Err(e) => {
                return Err(first_line(&e.to_string())
                    .trim_start_matches("error: ")
                    .to_owned());
            }
        };
        crate::replay::check_flags(&args).map_err(|e| format!("{e:#}"))?;
        crate::bounds::fps("--fps", args.render.fps).map_err(|e| format!("{e:#}"))?;
        Ok(())
    }
}

fn first_line(s: &str) -> String {
    s.lines().next().unwrap_or("").to_owned()
}

/// The rows: from a BIDS dataset root (a directory) or a manifest.
pub fn load_rows(args: &BatchArgs) -> anyhow::Result<Vec<Row>> {
    Ok(gazelight_batch::load_rows(&args.options(), &ReplayParser)?)
}

/// Runs `gazelight batch`.
pub fn run(args: BatchArgs) -> anyhow::Result<()> {
    Ok(gazelight_batch::run(args.options(), &ReplayParser)?)
}
