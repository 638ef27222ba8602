//! `gazelight batch MANIFEST`: many replays from one list (docs/batch.md).
//!
//! The list is a CSV or TOML manifest ([`manifest`]) or a BIDS dataset
//! root ([`bids_root`]: one row per eye-tracking recording). Each row runs what a single `gazelight replay`
//! with the row's options would — the same binary as a child process
//! (`gazelight replay REC … --out OUT/ID`), so its outputs are that
//! replay's, byte for byte — into its own folder `OUT/ID`. When it ends
//! well, its line of the summary ([`summary`]) and a completion record
//! ([`state`]) are written; `OUT/summary.csv` holds one line per row.
//!
//! - Resumable: a row whose record matches its options is skipped; a
//!   half-written one (no record) is run again with `--force`, which
//!   clears what it left.
//! - `--jobs N`: N replays at once, each in its own process.
//! - SIGINT, SIGTERM, SIGHUP: no new row starts, the running replays are
//!   asked to stop (SIGTERM), and the batch exits; finished rows keep
//!   their records, the interrupted ones run again next time. A replay's
//!   process also gets SIGTERM when the batch dies (even by SIGKILL).
//! - A failing row is recorded (`status` = `failed`, its error in
//!   `message`, its log in `OUT/_batch/ID.log`) and the others go on; the
//!   batch then exits with status 1.
//! - Slurm ([`slurm`]): `--slurm` writes a job-array script whose task K
//!   runs `--task K --tasks N` (rows K, K + N, …), `--submit` submits it,
//!   `--collect` merges the records into `summary.csv`.
//! - `--trials PATTERN` (with `gazelight trials`' `--baseline`,
//!   `--window`, `--max-invalid`, `--eye`): at the end (and with
//!   `--collect`), every finished row's per-trial table from its replay's
//!   `timeline.csv` and `events.csv` (`OUT/ID/trials.csv`) and
//!   `OUT/trials.csv` with them all, `recording` and `participant` first;
//!   the tables come from the replays' outputs, so other trial options
//!   need no replay again.
//! - `--bids DIR`: after its replay, each row's recording and timeline are
//!   exported into the BIDS dataset DIR (`gazelight export --bids`, its
//!   entities from the row), one export at a time; the row is finished
//!   only when its export is.
//!
//! The binary gives the batch what is clap's: its parser of `gazelight
//! replay` ([`ReplayCommand`]: a row is checked by the parser that will
//! read it) and the batch's options ([`BatchOptions`]); the rows then run
//! as child processes of that same executable.

// The error macros come first: the modules below use them.

/// `return Err(BatchError::Msg(format!(…)))`.
macro_rules! bail {
    ($($t:tt)*) => {
        return Err($crate::BatchError::Msg(format!($($t)*)).into())
    };
}
/// `BatchError::Msg(format!(…))`.
macro_rules! err {
    ($($t:tt)*) => {
        $crate::BatchError::Msg(format!($($t)*))
    };
}

pub mod bids_root;
pub mod inspect_timeline;
pub mod manifest;
pub mod slurm;
pub mod state;
pub mod summary;
pub mod trials;

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use manifest::Row;
use state::{Record, State, Status};

