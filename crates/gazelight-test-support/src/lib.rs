//! # gazelight-test-support
//!
//! One job: the harnesses that gazelight's tests and benchmarks share, so
//! that no crate keeps its own copy. It is a dev-dependency only (never a
//! dependency of a library or the binary) and is not published.
//!
//! - [`data`]: where the shared real test data lives ([`data_dir`],
//!   [`data_path`]): `GAZELIGHT_DATA_DIR` if set, else `shared/data` beside
//!   the workspace root.
//! - [`bids`]: the official BIDS validator on a dataset a test wrote
//!   ([`bids::validate`]).
//! - [`chromium`]: headless Chromium with a throw-away profile, and the
//!   status page's state as the page shows it.
//! - [`isolated`]: a test re-run alone in a child process of its test
//!   binary, for measurements of the whole process (its memory).
//! - [`netns`]: a test re-run inside a private network namespace
//!   (`unshare -n`, loopback up), so no discovery packet leaves the machine.
//! - [`seam`]: straight seams in a glare veil, from frames rendered with
//!   glare and without ([`seam::find_seams`]).
//!
//! Every harness follows the workspace's rule for missing tools: outside CI
//! a test that lacks one prints a `SKIP` line and returns; with `CI` set it
//! fails ([`skip_or_fail`]).

pub mod bids;
pub mod chromium;
pub mod data;
pub mod isolated;
pub mod netns;
pub mod seam;

pub use data::{DATA_DIR_ENV, DataDirError, data_dir, data_path, try_data_dir};

/// Whether `CI` is set (then a missing tool or data fails a test instead
/// of skipping it).
pub fn in_ci() -> bool {
    std::env::var_os("CI").is_some()
}

/// A test cannot run because `what` is missing: with `CI` set this panics
/// with `what`; otherwise it prints `SKIP: what` and returns, and the
/// caller returns too.
pub fn skip_or_fail(what: &str) {
    assert!(!in_ci(), "{what} (CI must have it)");
    eprintln!("SKIP: {what}");
}
