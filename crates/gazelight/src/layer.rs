//! `gazelight layer install [--implicit] | uninstall | status`: the OpenXR
//! API layer's manifest (crate `gazelight-openxr-layer`) in the user's data
//! directory, where the Khronos loader looks for it:
//! `$XDG_DATA_HOME/openxr/1/api_layers/{explicit,implicit}.d/` (XDG_DATA_HOME
//! defaults to `~/.local/share`).
//!
//! An explicit layer is loaded when the app or `XR_ENABLE_API_LAYERS` names
//! it; an implicit one in every OpenXR app, unless the variable of its
//! manifest's `disable_environment` is set. `status` says which manifests
//! are there, whether the library they name exists, whether the loader will
//! load the layer in this environment, whether an OpenXR loader and the
//! active runtime are found, and what the layer's config resolves to; it
//! exits non-zero on a bad config (the layer would pass everything through)
//! and when no runtime is found (no OpenXR app can start).

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use gazelight_openxr_layer::config::{ConfigLocation, LayerConfig};
use gazelight_openxr_layer::{DISABLE_ENV, LAYER_NAME};

/// The layer library's file name, beside the `gazelight` executable in a
/// cargo build (`cargo build -p gazelight-openxr-layer`).
pub const LIBRARY_FILE: &str = "libgazelight_openxr_layer.so";

/// Arguments of `gazelight layer`.
#[derive(Args, Debug)]
pub struct LayerArgs {
    #[command(subcommand)]
    pub action: LayerAction,
}

#[derive(Subcommand, Debug)]
pub enum LayerAction {
    /// Write the layer's manifest (explicit: loaded when
    /// XR_ENABLE_API_LAYERS names it; --implicit: in every OpenXR app).
    Install {
        /// Install as an implicit layer (disable with
        /// DISABLE_XR_APILAYER_GAZELIGHT_PERCEPTION=1).
        #[arg(long)]
        implicit: bool,
        /// The layer library (default: libgazelight_openxr_layer.so beside
        /// this executable).
        #[arg(long, value_name = "PATH")]
        library: Option<PathBuf>,
    },
    /// Remove the explicit and the implicit manifest.
    Uninstall,
    /// Whether the loader will find the layer, whether an OpenXR loader and
    /// the active runtime are found, and what the layer's config resolves
    /// to; exits non-zero on a bad config or without a runtime.
    Status,
}

/// Explicit or implicit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Explicit,
    Implicit,
}

impl Kind {
    fn dir(self) -> &'static str {
        match self {
            Self::Explicit => "explicit.d",
            Self::Implicit => "implicit.d",
        }
    }
}

/// `$XDG_DATA_HOME` (absolute), else `$HOME/.local/share`.
pub fn data_home(env: &dyn Fn(&str) -> Option<OsString>) -> anyhow::Result<PathBuf> {
    let set = |n: &str| env(n).filter(|v| !v.is_empty()).map(PathBuf::from);
    if let Some(p) = set("XDG_DATA_HOME").filter(|p| p.is_absolute()) {
        return Ok(p);
    }
    match set("HOME") {
        Some(h) => Ok(h.join(".local").join("share")),
        None => bail!("neither XDG_DATA_HOME (absolute) nor HOME is set"),
    }
}

/// Where the manifest of `kind` goes.
pub fn manifest_path(data_home: &Path, kind: Kind) -> PathBuf {
    data_home
        .join("openxr/1/api_layers")
        .join(kind.dir())
        .join(format!("{LAYER_NAME}.json"))
}

/// The manifest (loader manifest file format 1.0.0).
pub fn manifest_json(library: &Path, kind: Kind) -> serde_json::Value {
    let mut layer = serde_json::json!({
        "name": LAYER_NAME,
        "library_path": library.to_string_lossy(),
        "api_version": "1.0",
        "implementation_version": "1",
        "description": "gazelight: eye gaze from gazelight sources and light perception on the app's frames",
        // The layer serves it itself, on runtimes without it too: the
        // loader offers it and accepts an app enabling it.
        "instance_extensions": [{
            "name": gazelight_openxr_layer::gaze::EYE_GAZE_EXT.to_string_lossy(),
            "extension_version": gazelight_openxr_layer::gaze::EYE_GAZE_EXT_VERSION.to_string(),
        }],
    });
    if kind == Kind::Implicit
        && let Some(m) = layer.as_object_mut()
    {
        // The loader requires it of implicit layers.
        m.insert("disable_environment".into(), DISABLE_ENV.into());
    }
    serde_json::json!({ "file_format_version": "1.0.0", "api_layer": layer })
}

