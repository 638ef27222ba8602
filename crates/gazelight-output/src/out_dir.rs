//! The one rule for "may this command write its `--out` here": every
//! command that writes `--out` (`render`, `replay`, `run`, `record`, `psf`,
//! `calibrate`) asks [`prepare`] before it writes anything.
//!
//! Refused, whatever `--force` says:
//!
//! - an `--out` that **holds an input** of the command where the command
//!   would overwrite or clear it (the recording, trace, scene,
//!   configuration, calibration profile or head trace is `--out` itself, is
//!   named like one of the command's outputs, or lies under `frames/`):
//!   `replay DIR/timeline.csv --out DIR` would overwrite the timeline it is
//!   replaying; an input of another name beside the outputs is untouched
//!   and fine;
//! - an `--out` that **holds another kind of recording**: a Pupil Capture
//!   recording (1.x `info.csv`, an `info.player.json` another program wrote,
//!   `.pldata` streams without a gazelight `info.player.json`) or a Neon
//!   recording (`info.json` beside `.raw`/`.time` streams) — `record --out`
//!   into a Pupil Capture 1.x recording used to truncate its `pupil.pldata`;
//!   for every command but `record`, a gazelight recording too;
//! - an `--out` that is a file (a directory is expected), or for
//!   `calibrate` a directory (a file is expected).
//!
//! Refused **unless `--force`**: an `--out` that already holds what the
//! command writes — a previous run's outputs (any of `timeline.csv`,
//! `events.csv`, `psf.csv`, `xr.csv`, `session.json`, `contact_sheet.png`, `plot.png`, `frames/frame_*`
//! for `render`/`replay`/`run`; a gazelight recording for `record`;
//! `kernel.exr`, `kernel.png`, `psf.json` for `psf`; the profile itself for
//! `calibrate`). With `--force` those are **removed first**, so nothing of
//! the earlier run is left beside the new outputs (a re-run of `render`
//! after a SIGKILL keeps none of the killed run's extra frames). Other
//! files in the directory are never touched.

use std::path::{Path, PathBuf};

/// Why `--out` may not be written, or a file could not be.
#[derive(Debug, thiserror::Error)]
pub enum OutError {
    /// A refusal; the message says what was found and what to do.
    #[error("{0}")]
    Refused(String),
    /// A filesystem call failed on what `what` names.
    #[error("{what}")]
    Io {
        /// What was being done, and on which path.
        what: String,
        #[source]
        source: std::io::Error,
    },
}

/// `Err(OutError::Refused(format!(…)))`.
macro_rules! refuse {
    ($($arg:tt)*) => {
        return Err(OutError::Refused(format!($($arg)*)))
    };
}

/// Wraps an I/O error with what was being done.
fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> OutError {
    let what = what.into();
    move |source| OutError::Io { what, source }
}

/// What a command writes into its `--out`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutKind {
    /// `render`, `replay` and `run`: frames, `timeline.csv`, `psf.csv`,
    /// `xr.csv`, the contact sheet and the plot (a directory).
    Frames,
    /// `record`: a recording in Pupil's layout (a directory).
    Recording,
    /// `psf`: one kernel as EXR, PNG and JSON (a directory).
    Kernel,
    /// `calibrate`: one calibration profile (a file).
    Profile,
}

/// The top-level files of a [`OutKind::Frames`] output (`render`, `replay`
/// and `run` clear each other's: any of them left from another command
/// would be stale beside the new ones).
const FRAMES_FILES: [&str; 7] = [
    "timeline.csv",
    "events.csv",
    "session.json",
    "psf.csv",
    "xr.csv",
    "contact_sheet.png",
    "plot.png",
];
/// The frame images' directory and the prefix of their names.
const FRAMES_DIR: &str = "frames";
const FRAME_PREFIX: &str = "frame_";
/// `psf`'s files.
const KERNEL_FILES: [&str; 3] = ["kernel.exr", "kernel.png", "psf.json"];
/// A recording's description (Pupil Player 2.x and gazelight).
const PLAYER_INFO: &str = "info.player.json";
/// `record`'s temporary while it rewrites [`PLAYER_INFO`].
const PLAYER_INFO_TMP: &str = ".info.player.json.tmp";
/// What gazelight writes as `recording_software_name`.
pub const SOFTWARE_NAME: &str = "gazelight";

