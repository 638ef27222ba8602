//! liblsl, loaded at run time (`libloading`), and its C API as function
//! pointers. Nothing here reimplements the LSL protocol: every stream,
//! outlet, inlet, resolve and clock comes from the real library.
//!
//! Where the library comes from, in order:
//! 1. the path in `GAZELIGHT_LIBLSL` (an error there is final);
//! 2. the system library (`liblsl.so`, `liblsl.so.2` on the loader's path);
//! 3. the copy inside an installed `pylsl` (`<pylsl>/lib/liblsl.so`, found
//!    through `python3` without importing pylsl, then in the usual
//!    site-packages directories).
//!
//! Before any other call, the configuration is applied
//! ([`super::LslConfig::apply`]): by default discovery stays on this
//! machine.

use std::ffi::{CStr, CString, c_char, c_void};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use super::{LslConfig, LslError};

pub(crate) type Ptr = *mut c_void;

/// `lsl_channel_format_t`.
pub(crate) const CFT_DOUBLE64: i32 = 2;
pub(crate) const CFT_STRING: i32 = 3;
/// `lsl_error_code_t`.
pub(crate) const LSL_TIMEOUT_ERROR: i32 = -1;
pub(crate) const LSL_LOST_ERROR: i32 = -2;

/// The liblsl C API functions gazelight uses.
pub(crate) struct Api {
    pub path: PathBuf,
    pub version: i32,
    pub config: String,
    pub local_clock: unsafe extern "C" fn() -> f64,
    pub create_streaminfo:
        unsafe extern "C" fn(*const c_char, *const c_char, i32, f64, i32, *const c_char) -> Ptr,
    pub destroy_streaminfo: unsafe extern "C" fn(Ptr),
    pub get_desc: unsafe extern "C" fn(Ptr) -> Ptr,
    pub append_child: unsafe extern "C" fn(Ptr, *const c_char) -> Ptr,
    pub append_child_value: unsafe extern "C" fn(Ptr, *const c_char, *const c_char) -> Ptr,
    pub first_child: unsafe extern "C" fn(Ptr) -> Ptr,
    pub next_sibling: unsafe extern "C" fn(Ptr) -> Ptr,
    pub child: unsafe extern "C" fn(Ptr, *const c_char) -> Ptr,
    pub child_value_n: unsafe extern "C" fn(Ptr, *const c_char) -> *const c_char,
    pub empty: unsafe extern "C" fn(Ptr) -> i32,
    pub get_name: unsafe extern "C" fn(Ptr) -> *const c_char,
    pub get_type: unsafe extern "C" fn(Ptr) -> *const c_char,
    pub get_source_id: unsafe extern "C" fn(Ptr) -> *const c_char,
    pub get_channel_count: unsafe extern "C" fn(Ptr) -> i32,
    pub get_channel_format: unsafe extern "C" fn(Ptr) -> i32,
    pub get_nominal_srate: unsafe extern "C" fn(Ptr) -> f64,
    pub create_outlet: unsafe extern "C" fn(Ptr, i32, i32) -> Ptr,
    pub destroy_outlet: unsafe extern "C" fn(Ptr),
    pub push_sample_dtp: unsafe extern "C" fn(Ptr, *const f64, f64, i32) -> i32,
    pub push_sample_strtp: unsafe extern "C" fn(Ptr, *const *const c_char, f64, i32) -> i32,
    pub have_consumers: unsafe extern "C" fn(Ptr) -> i32,
    pub resolve_byprop:
        unsafe extern "C" fn(*mut Ptr, u32, *const c_char, *const c_char, i32, f64) -> i32,
    pub create_inlet: unsafe extern "C" fn(Ptr, i32, i32, i32) -> Ptr,
    pub destroy_inlet: unsafe extern "C" fn(Ptr),
    pub open_stream: unsafe extern "C" fn(Ptr, f64, *mut i32),
    pub get_fullinfo: unsafe extern "C" fn(Ptr, f64, *mut i32) -> Ptr,
    pub pull_sample_d: unsafe extern "C" fn(Ptr, *mut f64, i32, f64, *mut i32) -> f64,
    pub time_correction: unsafe extern "C" fn(Ptr, f64, *mut i32) -> f64,
    /// `lsl_pull_sample_buf`: each channel's string allocated by liblsl
    /// (freed with `destroy_string`) with its length.
    pub pull_sample_buf:
        unsafe extern "C" fn(Ptr, *mut *mut c_char, *mut u32, i32, f64, *mut i32) -> f64,
    pub destroy_string: unsafe extern "C" fn(*mut c_char),
    // Keeps the symbols above valid for the life of the process.
    _lib: libloading::Library,
}

