//! The OpenXR layer's configuration (`layer.toml`): its schema and loader,
//! here in the application core beside the CLI's and Python's
//! ([`crate::config`]), so the layer only calls it. One TOML file, `GAZELIGHT_LAYER_CONFIG` when
//! set, else `$XDG_CONFIG_HOME/gazelight/layer.toml` (`~/.config/…` when
//! `XDG_CONFIG_HOME` is unset). No file at the default place means the
//! defaults; a file named by `GAZELIGHT_LAYER_CONFIG` must exist.
//!
//! ```toml
//! source = "pupil://127.0.0.1:50020"   # any gazelight source URI
//! gaze = "gazelight"                   # or "runtime": the runtime's own eye tracker
//! effects = "on"                       # or "off"
//! out = "/tmp/layer-out"               # per-frame CSV (frames.csv)
//! dump = "/tmp/layer-dump"             # processed frames as PNG
//! dump_every = 30                      # every Nth processed frame per eye
//! white_cd_m2 = 200.0                  # 8-bit sRGB code 255 in cd/m²
//! scene_scale_cd_m2 = 100.0            # cd/m² per unit of a half-float image
//!
//! [filter]
//! dropout = { hold_s = 0.3 }
//!
//! [observer]
//! age_years = 25.0
//!
//! [pipeline]
//! pooling = { model = "gaussian", sigma_deg = 3.0 }
//! ```
//!
//! `[filter]` and `[pipeline]` are the library types `run` reads
//! (`gazelight_tracker::filter::FilterConfig`,
//! `gazelight_vision::pipeline::PipelineConfig`), checked the same way;
//! `[observer]` is the application core's
//! ([`crate::observer::ObserverSettings`]), as `run` and Python read it. The run's other
//! sections (`[scene]`, `[display]`, …) are refused: they do not apply to a
//! layer. An error names the file, line, column and field.
//!
//! The file is read with `gazelight_input::read_config`, as the CLI reads
//! its configs: a FIFO, a device or a file over 1 MiB is refused (the layer
//! then runs as the app without it, see `lib.rs`), never read into the
//! app's memory.

use std::ffi::OsString;
use std::ops::Range;
use std::path::{Path, PathBuf};

use gazelight_tracker::filter::FilterConfig;
use gazelight_tracker::uri::SourceUri;
use gazelight_vision::pipeline::PipelineConfig;
use serde::Deserialize;
use toml::Spanned;

/// The variable naming the config file.
pub const CONFIG_ENV: &str = "GAZELIGHT_LAYER_CONFIG";
/// `dump_every` when the file names none.
pub const DEFAULT_DUMP_EVERY: u32 = 30;
/// `white_cd_m2` when the file names none: a typical HMD's white.
pub const DEFAULT_WHITE_CD_M2: f64 = 200.0;
/// `scene_scale_cd_m2` when the file names none.
pub const DEFAULT_SCENE_SCALE_CD_M2: f64 = 100.0;

/// The source when the file names none: the one default of every front
/// end (Pupil Capture's default address).
pub use gazelight_tracker::uri::DEFAULT_SOURCE;

/// Where the gaze the app gets comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GazeMode {
    /// From the configured gazelight source.
    #[default]
    Gazelight,
    /// From the runtime's own eye tracker (the layer serves none).
    Runtime,
}

/// Whether the frame effects are applied.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Effects {
    #[default]
    On,
    Off,
}

/// `[observer]`: the application core's table, so its keys, ranges and
/// messages are `run`'s and Python's.
pub use crate::observer::ObserverSettings;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    source: Option<Spanned<String>>,
    gaze: Option<GazeMode>,
    effects: Option<Effects>,
    out: Option<PathBuf>,
    dump: Option<PathBuf>,
    dump_every: Option<Spanned<u32>>,
    white_cd_m2: Option<Spanned<f64>>,
    scene_scale_cd_m2: Option<Spanned<f64>>,
    filter: Option<Spanned<FilterConfig>>,
    observer: Option<Spanned<ObserverSettings>>,
    pipeline: Option<Spanned<PipelineConfig>>,
}

