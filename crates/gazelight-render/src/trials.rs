//! The per-trial table of a replay (`gazelight trials`, Python's
//! `gazelight.trials`): one row per event that opens a trial, with the
//! trial's fields, the subtractive baseline (Mathôt, Fabius, Van Heusden &
//! Van der Stigchel 2018, *Safe and sensible preprocessing and baseline
//! correction of pupil-size data*, Behav Res Methods 50:94–106: the mean
//! pupil in a short window before the onset, subtracted from every sample
//! after it), the peak and mean dilation over the analysis window, the
//! light-driven and residual pupil's mean over the window (the replay's
//! `pupil_light_mm` and `pupil_residual_mm` columns) and the residual's
//! own baseline-corrected mean and peak, the fraction of the window
//! without a measured pupil (blink, dropout, held or interpolated) and a
//! validity flag.
//!
//! It reads what a replay wrote: `timeline.csv` (one row per frame, the
//! first frame at `t_secs` 0) and `events.csv` (every event with its
//! `t_secs` on the same clock, its `trial` and text). A trial's fields
//! are the onset event's text and trial id, and each `!V TRIAL_VAR name
//! value` message of that trial (EyeLink) as a `var_name` column.
//!
//! Everything here is a function of the two tables, so the CLI and Python
//! give the same numbers.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// The largest `timeline.csv` or `events.csv` read, bytes (a day at
/// 120 fps stereo with every column is about 4 GiB; beyond that split it).
const MAX_TABLE_BYTES: u64 = 8 << 30;

/// What can go wrong in building the per-trial table.
#[derive(Debug, thiserror::Error)]
pub enum TrialsError {
    /// A file cannot be read.
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    /// A table lacks a column this needs.
    #[error("{path}: no `{column}` column (expected a replay's {what})")]
    Column {
        path: String,
        column: String,
        what: &'static str,
    },
    /// A value cannot be read.
    #[error("{path}: line {line}: `{column}`: cannot read {value:?} as a number")]
    Value {
        path: String,
        line: usize,
        column: String,
        value: String,
    },
    /// A flag's value.
    #[error("{0}")]
    Flag(String),
}

/// One view's series from `timeline.csv`.
#[derive(Clone, Debug, Default)]
pub struct TimelineSeries {
    /// Seconds from the replay's first frame.
    pub t_secs: Vec<f64>,
    /// The measured pupil (`pupil_mm`, else `pupil_raw` where the
    /// recording has no millimetres); NaN where not measured.
    pub pupil: Vec<f64>,
    /// `"mm"` or `"raw"`: which column `pupil` is.
    pub pupil_unit: &'static str,
    /// `pupil_light_mm` (NaN without the light response).
    pub pupil_light_mm: Vec<f64>,
    /// `pupil_residual_mm` (NaN where the pupil is not measured).
    pub pupil_residual_mm: Vec<f64>,
    /// `pupil_held`: the pupil was held or filled in, not measured.
    pub held: Vec<bool>,
}

/// One row of `events.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct EventRow {
    /// Seconds from the replay's first frame.
    pub t_secs: f64,
    pub text: String,
    /// The trial id (EyeLink `TRIALID`), empty where none.
    pub trial: String,
}

/// How the table is made.
#[derive(Clone, Debug)]
pub struct TrialOptions {
    /// Which events open a trial: `*` matches any run of characters; a
    /// pattern without `*` matches texts that start with it.
    pub pattern: String,
    /// The baseline window, seconds from the onset (default −0.2..0).
    pub baseline_secs: [f64; 2],
    /// The analysis window, seconds from the onset (default 0..3).
    pub window_secs: [f64; 2],
    /// A trial is valid when at most this share of its window, and of its
    /// baseline, lacks a measured pupil (default 0.5: a choice, not a
    /// published value; a study sets its own exclusion rule).
    pub max_invalid_fraction: f64,
}

