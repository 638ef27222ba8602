//! The batch manifest: a CSV or TOML list of recordings, each row turned
//! into the argument list of one `gazelight replay` (docs/batch.md).
//!
//! CSV: a header line, then one recording per line; `#` starts a comment
//! line; cells may be double-quoted (`""` is a quote inside). TOML: an
//! optional `[defaults]` table applied to every row and one `[[row]]`
//! table per recording (a row's keys override the defaults).
//!
//! Columns (keys): `id` (the row's output folder, default `NNN-STEM`),
//! `recording` (required), and any long option of `gazelight replay` by
//! its name (`scene`, `fps`, `from_secs`, `no_frames`, …; `-` or `_`).
//! Relative paths (`recording`, `scene`, `calibration`, `config`) are
//! taken from the manifest's directory. `out`, `force` and `trace` are the
//! batch's to set and are refused. `subject`, `session`, `task` and `run`
//! are the row's BIDS entities for `--bids` (not replay options). Every row
//! is checked before anything runs: an error names the file, the line and
//! the field.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use crate::{BatchError, Context, ReplayCommand, ReplayInputs, Result};

/// Largest manifest read, bytes (a row is ~100 bytes: ~100 000 rows).
const MAX_MANIFEST_BYTES: u64 = 16 << 20;
/// Longest row id.
const MAX_ID_CHARS: usize = 100;
/// Names the batch writes into `--out` itself: no row id may take them.
const RESERVED_IDS: [&str; 1] = ["summary.csv"];
/// Columns the batch sets itself.
const FORBIDDEN: [&str; 4] = ["out", "force", "trace", "help"];

/// Columns that are a row's BIDS entities (for `--bids`), not replay
/// options.
const ENTITIES: [&str; 4] = ["subject", "session", "task", "run"];

/// A row's BIDS entities for `--bids` (each optional: see [`Row::bids_names`]).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Entities {
    pub subject: Option<String>,
    pub session: Option<String>,
    pub task: Option<String>,
    pub run: Option<u32>,
}

/// One recording of the manifest.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Row {
    /// Line of the manifest it came from (1-based).
    pub line: usize,
    /// Its output folder's name.
    pub id: String,
    /// The recording as the manifest names it.
    pub recording: String,
    /// The arguments after `gazelight replay` (paths resolved), without
    /// `--out` and `--force`.
    pub argv: Vec<String>,
    /// Its BIDS entities (manifest columns, or a BIDS dataset's file name).
    pub entities: Entities,
}

impl Row {
    /// The parsed replay arguments with `--out out`.
    pub fn replay_args(&self, out: &Path, replay: &dyn ReplayCommand) -> Result<ReplayInputs> {
        let mut argv = vec!["replay".to_owned()];
        argv.extend(self.argv.iter().cloned());
        argv.push(format!("--out={}", out.display()));
        replay
            .parse(&argv)
            .map_err(|e| err!("row {}: {}", self.id, first_line(&e)))
    }

    /// Where `--bids` writes the row: its entities; subject by default the
    /// id's letters and digits, task `replay`.
    pub fn bids_names(&self) -> gazelight_tracker::import::bids::BidsNames {
        let e = &self.entities;
        let mut subject: String = self
            .id
            .chars()
            .filter(char::is_ascii_alphanumeric)
            .collect();
        if subject.is_empty() {
            subject.push_str("batch");
        }
        gazelight_tracker::import::bids::BidsNames {
            subject: e.subject.clone().unwrap_or(subject),
            session: e.session.clone(),
            task: e.task.clone().unwrap_or_else(|| "replay".to_owned()),
            run: e.run,
        }
    }

    /// The hash its completion record holds: the replay's arguments, the
    /// identity of each input file they name, and,
    /// with `--bids DIR`, the export's folder and entities (the export is
    /// part of the row's completion).
    pub fn options_hash(&self, bids: Option<&Path>) -> String {
        let mut argv = self.argv.clone();
        if let Some(dir) = bids {
            let n = self.bids_names();
            argv.push(format!("--bids={}", dir.display()));
            argv.push(n.prefix());
        }
        // The inputs' identities (size and modification time): a recording,
        // scene, config or profile rewritten in place runs again.
        argv.extend(crate::state::input_identities(&self.argv));
        crate::state::options_hash(&argv)
    }
}

