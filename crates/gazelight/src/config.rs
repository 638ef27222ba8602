//! The render configuration file (TOML). Every field is optional; unknown
//! fields are errors that name the field. Every section and key, with its
//! default and unit: `docs/configuration.md`. The example below is loaded
//! by the test `the_module_doc_example_loads`.
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
//! ```

use std::path::Path;

use anyhow::Context;
use gazelight_vision::pipeline::PipelineConfig;
use gazelight_vision::scene::{LuminanceScale, ViewParams};
use serde::{Deserialize, Serialize};

/// Scene settings.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneSettings {
    /// cd/m² per file unit, or a median key.
    pub luminance_scale: Option<LuminanceScale>,
    /// Head orientation, field of view and display size.
    pub view: Option<ViewParams>,
}

/// The whole render configuration.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RenderConfig {
    pub scene: SceneSettings,
    pub pipeline: PipelineConfig,
}

impl RenderConfig {
    /// Loads and validates a TOML file.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = gazelight_input::read_config(path, gazelight_input::ConfigSyntax::Toml)
            .with_context(|| format!("cannot read config {}", path.display()))?;
        let config: Self =
            toml::from_str(&text).map_err(|e| anyhow::anyhow!("config {}: {e}", path.display()))?;
        config
            .pipeline
            .validate()
            .with_context(|| format!("config {}: [pipeline]", path.display()))?;
        if let Some(scale) = &config.scene.luminance_scale {
            scale
                .validate()
                .with_context(|| format!("config {}: [scene]", path.display()))?;
        }
        if let Some(view) = &config.scene.view {
            view.validate()
                .with_context(|| format!("config {}: [scene]", path.display()))?;
        }
        Ok(config)
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
        let loaded = RenderConfig::load(&path);
        let _ = std::fs::remove_dir_all(&dir);
        let config = loaded.unwrap();
        assert_eq!(config.pipeline.glare.full_weight_deg, 12.0);
        // The key the example used to show is refused (tests/cli.rs too).
        let bad = text.replace("glare = {", "glare = { window_px = 256,");
        assert!(toml::from_str::<RenderConfig>(&bad).is_err());
    }
}
