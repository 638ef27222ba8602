//! The layer's log: one line per event on the app's standard error,
//! prefixed so it can be found among the app's own lines. The layer runs in
//! someone else's process, which installs no `tracing` subscriber for it.

use std::io::Write;

/// Writes `[gazelight-layer] LEVEL: MESSAGE` to standard error; a failed
/// write is dropped (the layer never stops the app over its log).
pub fn log(level: &str, message: &str) {
    let _ = writeln!(
        std::io::stderr().lock(),
        "[gazelight-layer] {level}: {message}"
    );
}