/// Writes the manifest of `kind` for `library` (made absolute, must exist);
/// returns its path.
pub fn install(data_home: &Path, kind: Kind, library: &Path) -> anyhow::Result<PathBuf> {
    let library = library.canonicalize().with_context(|| {
        format!(
            "layer library {}: not found (build it: cargo build -p gazelight-openxr-layer, or pass --library)",
            library.display()
        )
    })?;
    if !library.is_file() {
        bail!("layer library {}: not a file", library.display());
    }
    let path = manifest_path(data_home, kind);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let text = serde_json::to_string_pretty(&manifest_json(&library, kind))?;
    std::fs::write(&path, text + "\n").with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// Removes both manifests; returns the ones that were there.
pub fn uninstall(data_home: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut removed = Vec::new();
    for kind in [Kind::Explicit, Kind::Implicit] {
        let path = manifest_path(data_home, kind);
        match std::fs::remove_file(&path) {
            Ok(()) => removed.push(path),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(e).with_context(|| format!("removing {}", path.display())),
        }
    }
    Ok(removed)
}

/// The OpenXR loader's file name (what `run --display xr` opens; apps may
/// bundle their own).
pub const LOADER_FILE: &str = "libopenxr_loader.so.1";

/// The directories a library file name is looked up in here:
/// `LD_LIBRARY_PATH`, then the usual system library directories (the
/// dynamic linker's cache is not read).
fn library_dirs(env: &dyn Fn(&str) -> Option<OsString>) -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = env("LD_LIBRARY_PATH")
        .map(|v| {
            std::env::split_paths(&v)
                .filter(|p| p.is_absolute())
                .collect()
        })
        .unwrap_or_default();
    let arch = std::env::consts::ARCH;
    for d in [
        "/usr/local/lib".to_owned(),
        "/usr/local/lib64".to_owned(),
        format!("/usr/lib/{arch}-linux-gnu"),
        format!("/lib/{arch}-linux-gnu"),
        "/usr/lib64".to_owned(),
        "/usr/lib".to_owned(),
        "/lib64".to_owned(),
        "/lib".to_owned(),
    ] {
        dirs.push(PathBuf::from(d));
    }
    dirs
}

/// Where `file` is found in [`library_dirs`].
fn find_library(file: &str, env: &dyn Fn(&str) -> Option<OsString>) -> Option<PathBuf> {
    library_dirs(env)
        .into_iter()
        .map(|d| d.join(file))
        .find(|p| p.is_file())
}

/// The active runtime's manifest as the Khronos loader finds it on Linux:
/// `XR_RUNTIME_JSON`, else `openxr/1/active_runtime.<arch>.json` then
/// `active_runtime.json` in `$XDG_CONFIG_HOME` (default `~/.config`), each
/// of `$XDG_CONFIG_DIRS` (default `/etc/xdg`), then `/etc`. With the
/// variable: where it came from.
fn runtime_manifest(env: &dyn Fn(&str) -> Option<OsString>) -> (Option<PathBuf>, String) {
    let set = |n: &str| env(n).filter(|v| !v.is_empty());
    if let Some(p) = set("XR_RUNTIME_JSON") {
        let p = PathBuf::from(p);
        let exists = p.is_file();
        return (
            exists.then(|| p.clone()),
            format!("XR_RUNTIME_JSON={}", p.display()),
        );
    }
    let mut dirs = Vec::new();
    match set("XDG_CONFIG_HOME").map(PathBuf::from) {
        Some(p) if p.is_absolute() => dirs.push(p),
        _ => {
            if let Some(h) = set("HOME") {
                dirs.push(PathBuf::from(h).join(".config"));
            }
        }
    }
    let config_dirs = set("XDG_CONFIG_DIRS").unwrap_or_else(|| OsString::from("/etc/xdg"));
    dirs.extend(std::env::split_paths(&config_dirs).filter(|p| p.is_absolute()));
    dirs.push(PathBuf::from("/etc"));
    let arch = std::env::consts::ARCH;
    let mut tried = Vec::new();
    for d in &dirs {
        for name in [
            format!("active_runtime.{arch}.json"),
            "active_runtime.json".into(),
        ] {
            let p = d.join("openxr/1").join(name);
            if p.is_file() {
                return (Some(p), "the active runtime".into());
            }
            tried.push(p.display().to_string());
        }
    }
    (
        None,
        format!("no XR_RUNTIME_JSON, none of {}", tried.join(", ")),
    )
}

