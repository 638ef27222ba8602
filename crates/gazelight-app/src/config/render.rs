//! The configuration of `render` and `replay` (the CLI's and Python's
//! `gazelight.render`): the one configuration file of every command
//! ([`super::ServiceConfig`], the schema `run` reads), of which these two
//! use `[scene]` (scene file, luminance scale, view, projection),
//! `display.size`, `[pipeline]`, `[filter]` and `[observer]` (and
//! `replay` `source.calibration`); other keys are reported as ignored.
//! Every section and key, with its default and unit:
//! `docs/configuration.md`. The example below is loaded by the test
//! `the_module_doc_example_loads`.
//!
//! ```toml
//! [scene]
//! luminance_scale = { kind = "cd_m2_per_unit", factor = 1.0 }
//! view = { yaw_deg = -78.0, pitch_deg = -4.0, hfov_deg = 90.0, width = 720, height = 800 }
//!
//! [pipeline]
//! pooling = { model = "gaussian", sigma_deg = 2.0 }
//! temporal = { model = "krawczyk", tau_rod_secs = 0.4, tau_cone_secs = 0.1 }
//! glare = { full_weight_deg = 12.0, fade_sigma_deg = 2.0, psf_rebuild_threshold_mm = 0.1 }
//!
//! [observer]
//! age_years = 25.0
//!
//! [filter]
//! dropout = { hold_s = 0.3 }
//! ```

use std::path::{Path, PathBuf};

use gazelight_tracker::filter::FilterConfig;
use gazelight_vision::VisionError;
use gazelight_vision::pipeline::PipelineConfig;
use gazelight_vision::scene::{LuminanceScale, ProjectionKind, SceneProjection};

use super::{ConfigError, ConfigUser, FieldError, ProjectionSettings, ServiceConfig};
use crate::observer::ObserverSettings;

/// The scene image's full field, degrees (`--scene-fov-deg H[,V]`,
/// `scene.fov_deg = [H]` or `[H, V]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneFov {
    pub h_deg: f64,
    pub v_deg: Option<f64>,
}

impl SceneFov {
    /// One or two fields, each finite and > 0; `None` otherwise.
    pub fn from_degrees(v: &[f64]) -> Option<Self> {
        let ok = |f: &f64| f.is_finite() && *f > 0.0;
        match v {
            [h] if ok(h) => Some(Self {
                h_deg: *h,
                v_deg: None,
            }),
            [h, v] if ok(h) && ok(v) => Some(Self {
                h_deg: *h,
                v_deg: Some(*v),
            }),
            _ => None,
        }
    }
}

/// What a configuration file says about the view (each `None` = unset).
#[derive(Clone, Copy, Debug, Default)]
pub struct ViewDefaults {
    pub yaw_deg: Option<f64>,
    pub pitch_deg: Option<f64>,
    pub hfov_deg: Option<f64>,
}

