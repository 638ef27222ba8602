//! `gazelight inspect TIMELINE.csv`: what a render, replay or run wrote,
//! summarised: per view, the spread of the measured pupil and of its
//! residual after the pupil light response (docs/pupil-light-response.md).
//! Streams the file row by row (memory does not grow with its length).

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

use crate::{Context, Result};
use serde::Serialize;

/// Longest line read, bytes (a stereo row is a few hundred).
const MAX_LINE_BYTES: u64 = 64 << 10;

/// Running mean, variance, minimum and maximum (Welford); shared with the
/// batch summary ([`crate::summary`]).
#[derive(Clone, Copy, Debug)]
pub struct Stats {
    n: u64,
    mean: f64,
    m2: f64,
    min: f64,
    max: f64,
}

impl Default for Stats {
    fn default() -> Self {
        Self {
            n: 0,
            mean: 0.0,
            m2: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
        }
    }
}

impl Stats {
    pub fn add(&mut self, x: f64) {
        self.n += 1;
        let d = x - self.mean;
        self.mean += d / self.n as f64;
        self.m2 += d * (x - self.mean);
        self.min = self.min.min(x);
        self.max = self.max.max(x);
    }
    /// How many values were added.
    pub fn count(&self) -> u64 {
        self.n
    }
    pub fn mean(&self) -> Option<f64> {
        (self.n > 0).then_some(self.mean)
    }
    /// The sample standard deviation (n − 1).
    pub fn sd(&self) -> Option<f64> {
        (self.n > 1).then(|| (self.m2 / (self.n - 1) as f64).sqrt())
    }
    pub fn min(&self) -> Option<f64> {
        (self.n > 0).then_some(self.min)
    }
    pub fn max(&self) -> Option<f64> {
        (self.n > 0).then_some(self.max)
    }
}

/// A timeline CSV read row by row: bounded lines, each row checked
/// against the header's cell count, errors naming the file and line.
/// Shared with the batch summary.
pub struct TimelineReader {
    path: PathBuf,
    reader: BufReader<std::fs::File>,
    line: String,
    line_no: u64,
    header: Vec<String>,
}

impl TimelineReader {
    /// Opens `path` and reads its header.
    pub fn open(path: &Path) -> Result<Self> {
        let file =
            std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
        let mut r = Self {
            path: path.to_owned(),
            reader: BufReader::new(file),
            line: String::new(),
            line_no: 0,
            header: Vec::new(),
        };
        if !r.read_line()? {
            bail!("{}: empty", path.display());
        }
        r.header = r.line.trim_end().split(',').map(str::to_owned).collect();
        Ok(r)
    }

    fn read_line(&mut self) -> Result<bool> {
        self.line.clear();
        self.line_no += 1;
        let no = self.line_no;
        let n = self
            .reader
            .by_ref()
            .take(MAX_LINE_BYTES)
            .read_line(&mut self.line)
            .with_context(|| format!("{} (line {no})", self.path.display()))?;
        if n as u64 == MAX_LINE_BYTES && !self.line.ends_with('\n') {
            bail!(
                "{} (line {no}): longer than {MAX_LINE_BYTES} bytes",
                self.path.display()
            );
        }
        Ok(n > 0)
    }

    /// The header's column names.
    pub fn header(&self) -> &[String] {
        &self.header
    }

    /// The index of the column `name`.
    pub fn column(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    /// The next row's cells; `None` at the end of the file.
    pub fn next_row(&mut self) -> Result<Option<Vec<&str>>> {
        if !self.read_line()? {
            return Ok(None);
        }
        let cells: Vec<&str> = self.line.trim_end().split(',').collect();
        if cells.len() != self.header.len() {
            bail!(
                "{} (line {}): {} cells, the header has {}",
                self.path.display(),
                self.line_no,
                cells.len(),
                self.header.len()
            );
        }
        Ok(Some(cells))
    }
}

/// Cell `i` as a finite number (an empty or non-finite cell is `None`).
pub fn number(cells: &[&str], i: usize) -> Option<f64> {
    cells
        .get(i)
        .and_then(|c| c.parse::<f64>().ok())
        .filter(|v| v.is_finite())
}

/// One view's figures.
#[derive(Clone, Debug, Serialize)]
pub struct ViewSpread {
    /// "" (one view), "left", "right".
    pub view: String,
    /// Frames with a measured pupil (a residual).
    pub measured_frames: u64,
    /// SD of the measured pupil over those frames, mm.
    pub pupil_sd_mm: Option<f64>,
    /// SD of the residual over those frames, mm.
    pub residual_sd_mm: Option<f64>,
    /// Range of the light-driven pupil over all frames, mm.
    pub pupil_light_min_mm: Option<f64>,
    pub pupil_light_max_mm: Option<f64>,
}

/// The summary of a timeline.
#[derive(Clone, Debug, Serialize)]
pub struct TimelineSummary {
    pub frames: u64,
    pub views: Vec<ViewSpread>,
}

/// Whether `path` is a gazelight timeline with the pupil light columns (a
/// regular file whose header names them).
pub fn is_timeline(path: &Path) -> bool {
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return false;
    }
    let Ok(f) = std::fs::File::open(path) else {
        return false;
    };
    let mut header = String::new();
    let ok = BufReader::new(f.take(MAX_LINE_BYTES))
        .read_line(&mut header)
        .is_ok();
    ok && (header.starts_with("t_secs,") || header.starts_with("frame,t_secs,"))
        && header.contains("pupil_light_mm")
}