impl Default for TrialOptions {
    fn default() -> Self {
        Self {
            pattern: String::new(),
            baseline_secs: [-0.2, 0.0],
            window_secs: [0.0, 3.0],
            max_invalid_fraction: 0.5,
        }
    }
}

/// One trial.
#[derive(Clone, Debug, Default)]
pub struct TrialRow {
    /// 1, 2, … in time order.
    pub index: usize,
    /// The onset event's time, seconds from the replay's first frame.
    pub onset_secs: f64,
    pub event: String,
    pub trial: String,
    /// `TRIAL_VAR` name → value of the onset's trial.
    pub vars: BTreeMap<String, String>,
    /// Mean measured pupil over the baseline (mm, or the raw unit).
    pub baseline: f64,
    /// Peak and mean of (pupil − baseline) over the window.
    pub peak_dilation: f64,
    pub mean_dilation: f64,
    /// Mean `pupil_light_mm` and `pupil_residual_mm` over the window.
    pub light_mean_mm: f64,
    pub residual_mean_mm: f64,
    /// Mean and peak of (residual − the residual's baseline mean) over the
    /// window: the dilation the light does not explain.
    pub residual_dilation_mm: f64,
    pub residual_peak_dilation_mm: f64,
    /// Frames in the window, and the share of them without a measured
    /// pupil (blink, dropout, held or interpolated).
    pub window_frames: usize,
    pub invalid_fraction: f64,
    pub valid: bool,
}

/// Whether `text` matches `pattern` (see [`TrialOptions::pattern`]).
pub fn matches(pattern: &str, text: &str) -> bool {
    if !pattern.contains('*') {
        return text.starts_with(pattern);
    }
    // Glob with `*` only: the parts in order, the first anchored at the
    // start and the last at the end.
    let parts: Vec<&str> = pattern.split('*').collect();
    let mut rest = text;
    for (i, part) in parts.iter().enumerate() {
        if i == 0 {
            match rest.strip_prefix(part) {
                Some(r) => rest = r,
                None => return false,
            }
        } else if i == parts.len() - 1 {
            return rest.ends_with(part);
        } else {
            match rest.find(part) {
                Some(k) => rest = &rest[k + part.len()..],
                None => return false,
            }
        }
    }
    rest.is_empty()
}

/// `FROM..TO` in seconds (FROM < TO).
pub fn parse_range(flag: &str, s: &str) -> Result<[f64; 2], TrialsError> {
    let bad = || {
        TrialsError::Flag(format!(
            "{flag} {s}: expected FROM..TO in seconds from the onset, FROM < TO (e.g. -0.2..0)"
        ))
    };
    let (a, b) = s.split_once("..").ok_or_else(bad)?;
    let a: f64 = a.trim().parse().map_err(|_| bad())?;
    let b: f64 = b.trim().parse().map_err(|_| bad())?;
    if !(a.is_finite() && b.is_finite() && a < b) {
        return Err(bad());
    }
    Ok([a, b])
}

fn read_text(path: &Path) -> Result<String, TrialsError> {
    gazelight_input::read_to_string(path, MAX_TABLE_BYTES).map_err(|source| TrialsError::Io {
        path: path.display().to_string(),
        source,
    })
}

fn number(path: &Path, line: usize, column: &str, v: &str) -> Result<f64, TrialsError> {
    let v = v.trim();
    if v.is_empty() || v.eq_ignore_ascii_case("nan") {
        return Ok(f64::NAN);
    }
    v.parse().map_err(|_| TrialsError::Value {
        path: path.display().to_string(),
        line,
        column: column.to_owned(),
        value: v.to_owned(),
    })
}

