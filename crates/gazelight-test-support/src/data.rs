//! The shared real test data (HDR panoramas, eye-tracker recordings).
//!
//! It is not in the repository: the data directory is `GAZELIGHT_DATA_DIR`
//! when that is set, else `shared/data` beside the workspace root (the
//! directory whose `Cargo.toml` has a `[workspace]` table): for a checkout
//! at `/work/main` that is `/work/shared/data`.

use std::ffi::OsStr;
use std::fmt;
use std::path::{Path, PathBuf};

/// The environment variable that names the data directory.
pub const DATA_DIR_ENV: &str = "GAZELIGHT_DATA_DIR";

/// Why the data directory cannot be used.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DataDirError {
    /// No directory above `start` holds a workspace `Cargo.toml`.
    NoWorkspaceRoot { start: PathBuf },
    /// The directory resolved to `path` (`how`) does not exist.
    Missing { path: PathBuf, how: String },
}

impl fmt::Display for DataDirError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NoWorkspaceRoot { start } => write!(
                f,
                "no workspace Cargo.toml above {} to find the shared test data from; \
                 set {DATA_DIR_ENV}",
                start.display()
            ),
            Self::Missing { path, how } => write!(
                f,
                "the shared test data directory {} ({how}) does not exist; \
                 set {DATA_DIR_ENV} to where it is",
                path.display()
            ),
        }
    }
}

impl std::error::Error for DataDirError {}

/// The data directory, or why it cannot be used (resolved as the module
/// doc says; an empty `GAZELIGHT_DATA_DIR` counts as unset).
pub fn try_data_dir() -> Result<PathBuf, DataDirError> {
    resolve(
        std::env::var_os(DATA_DIR_ENV).as_deref(),
        Path::new(env!("CARGO_MANIFEST_DIR")),
    )
}

/// The data directory given the value of `GAZELIGHT_DATA_DIR` (`env`) and
/// a directory inside the workspace (`start`).
pub fn resolve(env: Option<&OsStr>, start: &Path) -> Result<PathBuf, DataDirError> {
    let (path, how) = match env.filter(|v| !v.is_empty()) {
        Some(dir) => (PathBuf::from(dir), format!("from {DATA_DIR_ENV}")),
        None => {
            let root = workspace_root(start).ok_or_else(|| DataDirError::NoWorkspaceRoot {
                start: start.to_path_buf(),
            })?;
            (
                sibling_data_dir(&root),
                format!("beside the workspace root {}", root.display()),
            )
        }
    };
    if path.is_dir() {
        Ok(path)
    } else {
        Err(DataDirError::Missing { path, how })
    }
}

/// The data directory. Panics with the path it looked for when it is
/// missing: a test that needs the data fails with that message.
pub fn data_dir() -> PathBuf {
    try_data_dir().unwrap_or_else(|e| panic!("{e}"))
}

/// `rel` (e.g. `hdr/blender-world/night.exr`) under [`data_dir`].
pub fn data_path(rel: impl AsRef<Path>) -> PathBuf {
    data_dir().join(rel)
}

/// The nearest directory at or above `start` whose `Cargo.toml` has a
/// `[workspace]` table.
pub fn workspace_root(start: &Path) -> Option<PathBuf> {
    start
        .ancestors()
        .find(|dir| is_workspace_manifest(&dir.join("Cargo.toml")))
        .map(Path::to_path_buf)
}

/// `shared/data` beside `workspace_root`.
pub fn sibling_data_dir(workspace_root: &Path) -> PathBuf {
    let parent = workspace_root.parent().unwrap_or(workspace_root);
    parent.join("shared").join("data")
}

fn is_workspace_manifest(path: &Path) -> bool {
    std::fs::read_to_string(path).is_ok_and(|text| text.lines().any(|l| l.trim() == "[workspace]"))
}