static API: OnceLock<Result<Api, LslError>> = OnceLock::new();

/// The loaded library. The first call loads it and applies `config`; later
/// calls return the same library (the configuration cannot change once
/// liblsl has started).
pub(crate) fn api(config: &LslConfig) -> Result<&'static Api, LslError> {
    API.get_or_init(|| load(config))
        .as_ref()
        .map_err(Clone::clone)
}

fn load(config: &LslConfig) -> Result<Api, LslError> {
    let (lib, path) = open_library()?;
    // SAFETY: the symbols are liblsl's C API with the signatures of
    // lsl_c.h (liblsl ≥ 1.14); `lib` outlives them (stored in `Api`).
    unsafe {
        macro_rules! sym {
            ($name:literal) => {{
                let s: libloading::Symbol<'_, _> = lib
                    .get(concat!($name, "\0").as_bytes())
                    .map_err(|e| LslError::Symbol {
                        path: path.display().to_string(),
                        name: $name,
                        reason: e.to_string(),
                    })?;
                *s
            }};
        }
        let set_config_content: unsafe extern "C" fn(*const c_char) =
            sym!("lsl_set_config_content");
        let set_config_filename: unsafe extern "C" fn(*const c_char) =
            sym!("lsl_set_config_filename");
        let library_version: unsafe extern "C" fn() -> i32 = sym!("lsl_library_version");
        // The configuration must be set before anything else touches liblsl.
        let applied = config.apply(|content| match content {
            super::config::Applied::Content(text) => {
                let c = cstring(text, "lsl configuration")?;
                set_config_content(c.as_ptr());
                Ok(())
            }
            super::config::Applied::File(p) => {
                let c = cstring(&p.display().to_string(), "lsl config_file")?;
                set_config_filename(c.as_ptr());
                Ok(())
            }
            super::config::Applied::Environment => Ok(()),
        })?;
        let api = Api {
            version: library_version(),
            config: applied,
            local_clock: sym!("lsl_local_clock"),
            create_streaminfo: sym!("lsl_create_streaminfo"),
            destroy_streaminfo: sym!("lsl_destroy_streaminfo"),
            get_desc: sym!("lsl_get_desc"),
            append_child: sym!("lsl_append_child"),
            append_child_value: sym!("lsl_append_child_value"),
            first_child: sym!("lsl_first_child"),
            next_sibling: sym!("lsl_next_sibling"),
            child: sym!("lsl_child"),
            child_value_n: sym!("lsl_child_value_n"),
            empty: sym!("lsl_empty"),
            get_name: sym!("lsl_get_name"),
            get_type: sym!("lsl_get_type"),
            get_source_id: sym!("lsl_get_source_id"),
            get_channel_count: sym!("lsl_get_channel_count"),
            get_channel_format: sym!("lsl_get_channel_format"),
            get_nominal_srate: sym!("lsl_get_nominal_srate"),
            create_outlet: sym!("lsl_create_outlet"),
            destroy_outlet: sym!("lsl_destroy_outlet"),
            push_sample_dtp: sym!("lsl_push_sample_dtp"),
            push_sample_strtp: sym!("lsl_push_sample_strtp"),
            have_consumers: sym!("lsl_have_consumers"),
            resolve_byprop: sym!("lsl_resolve_byprop"),
            create_inlet: sym!("lsl_create_inlet"),
            destroy_inlet: sym!("lsl_destroy_inlet"),
            open_stream: sym!("lsl_open_stream"),
            get_fullinfo: sym!("lsl_get_fullinfo"),
            pull_sample_d: sym!("lsl_pull_sample_d"),
            time_correction: sym!("lsl_time_correction"),
            pull_sample_buf: sym!("lsl_pull_sample_buf"),
            destroy_string: sym!("lsl_destroy_string"),
            path,
            _lib: lib,
        };
        tracing::info!(path = %api.path.display(), version = api.version, config = %api.config, "liblsl loaded");
        Ok(api)
    }
}

