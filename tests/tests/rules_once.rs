//! Each rule written once (issue 44): the values ARCHITECTURE.md and their
//! docs call "defined here only" have one definition with a literal value
//! in the workspace's Rust sources (`crates/*/src`); every other use takes
//! that constant. A copied literal anywhere else fails here, naming the
//! file and line.
//!
//! The check reads source text (code, not comments): it needs no crate of
//! the rules, only the sources, so it also sees crates this test crate does
//! not depend on.
#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup

use std::path::{Path, PathBuf};

/// A rule: what a definition with a literal looks like, and where the one
/// definition lives.
struct Rule {
    name: &'static str,
    /// Whether a line of code (comments stripped) defines the rule's value.
    defines: fn(&str) -> bool,
    /// The one file that may, relative to the workspace root.
    home: &'static str,
}

fn has_number(code: &str, n: &str) -> bool {
    code.match_indices(n).any(|(i, _)| {
        let before = code[..i].chars().next_back();
        let after = code[i + n.len()..].chars().next();
        !before.is_some_and(|c| c.is_ascii_digit() || c == '.' || c == '_')
            && !after.is_some_and(|c| c.is_ascii_digit() || c == '_')
    })
}

const RULES: &[Rule] = &[
    Rule {
        name: "the physiological pupil range (1.5–9 mm)",
        // A constant named for the pupil with either end as a literal, or
        // a clamp to a literal range.
        defines: |c| {
            let pupil_const = c.contains("const") && c.to_ascii_uppercase().contains("PUPIL");
            let ends = has_number(c, "1.5") || has_number(c, "9.0");
            (pupil_const && ends)
                || c.contains(".clamp(1.5, 9.0)")
                || c.contains(".clamp(1.0, 9.0)")
        },
        home: "crates/gazelight-eye/src/filter/physio.rs",
    },
    Rule {
        name: "the confidence gate (0.6)",
        defines: |c| c.to_ascii_lowercase().contains("confidence") && has_number(c, "0.6"),
        home: "crates/gazelight-eye/src/filter/confidence.rs",
    },
    Rule {
        name: "the sRGB table's size",
        defines: |c| {
            c.contains("LUT") && c.contains("const") && {
                let value = c.split('=').nth(1).unwrap_or("");
                value.trim_start().starts_with(|d: char| d.is_ascii_digit())
            }
        },
        home: "crates/gazelight-vision/src/encode.rs",
    },
    Rule {
        name: "Neon's scene camera (1600 × 1200 px)",
        defines: |c| has_number(c, "1600.0") && has_number(c, "1200.0"),
        home: "crates/gazelight-eye/src/sample.rs",
    },
];

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the workspace root")
        .to_path_buf()
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// Every `.rs` file under `crates/*/src`.
fn sources(root: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let crates = std::fs::read_dir(root.join("crates")).expect("crates/");
    for c in crates.flatten() {
        rust_files(&c.path().join("src"), &mut out);
    }
    out.sort();
    out
}

/// The code of a line: up to a `//` comment.
fn code(line: &str) -> &str {
    line.split("//").next().unwrap_or("")
}

#[test]
fn each_rule_has_one_definition_with_a_literal_value() {
    let root = workspace();
    let files = sources(&root);
    assert!(files.len() > 100, "found only {} sources", files.len());
    let mut problems = Vec::new();
    for rule in RULES {
        let mut found = Vec::new();
        for f in &files {
            let text = std::fs::read_to_string(f).expect("a source file");
            let rel = f
                .strip_prefix(&root)
                .unwrap_or(f)
                .to_string_lossy()
                .into_owned();
            for (i, line) in text.lines().enumerate() {
                if (rule.defines)(code(line)) {
                    found.push((rel.clone(), i + 1, line.trim().to_owned()));
                }
            }
        }
        let at_home = found.iter().filter(|(f, ..)| f == rule.home).count();
        if at_home != 1 || found.len() != 1 {
            problems.push(format!(
                "{}: expected one definition, in {}; found {}:\n{}",
                rule.name,
                rule.home,
                found.len(),
                found
                    .iter()
                    .map(|(f, l, s)| format!("    {f}:{l}: {s}"))
                    .collect::<Vec<_>>()
                    .join("\n")
            ));
        }
    }
    assert!(
        problems.is_empty(),
        "a rule is defined more than once (use the one constant):\n{}",
        problems.join("\n")
    );
}

/// The WGSL twin of the sRGB table's size (WGSL cannot import a Rust
/// constant) equals the one in `gazelight-vision`.
#[test]
fn the_wgsl_srgb_table_size_is_the_cpu_one() {
    let path = workspace().join("shaders/frame_state.wgsl");
    let text = std::fs::read_to_string(&path).expect("frame_state.wgsl");
    let values: Vec<usize> = text
        .lines()
        .filter_map(|l| code(l).trim().strip_prefix("const SRGB_LUT_SIZE: u32 = "))
        .map(|v| {
            v.trim_end_matches(';')
                .trim_end_matches('u')
                .parse()
                .expect("a number")
        })
        .collect();
    assert_eq!(
        values,
        [gazelight_vision::SRGB_LUT_SIZE],
        "{}",
        path.display()
    );
}
