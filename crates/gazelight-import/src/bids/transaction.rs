//! One export as one transaction: every file is written as a temporary
//! beside its final name (`.NAME.gazelight-tmp`), and only
//! [`Transaction::commit`] moves them into place — the data and sidecars
//! first, then the stale files of an earlier export of the same recording
//! removed, `participants.tsv` last. An export that fails (a full disk, a
//! source that breaks half-way) leaves the dataset as it was: its
//! temporaries are removed when the transaction is dropped uncommitted.

use std::fs::File;
use std::path::{Path, PathBuf};

use serde_json::Value;

use super::{BidsNames, ExportError, wio};

/// The suffixes of the per-recording files an export writes (and so may
/// find stale from an earlier export of the same names).
const RECORDING_SUFFIXES: [&str; 4] = [
    "_physio.tsv.gz",
    "_physio.json",
    "_physioevents.tsv.gz",
    "_physioevents.json",
];

/// What the commit does with a staged file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// Replaces the file at its final name.
    Replace,
    /// Put in place only where no file has that name (a dataset's
    /// `README`, which the user may have edited).
    IfMissing,
}

/// The files of one export under a dataset root, staged until
/// [`commit`](Self::commit).
#[derive(Debug)]
pub struct Transaction {
    root: PathBuf,
    names: BidsNames,
    /// (temporary, final, kind), in the order they were staged.
    staged: Vec<(PathBuf, PathBuf, Kind)>,
    /// `participants.tsv`'s new text, written last.
    participants: Option<String>,
}

/// The temporary a file is staged in: a hidden name in the same folder
/// (so the rename never crosses file systems).
fn temporary(path: &Path) -> PathBuf {
    let mut name = std::ffi::OsString::from(".");
    name.push(path.file_name().unwrap_or_default());
    name.push(".gazelight-tmp");
    path.with_file_name(name)
}

impl Transaction {
    /// A transaction writing the recording `names` into the dataset at
    /// `root` (created at commit when missing; its folders are made as
    /// files are staged).
    pub fn new(root: &Path, names: &BidsNames) -> Result<Self, ExportError> {
        names.check()?;
        Ok(Self {
            root: root.to_owned(),
            names: names.clone(),
            staged: Vec::new(),
            participants: None,
        })
    }

    /// The dataset's root.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The recording's names.
    pub fn names(&self) -> &BidsNames {
        &self.names
    }

