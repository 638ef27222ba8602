//! The render configuration file (TOML). Every field is optional; unknown
//! fields are errors that name the field.
//!
//! ```toml
//! [scene]
//! luminance_scale = { kind = "cd_m2_per_unit", factor = 1.0 }
//! view = { yaw_deg = -78.0, pitch_deg = -4.0, hfov_deg = 90.0, width = 720, height = 800 }
//!
//! [pipeline]
//! pooling = { model = "gaussian", sigma_deg = 2.0 }
//! temporal = { model = "krawczyk", tau_rod_secs = 0.4, tau_cone_secs = 0.1 }
//! glare = { window_px = 256 }
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
