//! The configuration file (TOML) every command reads: one schema
//! ([`ServiceConfig`]) for the source, the display, the scene, the
//! perception pipeline, the filter chain and the network endpoints, one
//! loader, one set of checks. The CLI (`gazelight run`, `render`, `replay`,
//! `calibrate`) and Python's `gazelight.render` load it here; a command
//! uses the keys that apply to it ([`ConfigUser`]) and the others are
//! reported as ignored, not refused. [`render::RenderConfig`] is the part
//! `render` and `replay` take; [`filter_from_str`] /
//! [`filter_from_value`] read a `[filter]` table alone (Python's
//! `config=`).
//!
//! Every field is optional (a missing one takes the flag or the default);
//! unknown fields are errors that name the field, and every value is
//! validated on load with an error naming the file and the field
//! (`config run.toml: display.fps = -5: …`). Relative paths are resolved
//! against the directory of the file. Every section and key, with its
//! default and unit: `docs/configuration.md`. The example below is loaded
//! by the test `the_module_doc_example_loads`.
//!
//! ```toml
//! [source]
//! uri = "pupil://127.0.0.1:50020"   # or replay://PATH?speed=1, synthetic://demo
//! calibration = "profile.json"
//!
//! [display]
//! fps = 90.0
//! size = "720x800"
//! headless = true
//!
//! [scene]
//! file = "city.exr"
//! luminance_scale = { kind = "median_key", key_cd_m2 = 20.0 }
//! head = "fixed"                    # or "trace:head.csv"
//! yaw_deg = -78.4
//! pitch_deg = -6.0
//! hfov_deg = 90.0
//!
//! [pipeline]                        # as in the render configuration
//! glare = { full_weight_deg = 12.0, fade_sigma_deg = 2.0 }
//!
//! [filter]                          # the tracker's filter chain
//! dropout = { hold_s = 0.5 }
//!
//! [output]
//! dir = "out"
//!
//! [http]
//! addr = "127.0.0.1:8080"
//!
//! [relay]
//! addr = "127.0.0.1:50030"
//! ```

pub mod render;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use gazelight_tracker::filter::FilterConfig;
use gazelight_vision::pipeline::PipelineConfig;
use gazelight_vision::scene::{LuminanceScale, ProjectionKind, ViewParams};
use serde::Deserialize;

use crate::bounds::{self, BoundsError, Num};
use crate::observer::ObserverSettings;

pub use render::{RenderConfig, SceneFov, ViewDefaults};

/// A configuration that cannot be used. The message names the file (a
/// path, or the name a caller gave text or a table) and, for a bad value,
/// the field.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file cannot be read: missing, not a regular file, over
    /// `gazelight_input::MAX_CONFIG_BYTES`, or its structure refused.
    #[error("cannot read config {}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Not TOML, an unknown key or a value of the wrong type; the message
    /// is the TOML parser's (it names the key, line and column).
    #[error("config {}: {message}", path.display())]
    Syntax { path: PathBuf, message: String },
    /// A value out of its range or inconsistent with another.
    #[error("config {}: {}", path.display(), error.message)]
    Invalid { path: PathBuf, error: FieldError },
}

impl ConfigError {
    /// The field a bad value is in (`display.fps`), when the error is one.
    pub fn field(&self) -> Option<&str> {
        match self {
            Self::Invalid { error, .. } => Some(&error.field),
            _ => None,
        }
    }
}

/// A value out of its range: the dotted key (`display.fps`,
/// `pipeline`, `limits`) and the sentence, which names the key too
/// (`display.fps = -5: expected a rate …`).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct FieldError {
    /// The section or dotted key, as far as it is known.
    pub field: String,
    /// The whole sentence.
    pub message: String,
}

impl FieldError {
    fn new(field: &str, message: impl Into<String>) -> Self {
        Self {
            field: field.to_owned(),
            message: message.into(),
        }
    }
}

