//! Helpers shared by the `gazelight` binary's integration tests: running
//! the binary, per-test temporary directories, the shared real data, the
//! pyzmq Pupil peer (crates/gazelight-tracker/tests/pupil_peer.py) and
//! bounded waits for child processes, listening ports, log lines and rows
//! of the outputs a run is still writing.
//!
//! Timing (issue 50): a test waits for an event it can observe (a log line,
//! rows on disk, a counter) instead of sleeping "long enough", and derives
//! any time bound from the instants of those events. The `limit`s of the
//! waits here are backstops against a hung program, never the bound a test
//! checks.
//!
//! Every test file declares `mod common;`, so each test binary compiles its
//! own copy of this module and uses only some of the helpers; hence the
//! module-wide `dead_code` allowance.
#![allow(dead_code)]

use std::io::{BufRead, BufReader, Read};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Runs the binary to completion with `RUST_LOG=warn`.
pub fn gazelight(args: &[&str]) -> Output {
    gazelight_env(args, &[])
}

/// Runs the binary to completion with `RUST_LOG=warn` and extra
/// environment variables.
pub fn gazelight_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_gazelight"));
    cmd.args(args).env("RUST_LOG", "warn");
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("run gazelight")
}

/// A fresh, empty temporary directory private to this test binary and
/// process (`gazelight-<test file>-<pid>-<name>`).
pub fn tmp(name: &str) -> PathBuf {
    let dir = tmp_path(name);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// Like [`tmp`], but the directory is only removed, not created (for
/// commands that create their output directory themselves).
pub fn tmp_path(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "gazelight-{}-{}-{name}",
        env!("CARGO_CRATE_NAME"),
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A path under the shared real data (/work/shared/data).
pub fn shared(rel: &str) -> PathBuf {
    gazelight_test_support::data_path(rel)
}

/// [`shared`] as a UTF-8 string, for command lines.
pub fn shared_str(rel: &str) -> String {
    shared(rel).to_str().expect("utf-8").to_owned()
}

/// Whether python3 with pyzmq + msgpack (the Pupil peer's needs) is
/// available. Outside CI a missing one prints a SKIP line; with `CI` set
/// it fails the test.
pub fn python_ready() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import zmq, msgpack"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI must have python3 + pyzmq + msgpack"
        );
        eprintln!("SKIP: python3 with pyzmq + msgpack not available");
    }
    ok
}

/// A child process killed (and reaped) on drop.
pub struct Proc(pub Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A running pyzmq Pupil peer; killed on drop.
pub struct Peer {
    _proc: Proc,
    /// Its Pupil Remote port, from its `READY remote=<port> …` line.
    pub remote_port: u16,
}

/// Starts crates/gazelight-tracker/tests/pupil_peer.py with `args` and
/// waits for its `READY remote=<port> sub=<port> pub=<port>` line.
pub fn spawn_peer(args: &[&str]) -> Peer {
    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../gazelight-tracker/tests/pupil_peer.py");
    let mut child = Command::new("python3")
        .arg(script)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("spawn peer (python3 with pyzmq + msgpack)");
    let mut line = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut line)
        .expect("READY line");
    let remote_port = line
        .split_whitespace()
        .find_map(|w| w.strip_prefix("remote="))
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("no remote port in {line:?}"));
    Peer {
        _proc: Proc(child),
        remote_port,
    }
}

/// [`spawn_peer`] on ephemeral ports (Pupil Remote, SUB and PUB all 0)
/// publishing at `rate_hz` and exiting after `timeout_secs`, with `extra`
/// arguments appended.
pub fn spawn_peer_any_port(rate_hz: &str, timeout_secs: &str, extra: &[&str]) -> Peer {
    let mut args = vec![
        "--remote-port",
        "0",
        "--sub-port",
        "0",
        "--pub-port",
        "0",
        "--rate",
        rate_hz,
        "--timeout",
        timeout_secs,
    ];
    args.extend_from_slice(extra);
    spawn_peer(&args)
}

/// A TCP port free on 127.0.0.1 at the time of the call.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .expect("bind")
        .local_addr()
        .expect("addr")
        .port()
}