/// The loader and runtime lines of the report; the second value is whether
/// a runtime with its library was found.
fn loader_and_runtime(env: &dyn Fn(&str) -> Option<OsString>) -> (Vec<String>, bool) {
    let mut lines = Vec::new();
    lines.push(match find_library(LOADER_FILE, env) {
        Some(p) => format!("loader: {} (what `gazelight run --display xr` opens)", p.display()),
        None => format!(
            "loader: {LOADER_FILE} not found in LD_LIBRARY_PATH or the system library directories \
             (install libopenxr-loader1; apps that bundle their own loader, e.g. Godot, do not need it)"
        ),
    });
    let (manifest, from) = runtime_manifest(env);
    let Some(manifest) = manifest else {
        lines.push(format!(
            "runtime: not found ({from}): no OpenXR app can start; start your runtime's setup \
             (Monado, SteamVR: \"Set SteamVR as OpenXR runtime\") or set XR_RUNTIME_JSON"
        ));
        return (lines, false);
    };
    let json: Option<serde_json::Value> = std::fs::read_to_string(&manifest)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok());
    let field = |k: &str| {
        json.as_ref()
            .and_then(|m| m.get("runtime"))
            .and_then(|r| r.get(k))
            .and_then(|v| v.as_str())
            .map(str::to_owned)
    };
    let name = field("name").map_or(String::new(), |n| format!(" \"{n}\""));
    let Some(library) = field("library_path") else {
        lines.push(format!(
            "runtime: {} ({from}) is not a runtime manifest (no runtime.library_path)",
            manifest.display()
        ));
        return (lines, false);
    };
    // As the loader: a relative path is relative to the manifest (its
    // real path: active_runtime.json is usually a symlink), a bare file
    // name is looked up in the library path.
    let resolved = if library.contains('/') {
        let base = manifest
            .canonicalize()
            .ok()
            .and_then(|p| p.parent().map(Path::to_path_buf))
            .unwrap_or_default();
        // `components` drops the `./` of `./bin/…`.
        Some(base.join(&library).components().collect::<PathBuf>()).filter(|p| p.is_file())
    } else {
        find_library(&library, env)
    };
    let ok = resolved.is_some();
    lines.push(match resolved {
        Some(lib) => format!(
            "runtime{name}: {} ({from}), library {}",
            manifest.display(),
            lib.display()
        ),
        None => format!(
            "runtime{name}: {} ({from}), but its library {library} does not exist: no OpenXR app can start",
            manifest.display()
        ),
    });
    (lines, ok)
}

/// What `status` found.
#[derive(Debug)]
pub struct StatusReport {
    /// One fact a line.
    pub lines: Vec<String>,
    /// Why `status` fails: a bad config, no runtime (empty: it succeeds).
    pub problems: Vec<String>,
}