/// The layer's configuration, checked.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerConfig {
    pub source: SourceUri,
    pub gaze: GazeMode,
    pub effects: Effects,
    pub out: Option<PathBuf>,
    pub dump: Option<PathBuf>,
    /// Every Nth processed frame of each eye is dumped; ≥ 1.
    pub dump_every: u32,
    /// cd/m² of an 8-bit sRGB image's code 255; > 0.
    pub white_cd_m2: f64,
    /// cd/m² per unit of an `R16G16B16A16_SFLOAT` image; > 0.
    pub scene_scale_cd_m2: f64,
    pub filter: FilterConfig,
    pub observer: ObserverSettings,
    pub pipeline: PipelineConfig,
}

/// A config that cannot be used.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ConfigError {
    #[error("config {path}: cannot read: {reason}")]
    Read { path: PathBuf, reason: String },
    #[error("config {path}:{line}:{column}: {field}: {message}")]
    Invalid {
        path: PathBuf,
        /// 1-based.
        line: usize,
        /// 1-based, in characters.
        column: usize,
        /// The dotted key (`pipeline.pooling.sigma_deg`), as far as it is
        /// known.
        field: String,
        message: String,
    },
}

/// Where the config file is looked for.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ConfigLocation {
    /// Named by `GAZELIGHT_LAYER_CONFIG`: it must exist.
    Env(PathBuf),
    /// The default place: the defaults when it does not exist.
    Default(PathBuf),
}

impl ConfigLocation {
    pub fn path(&self) -> &Path {
        match self {
            Self::Env(p) | Self::Default(p) => p,
        }
    }

    /// Where the config is, given the environment (`env(name)`); `None`
    /// when neither the variables nor `HOME` say.
    pub fn resolve(env: impl Fn(&str) -> Option<OsString>) -> Option<Self> {
        let set = |name: &str| env(name).filter(|v| !v.is_empty());
        if let Some(p) = set(CONFIG_ENV) {
            return Some(Self::Env(PathBuf::from(p)));
        }
        // XDG Base Directory: a relative XDG_CONFIG_HOME is ignored.
        let base = set("XDG_CONFIG_HOME")
            .map(PathBuf::from)
            .filter(|p| p.is_absolute())
            .or_else(|| set("HOME").map(|h| PathBuf::from(h).join(".config")))?;
        Some(Self::Default(base.join("gazelight").join("layer.toml")))
    }
}

impl Default for LayerConfig {
    fn default() -> Self {
        Self {
            source: default_source(),
            gaze: GazeMode::default(),
            effects: Effects::default(),
            out: None,
            dump: None,
            dump_every: DEFAULT_DUMP_EVERY,
            white_cd_m2: DEFAULT_WHITE_CD_M2,
            scene_scale_cd_m2: DEFAULT_SCENE_SCALE_CD_M2,
            filter: FilterConfig::default(),
            observer: ObserverSettings::default(),
            pipeline: PipelineConfig::default(),
        }
    }
}

fn default_source() -> SourceUri {
    match SourceUri::parse(DEFAULT_SOURCE) {
        Ok(uri) => uri,
        // The constant parses (test `the_default_source_parses`).
        Err(e) => unreachable!("{DEFAULT_SOURCE}: {e}"),
    }
}

impl LayerConfig {
    /// The config of this process: from [`ConfigLocation::resolve`] on the
    /// process environment. `Ok(None)`: no file, the defaults apply.
    pub fn load_from_env() -> Result<Option<(PathBuf, Self)>, ConfigError> {
        match ConfigLocation::resolve(|n| std::env::var_os(n)) {
            None => Ok(None),
            Some(location) => Self::load_at(&location),
        }
    }

