//! Tests in a private network namespace (`unshare -n`, loopback up): LSL
//! and mDNS discovery send multicast, and inside a namespace of its own no
//! packet of a test can leave the machine or meet another test's.
//!
//! A test re-runs itself inside ([`rerun_test`]): its first line is
//!
//! ```ignore
//! if !gazelight_test_support::netns::inside() { /* check, re-run, return */ }
//! ```
//!
//! Needs `unshare -n` (root), `ip` (iproute2) and python3 with the modules
//! the test's peer imports; outside CI a missing one prints a `SKIP` line,
//! with `CI` set it fails ([`ready`]).

use std::ffi::OsStr;
use std::process::{Command, Output};

/// Set in the test process that [`rerun_test`] starts inside the namespace.
pub const INNER_ENV: &str = "GAZELIGHT_NETNS";

/// The shell prefix that brings loopback up, then runs `"$0" "$@"`.
const LOOPBACK_UP_THEN_EXEC: &str = "ip link set lo up && exec \"$0\" \"$@\"";

/// Whether this process is the re-run inside the namespace.
pub fn inside() -> bool {
    std::env::var_os(INNER_ENV).is_some()
}

/// Whether `unshare -n`, `ip` and python3 importing every module of
/// `python_modules` work here. When not: with `CI` set this panics,
/// otherwise it prints a `SKIP` line naming what is needed.
pub fn ready(python_modules: &[&str]) -> bool {
    let ok = |c: &mut Command| c.output().is_ok_and(|o| o.status.success());
    let imports = python_modules.join(", ");
    let have = ok(Command::new("unshare").args(["-n", "true"]))
        && ok(Command::new("ip").arg("-V"))
        && (python_modules.is_empty()
            || ok(Command::new("python3").args(["-c", &format!("import {imports}")])));
    if !have {
        crate::skip_or_fail(&format!(
            "needs unshare -n (as root), ip (iproute2) and python3 with {imports}"
        ));
    }
    have
}

/// Runs test `name` of this test binary again, alone, inside a fresh
/// network namespace with loopback up and `env` set (plus [`INNER_ENV`]);
/// prints its output and panics unless it ran and passed.
pub fn rerun_test(name: &str, env: &[(&str, &OsStr)]) {
    let exe =
        std::env::current_exe().unwrap_or_else(|e| panic!("the running test binary's path: {e}"));
    let out = Command::new("unshare")
        .args(["-n", "sh", "-c", LOOPBACK_UP_THEN_EXEC])
        .arg(&exe)
        .args([name, "--exact", "--nocapture", "--test-threads=1"])
        .env(INNER_ENV, "1")
        .envs(env.iter().copied())
        .output()
        .unwrap_or_else(|e| panic!("unshare -n {}: {e}", exe.display()));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("{text}");
    assert!(
        out.status.success(),
        "{name} in the network namespace failed"
    );
    assert!(text.contains("1 passed"), "{name} did not run: {text}");
}

/// Runs `sh -c script` inside a fresh network namespace (loopback down:
/// the script sets up what it needs) with `env` set; returns its output.
pub fn run_script(script: &str, env: &[(&str, &OsStr)]) -> Output {
    Command::new("unshare")
        .args(["-n", "sh", "-c", script])
        .envs(env.iter().copied())
        .output()
        .unwrap_or_else(|e| panic!("unshare -n sh -c …: {e}"))
}
