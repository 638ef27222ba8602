//! Head orientation for the panorama view: fixed, or a recorded head trace
//! (CSV `t_secs,yaw_deg,pitch_deg`, linearly interpolated, held at the ends).

use std::path::Path;

use anyhow::{Context, bail};

/// A recorded head trace.
#[derive(Clone, Debug, PartialEq)]
pub struct HeadTrace {
    /// `(t_secs, yaw_deg, pitch_deg)`, strictly increasing in time.
    pub points: Vec<(f64, f64, f64)>,
}

impl HeadTrace {
    /// Loads a CSV with an optional header line; errors name the file and
    /// the line.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = gazelight_input::read_to_string(path, gazelight_input::MAX_TEXT_BYTES)
            .with_context(|| format!("cannot read head trace {}", path.display()))?;
        Self::parse(&text).map_err(|e| anyhow::anyhow!("head trace {}: {e}", path.display()))
    }

    /// Parses the CSV text.
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        let mut points: Vec<(f64, f64, f64)> = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let n = i + 1;
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            if i == 0 && fields.first().is_some_and(|f| f.parse::<f64>().is_err()) {
                continue; // header
            }
            if fields.len() != 3 {
                return Err(anyhow::anyhow!(
                    "line {n}: expected 3 fields t_secs,yaw_deg,pitch_deg, got {}",
                    fields.len()
                ));
            }
            let mut v = [0.0f64; 3];
            for (k, (name, f)) in ["t_secs", "yaw_deg", "pitch_deg"]
                .iter()
                .zip(&fields)
                .enumerate()
            {
                v[k] = f
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| {
                        anyhow::anyhow!("line {n}: {name} `{f}` is not a finite number")
                    })?;
            }
            if v[2].abs() > 90.0 {
                return Err(anyhow::anyhow!(
                    "line {n}: pitch_deg {} outside −90..=90",
                    v[2]
                ));
            }
            if let Some(last) = points.last()
                && v[0] <= last.0
            {
                return Err(anyhow::anyhow!(
                    "line {n}: t_secs {} does not increase (previous {})",
                    v[0],
                    last.0
                ));
            }
            points.push((v[0], v[1], v[2]));
        }
        if points.is_empty() {
            return Err(anyhow::anyhow!("no samples"));
        }
        Ok(Self { points })
    }

    /// Yaw and pitch (degrees) at `t_secs` from the trace's start.
    pub fn at(&self, t_secs: f64) -> (f64, f64) {
        let p = &self.points;
        let t = p[0].0 + t_secs;
        let i = p.partition_point(|q| q.0 <= t);
        if i == 0 {
            return (p[0].1, p[0].2);
        }
        if i >= p.len() {
            let l = p[p.len() - 1];
            return (l.1, l.2);
        }
        let (a, b) = (p[i - 1], p[i]);
        let f = (t - a.0) / (b.0 - a.0);
        (a.1 + (b.1 - a.1) * f, a.2 + (b.2 - a.2) * f)
    }
}

/// Where the view's orientation comes from, resolved.
#[derive(Clone, Debug)]
pub enum Head {
    Fixed,
    Trace(HeadTrace),
}

impl Head {
    /// Yaw/pitch at session time `t_secs`, or `None` for a fixed head.
    pub fn orientation(&self, t_secs: f64) -> Option<(f64, f64)> {
        match self {
            Head::Fixed => None,
            Head::Trace(tr) => Some(tr.at(t_secs)),
        }
    }
}

/// Refuses `mouse` without a window.
pub fn require_window(what: &str) -> anyhow::Result<()> {
    bail!("{what} needs the window: drop --headless (or set display.headless = false)")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_and_holds_the_ends() {
        let t = HeadTrace::parse("t_secs,yaw_deg,pitch_deg\n10,0,0\n11,10,-4\n").unwrap();
        assert_eq!(t.at(-1.0), (0.0, 0.0));
        assert_eq!(t.at(0.5), (5.0, -2.0));
        assert_eq!(t.at(5.0), (10.0, -4.0));
    }

    #[test]
    fn bad_lines_are_named() {
        let e = HeadTrace::parse("0,0,0\n1,x,0\n").unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("yaw_deg"), "{e}");
        let e = HeadTrace::parse("0,0,0\n0,1,0\n").unwrap_err().to_string();
        assert!(e.contains("does not increase"), "{e}");
        let e = HeadTrace::parse("0,0,95\n").unwrap_err().to_string();
        assert!(e.contains("pitch_deg"), "{e}");
        assert!(HeadTrace::parse("").is_err());
    }
}