/// `[source]`.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SourceSettings {
    /// Source URI (`pupil://HOST:PORT`, `replay://PATH[?speed=S]`,
    /// `synthetic://demo`).
    pub uri: Option<String>,
    /// Calibration profile (JSON).
    pub calibration: Option<PathBuf>,
}

/// `[display]`.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DisplaySettings {
    /// Display rate, Hz.
    pub fps: Option<f64>,
    /// Display size per eye, `"WIDTHxHEIGHT"`.
    pub size: Option<String>,
    /// Run with no window.
    pub headless: Option<bool>,
}

/// `[scene]`.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneSettings {
    /// HDR panorama (OpenEXR / Radiance); default the embedded night scene.
    pub file: Option<PathBuf>,
    /// cd/m² per file unit, or a median key.
    pub luminance_scale: Option<LuminanceScale>,
    /// `"fixed"` or `"trace:FILE"`.
    pub head: Option<String>,
    pub yaw_deg: Option<f64>,
    pub pitch_deg: Option<f64>,
    pub hfov_deg: Option<f64>,
    /// The view in one table (`{ yaw_deg, pitch_deg, hfov_deg, width,
    /// height }`): on load it becomes the three keys above and
    /// `display.size`, which must then not be given as well.
    pub view: Option<ViewParams>,
    /// The scene image's projection when its file does not say
    /// (`--scene-projection`): equirectangular, perspective, angular,
    /// hemispherical, equisolid, stereographic.
    pub projection: Option<String>,
    /// Its full field, degrees: `[H]` (square pixels) or `[H, V]`
    /// (`--scene-fov-deg`).
    pub fov_deg: Option<Vec<f64>>,
}

/// `scene.projection` and `scene.fov_deg`, parsed.
pub type ProjectionSettings = (ProjectionKind, Option<SceneFov>);

impl SceneSettings {
    /// `scene.projection` and `scene.fov_deg`, parsed; the error is the
    /// sentence after `scene.projection/fov_deg: `.
    pub fn projection_settings(&self) -> Result<Option<ProjectionSettings>, BoundsError> {
        let Some(name) = &self.projection else {
            if self.fov_deg.is_some() {
                return Err(BoundsError("fov_deg without projection".into()));
            }
            return Ok(None);
        };
        let kind = ProjectionKind::parse(name)
            .ok_or_else(|| BoundsError(format!("unknown projection {name:?}")))?;
        let fov = match self.fov_deg.as_deref() {
            None => None,
            Some(v) => Some(SceneFov::from_degrees(v).ok_or_else(|| {
                BoundsError(format!(
                    "fov_deg = {v:?}: expected [H] or [H, V] in degrees > 0"
                ))
            })?),
        };
        Ok(Some((kind, fov)))
    }
}

/// `[output]`.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputSettings {
    /// Directory for frames, `timeline.csv` and `psf.csv`.
    pub dir: Option<PathBuf>,
}

/// `[http]` / `[relay]`.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EndpointSettings {
    /// `HOST:PORT` to listen on.
    pub addr: Option<String>,
}

/// The whole configuration.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ServiceConfig {
    pub source: SourceSettings,
    pub display: DisplaySettings,
    pub scene: SceneSettings,
    pub pipeline: PipelineConfig,
    pub filter: FilterConfig,
    pub output: OutputSettings,
    pub http: EndpointSettings,
    pub relay: EndpointSettings,
    /// Lab Streaming Layer: outlets, discovery scope, inlet mapping.
    pub lsl: gazelight_tracker::lsl::LslConfig,
    /// The observer (CIE 146 age and pigmentation of the glare kernel).
    pub observer: ObserverSettings,
    /// What one ZeroMQ peer may send, per socket kind (the `pupil://`
    /// client and the relay); see `gazelight_pupil::limits`.
    pub limits: gazelight_tracker::pupil::limits::ZmqLimits,
}