/// The status report, one fact a line.
pub fn status(data_home: &Path, env: &dyn Fn(&str) -> Option<OsString>) -> StatusReport {
    let mut lines = Vec::new();
    let mut problems = Vec::new();
    let set = |n: &str| env(n).filter(|v| !v.is_empty());
    for kind in [Kind::Explicit, Kind::Implicit] {
        let path = manifest_path(data_home, kind);
        let label = match kind {
            Kind::Explicit => "explicit",
            Kind::Implicit => "implicit",
        };
        let Ok(text) = std::fs::read_to_string(&path) else {
            lines.push(format!(
                "{label}: not installed ({} absent)",
                path.display()
            ));
            continue;
        };
        let manifest: Option<serde_json::Value> = serde_json::from_str(&text).ok();
        let field = |k: &str| {
            manifest
                .as_ref()
                .and_then(|m| m.get("api_layer"))
                .and_then(|l| l.get(k))
                .and_then(|v| v.as_str())
                .map(str::to_owned)
        };
        let library = field("library_path").map(PathBuf::from);
        let library_ok = library.as_deref().is_some_and(Path::is_file);
        let problem = if manifest.is_none() {
            Some("the manifest is not valid JSON".to_owned())
        } else if field("name").as_deref() != Some(LAYER_NAME) {
            Some(format!("the manifest does not name {LAYER_NAME}"))
        } else if !library_ok {
            Some(format!(
                "its library {} does not exist",
                library
                    .as_deref()
                    .map_or("(none)".into(), |p| p.display().to_string())
            ))
        } else if kind == Kind::Implicit && field("disable_environment").is_none() {
            Some("an implicit manifest without disable_environment (the loader skips it)".into())
        } else {
            None
        };
        let verdict = match (&problem, kind) {
            (Some(p), _) => format!("the loader will not load it: {p}"),
            (None, Kind::Explicit) => {
                let enabled = set("XR_ENABLE_API_LAYERS")
                    .is_some_and(|v| v.to_string_lossy().split(':').any(|n| n == LAYER_NAME));
                format!(
                    "the loader finds it; loaded when the app or XR_ENABLE_API_LAYERS names {LAYER_NAME} (in this environment: {})",
                    if enabled { "named" } else { "not named" }
                )
            }
            (None, Kind::Implicit) => {
                // The loader disables it when the variable exists, even
                // empty (its PlatformUtilsGetEnvSet: getenv != NULL).
                if env(DISABLE_ENV).is_some() {
                    format!("the loader finds it, but {DISABLE_ENV} is set: not loaded")
                } else {
                    "the loader finds it and loads it in every OpenXR app".to_owned()
                }
            }
        };
        lines.push(format!("{label}: {} ({verdict})", path.display()));
    }
    if let Some(p) = set("XR_API_LAYER_PATH") {
        lines.push(format!(
            "XR_API_LAYER_PATH={}: the loader looks for explicit layers only there",
            p.to_string_lossy()
        ));
    }
    let (runtime_lines, runtime_ok) = loader_and_runtime(env);
    lines.extend(runtime_lines);
    if !runtime_ok {
        problems.push("no OpenXR runtime found".to_owned());
    }
    lines.push(match ConfigLocation::resolve(|n| env(n)) {
        None => "config: no place to look (no GAZELIGHT_LAYER_CONFIG, XDG_CONFIG_HOME or HOME): defaults".into(),
        Some(location) => {
            let from = match location {
                ConfigLocation::Env(_) => "GAZELIGHT_LAYER_CONFIG",
                ConfigLocation::Default(_) => "the default place",
            };
            match LayerConfig::load_at(&location) {
                Ok(Some((path, c))) => {
                    format!("config: {} ({from}): {}", path.display(), c.summary())
                }
                Ok(None) => format!(
                    "config: no file at {} ({from}): the defaults: {}",
                    location.path().display(),
                    LayerConfig::default().summary()
                ),
                Err(e) => {
                    problems.push(format!("the layer config is invalid ({from})"));
                    format!("{e}: the layer will pass everything through")
                }
            }
        }
    });
    StatusReport { lines, problems }
}

/// The parse-only check (`GAZELIGHT_PARSE_ONLY=1`, the doc-command test):
/// for `status`, the layer config it would report (`GAZELIGHT_LAYER_CONFIG`,
/// else the default place) is loaded and checked; nothing else is looked at.
pub fn check(args: &LayerArgs) -> anyhow::Result<()> {
    if let LayerAction::Status = args.action
        && let Some(location) = ConfigLocation::resolve(|n| std::env::var_os(n))
    {
        LayerConfig::load_at(&location)?;
    }
    Ok(())
}

