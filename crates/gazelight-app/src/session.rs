//! The settings in effect for one session, each with where it came from —
//! a flag, the configuration file, the calibration profile or the
//! default — so that nothing takes effect silently.
//!
//! `render`, `replay` and `run` print them after their summary, write them
//! as `session.json` beside `timeline.csv`, and `run` serves them in its
//! status JSON (`settings`). A calibration profile that replaces the
//! tracker's own millimetres says so in its note.
//!
//! ```json
//! {
//!   "command": "replay",
//!   "config_file": "study.toml",
//!   "ignored_config_keys": ["http.addr"],
//!   "settings": {
//!     "observer.age_years": { "value": 70.0, "source": "config" },
//!     "scene.cd_m2_per_unit": { "value": 1.0, "source": "default",
//!                               "note": "OpenEXR holds no absolute luminance: …" }
//!   }
//! }
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use gazelight_tracker::PupilUnit;
use gazelight_tracker::profile::PupilCalibration;
use serde::Serialize;

/// Why `session.json` could not be written.
#[derive(Debug, thiserror::Error)]
pub enum SessionWriteError {
    /// The settings did not serialise (a non-finite number in a table).
    #[error("session settings as JSON")]
    Json(#[source] serde_json::Error),
    /// The file could not be written.
    #[error(transparent)]
    Write(#[from] gazelight_output::OutError),
}

/// The view angles the flags gave (`--yaw-deg`, `--pitch-deg`,
/// `--hfov-deg`; `None`: not given).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ViewAngleFlags {
    /// `--yaw-deg`.
    pub yaw_deg: Option<f64>,
    /// `--pitch-deg`.
    pub pitch_deg: Option<f64>,
    /// `--hfov-deg`.
    pub hfov_deg: Option<f64>,
}

/// Where a setting's value came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Origin {
    /// A command-line flag.
    Flag,
    /// The `--config` file.
    Config,
    /// The calibration profile.
    Profile,
    /// gazelight's default.
    Default,
    /// What the tracker or recording gave (e.g. per-eye gaze).
    Source,
}

impl Origin {
    /// `flag`, `config`, …
    pub fn as_str(self) -> &'static str {
        match self {
            Origin::Flag => "flag",
            Origin::Config => "config",
            Origin::Profile => "profile",
            Origin::Default => "default",
            Origin::Source => "source",
        }
    }

    /// The first of a flag, a configuration value and a profile value that
    /// is present, else the default.
    pub fn first<T>(flag: Option<T>, config: Option<T>, profile: Option<T>) -> Self {
        if flag.is_some() {
            Origin::Flag
        } else if config.is_some() {
            Origin::Config
        } else if profile.is_some() {
            Origin::Profile
        } else {
            Origin::Default
        }
    }
}

/// One setting.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Setting {
    pub value: serde_json::Value,
    pub source: Origin,
    /// What the user should know about it (a replaced unit, an assumed
    /// scale).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// Every setting of a session.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SessionSettings {
    /// `render`, `replay` or `run`.
    pub command: String,
    /// The `--config` file, if any.
    pub config_file: Option<PathBuf>,
    /// Keys of that file the command does not use.
    pub ignored_config_keys: Vec<String>,
    /// By dotted key (`observer.age_years`).
    pub settings: BTreeMap<String, Setting>,
}

impl SessionSettings {
    /// An empty record for `command`.
    pub fn new(command: &str, config_file: Option<&Path>, ignored: &[String]) -> Self {
        Self {
            command: command.to_owned(),
            config_file: config_file.map(Path::to_path_buf),
            ignored_config_keys: ignored.to_vec(),
            settings: BTreeMap::new(),
        }
    }

    /// Records `key = value` from `source`.
    pub fn set(&mut self, key: &str, value: impl Serialize, source: Origin) -> &mut Setting {
        let value = serde_json::to_value(value).unwrap_or(serde_json::Value::Null);
        self.settings.insert(
            key.to_owned(),
            Setting {
                value,
                source,
                note: None,
            },
        );
        // Just inserted.
        self.settings
            .get_mut(key)
            .unwrap_or_else(|| unreachable!("inserted above"))
    }