/// Largest display rate accepted, Hz.
pub const MAX_FPS: f64 = bounds::MAX_FPS;

/// Checks a display rate; the sentence is what follows the flag or key
/// (`--fps `, `display.fps = `).
pub fn check_fps(fps: f64) -> Result<f64, BoundsError> {
    let min = bounds::MIN_FPS;
    if fps.is_finite() && fps >= min && fps <= MAX_FPS {
        Ok(fps)
    } else {
        Err(BoundsError(format!(
            "{}: expected a rate {min} ≤ Hz ≤ {MAX_FPS}",
            Num(fps)
        )))
    }
}

/// Parses `WIDTHxHEIGHT` (each side 8..=8192 pixels: [`bounds::parse_size`]).
pub fn parse_size(s: &str) -> Result<(usize, usize), BoundsError> {
    bounds::parse_size(s)
}

/// Parses a listening address; only a literal `IP:PORT` is accepted.
pub fn parse_addr(s: &str) -> Result<SocketAddr, BoundsError> {
    s.parse::<SocketAddr>()
        .map_err(|_| BoundsError(format!("`{s}`: expected IP:PORT, e.g. 127.0.0.1:8080")))
}

/// Head orientation source.
#[derive(Clone, Debug, PartialEq)]
pub enum HeadSpec {
    /// The view stays at the configured yaw/pitch.
    Fixed,
    /// A head trace CSV (`t_secs,yaw_deg,pitch_deg`).
    Trace(PathBuf),
    /// The mouse drags the view (needs a window).
    Mouse,
}

/// Parses `fixed`, `trace:FILE` or `mouse`.
pub fn parse_head(s: &str) -> Result<HeadSpec, BoundsError> {
    match s {
        "fixed" => Ok(HeadSpec::Fixed),
        "mouse" => Ok(HeadSpec::Mouse),
        _ => match s.strip_prefix("trace:") {
            Some(p) if !p.is_empty() => Ok(HeadSpec::Trace(PathBuf::from(p))),
            _ => Err(BoundsError(format!(
                "`{s}`: expected fixed, mouse or trace:FILE (a CSV t_secs,yaw_deg,pitch_deg)"
            ))),
        },
    }
}

/// The command reading a configuration file: every command reads the one
/// schema ([`ServiceConfig`]) and uses the keys that apply to it; the others
/// are reported as ignored, not refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConfigUser {
    Run,
    Render,
    Replay,
    Calibrate,
}

impl ConfigUser {
    /// `gazelight NAME`.
    pub fn name(self) -> &'static str {
        match self {
            ConfigUser::Run => "run",
            ConfigUser::Render => "render",
            ConfigUser::Replay => "replay",
            ConfigUser::Calibrate => "calibrate",
        }
    }

    /// The sections (`"pipeline"`) and keys (`"scene.file"`) the command
    /// uses.
    fn applies(self) -> &'static [&'static str] {
        const VIEW: [&str; 12] = [
            "scene.file",
            "scene.projection",
            "scene.fov_deg",
            "scene.luminance_scale",
            "scene.yaw_deg",
            "scene.pitch_deg",
            "scene.hfov_deg",
            "scene.view",
            "display.size",
            "pipeline",
            "filter",
            "observer",
        ];
        const REPLAY: [&str; 13] = [
            VIEW[0],
            VIEW[10],
            VIEW[11],
            VIEW[1],
            VIEW[2],
            VIEW[3],
            VIEW[4],
            VIEW[5],
            VIEW[6],
            VIEW[7],
            VIEW[8],
            VIEW[9],
            "source.calibration",
        ];
        match self {
            ConfigUser::Run => &[
                "source", "display", "scene", "pipeline", "filter", "output", "http", "relay",
                "lsl", "observer", "limits",
            ],
            ConfigUser::Render => &VIEW,
            ConfigUser::Replay => &REPLAY,
            ConfigUser::Calibrate => &["source.uri", "limits"],
        }
    }

    /// The keys of `table` (a parsed file) that do not apply: a section
    /// none of whose keys applies by its name (`http`), else each key
    /// dotted (`display.fps`), in file order.
    fn ignored(self, table: &toml::Table) -> Vec<String> {
        let applies = self.applies();
        let mut out = Vec::new();
        for (section, value) in table {
            if applies.contains(&section.as_str()) {
                continue;
            }
            let prefix = format!("{section}.");
            let partly = applies.iter().any(|a| a.starts_with(&prefix));
            match value.as_table() {
                Some(keys) if partly => {
                    for key in keys.keys() {
                        let dotted = format!("{section}.{key}");
                        if !applies.contains(&dotted.as_str()) {
                            out.push(dotted);
                        }
                    }
                }
                _ => out.push(section.clone()),
            }
        }
        out
    }
}

