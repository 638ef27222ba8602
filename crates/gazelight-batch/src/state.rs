//! What the batch keeps between runs, under `OUT/_batch/`: per row a
//! completion record `ID.json` (written atomically once the row's outputs
//! are complete, with the hash of the row's replay options) and the log
//! of its replay `ID.log`. A row is finished when its record says `ok`
//! with the hash of its current options and its `timeline.csv` is there;
//! anything else (no record, another hash, `failed`) is run again.

use std::path::{Path, PathBuf};

use crate::{Context, Result};
use serde::{Deserialize, Serialize};

/// The batch's own folder inside `OUT`.
pub const STATE_DIR: &str = "_batch";

/// How a row ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Ok,
    Failed,
}

/// The completion record of one row.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Record {
    pub id: String,
    /// [`options_hash`] of the row when it ran.
    pub options_hash: String,
    pub status: Status,
    /// Why it failed ("" when ok).
    pub message: String,
    /// The summary values (`summary::COLUMNS` order; empty when failed).
    pub values: Vec<String>,
    /// Frames rendered and the wall time of the replay (not in the
    /// summary table, which stays the same wherever it is computed).
    pub frames: u64,
    pub wall_secs: f64,
}

/// FNV-1a, 64 bits (Fowler–Noll–Vo; offset basis 0xcbf29ce484222325,
/// prime 0x100000001b3): a change detector, not a cryptographic hash.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// The hash of a row's replay: gazelight's version and the replay's
/// arguments (paths resolved; `--out` and `--force` left out).
pub fn options_hash(argv: &[String]) -> String {
    let mut text = format!("gazelight {}", env!("CARGO_PKG_VERSION"));
    for a in argv {
        text.push('\0');
        text.push_str(a);
    }
    format!("fnv1a64:{:016x}", fnv1a64(text.as_bytes()))
}

/// Most directory entries an input's identity covers (a recording folder
/// and its subfolders, breadth first).
const MAX_IDENTITY_ENTRIES: usize = 10_000;

/// The identity of each absolute path among a row's arguments (the
/// recording, and `--scene=`, `--config=`, `--calibration=` values), one
/// `input:PATH:…` string each: for a file its size and modification time
/// (ns), for a folder (a Neon or Pupil recording) the names, sizes and
/// times of its entries two levels deep (at most
/// [`MAX_IDENTITY_ENTRIES`]). A recording rewritten in place, even with
/// the same size, gets another identity, so its row runs again.
pub fn input_identities(argv: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    for a in argv {
        let value = match a.split_once('=') {
            Some((flag, v)) if flag.starts_with("--") => v,
            _ => a.as_str(),
        };
        let path = Path::new(value);
        if !path.is_absolute() {
            continue;
        }
        let Ok(meta) = std::fs::metadata(path) else {
            continue;
        };
        let mut id = format!("input:{value}:{}", stamp(&meta));
        if meta.is_dir() {
            let mut h: u64 = fnv1a64(b"");
            let mut seen = 0usize;
            let mut queue = vec![(path.to_path_buf(), 0u8)];
            while let Some((dir, depth)) = queue.pop() {
                let Ok(read) = std::fs::read_dir(&dir) else {
                    continue;
                };
                let mut entries: Vec<_> = read.flatten().collect();
                entries.sort_by_key(|e| e.file_name());
                for e in entries {
                    seen += 1;
                    if seen > MAX_IDENTITY_ENTRIES {
                        break;
                    }
                    let Ok(m) = e.metadata() else { continue };
                    let line = format!("{}\0{}\0", e.path().display(), stamp(&m));
                    h ^= fnv1a64(line.as_bytes());
                    h = h.wrapping_mul(0x0000_0100_0000_01b3);
                    if m.is_dir() && depth < 1 {
                        queue.push((e.path(), depth + 1));
                    }
                }
            }
            id.push_str(&format!(":entries:{h:016x}"));
        }
        out.push(id);
    }
    out
}

/// `SIZE:MTIME_NS` of a file (the directory's own for a directory).
fn stamp(meta: &std::fs::Metadata) -> String {
    let mtime = meta
        .modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_nanos());
    format!("{}:{mtime}", meta.len())
}

/// The batch's folder and the paths of one row's files in it.
pub struct State {
    dir: PathBuf,
}

impl State {
    /// `out/_batch`, created.
    pub fn open(out: &Path) -> Result<Self> {
        let dir = out.join(STATE_DIR);
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        Ok(Self { dir })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn record_path(&self, id: &str) -> PathBuf {
        self.dir.join(format!("{id}.json"))
    }

    pub fn log_path(&self, id: &str) -> PathBuf {
        self.dir.join(format!("{id}.log"))
    }

    /// The row's record, if one can be read (a damaged one counts as none).
    pub fn read(&self, id: &str) -> Option<Record> {
        let text = std::fs::read_to_string(self.record_path(id)).ok()?;
        let r: Record = serde_json::from_str(&text).ok()?;
        (r.id == id).then_some(r)
    }

    /// Removes the row's record (before the row runs again).
    pub fn forget(&self, id: &str) -> Result<()> {
        let p = self.record_path(id);
        match std::fs::remove_file(&p) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(e) => Err(e).with_context(|| format!("cannot remove {}", p.display())),
        }
    }

    /// Writes the row's record atomically: a temporary file, flushed to
    /// disk, renamed into place.
    pub fn write(&self, record: &Record) -> Result<()> {
        let path = self.record_path(&record.id);
        let text = serde_json::to_string_pretty(record).context("batch record as JSON")? + "\n";
        // `.ID.json.tmp`, removed when the write or the rename fails.
        Ok(gazelight_output::write_atomic(&path, text.as_bytes())?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The FNV-1a 64 test vectors of the reference implementation
    /// (Landon Curt Noll, fnv/test_fnv.c: "" and "a", "foobar").
    #[test]
    fn fnv1a64_matches_the_reference_vectors() {
        assert_eq!(fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn a_record_round_trips_and_a_damaged_one_is_none() {
        let dir =
            std::env::temp_dir().join(format!("gazelight-batch-state-{}", std::process::id()));
        let s = State::open(&dir).unwrap();
        let r = Record {
            id: "a".into(),
            options_hash: options_hash(&["x".into()]),
            status: Status::Ok,
            message: String::new(),
            values: vec!["1".into()],
            frames: 3,
            wall_secs: 0.5,
        };
        s.write(&r).unwrap();
        assert_eq!(s.read("a"), Some(r));
        std::fs::write(s.record_path("b"), "{\"id\": \"b\", ").unwrap();
        assert_eq!(s.read("b"), None);
        assert_ne!(options_hash(&["x".into()]), options_hash(&["y".into()]));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