/// One cell: where it is and what it holds.
pub(crate) struct Cell {
    pub line: usize,
    pub field: String,
    pub value: Value,
}

pub(crate) enum Value {
    Text(String),
    Bool(bool),
}

/// What a replay option takes, from clap's own description of `replay`
/// ([`ReplayCommand::flags`]).
#[derive(Clone, Debug)]
pub struct Flag {
    /// Its long name, without `--`.
    pub long: String,
    /// Whether it takes a value (else a switch).
    pub takes_value: bool,
    /// Whether its value is a path (`FILE` or `DIR`: taken from the
    /// manifest's directory when relative).
    pub path: bool,
}

/// Reads and checks the manifest at `path`.
pub fn load(path: &Path, replay: &dyn ReplayCommand) -> Result<Vec<Row>> {
    if path.is_dir() {
        bail!(
            "{}: a directory; give a CSV or TOML manifest, or a BIDS dataset root \
             (docs/batch.md)",
            path.display()
        );
    }
    let file =
        std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut text = String::new();
    std::io::Read::read_to_string(
        &mut std::io::Read::take(file, MAX_MANIFEST_BYTES + 1),
        &mut text,
    )
    .with_context(|| format!("cannot read {} (UTF-8 text expected)", path.display()))?;
    if text.len() as u64 > MAX_MANIFEST_BYTES {
        bail!(
            "{}: longer than {} MiB",
            path.display(),
            MAX_MANIFEST_BYTES >> 20
        );
    }
    let toml = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    let flags = replay.flags();
    let raw = if toml {
        toml_rows(&text)
    } else {
        csv_rows(&text, &|name| check_field(name, &flags))
    }
    .map_err(|e| err!("{}: {e}", path.display()))?;
    let base = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let base = std::fs::canonicalize(base)
        .with_context(|| format!("cannot resolve the directory of {}", path.display()))?;
    let mut rows: Vec<Row> = Vec::with_capacity(raw.len());
    // Each id's line: one lookup per row (a 100 000-row manifest is
    // checked in linear time, not 5·10⁹ comparisons).
    let mut seen: HashMap<String, usize> = HashMap::with_capacity(raw.len());
    for (k, (line, cells)) in raw.into_iter().enumerate() {
        let row = build_row(k, line, cells, &base, &flags, replay)
            .map_err(|e| err!("{}: {e}", path.display()))?;
        if let Some(other) = seen.insert(row.id.clone(), row.line) {
            bail!(
                "{}: line {}: field id: {:?} is already the id of line {other}",
                path.display(),
                row.line,
                row.id,
            );
        }
        rows.push(row);
    }
    if rows.is_empty() {
        bail!("{}: no recordings listed", path.display());
    }
    Ok(rows)
}

/// Whether `name` is a column the manifest may have.
fn check_field(name: &str, flags: &[Flag]) -> Result<(), String> {
    let key = name.trim().replace('_', "-");
    if key == "id" || key == "recording" || ENTITIES.contains(&key.as_str()) {
        return Ok(());
    }
    if FORBIDDEN.contains(&key.as_str()) {
        return Err(format!(
            "field {name}: the batch sets --{key} itself (each row writes OUT/ID); leave it out"
        ));
    }
    if flags.iter().any(|f| f.long == key) {
        Ok(())
    } else {
        Err(format!(
            "field {name}: not an option of `gazelight replay` (see `gazelight replay --help`)"
        ))
    }
}

