//! Config errors name the file, line and field; the defaults and the
//! resolution of the file's place.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use gazelight_openxr_layer::config::{ConfigError, ConfigLocation, Effects, GazeMode, LayerConfig};

fn err(text: &str) -> (usize, usize, String, String) {
    match LayerConfig::parse(Path::new("/etc/layer.toml"), text) {
        Err(ConfigError::Invalid {
            path,
            line,
            column,
            field,
            message,
        }) => {
            assert_eq!(path, Path::new("/etc/layer.toml"));
            (line, column, field, message)
        }
        other => panic!("expected an invalid config, got {other:?}"),
    }
}

#[test]
fn an_unknown_key_in_a_section_names_its_line_and_field() {
    let (line, column, field, message) =
        err("source = \"pupil://127.0.0.1:50020\"\n\n[pipeline]\nglare = { window_px = 256 }\n");
    assert_eq!((line, column), (4, 11));
    assert_eq!(field, "pipeline.glare");
    assert!(message.contains("window_px"), "{message}");
}

#[test]
fn a_wrong_value_names_its_key() {
    let (line, _, field, message) = err("effects = \"on\"\ngaze = \"eyes\"\n");
    assert_eq!(line, 2);
    assert_eq!(field, "gaze");
    assert!(message.contains("eyes"), "{message}");
    let (line, _, field, message) =
        err("[pipeline]\npooling = { model = \"gaussian\", sigma_deg = \"two\" }\n");
    assert_eq!(line, 2);
    assert_eq!(field, "pipeline.pooling", "{message}");
    assert!(message.contains("two"), "{message}");
    let (line, _, field, _) = err("effects = true\n");
    assert_eq!((line, field.as_str()), (1, "effects"));
}

#[test]
fn a_section_of_run_that_does_not_apply_is_refused() {
    let (line, _, field, message) = err("gaze = \"runtime\"\n[scene]\nfile = \"x.exr\"\n");
    assert_eq!(line, 2);
    assert_eq!(field, "scene");
    assert!(message.contains("scene"), "{message}");
}

#[test]
fn a_bad_source_uri_names_source() {
    let (line, _, field, message) = err("\nsource = \"pupil://127.0.0.1:notaport\"\n");
    assert_eq!((line, field.as_str()), (2, "source"));
    assert!(message.contains("port"), "{message}");
}

#[test]
fn values_out_of_range_are_refused_with_their_field() {
    let (line, _, field, message) = err("gaze = \"gazelight\"\n[observer]\nage_years = 300.0\n");
    assert_eq!(field, "observer.age_years");
    assert!(message.contains("300"), "{message}");
    assert!((2..=3).contains(&line), "line {line}");
    let (_, _, field, message) = err("[filter]\ndropout = { hold_s = -1.0 }\n");
    assert_eq!(field, "filter");
    assert!(message.contains("hold_s"), "{message}");
}