/// Reads the timeline at `path`.
pub fn summarize(path: &Path) -> Result<TimelineSummary> {
    let mut reader = TimelineReader::open(path)?;
    // Per view: (name, pupil column, light column, residual column).
    let mut views = Vec::new();
    for (view, suffix) in [("", ""), ("left", "_left"), ("right", "_right")] {
        if let (Some(p), Some(l), Some(r)) = (
            reader.column(&format!("pupil_mm{suffix}")),
            reader.column(&format!("pupil_light_mm{suffix}")),
            reader.column(&format!("pupil_residual_mm{suffix}")),
        ) {
            views.push((view, p, l, r));
        }
    }
    if views.is_empty() {
        bail!(
            "{}: a timeline without pupil_mm, pupil_light_mm and pupil_residual_mm columns",
            path.display()
        );
    }
    let mut pupil = vec![Stats::default(); views.len()];
    let mut residual = vec![Stats::default(); views.len()];
    let mut light = vec![Stats::default(); views.len()];
    let mut frames = 0u64;
    while let Some(cells) = reader.next_row()? {
        frames += 1;
        for (k, &(_, p, l, r)) in views.iter().enumerate() {
            if let Some(v) = number(&cells, l) {
                light[k].add(v);
            }
            if let (Some(pv), Some(rv)) = (number(&cells, p), number(&cells, r)) {
                pupil[k].add(pv);
                residual[k].add(rv);
            }
        }
    }
    Ok(TimelineSummary {
        frames,
        views: views
            .iter()
            .enumerate()
            .map(|(k, &(view, ..))| ViewSpread {
                view: view.to_owned(),
                measured_frames: pupil[k].count(),
                pupil_sd_mm: pupil[k].sd(),
                residual_sd_mm: residual[k].sd(),
                pupil_light_min_mm: light[k].min(),
                pupil_light_max_mm: light[k].max(),
            })
            .collect(),
    })
}

impl std::fmt::Display for TimelineSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "gazelight timeline, {} frames", self.frames)?;
        let mm = |v: Option<f64>| v.map_or("-".to_owned(), |v| format!("{v:.3}"));
        for v in &self.views {
            write!(
                f,
                "\n  pupil light response{}: residual SD {} mm vs pupil SD {} mm over {} measured frames; light-driven pupil {}–{} mm",
                if v.view.is_empty() {
                    String::new()
                } else {
                    format!(" ({} eye)", v.view)
                },
                mm(v.residual_sd_mm),
                mm(v.pupil_sd_mm),
                v.measured_frames,
                mm(v.pupil_light_min_mm),
                mm(v.pupil_light_max_mm),
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(name: &str, text: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("gazelight-timeline-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    /// Pupils 4, 5, 6 mm (SD 1) with residuals 0.1, −0.1, 0 (SD 0.1); a
    /// held frame (blank residual) left out of both.
    #[test]
    fn spreads_over_the_measured_frames() {
        let p = file(
            "ok.csv",
            "t_secs,pupil_mm,pupil_light_mm,pupil_residual_mm\n0,4,3.9,0.1\n0.1,5,5.1,-0.1\n0.2,6,6,0\n0.3,7,6.5,\n",
        );
        assert!(is_timeline(&p));
        let s = summarize(&p).unwrap();
        assert_eq!(s.frames, 4);
        let v = &s.views[0];
        assert_eq!(v.measured_frames, 3);
        assert!((v.pupil_sd_mm.unwrap() - 1.0).abs() < 1e-12);
        assert!((v.residual_sd_mm.unwrap() - 0.1).abs() < 1e-12);
        assert_eq!(
            (v.pupil_light_min_mm, v.pupil_light_max_mm),
            (Some(3.9), Some(6.5))
        );
    }

    #[test]
    fn a_short_row_is_named_with_its_line() {
        let p = file(
            "short.csv",
            "t_secs,pupil_mm,pupil_light_mm,pupil_residual_mm\n0,4,3.9,0.1\n0.1,5\n",
        );
        let e = summarize(&p).unwrap_err().to_string();
        assert!(e.contains("(line 3): 2 cells, the header has 4"), "{e}");
        let other = file("other.csv", "time,left,right\n0,4,4\n");
        assert!(!is_timeline(&other));
    }
}
