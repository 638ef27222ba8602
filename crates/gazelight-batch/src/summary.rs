//! One recording's line of the batch summary (`summary.csv`): what its
//! replay wrote (`timeline.csv`: frames, pupil, adaptation, light-driven
//! pupil and residual) and what its recording holds over the replayed
//! window (rates, dropout, blinks, through the replay's filter chain),
//! and the `warning:` lines its replay printed. Every value is a fixed-precision string, so the summary of the
//! same rows is the same file wherever it was computed (a local run, a
//! Slurm array's `--collect`).

use std::path::Path;

use crate::{ReplayInputs, Result};
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::import;
use gazelight_tracker::profile::PupilCalibration;
use gazelight_tracker::summary::Summarizer;

use gazelight_app::config::{ConfigUser, RenderConfig};

use crate::inspect_timeline::{Stats, TimelineReader, number};

/// The summary's columns after `id, recording, status, message`.
pub const COLUMNS: [&str; 27] = [
    "frames",
    "views",
    "duration_secs",
    "pupil_rate_right_hz",
    "pupil_rate_left_hz",
    "gaze_rate_hz",
    "dropout_right",
    "dropout_left",
    "blinks_right",
    "blinks_left",
    "blink_events",
    "pupil_measured_frames",
    "pupil_mean_mm",
    "pupil_sd_mm",
    "pupil_min_mm",
    "pupil_max_mm",
    "adaptation_min_cd_m2",
    "adaptation_max_cd_m2",
    "pupil_light_mean_mm",
    "pupil_light_min_mm",
    "pupil_light_max_mm",
    "residual_frames",
    "residual_mean_mm",
    "residual_sd_mm",
    "residual_min_mm",
    "residual_max_mm",
    "warnings",
];

/// What a replay's `timeline.csv` says, all views pooled.
#[derive(Clone, Debug, Default)]
pub struct TimelineFigures {
    pub frames: u64,
    pub views: usize,
    /// The last frame's time from the first, s.
    pub duration_secs: f64,
    pupil: Stats,
    /// Frames×views with a measured pupil (`pupil_held` 0), in mm or not.
    measured: u64,
    adaptation: Stats,
    light: Stats,
    residual: Stats,
}

/// Reads a replay's timeline (streamed; bad lines named).
pub fn read_timeline(path: &Path) -> Result<TimelineFigures> {
    let mut reader = TimelineReader::open(path)?;
    // Per view: pupil, held, adaptation, light, residual columns.
    let mut views = Vec::new();
    for suffix in ["", "_left", "_right"] {
        if let (Some(p), Some(h), Some(a)) = (
            reader.column(&format!("pupil_mm{suffix}")),
            reader.column(&format!("pupil_held{suffix}")),
            reader.column(&format!("adaptation_cd_m2{suffix}")),
        ) {
            let l = reader.column(&format!("pupil_light_mm{suffix}"));
            let r = reader.column(&format!("pupil_residual_mm{suffix}"));
            views.push((p, h, a, l, r));
        }
    }
    if reader.header().first().map(String::as_str) != Some("t_secs") || views.is_empty() {
        bail!(
            "{}: not a gazelight timeline (t_secs, pupil_mm, pupil_held, adaptation_cd_m2 columns)",
            path.display()
        );
    }
    let mut f = TimelineFigures {
        views: views.len(),
        ..TimelineFigures::default()
    };
    while let Some(cells) = reader.next_row()? {
        let num = |i: usize| number(&cells, i);
        f.frames += 1;
        if let Some(t) = num(0) {
            f.duration_secs = t;
        }
        for &(p, h, a, l, r) in &views {
            // Measured where `pupil_held` is 0 (an eye the recording does
            // not have has an empty cell: not counted); the mm figures
            // from the frames whose pupil is in mm.
            if num(h) == Some(0.0) {
                f.measured += 1;
                if let Some(pv) = num(p) {
                    f.pupil.add(pv);
                }
            }
            if let Some(v) = num(a) {
                f.adaptation.add(v);
            }
            if let Some(v) = l.and_then(num) {
                f.light.add(v);
            }
            if let Some(v) = r.and_then(num) {
                f.residual.add(v);
            }
        }
    }
    Ok(f)
}