pub fn run(args: LayerArgs) -> anyhow::Result<()> {
    let env = |n: &str| std::env::var_os(n);
    let home = data_home(&env)?;
    match args.action {
        LayerAction::Install { implicit, library } => {
            let library = match library {
                Some(l) => l,
                None => std::env::current_exe()?
                    .parent()
                    .map(|d| d.join(LIBRARY_FILE))
                    .context("the executable has no directory")?,
            };
            let kind = if implicit {
                Kind::Implicit
            } else {
                Kind::Explicit
            };
            let path = install(&home, kind, &library)?;
            println!("installed {}", path.display());
            if kind == Kind::Explicit {
                println!("enable it with XR_ENABLE_API_LAYERS={LAYER_NAME}");
            } else {
                println!("every OpenXR app loads it; disable with {DISABLE_ENV}=1");
            }
        }
        LayerAction::Uninstall => {
            let removed = uninstall(&home)?;
            if removed.is_empty() {
                println!("no manifest installed under {}", home.display());
            }
            for p in removed {
                println!("removed {}", p.display());
            }
        }
        LayerAction::Status => {
            let report = status(&home, &env);
            for line in &report.lines {
                println!("{line}");
            }
            if !report.problems.is_empty() {
                bail!("{}", report.problems.join("; "));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("gazelight-layer-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn env<'a>(vars: &'a [(&'a str, String)]) -> impl Fn(&str) -> Option<OsString> + 'a {
        move |n| {
            vars.iter()
                .find(|(k, _)| *k == n)
                .map(|(_, v)| OsString::from(v))
        }
    }

    #[test]
    fn the_data_home_is_xdg_data_home_else_home_local_share() {
        let e = [
            ("XDG_DATA_HOME", "/d".to_owned()),
            ("HOME", "/h".to_owned()),
        ];
        assert_eq!(data_home(&env(&e)).unwrap(), PathBuf::from("/d"));
        let e = [
            ("XDG_DATA_HOME", "rel".to_owned()),
            ("HOME", "/h".to_owned()),
        ];
        assert_eq!(
            data_home(&env(&e)).unwrap(),
            PathBuf::from("/h/.local/share")
        );
        assert!(data_home(&env(&[])).is_err());
    }

    #[test]
    fn status_finds_the_runtime_as_the_loader_does() {
        let dir = temp("runtime");
        let lib_dir = dir.join("lib");
        std::fs::create_dir_all(&lib_dir).unwrap();
        std::fs::write(lib_dir.join(LOADER_FILE), b"stand-in").unwrap();
        std::fs::write(lib_dir.join("libruntime.so"), b"stand-in").unwrap();
        // The user's active runtime, a symlink to a manifest whose library
        // path is relative to the manifest's real directory (as SteamVR's).
        let real = dir.join("vendor");
        std::fs::create_dir_all(real.join("bin")).unwrap();
        std::fs::write(real.join("bin/vrclient.so"), b"stand-in").unwrap();
        std::fs::write(
            real.join("vendor_runtime.json"),
            r#"{"file_format_version": "1.0.0", "runtime": {"name": "Vendor", "library_path": "./bin/vrclient.so"}}"#,
        )
        .unwrap();
        let config = dir.join("config");
        std::fs::create_dir_all(config.join("openxr/1")).unwrap();
        std::os::unix::fs::symlink(
            real.join("vendor_runtime.json"),
            config.join("openxr/1/active_runtime.json"),
        )
        .unwrap();
        let data = dir.join("data");
        let vars = [
            ("LD_LIBRARY_PATH", lib_dir.to_string_lossy().into_owned()),
            ("XDG_CONFIG_HOME", config.to_string_lossy().into_owned()),
            (
                "XDG_CONFIG_DIRS",
                dir.join("none").to_string_lossy().into_owned(),
            ),
        ];
        let report = status(&data, &env(&vars));
        let s = report.lines.join("\n");
        assert!(report.problems.is_empty(), "{report:?}");
        assert!(
            s.contains(&format!("loader: {}", lib_dir.join(LOADER_FILE).display())),
            "{s}"
        );
        assert!(s.contains("runtime \"Vendor\": "), "{s}");
        assert!(s.contains("vendor/bin/vrclient.so"), "{s}");

        // XR_RUNTIME_JSON wins; a bare library name is looked up in the
        // library path; a missing library fails the status.
        let manifest = dir.join("bare.json");
        std::fs::write(
            &manifest,
            r#"{"file_format_version": "1.0.0", "runtime": {"library_path": "libruntime.so"}}"#,
        )
        .unwrap();
        let mut vars = vars.to_vec();
        vars.push(("XR_RUNTIME_JSON", manifest.to_string_lossy().into_owned()));
        let report = status(&data, &env(&vars));
        let s = report.lines.join("\n");
        assert!(report.problems.is_empty(), "{report:?}");
        assert!(
            s.contains(&format!(
                "library {}",
                lib_dir.join("libruntime.so").display()
            )),
            "{s}"
        );
        std::fs::remove_file(lib_dir.join("libruntime.so")).unwrap();
        let report = status(&data, &env(&vars));
        assert_eq!(report.problems, ["no OpenXR runtime found"], "{report:?}");
        assert!(
            report.lines.join("\n").contains("does not exist"),
            "{report:?}"
        );

        // Nothing anywhere: not found, named in the report.
        let vars = [(
            "XR_RUNTIME_JSON",
            dir.join("gone.json").to_string_lossy().into_owned(),
        )];
        let report = status(&data, &env(&vars));
        assert!(
            report
                .lines
                .join("\n")
                .contains("runtime: not found (XR_RUNTIME_JSON="),
            "{report:?}"
        );
        assert_eq!(report.problems, ["no OpenXR runtime found"]);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn install_status_uninstall_with_a_temp_data_home() {
        let dir = temp("install");
        let data = dir.join("data");
        let lib = dir.join(LIBRARY_FILE);
        // No library: refused, nothing written.
        assert!(install(&data, Kind::Explicit, &lib).is_err());
        assert!(!manifest_path(&data, Kind::Explicit).exists());
        std::fs::write(&lib, b"not really a library").unwrap();

        let explicit = install(&data, Kind::Explicit, &lib).unwrap();
        // The Khronos loader's user directory for explicit layers.
        assert_eq!(
            explicit,
            data.join("openxr/1/api_layers/explicit.d/XR_APILAYER_GAZELIGHT_perception.json")
        );
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&explicit).unwrap()).unwrap();
        assert_eq!(m["file_format_version"], "1.0.0");
        assert_eq!(m["api_layer"]["name"], "XR_APILAYER_GAZELIGHT_perception");
        assert_eq!(
            m["api_layer"]["library_path"],
            lib.canonicalize().unwrap().to_string_lossy().as_ref()
        );
        assert!(m["api_layer"].get("disable_environment").is_none());
        // XR_EXT_eye_gaze_interaction version 2 (the OpenXR registry's
        // XR_EXT_eye_gaze_interaction_SPEC_VERSION), a string as the
        // loader's manifest format has it.
        assert_eq!(
            m["api_layer"]["instance_extensions"],
            serde_json::json!([{ "name": "XR_EXT_eye_gaze_interaction", "extension_version": "2" }])
        );

        let implicit = install(&data, Kind::Implicit, &lib).unwrap();
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&implicit).unwrap()).unwrap();
        assert_eq!(
            m["api_layer"]["disable_environment"],
            "DISABLE_XR_APILAYER_GAZELIGHT_PERCEPTION"
        );

        let config = dir.join("layer.toml");
        std::fs::write(&config, "source = \"pupil://10.0.0.2:50020\"\n").unwrap();
        let vars = [
            (
                "XR_ENABLE_API_LAYERS",
                "XR_APILAYER_OTHER:XR_APILAYER_GAZELIGHT_perception".to_owned(),
            ),
            (
                "GAZELIGHT_LAYER_CONFIG",
                config.to_string_lossy().into_owned(),
            ),
        ];
        let s = status(&data, &env(&vars)).lines.join("\n");
        assert!(s.contains("(in this environment: named)"), "{s}");
        assert!(s.contains("loads it in every OpenXR app"), "{s}");
        assert!(s.contains("source pupil://10.0.0.2:50020"), "{s}");

        // Disabled, a bad config, a library gone.
        std::fs::write(&config, "gaze = \"eyes\"\n").unwrap();
        let vars = [
            ("DISABLE_XR_APILAYER_GAZELIGHT_PERCEPTION", "1".to_owned()),
            (
                "GAZELIGHT_LAYER_CONFIG",
                config.to_string_lossy().into_owned(),
            ),
        ];
        let report = status(&data, &env(&vars));
        assert!(
            report
                .problems
                .iter()
                .any(|p| p.contains("config is invalid")),
            "{report:?}"
        );
        let s = report.lines.join("\n");
        assert!(s.contains("(in this environment: not named)"), "{s}");
        assert!(
            s.contains("DISABLE_XR_APILAYER_GAZELIGHT_PERCEPTION is set: not loaded"),
            "{s}"
        );
        assert!(s.contains("layer.toml:1:8: gaze:"), "{s}");
        std::fs::remove_file(&lib).unwrap();
        let s = status(&data, &env(&[])).lines.join("\n");
        assert_eq!(
            s.matches("the loader will not load it: its library")
                .count(),
            2,
            "{s}"
        );

        let removed = uninstall(&data).unwrap();
        assert_eq!(removed, vec![explicit.clone(), implicit.clone()]);
        assert!(!explicit.exists() && !implicit.exists());
        let s = status(&data, &env(&[])).lines.join("\n");
        assert_eq!(s.matches("not installed").count(), 2, "{s}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
