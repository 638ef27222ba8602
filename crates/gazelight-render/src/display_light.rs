//! The display's light as the pupil light response's input
//! (`replay --display-light FILE`, docs/screen-experiment.md): for a
//! screen experiment the eye sees a display of known luminance, not a
//! panorama, so the model's input is that luminance over time and the
//! display's angular size.
//!
//! The file is a CSV (`#` lines are comments) in one of two forms, told
//! apart by its header:
//!
//! ```text
//! t_secs,luminance_cd_m2          event,luminance_cd_m2
//! 0,2.5                           fixation*,2.5
//! 12.0,120                        cond=bright*,120
//! ```
//!
//! * `t_secs,luminance_cd_m2`: seconds from the recording's first sample
//!   (the clock of `--pupil-fit` and of `events.csv`'s
//!   `recording_t_secs` − the first sample); each luminance holds until
//!   the next row (a display shows a frame until the next one), the first
//!   row's before it.
//! * `event,luminance_cd_m2`: an event pattern (as `gazelight trials
//!   --events`: `*` matches any run of characters, a pattern without one
//!   matches texts that start with it) and the luminance the display shows
//!   from each matching event of the recording on; before the first
//!   matching event, the first one's luminance. A recording's events are
//!   turned into the time form by [`DisplayLight::from_events`].
//!
//! Both the gaze and the field see the display's luminance (a uniform
//! screen), over the display's solid angle: a rectangle of `W×H` degrees
//! centred on the line of sight, Ω = 4·asin(sin(W/2)·sin(H/2)) sr (the
//! exact solid angle of a rectangular pyramid).

use std::path::Path;

use gazelight_tracker::pupil_response::EyeInput;

use crate::trials::matches;

/// The largest display-light file read, bytes.
const MAX_FILE_BYTES: u64 = 256 << 20;
/// Square degrees per steradian, (180/π)².
const DEG2_PER_SR: f64 = (180.0 / std::f64::consts::PI) * (180.0 / std::f64::consts::PI);

/// What can go wrong in reading the display's light.
#[derive(Debug, thiserror::Error)]
pub enum DisplayLightError {
    #[error("--display-light {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("--display-light {path}: line {line}: {reason}")]
    Line {
        path: String,
        line: usize,
        reason: String,
    },
    #[error("--display-light {path}: {reason}")]
    File { path: String, reason: String },
    #[error("{0}")]
    Geometry(String),
}

/// The display's angular size, degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DisplayGeometry {
    pub width_deg: f64,
    pub height_deg: f64,
}

impl DisplayGeometry {
    /// `WxH` in degrees (`--display-deg`), each in (0, 180).
    pub fn parse_deg(s: &str) -> Result<Self, DisplayLightError> {
        let [w, h] = parse_pair("--display-deg", s)?;
        let g = Self {
            width_deg: w,
            height_deg: h,
        };
        g.check("--display-deg", s)?;
        Ok(g)
    }

    /// A `WxH` cm display at `distance_cm` from the eye
    /// (`--display-cm`, `--viewing-distance-cm`): 2·atan(W / 2d).
    pub fn from_cm(size: &str, distance_cm: f64) -> Result<Self, DisplayLightError> {
        let [w, h] = parse_pair("--display-cm", size)?;
        if !(distance_cm.is_finite() && distance_cm > 0.0) {
            return Err(DisplayLightError::Geometry(format!(
                "--viewing-distance-cm {distance_cm}: expected a distance > 0 cm"
            )));
        }
        let deg = |x: f64| 2.0 * (x / (2.0 * distance_cm)).atan().to_degrees();
        Ok(Self {
            width_deg: deg(w),
            height_deg: deg(h),
        })
    }

    fn check(&self, flag: &str, s: &str) -> Result<(), DisplayLightError> {
        let ok = |x: f64| x.is_finite() && x > 0.0 && x < 180.0;
        if ok(self.width_deg) && ok(self.height_deg) {
            Ok(())
        } else {
            Err(DisplayLightError::Geometry(format!(
                "{flag} {s}: expected WxH with each between 0 and 180 degrees"
            )))
        }
    }

    /// The display's solid angle, deg².
    pub fn solid_angle_deg2(&self) -> f64 {
        let a = (0.5 * self.width_deg).to_radians().sin();
        let b = (0.5 * self.height_deg).to_radians().sin();
        4.0 * (a * b).asin() * DEG2_PER_SR
    }
}

