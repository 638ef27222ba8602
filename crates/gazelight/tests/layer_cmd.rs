//! `gazelight layer install | status | uninstall` as a user runs them, with
//! a temporary XDG_DATA_HOME and XDG_CONFIG_HOME (never the real ones).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{gazelight_env, tmp};

#[test]
fn install_status_uninstall_in_a_temp_data_home() {
    let dir = tmp("layer-cmd");
    let data = dir.join("data");
    let config = dir.join("config");
    let lib = dir.join("libgazelight_openxr_layer.so");
    std::fs::write(&lib, b"stand-in").unwrap();
    std::fs::create_dir_all(config.join("gazelight")).unwrap();
    std::fs::write(config.join("gazelight/layer.toml"), "effects = \"off\"\n").unwrap();
    let (d, c, l) = (
        data.to_str().unwrap(),
        config.to_str().unwrap(),
        lib.to_str().unwrap(),
    );
    let env = [
        ("XDG_DATA_HOME", d),
        ("XDG_CONFIG_HOME", c),
        ("GAZELIGHT_LAYER_CONFIG", ""),
        ("XR_ENABLE_API_LAYERS", ""),
        ("DISABLE_XR_APILAYER_GAZELIGHT_PERCEPTION", ""),
    ];
    let text = |o: &std::process::Output| {
        format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        )
    };

    let o = gazelight_env(&["layer", "install", "--implicit", "--library", l], &env);
    assert!(o.status.success(), "{}", text(&o));
    let manifest =
        data.join("openxr/1/api_layers/implicit.d/XR_APILAYER_GAZELIGHT_perception.json");
    assert!(manifest.is_file(), "{}", text(&o));

    let o = gazelight_env(&["layer", "status"], &env);
    let s = text(&o);
    assert!(o.status.success(), "{s}");
    assert!(s.contains("explicit: not installed"), "{s}");
    // Present, even empty, the variable disables it (as in the loader).
    assert!(
        s.contains("DISABLE_XR_APILAYER_GAZELIGHT_PERCEPTION is set: not loaded"),
        "{s}"
    );
    assert!(s.contains("effects Off"), "{s}");

    let o = gazelight_env(&["layer", "uninstall"], &env);
    assert!(o.status.success() && !manifest.exists(), "{}", text(&o));

    // A library that does not exist: refused, nothing written.
    let missing = dir.join("nope.so");
    let o = gazelight_env(
        &["layer", "install", "--library", missing.to_str().unwrap()],
        &env,
    );
    assert!(!o.status.success());
    assert!(text(&o).contains("nope.so"), "{}", text(&o));
    assert!(!data.join("openxr/1/api_layers/explicit.d").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