/// One row's cells → its replay arguments, checked.
pub(crate) fn build_row(
    index: usize,
    line: usize,
    cells: Vec<Cell>,
    base: &Path,
    flags: &[Flag],
    replay: &dyn ReplayCommand,
) -> Result<Row> {
    let mut id = None;
    let mut recording = None;
    let mut entities = Entities::default();
    let mut options: Vec<String> = Vec::new();
    // Flag name → field as written (to name it in errors).
    let mut fields: BTreeMap<String, (usize, String)> = BTreeMap::new();
    for cell in cells {
        let at = |msg: String| err!("line {}: field {}: {msg}", cell.line, cell.field);
        let key = cell.field.trim().replace('_', "-");
        match key.as_str() {
            "id" => {
                let v = text(&cell.value);
                if !v.is_empty() {
                    id = Some(check_id(&v).map_err(at)?);
                }
                continue;
            }
            "recording" => {
                let v = text(&cell.value);
                if !v.is_empty() {
                    recording = Some(v);
                }
                continue;
            }
            "subject" | "session" | "task" => {
                let v = text(&cell.value);
                if v.is_empty() {
                    continue;
                }
                if !gazelight_tracker::import::bids::is_label(&v) {
                    return Err(at(format!(
                        "{v:?}: a BIDS label is letters and digits only"
                    )));
                }
                match key.as_str() {
                    "subject" => entities.subject = Some(v),
                    "session" => entities.session = Some(v),
                    _ => entities.task = Some(v),
                }
                continue;
            }
            "run" => {
                let v = text(&cell.value);
                if !v.is_empty() {
                    entities.run = Some(
                        v.parse()
                            .map_err(|_| at(format!("{v:?}: a BIDS run is a whole number ≥ 0")))?,
                    );
                }
                continue;
            }
            _ => {}
        }
        check_field(&cell.field, flags).map_err(|e| err!("line {}: {e}", cell.line))?;
        let Some(flag) = flags.iter().find(|f| f.long == key) else {
            continue; // checked just above
        };
        fields.insert(flag.long.clone(), (cell.line, cell.field.clone()));
        if flag.takes_value {
            let v = text(&cell.value);
            if v.is_empty() {
                continue;
            }
            let v = if flag.path { resolve(base, &v) } else { v };
            options.push(format!("--{}={v}", flag.long));
        } else {
            let on = match &cell.value {
                Value::Bool(b) => *b,
                Value::Text(t) => match t.trim().to_ascii_lowercase().as_str() {
                    "" | "false" | "no" | "0" => false,
                    "true" | "yes" | "1" => true,
                    other => {
                        return Err(at(format!("{other:?}: expected true or false (a switch)")));
                    }
                },
            };
            if on {
                options.push(format!("--{}", flag.long));
            }
        }
    }
    let Some(recording) = recording else {
        bail!("line {line}: field recording: missing (every row names its recording)");
    };
    let id = match id {
        Some(id) => id,
        None => default_id(index, &recording),
    };
    let mut argv = vec![resolve(base, &recording)];
    argv.extend(options);
    let row = Row {
        line,
        id,
        recording,
        argv,
        entities,
    };
    // clap's parse and replay's own flag checks, with the field named.
    let named = |msg: String| -> BatchError {
        let flag = msg
            .split(|c: char| c.is_whitespace() || c == '\'' || c == '=' || c == ':')
            .find_map(|w| w.strip_prefix("--"))
            .map(str::to_owned);
        match flag.and_then(|f| fields.get(&f)) {
            Some((l, field)) => err!("line {l}: field {field}: {msg}"),
            None => err!("line {line}: {msg}"),
        }
    };
    let mut argv = vec!["replay".to_owned()];
    argv.extend(row.argv.iter().cloned());
    argv.push("--out=-".to_owned());
    replay.check(&argv).map_err(named)?;
    Ok(row)
}

fn first_line(s: &str) -> String {
    s.lines().next().unwrap_or("").to_owned()
}

fn text(v: &Value) -> String {
    match v {
        Value::Text(t) => t.trim().to_owned(),
        Value::Bool(b) => b.to_string(),
    }
}

/// `path` taken from `base` when relative.
fn resolve(base: &Path, path: &str) -> String {
    let p = PathBuf::from(path);
    if p.is_absolute() {
        path.to_owned()
    } else {
        base.join(p).display().to_string()
    }
}

/// An id is a folder name: letters, digits, `.`, `_`, `-`, starting with
/// a letter or digit.
pub(crate) fn check_id(id: &str) -> Result<String, String> {
    let ok = !id.is_empty()
        && id.chars().count() <= MAX_ID_CHARS
        && id.chars().next().is_some_and(|c| c.is_ascii_alphanumeric())
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'));
    if ok && RESERVED_IDS.iter().any(|r| id.eq_ignore_ascii_case(r)) {
        Err(format!(
            "{id:?}: the batch writes a file of that name into --out; choose another id"
        ))
    } else if ok {
        Ok(id.to_owned())
    } else {
        Err(format!(
            "{id:?}: an id is a folder name of at most {MAX_ID_CHARS} letters, digits, '.', '_' \
             or '-', starting with a letter or digit"
        ))
    }
}