/// Waits (bounded by `limit`) until something accepts connections on
/// 127.0.0.1:`port`.
pub fn wait_listening(port: u16, limit: Duration) {
    let start = Instant::now();
    while TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            start.elapsed() < limit,
            "nothing listens on {port} after {limit:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Waits for the child (bounded by `limit`, killed past it) and collects
/// its output.
pub fn wait_bounded(mut child: Child, limit: Duration) -> Output {
    let start = Instant::now();
    loop {
        if child.try_wait().expect("try_wait").is_some() {
            return child.wait_with_output().expect("output");
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let out = child.wait_with_output().expect("output");
            panic!(
                "gazelight did not end within {limit:?}; stderr: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Waits for the child (bounded by `limit`, killed past it) without
/// taking its pipes.
pub fn wait_exit(child: &mut Child, limit: Duration) -> ExitStatus {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            return status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            panic!("gazelight did not end within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Polls `probe` every 20 ms until it gives `Some`, and returns that and
/// the instant it was seen. `limit` is a backstop against a hung program
/// (the test fails naming `what`), not a bound the test measures.
pub fn wait_for<T>(
    limit: Duration,
    what: &str,
    mut probe: impl FnMut() -> Option<T>,
) -> (T, Instant) {
    let start = Instant::now();
    loop {
        if let Some(v) = probe() {
            return (v, Instant::now());
        }
        assert!(start.elapsed() < limit, "no {what} within {limit:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Sends `kill -<signal>` (`INT`, `TERM`, …) to the child.
pub fn signal(child: &Child, signal: &str) {
    let status = Command::new("kill")
        .args([&format!("-{signal}"), &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(status.success(), "kill -{signal} {}", child.id());
}

/// A child's stderr, read line by line on a thread while it runs, so a
/// test can wait for a log line (the program's own record of an event)
/// instead of sleeping. [`LogWatch::finish`] returns the whole text once the
/// child has exited.
pub struct LogWatch {
    text: Arc<Mutex<String>>,
    thread: Option<JoinHandle<()>>,
}

impl LogWatch {
    /// Takes the child's (piped) stderr.
    pub fn start(child: &mut Child) -> Self {
        let mut stderr = BufReader::new(child.stderr.take().expect("piped stderr"));
        let text = Arc::new(Mutex::new(String::new()));
        let sink = Arc::clone(&text);
        let thread = std::thread::spawn(move || {
            let mut line = Vec::new();
            loop {
                line.clear();
                match stderr.read_until(b'\n', &mut line) {
                    Ok(0) | Err(_) => break,
                    Ok(_) => sink
                        .lock()
                        .expect("log")
                        .push_str(&String::from_utf8_lossy(&line)),
                }
            }
            // Anything after a read error, for the failure message.
            let mut rest = Vec::new();
            let _ = stderr.read_to_end(&mut rest);
            sink.lock()
                .expect("log")
                .push_str(&String::from_utf8_lossy(&rest));
        });
        Self {
            text,
            thread: Some(thread),
        }
    }

    /// The text read so far.
    pub fn text(&self) -> String {
        self.text.lock().expect("log").clone()
    }

    /// Waits (bounded by the backstop `limit`) until a line containing
    /// `needle` has been logged; returns the instant the test saw it (no
    /// earlier than the program logged it).
    pub fn wait_line(&self, needle: &str, limit: Duration) -> Instant {
        wait_for(limit, &format!("log line with {needle:?}"), || {
            self.text().contains(needle).then_some(())
        })
        .1
    }

    /// The whole stderr, after the child exited (its end of the pipe closed).
    pub fn finish(mut self) -> String {
        if let Some(t) = self.thread.take() {
            t.join().expect("stderr reader");
        }
        self.text()
    }
}

/// How many datums of `stream` a recording (`record`, flushed every
/// second) has on disk so far, by its timestamps file; 0 before it exists
/// or while it cannot be read whole.
pub fn datums_on_disk(dir: &Path, stream: &str) -> usize {
    let (_, npy) = gazelight_tracker::recording::stream_paths(dir, stream);
    gazelight_tracker::recording::read_npy_f64(&npy).map_or(0, |ts| ts.len())
}

/// A CSV as a header → column index map and rows of fields.
pub struct Csv {
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

impl Csv {
    pub fn read(path: &Path) -> Self {
        let text =
            std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut lines = text.lines();
        let header = lines
            .next()
            .expect("header")
            .split(',')
            .map(str::to_owned)
            .collect();
        let rows = lines
            .map(|l| l.split(',').map(str::to_owned).collect())
            .collect();
        Self { header, rows }
    }

    /// The whole rows of a CSV a running program is still writing (its
    /// writer flushes whole rows, at least every second): `None` before the
    /// file has its header; a last line without its newline is left out.
    pub fn try_read(path: &Path) -> Option<Self> {
        let text = std::fs::read_to_string(path).ok()?;
        let whole = &text[..text.rfind('\n')? + 1];
        let mut lines = whole.lines();
        let header: Vec<String> = lines.next()?.split(',').map(str::to_owned).collect();
        let rows = lines
            .map(|l| l.split(',').map(str::to_owned).collect::<Vec<String>>())
            .filter(|r| r.len() == header.len())
            .collect();
        Some(Self { header, rows })
    }

    pub fn col(&self, name: &str) -> usize {
        self.header
            .iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("no column {name} in {:?}", self.header))
    }

    /// A column's numbers; an empty cell (nothing measured) reads NaN.
    pub fn f64s(&self, name: &str) -> Vec<f64> {
        let c = self.col(name);
        self.rows
            .iter()
            .map(|r| {
                if r[c].is_empty() {
                    f64::NAN
                } else {
                    r[c].parse::<f64>().expect("number")
                }
            })
            .collect()
    }

    pub fn strs(&self, name: &str) -> Vec<String> {
        let c = self.col(name);
        self.rows.iter().map(|r| r[c].clone()).collect()
    }
}

/// The complete lines of a CSV being written (a last line without its
/// newline is not yet a row), as maps from column to text.
pub fn complete_rows(path: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Vec::new();
    };
    let complete = match text.rfind('\n') {
        Some(k) => &text[..k],
        None => return Vec::new(),
    };
    let mut lines = complete.lines();
    let Some(header) = lines.next() else {
        return Vec::new();
    };
    let names: Vec<&str> = header.split(',').collect();
    lines
        .map(|l| {
            names
                .iter()
                .zip(l.split(','))
                .map(|(n, v)| ((*n).to_owned(), v.to_owned()))
                .collect()
        })
        .collect()
}