/// What the recording holds over the replayed window.
#[derive(Clone, Debug, Default)]
pub struct RecordingFigures {
    pub pupil_rate_hz: [f64; 2],
    pub gaze_rate_hz: f64,
    pub dropout: [f64; 2],
    pub blinks: [u64; 2],
    pub blink_events: u64,
}

/// Summarises the recording of `args` over `[t0, t0 + duration_secs]`
/// (t0 = its first sample + `--from-secs`), through the filter chain the
/// replay ran (the configuration's `[filter]`, the calibration profile).
pub fn read_recording(args: &ReplayInputs, duration_secs: f64) -> Result<RecordingFigures> {
    let config = match &args.config {
        Some(p) => RenderConfig::load(p, ConfigUser::Replay)?,
        None => RenderConfig::default(),
    };
    let calibration = match args.calibration.as_ref().or(config.calibration.as_ref()) {
        Some(p) => Some(PupilCalibration::load(p)?),
        None => None,
    };
    let path = &args.recording;
    // Pass 1: the first sample's time.
    let mut t_first = f64::INFINITY;
    for s in import::open(path)? {
        match s {
            Ok(s) if s.t_secs().is_finite() => t_first = t_first.min(s.t_secs()),
            Ok(_) => {}
            Err(_) => break,
        }
    }
    if !t_first.is_finite() {
        bail!("{}: no readable samples", path.display());
    }
    let t0 = t_first + args.from_secs;
    let t1 = t0 + duration_secs;
    let mut chain = FilterChain::new(config.filter, PupilCalibration::identity())
        .map_err(|e| err!("filter configuration: {e}"))?;
    if let Some(c) = &calibration {
        chain.set_calibration(c.clone());
    }
    let mut summarizer = Summarizer::new(chain);
    let mut importer = import::open(path)?;
    for s in importer.by_ref() {
        let Ok(s) = s else { break };
        let t = s.t_secs();
        if !(t >= t0 && t <= t1) {
            continue;
        }
        summarizer.push(&s);
    }
    let summary = summarizer.finish(Some(importer.format()), importer.warnings());
    Ok(RecordingFigures {
        pupil_rate_hz: summary.rate_hz.pupil,
        gaze_rate_hz: summary.rate_hz.gaze,
        dropout: [
            summary.pupil[0].dropout_fraction,
            summary.pupil[1].dropout_fraction,
        ],
        blinks: summary.blinks.detected,
        blink_events: summary.blinks.recording.iter().sum(),
    })
}

fn fixed(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v:.digits$}"),
        _ => String::new(),
    }
}

/// The `warning:` lines a row's replay printed (its log, `text`): what
/// the run told its user, each warning once.
pub fn count_warnings(text: &str) -> usize {
    text.lines()
        .filter(|l| l.trim_start().starts_with("warning:"))
        .count()
}

/// The row's values in [`COLUMNS`] order; `warnings` from
/// [`count_warnings`] on its replay's log.
pub fn values(t: &TimelineFigures, r: &RecordingFigures, warnings: usize) -> Vec<String> {
    let mm = |v: Option<f64>| fixed(v, 4);
    let cd = |v: Option<f64>| match v {
        Some(v) if v.is_finite() => format!("{v:.6e}"),
        _ => String::new(),
    };
    vec![
        t.frames.to_string(),
        t.views.to_string(),
        fixed(Some(t.duration_secs), 4),
        fixed(Some(r.pupil_rate_hz[0]), 3),
        fixed(Some(r.pupil_rate_hz[1]), 3),
        fixed(Some(r.gaze_rate_hz), 3),
        fixed(Some(r.dropout[0]), 4),
        fixed(Some(r.dropout[1]), 4),
        r.blinks[0].to_string(),
        r.blinks[1].to_string(),
        r.blink_events.to_string(),
        t.measured.to_string(),
        mm(t.pupil.mean()),
        mm(t.pupil.sd()),
        mm(t.pupil.min()),
        mm(t.pupil.max()),
        cd(t.adaptation.min()),
        cd(t.adaptation.max()),
        mm(t.light.mean()),
        mm(t.light.min()),
        mm(t.light.max()),
        t.residual.count().to_string(),
        mm(t.residual.mean()),
        mm(t.residual.sd()),
        mm(t.residual.min()),
        mm(t.residual.max()),
        warnings.to_string(),
    ]
}

