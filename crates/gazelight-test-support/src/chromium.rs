//! Headless Chromium (Debian's `chromium`) for the status page tests: a
//! run with a throw-away profile, the page's DOM after WebSocket updates,
//! and the page's state as it shows it.
//!
//! A missing `chromium` fails the test (CI installs it, `.ci/test`).

use std::process::Command;
use std::sync::atomic::{AtomicU64, Ordering};

/// The flags of every run: headless, no sandbox (CI runs as root), no GPU,
/// nothing fetched or synced in the background, no scroll bars in
/// screenshots.
pub const FLAGS: [&str; 8] = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--hide-scrollbars",
];

/// Runs `chromium` with [`FLAGS`], a fresh profile (removed afterwards)
/// and `args`; returns its stdout. Panics when Chromium is missing or
/// fails, with its status and stderr.
pub fn run(args: &[String]) -> String {
    static RUNS: AtomicU64 = AtomicU64::new(0);
    let profile = std::env::temp_dir().join(format!(
        "gazelight-chromium-{}-{}",
        std::process::id(),
        RUNS.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&profile);
    let out = Command::new("chromium")
        .args(FLAGS)
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(args)
        .output();
    let _ = std::fs::remove_dir_all(&profile);
    let out = out.unwrap_or_else(|e| {
        panic!("headless Chromium (Debian package `chromium`) must be installed: {e}")
    });
    assert!(
        out.status.success(),
        "chromium {args:?}: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The status page's DOM at `url` after it has had WebSocket updates.
/// Virtual time runs out as soon as the page is idle, so on a loaded
/// machine (a cold Chromium start beside a build) it can end before the
/// socket's first real-time message arrives: up to 4 loads, the first with
/// an update returned (else the last, which the caller's assertion
/// reports).
pub fn dump_with_updates(url: &str) -> String {
    let mut dom = String::new();
    for _ in 0..4 {
        dom = run(&[
            "--virtual-time-budget=3000".into(),
            "--dump-dom".into(),
            url.to_owned(),
        ]);
        if page_state(&dom).0 >= 1 {
            break;
        }
    }
    dom
}

/// The status page as a DOM dump shows it: (WebSocket updates, script
/// errors, the mirrored `#state` JSON text (empty before the first
/// update), the `#errors` text). Panics, quoting the DOM, when an element
/// is missing.
pub fn page_state(dom: &str) -> (u64, u64, String, String) {
    let attr = |name: &str| -> u64 {
        let key = format!("{name}=\"");
        let value = dom
            .find(&key)
            .and_then(|i| dom[i + key.len()..].split('"').next())
            .unwrap_or_else(|| panic!("no {name} in {dom}"));
        value
            .parse()
            .unwrap_or_else(|e| panic!("{name}=\"{value}\": {e}"))
    };
    let body = dom
        .find("<pre id=\"state\"")
        .map(|i| &dom[i..])
        .unwrap_or_else(|| panic!("no #state in {dom}"));
    let json = body
        .find('>')
        .zip(body.find("</pre>"))
        .map(|(open, close)| &body[open + 1..close])
        .unwrap_or_else(|| panic!("#state not closed in {dom}"))
        .replace("&quot;", "\"")
        .replace("&amp;", "&");
    let state = json.trim().to_owned();
    let errors_tag = "<div id=\"errors\">";
    let errors = dom
        .find(errors_tag)
        .and_then(|i| dom[i + errors_tag.len()..].split("</div>").next())
        .unwrap_or_else(|| panic!("no #errors in {dom}"))
        .to_owned();
    (attr("data-updates"), attr("data-errors"), state, errors)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The page's markup as `serve/page.html` writes it, filled as its
    /// script fills it.
    #[test]
    fn page_state_reads_the_counters_state_and_errors() {
        let dom = r#"<html><body data-updates="12" data-errors="0">
<pre id="state" class="x">{&quot;frames&quot;:7,&quot;health&quot;:&quot;live&quot;}</pre>
<div id="errors"></div></body></html>"#;
        let (updates, errors, state, text) = page_state(dom);
        assert_eq!((updates, errors), (12, 0));
        assert_eq!(state, r#"{"frames":7,"health":"live"}"#);
        assert_eq!(text, "");
        let empty = r#"<body data-updates="0" data-errors="2"><pre id="state"></pre><div id="errors">TypeError: x</div>"#;
        let (updates, errors, state, text) = page_state(empty);
        assert_eq!((updates, errors), (0, 2));
        assert_eq!(state, "");
        assert_eq!(text, "TypeError: x");
    }

    #[test]
    #[should_panic(expected = "no data-updates")]
    fn a_page_without_the_counters_is_reported() {
        page_state("<pre id=\"state\"></pre><div id=\"errors\"></div>");
    }
}