    /// Records the view's angles, each from the flag, else the
    /// configuration, else the default.
    pub fn set_view(
        &mut self,
        view: &gazelight_vision::scene::ViewParams,
        flags: ViewAngleFlags,
        config: crate::config::ViewDefaults,
    ) {
        for (key, value, flag, configured) in [
            ("view.yaw_deg", view.yaw_deg, flags.yaw_deg, config.yaw_deg),
            (
                "view.pitch_deg",
                view.pitch_deg,
                flags.pitch_deg,
                config.pitch_deg,
            ),
            (
                "view.hfov_deg",
                view.hfov_deg,
                flags.hfov_deg,
                config.hfov_deg,
            ),
        ] {
            self.set(key, value, Origin::first(flag, configured, None));
        }
    }

    /// Records the observer in effect (`psf`'s age and pigmentation), each
    /// from the flag, else `[observer]`, else the profile, else the default.
    pub fn set_observer(
        &mut self,
        psf: &gazelight_vision::psf::PsfParams,
        flags: &crate::observer::ObserverFlags,
        config: &crate::observer::ObserverSettings,
        profile: Option<gazelight_tracker::profile::Observer>,
    ) {
        self.set(
            "observer.age_years",
            psf.age_years,
            Origin::first(
                flags.age_years,
                config.age_years,
                profile.map(|o| o.age_years),
            ),
        );
        self.set(
            "observer.pigmentation",
            psf.pigmentation,
            Origin::first(
                flags.pigmentation,
                config.pigmentation,
                profile.map(|o| o.pigmentation),
            ),
        );
    }

    /// Records `[pipeline]` and `[filter]`: from the configuration file
    /// when one was given and differs from the defaults.
    pub fn set_models(
        &mut self,
        pipeline: &gazelight_vision::pipeline::PipelineConfig,
        filter: gazelight_tracker::filter::FilterConfig,
        config_given: bool,
    ) {
        let from_file = |differs: bool| {
            if config_given && differs {
                Origin::Config
            } else {
                Origin::Default
            }
        };
        self.set(
            "pipeline",
            pipeline,
            from_file(*pipeline != gazelight_vision::pipeline::PipelineConfig::default()),
        );
        self.set(
            "filter",
            filter,
            from_file(filter != gazelight_tracker::filter::FilterConfig::default()),
        );
    }

    /// Records the backend choice (`auto` is the default).
    pub fn set_backend(&mut self, choice: crate::backend::BackendChoice) {
        let origin = if choice == crate::backend::BackendChoice::Auto {
            Origin::Default
        } else {
            Origin::Flag
        };
        self.set("backend", choice.to_string(), origin);
    }

    /// Records the calibration profile (`None`: none given) and what it
    /// does to each eye's pupil.
    pub fn set_calibration(
        &mut self,
        path: Option<&Path>,
        calibration: Option<&PupilCalibration>,
        source: Origin,
    ) {
        let (Some(path), Some(c)) = (path, calibration) else {
            self.set(
                "calibration.profile",
                serde_json::Value::Null,
                Origin::Default,
            )
            .note = Some(
                "none: pupils in mm pass through; other units fall back to the light model"
                    .to_owned(),
            );
            return;
        };
        let mut notes = Vec::new();
        for (eye, map) in [("right", &c.eyes.right), ("left", &c.eyes.left)] {
            let Some(m) = map else { continue };
            let replaces = if m.raw_unit == PupilUnit::Mm {
                "; replaces the tracker's own millimetres"
            } else {
                ""
            };
            notes.push(format!(
                "{eye} eye: raw pupil in {}: black {:.3} → {} mm, white {:.3} → {} mm{replaces}",
                raw_pupil_words(m.raw_unit),
                m.raw_black,
                m.mm_max,
                m.raw_white,
                m.mm_min
            ));
        }
        if notes.is_empty() {
            notes.push("no eye maps: pupils in mm pass through".to_owned());
        }
        self.set("calibration.profile", path.display().to_string(), source)
            .note = Some(notes.join("; "));
    }