/// One CSV cell, quoted when it holds a comma, a quote or a line break.
pub fn csv_cell(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\"").replace(['\n', '\r'], " "))
    } else {
        s.to_owned()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hand-made timeline: measured pupils 4, 5, 6 mm (mean 5, SD 1), a
    /// held frame left out; adaptation 0.01 … 2 cd/m²; residuals 0.1,
    /// −0.1, 0 (mean 0, SD 0.1).
    #[test]
    fn timeline_figures_from_a_known_timeline() {
        let dir = std::env::temp_dir().join(format!("gazelight-batch-tl-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("timeline.csv");
        std::fs::write(
            &p,
            "t_secs,gaze_u,gaze_v,pupil_mm,pupil_held,target_cd_m2,adaptation_cd_m2,pupil_light_mm,pupil_residual_mm\n\
             0.0000,0.5,0.5,4,0,1,1.0e-2,3.9,0.1\n\
             0.0500,0.5,0.5,5,0,1,2.0e0,5.1,-0.1\n\
             0.1000,0.5,0.5,6,0,1,5.0e-1,6.0,0\n\
             0.1500,0.5,0.5,7,1,1,5.0e-1,6.5,\n",
        )
        .unwrap();
        let t = read_timeline(&p).unwrap();
        let v = values(&t, &RecordingFigures::default(), 2);
        let get = |name: &str| v[COLUMNS.iter().position(|c| *c == name).unwrap()].clone();
        assert_eq!(get("frames"), "4");
        assert_eq!(get("duration_secs"), "0.1500");
        assert_eq!(get("pupil_measured_frames"), "3");
        assert_eq!(get("pupil_mean_mm"), "5.0000");
        assert_eq!(get("pupil_sd_mm"), "1.0000");
        assert_eq!(
            (get("pupil_min_mm"), get("pupil_max_mm")),
            ("4.0000".into(), "6.0000".into())
        );
        assert_eq!(get("adaptation_min_cd_m2"), "1.000000e-2");
        assert_eq!(get("adaptation_max_cd_m2"), "2.000000e0");
        assert_eq!(get("pupil_light_min_mm"), "3.9000");
        assert_eq!(get("pupil_light_max_mm"), "6.5000");
        assert_eq!(get("residual_frames"), "3");
        assert_eq!(get("residual_mean_mm"), "0.0000");
        assert_eq!(get("residual_sd_mm"), "0.1000");
        assert_eq!(get("warnings"), "2");
        // A short row is named.
        std::fs::write(&p, "t_secs,pupil_mm,pupil_held,adaptation_cd_m2\n0,4,0\n").unwrap();
        let e = read_timeline(&p).unwrap_err().to_string();
        assert!(e.contains("(line 2): 3 cells, the header has 4"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn warnings_are_the_replays_warning_lines() {
        let log = "2026-12-07T11:46:34Z  WARN gazelight::replay: not in mm\n\
                   replay: 41 frames\n\
                   warning: a.asc: raw unit\n\
                   note: a warning: is not one here\n\
                   warning: a.asc: events: cut\n";
        assert_eq!(count_warnings(log), 2);
        assert_eq!(count_warnings(""), 0);
    }

    #[test]
    fn cells_with_commas_are_quoted() {
        assert_eq!(csv_cell("plain"), "plain");
        assert_eq!(csv_cell("a, \"b\""), "\"a, \"\"b\"\"\"");
    }
}