/// Reads one view of `timeline.csv` (`suffix`: `""` for a mono replay,
/// `"_left"`/`"_right"` for a stereo one's eyes).
pub fn read_timeline(path: &Path, suffix: &str) -> Result<TimelineSeries, TrialsError> {
    let text = read_text(path)?;
    let mut lines = text.lines().enumerate();
    let header = lines
        .next()
        .map(|(_, l)| gazelight_input::split_csv_line(l, ','))
        .unwrap_or_default();
    let find = |name: &str| header.iter().position(|h| h == name);
    let need = |name: &str| {
        find(name).ok_or_else(|| TrialsError::Column {
            path: path.display().to_string(),
            column: name.to_owned(),
            what: "timeline.csv",
        })
    };
    let col = |base: &str| format!("{base}{suffix}");
    let t_col = need("t_secs")?;
    let mm_col = find(&col("pupil_mm"));
    let raw_col = find(&col("pupil_raw"));
    let light_col = find(&col("pupil_light_mm"));
    let residual_col = find(&col("pupil_residual_mm"));
    let held_col = find(&col("pupil_held"));
    if mm_col.is_none() && raw_col.is_none() {
        need(&col("pupil_mm"))?;
    }
    let mut s = TimelineSeries::default();
    let mut mm = Vec::new();
    let mut raw = Vec::new();
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let f = gazelight_input::split_csv_line(line, ',');
        let get = |c: Option<usize>, name: &str| -> Result<f64, TrialsError> {
            match c.and_then(|c| f.get(c)) {
                Some(v) => number(path, i + 1, name, v),
                None => Ok(f64::NAN),
            }
        };
        let t = get(Some(t_col), "t_secs")?;
        if !t.is_finite() {
            continue;
        }
        s.t_secs.push(t);
        mm.push(get(mm_col, "pupil_mm")?);
        raw.push(get(raw_col, "pupil_raw")?);
        s.pupil_light_mm.push(get(light_col, "pupil_light_mm")?);
        s.pupil_residual_mm
            .push(get(residual_col, "pupil_residual_mm")?);
        let held = held_col
            .and_then(|c| f.get(c))
            .is_some_and(|v| matches!(v.trim(), "1" | "true"));
        s.held.push(held);
    }
    if mm.iter().any(|v| v.is_finite()) {
        s.pupil = mm;
        s.pupil_unit = "mm";
    } else {
        s.pupil = raw;
        s.pupil_unit = "raw";
    }
    Ok(s)
}

/// Reads `events.csv` (`t_secs`, `text`, `trial`).
pub fn read_events(path: &Path) -> Result<Vec<EventRow>, TrialsError> {
    let text = read_text(path)?;
    let mut lines = text.lines().enumerate();
    let header = lines
        .next()
        .map(|(_, l)| gazelight_input::split_csv_line(l, ','))
        .unwrap_or_default();
    let need = |name: &str| {
        header
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| TrialsError::Column {
                path: path.display().to_string(),
                column: name.to_owned(),
                what: "events.csv",
            })
    };
    let (t_col, text_col) = (need("t_secs")?, need("text")?);
    let trial_col = header.iter().position(|h| h == "trial");
    let mut out = Vec::new();
    for (i, line) in lines {
        if line.is_empty() {
            continue;
        }
        let f = gazelight_input::split_csv_line(line, ',');
        let t = number(
            path,
            i + 1,
            "t_secs",
            f.get(t_col).map_or("", String::as_str),
        )?;
        out.push(EventRow {
            t_secs: t,
            text: f.get(text_col).cloned().unwrap_or_default(),
            trial: trial_col
                .and_then(|c| f.get(c))
                .cloned()
                .unwrap_or_default(),
        });
    }
    Ok(out)
}

/// Each trial's `TRIAL_VAR`s from its `!V TRIAL_VAR name value` messages.
fn trial_vars(events: &[EventRow]) -> BTreeMap<String, BTreeMap<String, String>> {
    let mut out: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
    for e in events {
        if let Some(rest) = e.text.strip_prefix("!V TRIAL_VAR ") {
            let mut it = rest.trim().splitn(2, char::is_whitespace);
            if let Some(name) = it.next().filter(|n| !n.is_empty()) {
                let value = it.next().unwrap_or("").trim().to_owned();
                out.entry(e.trial.clone())
                    .or_default()
                    .insert(name.to_owned(), value);
            }
        }
    }
    out
}

