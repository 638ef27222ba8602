//! The configuration of `render` and `replay`: the one configuration file
//! of every command ([`crate::service_config::ServiceConfig`], the schema
//! `run` reads), of which these two use `[scene]` (scene file, luminance
//! scale, view), `display.size`, `[pipeline]`, `[filter]` and `[observer]`
//! (and `replay` `source.calibration`); other keys are reported as ignored.
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
use gazelight_vision::pipeline::PipelineConfig;
use gazelight_vision::scene::LuminanceScale;

use crate::observer::ObserverSettings;
use crate::service_config::{ConfigUser, ServiceConfig};
use crate::view_args::ViewDefaults;

/// What `render` and `replay` take from the configuration file.
#[derive(Clone, Debug, Default)]
pub struct RenderConfig {
    /// `scene.file`: the HDR scene when `--scene` is not given.
    pub scene_file: Option<PathBuf>,
    /// `scene.luminance_scale`.
    pub luminance_scale: Option<LuminanceScale>,
    /// `scene.projection` and `scene.fov_deg`.
    pub projection: Option<(
        gazelight_vision::scene::ProjectionKind,
        Option<crate::view_args::SceneFov>,
    )>,
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
    pub fn load(path: &Path, user: ConfigUser) -> anyhow::Result<Self> {
        let (config, ignored) = ServiceConfig::load_for(path, user)?;
        let size = config
            .display
            .size
            .as_deref()
            .map(crate::service_config::parse_size)
            .transpose()
            .map_err(|e| anyhow::anyhow!("config {}: display.size = {e}", path.display()))?;
        let projection = config.scene.projection_settings()?;
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
pub(crate) mod tests {
    use super::*;

    /// The TOML example of this module's documentation.
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

    #[test]
    fn the_module_doc_example_loads() {
        let text = doc_example(include_str!("config.rs"));
        assert!(text.contains("[pipeline]"), "no example found: {text}");
        let dir = std::env::temp_dir().join(format!("gazelight-render-doc-{}", std::process::id()));
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
    }
}
