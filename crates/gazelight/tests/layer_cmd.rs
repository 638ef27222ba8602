//! `gazelight layer install | status | uninstall` as a user runs them, with
//! a temporary XDG_DATA_HOME and XDG_CONFIG_HOME (never the real ones) and
//! a stand-in runtime manifest (XR_RUNTIME_JSON).
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
    let runtime_lib = dir.join("libstand_in_runtime.so");
    std::fs::write(&runtime_lib, b"stand-in").unwrap();
    let runtime = dir.join("runtime.json");
    std::fs::write(
        &runtime,
        format!(
            r#"{{"file_format_version": "1.0.0", "runtime": {{"name": "stand-in", "library_path": "{}"}}}}"#,
            runtime_lib.display()
        ),
    )
    .unwrap();
    let (d, c, l, r) = (
        data.to_str().unwrap(),
        config.to_str().unwrap(),
        lib.to_str().unwrap(),
        runtime.to_str().unwrap(),
    );
    let env = [
        ("XDG_DATA_HOME", d),
        ("XDG_CONFIG_HOME", c),
        ("GAZELIGHT_LAYER_CONFIG", ""),
        ("XR_ENABLE_API_LAYERS", ""),
        ("DISABLE_XR_APILAYER_GAZELIGHT_PERCEPTION", ""),
        ("XR_RUNTIME_JSON", r),
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
    assert!(s.contains("runtime \"stand-in\": "), "{s}");
    assert!(s.contains("loader: "), "{s}");

    // A bad layer.toml: reported with its line, and the status fails.
    std::fs::write(config.join("gazelight/layer.toml"), "effects = \"maybe\"\n").unwrap();
    let o = gazelight_env(&["layer", "status"], &env);
    let s = text(&o);
    assert!(!o.status.success(), "{s}");
    assert!(s.contains("layer.toml:1:"), "{s}");
    assert!(s.contains("the layer config is invalid"), "{s}");
    std::fs::write(config.join("gazelight/layer.toml"), "effects = \"off\"\n").unwrap();

    // No runtime: reported, and the status fails.
    let gone = dir.join("gone.json");
    let mut no_runtime = env.to_vec();
    no_runtime.retain(|(k, _)| *k != "XR_RUNTIME_JSON");
    no_runtime.push(("XR_RUNTIME_JSON", gone.to_str().unwrap()));
    let o = gazelight_env(&["layer", "status"], &no_runtime);
    let s = text(&o);
    assert!(!o.status.success(), "{s}");
    assert!(s.contains("runtime: not found"), "{s}");

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