    /// Loads the file at `location`; a missing file at the default place
    /// is `Ok(None)`.
    pub fn load_at(location: &ConfigLocation) -> Result<Option<(PathBuf, Self)>, ConfigError> {
        let path = location.path();
        // The bounded reader, as every front end's config: regular files
        // only (a FIFO is refused without blocking the app's thread,
        // `/dev/zero` without reading it), at most
        // `gazelight_input::MAX_CONFIG_BYTES`, and its structure scanned
        // before the TOML parser builds anything.
        match gazelight_input::read_config(path, gazelight_input::ConfigSyntax::Toml) {
            Ok(text) => Self::parse(path, &text).map(|c| Some((path.to_path_buf(), c))),
            Err(e)
                if e.kind() == std::io::ErrorKind::NotFound
                    && matches!(location, ConfigLocation::Default(_)) =>
            {
                Ok(None)
            }
            Err(e) => Err(ConfigError::Read {
                path: path.to_path_buf(),
                reason: e.to_string(),
            }),
        }
    }

    /// Parses and checks the text of the file `path`.
    pub fn parse(path: &Path, text: &str) -> Result<Self, ConfigError> {
        let invalid = |span: Option<Range<usize>>, field: Option<String>, message: String| {
            let at = span.map_or(0, |s| s.start);
            let (line, column) = line_column(text, at);
            ConfigError::Invalid {
                path: path.to_path_buf(),
                line,
                column,
                field: field.unwrap_or_else(|| field_at(text, at)),
                message,
            }
        };
        let raw: RawConfig = toml::from_str(text)
            .map_err(|e| invalid(e.span(), None, e.message().trim().to_owned()))?;
        let source = match &raw.source {
            None => default_source(),
            Some(s) => SourceUri::parse(s.get_ref())
                .map_err(|e| invalid(Some(s.span()), Some("source".into()), e.to_string()))?,
        };
        if let Some(f) = &raw.filter {
            f.get_ref()
                .validate()
                .map_err(|e| invalid(Some(f.span()), Some("filter".into()), e.to_string()))?;
        }
        if let Some(p) = &raw.pipeline {
            p.get_ref()
                .validate()
                .map_err(|e| invalid(Some(p.span()), Some("pipeline".into()), e.to_string()))?;
        }
        if let Some(o) = &raw.observer {
            // The application core's check, which names the wrong field.
            o.get_ref()
                .validate_fields()
                .map_err(|(key, e)| invalid(Some(o.span()), Some(key.into()), e.to_string()))?;
        }
        // The luminance bound every front end shares
        // (`gazelight_vision::scene::MAX_SCALE_FACTOR`).
        let max = gazelight_vision::scene::MAX_SCALE_FACTOR;
        let positive = |v: &Option<Spanned<f64>>, key: &str, default: f64| match v {
            None => Ok(default),
            Some(x) if x.get_ref().is_finite() && *x.get_ref() > 0.0 && *x.get_ref() <= max => {
                Ok(*x.get_ref())
            }
            Some(x) => Err(invalid(Some(x.span()), Some(key.into()), {
                let v = *x.get_ref();
                let v = if v.abs() >= 1e9 {
                    format!("{v:e}")
                } else {
                    format!("{v}")
                };
                format!("{v}: expected a finite number > 0 and ≤ {max:e} cd/m²")
            })),
        };
        let white_cd_m2 = positive(&raw.white_cd_m2, "white_cd_m2", DEFAULT_WHITE_CD_M2)?;
        let scene_scale_cd_m2 = positive(
            &raw.scene_scale_cd_m2,
            "scene_scale_cd_m2",
            DEFAULT_SCENE_SCALE_CD_M2,
        )?;
        let dump_every = match &raw.dump_every {
            None => DEFAULT_DUMP_EVERY,
            Some(n) if *n.get_ref() >= 1 => *n.get_ref(),
            Some(n) => {
                return Err(invalid(
                    Some(n.span()),
                    Some("dump_every".into()),
                    "0: expected an integer ≥ 1".into(),
                ));
            }
        };
        Ok(Self {
            source,
            dump_every,
            white_cd_m2,
            scene_scale_cd_m2,
            gaze: raw.gaze.unwrap_or_default(),
            effects: raw.effects.unwrap_or_default(),
            out: raw.out,
            dump: raw.dump,
            filter: raw.filter.map(Spanned::into_inner).unwrap_or_default(),
            observer: raw.observer.map(Spanned::into_inner).unwrap_or_default(),
            pipeline: raw.pipeline.map(Spanned::into_inner).unwrap_or_default(),
        })
    }

