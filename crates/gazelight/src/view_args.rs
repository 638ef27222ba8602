//! The view and scene-scale flags `render`, `replay` and `run` share, and
//! how they override a configuration.

use clap::Args;
use gazelight_vision::scene::{LuminanceScale, ProjectionKind, Scene, ViewParams};

/// `--scene-fov-deg H[,V]` and what a configuration file says about the
/// view: the application core's types (`gazelight_app::config`).
pub use gazelight_app::config::{SceneFov, ViewDefaults};

fn parse_fov(s: &str) -> Result<SceneFov, String> {
    let num = |t: &str| {
        t.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| format!("{t:?} is not a field in degrees > 0"))
    };
    match s.split_once(',') {
        Some((h, v)) => Ok(SceneFov {
            h_deg: num(h)?,
            v_deg: Some(num(v)?),
        }),
        None => Ok(SceneFov {
            h_deg: num(s)?,
            v_deg: None,
        }),
    }
}

fn parse_projection(s: &str) -> Result<ProjectionKind, String> {
    ProjectionKind::parse(s).ok_or_else(|| {
        format!(
            "expected one of {}",
            ProjectionKind::ALL.map(ProjectionKind::name).join(", ")
        )
    })
}

/// Head orientation, field of view and the scene's luminance scale.
#[derive(Args, Clone, Copy, Debug, Default)]
pub struct ViewArgs {
    /// Head yaw, degrees (positive right).
    #[arg(long, allow_hyphen_values = true)]
    pub yaw_deg: Option<f64>,
    /// Head pitch, degrees (positive up).
    #[arg(long, allow_hyphen_values = true)]
    pub pitch_deg: Option<f64>,
    /// Horizontal field of view, degrees.
    #[arg(long)]
    pub hfov_deg: Option<f64>,
    /// cd/m² per scene-file unit (the shared panoramas are relative).
    #[arg(long, conflicts_with = "scene_key_cd_m2")]
    pub luminance_scale: Option<f64>,
    /// Scale the scene so its median luminance is this many cd/m².
    #[arg(long)]
    pub scene_key_cd_m2: Option<f64>,
    /// The scene image's projection, when its file does not say (a
    /// Radiance VIEW= does): equirectangular, perspective, angular,
    /// hemispherical, equisolid, stereographic.
    #[arg(long, value_name = "KIND", value_parser = parse_projection)]
    pub scene_projection: Option<ProjectionKind>,
    /// The scene image's full field, degrees: `H` (square pixels) or `H,V`.
    #[arg(long, value_name = "H[,V]", value_parser = parse_fov, requires = "scene_projection")]
    pub scene_fov_deg: Option<SceneFov>,
}

impl ViewArgs {
    /// The view angles the flags gave, as `session.json`'s record takes
    /// them.
    pub fn angle_flags(&self) -> gazelight_app::session::ViewAngleFlags {
        gazelight_app::session::ViewAngleFlags {
            yaw_deg: self.yaw_deg,
            pitch_deg: self.pitch_deg,
            hfov_deg: self.hfov_deg,
        }
    }

    /// The luminance scale: a flag, else the configuration's, else the
    /// default; bounded ([`crate::bounds::luminance_scale`]).
    pub fn scale(&self, configured: Option<LuminanceScale>) -> anyhow::Result<LuminanceScale> {
        let scale = match (self.luminance_scale, self.scene_key_cd_m2) {
            (Some(factor), _) => LuminanceScale::CdM2PerUnit { factor },
            (None, Some(key_cd_m2)) => LuminanceScale::MedianKey { key_cd_m2 },
            (None, None) => configured.unwrap_or_default(),
        };
        Ok(crate::bounds::luminance_scale(scale)?)
    }

    /// Gives `scene` the projection of `--scene-projection` and
    /// `--scene-fov-deg`, else the configuration's `scene.projection` and
    /// `scene.fov_deg` (over its header's), if given.
    pub fn apply_projection(
        &self,
        scene: &mut Scene,
        configured: Option<(ProjectionKind, Option<SceneFov>)>,
    ) -> anyhow::Result<()> {
        let (kind, fov) = match (self.scene_projection, configured) {
            (Some(k), _) => (k, self.scene_fov_deg),
            (None, Some((k, f))) => (k, f),
            (None, None) => return Ok(()),
        };
        let (w, h) = (scene.image.width, scene.image.height);
        // The application core's rule (Python's config takes it too).
        scene.projection = Some(gazelight_app::config::render::scene_projection(
            (kind, fov),
            w,
            h,
        )?);
        Ok(())
    }

    /// The view: each angle from a flag, else the configuration, else
    /// `base`; the size is `(width, height)`.
    pub fn view(
        &self,
        configured: ViewDefaults,
        base: ViewParams,
        (width, height): (usize, usize),
    ) -> ViewParams {
        ViewParams {
            yaw_deg: self.yaw_deg.or(configured.yaw_deg).unwrap_or(base.yaw_deg),
            pitch_deg: self
                .pitch_deg
                .or(configured.pitch_deg)
                .unwrap_or(base.pitch_deg),
            hfov_deg: self
                .hfov_deg
                .or(configured.hfov_deg)
                .unwrap_or(base.hfov_deg),
            width,
            height,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_override_the_configuration_which_overrides_the_base() {
        let base = ViewParams {
            yaw_deg: 1.0,
            pitch_deg: 2.0,
            hfov_deg: 3.0,
            width: 8,
            height: 6,
        };
        let flags = ViewArgs {
            yaw_deg: Some(10.0),
            ..ViewArgs::default()
        };
        let cfg = ViewDefaults {
            yaw_deg: Some(20.0),
            pitch_deg: Some(30.0),
            hfov_deg: None,
        };
        let v = flags.view(cfg, base, (4, 2));
        assert_eq!(
            (v.yaw_deg, v.pitch_deg, v.hfov_deg, v.width, v.height),
            (10.0, 30.0, 3.0, 4, 2)
        );
        let s = ViewArgs {
            scene_key_cd_m2: Some(20.0),
            ..ViewArgs::default()
        }
        .scale(Some(LuminanceScale::CdM2PerUnit { factor: 5.0 }))
        .unwrap();
        assert_eq!(s, LuminanceScale::MedianKey { key_cd_m2: 20.0 });
        assert!(
            ViewArgs {
                luminance_scale: Some(1e308),
                ..ViewArgs::default()
            }
            .scale(None)
            .is_err()
        );
    }
}