/// A scene projection that cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum ProjectionError {
    /// A projection other than equirectangular without its field.
    #[error("--scene-projection {0} needs --scene-fov-deg")]
    NeedsFov(&'static str),
    /// A field the projection cannot map.
    #[error("--scene-fov-deg")]
    Fov(#[source] VisionError),
}

/// The projection of a `width_px`×`height_px` scene image of `kind` with
/// the field `fov` (`--scene-projection`/`--scene-fov-deg`, or
/// `scene.projection`/`scene.fov_deg`).
pub fn scene_projection(
    (kind, fov): ProjectionSettings,
    width_px: usize,
    height_px: usize,
) -> Result<SceneProjection, ProjectionError> {
    match (kind, fov) {
        (ProjectionKind::Equirectangular, _) => {
            Ok(SceneProjection::equirectangular(width_px, height_px))
        }
        (_, None) => Err(ProjectionError::NeedsFov(kind.name())),
        (_, Some(SceneFov { h_deg, v_deg: None })) => {
            SceneProjection::with_square_pixels(kind, h_deg, width_px, height_px)
                .map_err(ProjectionError::Fov)
        }
        (
            _,
            Some(SceneFov {
                h_deg,
                v_deg: Some(v),
            }),
        ) => {
            SceneProjection::new(kind, h_deg, v, width_px, height_px).map_err(ProjectionError::Fov)
        }
    }
}

/// What `render` and `replay` take from the configuration file.
#[derive(Clone, Debug, Default)]
pub struct RenderConfig {
    /// `scene.file`: the HDR scene when `--scene` is not given.
    pub scene_file: Option<PathBuf>,
    /// `scene.luminance_scale`.
    pub luminance_scale: Option<LuminanceScale>,
    /// `scene.projection` and `scene.fov_deg`.
    pub projection: Option<ProjectionSettings>,
    /// `scene.yaw_deg`, `pitch_deg`, `hfov_deg` (or `scene.view`).
    pub view: ViewDefaults,
    /// `display.size` (or `scene.view`'s width and height).
    pub size: Option<(usize, usize)>,
    pub pipeline: PipelineConfig,
    /// `[filter]`: the tracker's filter chain the samples go through.
    pub filter: FilterConfig,
    /// `[observer]`.
    pub observer: ObserverSettings,
    /// `source.calibration` (`replay` only).
    pub calibration: Option<PathBuf>,
    /// The file's keys that do not apply (reported on load).
    pub ignored: Vec<String>,
}

impl RenderConfig {
    /// Loads and validates the configuration file for `user` (`render` or
    /// `replay`).
    pub fn load(path: &Path, user: ConfigUser) -> Result<Self, ConfigError> {
        let (config, ignored) = ServiceConfig::load_for(path, user)?;
        Self::from_service(config, ignored, path, user)
    }

    /// [`Self::load`] on text already read (`origin`: the file it came
    /// from, or a name).
    pub fn from_str(text: &str, origin: &Path, user: ConfigUser) -> Result<Self, ConfigError> {
        let (config, ignored) = ServiceConfig::from_str_for(text, origin, user)?;
        Self::from_service(config, ignored, origin, user)
    }

    /// [`Self::load`] on a table already built (Python's dict).
    pub fn from_table(
        table: toml::Table,
        origin: &Path,
        user: ConfigUser,
    ) -> Result<Self, ConfigError> {
        let (config, ignored) = ServiceConfig::from_table_for(table, origin, user)?;
        Self::from_service(config, ignored, origin, user)
    }

    fn from_service(
        config: ServiceConfig,
        ignored: Vec<String>,
        origin: &Path,
        user: ConfigUser,
    ) -> Result<Self, ConfigError> {
        // Both were checked on load; kept fallible all the same.
        let invalid = |field: &str, message: String| ConfigError::Invalid {
            path: origin.to_path_buf(),
            error: FieldError::new(field, message),
        };
        let size = config
            .display
            .size
            .as_deref()
            .map(super::parse_size)
            .transpose()
            .map_err(|e| invalid("display.size", format!("display.size = {e}")))?;
        let projection = config
            .scene
            .projection_settings()
            .map_err(|e| invalid("scene.projection", format!("scene.projection/fov_deg: {e}")))?;
        Ok(Self {
            scene_file: config.scene.file,
            luminance_scale: config.scene.luminance_scale,
            projection,
            view: ViewDefaults {
                yaw_deg: config.scene.yaw_deg,
                pitch_deg: config.scene.pitch_deg,
                hfov_deg: config.scene.hfov_deg,
            },
            size,
            pipeline: config.pipeline,
            filter: config.filter,
            observer: config.observer,
            calibration: (user == ConfigUser::Replay)
                .then_some(config.source.calibration)
                .flatten(),
            ignored,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::tests::doc_example;

    #[test]
    fn the_module_doc_example_loads() {
        let text = doc_example(include_str!("render.rs"));
        assert!(text.contains("[pipeline]"), "no example found: {text}");
        let dir =
            std::env::temp_dir().join(format!("gazelight-app-render-doc-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("render.toml");
        std::fs::write(&path, &text).unwrap();
        let loaded = RenderConfig::load(&path, ConfigUser::Render);
        let _ = std::fs::remove_dir_all(&dir);
        let config = loaded.unwrap();
        assert_eq!(config.pipeline.glare.full_weight_deg, 12.0);
        assert_eq!(config.view.yaw_deg, Some(-78.0));
        assert_eq!(config.size, Some((720, 800)));
        assert_eq!(config.observer.age_years, Some(25.0));
        assert_eq!(config.filter.dropout.hold_s, 0.3);
        assert!(config.ignored.is_empty(), "{:?}", config.ignored);
        // The key the example used to show is refused (tests/cli.rs too).
        let bad = text.replace("glare = {", "glare = { window_px = 256,");
        assert!(toml::from_str::<ServiceConfig>(&bad).is_err());
        // Text and a file give the same configuration; text names its origin.
        let same =
            RenderConfig::from_str(&text, Path::new("<config>"), ConfigUser::Render).unwrap();
        assert_eq!(same.size, config.size);
        assert_eq!(same.pipeline, config.pipeline);
        let e = RenderConfig::from_str(&bad, Path::new("<config>"), ConfigUser::Render)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("config <config>: ") && e.contains("window_px"),
            "{e}"
        );
    }

    /// `replay` takes `source.calibration`, resolved against the file's
    /// directory; `render` reports it as ignored.
    #[test]
    fn calibration_is_replays_and_resolved() {
        let text = "[source]\ncalibration = \"p.json\"\n";
        let origin = Path::new("/study/run.toml");
        let replay = RenderConfig::from_str(text, origin, ConfigUser::Replay).unwrap();
        assert_eq!(
            replay.calibration.as_deref(),
            Some(Path::new("/study/p.json"))
        );
        assert!(replay.ignored.is_empty(), "{:?}", replay.ignored);
        let render = RenderConfig::from_str(text, origin, ConfigUser::Render).unwrap();
        assert_eq!(render.calibration, None);
        assert_eq!(render.ignored, vec!["source".to_owned()]);
    }

    #[test]
    fn a_projection_needs_its_field() {
        let e = scene_projection((ProjectionKind::Angular, None), 64, 64).unwrap_err();
        assert_eq!(
            e.to_string(),
            "--scene-projection angular needs --scene-fov-deg"
        );
        assert!(scene_projection((ProjectionKind::Equirectangular, None), 64, 32).is_ok());
        let fov = SceneFov::from_degrees(&[180.0]);
        assert!(scene_projection((ProjectionKind::Angular, fov), 64, 64).is_ok());
        assert_eq!(SceneFov::from_degrees(&[]), None);
        assert_eq!(SceneFov::from_degrees(&[90.0, f64::NAN]), None);
        assert_eq!(SceneFov::from_degrees(&[1.0, 2.0, 3.0]), None);
    }
}