    /// The settings as indented text lines, one per setting
    /// (`observer.age_years = 70.0 [config]`); a setting whose value is a
    /// table (the pipeline's models, a luminance scale) gets one line per
    /// leaf (`pipeline.tone.model = "ward_ferwerda" [default]`), its note
    /// after its last line; ignored configuration keys last.
    pub fn summary(&self) -> String {
        let mut out = String::from("settings in effect (source in brackets):\n");
        for (key, s) in &self.settings {
            let mut leaves = Vec::new();
            flatten(key, &s.value, &mut leaves);
            let last = leaves.len().saturating_sub(1);
            for (i, (k, v)) in leaves.iter().enumerate() {
                out.push_str(&format!("  {k} = {v} [{}]", s.source.as_str()));
                if i == last
                    && let Some(n) = &s.note
                {
                    out.push_str(&format!(" — {n}"));
                }
                out.push('\n');
            }
        }
        if !self.ignored_config_keys.is_empty() {
            out.push_str(&format!(
                "  ignored in the configuration file: {}\n",
                self.ignored_config_keys.join(", ")
            ));
        }
        out
    }

    /// Writes `dir/session.json` (a temporary file renamed into place, so
    /// a reader never sees half of it).
    pub fn write(&self, dir: &Path) -> Result<(), SessionWriteError> {
        let path = dir.join("session.json");
        let text = serde_json::to_string_pretty(self).map_err(SessionWriteError::Json)?;
        // `.session.json.tmp`, removed when the write or the rename fails.
        Ok(gazelight_output::write_atomic(
            &path,
            (text + "\n").as_bytes(),
        )?)
    }
}

/// A raw pupil unit in a user's words.
pub fn pupil_unit_words(u: PupilUnit) -> &'static str {
    match u {
        PupilUnit::Px => "eye-camera pixels",
        PupilUnit::Mm => "mm",
        PupilUnit::ArbitraryArea => "arbitrary area units",
        PupilUnit::Arbitrary => "arbitrary diameter units",
    }
}

/// What a calibration's raw pupil value is, in a user's words: a
/// diameter in the tracker's unit, or for an area the square root of the
/// area (the calibration maps √area, which is linear in diameter).
pub fn raw_pupil_words(u: PupilUnit) -> &'static str {
    match u {
        PupilUnit::ArbitraryArea => "√area (square root of the arbitrary area units)",
        u => pupil_unit_words(u),
    }
}

/// `value`'s leaves under `key` (`key.field.…`, in the object's order),
/// each with its value as JSON; an empty object or a non-object is one
/// leaf.
fn flatten(key: &str, value: &serde_json::Value, out: &mut Vec<(String, String)>) {
    match value {
        serde_json::Value::Object(map) if !map.is_empty() => {
            for (k, v) in map {
                flatten(&format!("{key}.{k}"), v, out);
            }
        }
        v => out.push((key.to_owned(), v.to_string())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_present_source_wins() {
        assert_eq!(Origin::first(Some(1), Some(2), Some(3)), Origin::Flag);
        assert_eq!(Origin::first(None, Some(2), Some(3)), Origin::Config);
        assert_eq!(Origin::first(None, None, Some(3)), Origin::Profile);
        assert_eq!(Origin::first::<i32>(None, None, None), Origin::Default);
    }

    #[test]
    fn summary_and_json_name_value_and_source() {
        let mut s =
            SessionSettings::new("render", Some(Path::new("a.toml")), &["http.addr".into()]);
        s.set("observer.age_years", 70.0, Origin::Config);
        let text = s.summary();
        assert!(
            text.contains("observer.age_years = 70.0 [config]"),
            "{text}"
        );
        assert!(
            text.contains("ignored in the configuration file: http.addr"),
            "{text}"
        );
        // A table: one line per leaf, the note after the last.
        s.set(
            "pipeline",
            serde_json::json!({"tone": {"model": "ward_ferwerda", "peak": 100.0}, "range": [1.5, 9.0]}),
            Origin::Default,
        )
        .note = Some("the models".into());
        let text = s.summary();
        for line in [
            "  pipeline.range = [1.5,9.0] [default]\n",
            "  pipeline.tone.model = \"ward_ferwerda\" [default]\n",
            "  pipeline.tone.peak = 100.0 [default] — the models\n",
        ] {
            assert!(text.contains(line), "lacks {line:?}: {text}");
        }
        assert!(text.lines().all(|l| l.len() < 200), "{text}");
        let json = serde_json::to_value(&s).unwrap();
        assert_eq!(json["settings"]["observer.age_years"]["source"], "config");
        assert_eq!(json["config_file"], "a.toml");
    }
}
