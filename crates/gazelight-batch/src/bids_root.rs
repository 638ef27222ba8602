//! A BIDS dataset root as the batch's list (docs/batch.md): one row per
//! eye-tracking recording found under `sub-*/[ses-*/]<datatype>/`.
//!
//! A recording is the `*_physio.json` sidecars with `PhysioType:
//! "eyetrack"` whose names differ only in the `recording-` label's digits
//! (`recording-eye1`, `eye2`, `eye3`: the grouping the BIDS importer uses
//! when it opens one of them); the row replays the first one's
//! `*_physio.tsv.gz`, which brings its sibling eyes. The row's id is the
//! file name's entities without `recording-` (`sub-01_ses-1_task-x_run-1`),
//! its BIDS entities those of the name, its replay options the
//! `[defaults]` table of `--defaults FILE.toml` (none without it; a TOML
//! manifest's rows in that file are not used).
//! `derivatives/` and other top-level folders are not searched.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use crate::{Context, ReplayCommand, Result};

use crate::manifest::{self, Cell, Entities, Row, Value};

/// Largest sidecar read, bytes.
const MAX_SIDECAR_BYTES: u64 = 1 << 20;
/// Most recordings taken from one dataset.
const MAX_RECORDINGS: usize = 100_000;

/// Sorted entries of `dir` that are folders named `PREFIX…`.
fn subdirs(dir: &Path, prefix: &str) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("cannot read {}", dir.display()))? {
        let e = e.with_context(|| format!("cannot read {}", dir.display()))?;
        let p = e.path();
        if p.is_dir()
            && e.file_name()
                .to_str()
                .is_some_and(|n| n.starts_with(prefix))
        {
            out.push(p);
        }
    }
    out.sort();
    Ok(out)
}

/// `stem` without its `_recording-<label>` entity, and the label's kind
/// (the label without digits).
fn split_recording(stem: &str) -> (String, String) {
    let mut base = Vec::new();
    let mut kind = String::new();
    for part in stem.split('_') {
        match part.strip_prefix("recording-") {
            Some(label) => kind = label.chars().filter(|c| !c.is_ascii_digit()).collect(),
            None => base.push(part),
        }
    }
    (base.join("_"), kind)
}

/// The entities of a file name's stem (`sub-01_ses-1_task-x_run-2`).
fn entities(stem: &str, file: &Path) -> Result<Entities> {
    let mut e = Entities::default();
    for part in stem.split('_') {
        let Some((key, value)) = part.split_once('-') else {
            continue;
        };
        match key {
            "sub" => e.subject = Some(value.to_owned()),
            "ses" => e.session = Some(value.to_owned()),
            "task" => e.task = Some(value.to_owned()),
            "run" => {
                e.run = Some(value.parse::<u32>().with_context(|| {
                    format!(
                        "{}: run-{value}: a BIDS run is a whole number",
                        file.display()
                    )
                })?);
            }
            _ => {}
        }
    }
    if e.subject.is_none() {
        bail!("{}: no sub-<label> in the file name", file.display());
    }
    Ok(e)
}