/// Frames with `t_secs` in `[from, to)`.
fn span(t: &[f64], from: f64, to: f64) -> std::ops::Range<usize> {
    let a = t.partition_point(|x| *x < from);
    let b = t.partition_point(|x| *x < to);
    a..b.max(a)
}

fn mean(it: impl Iterator<Item = f64>) -> (f64, usize) {
    let (mut s, mut n) = (0.0, 0usize);
    for v in it.filter(|v| v.is_finite()) {
        s += v;
        n += 1;
    }
    (if n > 0 { s / n as f64 } else { f64::NAN }, n)
}

fn peak(it: impl Iterator<Item = f64>) -> f64 {
    it.filter(|v| v.is_finite()).fold(f64::NAN, f64::max)
}

/// The per-trial table: one row per event matching the pattern, in time
/// order.
pub fn trial_table(
    timeline: &TimelineSeries,
    events: &[EventRow],
    options: &TrialOptions,
) -> Vec<TrialRow> {
    let vars = trial_vars(events);
    let t = &timeline.t_secs;
    let measured = |k: usize| timeline.pupil[k].is_finite() && !timeline.held[k];
    let mut onsets: Vec<&EventRow> = events
        .iter()
        .filter(|e| e.t_secs.is_finite() && matches(&options.pattern, &e.text))
        .collect();
    onsets.sort_by(|a, b| a.t_secs.total_cmp(&b.t_secs));
    let mut rows = Vec::with_capacity(onsets.len());
    for (i, e) in onsets.into_iter().enumerate() {
        let [b0, b1] = options.baseline_secs;
        let [w0, w1] = options.window_secs;
        let base = span(t, e.t_secs + b0, e.t_secs + b1);
        let win = span(t, e.t_secs + w0, e.t_secs + w1);
        let clean = |r: std::ops::Range<usize>| r.filter(move |k| measured(*k));
        let (baseline, base_n) = mean(clean(base.clone()).map(|k| timeline.pupil[k]));
        let (residual_base, _) = mean(clean(base.clone()).map(|k| timeline.pupil_residual_mm[k]));
        let dil = |k: usize| timeline.pupil[k] - baseline;
        let rdil = |k: usize| timeline.pupil_residual_mm[k] - residual_base;
        let (mean_dilation, win_n) = mean(clean(win.clone()).map(dil));
        let window_frames = win.len();
        let invalid_fraction = if window_frames > 0 {
            1.0 - win_n as f64 / window_frames as f64
        } else {
            1.0
        };
        let base_invalid = if base.is_empty() {
            1.0
        } else {
            1.0 - base_n as f64 / base.len() as f64
        };
        let max = options.max_invalid_fraction;
        rows.push(TrialRow {
            index: i + 1,
            onset_secs: e.t_secs,
            event: e.text.clone(),
            trial: e.trial.clone(),
            vars: vars.get(&e.trial).cloned().unwrap_or_default(),
            baseline,
            peak_dilation: peak(clean(win.clone()).map(dil)),
            mean_dilation,
            light_mean_mm: mean(win.clone().map(|k| timeline.pupil_light_mm[k])).0,
            residual_mean_mm: mean(clean(win.clone()).map(|k| timeline.pupil_residual_mm[k])).0,
            residual_dilation_mm: mean(clean(win.clone()).map(rdil)).0,
            residual_peak_dilation_mm: peak(clean(win.clone()).map(rdil)),
            window_frames,
            invalid_fraction,
            valid: window_frames > 0
                && baseline.is_finite()
                && invalid_fraction <= max
                && base_invalid <= max,
        });
    }
    rows
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}

fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.6}")
    } else {
        String::new()
    }
}