/// Checks that `command` may write `out` (see the module docs) and, with
/// `force`, removes a previous run's outputs from it. `inputs` are the
/// files and directories the command reads (missing ones are ignored: the
/// command reports those itself). Creates nothing.
pub fn prepare(
    command: &str,
    out: &Path,
    kind: OutKind,
    inputs: &[&Path],
    force: bool,
) -> Result<(), OutError> {
    let shown = out.display();
    let meta = match std::fs::symlink_metadata(out) {
        Ok(m) => Some(m),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(io(format!("{command} --out {shown}"))(e)),
    };
    // A symlink to a directory is followed, as `create_dir_all` would.
    let is_dir = out.is_dir();
    if let Some(input) = held_input(out, kind, inputs) {
        refuse!(
            "{command} --out {shown}: it holds the input {}; writing there would overwrite or clear it \
             (--force does not change this): choose another directory",
            input.display()
        );
    }
    if kind == OutKind::Profile {
        return prepare_file(command, out, is_dir, meta.is_some(), force);
    }
    if meta.is_none() {
        return Ok(());
    }
    if !is_dir {
        refuse!("{command} --out {shown}: exists and is not a directory");
    }
    let recording = recording_in(out)?;
    match (recording, kind) {
        (Some(Recording::Gazelight), OutKind::Recording) | (None, _) => {}
        (Some(r), _) => refuse!(
            "{command} --out {shown}: the directory holds {}; gazelight never writes into another \
             recording (--force does not change this): choose another directory",
            r.describe()
        ),
    }
    let previous = previous_outputs(out, kind)?;
    if previous.is_empty() {
        return Ok(());
    }
    if !force {
        refuse!(
            "{command} --out {shown}: holds a previous run's outputs ({}); give --force to clear \
             them first, or choose another directory",
            list(&previous)
        );
    }
    clear(out, &previous)?;
    tracing::info!(out = %shown, cleared = %list(&previous), "--force: cleared a previous run's outputs");
    Ok(())
}

/// An output file named by a flag (`profile phases --out`, `glare
/// --json`): refused, before anything is written, when it is one of the
/// command's `inputs` (the same file after symlinks, or a hard link to
/// it) or a directory. Missing inputs are ignored.
pub fn check_out_file(
    command: &str,
    flag: &str,
    out: &Path,
    inputs: &[&Path],
) -> Result<(), OutError> {
    let shown = out.display();
    if out.is_dir() {
        refuse!("{command} {flag} {shown}: is a directory; a file name is expected");
    }
    let Some(target) = canonical(out) else {
        return Ok(());
    };
    let out_id = file_id(out);
    for input in inputs {
        let input_path = canonical(input);
        let same_path = input_path.as_ref().is_some_and(|i| *i == target);
        let same_file = out_id.is_some() && out_id == file_id(input);
        // An existing file inside an input directory (a recording's own
        // files) is part of that input.
        let inside = out_id.is_some()
            && input.is_dir()
            && input_path.as_ref().is_some_and(|i| target.starts_with(i));
        if same_path || same_file || inside {
            refuse!(
                "{command} {flag} {shown}: is the input {}; writing it would destroy what the \
                 command reads: choose another file",
                input.display()
            );
        }
    }
    Ok(())
}

/// Device and inode of an existing file.
fn file_id(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

/// Writes `bytes` to `path` through a temporary beside it
/// (`.NAME.tmp`, flushed, renamed into place): a reader never sees half a
/// file, and when writing or the rename fails the temporary is removed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), OutError> {
    use std::io::Write;
    let name = path
        .file_name()
        .ok_or_else(|| OutError::Refused(format!("{}: not a file name", path.display())))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(".tmp");
    let tmp = path.with_file_name(tmp_name);
    let result = (|| {
        let mut f =
            std::fs::File::create(&tmp).map_err(io(format!("cannot write {}", tmp.display())))?;
        f.write_all(bytes)
            .and_then(|()| f.sync_all())
            .map_err(io(format!("cannot write {}", tmp.display())))?;
        std::fs::rename(&tmp, path).map_err(io(format!("cannot write {}", path.display())))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// [`OutKind::Profile`]: one file, replaced only with `force`.
fn prepare_file(
    command: &str,
    out: &Path,
    is_dir: bool,
    exists: bool,
    force: bool,
) -> Result<(), OutError> {
    let shown = out.display();
    if is_dir {
        refuse!(
            "{command} --out {shown}: is a directory; the profile is a file (e.g. profile.json)"
        );
    }
    if exists && !force {
        refuse!(
            "{command} --out {shown}: the file exists (a previous profile?); give --force to \
             replace it, or choose another name"
        );
    }
    Ok(())
}

/// The first of `inputs` that a run of `kind` into `out` would overwrite or
/// clear: `out` itself, or a file of the names the command writes (for
/// [`OutKind::Frames`] anything under `frames/`). Other files in `out` are
/// never touched, so an input among them is fine.
fn held_input<'a>(out: &Path, kind: OutKind, inputs: &[&'a Path]) -> Option<&'a Path> {
    let out = canonical(out)?;
    inputs.iter().copied().find(|input| {
        let Some(input) = canonical(input) else {
            return false;
        };
        if kind == OutKind::Profile {
            return input == out;
        }
        let Ok(rel) = input.strip_prefix(&out) else {
            return false;
        };
        let mut parts = rel.components();
        let Some(first) = parts.next() else {
            return true; // `out` itself
        };
        let name = first.as_os_str().to_string_lossy();
        let top_level = parts.next().is_none();
        match kind {
            OutKind::Frames => name == FRAMES_DIR || (top_level && FRAMES_FILES.contains(&&*name)),
            OutKind::Kernel => top_level && KERNEL_FILES.contains(&&*name),
            OutKind::Recording => top_level && is_recording_file(&name),
            OutKind::Profile => false,
        }
    })
}