/// The shipped binocular EyeLink recording made a left-eye-only one, as
/// EyeLink writes a monocular recording (`START`/`SAMPLES`/`EVENTS` lines
/// without `RIGHT`, samples `time xL yL pL …`, no right-eye events), into
/// `dir/left_eye.asc`: the monocular file the pupil, BIDS and CLI tests
/// share.
pub fn left_eye_eyelink(dir: &Path) -> PathBuf {
    let src = data_path("eye/eyelink-psa/both_eyes.asc");
    let text = std::fs::read_to_string(&src).unwrap_or_else(|e| panic!("{}: {e}", src.display()));
    let mut out = String::with_capacity(text.len());
    for line in text.lines() {
        let first = line.split_whitespace().next().unwrap_or("");
        let f: Vec<&str> = line.split_whitespace().collect();
        if first.starts_with(|c: char| c.is_ascii_digit()) && f.len() >= 8 {
            // time xL yL pL xR yR pR flags…
            out.push_str(&format!("{}\t{}\t{}\t{}\t...\n", f[0], f[1], f[2], f[3]));
        } else if [
            "START",
            "END",
            "SAMPLES",
            "EVENTS",
            "PRESCALER",
            "VPRESCALER",
        ]
        .contains(&first)
        {
            out.push_str(&line.replace("\tRIGHT", "").replace(" RIGHT", ""));
            out.push('\n');
        } else if ["SBLINK", "EBLINK", "SFIX", "EFIX", "SSACC", "ESACC"].contains(&first)
            && f.get(1) == Some(&"R")
        {
            continue;
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    let p = dir.join("left_eye.asc");
    std::fs::create_dir_all(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    std::fs::write(&p, out).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    p
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    /// A throw-away directory tree: `base/ws/Cargo.toml` ([workspace]),
    /// `base/ws/crates/c/Cargo.toml` ([package]).
    fn tree(name: &str) -> PathBuf {
        let base = std::env::temp_dir().join(format!(
            "gazelight-test-support-{}-{name}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&base);
        let member = base.join("ws").join("crates").join("c");
        std::fs::create_dir_all(&member).unwrap();
        std::fs::write(
            base.join("ws").join("Cargo.toml"),
            "[workspace]\nmembers = [\"crates/c\"]\n",
        )
        .unwrap();
        std::fs::write(member.join("Cargo.toml"), "[package]\nname = \"c\"\n").unwrap();
        base
    }

    #[test]
    fn the_root_is_the_nearest_workspace_manifest_above_a_member() {
        let base = tree("root");
        let member = base.join("ws").join("crates").join("c");
        assert_eq!(workspace_root(&member), Some(base.join("ws")));
        assert_eq!(workspace_root(&base.join("ws")), Some(base.join("ws")));
        // Nothing above the tree's base is a workspace of this test's making;
        // a package manifest alone is not a root.
        assert_ne!(workspace_root(&member), Some(member.clone()));
        assert_eq!(
            sibling_data_dir(&base.join("ws")),
            base.join("shared").join("data")
        );
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn this_workspace_resolves_beside_its_root() {
        // This crate sits at <root>/crates/gazelight-test-support.
        let here = Path::new(env!("CARGO_MANIFEST_DIR"));
        let root = here.parent().and_then(Path::parent).unwrap();
        assert_eq!(workspace_root(here).as_deref(), Some(root));
        assert!(root.join("Cargo.toml").is_file());
    }

    #[test]
    fn without_the_variable_the_data_is_shared_data_beside_the_root() {
        let base = tree("sibling");
        let member = base.join("ws").join("crates").join("c");
        let err = resolve(None, &member).unwrap_err();
        let expected = base.join("shared").join("data");
        assert_eq!(
            err,
            DataDirError::Missing {
                path: expected.clone(),
                how: format!("beside the workspace root {}", base.join("ws").display()),
            }
        );
        // The message names the path it looked for and the variable.
        let msg = err.to_string();
        assert!(msg.contains(&expected.display().to_string()), "{msg}");
        assert!(msg.contains(DATA_DIR_ENV), "{msg}");
        std::fs::create_dir_all(&expected).unwrap();
        assert_eq!(resolve(None, &member), Ok(expected.clone()));
        // An empty variable counts as unset.
        assert_eq!(resolve(Some(OsStr::new("")), &member), Ok(expected));
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn the_variable_wins_and_a_missing_one_is_named() {
        let base = tree("env");
        let member = base.join("ws").join("crates").join("c");
        std::fs::create_dir_all(base.join("shared").join("data")).unwrap();
        let elsewhere = base.join("elsewhere");
        let err = resolve(Some(elsewhere.as_os_str()), &member).unwrap_err();
        assert!(err.to_string().contains(&elsewhere.display().to_string()));
        assert!(err.to_string().contains("from GAZELIGHT_DATA_DIR"));
        std::fs::create_dir_all(&elsewhere).unwrap();
        assert_eq!(resolve(Some(elsewhere.as_os_str()), &member), Ok(elsewhere));
        std::fs::remove_dir_all(&base).unwrap();
    }
}