/// Why a batch (or one of its steps) failed. Printed as the CLI prints
/// errors (each source after a `: `), every message is the one the batch
/// gave before it was a library.
#[derive(Debug, thiserror::Error)]
pub enum BatchError {
    /// The message says it all (a manifest's line and field, a flag out
    /// of range, how many rows failed).
    #[error("{0}")]
    Msg(String),
    /// A file, folder or process could not be used: what was being done.
    #[error("{context}")]
    Io {
        context: String,
        #[source]
        source: std::io::Error,
    },
    /// A sidecar or a record that is not the JSON expected.
    #[error("{context}")]
    Json {
        context: String,
        #[source]
        source: serde_json::Error,
    },
    /// A number in a file name (a BIDS `run-` label).
    #[error("{context}")]
    Number {
        context: String,
        #[source]
        source: std::num::ParseIntError,
    },
    #[error(transparent)]
    Out(#[from] gazelight_output::OutError),
    #[error(transparent)]
    Config(#[from] gazelight_app::config::ConfigError),
    #[error(transparent)]
    Profile(#[from] gazelight_tracker::profile::ProfileError),
    #[error(transparent)]
    Import(#[from] gazelight_tracker::import::ImportError),
    #[error(transparent)]
    Trials(#[from] gazelight_render::trials::TrialsError),
}

/// The crate's results: [`BatchError`] unless said otherwise.
pub type Result<T, E = BatchError> = std::result::Result<T, E>;

/// An error with what was being done when it happened (the context as
/// its message, the error as its source).
pub(crate) trait Context<T> {
    fn with_context(self, what: impl FnOnce() -> String) -> Result<T>;
    fn context(self, what: &str) -> Result<T>
    where
        Self: Sized,
    {
        self.with_context(|| what.to_owned())
    }
}

impl<T> Context<T> for std::result::Result<T, std::io::Error> {
    fn with_context(self, what: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|source| BatchError::Io {
            context: what(),
            source,
        })
    }
}

impl<T> Context<T> for std::result::Result<T, serde_json::Error> {
    fn with_context(self, what: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|source| BatchError::Json {
            context: what(),
            source,
        })
    }
}

impl<T> Context<T> for std::result::Result<T, std::num::ParseIntError> {
    fn with_context(self, what: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|source| BatchError::Number {
            context: what(),
            source,
        })
    }
}

/// `e` and its sources, `outer: inner: …`, as the CLI prints an error.
pub use gazelight_output::error_chain as chain;

/// What the batch reads of a row's replay arguments.
#[derive(Clone, Debug)]
pub struct ReplayInputs {
    /// The recording replayed.
    pub recording: PathBuf,
    /// `--config`.
    pub config: Option<PathBuf>,
    /// `--calibration`.
    pub calibration: Option<PathBuf>,
    /// `--from-secs`.
    pub from_secs: f64,
}

/// `gazelight replay`'s command line as the batch needs it: the binary's
/// own parser (clap's), so that a row is checked by the parser that will
/// read it when the row runs as `gazelight replay …`.
pub trait ReplayCommand: Sync {
    /// `replay`'s long options.
    fn flags(&self) -> Vec<manifest::Flag>;
    /// Parses `argv` (`replay` first): the inputs, or the first line of
    /// the parser's error.
    fn parse(&self, argv: &[String]) -> Result<ReplayInputs, String>;
    /// Parses `argv` (`replay` first) and makes `replay`'s own checks of
    /// its flags (those made before it opens anything): the message of
    /// the first that fails (the parser's without its `error: `).
    fn check(&self, argv: &[String]) -> Result<(), String>;
}

/// Most replays at once.
const MAX_JOBS: usize = 256;
/// How often a waiting worker looks at its replay and the stop flag.
const POLL: Duration = Duration::from_millis(50);
/// Longest error message kept from a failed replay's log, characters.
const MAX_MESSAGE_CHARS: usize = 300;

/// The options of `gazelight batch` (its flags: the binary's `BatchArgs`).
#[derive(Clone, Debug)]
pub struct BatchOptions {
    /// The manifest (a CSV or TOML file) or a BIDS dataset's root folder.
    pub manifest: PathBuf,
    /// `--defaults`: with a BIDS dataset root, a TOML file whose
    /// `[defaults]` give every recording's replay options.
    pub defaults: Option<PathBuf>,
    /// `--bids`: each row's recording and timeline exported there.
    pub bids: Option<PathBuf>,
    /// `--out` (default: beside the manifest, `STEM-out`).
    pub out: Option<PathBuf>,
    /// `--jobs`: replays at once.
    pub jobs: usize,
    /// `--task K`: only slice K of `--tasks N`.
    pub task: Option<usize>,
    /// `--tasks N`: the slices, or the array's tasks.
    pub tasks: Option<usize>,
    /// `--slurm`: write the job-array script; nothing is replayed.
    pub slurm: bool,
    /// `--submit`: submit the script with `sbatch`.
    pub submit: bool,
    /// `--sbatch`: extra `#SBATCH` options.
    pub sbatch: Vec<String>,
    /// `--collect`: merge the records into `summary.csv`.
    pub collect: bool,
    /// `--trials PATTERN`: the per-trial tables, trials opened by the
    /// events matching it.
    pub trials: Option<String>,
    /// The trial tables' window, baseline, validity and eye.
    pub trial_window: trials::TrialWindow,
}

/// The default output folder: `DIR/STEM-out` for `DIR/STEM.EXT`.
fn default_out(manifest: &Path) -> PathBuf {
    let stem = manifest
        .file_stem()
        .map_or_else(|| "batch".to_owned(), |s| s.to_string_lossy().into_owned());
    manifest.with_file_name(format!("{stem}-out"))
}

/// The rows: from a BIDS dataset root (a directory) or a manifest.
pub fn load_rows(args: &BatchOptions, replay: &dyn ReplayCommand) -> Result<Vec<Row>> {
    if args.manifest.is_dir() {
        bids_root::load(&args.manifest, args.defaults.as_deref(), replay)
    } else {
        if let Some(d) = &args.defaults {
            bail!(
                "--defaults {}: only for a BIDS dataset root (a manifest has its own \
                 [defaults] or columns)",
                d.display()
            );
        }
        manifest::load(&args.manifest, replay)
    }
}

/// Runs `gazelight batch`, its rows' replays checked and read by `replay`.
pub fn run(args: BatchOptions, replay: &dyn ReplayCommand) -> Result<()> {
    let rows = load_rows(&args, replay)?;
    let trials = args
        .trials
        .as_deref()
        .map(|p| args.trial_window.spec(p))
        .transpose()?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| default_out(&args.manifest));
    if args.slurm {
        // Before anything is created: a path the script cannot name.
        slurm::check_paths(&args.manifest, &out)?;
    }
    // Before anything is created: an `--out` holding files of the user's
    // where the batch would write.
    check_out_dir(&out, &rows)?;
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let state = State::open(&out)?;
    let bids = match &args.bids {
        Some(dir) => {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("--bids: cannot create {}", dir.display()))?;
            Some(
                std::fs::canonicalize(dir)
                    .with_context(|| format!("--bids: cannot resolve {}", dir.display()))?,
            )
        }
        None => None,
    };
    let bids = bids.as_deref();
    if args.collect {
        let collected = collect(&rows, &out, &state, bids);
        if let Some(spec) = &trials {
            write_trials(&rows, &out, &state, bids, spec)?;
        }
        return collected;
    }
    if args.slurm {
        return slurm::write_and_submit(&args, &rows, &out, &state);
    }
    if !(1..=MAX_JOBS).contains(&args.jobs) {
        bail!("--jobs {}: expected 1 to {MAX_JOBS}", args.jobs);
    }
    let slice: Vec<&Row> = match (args.task, args.tasks) {
        (Some(k), Some(n)) => {
            if n == 0 || k >= n {
                bail!("--task {k} --tasks {n}: expected 0 ≤ K < N");
            }
            rows.iter().skip(k).step_by(n).collect()
        }
        (None, Some(n)) => bail!("--tasks {n} without --task (or --slurm): which slice?"),
        _ => rows.iter().collect(),
    };
    let outcome = run_rows(&slice, &out, &state, args.jobs, bids, replay)?;
    if args.task.is_none() {
        let path = write_summary(&rows, &out, &state, bids)?;
        println!("wrote {}", path.display());
        if let Some(spec) = &trials {
            write_trials(&rows, &out, &state, bids, spec)?;
        }
    }
    if let Some(sig) = outcome.interrupted {
        bail!(
            "{sig}: stopped; {} of {} recordings finished, the interrupted ones run again when the \
             same command is given again",
            outcome.finished,
            slice.len()
        );
    }
    if outcome.failed > 0 {
        bail!(
            "{} of {} recordings failed (status and message in the summary, the replay's log in {})",
            outcome.failed,
            slice.len(),
            state.dir().display()
        );
    }
    Ok(())
}

