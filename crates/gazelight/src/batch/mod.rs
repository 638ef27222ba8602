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

pub mod bids_root;
pub mod manifest;
pub mod slurm;
pub mod state;
pub mod summary;

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::Args;

use manifest::Row;
use state::{Record, State, Status};

/// Most replays at once.
const MAX_JOBS: usize = 256;
/// How often a waiting worker looks at its replay and the stop flag.
const POLL: Duration = Duration::from_millis(50);
/// Longest error message kept from a failed replay's log, characters.
const MAX_MESSAGE_CHARS: usize = 300;

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

/// The default output folder: `DIR/STEM-out` for `DIR/STEM.EXT`.
fn default_out(manifest: &Path) -> PathBuf {
    let stem = manifest
        .file_stem()
        .map_or_else(|| "batch".to_owned(), |s| s.to_string_lossy().into_owned());
    manifest.with_file_name(format!("{stem}-out"))
}

/// The rows: from a BIDS dataset root (a directory) or a manifest.
pub fn load_rows(args: &BatchArgs) -> anyhow::Result<Vec<Row>> {
    if args.manifest.is_dir() {
        bids_root::load(&args.manifest, args.defaults.as_deref())
    } else {
        if let Some(d) = &args.defaults {
            bail!(
                "--defaults {}: only for a BIDS dataset root (a manifest has its own \
                 [defaults] or columns)",
                d.display()
            );
        }
        manifest::load(&args.manifest)
    }
}

/// Runs `gazelight batch`.
pub fn run(args: BatchArgs) -> anyhow::Result<()> {
    let rows = load_rows(&args)?;
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
    let outcome = run_rows(&slice, &out, &state, args.jobs, bids)?;
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
fn check_out_dir(out: &Path, rows: &[Row]) -> anyhow::Result<()> {
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
) -> anyhow::Result<Outcome> {
    let exe = std::env::current_exe().context("cannot find gazelight's own executable")?;
    let stop = crate::shutdown::stop_flag();
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
                    let ended = run_row(&exe, row, out, state, stop.as_deref(), export);
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
        .map_err(|_| anyhow::anyhow!("a batch worker panicked"))?;
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
    stop: Option<&crate::shutdown::StopFlag>,
    export: Option<(&Path, &Mutex<()>)>,
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
            Err(e) => RowEnd::Failed(format!("{msg}; and its record: {e:#}")),
        }
    };
    if let Err(e) = state.forget(&row.id) {
        return fail(format!("{e:#}"));
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
        Err(e) => return fail(format!("{e:#}")),
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
    let values = match row_values(row, &dir, warnings) {
        Ok(v) => v,
        Err(e) => return fail(format!("summary: {e:#}")),
    };
    if let Some((bids, lock)) = export {
        let argv = match export_argv(row, &dir, bids) {
            Ok(a) => a,
            Err(e) => return fail(format!("BIDS export: {e:#}")),
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
            Err(e) => return fail(format!("BIDS export: {e:#}")),
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
        Err(e) => RowEnd::Failed(format!("{e:#}")),
    }
}

/// The row's summary values from its outputs and recording.
fn row_values(row: &Row, dir: &Path, warnings: usize) -> anyhow::Result<Vec<String>> {
    let args = row.replay_args(dir)?;
    let timeline = summary::read_timeline(&dir.join("timeline.csv"))?;
    let recording = summary::read_recording(&args, timeline.duration_secs)?;
    Ok(summary::values(&timeline, &recording, warnings))
}

/// `gazelight export --bids DIR …` of `row` with its replay's timeline in
/// `dir` (and its calibration profile, if any).
fn export_argv(row: &Row, dir: &Path, bids: &Path) -> anyhow::Result<Vec<String>> {
    let args = row.replay_args(dir)?;
    let names = row.bids_names();
    let recording = row
        .argv
        .first()
        .ok_or_else(|| anyhow::anyhow!("row {}: no recording", row.id))?;
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
    stop: Option<&crate::shutdown::StopFlag>,
) -> anyhow::Result<ExitStatus> {
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
fn write_summary(
    rows: &[Row],
    out: &Path,
    state: &State,
    bids: Option<&Path>,
) -> anyhow::Result<PathBuf> {
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
    crate::out_dir::write_atomic(&path, text.as_bytes())?;
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
    spec: &crate::trials::TrialSpec,
) -> anyhow::Result<()> {
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
                crate::out_dir::write_atomic(&dir.join("trials.csv"), text.as_bytes())?;
                let participant = row.entities.subject.clone().unwrap_or_default();
                tables.push((row.id.clone(), participant, text));
            }
            Err(e) => {
                eprintln!("batch: trials of {}: {e:#}", row.id);
                failed.push(row.id.as_str());
            }
        }
    }
    let path = out.join("trials.csv");
    crate::out_dir::write_atomic(&path, crate::trials::combine(&tables).as_bytes())?;
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
fn collect(rows: &[Row], out: &Path, state: &State, bids: Option<&Path>) -> anyhow::Result<()> {
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