/// `path` with every symlink resolved; a path that does not exist (yet),
/// or a dangling symlink, resolves through its parent.
fn canonical(path: &Path) -> Option<PathBuf> {
    std::fs::canonicalize(path).ok().or_else(|| {
        let parent = path.parent().filter(|p| !p.as_os_str().is_empty());
        let parent = std::fs::canonicalize(parent.unwrap_or(Path::new("."))).ok()?;
        Some(parent.join(path.file_name()?))
    })
}

/// The top-level names `record` writes (and `--force` clears).
fn is_recording_file(name: &str) -> bool {
    name == PLAYER_INFO
        || name == PLAYER_INFO_TMP
        || name.ends_with(".pldata")
        || name.ends_with("_timestamps.npy")
}

/// A recording found in an output directory.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Recording {
    /// Pupil Capture 1.x (`info.csv`).
    PupilCapture1,
    /// `info.player.json` written by another program (its name).
    Player(String),
    /// `.pldata` streams with no `info.player.json`.
    Pldata(String),
    /// A Neon recording (`info.json` with `.raw`/`.time` streams).
    Neon,
    /// A recording gazelight's `record` wrote.
    Gazelight,
}

impl Recording {
    fn describe(&self) -> String {
        match self {
            Self::PupilCapture1 => "a Pupil Capture 1.x recording (info.csv)".to_owned(),
            Self::Player(by) => format!("a recording by {by} (info.player.json)"),
            Self::Pldata(name) => format!("a Pupil recording ({name})"),
            Self::Neon => "a Neon recording (info.json and its streams)".to_owned(),
            Self::Gazelight => "a recording by gazelight record (info.player.json)".to_owned(),
        }
    }
}

/// The entries of `dir` (names only; unreadable names are skipped).
fn entries(dir: &Path) -> Result<Vec<String>, OutError> {
    let read = std::fs::read_dir(dir).map_err(io(format!("cannot read {}", dir.display())))?;
    let mut names = Vec::new();
    for entry in read {
        let entry = entry.map_err(io(format!("cannot read {}", dir.display())))?;
        if let Some(name) = entry.file_name().to_str() {
            names.push(name.to_owned());
        }
    }
    names.sort();
    Ok(names)
}

/// Whether `path` exists as a directory entry (a dangling symlink counts).
fn present(path: &Path) -> bool {
    std::fs::symlink_metadata(path).is_ok()
}

/// Which recording `dir` holds, if any.
fn recording_in(dir: &Path) -> Result<Option<Recording>, OutError> {
    if present(&dir.join("info.csv")) {
        return Ok(Some(Recording::PupilCapture1));
    }
    let names = entries(dir)?;
    let info = dir.join(PLAYER_INFO);
    if present(&info) {
        return Ok(Some(match player_software(&info) {
            Some(name) if name == SOFTWARE_NAME => Recording::Gazelight,
            Some(name) => Recording::Player(name),
            None => Recording::Player("an unknown program".to_owned()),
        }));
    }
    if let Some(p) = names.iter().find(|n| n.ends_with(".pldata")) {
        return Ok(Some(Recording::Pldata(p.clone())));
    }
    if present(&dir.join("info.json"))
        && names
            .iter()
            .any(|n| n.ends_with(".raw") || n.ends_with(".time") || n == "eye_state.dtype")
    {
        return Ok(Some(Recording::Neon));
    }
    Ok(None)
}

/// `recording_software_name` of an `info.player.json` (`None` when it
/// cannot be read or has none).
fn player_software(path: &Path) -> Option<String> {
    let text = gazelight_input::read_config(path, gazelight_input::ConfigSyntax::Json).ok()?;
    let value: serde_json::Value = serde_json::from_str(&text).ok()?;
    value
        .get("recording_software_name")?
        .as_str()
        .map(str::to_owned)
}