/// Refuses an `--out` that already exists without the batch's own
/// `_batch/` folder (so no earlier batch wrote it) but holds a
/// `summary.csv` or an entry named like a row's output folder: the batch
/// would overwrite the user's own files. An earlier batch's folder (with
/// `_batch/`) is resumed; a folder with other files only is fine.
fn check_out_dir(out: &Path, rows: &[Row]) -> Result<()> {
    if !out.is_dir() || out.join(state::STATE_DIR).is_dir() {
        return Ok(());
    }
    let mut clashes: Vec<String> = Vec::new();
    for name in ["summary.csv", "trials.csv"] {
        if std::fs::symlink_metadata(out.join(name)).is_ok() {
            clashes.push(name.to_owned());
        }
    }
    for row in rows {
        if std::fs::symlink_metadata(out.join(&row.id)).is_ok() {
            clashes.push(format!("{}/", row.id));
        }
    }
    if clashes.is_empty() {
        return Ok(());
    }
    let n = clashes.len();
    clashes.truncate(5);
    bail!(
        "--out {}: holds {n} entr{} the batch would write ({}{}) but no {}/ folder of an earlier \
         batch: they are not the batch's to overwrite; choose another --out (or move them)",
        out.display(),
        if n == 1 { "y" } else { "ies" },
        clashes.join(", "),
        if n > 5 { ", …" } else { "" },
        state::STATE_DIR
    )
}

/// What a run of some rows came to.
#[derive(Debug, Default)]
struct Outcome {
    finished: usize,
    failed: usize,
    interrupted: Option<&'static str>,
}

/// Whether `row` is finished (its record says ok for its options, and
/// export when `bids`, and its timeline is there).
fn finished(row: &Row, out: &Path, state: &State, bids: Option<&Path>) -> bool {
    state
        .read(&row.id)
        .is_some_and(|r| r.status == Status::Ok && r.options_hash == row.options_hash(bids))
        && out.join(&row.id).join("timeline.csv").is_file()
}

