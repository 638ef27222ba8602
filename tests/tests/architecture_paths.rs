//! ARCHITECTURE.md's pupil path stays true (issue 44): the list between
//! `<!-- pupil-path -->` markers names, in order, the files a pupil value
//! passes from a tracker datum to the GPU kernel. Each entry's file must
//! exist and hold the item the entry names (so a renamed function or a
//! moved file fails here, naming the entry), the list has at most 12 files,
//! and it never comes back to a crate it left.
#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup

use std::path::Path;

/// One entry: `N. `path` — `item`: what happens there`.
struct Entry {
    line: String,
    path: String,
    item: String,
}

fn entries(doc: &str) -> Vec<Entry> {
    let start = doc
        .find("<!-- pupil-path -->")
        .expect("ARCHITECTURE.md has no <!-- pupil-path --> list");
    let end = doc[start..]
        .find("<!-- /pupil-path -->")
        .map(|k| start + k)
        .expect("the pupil-path list is not closed");
    doc[start..end]
        .lines()
        .filter(|l| l.chars().next().is_some_and(|c| c.is_ascii_digit()))
        .map(|l| {
            let ticks: Vec<&str> = l.split('`').collect();
            // ticks[1] is the path, ticks[3] the item.
            assert!(ticks.len() >= 4, "entry without `path` and `item`: {l}");
            Entry {
                line: l.to_owned(),
                path: ticks[1].to_owned(),
                item: ticks[3].to_owned(),
            }
        })
        .collect()
}

/// The crate a path is in: `crates/NAME/…` → `NAME`.
fn crate_of(path: &str) -> &str {
    path.strip_prefix("crates/")
        .and_then(|p| p.split('/').next())
        .unwrap_or(path)
}

/// The rules on a list; `read` gives a file's text (`None`: no file).
fn check(list: &[Entry], read: impl Fn(&str) -> Option<String>) -> Result<(), String> {
    if !(6..=12).contains(&list.len()) {
        return Err(format!(
            "the pupil path lists {} files; the bar is at most 12 (and a real path has more than 5)",
            list.len()
        ));
    }
    let mut left: Vec<&str> = Vec::new();
    for (k, e) in list.iter().enumerate() {
        let text = read(&e.path).ok_or_else(|| format!("entry {}: no file {}", k + 1, e.path))?;
        if !text.contains(&e.item) {
            return Err(format!(
                "entry {} names `{}`, which {} does not hold: {}",
                k + 1,
                e.item,
                e.path,
                e.line
            ));
        }
        let c = crate_of(&e.path);
        if left.last() != Some(&c) {
            if left.contains(&c) {
                return Err(format!(
                    "entry {} returns to crate {c}, which the path left before: {}",
                    k + 1,
                    e.line
                ));
            }
            left.push(c);
        }
    }
    Ok(())
}

#[test]
fn the_pupil_path_is_short_one_way_and_names_what_exists() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let doc = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap();
    let list = entries(&doc);
    let read = |p: &str| std::fs::read_to_string(root.join(p)).ok();
    if let Err(e) = check(&list, read) {
        panic!("ARCHITECTURE.md's pupil path: {e}");
    }
}

/// The rules on lists written here: each fails where it should.
#[test]
fn the_check_finds_a_return_a_missing_item_and_a_long_list() {
    let list = |crates: &[&str]| -> Vec<Entry> {
        let mut doc = String::from("<!-- pupil-path -->\n");
        for (k, c) in crates.iter().enumerate() {
            doc += &format!("{}. `crates/{c}/src/f{k}.rs` — `item{k}`: x\n", k + 1);
        }
        doc += "<!-- /pupil-path -->\n";
        entries(&doc)
    };
    // Every file holds every item.
    let all = |_: &str| Some((0..20).map(|k| format!("item{k} ")).collect::<String>());
    let good = list(&["a", "a", "b", "c", "c", "d"]);
    assert_eq!(check(&good, all), Ok(()));
    let back = list(&["a", "b", "b", "c", "a", "d"]);
    let e = check(&back, all).unwrap_err();
    assert!(e.contains("entry 5 returns to crate a"), "{e}");
    let long = list(&["a"; 13]);
    assert!(check(&long, all).unwrap_err().contains("13 files"));
    let missing = check(&good, |p: &str| {
        (!p.ends_with("f3.rs")).then(|| all(p).unwrap())
    });
    assert!(missing.unwrap_err().contains("entry 4: no file"));
    let renamed = check(&good, |_: &str| Some("item0 item1 item2".to_owned()));
    assert!(renamed.unwrap_err().contains("entry 4 names `item3`"));
}

/// Every repository path ARCHITECTURE.md names in backticks
/// (`crates/…`, `tests/…`, `.ci/…`, `docs/…`) exists: a moved or renamed
/// file fails here, naming the line (issue 44: the map stays true).
#[test]
fn every_path_the_architecture_names_exists() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let doc = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap();
    let missing = named_paths(&doc)
        .into_iter()
        .filter(|(_, p)| !root.join(p).exists())
        .map(|(line, p)| format!("line {line}: {p}"))
        .collect::<Vec<_>>();
    assert!(
        missing.is_empty(),
        "ARCHITECTURE.md names paths that do not exist:\n{}",
        missing.join("\n")
    );
}

/// `(line number, path)` of each backticked repository path in `doc`
/// (a glob or a placeholder such as `<name>` is not a path).
fn named_paths(doc: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    for (i, line) in doc.lines().enumerate() {
        for (k, part) in line.split('`').enumerate() {
            let is_code = k % 2 == 1;
            let rooted = ["crates/", "tests/", ".ci/", "docs/"]
                .iter()
                .any(|r| part.starts_with(r));
            let plain = !part.contains(['*', '<', '>', ' ', '{', '…']);
            if is_code && rooted && plain {
                // `path:line` or `path (…)` name the path before them.
                let path = part.split(':').next().unwrap_or(part);
                out.push((i + 1, path.trim_end_matches('/').to_owned()));
            }
        }
    }
    out
}

#[test]
fn named_paths_takes_backticked_repository_paths_only() {
    let doc = "a `crates/x/src/y.rs` and `crates/x/src/*.rs`, `frames.rs`,\n`docs/a.md:12` b";
    assert_eq!(
        named_paths(doc),
        vec![
            (1, "crates/x/src/y.rs".to_owned()),
            (2, "docs/a.md".to_owned())
        ]
    );
}