/// The rows of the BIDS dataset at `root`, with the `[defaults]` of
/// `defaults` (a TOML file) as every row's replay options.
pub fn load(root: &Path, defaults: Option<&Path>, replay: &dyn ReplayCommand) -> Result<Vec<Row>> {
    let root = std::fs::canonicalize(root)
        .with_context(|| format!("cannot resolve {}", root.display()))?;
    if !root.join("dataset_description.json").is_file() {
        bail!(
            "{}: a directory without dataset_description.json: not a BIDS dataset root \
             (give a CSV or TOML manifest, or a BIDS dataset's root folder)",
            root.display()
        );
    }
    let (default_cells, base) = match defaults {
        Some(p) => {
            let (c, b) = manifest::load_defaults(p, replay)?;
            (c, Some(b))
        }
        None => (Vec::new(), None),
    };
    // (id, kind) → the group's physio files (sidecars), sorted.
    let mut groups: BTreeMap<(String, String), Vec<PathBuf>> = BTreeMap::new();
    for sub in subdirs(&root, "sub-")? {
        let mut holders = subdirs(&sub, "ses-")?;
        holders.insert(0, sub);
        for holder in holders {
            for datatype in subdirs(&holder, "")? {
                if datatype
                    .file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("ses-"))
                {
                    continue;
                }
                let mut names = Vec::new();
                for e in std::fs::read_dir(&datatype)
                    .with_context(|| format!("cannot read {}", datatype.display()))?
                {
                    let e = e.with_context(|| format!("cannot read {}", datatype.display()))?;
                    if let Some(n) = e.file_name().to_str()
                        && n.ends_with("_physio.json")
                    {
                        names.push(e.path());
                    }
                }
                names.sort();
                for json in names {
                    let text = gazelight_input::read_to_string(&json, MAX_SIDECAR_BYTES)
                        .with_context(|| format!("cannot read {}", json.display()))?;
                    let sidecar: serde_json::Value = serde_json::from_str(&text)
                        .with_context(|| format!("{}: not JSON", json.display()))?;
                    if sidecar
                        .get("PhysioType")
                        .and_then(serde_json::Value::as_str)
                        != Some("eyetrack")
                    {
                        continue;
                    }
                    let stem = json
                        .file_name()
                        .and_then(|n| n.to_str())
                        .and_then(|n| n.strip_suffix("_physio.json"))
                        .unwrap_or_default();
                    let (id, kind) = split_recording(stem);
                    groups.entry((id, kind)).or_default().push(json);
                    if groups.len() > MAX_RECORDINGS {
                        bail!("{}: more than {MAX_RECORDINGS} recordings", root.display());
                    }
                }
            }
        }
    }
    let flags = replay.flags();
    let mut rows: Vec<Row> = Vec::with_capacity(groups.len());
    // Each id's index in `rows`.
    let mut seen: HashMap<String, usize> = HashMap::with_capacity(groups.len());
    for (index, ((id, kind), files)) in groups.into_iter().enumerate() {
        let Some(first) = files.first() else { continue };
        let tsv = first.with_file_name(
            first
                .file_name()
                .and_then(|n| n.to_str())
                .unwrap_or_default()
                .replace("_physio.json", "_physio.tsv.gz"),
        );
        if !tsv.is_file() {
            bail!(
                "{}: its data file {} is missing",
                first.display(),
                tsv.display()
            );
        }
        // One lookup per recording (linear in a large dataset).
        if let Some(&other) = seen.get(&id) {
            let other: &Row = &rows[other];
            bail!(
                "{}: recording label kind `{kind}` beside {}'s: two recordings with the id {id}",
                first.display(),
                other.recording
            );
        }
        seen.insert(id.clone(), rows.len());
        let id = manifest::check_id(&id).map_err(|e| err!("{}: {e}", first.display()))?;
        let mut cells: Vec<Cell> = default_cells
            .iter()
            .map(|c| Cell {
                line: c.line,
                field: c.field.clone(),
                value: match &c.value {
                    Value::Text(t) => Value::Text(t.clone()),
                    Value::Bool(b) => Value::Bool(*b),
                },
            })
            .collect();
        cells.push(Cell {
            line: 0,
            field: "recording".to_owned(),
            value: Value::Text(tsv.display().to_string()),
        });
        let mut row = manifest::build_row(
            index,
            0,
            cells,
            base.as_deref().unwrap_or(&root),
            &flags,
            replay,
        )
        .map_err(|e| match defaults {
            Some(d) => err!("{}: {e} (for {})", d.display(), tsv.display()),
            None => err!("{}: {e}", tsv.display()),
        })?;
        row.id = id.clone();
        row.entities = entities(&id, first)?;
        rows.push(row);
    }
    if rows.is_empty() {
        bail!(
            "{}: no eye-tracking recordings (sub-*/[ses-*/]*/…_physio.json with PhysioType \
             eyetrack)",
            root.display()
        );
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_split_into_id_kind_and_entities() {
        assert_eq!(
            split_recording("sub-01_ses-1_task-x_run-2_recording-eye1"),
            ("sub-01_ses-1_task-x_run-2".to_owned(), "eye".to_owned())
        );
        let e = entities("sub-01_ses-a_task-x_run-02", Path::new("f")).unwrap();
        assert_eq!(e.subject.as_deref(), Some("01"));
        assert_eq!(e.session.as_deref(), Some("a"));
        assert_eq!(e.task.as_deref(), Some("x"));
        assert_eq!(e.run, Some(2));
        let err = format!(
            "{:#}",
            entities("task-x", Path::new("/d/task-x_physio.json")).unwrap_err()
        );
        assert!(err.contains("/d/task-x_physio.json: no sub-"), "{err}");
    }
}