/// `NNN-STEM`: the row number and the recording's name.
fn default_id(index: usize, recording: &str) -> String {
    let p = Path::new(recording.trim_end_matches('/'));
    let stem = p
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut clean: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .take(MAX_ID_CHARS - 8)
        .collect();
    if clean.is_empty() {
        clean.push_str("recording");
    }
    format!("{:03}-{clean}", index + 1)
}

/// The data rows of a CSV manifest: (line, cells).
fn csv_rows(
    text: &str,
    check: &dyn Fn(&str) -> Result<(), String>,
) -> Result<Vec<(usize, Vec<Cell>)>, String> {
    let mut header: Option<(usize, Vec<String>)> = None;
    let mut rows = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let trimmed = raw.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let cells = split_csv(raw).map_err(|e| format!("line {line}: {e}"))?;
        match &header {
            None => {
                for (k, name) in cells.iter().enumerate() {
                    if name.trim().is_empty() {
                        return Err(format!("line {line}: column {} has no name", k + 1));
                    }
                    if cells[..k].iter().any(|c| c.trim() == name.trim()) {
                        return Err(format!("line {line}: field {}: named twice", name.trim()));
                    }
                    check(name.trim()).map_err(|e| format!("line {line}: {e}"))?;
                }
                if !cells.iter().any(|c| c.trim() == "recording") {
                    return Err(format!(
                        "line {line}: the header has no `recording` column (the first \
                         non-comment line is the header)"
                    ));
                }
                header = Some((line, cells.iter().map(|c| c.trim().to_owned()).collect()));
            }
            Some((hline, names)) => {
                if cells.len() != names.len() {
                    return Err(format!(
                        "line {line}: {} fields, the header (line {hline}) has {}",
                        cells.len(),
                        names.len()
                    ));
                }
                rows.push((
                    line,
                    names
                        .iter()
                        .zip(cells)
                        .map(|(n, v)| Cell {
                            line,
                            field: n.clone(),
                            value: Value::Text(v),
                        })
                        .collect(),
                ));
            }
        }
    }
    if header.is_none() {
        return Err("empty: expected a header line naming the columns".to_owned());
    }
    Ok(rows)
}

/// Splits one CSV line (RFC 4180 quoting within the line).
fn split_csv(line: &str) -> Result<Vec<String>, String> {
    let mut cells = Vec::new();
    let mut cell = String::new();
    let mut chars = line.chars().peekable();
    let mut quoted = false;
    let mut was_quoted = false;
    while let Some(c) = chars.next() {
        if quoted {
            match c {
                '"' if chars.peek() == Some(&'"') => {
                    chars.next();
                    cell.push('"');
                }
                '"' => quoted = false,
                c => cell.push(c),
            }
        } else {
            match c {
                ',' => {
                    cells.push(std::mem::take(&mut cell));
                    was_quoted = false;
                }
                '"' if cell.trim().is_empty() && !was_quoted => {
                    cell.clear();
                    quoted = true;
                    was_quoted = true;
                }
                '"' => return Err("a quote inside an unquoted field".to_owned()),
                c if was_quoted && !c.is_whitespace() => {
                    return Err("text after a closing quote".to_owned());
                }
                c => cell.push(c),
            }
        }
    }
    if quoted {
        return Err("a quoted field is not closed on its line".to_owned());
    }
    cells.push(cell);
    Ok(cells)
}

type SpannedTable = BTreeMap<String, toml::Spanned<toml::Value>>;

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlManifest {
    #[serde(default)]
    defaults: SpannedTable,
    #[serde(default)]
    row: Vec<toml::Spanned<SpannedTable>>,
}