/// The progress counters, printed as one line on stderr after each row.
struct Progress {
    total: usize,
    done: usize,
    skipped: usize,
    failed: usize,
    /// Rows run (not skipped) that have ended, their frames and the sum
    /// of their wall times (each from its start to its end, in its worker).
    ran: usize,
    frames: u64,
    row_secs: f64,
    to_run: usize,
    jobs: usize,
    /// When each running row started (rows started, not yet ended).
    running: Vec<Instant>,
    started: Instant,
}

impl Progress {
    fn line(&self) -> String {
        let secs = self.started.elapsed().as_secs_f64();
        let fps = if secs > 0.0 {
            self.frames as f64 / secs
        } else {
            0.0
        };
        let eta = if self.ran > 0 {
            let running: Vec<f64> = self
                .running
                .iter()
                .map(|t| t.elapsed().as_secs_f64())
                .collect();
            let unstarted = self.to_run.saturating_sub(self.ran + running.len());
            hms(eta_secs(
                self.row_secs / self.ran as f64,
                &running,
                unstarted,
                self.jobs,
            ))
        } else {
            "-".to_owned()
        };
        format!(
            "batch: {}/{} recordings done ({} skipped, {} failed) · {} frames at {fps:.1} frames/s · ETA {eta}",
            self.done, self.total, self.skipped, self.failed, self.frames
        )
    }
}

/// The time left, in seconds, when rows take `row_secs` each (the mean
/// of the rows ended so far: their measured rate), `running_secs` holds
/// how long each running row has run, `unstarted` rows wait and `jobs`
/// workers take the next row as soon as theirs ends: each worker's load
/// is what its running row has left (at least 0), the unstarted rows go
/// to the least loaded workers in turn, and the batch ends with the most
/// loaded one.
fn eta_secs(row_secs: f64, running_secs: &[f64], unstarted: usize, jobs: usize) -> f64 {
    let jobs = jobs.max(1);
    let mut loads: Vec<f64> = running_secs
        .iter()
        .map(|e| (row_secs - e).max(0.0))
        .collect();
    loads.resize(jobs.max(loads.len()), 0.0);
    loads.sort_by(f64::total_cmp);
    // Every load is within one row of every other (0..=row_secs), so the
    // least loaded worker after each added row is the next in this order:
    // whole rounds for all, then one more row for the least loaded.
    let rounds = unstarted / loads.len();
    let extra = unstarted % loads.len();
    loads
        .iter()
        .enumerate()
        .map(|(i, l)| l + row_secs * (rounds + usize::from(i < extra)) as f64)
        .fold(0.0, f64::max)
}