    /// Creates the temporary of `path` (its folder made), to be moved to
    /// `path` at commit. Staging a path twice keeps the later file.
    pub(super) fn create(&mut self, path: &Path) -> Result<File, ExportError> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(wio(dir))?;
        }
        let tmp = temporary(path);
        let f = File::create(&tmp).map_err(wio(path))?;
        self.staged.retain(|(_, p, _)| p != path);
        self.staged.push((tmp, path.to_owned(), Kind::Replace));
        Ok(f)
    }

    /// Stages `text` as the file `path`.
    pub(super) fn write(&mut self, path: &Path, text: &str) -> Result<(), ExportError> {
        use std::io::Write;
        let mut f = self.create(path)?;
        f.write_all(text.as_bytes()).map_err(wio(path))?;
        f.sync_all().map_err(wio(path))
    }

    /// Stages `text` as `path` where no file of that name exists at commit.
    pub(super) fn write_if_missing(&mut self, path: &Path, text: &str) -> Result<(), ExportError> {
        self.write(path, text)?;
        if let Some(last) = self.staged.last_mut() {
            last.2 = Kind::IfMissing;
        }
        Ok(())
    }

    /// Stages `v` as pretty JSON in `path`.
    pub(super) fn write_json(&mut self, path: &Path, v: &Value) -> Result<(), ExportError> {
        let text =
            serde_json::to_string_pretty(v).map_err(|e| ExportError::Invalid(e.to_string()))?;
        self.write(path, &(text + "\n"))
    }

    /// Takes back a staged file: it will not be written.
    pub(super) fn discard(&mut self, path: &Path) {
        self.staged.retain(|(tmp, p, _)| {
            let keep = p != path;
            if !keep {
                let _ = std::fs::remove_file(tmp);
            }
            keep
        });
    }

    /// Whether `path` is staged.
    pub fn is_staged(&self, path: &Path) -> bool {
        self.staged.iter().any(|(_, p, _)| p == path)
    }

    /// Stages `participants.tsv` with this recording's participant: the
    /// file as it is with a row added when the participant is missing,
    /// padded with `n/a` to the table's columns.
    pub(super) fn add_participant(&mut self) -> Result<(), ExportError> {
        let path = self.root.join("participants.tsv");
        let id = format!("sub-{}", self.names.subject);
        let mut text = if path.exists() {
            gazelight_input::read_to_string(&path, gazelight_input::MAX_TEXT_BYTES)
                .map_err(wio(&path))?
        } else {
            "participant_id\n".to_owned()
        };
        let columns = text.lines().next().map_or(1, |h| h.split('\t').count());
        if text
            .lines()
            .skip(1)
            .any(|l| l.split('\t').next() == Some(id.as_str()))
        {
            self.participants = None;
            return Ok(());
        }
        if !text.ends_with('\n') {
            text.push('\n');
        }
        text.push_str(&id);
        for _ in 1..columns {
            text.push_str("\tn/a");
        }
        text.push('\n');
        self.participants = Some(text);
        Ok(())
    }

    /// The files of an earlier export of the same recording (same
    /// subject, session, task and run) in `dir` that this one does not
    /// write: an eye the new recording lacks, a replay derivative not
    /// given this time. They would be merged on read with the new ones.
    fn stale_in(&self, dir: &Path) -> Vec<PathBuf> {
        let start = format!("{}_recording-", self.names.prefix());
        let Ok(entries) = std::fs::read_dir(dir) else {
            return Vec::new();
        };
        entries
            .flatten()
            .map(|e| e.path())
            .filter(|p| {
                p.file_name().and_then(|n| n.to_str()).is_some_and(|n| {
                    n.starts_with(&start) && RECORDING_SUFFIXES.iter().any(|s| n.ends_with(s))
                })
            })
            .filter(|p| !self.is_staged(p))
            .collect()
    }

    /// Moves every staged file into place, removes the stale files of an
    /// earlier export of the same recording, and writes
    /// `participants.tsv` last; returns the stale files removed. A failed
    /// rename stops the commit with the files not yet moved left as they
    /// were (their temporaries removed).
    pub fn commit(mut self) -> Result<Vec<PathBuf>, ExportError> {
        let dirs = [
            self.root.join(self.names.dir()),
            self.root
                .join("derivatives")
                .join("gazelight")
                .join(self.names.dir()),
        ];
        let stale: Vec<PathBuf> = dirs.iter().flat_map(|d| self.stale_in(d)).collect();
        // Data before sidecars: a reader that finds a sidecar finds its data.
        let staged = std::mem::take(&mut self.staged);
        let (data, rest): (Vec<_>, Vec<_>) = staged
            .into_iter()
            .partition(|(_, p, _)| p.extension().is_some_and(|e| e == "gz"));
        let mut pending: std::collections::VecDeque<_> = data.into_iter().chain(rest).collect();
        while let Some((tmp, path, kind)) = pending.pop_front() {
            let result = if kind == Kind::IfMissing && path.exists() {
                std::fs::remove_file(&tmp)
            } else {
                std::fs::rename(&tmp, &path)
            };
            if let Err(e) = result {
                let _ = std::fs::remove_file(&tmp);
                self.staged = pending.into_iter().collect();
                return Err(wio(&path)(e));
            }
        }
        for p in &stale {
            std::fs::remove_file(p).map_err(wio(p))?;
        }
        if let Some(text) = self.participants.take() {
            let path = self.root.join("participants.tsv");
            let tmp = temporary(&path);
            let write = std::fs::write(&tmp, text).and_then(|()| std::fs::rename(&tmp, &path));
            if let Err(e) = write {
                let _ = std::fs::remove_file(&tmp);
                return Err(wio(&path)(e));
            }
        }
        Ok(stale)
    }
}

impl Drop for Transaction {
    /// An uncommitted (or half-committed) transaction removes its
    /// temporaries: the dataset keeps its earlier files.
    fn drop(&mut self) {
        for (tmp, _, _) in &self.staged {
            let _ = std::fs::remove_file(tmp);
        }
    }
}