fn open_library() -> Result<(libloading::Library, PathBuf), LslError> {
    // Every `Library::new` below: loading liblsl runs its static
    // initialisers, which only set up C++ runtime state.
    if let Some(p) = std::env::var_os("GAZELIGHT_LIBLSL") {
        let path = PathBuf::from(p);
        // SAFETY: liblsl's initialisers only set up C++ runtime state (above).
        return unsafe { libloading::Library::new(&path) }
            .map(|l| (l, path.clone()))
            .map_err(|e| LslError::Load {
                path: format!("{} (from GAZELIGHT_LIBLSL)", path.display()),
                reason: e.to_string(),
            });
    }
    let mut tried = Vec::new();
    for name in ["liblsl.so", "liblsl.so.2"] {
        // SAFETY: as above, liblsl's initialisers.
        match unsafe { libloading::Library::new(name) } {
            Ok(l) => return Ok((l, PathBuf::from(name))),
            Err(_) => tried.push(name.to_owned()),
        }
    }
    for dir in pylsl_dirs() {
        for name in ["liblsl.so", "liblsl.so.2"] {
            let path = dir.join("lib").join(name);
            if !path.is_file() {
                tried.push(path.display().to_string());
                continue;
            }
            // SAFETY: as above, liblsl's initialisers.
            match unsafe { libloading::Library::new(&path) } {
                Ok(l) => return Ok((l, path)),
                Err(e) => tried.push(format!("{} ({e})", path.display())),
            }
        }
    }
    Err(LslError::NotFound { tried })
}

/// Directories of installed `pylsl` packages: what `python3` reports (via
/// `importlib.util.find_spec`, which does not import pylsl), then the
/// site-packages directories of the usual prefixes.
fn pylsl_dirs() -> Vec<PathBuf> {
    let mut dirs = Vec::new();
    let probe = std::process::Command::new("python3")
        .args([
            "-c",
            "import importlib.util as u;s=u.find_spec('pylsl');print(s.submodule_search_locations[0] if s else '')",
        ])
        .stderr(std::process::Stdio::null())
        .output();
    if let Ok(out) = probe
        && out.status.success()
    {
        let line = String::from_utf8_lossy(&out.stdout).trim().to_owned();
        if !line.is_empty() {
            dirs.push(PathBuf::from(line));
        }
    }
    for root in ["/usr/lib", "/usr/local/lib"] {
        let Ok(entries) = std::fs::read_dir(root) else {
            continue;
        };
        for e in entries.flatten() {
            let name = e.file_name();
            if !name.to_string_lossy().starts_with("python3") {
                continue;
            }
            for sub in ["site-packages", "dist-packages"] {
                let d = e.path().join(sub).join("pylsl");
                if d.is_dir() && !dirs.contains(&d) {
                    dirs.push(d);
                }
            }
        }
    }
    dirs
}

pub(crate) fn cstring(s: &str, what: &str) -> Result<CString, LslError> {
    CString::new(s).map_err(|_| LslError::Argument {
        reason: format!("{what} `{s}` contains a NUL byte"),
    })
}

/// A C string owned by liblsl, copied. `None` for a null pointer.
///
/// # Safety
/// `p` is null or a NUL-terminated string valid for the call.
pub(crate) unsafe fn copy_str(p: *const c_char) -> Option<String> {
    if p.is_null() {
        None
    } else {
        // SAFETY: per the contract above.
        Some(unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
    }
}

/// Whether a path names a readable file (for config checks).
pub(crate) fn readable(p: &Path) -> bool {
    std::fs::File::open(p).is_ok()
}