/// Reads a configuration file with the bounded reader every front end
/// uses (`gazelight_input::read_config`: a regular file of at most 1 MiB,
/// its structure scanned before the TOML parser builds anything).
pub fn read_text(path: &Path) -> Result<String, ConfigError> {
    gazelight_input::read_config(path, gazelight_input::ConfigSyntax::Toml).map_err(|source| {
        ConfigError::Read {
            path: path.to_path_buf(),
            source,
        }
    })
}

/// Parses TOML text into a table; the error names `origin`.
pub fn parse_table(text: &str, origin: &Path) -> Result<toml::Table, ConfigError> {
    toml::from_str(text).map_err(|e| ConfigError::Syntax {
        path: origin.to_path_buf(),
        message: e.to_string(),
    })
}

impl ServiceConfig {
    /// Loads and validates a TOML file (for `run`); errors name the file
    /// and the field.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::load_for(path, ConfigUser::Run).map(|(config, _)| config)
    }

    /// [`Self::load`] for `user`, with the keys that do not apply to it
    /// (each also logged as a warning naming the file, the key and the
    /// command).
    pub fn load_for(path: &Path, user: ConfigUser) -> Result<(Self, Vec<String>), ConfigError> {
        let text = read_text(path)?;
        Self::from_str_for(&text, path, user)
    }

    /// [`Self::load_for`] on text already read; `origin` is the file it
    /// came from (errors name it; relative paths are resolved against its
    /// directory), or a name for text that came from no file.
    pub fn from_str_for(
        text: &str,
        origin: &Path,
        user: ConfigUser,
    ) -> Result<(Self, Vec<String>), ConfigError> {
        Self::from_table_for(parse_table(text, origin)?, origin, user)
    }

    /// [`Self::from_str_for`] on a table already built (Python's dict,
    /// converted as it is); every check is this loader's.
    pub fn from_table_for(
        table: toml::Table,
        origin: &Path,
        user: ConfigUser,
    ) -> Result<(Self, Vec<String>), ConfigError> {
        let invalid = |error: FieldError| ConfigError::Invalid {
            path: origin.to_path_buf(),
            error,
        };
        let ignored = user.ignored(&table);
        let mut config: Self =
            table
                .try_into()
                .map_err(|e: toml::de::Error| ConfigError::Syntax {
                    path: origin.to_path_buf(),
                    message: e.to_string(),
                })?;
        config.validate().map_err(invalid)?;
        config.expand_view().map_err(invalid)?;
        if !ignored.iter().any(|k| k == "limits") {
            // Every socket opened from here on uses them.
            gazelight_tracker::pupil::limits::set_process_limits(config.limits)
                .map_err(|e| invalid(FieldError::new("limits", e.to_string())))?;
        }
        for key in &ignored {
            tracing::warn!(
                "config {}: `{key}` does not apply to `gazelight {}`; ignored",
                origin.display(),
                user.name()
            );
        }
        let config = config.resolved_against(origin);
        Ok((config, ignored))
    }

    /// `scene.view` into `scene.yaw_deg`, `pitch_deg`, `hfov_deg` and
    /// `display.size`; an error when any of those is given as well.
    fn expand_view(&mut self) -> Result<(), FieldError> {
        let Some(view) = self.scene.view.take() else {
            return Ok(());
        };
        for (key, set) in [
            ("scene.yaw_deg", self.scene.yaw_deg.is_some()),
            ("scene.pitch_deg", self.scene.pitch_deg.is_some()),
            ("scene.hfov_deg", self.scene.hfov_deg.is_some()),
            ("display.size", self.display.size.is_some()),
        ] {
            if set {
                return Err(FieldError::new(
                    "scene.view",
                    format!("scene.view and {key} both set: give the view one way"),
                ));
            }
        }
        self.scene.yaw_deg = Some(view.yaw_deg);
        self.scene.pitch_deg = Some(view.pitch_deg);
        self.scene.hfov_deg = Some(view.hfov_deg);
        self.display.size = Some(format!("{}x{}", view.width, view.height));
        Ok(())
    }

    /// Relative paths resolved against the directory of the file at `path`.
    fn resolved_against(self, path: &Path) -> Self {
        let mut config = self;
        let base = path.parent().unwrap_or(Path::new("."));
        let resolve = |p: &mut Option<PathBuf>| {
            if let Some(p) = p
                && p.is_relative()
            {
                *p = base.join(&*p);
            }
        };
        resolve(&mut config.source.calibration);
        resolve(&mut config.scene.file);
        resolve(&mut config.output.dir);
        resolve(&mut config.lsl.config_file);
        if let Some(h) = &config.scene.head
            && let Some(rel) = h.strip_prefix("trace:")
            && Path::new(rel).is_relative()
        {
            config.scene.head = Some(format!("trace:{}", base.join(rel).display()));
        }
        config
    }

    /// Checks every field; the error names it (`display.fps = …: …`).
    pub fn validate(&self) -> Result<(), FieldError> {
        self.limits
            .validate()
            .map_err(|e| FieldError::new("limits", e.to_string()))?;
        if let Some(uri) = &self.source.uri
            && uri.trim().is_empty()
        {
            return Err(FieldError::new("source.uri", "source.uri is empty"));
        }
        if let Some(fps) = self.display.fps {
            check_fps(fps)
                .map_err(|e| FieldError::new("display.fps", format!("display.fps = {e}")))?;
        }
        if let Some(size) = &self.display.size {
            parse_size(size)
                .map_err(|e| FieldError::new("display.size", format!("display.size = {e}")))?;
        }
        if let Some(scale) = &self.scene.luminance_scale {
            scale.validate().map_err(|e| {
                FieldError::new(
                    "scene.luminance_scale",
                    format!("scene.luminance_scale: {e}"),
                )
            })?;
        }
        self.scene.projection_settings().map_err(|e| {
            FieldError::new("scene.projection", format!("scene.projection/fov_deg: {e}"))
        })?;
        if let Some(head) = &self.scene.head {
            parse_head(head)
                .map_err(|e| FieldError::new("scene.head", format!("scene.head = {e}")))?;
        }
        if let Some(y) = self.scene.yaw_deg
            && !y.is_finite()
        {
            return Err(FieldError::new(
                "scene.yaw_deg",
                format!("scene.yaw_deg = {y}: expected a finite angle"),
            ));
        }
        if let Some(p) = self.scene.pitch_deg
            && !(p.is_finite() && p.abs() <= 90.0)
        {
            return Err(FieldError::new(
                "scene.pitch_deg",
                format!("scene.pitch_deg = {p}: expected −90 ≤ pitch ≤ 90"),
            ));
        }
        if let Some(f) = self.scene.hfov_deg
            && !(f > 0.0 && f < 179.0)
        {
            return Err(FieldError::new(
                "scene.hfov_deg",
                format!("scene.hfov_deg = {f}: expected 0 < hfov < 179"),
            ));
        }
        if let Some(view) = &self.scene.view {
            view.validate()
                .map_err(|e| FieldError::new("scene.view", format!("scene.view: {e}")))?;
        }
        self.pipeline
            .validate()
            .map_err(|e| FieldError::new("pipeline", format!("pipeline: {e}")))?;
        self.observer
            .validate_fields()
            .map_err(|(key, e)| FieldError::new(key, e.to_string()))?;
        self.filter
            .validate()
            .map_err(|e| FieldError::new("filter", format!("filter.{e}")))?;
        for (name, ep) in [("http", &self.http), ("relay", &self.relay)] {
            if let Some(a) = &ep.addr {
                parse_addr(a).map_err(|e| {
                    FieldError::new(&format!("{name}.addr"), format!("{name}.addr = {e}"))
                })?;
            }
        }
        Ok(())
    }
}