fn toml_line(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

fn toml_cell(text: &str, k: &str, v: &toml::Spanned<toml::Value>) -> Result<Cell, String> {
    let line = toml_line(text, v.span().start);
    let value = match v.get_ref() {
        toml::Value::String(s) => Value::Text(s.clone()),
        toml::Value::Integer(i) => Value::Text(i.to_string()),
        toml::Value::Float(f) => Value::Text(f.to_string()),
        toml::Value::Boolean(b) => Value::Bool(*b),
        other => {
            return Err(format!(
                "line {line}: field {k}: a {}, expected a string, number or true/false",
                other.type_str()
            ));
        }
    };
    Ok(Cell {
        line,
        field: k.to_owned(),
        value,
    })
}

/// The `[defaults]` table of a TOML file (`--defaults`, for a BIDS dataset
/// root) as cells, and the file's directory (relative paths are taken from
/// it). Its `[[row]]` tables, if any (a TOML manifest's), are not used.
pub(crate) fn load_defaults(
    path: &Path,
    replay: &dyn ReplayCommand,
) -> Result<(Vec<Cell>, PathBuf)> {
    let text = gazelight_input::read_to_string(path, MAX_MANIFEST_BYTES)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let m: TomlManifest = toml::from_str(&text).map_err(|e| {
        let at = e
            .span()
            .map(|s| format!("line {}: ", toml_line(&text, s.start)));
        err!(
            "{}: {}{}",
            path.display(),
            at.unwrap_or_default(),
            first_line(e.message())
        )
    })?;
    let flags = replay.flags();
    let mut cells = Vec::with_capacity(m.defaults.len());
    for (k, v) in &m.defaults {
        let c = toml_cell(&text, k, v).map_err(|e| err!("{}: {e}", path.display()))?;
        if k == "id" || k == "recording" || ENTITIES.contains(&k.as_str()) {
            bail!(
                "{}: line {}: field {k}: each recording's own (from its file name), not [defaults]",
                path.display(),
                c.line
            );
        }
        check_field(k, &flags).map_err(|e| err!("{}: line {}: {e}", path.display(), c.line))?;
        cells.push(c);
    }
    let base = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let base = std::fs::canonicalize(base)
        .with_context(|| format!("cannot resolve the directory of {}", path.display()))?;
    Ok((cells, base))
}

/// The rows of a TOML manifest: (line of `[[row]]`, cells: the defaults
/// the row does not override, then the row's keys).
fn toml_rows(text: &str) -> Result<Vec<(usize, Vec<Cell>)>, String> {
    let line_of = |offset: usize| toml_line(text, offset);
    let m: TomlManifest = toml::from_str(text).map_err(|e| {
        let at = e.span().map(|s| format!("line {}: ", line_of(s.start)));
        format!("{}{}", at.unwrap_or_default(), first_line(e.message()))
    })?;
    let cell = |k: &str, v: &toml::Spanned<toml::Value>| toml_cell(text, k, v);
    let mut rows = Vec::with_capacity(m.row.len());
    for r in &m.row {
        let line = line_of(r.span().start);
        let table = r.get_ref();
        let mut cells = Vec::with_capacity(m.defaults.len() + table.len());
        for (k, v) in &m.defaults {
            if k == "id" || k == "recording" {
                return Err(format!(
                    "line {}: field {k}: belongs to each [[row]], not [defaults]",
                    line_of(v.span().start)
                ));
            }
            if !table.contains_key(k) {
                cells.push(cell(k, v)?);
            }
        }
        for (k, v) in table {
            cells.push(cell(k, v)?);
        }
        rows.push((line, cells));
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_replay::Fake;

    fn write(name: &str, text: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("gazelight-manifest-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    fn err(name: &str, text: &str) -> String {
        format!("{:#}", load(&write(name, text), &Fake).unwrap_err())
    }

    #[test]
    fn csv_rows_become_replay_arguments() {
        let p = write(
            "ok.csv",
            "# a study\nid,recording,fps,no_frames,size,from-secs\n\
             a,rec/one.asc,20,true,64x48,\n\"b\",/abs/two,,no,\"96x80\",1.5\n",
        );
        let rows = load(&p, &Fake).unwrap();
        let base = std::fs::canonicalize(p.parent().unwrap()).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].line, 3);
        assert_eq!(
            rows[0].argv,
            [
                base.join("rec/one.asc").display().to_string(),
                "--fps=20".to_owned(),
                "--no-frames".to_owned(),
                "--size=64x48".to_owned()
            ]
        );
        assert_eq!(
            rows[1].argv,
            ["/abs/two", "--size=96x80", "--from-secs=1.5"].map(String::from)
        );
        assert_eq!(rows[1].recording, "/abs/two");
    }

    #[test]
    fn toml_defaults_and_rows() {
        let p = write(
            "ok.toml",
            "[defaults]\nfps = 20\nno_frames = true\n\n[[row]]\nrecording = \"x.csv\"\n\n\
             [[row]]\nid = \"late\"\nrecording = \"/y.asc\"\nfps = 10.5\nno_frames = false\n",
        );
        let rows = load(&p, &Fake).unwrap();
        assert_eq!(rows[0].id, "001-x");
        assert_eq!(rows[0].line, 5);
        assert_eq!(&rows[0].argv[1..], ["--fps=20", "--no-frames"]);
        assert_eq!(rows[1].id, "late");
        assert_eq!(rows[1].argv, ["/y.asc", "--fps=10.5"]);
    }

    #[test]
    fn bad_rows_name_file_line_and_field() {
        let e = err("unknown.csv", "recording,speed\na.csv,3\n");
        assert!(
            e.contains("unknown.csv: line 1: field speed: not an option"),
            "{e}"
        );
        let e = err("value.csv", "recording,fps\na.csv,20\nb.csv,fast\n");
        assert!(e.contains("value.csv: line 3: field fps:"), "{e}");
        let e = err("range.csv", "recording,from_secs\na.csv,-2\n");
        assert!(e.contains("line 2: field from_secs: --from-secs -2"), "{e}");
        let e = err("switch.csv", "recording,stereo\na.csv,maybe\n");
        assert!(e.contains("line 2: field stereo: \"maybe\""), "{e}");
        let e = err("out.csv", "recording,out\na.csv,x\n");
        assert!(e.contains("line 1: field out: the batch sets --out"), "{e}");
        let e = err(
            "trace.toml",
            "[[row]]\nrecording = \"a\"\ntrace = \"t.csv\"\n",
        );
        assert!(
            e.contains("line 3: field trace: the batch sets --trace"),
            "{e}"
        );
        let e = err("short.csv", "recording,fps\na.csv\n");
        assert!(
            e.contains("line 2: 1 fields, the header (line 1) has 2"),
            "{e}"
        );
        let e = err("missing.csv", "id,recording\nx,\n");
        assert!(e.contains("line 2: field recording: missing"), "{e}");
        let e = err("dup.csv", "id,recording\nx,a\nx,b\n");
        assert!(
            e.contains("line 3: field id: \"x\" is already the id of line 2"),
            "{e}"
        );
        let e = err("badid.csv", "id,recording\n../x,a\n");
        assert!(e.contains("line 2: field id:"), "{e}");
        let e = err("quote.csv", "recording\n\"a.csv\n");
        assert!(e.contains("line 2: a quoted field is not closed"), "{e}");
        let e = err("bad.toml", "[[row]]\nrecording = \"a\"\nfps = [1]\n");
        assert!(e.contains("bad.toml: line 3: field fps: a array"), "{e}");
        let e = err("syntax.toml", "[[row]]\nrecording = \"a\"\nfps = \n");
        assert!(e.contains("syntax.toml: line 3"), "{e}");
        let e = err("val.toml", "[[row]]\nrecording = \"a\"\n\nsize = \"big\"\n");
        assert!(e.contains("val.toml: line 4: field size:"), "{e}");
        let dir = write("x", "").parent().unwrap().to_path_buf();
        let e = format!("{:#}", load(&dir, &Fake).unwrap_err());
        assert!(
            e.contains("a directory; give a CSV or TOML manifest"),
            "{e}"
        );
        let e = err("label.csv", "recording,subject\na.csv,s-1\n");
        assert!(e.contains("line 2: field subject: \"s-1\""), "{e}");
        let e = err("run.csv", "recording,run\na.csv,x\n");
        assert!(e.contains("line 2: field run: \"x\""), "{e}");
    }
}