fn hms(secs: f64) -> String {
    let s = secs.round().max(0.0) as u64;
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

/// Runs the unfinished `rows`, `jobs` at a time.
fn run_rows(
    rows: &[&Row],
    out: &Path,
    state: &State,
    jobs: usize,
    bids: Option<&Path>,
    replay: &dyn ReplayCommand,
) -> Result<Outcome> {
    let exe = std::env::current_exe().context("cannot find gazelight's own executable")?;
    let stop = gazelight_app::shutdown::stop_flag();
    // One export at a time: they share the dataset's participants.tsv.
    let export_lock = Mutex::new(());
    let export = bids.map(|dir| (dir, &export_lock));
    let mut todo = Vec::new();
    let mut skipped = 0;
    for row in rows {
        if finished(row, out, state, bids) {
            eprintln!("batch: skip {}: finished earlier", row.id);
            skipped += 1;
        } else {
            todo.push(*row);
        }
    }
    let progress = Mutex::new(Progress {
        total: rows.len(),
        done: skipped,
        skipped,
        failed: 0,
        ran: 0,
        frames: 0,
        row_secs: 0.0,
        to_run: todo.len(),
        jobs,
        running: Vec::new(),
        started: Instant::now(),
    });
    if let Ok(p) = progress.lock() {
        eprintln!("{}", p.line());
    }
    let next = AtomicUsize::new(0);
    let outcome = Mutex::new(Outcome {
        finished: skipped,
        ..Outcome::default()
    });
    std::thread::scope(|scope| {
        for _ in 0..jobs.min(todo.len()) {
            scope.spawn(|| {
                loop {
                    if stop.as_ref().is_some_and(|s| s.requested()) {
                        break;
                    }
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(row) = todo.get(i) else { break };
                    let row_started = Instant::now();
                    if let Ok(mut p) = progress.lock() {
                        p.running.push(row_started);
                    }
                    let ended = run_row(&exe, row, out, state, stop.as_deref(), export, replay);
                    let (Ok(mut p), Ok(mut o)) = (progress.lock(), outcome.lock()) else {
                        break;
                    };
                    if let Some(k) = p.running.iter().position(|t| *t == row_started) {
                        p.running.swap_remove(k);
                    }
                    if !matches!(ended, RowEnd::Interrupted) {
                        p.row_secs += row_started.elapsed().as_secs_f64();
                    }
                    match ended {
                        RowEnd::Done(r) => {
                            eprintln!(
                                "batch: done {}: {} frames in {:.1} s",
                                row.id, r.frames, r.wall_secs
                            );
                            p.done += 1;
                            p.ran += 1;
                            p.frames += r.frames;
                            o.finished += 1;
                        }
                        RowEnd::Failed(msg) => {
                            eprintln!(
                                "batch: FAILED {}: {msg} (log: {})",
                                row.id,
                                state.log_path(&row.id).display()
                            );
                            p.done += 1;
                            p.ran += 1;
                            p.failed += 1;
                            o.failed += 1;
                        }
                        RowEnd::Interrupted => {
                            eprintln!("batch: interrupted {}: it runs again next time", row.id);
                        }
                    }
                    eprintln!("{}", p.line());
                }
            });
        }
    });
    let mut outcome = outcome
        .into_inner()
        .map_err(|_| err!("a batch worker panicked"))?;
    outcome.interrupted = stop.as_ref().and_then(|s| s.signal());
    if let Ok(p) = progress.lock() {
        let secs = p.started.elapsed().as_secs_f64();
        println!(
            "batch: ran {} recordings ({} skipped, {} failed): {} frames in {secs:.1} s, {:.2} frames/s with --jobs {jobs}",
            p.ran,
            p.skipped,
            p.failed,
            p.frames,
            if secs > 0.0 {
                p.frames as f64 / secs
            } else {
                0.0
            }
        );
    }
    Ok(outcome)
}

/// How one row's run ended.
enum RowEnd {
    Done(Record),
    Failed(String),
    Interrupted,
}

/// Runs one row's replay as a child process, then writes its record.
fn run_row(
    exe: &Path,
    row: &Row,
    out: &Path,
    state: &State,
    stop: Option<&gazelight_app::shutdown::StopFlag>,
    export: Option<(&Path, &Mutex<()>)>,
    replay_cli: &dyn ReplayCommand,
) -> RowEnd {
    let hash = row.options_hash(export.map(|(d, _)| d));
    let fail = |msg: String| -> RowEnd {
        let record = Record {
            id: row.id.clone(),
            options_hash: hash.clone(),
            status: Status::Failed,
            message: msg.clone(),
            values: Vec::new(),
            frames: 0,
            wall_secs: 0.0,
        };
        match state.write(&record) {
            Ok(()) => RowEnd::Failed(msg),
            Err(e) => RowEnd::Failed(format!("{msg}; and its record: {}", chain(&e))),
        }
    };
    if let Err(e) = state.forget(&row.id) {
        return fail(chain(&e));
    }
    let dir = out.join(&row.id);
    let started = Instant::now();
    let mut replay = vec!["replay".to_owned()];
    replay.extend(row.argv.iter().cloned());
    replay.push(format!("--out={}", dir.display()));
    if dir.exists() {
        replay.push("--force".to_owned());
    }
    let log = state.log_path(&row.id);
    let status = match spawn_and_wait(exe, &replay, &log, false, stop) {
        Ok(s) => s,
        Err(e) => return fail(chain(&e)),
    };
    let wall_secs = started.elapsed().as_secs_f64();
    if !status.success() {
        if stop.is_some_and(|s| s.requested()) {
            return RowEnd::Interrupted;
        }
        return fail(error_of(&state.log_path(&row.id), status));
    }
    // The replay's own warnings, before an export appends to its log.
    let warnings = summary::count_warnings(&std::fs::read_to_string(&log).unwrap_or_default());
    let values = match row_values(row, &dir, warnings, replay_cli) {
        Ok(v) => v,
        Err(e) => return fail(format!("summary: {}", chain(&e))),
    };
    if let Some((bids, lock)) = export {
        let argv = match export_argv(row, &dir, bids, replay_cli) {
            Ok(a) => a,
            Err(e) => return fail(format!("BIDS export: {}", chain(&e))),
        };
        let status = {
            let Ok(_one) = lock.lock() else {
                return fail("BIDS export: another export panicked".to_owned());
            };
            spawn_and_wait(exe, &argv, &log, true, stop)
        };
        match status {
            Ok(s) if s.success() => {}
            Ok(s) => {
                if stop.is_some_and(|s| s.requested()) {
                    return RowEnd::Interrupted;
                }
                return fail(format!("BIDS export: {}", error_of(&log, s)));
            }
            Err(e) => return fail(format!("BIDS export: {}", chain(&e))),
        }
    }
    let frames = values
        .first()
        .and_then(|f| f.parse().ok())
        .unwrap_or_default();
    let record = Record {
        id: row.id.clone(),
        options_hash: hash,
        status: Status::Ok,
        message: String::new(),
        values,
        frames,
        wall_secs,
    };
    match state.write(&record) {
        Ok(()) => RowEnd::Done(record),
        Err(e) => RowEnd::Failed(chain(&e)),
    }
}

/// The row's summary values from its outputs and recording.
fn row_values(
    row: &Row,
    dir: &Path,
    warnings: usize,
    replay: &dyn ReplayCommand,
) -> Result<Vec<String>> {
    let args = row.replay_args(dir, replay)?;
    let timeline = summary::read_timeline(&dir.join("timeline.csv"))?;
    let recording = summary::read_recording(&args, timeline.duration_secs)?;
    Ok(summary::values(&timeline, &recording, warnings))
}

/// `gazelight export --bids DIR …` of `row` with its replay's timeline in
/// `dir` (and its calibration profile, if any).
fn export_argv(
    row: &Row,
    dir: &Path,
    bids: &Path,
    replay: &dyn ReplayCommand,
) -> Result<Vec<String>> {
    let args = row.replay_args(dir, replay)?;
    let names = row.bids_names();
    let recording = row
        .argv
        .first()
        .ok_or_else(|| err!("row {}: no recording", row.id))?;
    let mut argv = vec![
        "export".to_owned(),
        format!("--bids={}", bids.display()),
        format!("--subject={}", names.subject),
        format!("--task={}", names.task),
        format!("--timeline={}", dir.join("timeline.csv").display()),
    ];
    if let Some(s) = &names.session {
        argv.push(format!("--session={s}"));
    }
    if let Some(r) = names.run {
        argv.push(format!("--run={r}"));
    }
    if let Some(c) = &args.calibration {
        argv.push(format!("--calibration={}", c.display()));
    }
    argv.push("--".to_owned());
    argv.push(recording.clone());
    Ok(argv)
}

/// Starts `gazelight ARGV…` (a row's replay, with `--force` when its
/// folder exists: what an interrupted run left is cleared; or its export),
/// its output to `log` (appended to when `append`), in its own process
/// group (a Ctrl-C reaches the batch, which passes it on once), with
/// SIGTERM as its parent-death signal; waits for it, passing a stop
/// request on as SIGTERM.
fn spawn_and_wait(
    exe: &Path,
    argv: &[String],
    log: &Path,
    append: bool,
    stop: Option<&gazelight_app::shutdown::StopFlag>,
) -> Result<ExitStatus> {
    let log_file = std::fs::OpenOptions::new()
        .create(true)
        .write(true)
        .append(append)
        .truncate(!append)
        .open(log)
        .with_context(|| format!("cannot write {}", log.display()))?;
    let err_file = log_file
        .try_clone()
        .with_context(|| format!("cannot write {}", log.display()))?;
    let mut cmd = Command::new(exe);
    cmd.args(argv);
    cmd.stdin(Stdio::null())
        .stdout(log_file)
        .stderr(err_file)
        .process_group(0);
    // SAFETY: getpid before the fork; in the child only prctl and getppid,
    // both async-signal-safe, run between fork and exec.
    let parent = unsafe { libc::getpid() };
    // SAFETY: see above.
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The batch died before the signal was set: do not run orphaned.
            if libc::getppid() != parent {
                return Err(std::io::Error::other("the batch ended"));
            }
            Ok(())
        });
    }
    let mut child = cmd
        .spawn()
        .with_context(|| format!("cannot start {}", exe.display()))?;
    let mut passed_on = false;
    loop {
        if let Some(status) = child
            .try_wait()
            .context("waiting for the child gazelight")?
        {
            return Ok(status);
        }
        if !passed_on && stop.is_some_and(|s| s.requested()) {
            if let Ok(pid) = i32::try_from(child.id()) {
                // SAFETY: kill on our own child's pid (not yet reaped).
                unsafe { libc::kill(pid, libc::SIGTERM) };
            }
            passed_on = true;
        }
        std::thread::sleep(POLL);
    }
}