#[test]
fn the_module_doc_example_loads() {
    let src = include_str!("../../gazelight-app/src/layer_config.rs");
    let text: String = src
        .lines()
        .skip_while(|l| l.trim() != "//! ```toml")
        .skip(1)
        .take_while(|l| l.trim() != "//! ```")
        .map(|l| l.trim_start_matches("//!").strip_prefix(' ').unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    assert!(text.contains("[pipeline]"), "{text}");
    let c = LayerConfig::parse(Path::new("doc.toml"), &text).unwrap();
    assert_eq!(c.source.to_string(), "pupil://127.0.0.1:50020");
    assert_eq!(c.gaze, GazeMode::Gazelight);
    assert_eq!(c.effects, Effects::On);
    assert_eq!(c.out.as_deref(), Some(Path::new("/tmp/layer-out")));
    assert_eq!(c.filter.dropout.hold_s, 0.3);
    assert_eq!(c.observer.age_years, Some(25.0));
    assert_eq!(
        format!("{:?}", c.pipeline.pooling),
        "Gaussian { sigma_deg: 3.0 }"
    );
    // An empty file is the defaults.
    assert_eq!(
        LayerConfig::parse(Path::new("e.toml"), "").unwrap(),
        LayerConfig::default()
    );
}

fn env<'a>(vars: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<OsString> + 'a {
    move |n| {
        vars.iter()
            .find(|(k, _)| *k == n)
            .map(|(_, v)| OsString::from(v))
    }
}

#[test]
fn the_file_is_found_by_variable_then_xdg_then_home() {
    let all = [
        ("GAZELIGHT_LAYER_CONFIG", "/x/my.toml"),
        ("XDG_CONFIG_HOME", "/cfg"),
        ("HOME", "/home/u"),
    ];
    assert_eq!(
        ConfigLocation::resolve(env(&all)),
        Some(ConfigLocation::Env(PathBuf::from("/x/my.toml")))
    );
    assert_eq!(
        ConfigLocation::resolve(env(&all[1..])),
        Some(ConfigLocation::Default(PathBuf::from(
            "/cfg/gazelight/layer.toml"
        )))
    );
    // A relative XDG_CONFIG_HOME is ignored (XDG Base Directory spec).
    assert_eq!(
        ConfigLocation::resolve(env(&[("XDG_CONFIG_HOME", "rel"), ("HOME", "/home/u")])),
        Some(ConfigLocation::Default(PathBuf::from(
            "/home/u/.config/gazelight/layer.toml"
        )))
    );
    assert_eq!(ConfigLocation::resolve(env(&[])), None);
}

#[test]
fn a_missing_file_is_the_defaults_only_at_the_default_place() {
    let missing =
        std::env::temp_dir().join(format!("gazelight-no-such-{}.toml", std::process::id()));
    assert_eq!(
        LayerConfig::load_at(&ConfigLocation::Default(missing.clone())),
        Ok(None)
    );
    match LayerConfig::load_at(&ConfigLocation::Env(missing.clone())) {
        Err(ConfigError::Read { path, .. }) => assert_eq!(path, missing),
        other => panic!("{other:?}"),
    }
}

#[test]
fn the_luminance_mapping_and_dump_keys_are_checked() {
    let (line, _, field, message) = err("effects = \"on\"\nwhite_cd_m2 = -80.0\n");
    assert_eq!((line, field.as_str()), (2, "white_cd_m2"), "{message}");
    let (line, _, field, _) = err("scene_scale_cd_m2 = 0.0\n");
    assert_eq!((line, field.as_str()), (1, "scene_scale_cd_m2"));
    let (line, _, field, _) = err("out = \"/tmp\"\ndump_every = 0\n");
    assert_eq!((line, field.as_str()), (2, "dump_every"));
    let c = LayerConfig::parse(
        Path::new("/etc/layer.toml"),
        "white_cd_m2 = 250.0\nscene_scale_cd_m2 = 80.0\ndump_every = 3\n",
    )
    .unwrap();
    assert_eq!(
        (c.white_cd_m2, c.scene_scale_cd_m2, c.dump_every),
        (250.0, 80.0, 3)
    );
}

/// A scratch directory of this test process.
fn scratch(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("gazelight-layer-cfg-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `load_at` on `path` in a thread: its error, or a panic when it has not
/// returned within 10 s (a blocking open or an endless read).
fn read_error_within_10s(path: PathBuf) -> String {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(LayerConfig::load_at(&ConfigLocation::Env(path)));
    });
    match rx.recv_timeout(std::time::Duration::from_secs(10)) {
        Ok(Err(ConfigError::Read { reason, .. })) => reason,
        Ok(other) => panic!("expected a read error, got {other:?}"),
        Err(_) => panic!("the config load did not return within 10 s"),
    }
}

#[test]
fn an_oversized_config_is_refused_by_its_size_before_reading() {
    let dir = scratch("big");
    let path = dir.join("layer.toml");
    // 40 MB of comment lines: valid TOML, read whole it would become a
    // 40 MB String in the app's process. Sparse, so the test writes little.
    let f = std::fs::File::create(&path).unwrap();
    f.set_len(40_000_000).unwrap();
    drop(f);
    let reason = read_error_within_10s(path);
    assert!(reason.contains("limit"), "{reason}");
    assert!(reason.contains("40000000"), "{reason}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[cfg(unix)]
#[test]
fn a_fifo_or_a_device_as_config_is_refused_without_blocking() {
    let dir = scratch("fifo");
    let fifo = dir.join("layer.toml");
    let ok = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success();
    assert!(ok);
    // No writer ever opens it: a plain open would block forever.
    let reason = read_error_within_10s(fifo);
    assert!(reason.contains("FIFO"), "{reason}");
    let reason = read_error_within_10s(PathBuf::from("/dev/zero"));
    assert!(reason.contains("character device"), "{reason}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_config_with_a_huge_array_is_refused_before_parsing() {
    let dir = scratch("array");
    let path = dir.join("layer.toml");
    // Under the byte limit, but 200 k values: refused by the structure scan.
    let mut text = String::from("dump_every = [");
    text.push_str(&"1,".repeat(200_000));
    text.push_str("1]\n");
    std::fs::write(&path, text).unwrap();
    let reason = read_error_within_10s(path);
    assert!(reason.contains("values"), "{reason}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn luminance_keys_share_the_clis_upper_bound() {
    // 1e308 cd/m² per unit is refused here as by `render --luminance-scale`.
    for key in ["white_cd_m2", "scene_scale_cd_m2"] {
        let (line, _, field, message) = err(&format!("effects = \"on\"\n{key} = 1e308\n"));
        assert_eq!((line, field.as_str()), (2, key), "{message}");
        assert!(
            message.contains("1e308") && message.contains("1e20"),
            "{message}"
        );
    }
    // The bound itself is accepted.
    let c = LayerConfig::parse(Path::new("l.toml"), "white_cd_m2 = 1e20\n").unwrap();
    assert_eq!(c.white_cd_m2, gazelight_vision::scene::MAX_SCALE_FACTOR);
}