/// A `[filter]` table given alone (Python's `config=` of `read` and
/// `FilterChain`) that cannot be used; the messages are the CLI's.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FilterConfigError {
    /// Not TOML, an unknown key or a value of the wrong type.
    #[error("filter configuration: {0}")]
    Syntax(String),
    /// A value out of its range (`filter.dropout.hold_s = …`).
    #[error("filter.{0}")]
    Invalid(String),
}

/// The filter chain's configuration from the contents of a `[filter]`
/// table as TOML text, checked as the file's `[filter]` is.
pub fn filter_from_str(text: &str) -> Result<FilterConfig, FilterConfigError> {
    let config: FilterConfig =
        toml::from_str(text).map_err(|e| FilterConfigError::Syntax(e.to_string()))?;
    check_filter(config)
}

/// [`filter_from_str`] on a value already built (a Python dict converted as
/// it is, NaN staying NaN, so this check says what is wrong).
pub fn filter_from_value(value: toml::Value) -> Result<FilterConfig, FilterConfigError> {
    let config: FilterConfig = value
        .try_into()
        .map_err(|e: toml::de::Error| FilterConfigError::Syntax(e.to_string()))?;
    check_filter(config)
}

fn check_filter(config: FilterConfig) -> Result<FilterConfig, FilterConfigError> {
    config
        .validate()
        .map_err(|e| FilterConfigError::Invalid(e.to_string()))?;
    Ok(config)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The TOML example of a module's documentation.
    pub(crate) fn doc_example(source: &str) -> String {
        let mut lines = source.lines().skip_while(|l| l.trim() != "//! ```toml");
        lines.next();
        lines
            .take_while(|l| l.trim() != "//! ```")
            .map(|l| {
                l.strip_prefix("//!")
                    .unwrap_or(l)
                    .strip_prefix(' ')
                    .unwrap_or("")
            })
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// `scene.projection` and `scene.fov_deg`: a known name with one or two
    /// fields parses; an unknown name, a field without a projection and
    /// three numbers are refused by name.
    #[test]
    fn scene_projection_keys_parse_and_refuse() {
        let with = |p: Option<&str>, f: Option<Vec<f64>>| SceneSettings {
            projection: p.map(str::to_owned),
            fov_deg: f,
            ..SceneSettings::default()
        };
        let (k, fov) = with(Some("angular"), Some(vec![182.0]))
            .projection_settings()
            .unwrap()
            .unwrap();
        assert_eq!(k, ProjectionKind::Angular);
        assert_eq!((fov.unwrap().h_deg, fov.unwrap().v_deg), (182.0, None));
        assert!(
            with(Some("perspective"), Some(vec![60.0, 40.0]))
                .projection_settings()
                .unwrap()
                .is_some()
        );
        assert!(with(None, None).projection_settings().unwrap().is_none());
        let e = with(Some("fishy"), None).projection_settings().unwrap_err();
        assert!(e.to_string().contains("fishy"), "{e}");
        assert!(with(None, Some(vec![90.0])).projection_settings().is_err());
        assert!(
            with(Some("angular"), Some(vec![1.0, 2.0, 3.0]))
                .projection_settings()
                .is_err()
        );
    }

    fn load_str(text: &str) -> Result<ServiceConfig, ConfigError> {
        let dir = std::env::temp_dir().join(format!("gazelight-app-svc-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        static SEQ: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = SEQ.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let path = dir.join(format!("c{n}.toml"));
        std::fs::write(&path, text).unwrap();
        let r = ServiceConfig::load(&path);
        let _ = std::fs::remove_file(&path);
        r
    }

    /// A valid file whose values the property below replaces one at a time.
    const FULL: &str = "[source]\nuri = \"pupil://127.0.0.1:50020\"\ncalibration = \"p.json\"\n\
         [display]\nfps = 90.0\nsize = \"720x800\"\nheadless = true\n\
         [scene]\nhead = \"trace:h.csv\"\nyaw_deg = 10.0\n\
         [http]\naddr = \"127.0.0.1:8080\"\n[relay]\naddr = \"127.0.0.1:50030\"\n\
         [observer]\nage_years = 25.0\npigmentation = 0.5\n";

    /// Values no field should accept silently or panic on.
    const HOSTILE: [&str; 16] = [
        "1e308",
        "-1e308",
        "nan",
        "inf",
        "-inf",
        "-1",
        "0",
        "1e-300",
        "\"\"",
        "\"99999999999x99999999999\"",
        "\"127.0.0.1:99999\"",
        "[]",
        "{}",
        "true",
        "\"pupil://[::1\"",
        "18446744073709551616",
    ];

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(
            std::env::var("GAZELIGHT_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(256)
        ))]

        /// Any file — random bytes, or the full file with one value replaced
        /// by a hostile one — gives Ok or an error naming the config file;
        /// never a panic. A loaded config has finite, in-range values.
        #[test]
        fn any_config_text_is_ok_or_a_named_error(
            bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..512),
            line in 0usize..32,
            hostile in 0usize..HOSTILE.len(),
            random in proptest::prelude::any::<bool>(),
        ) {
            let text = if random {
                String::from_utf8_lossy(&bytes).into_owned()
            } else {
                let lines: Vec<&str> = FULL.lines().collect();
                let i = line % lines.len();
                lines
                    .iter()
                    .enumerate()
                    .map(|(j, l)| match l.split_once(" = ") {
                        Some((k, _)) if j == i => format!("{k} = {}", HOSTILE[hostile]),
                        _ => (*l).to_string(),
                    })
                    .collect::<Vec<_>>()
                    .join("\n")
            };
            match load_str(&text) {
                Ok(c) => {
                    if let Some(fps) = c.display.fps {
                        proptest::prop_assert!(fps.is_finite() && fps > 0.0, "fps {fps}");
                    }
                }
                Err(e) => {
                    let msg = crate::tests::chain(&e);
                    proptest::prop_assert!(msg.contains("config"), "{msg}");
                }
            }
        }
    }

    #[test]
    fn the_module_doc_example_loads() {
        let text = doc_example(include_str!("config.rs"));
        assert!(text.contains("[relay]"), "no example found: {text}");
        let c = load_str(&text).unwrap();
        assert_eq!(c.display.fps, Some(90.0));
        assert_eq!(c.pipeline.glare.full_weight_deg, 12.0);
        assert_eq!(c.filter.dropout.hold_s, 0.5);
        let bad = text.replace("glare = {", "glare = { window_px = 256,");
        assert!(load_str(&bad).is_err());
    }

    #[test]
    fn a_full_file_loads_and_resolves_paths() {
        let c = load_str(
            "[source]\nuri = \"pupil://127.0.0.1:50020\"\ncalibration = \"p.json\"\n\
             [display]\nfps = 90.0\nsize = \"720x800\"\nheadless = true\n\
             [scene]\nhead = \"trace:h.csv\"\nyaw_deg = 10.0\n\
             [http]\naddr = \"127.0.0.1:8080\"\n[relay]\naddr = \"127.0.0.1:50030\"\n",
        )
        .unwrap();
        assert_eq!(c.display.fps, Some(90.0));
        assert!(c.source.calibration.unwrap().is_absolute());
        assert!(c.scene.head.unwrap().starts_with("trace:/"));
    }

    #[test]
    fn errors_name_the_field() {
        let e = load_str("[display]\nfps = -5.0\n").unwrap_err();
        assert_eq!(e.field(), Some("display.fps"));
        let e = e.to_string();
        assert!(e.contains("display.fps") && e.contains("-5"), "{e}");
        let e = load_str("[display]\nsize = \"720by800\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("display.size"), "{e}");
        let e = load_str("[source]\nurl = \"x\"\n").unwrap_err().to_string();
        assert!(e.contains("url"), "{e}");
        let e = load_str("[http]\naddr = \"localhost\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("http.addr"), "{e}");
        let e = load_str("[filter.dropout]\nhold_s = -1.0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("dropout.hold_s"), "{e}");
        let e = load_str("[scene]\nhead = \"spin\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("scene.head"), "{e}");
        let e = load_str("[observer]\nage_years = 300.0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("observer.age_years"), "{e}");
        let e = load_str("[observer]\npigmentation = -0.1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("observer.pigmentation"), "{e}");
        let e = load_str("[observer]\niris = 1\n").unwrap_err().to_string();
        assert!(e.contains("iris"), "{e}");
        let c = load_str("[observer]\nage_years = 70\npigmentation = 1.0\n").unwrap();
        assert_eq!(c.observer.age_years, Some(70.0));
        assert_eq!(c.observer.pigmentation, Some(1.0));
    }

    /// The file is named in every error, a read error with its reason
    /// underneath (as the CLI prints it, `cannot read config PATH: …`).
    #[test]
    fn a_missing_file_is_a_read_error_naming_it() {
        let missing =
            std::env::temp_dir().join(format!("gazelight-app-no-such-{}.toml", std::process::id()));
        let e = ServiceConfig::load(&missing).unwrap_err();
        assert!(matches!(e, ConfigError::Read { .. }), "{e:?}");
        let msg = crate::tests::chain(&e);
        assert!(
            msg.starts_with(&format!("cannot read config {}: ", missing.display())),
            "{msg}"
        );
    }

    /// A `[filter]` table alone: text and a value give the same result and
    /// the file's messages.
    #[test]
    fn a_filter_table_alone_is_checked_as_the_files() {
        let c = filter_from_str("dropout = { hold_s = 0.25 }\n").unwrap();
        assert_eq!(c.dropout.hold_s, 0.25);
        let mut dropout = toml::Table::new();
        dropout.insert("hold_s".into(), toml::Value::Float(0.25));
        let mut table = toml::Table::new();
        table.insert("dropout".into(), toml::Value::Table(dropout.clone()));
        assert_eq!(filter_from_value(toml::Value::Table(table)).unwrap(), c);
        let e = filter_from_str("dropout = { hold_s = -1.0 }\n").unwrap_err();
        assert!(
            matches!(&e, FilterConfigError::Invalid(_)) && e.to_string().contains("dropout.hold_s"),
            "{e}"
        );
        // The same words as the file's `[filter]`.
        let file = load_str("[filter.dropout]\nhold_s = -1.0\n").unwrap_err();
        assert!(file.to_string().ends_with(&e.to_string()), "{file} / {e}");
        let e = filter_from_str("confidence = [").unwrap_err();
        assert!(matches!(e, FilterConfigError::Syntax(_)), "{e}");
        let e = filter_from_str("confidense = {}").unwrap_err();
        assert!(e.to_string().contains("confidense"), "{e}");
    }
}