/// The replay's error from its log (its last `error:` line), or its exit
/// status.
fn error_of(log: &Path, status: ExitStatus) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let line = text
        .lines()
        .rev()
        .find_map(|l| l.strip_prefix("error: "))
        .map_or_else(|| format!("the replay ended with {status}"), str::to_owned);
    line.chars().take(MAX_MESSAGE_CHARS).collect()
}

/// Writes `OUT/summary.csv` (atomically) from the rows' records: one line
/// per manifest row in manifest order; a row without a record for its
/// current options is `pending`.
fn write_summary(rows: &[Row], out: &Path, state: &State, bids: Option<&Path>) -> Result<PathBuf> {
    let mut text = String::from("id,recording,status,message");
    for c in summary::COLUMNS {
        text.push(',');
        text.push_str(c);
    }
    text.push('\n');
    for row in rows {
        let record = state
            .read(&row.id)
            .filter(|r| r.options_hash == row.options_hash(bids));
        let (status, message, values) = match record {
            Some(r) if r.status == Status::Ok && r.values.len() == summary::COLUMNS.len() => {
                ("ok", String::new(), r.values)
            }
            Some(r) if r.status == Status::Failed => ("failed", r.message, Vec::new()),
            _ => ("pending", String::new(), Vec::new()),
        };
        let mut cells = vec![
            summary::csv_cell(&row.id),
            summary::csv_cell(&row.recording),
            status.to_owned(),
            summary::csv_cell(&message),
        ];
        cells.extend(
            (0..summary::COLUMNS.len()).map(|i| summary::csv_cell(values.get(i).map_or("", |v| v))),
        );
        text.push_str(&cells.join(","));
        text.push('\n');
    }
    let path = out.join("summary.csv");
    gazelight_output::write_atomic(&path, text.as_bytes())?;
    Ok(path)
}

