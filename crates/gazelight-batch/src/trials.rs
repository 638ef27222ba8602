//! `gazelight trials`: the per-trial table of a replay
//! (`gazelight_render::trials`, where the logic lives; Python calls the
//! same functions); `batch --trials` uses the same options
//! ([`TrialWindow`]) for every recording; docs/screen-experiment.md.

use std::path::{Path, PathBuf};

use gazelight_render::trials::{self, TrialOptions, TrialRow, TrialsError};

use crate::{Context as _, Result};

/// The options of a per-trial table besides its events pattern: shared
/// by `gazelight trials` and `gazelight batch --trials` (the binary's
/// `TrialWindowArgs`, whose flags they are).
#[derive(Clone, Debug)]
pub struct TrialWindow {
    /// `--baseline`: FROM..TO seconds from each onset.
    pub baseline: String,
    /// `--window`: the analysis window, FROM..TO seconds from each onset.
    pub window: String,
    /// `--max-invalid`: the largest share of a valid trial's window (and
    /// baseline) without a measured pupil.
    pub max_invalid: f64,
    /// `--eye`: left or right (a stereo replay's view), or none.
    pub eye: Option<String>,
}

/// What a table needs: the options and the timeline's column suffix.
#[derive(Clone, Debug)]
pub struct TrialSpec {
    pub options: TrialOptions,
    suffix: &'static str,
}

impl TrialWindow {
    /// The options for onsets matching `pattern`, checked.
    pub fn spec(&self, pattern: &str) -> Result<TrialSpec> {
        if !(0.0..=1.0).contains(&self.max_invalid) {
            bail!(
                "--max-invalid {}: expected a fraction from 0 to 1",
                self.max_invalid
            );
        }
        let suffix = match self.eye.as_deref() {
            None => "",
            Some("left") => "_left",
            Some("right") => "_right",
            Some(e) => bail!("--eye {e}: expected left or right"),
        };
        Ok(TrialSpec {
            options: TrialOptions {
                pattern: pattern.to_owned(),
                baseline_secs: trials::parse_range("--baseline", &self.baseline)?,
                window_secs: trials::parse_range("--window", &self.window)?,
                max_invalid_fraction: self.max_invalid,
            },
            suffix,
        })
    }
}

impl TrialSpec {
    /// The table of the replay in `dir` and its pupil unit.
    pub fn table(&self, dir: &Path) -> Result<(Vec<TrialRow>, &'static str), TrialsError> {
        trials::from_replay_dir(dir, self.suffix, &self.options)
    }
}

/// `gazelight trials`: the table of the replay in `dir`, its trials
/// opened by the events matching `events`, written to `out` (default
/// `dir/trials.csv`; `-` for standard output).
pub fn write_table(
    dir: &Path,
    events: &str,
    window: &TrialWindow,
    out: Option<&Path>,
) -> Result<()> {
    let spec = window.spec(events)?;
    let (rows, unit) = spec.table(dir)?;
    if rows.is_empty() {
        bail!(
            "{}: no event matches --events {:?} (see its events.csv's text column)",
            dir.join("events.csv").display(),
            events
        );
    }
    let csv = trials::to_csv(&rows, unit);
    let valid = rows.iter().filter(|r| r.valid).count();
    match out {
        Some(p) if p.as_os_str() == "-" => print!("{csv}"),
        out => {
            let path = out.map_or_else(|| dir.join("trials.csv"), PathBuf::from);
            std::fs::write(&path, csv).with_context(|| format!("writing {}", path.display()))?;
            println!(
                "wrote {}: {} trials ({valid} valid), pupil in {unit}",
                path.display(),
                rows.len()
            );
        }
    }
    Ok(())
}

/// One table parsed: recording, participant, header, rows.
type Parsed<'a> = (&'a str, &'a str, Vec<String>, Vec<Vec<String>>);

/// Joins per-recording tables (`(recording, participant, table CSV)`)
/// into one: `recording`, `participant`, then every column of the tables
/// in the order first seen (recordings with other `TRIAL_VAR`s or another
/// pupil unit leave the cells they lack empty).
pub fn combine(tables: &[(String, String, String)]) -> String {
    use gazelight_input::{csv_field, split_csv_line};
    let mut columns: Vec<String> = Vec::new();
    let parsed: Vec<Parsed<'_>> = tables
        .iter()
        .filter_map(|(rec, part, text)| {
            let mut lines = text.lines();
            let header = split_csv_line(lines.next()?, ',');
            for h in &header {
                if !columns.contains(h) {
                    columns.push(h.clone());
                }
            }
            let rows = lines.map(|l| split_csv_line(l, ',')).collect();
            Some((rec.as_str(), part.as_str(), header, rows))
        })
        .collect();
    let mut out = String::from("recording,participant");
    for c in &columns {
        out.push(',');
        out.push_str(&csv_field(c));
    }
    out.push('\n');
    for (rec, part, header, rows) in &parsed {
        for row in rows {
            out.push_str(&csv_field(rec));
            out.push(',');
            out.push_str(&csv_field(part));
            for c in &columns {
                out.push(',');
                let cell = header
                    .iter()
                    .position(|h| h == c)
                    .and_then(|i| row.get(i))
                    .map_or("", String::as_str);
                out.push_str(&csv_field(cell));
            }
            out.push('\n');
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_with_other_columns_are_joined_by_name() {
        let a = "index,event,baseline_mm,var_cond\n1,\"go, now\",3.5,dark\n2,go,3.6,bright\n";
        let b = "index,event,baseline_arbitrary\n1,go,812\n";
        let t = combine(&[
            ("s01".into(), "01".into(), a.into()),
            ("s02".into(), String::new(), b.into()),
        ]);
        assert_eq!(
            t,
            "recording,participant,index,event,baseline_mm,var_cond,baseline_arbitrary\n\
             s01,01,1,\"go, now\",3.5,dark,\n\
             s01,01,2,go,3.6,bright,\n\
             s02,,1,go,,,812\n"
        );
    }
}
