//! The bounds on every number a user gives live in the application core
//! (`gazelight_app::bounds`), shared with the Python module and the OpenXR
//! layer; here the CLI only shows a scene's luminance warning on stderr.

pub use gazelight_app::bounds::*;

/// [`gazelight_app::bounds::scene_luminance`], its warning (an implausibly
/// bright scene) logged and printed.
pub fn scene_luminance(scene: &gazelight_vision::scene::Scene) -> anyhow::Result<SceneRange> {
    let range = gazelight_app::bounds::scene_luminance(scene)?;
    if let Some(msg) = &range.warning {
        tracing::warn!("{msg}");
        eprintln!("warning: {msg}");
    }
    Ok(range)
}
