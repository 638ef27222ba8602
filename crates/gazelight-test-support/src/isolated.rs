//! Tests that measure the whole process (its resident memory) run alone in
//! a child process: the test binary runs every other test in parallel
//! threads, whose allocations would otherwise show up in the measurement.

/// Environment variable set in the child that runs one test alone.
const CHILD_ENV: &str = "GAZELIGHT_ISOLATED_TEST";

/// Runs the test `name` (its full path, e.g. `serve::tests::x`) alone in a
/// child process of this test binary and asserts that it passed; returns
/// `false` there, so the caller returns. In that child it returns `true`:
/// the caller then does the measurement.
pub fn in_own_process(name: &str) -> bool {
    if std::env::var(CHILD_ENV).as_deref() == Ok(name) {
        return true;
    }
    let exe = std::env::current_exe().unwrap_or_else(|e| panic!("the test binary's path: {e}"));
    let out = std::process::Command::new(exe)
        .args([name, "--exact", "--test-threads=1", "--nocapture"])
        .env(CHILD_ENV, name)
        .output()
        .unwrap_or_else(|e| panic!("the test binary runs: {e}"));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("{text}");
    assert!(out.status.success(), "{name} failed in its own process");
    assert!(
        text.contains("1 passed"),
        "{name} did not run in its own process"
    );
    false
}