/// The entries of `out` a run of `kind` would write (its previous outputs),
/// relative to `out`.
fn previous_outputs(out: &Path, kind: OutKind) -> Result<Vec<PathBuf>, OutError> {
    let mut found = Vec::new();
    match kind {
        OutKind::Frames => {
            for name in FRAMES_FILES {
                if present(&out.join(name)) {
                    found.push(PathBuf::from(name));
                }
            }
            let frames = out.join(FRAMES_DIR);
            if frames.is_dir() {
                for name in entries(&frames)? {
                    if name.starts_with(FRAME_PREFIX) {
                        found.push(Path::new(FRAMES_DIR).join(name));
                    }
                }
            } else if present(&frames) {
                found.push(PathBuf::from(FRAMES_DIR));
            }
        }
        OutKind::Kernel => {
            for name in KERNEL_FILES {
                if present(&out.join(name)) {
                    found.push(PathBuf::from(name));
                }
            }
        }
        OutKind::Recording => {
            for name in entries(out)? {
                if is_recording_file(&name) {
                    found.push(PathBuf::from(name));
                }
            }
        }
        OutKind::Profile => {}
    }
    Ok(found)
}

/// Removes `names` (relative to `out`; files and symlinks, never what a
/// symlink points to).
fn clear(out: &Path, names: &[PathBuf]) -> Result<(), OutError> {
    for name in names {
        let path = out.join(name);
        let meta = std::fs::symlink_metadata(&path)
            .map_err(io(format!("--force: cannot clear {}", path.display())))?;
        if meta.is_dir() {
            refuse!(
                "--force: {} is a directory where gazelight writes a file; remove it yourself",
                path.display()
            );
        }
        std::fs::remove_file(&path)
            .map_err(io(format!("--force: cannot clear {}", path.display())))?;
    }
    Ok(())
}

/// "a, b, c and N more".
fn list(names: &[PathBuf]) -> String {
    const SHOWN: usize = 4;
    let mut s = names
        .iter()
        .take(SHOWN)
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > SHOWN {
        s.push_str(&format!(" and {} more", names.len() - SHOWN));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("gazelight-outdir-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_failed_rename_leaves_no_temporary_and_the_old_file_whole() {
        let d = tmp("atomic");
        // The target is a non-empty directory: the rename fails.
        let target = d.join("summary.csv");
        std::fs::create_dir_all(target.join("keep")).unwrap();
        let e = write_atomic(&target, b"a,b\n").unwrap_err();
        assert!(format!("{e:#}").contains("summary.csv"), "{e:#}");
        assert!(!d.join(".summary.csv.tmp").exists());
        assert!(target.join("keep").is_dir());
        // A plain file is replaced whole.
        let f = d.join("x.json");
        std::fs::write(&f, "old").unwrap();
        write_atomic(&f, b"new").unwrap();
        assert_eq!(std::fs::read_to_string(&f).unwrap(), "new");
        assert!(!d.join(".x.json.tmp").exists());
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn empty_missing_and_unrelated_directories_are_fine() {
        let d = tmp("fine");
        prepare("render", &d.join("new"), OutKind::Frames, &[], false).unwrap();
        prepare("render", &d, OutKind::Frames, &[], false).unwrap();
        std::fs::write(d.join("notes.txt"), "mine").unwrap();
        prepare("render", &d, OutKind::Frames, &[], false).unwrap();
        prepare("record", &d, OutKind::Recording, &[], false).unwrap();
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn force_clears_only_what_the_command_writes() {
        let d = tmp("force");
        std::fs::create_dir_all(d.join("frames")).unwrap();
        for f in [
            "timeline.csv",
            "plot.png",
            "notes.txt",
            "frames/frame_00007.png",
            "frames/keep.txt",
        ] {
            std::fs::write(d.join(f), "x").unwrap();
        }
        let e = prepare("render", &d, OutKind::Frames, &[], false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--force") && e.contains("timeline.csv"), "{e}");
        prepare("render", &d, OutKind::Frames, &[], true).unwrap();
        assert!(!d.join("timeline.csv").exists() && !d.join("plot.png").exists());
        assert!(!d.join("frames/frame_00007.png").exists());
        assert!(d.join("notes.txt").exists() && d.join("frames/keep.txt").exists());
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn inputs_inside_out_and_foreign_recordings_are_refused_even_with_force() {
        let d = tmp("held");
        std::fs::write(d.join("timeline.csv"), "t_secs\n").unwrap();
        let input = d.join("timeline.csv");
        let e = prepare("replay", &d, OutKind::Frames, &[&input], true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("holds the input"), "{e}");
        let e = prepare("replay", &d, OutKind::Frames, &[&d], true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("holds the input"), "{e}");
        // An input of another name beside the outputs is never touched.
        std::fs::write(d.join("trace.csv"), "t_secs\n").unwrap();
        std::fs::remove_file(&input).unwrap();
        prepare(
            "replay",
            &d,
            OutKind::Frames,
            &[&d.join("trace.csv")],
            false,
        )
        .unwrap();
        std::fs::write(d.join("info.csv"), "key,value\n").unwrap();
        let e = prepare("record", &d, OutKind::Recording, &[], true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("Pupil Capture 1.x"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }
}