/// Writes every finished row's per-trial table (`OUT/ID/trials.csv`) and
/// `OUT/trials.csv` with them all; a row whose table cannot be made (no
/// `events.csv`) is named, and the batch then fails.
fn write_trials(
    rows: &[Row],
    out: &Path,
    state: &State,
    bids: Option<&Path>,
    spec: &trials::TrialSpec,
) -> Result<()> {
    let mut tables = Vec::new();
    let mut failed = Vec::new();
    let (mut n, mut valid) = (0, 0);
    for row in rows {
        if !finished(row, out, state, bids) {
            continue;
        }
        let dir = out.join(&row.id);
        match spec.table(&dir) {
            Ok((trials, unit)) => {
                if trials.is_empty() {
                    eprintln!(
                        "batch: trials of {}: no event matches --trials {:?}",
                        row.id, spec.options.pattern
                    );
                }
                n += trials.len();
                valid += trials.iter().filter(|t| t.valid).count();
                let text = gazelight_render::trials::to_csv(&trials, unit);
                gazelight_output::write_atomic(&dir.join("trials.csv"), text.as_bytes())?;
                let participant = row.entities.subject.clone().unwrap_or_default();
                tables.push((row.id.clone(), participant, text));
            }
            Err(e) => {
                eprintln!("batch: trials of {}: {}", row.id, chain(&e));
                failed.push(row.id.as_str());
            }
        }
    }
    let path = out.join("trials.csv");
    gazelight_output::write_atomic(&path, trials::combine(&tables).as_bytes())?;
    println!(
        "wrote {}: {n} trials ({valid} valid) of {} recordings",
        path.display(),
        tables.len()
    );
    if !failed.is_empty() {
        bail!(
            "--trials: {} recordings have no table [{}] (the reason above each)",
            failed.len(),
            some_ids(&failed)
        );
    }
    Ok(())
}

/// Most row ids an error message lists.
const MAX_IDS_SHOWN: usize = 10;

/// The first [`MAX_IDS_SHOWN`] of `ids`, then how many more: a message of
/// a 100 000-row batch stays one readable line.
fn some_ids(ids: &[&str]) -> String {
    let mut s = ids
        .iter()
        .take(MAX_IDS_SHOWN)
        .copied()
        .collect::<Vec<_>>()
        .join(", ");
    if ids.len() > MAX_IDS_SHOWN {
        s.push_str(&format!(", … and {} more", ids.len() - MAX_IDS_SHOWN));
    }
    s
}

/// `--collect`: the summary from the records; an error when a row failed
/// or has not run.
fn collect(rows: &[Row], out: &Path, state: &State, bids: Option<&Path>) -> Result<()> {
    let path = write_summary(rows, out, state, bids)?;
    let mut ok = 0;
    let mut failed = Vec::new();
    let mut pending = Vec::new();
    for row in rows {
        match state
            .read(&row.id)
            .filter(|r| r.options_hash == row.options_hash(bids))
        {
            Some(r) if r.status == Status::Ok => ok += 1,
            Some(_) => failed.push(row.id.as_str()),
            None => pending.push(row.id.as_str()),
        }
    }
    println!(
        "collected {} rows into {}: {ok} ok, {} failed, {} pending",
        rows.len(),
        path.display(),
        failed.len(),
        pending.len()
    );
    if !failed.is_empty() || !pending.is_empty() {
        bail!(
            "not every row finished: {} failed [{}], {} pending [{}] (every row's status is in {})",
            failed.len(),
            some_ids(&failed),
            pending.len(),
            some_ids(&pending),
            path.display()
        );
    }
    Ok(())
}