    /// One line: what the config resolved to.
    pub fn summary(&self) -> String {
        let dir = |d: &Option<PathBuf>| {
            d.as_ref()
                .map_or("-".to_owned(), |p| p.display().to_string())
        };
        format!(
            "source {}, gaze {:?}, effects {:?}, out {}, dump {}, observer age {} pigmentation {}",
            self.source,
            self.gaze,
            self.effects,
            dir(&self.out),
            dir(&self.dump),
            self.observer
                .age_years
                .map_or("default".to_owned(), |a| format!("{a} years")),
            self.observer
                .pigmentation
                .map_or("default".to_owned(), |p| p.to_string()),
        )
    }
}

/// 1-based line and column (in characters) of byte `offset` in `text`.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = prefix(text, offset);
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (line, before[line_start..].chars().count() + 1)
}

/// `text` up to byte `offset`, shortened to a character boundary.
fn prefix(text: &str, offset: usize) -> &str {
    let mut end = offset.min(text.len());
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    &text[..end]
}

fn is_key_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.'
}

/// The dotted key at byte `offset`: the table header above it, the line's
/// first key and the innermost key before the offset (inline tables).
fn field_at(text: &str, offset: usize) -> String {
    let before = prefix(text, offset);
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let section = before[..line_start]
        .lines()
        .map(str::trim)
        .rfind(|l| l.starts_with('['))
        .map(|l| l.trim_matches(|c| c == '[' || c == ']').trim().to_owned());
    let on_line = &before[line_start..];
    let mut keys: Vec<String> = Vec::new();
    let mut parts = on_line.split('=').peekable();
    while let Some(part) = parts.next() {
        if parts.peek().is_none() {
            break;
        }
        let key: String = part
            .trim_end()
            .chars()
            .rev()
            .take_while(|c| is_key_char(*c))
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        if !key.is_empty() {
            keys.push(key);
        }
    }
    if keys.is_empty() {
        // The offset is at a key (an unknown field): the word there.
        let rest = &text[before.len()..];
        let word: String = rest.chars().take_while(|c| is_key_char(*c)).collect();
        if !word.is_empty() {
            keys.push(word);
        }
    } else if keys.len() > 2 {
        let last = keys.pop().unwrap_or_default();
        keys.truncate(1);
        keys.push(last);
    }
    section
        .into_iter()
        .chain(keys)
        .collect::<Vec<_>>()
        .join(".")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The documentation's example loads; a section of `run` is refused
    /// with its line and key; the observer's wrong field is named (the
    /// layer's own tests, `crates/gazelight-openxr-layer/tests/config.rs`,
    /// check the rest through the layer).
    #[test]
    fn the_doc_example_loads_and_errors_name_line_and_field() {
        let text = crate::config::tests::doc_example(include_str!("layer_config.rs"));
        assert!(text.contains("[observer]"), "{text}");
        let c = LayerConfig::parse(Path::new("doc.toml"), &text).unwrap();
        assert_eq!(c.dump_every, 30);
        assert_eq!(c.observer.age_years, Some(25.0));
        let e = LayerConfig::parse(
            Path::new("l.toml"),
            "gaze = \"runtime\"\n[display]\nfps = 1\n",
        )
        .unwrap_err();
        match e {
            ConfigError::Invalid { line, field, .. } => {
                assert_eq!((line, field.as_str()), (2, "display"))
            }
            other => panic!("{other:?}"),
        }
        let e = LayerConfig::parse(Path::new("l.toml"), "[observer]\npigmentation = 3.0\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("config l.toml:") && e.contains("observer.pigmentation: "),
            "{e}"
        );
    }
}
