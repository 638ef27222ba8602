#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! An import error quoting a hostile input (a 16 MiB tag) shows its head
//! and tail and how much was left out, never the whole input.

use std::path::PathBuf;

use gazelight_import::{ImportError, MAX_REASON_BYTES, Position};

#[test]
fn a_reason_quoting_16_mib_is_shown_capped_with_the_count_left_out() {
    let tag = format!("<{}é>", "a".repeat(16 << 20));
    let e = ImportError::Structure {
        path: PathBuf::from("/data/x.xdf"),
        position: Position::Line(2),
        reason: format!("unexpected tag {tag}; expected <info>"),
    };
    let shown = e.to_string();
    assert!(
        shown.len() < MAX_REASON_BYTES + 200,
        "{} bytes",
        shown.len()
    );
    assert!(shown.starts_with("/data/x.xdf"), "{}", &shown[..80]);
    assert!(shown.contains("bytes left out"), "{shown}");
    // The end of the reason (what was expected) is still there.
    assert!(
        shown.ends_with("é>; expected <info>"),
        "{}",
        &shown[shown.len() - 80..]
    );
    // A short reason is shown whole.
    let e = ImportError::UnknownFormat {
        path: PathBuf::from("/x"),
        reason: "no header".into(),
    };
    assert_eq!(e.to_string(), "/x: unknown recording format (no header)");
}