/// A stand-in for the binary's `replay` parser: a few of its options,
/// its error texts where the tests look at them.
#[cfg(test)]
pub(crate) mod test_replay {
    use std::path::PathBuf;

    use crate::manifest::Flag;
    use crate::{ReplayCommand, ReplayInputs};

    pub(crate) struct Fake;

    impl ReplayCommand for Fake {
        fn flags(&self) -> Vec<Flag> {
            [
                ("fps", true, false),
                ("size", true, false),
                ("from-secs", true, false),
                ("no-frames", false, false),
                ("stereo", false, false),
                ("scene", true, true),
                ("config", true, true),
                ("calibration", true, true),
                ("trace", true, true),
                ("out", true, true),
                ("force", false, false),
            ]
            .map(|(long, takes_value, path)| Flag {
                long: long.to_owned(),
                takes_value,
                path,
            })
            .to_vec()
        }

        fn parse(&self, argv: &[String]) -> Result<ReplayInputs, String> {
            let mut inputs = ReplayInputs {
                recording: PathBuf::new(),
                config: None,
                calibration: None,
                from_secs: 0.0,
            };
            for a in argv.iter().skip(1) {
                let Some(flag) = a.strip_prefix("--") else {
                    inputs.recording = a.into();
                    continue;
                };
                let (name, value) = flag.split_once('=').unwrap_or((flag, ""));
                let bad = || format!("error: invalid value '{value}' for '--{name} <X>'");
                match name {
                    "fps" => drop(value.parse::<f64>().map_err(|_| bad())?),
                    "size" if !value.contains('x') => return Err(bad()),
                    "from-secs" => inputs.from_secs = value.parse().map_err(|_| bad())?,
                    "config" => inputs.config = Some(value.into()),
                    "calibration" => inputs.calibration = Some(value.into()),
                    _ => {}
                }
            }
            Ok(inputs)
        }

        fn check(&self, argv: &[String]) -> Result<(), String> {
            let inputs = self
                .parse(argv)
                .map_err(|e| e.trim_start_matches("error: ").to_owned())?;
            if inputs.from_secs < 0.0 {
                return Err(format!(
                    "--from-secs {}: expected 0 or more seconds",
                    inputs.from_secs
                ));
            }
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::eta_secs;

    /// Rows of `row_secs` each run by `jobs` workers from time 0 (each
    /// takes the next row as its own ends): at every row's end, the ETA
    /// from the measured row time against the real time left.
    fn check_schedule(rows: usize, jobs: usize, row_secs: f64) {
        let end = rows.div_ceil(jobs) as f64 * row_secs;
        // Each worker's running row's start, or None when idle.
        let mut busy: Vec<Option<f64>> = vec![None; jobs];
        let mut started = 0;
        for slot in busy.iter_mut().take(rows) {
            *slot = Some(0.0);
            started += 1;
        }
        // The next row to end (the lowest worker on a tie).
        while let Some((k, now)) = busy
            .iter()
            .enumerate()
            .filter_map(|(k, s)| s.map(|t| (k, t + row_secs)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
        {
            busy[k] = None;
            let running: Vec<f64> = busy.iter().flatten().map(|t| now - t).collect();
            let eta = eta_secs(row_secs, &running, rows - started, jobs);
            assert!(
                (eta - (end - now)).abs() < 1e-9,
                "{rows} rows, {jobs} jobs, a row ends at {now}: ETA {eta}, left {}",
                end - now
            );
            if started < rows {
                busy[k] = Some(now);
                started += 1;
            }
        }
    }

    #[test]
    fn the_eta_is_the_time_left_for_rows_of_known_time() {
        for jobs in 1..=4 {
            for rows in 1..=9 {
                check_schedule(rows, jobs, 10.0);
            }
        }
        // Four jobs, five rows of 10 s: after the first four (10 s in),
        // 10 s are left; rows ÷ elapsed (the old estimate) said 2.5 s.
        assert_eq!(eta_secs(10.0, &[], 1, 4), 10.0);
        // A row halfway through and two waiting, two jobs: 5 + 10 on one
        // worker, 10 on the other.
        assert_eq!(eta_secs(10.0, &[5.0], 2, 2), 15.0);
        // A row running longer than the mean counts as ending now.
        assert_eq!(eta_secs(10.0, &[12.0], 0, 2), 0.0);
    }
}