fn parse_pair(flag: &str, s: &str) -> Result<[f64; 2], DisplayLightError> {
    let bad = || DisplayLightError::Geometry(format!("{flag} {s}: expected WxH, e.g. 40x30"));
    let (a, b) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let a: f64 = a.trim().parse().map_err(|_| bad())?;
    let b: f64 = b.trim().parse().map_err(|_| bad())?;
    if a.is_finite() && b.is_finite() && a > 0.0 && b > 0.0 {
        Ok([a, b])
    } else {
        Err(bad())
    }
}

/// The file as read: its form and rows.
#[derive(Clone, Debug, PartialEq)]
pub enum DisplayLightTable {
    /// (seconds from the first sample, cd/m²), in time order.
    Times(Vec<(f64, f64)>),
    /// (event pattern, cd/m²), in the file's order.
    Events(Vec<(String, f64)>),
}

impl DisplayLightTable {
    /// Reads a `--display-light` file.
    pub fn load(path: &Path) -> Result<Self, DisplayLightError> {
        let text = gazelight_input::read_to_string(path, MAX_FILE_BYTES).map_err(|source| {
            DisplayLightError::Io {
                path: path.display().to_string(),
                source,
            }
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses a `--display-light` file's text (`name` for the messages).
    pub fn parse(text: &str, name: &str) -> Result<Self, DisplayLightError> {
        let line_err = |line: usize, reason: String| DisplayLightError::Line {
            path: name.to_owned(),
            line,
            reason,
        };
        let mut rows = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
        let Some((_, header)) = rows.next() else {
            return Err(DisplayLightError::File {
                path: name.to_owned(),
                reason: "empty: expected a header `t_secs,luminance_cd_m2` or \
                         `event,luminance_cd_m2`"
                    .to_owned(),
            });
        };
        let cols: Vec<String> = header
            .split(',')
            .map(|c| c.trim().to_ascii_lowercase())
            .collect();
        let by_time = match cols.iter().map(String::as_str).collect::<Vec<_>>()[..] {
            ["t_secs", "luminance_cd_m2"] => true,
            ["event", "luminance_cd_m2"] => false,
            _ => {
                return Err(DisplayLightError::File {
                    path: name.to_owned(),
                    reason: format!(
                        "header {header:?}: expected `t_secs,luminance_cd_m2` or \
                         `event,luminance_cd_m2`"
                    ),
                });
            }
        };
        let mut times = Vec::new();
        let mut events = Vec::new();
        for (i, line) in rows {
            // The luminance is the last field; an event pattern may hold commas.
            let Some((key, lum)) = line.rsplit_once(',') else {
                return Err(line_err(i + 1, format!("{line:?}: expected two fields")));
            };
            let lum: f64 = lum
                .trim()
                .parse()
                .ok()
                .filter(|l: &f64| l.is_finite() && *l >= 0.0)
                .ok_or_else(|| {
                    line_err(
                        i + 1,
                        format!("luminance {:?}: expected cd/m² ≥ 0", lum.trim()),
                    )
                })?;
            if by_time {
                let t: f64 = key
                    .trim()
                    .parse()
                    .ok()
                    .filter(|t: &f64| t.is_finite())
                    .ok_or_else(|| {
                        line_err(i + 1, format!("t_secs {:?}: expected seconds", key.trim()))
                    })?;
                if times.last().is_some_and(|(t0, _)| t < *t0) {
                    return Err(line_err(i + 1, format!("t_secs {t} before the row above")));
                }
                times.push((t, lum));
            } else {
                let key = key.trim().trim_matches('"');
                if key.is_empty() {
                    return Err(line_err(i + 1, "an empty event pattern".to_owned()));
                }
                events.push((key.to_owned(), lum));
            }
        }
        if times.is_empty() && events.is_empty() {
            return Err(DisplayLightError::File {
                path: name.to_owned(),
                reason: "no rows after the header".to_owned(),
            });
        }
        Ok(if by_time {
            Self::Times(times)
        } else {
            Self::Events(events)
        })
    }
}

/// The display's luminance over time and its size: the light input of
/// the pupil light response.
#[derive(Clone, Debug, PartialEq)]
pub struct DisplayLight {
    /// (seconds from the recording's first sample, cd/m²), in time order.
    pub steps: Vec<(f64, f64)>,
    pub geometry: DisplayGeometry,
    /// How many of the recording's events set the luminance (the event form).
    pub events_matched: usize,
}

impl DisplayLight {
    /// The time form as it is; the event form through the recording's
    /// events (`(seconds from its first sample, text)`, any order): each
    /// event takes the first pattern it matches.
    pub fn new<'a>(
        table: &DisplayLightTable,
        geometry: DisplayGeometry,
        events: impl IntoIterator<Item = (f64, &'a str)>,
        name: &str,
    ) -> Result<Self, DisplayLightError> {
        match table {
            DisplayLightTable::Times(t) => Ok(Self {
                steps: t.clone(),
                geometry,
                events_matched: 0,
            }),
            DisplayLightTable::Events(patterns) => {
                let mut steps: Vec<(f64, f64)> = events
                    .into_iter()
                    .filter(|(t, _)| t.is_finite())
                    .filter_map(|(t, text)| {
                        patterns
                            .iter()
                            .find(|(p, _)| matches(p, text))
                            .map(|(_, l)| (t, *l))
                    })
                    .collect();
                steps.sort_by(|a, b| a.0.total_cmp(&b.0));
                if steps.is_empty() {
                    return Err(DisplayLightError::File {
                        path: name.to_owned(),
                        reason: "none of the recording's events matches its patterns \
                                 (see events.csv's text column)"
                            .to_owned(),
                    });
                }
                Ok(Self {
                    events_matched: steps.len(),
                    steps,
                    geometry,
                })
            }
        }
    }

    /// The luminance at `t_secs` from the recording's first sample, cd/m².
    pub fn luminance_at(&self, t_secs: f64) -> f64 {
        let k = self.steps.partition_point(|(t, _)| *t <= t_secs);
        self.steps[k.saturating_sub(1)].1
    }

    /// What an eye looking at the display sees at `t_secs`.
    pub fn input_at(&self, t_secs: f64) -> EyeInput {
        let l = self.luminance_at(t_secs);
        EyeInput {
            gaze_luminance_cd_m2: l,
            field_mean_luminance_cd_m2: l,
            field_area_deg2: self.geometry.solid_angle_deg2(),
            lit: true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_forms_and_the_step_hold() {
        let t = DisplayLightTable::parse("# c\nt_secs,luminance_cd_m2\n0,2\n5,100\n", "f").unwrap();
        let g = DisplayGeometry::parse_deg("40x30").unwrap();
        let d = DisplayLight::new(&t, g, [], "f").unwrap();
        assert_eq!(d.luminance_at(-1.0), 2.0);
        assert_eq!(d.luminance_at(4.99), 2.0);
        assert_eq!(d.luminance_at(5.0), 100.0);
        let e =
            DisplayLightTable::parse("event,luminance_cd_m2\ndark*,1\nbright*,80\n", "f").unwrap();
        let d = DisplayLight::new(
            &e,
            g,
            [(3.0, "bright 2"), (1.0, "dark 1"), (2.0, "other")],
            "f",
        )
        .unwrap();
        assert_eq!(d.steps, vec![(1.0, 1.0), (3.0, 80.0)]);
        assert!(DisplayLightTable::parse("t,l\n1,2\n", "f").is_err());
        assert!(DisplayLightTable::parse("t_secs,luminance_cd_m2\n1,-2\n", "f").is_err());
    }

    /// Solid angle of a rectangle: a small one is W·H deg²; a 90°×90°
    /// one is a sixth of the sphere (a cube's face), 4π/6 sr.
    #[test]
    fn solid_angle_of_the_display() {
        let small = DisplayGeometry {
            width_deg: 1.0,
            height_deg: 2.0,
        };
        assert!((small.solid_angle_deg2() - 2.0).abs() < 1e-3);
        let face = DisplayGeometry {
            width_deg: 90.0,
            height_deg: 90.0,
        };
        let sixth = 4.0 * std::f64::consts::PI / 6.0 * DEG2_PER_SR;
        assert!((face.solid_angle_deg2() - sixth).abs() < 1e-9 * sixth);
        let cm = DisplayGeometry::from_cm("120x60", 60.0).unwrap();
        assert!((cm.width_deg - 90.0).abs() < 1e-9);
    }
}
