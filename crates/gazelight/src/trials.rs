//! `gazelight trials`: the per-trial table of a replay
//! (`gazelight_render::trials`, where the logic lives; Python calls the
//! same functions); `batch --trials` uses the same options
//! ([`TrialWindowArgs`]) for every recording; docs/screen-experiment.md.

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use clap::Args;
use gazelight_render::trials::{self, TrialOptions, TrialRow};

/// The options of a per-trial table besides its events pattern: shared
/// by `gazelight trials` and `gazelight batch --trials`.
#[derive(Args, Clone, Debug)]
pub struct TrialWindowArgs {
    /// The baseline, FROM..TO seconds from each onset (subtractive:
    /// Mathôt et al. 2018).
    #[arg(
        long,
        value_name = "FROM..TO",
        default_value = "-0.2..0",
        allow_hyphen_values = true
    )]
    pub baseline: String,
    /// The analysis window, FROM..TO seconds from each onset.
    #[arg(
        long,
        value_name = "FROM..TO",
        default_value = "0..3",
        allow_hyphen_values = true
    )]
    pub window: String,
    /// A trial is valid when at most this share of its window (and of its
    /// baseline) has no measured pupil.
    #[arg(long, value_name = "FRACTION", default_value_t = 0.5)]
    pub max_invalid: f64,
    /// Which view of a stereo replay: left or right (default: a mono
    /// replay's one view).
    #[arg(long, value_name = "EYE")]
    pub eye: Option<String>,
}

/// What a table needs: the options and the timeline's column suffix.
#[derive(Clone, Debug)]
pub struct TrialSpec {
    pub options: TrialOptions,
    suffix: &'static str,
}

impl TrialWindowArgs {
    /// The options for onsets matching `pattern`, checked.
    pub fn spec(&self, pattern: &str) -> anyhow::Result<TrialSpec> {
        if !(0.0..=1.0).contains(&self.max_invalid) {
            anyhow::bail!(
                "--max-invalid {}: expected a fraction from 0 to 1",
                self.max_invalid
            );
        }
        let suffix = match self.eye.as_deref() {
            None => "",
            Some("left") => "_left",
            Some("right") => "_right",
            Some(e) => anyhow::bail!("--eye {e}: expected left or right"),
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
    pub fn table(&self, dir: &Path) -> anyhow::Result<(Vec<TrialRow>, &'static str)> {
        Ok(trials::from_replay_dir(dir, self.suffix, &self.options)?)
    }
}

/// Arguments of `gazelight trials`.
#[derive(Args, Debug)]
pub struct TrialsArgs {
    /// A replay's output folder (its `timeline.csv` and `events.csv`).
    #[arg(value_name = "REPLAY_DIR")]
    pub dir: PathBuf,
    /// Which events open a trial: `*` matches any run of characters; a
    /// pattern without `*` matches the texts that start with it.
    #[arg(long, value_name = "PATTERN")]
    pub events: String,
    #[command(flatten)]
    pub window: TrialWindowArgs,
    /// Where to write the table (default REPLAY_DIR/trials.csv; `-` for
    /// standard output).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

/// Runs `gazelight trials`.
pub fn run(args: TrialsArgs) -> anyhow::Result<()> {
    let spec = args.window.spec(&args.events)?;
    let (rows, unit) = spec.table(&args.dir)?;
    if rows.is_empty() {
        anyhow::bail!(
            "{}: no event matches --events {:?} (see its events.csv's text column)",
            args.dir.join("events.csv").display(),
            args.events
        );
    }
    let csv = trials::to_csv(&rows, unit);
    let valid = rows.iter().filter(|r| r.valid).count();
    match args.out.as_deref() {
        Some(p) if p.as_os_str() == "-" => print!("{csv}"),
        out => {
            let path = out.map_or_else(|| args.dir.join("trials.csv"), PathBuf::from);
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