/// The table as CSV; `unit` is the pupil's (`"mm"` or `"raw"`), in the
/// baseline and dilation columns' names.
pub fn to_csv(rows: &[TrialRow], unit: &str) -> String {
    let mut names: Vec<&String> = rows.iter().flat_map(|r| r.vars.keys()).collect();
    names.sort();
    names.dedup();
    let mut s = format!(
        "index,onset_secs,event,trial,baseline_{unit},peak_dilation_{unit},mean_dilation_{unit},\
         pupil_light_mean_mm,pupil_residual_mean_mm,residual_dilation_mm,\
         residual_peak_dilation_mm,window_frames,invalid_fraction,valid"
    );
    for n in &names {
        let _ = write!(s, ",var_{}", csv_field(n));
    }
    s.push('\n');
    for r in rows {
        let _ = write!(
            s,
            "{},{:.6},{},{},{},{},{},{},{},{},{},{},{:.4},{}",
            r.index,
            r.onset_secs,
            csv_field(&r.event),
            csv_field(&r.trial),
            num(r.baseline),
            num(r.peak_dilation),
            num(r.mean_dilation),
            num(r.light_mean_mm),
            num(r.residual_mean_mm),
            num(r.residual_dilation_mm),
            num(r.residual_peak_dilation_mm),
            r.window_frames,
            r.invalid_fraction,
            u8::from(r.valid)
        );
        for n in &names {
            let v = r.vars.get(*n).map_or("", String::as_str);
            let _ = write!(s, ",{}", csv_field(v));
        }
        s.push('\n');
    }
    s
}

/// A replay's folder (`timeline.csv` and `events.csv`) → the table, for
/// the view `suffix`; returns the rows and the pupil's unit.
pub fn from_replay_dir(
    dir: &Path,
    suffix: &str,
    options: &TrialOptions,
) -> Result<(Vec<TrialRow>, &'static str), TrialsError> {
    let timeline = read_timeline(&dir.join("timeline.csv"), suffix)?;
    let events = read_events(&dir.join("events.csv"))?;
    Ok((
        trial_table(&timeline, &events, options),
        timeline.pupil_unit,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns() {
        assert!(matches("TRIALID", "TRIALID 3"));
        assert!(!matches("TRIALID", "x TRIALID"));
        assert!(matches("*onset*", "stim onset dark"));
        assert!(matches("target *", "target bright"));
        assert!(!matches("target *x", "target bright"));
    }

    /// A hand-made timeline: pupil 4 mm, +0.5 mm from 1 s to 2 s after an
    /// onset at 1 s; one blink frame in the window.
    #[test]
    fn baseline_and_dilation_by_hand() {
        let t: Vec<f64> = (0..40).map(|k| k as f64 * 0.1).collect();
        let pupil: Vec<f64> = t
            .iter()
            .map(|t| if (2.0..3.0).contains(t) { 4.5 } else { 4.0 })
            .collect();
        let mut s = TimelineSeries {
            pupil_light_mm: vec![4.0; t.len()],
            pupil_residual_mm: pupil.iter().map(|p| p - 4.0).collect(),
            held: vec![false; t.len()],
            pupil,
            t_secs: t,
            pupil_unit: "mm",
        };
        s.pupil[15] = f64::NAN;
        let ev = vec![EventRow {
            t_secs: 1.0,
            text: "go".into(),
            trial: String::new(),
        }];
        let rows = trial_table(
            &s,
            &ev,
            &TrialOptions {
                pattern: "go".into(),
                window_secs: [0.0, 2.0],
                ..TrialOptions::default()
            },
        );
        assert_eq!(rows.len(), 1);
        let r = &rows[0];
        assert!((r.baseline - 4.0).abs() < 1e-12);
        assert!((r.peak_dilation - 0.5).abs() < 1e-12);
        // 20 frames, 19 measured, 10 of them at +0.5.
        assert_eq!(r.window_frames, 20);
        assert!((r.invalid_fraction - 0.05).abs() < 1e-12);
        assert!((r.mean_dilation - 5.0 / 19.0).abs() < 1e-12);
        assert!((r.residual_dilation_mm - 5.0 / 19.0).abs() < 1e-12);
        assert!(r.valid);
    }
}
