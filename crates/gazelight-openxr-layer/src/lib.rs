//! `gazelight-openxr-layer`: an OpenXR API layer (a `cdylib`) that the
//! Khronos loader puts between any OpenXR application and its runtime.
//!
//! What it does today: it negotiates with the loader
//! ([`xrNegotiateLoaderApiLayerInterface`]), creates its instance by
//! chaining to the next layer or the runtime (`xrCreateApiLayerInstance`),
//! keeps a dispatch table per instance from the next `xrGetInstanceProcAddr`,
//! and forwards every function: its `xrGetInstanceProcAddr` hands out the
//! next layer's own pointers for everything but itself and
//! `xrDestroyInstance`. At instance creation it reads its configuration
//! ([`config`]) and logs what it resolved to, or the error (file, line,
//! field) and stays in pass-through mode.
//!
//! Eye gaze ([`gaze`]): with `gaze = "gazelight"` and an app that enables
//! `XR_EXT_eye_gaze_interaction`, the layer enables
//! `XR_KHR_convert_timespec_time` below itself, starts the live eye task on
//! the config's `source` and serves the gaze action's space from it.
//!
//! Frame effects ([`frames`]): with `effects = "on"` and an app on
//! `XR_KHR_vulkan_enable2`, the layer puts a wgpu device on the app's own
//! Vulkan device ([`vk`]) and, in `xrEndFrame`, runs gazelight-gpu's frame
//! pipeline on each projection view's image with that eye's gaze and pupil
//! ([`process`], [`import`]), before the image goes to the runtime.
//!
//! `XR_EXT_eye_gaze_interaction` is the layer's own when it serves the
//! gaze: the manifest `gazelight layer install` writes lists it (so the
//! loader offers it and accepts it on runtimes that lack it), and the layer
//! takes it out of the create info it passes down.
//!
//! Never the app's crash: every exported entry point runs in
//! [`guard::guarded`], which catches a panic, logs it, turns the layer into
//! pass-through mode and answers as a layer that only forwards would.
//! In a build with the `test-hooks` feature (tests only, never the
//! product), `GAZELIGHT_LAYER_TEST_PANIC` forces a panic ([`guard`]).

pub mod config;
pub mod frames;
pub mod gaze;
pub mod guard;
pub mod import;
mod log;
pub mod process;
pub mod vk;

use std::collections::HashMap;
use std::ffi::{CStr, c_char};
use std::sync::{Mutex, MutexGuard, PoisonError};

use openxr_sys as xr;
use openxr_sys::Handle as _;
use openxr_sys::pfn;

pub use log::log;

/// The layer's name in its manifest and in `XR_ENABLE_API_LAYERS`.
pub const LAYER_NAME: &str = "XR_APILAYER_GAZELIGHT_perception";
/// The environment variable that disables the implicit layer (its manifest's
/// `disable_environment`).
pub const DISABLE_ENV: &str = "DISABLE_XR_APILAYER_GAZELIGHT_PERCEPTION";
/// The loader–layer interface version this layer speaks
/// (`XR_CURRENT_LOADER_API_LAYER_VERSION`).
const INTERFACE_VERSION: u32 = xr::CURRENT_LOADER_API_LAYER_VERSION as u32;

/// What the layer keeps per instance: the next layer's entry points.
#[derive(Clone, Copy)]
struct Dispatch {
    next_get_instance_proc_addr: pfn::GetInstanceProcAddr,
    next_destroy_instance: Option<pfn::DestroyInstance>,
}

static INSTANCES: Mutex<Option<HashMap<u64, Dispatch>>> = Mutex::new(None);

/// The instance table, also after a panic poisoned it (the table holds only
/// plain pointers, each insert or remove is whole).
fn instances() -> MutexGuard<'static, Option<HashMap<u64, Dispatch>>> {
    INSTANCES.lock().unwrap_or_else(PoisonError::into_inner)
}

fn dispatch_of(instance: xr::Instance) -> Option<Dispatch> {
    instances()
        .as_ref()
        .and_then(|m| m.get(&instance.into_raw()).copied())
}

/// The loader calls this first: it checks the versions the loader offers
/// and returns the layer's `xrGetInstanceProcAddr` and
/// `xrCreateApiLayerInstance`.
///
/// # Safety
/// Called by the OpenXR loader with valid (or null) pointers.
#[unsafe(no_mangle)]
pub unsafe extern "system" fn xrNegotiateLoaderApiLayerInterface(
    loader_info: *const xr::NegotiateLoaderInfo,
    layer_name: *const c_char,
    request: *mut xr::NegotiateApiLayerRequest,
) -> xr::Result {
    guard::guarded(
        "xrNegotiateLoaderApiLayerInterface",
        // A panic before the answer: answer as a pass-through layer.
        // SAFETY: the loader's pointers for this call, handed on unchanged
        // (`fill_request` checks `request` for null).
        || unsafe { fill_request(request, xr::CURRENT_API_VERSION) },
        // SAFETY: as above; `negotiate` checks both structures for null.
        || unsafe { negotiate(loader_info, layer_name, request) },
    )
}

/// Checks the loader's versions and fills in `request`.
///
/// # Safety
/// `loader_info` and `request` are null or valid for this call;
/// `layer_name` is null or a NUL-terminated string.
unsafe fn negotiate(
    loader_info: *const xr::NegotiateLoaderInfo,
    layer_name: *const c_char,
    request: *mut xr::NegotiateApiLayerRequest,
) -> xr::Result {
    if loader_info.is_null() || request.is_null() {
        log("error", "negotiation: null loader info or request");
        return xr::Result::ERROR_INITIALIZATION_FAILED;
    }
    // SAFETY: checked non-null; the loader owns both for this call.
    let (info, req) = unsafe { (&*loader_info, &*request) };
    #[cfg(feature = "test-hooks")]
    guard::test_hook("xrNegotiateLoaderApiLayerInterface");
    if !layer_name.is_null() {
        // SAFETY: the loader passes a NUL-terminated name.
        let name = unsafe { CStr::from_ptr(layer_name) }.to_string_lossy();
        if name != LAYER_NAME {
            log(
                "warn",
                &format!("negotiation: the loader names this layer {name}, expected {LAYER_NAME}"),
            );
        }
    }
    if info.struct_type != xr::NegotiateLoaderInfo::TYPE
        || info.struct_version != xr::NegotiateLoaderInfo::VERSION
        || info.struct_size != size_of::<xr::NegotiateLoaderInfo>()
        || req.struct_type != xr::NegotiateApiLayerRequest::TYPE
        || req.struct_version != xr::NegotiateApiLayerRequest::VERSION
        || req.struct_size != size_of::<xr::NegotiateApiLayerRequest>()
    {
        log(
            "error",
            "negotiation: the loader's structures are of another type, version or size",
        );
        return xr::Result::ERROR_INITIALIZATION_FAILED;
    }
    if !(info.min_interface_version..=info.max_interface_version).contains(&INTERFACE_VERSION) {
        log(
            "error",
            &format!(
                "negotiation: the loader speaks interface versions {}..={}, this layer {INTERFACE_VERSION}",
                info.min_interface_version, info.max_interface_version
            ),
        );
        return xr::Result::ERROR_INITIALIZATION_FAILED;
    }
    // The layer passes every API version through: it answers the newest the
    // loader takes, at most the one its headers know.
    let api = if info.max_api_version.into_raw() < xr::CURRENT_API_VERSION.into_raw() {
        info.max_api_version
    } else {
        xr::CURRENT_API_VERSION
    };
    if api.major() < 1 {
        log(
            "error",
            &format!("negotiation: the loader offers API up to {api}, this layer needs 1.0"),
        );
        return xr::Result::ERROR_API_VERSION_UNSUPPORTED;
    }
    // SAFETY: `request` checked non-null above, the loader's for this call.
    unsafe { fill_request(request, api) }
}

/// Writes the layer's interface version, `api` and its two entry points
/// into the loader's request.
///
/// # Safety
/// `request` is null or a valid, writable `XrNegotiateApiLayerRequest`.
unsafe fn fill_request(request: *mut xr::NegotiateApiLayerRequest, api: xr::Version) -> xr::Result {
    if request.is_null() {
        return xr::Result::ERROR_INITIALIZATION_FAILED;
    }
    // SAFETY: non-null, owned by the loader for this call.
    let req = unsafe { &mut *request };
    req.layer_interface_version = INTERFACE_VERSION;
    req.layer_api_version = api;
    req.get_instance_proc_addr = Some(get_instance_proc_addr);
    req.create_api_layer_instance = Some(create_api_layer_instance);
    xr::Result::SUCCESS
}

/// `xrCreateApiLayerInstance`: creates the instance through the next layer
/// (its `next_info` advanced by one), then records the next layer's entry
/// points and reads the configuration.
///
/// # Safety
/// Called by the loader (or the layer above) with `info` null or valid,
/// `layer_info` null or the loader's chain for this call, `instance` null
/// or writable.
unsafe extern "system" fn create_api_layer_instance(
    info: *const xr::InstanceCreateInfo,
    layer_info: *const xr::ApiLayerCreateInfo,
    instance: *mut xr::Instance,
) -> xr::Result {
    // Set once the next layer was called: a panic after that must not
    // create a second instance.
    let created: std::cell::Cell<Option<xr::Result>> = std::cell::Cell::new(None);
    guard::guarded(
        "xrCreateApiLayerInstance",
        || match created.get() {
            Some(result) => result,
            // SAFETY: the caller's pointers, handed on unchanged;
            // `create_next` checks them for null.
            None => unsafe { create_next(info, layer_info, instance) },
        },
        || {
            let loaded = config::LayerConfig::load_from_env();
            // Below, `info` is null or the app's valid create info for this
            // call: what `wanted` and `enables` ask.
            let serve_gaze = match &loaded {
                // SAFETY: `info` as `wanted` asks (see above).
                Ok(Some((_, c))) => unsafe { gaze::wanted(info, c) },
                // SAFETY: `info` as `wanted` asks (see above).
                Ok(None) => unsafe { gaze::wanted(info, &config::LayerConfig::default()) },
                Err(_) => false,
            };
            // The frame effects: for Vulkan apps (XR_KHR_vulkan_enable2).
            let effects = match &loaded {
                // SAFETY: `info` as `wanted` asks (see above).
                Ok(Some((_, c))) => unsafe { frames::wanted(info, c) },
                // SAFETY: `info` as `wanted` asks (see above).
                Ok(None) => unsafe { frames::wanted(info, &config::LayerConfig::default()) },
                Err(_) => false,
            };
            let want_eye = serve_gaze || effects;
            // What goes down: eye gaze needs XR_KHR_convert_timespec_time
            // below the layer (sample times); without it the layer serves
            // no gaze. XR_EXT_eye_gaze_interaction is the layer's own when
            // it serves the gaze: it is taken out of the create info, so
            // the runtime need not have it (the loader accepts it from the
            // layer's manifest, `gazelight layer install`).
            let add_convert =
                // SAFETY: `info` is null or the app's valid create info.
                want_eye && !unsafe { gaze::enables(info, gaze::CONVERT_TIMESPEC_EXT) };
            let (result, with_convert) = if add_convert || serve_gaze {
                // SAFETY: the caller's pointers, handed on; the names added
                // are 'static C strings.
                let r = unsafe {
                    create_changed(
                        info,
                        layer_info,
                        instance,
                        add_convert.then_some(gaze::CONVERT_TIMESPEC_EXT),
                        serve_gaze.then_some(gaze::EYE_GAZE_EXT),
                    )
                };
                if r == xr::Result::ERROR_EXTENSION_NOT_PRESENT && add_convert {
                    log(
                        "warn",
                        "eye gaze: the runtime lacks XR_KHR_convert_timespec_time; the layer serves no gaze",
                    );
                    // SAFETY: the caller's pointers, handed on unchanged
                    // (the changed create failed: nothing was created).
                    (unsafe { create_next(info, layer_info, instance) }, false)
                } else {
                    if serve_gaze && r.into_raw() >= 0 {
                        log(
                            "info",
                            "eye gaze: XR_EXT_eye_gaze_interaction is served by the layer (not passed down to the runtime)",
                        );
                    }
                    (r, r.into_raw() >= 0)
                }
            } else {
                // SAFETY: the caller's pointers, handed on unchanged.
                (unsafe { create_next(info, layer_info, instance) }, want_eye)
            };
            created.set(Some(result));
            #[cfg(feature = "test-hooks")]
            guard::test_hook("xrCreateApiLayerInstance");
            if result.into_raw() >= 0 {
                let config = match loaded {
                    Ok(Some((path, config))) => {
                        log(
                            "info",
                            &format!("config {}: {}", path.display(), config.summary()),
                        );
                        Some(config)
                    }
                    Ok(None) => {
                        log(
                            "info",
                            "no config file (GAZELIGHT_LAYER_CONFIG, $XDG_CONFIG_HOME/gazelight/layer.toml): defaults",
                        );
                        Some(config::LayerConfig::default())
                    }
                    Err(e) => {
                        log(
                            "error",
                            &format!("{e}; the layer passes everything through"),
                        );
                        guard::set_pass_through();
                        None
                    }
                };
                // SAFETY: the next layer wrote the instance on success.
                let created = unsafe { *instance };
                if let Some(config) = &config
                    && with_convert
                    && let Some(d) = dispatch_of(created)
                    && let Err(e) =
                        gaze::start(created, d.next_get_instance_proc_addr, config, serve_gaze)
                {
                    log("error", &format!("eye gaze: {e}; the layer serves no gaze"));
                }
                if let Some(config) = &config
                    && effects
                    && let Some(d) = dispatch_of(created)
                {
                    frames::start(created, d.next_get_instance_proc_addr, config);
                }
            }
            result
        },
    )
}

/// [`create_next`] with extension `add` enabled and `remove` taken out
/// of the app's list.
///
/// # Safety
/// As [`create_next`]; `info`'s extension names, when non-null, are an
/// array of `enabled_extension_count` entries, each null or NUL-terminated.
unsafe fn create_changed(
    info: *const xr::InstanceCreateInfo,
    layer_info: *const xr::ApiLayerCreateInfo,
    instance: *mut xr::Instance,
    add: Option<&CStr>,
    remove: Option<&CStr>,
) -> xr::Result {
    if info.is_null() {
        // SAFETY: the caller's pointers, handed on unchanged.
        return unsafe { create_next(info, layer_info, instance) };
    }
    // SAFETY: non-null; the app's create info for this call.
    let mut changed = unsafe { *info };
    let mut names: Vec<*const c_char> = if changed.enabled_extension_names.is_null() {
        Vec::new()
    } else {
        // SAFETY: an array of `enabled_extension_count` names.
        unsafe {
            std::slice::from_raw_parts(
                changed.enabled_extension_names,
                changed.enabled_extension_count as usize,
            )
        }
        .to_vec()
    };
    if let Some(remove) = remove {
        // SAFETY: the app's non-null entries are NUL-terminated names.
        names.retain(|&p| p.is_null() || unsafe { CStr::from_ptr(p) } != remove);
    }
    if let Some(add) = add {
        names.push(add.as_ptr());
    }
    changed.enabled_extension_names = names.as_ptr();
    changed.enabled_extension_count = names.len() as u32;
    // SAFETY: `changed` is the app's create info with a name array that
    // outlives the call (`names`, its entries the app's or 'static).
    unsafe { create_next(&changed, layer_info, instance) }
}

/// Calls the next layer's `xrCreateApiLayerInstance` with the chain advanced
/// past this layer, and records the next layer's entry points for the new
/// instance. No panicking code: it is also the fallback after a panic.
///
/// # Safety
/// `info` is what the next layer may be given (null or a valid create
/// info); `layer_info` is null or the loader's `XrApiLayerCreateInfo` whose
/// `next_info` chain is valid for this call; `instance` is null or
/// writable.
unsafe fn create_next(
    info: *const xr::InstanceCreateInfo,
    layer_info: *const xr::ApiLayerCreateInfo,
    instance: *mut xr::Instance,
) -> xr::Result {
    if layer_info.is_null() || instance.is_null() {
        return xr::Result::ERROR_INITIALIZATION_FAILED;
    }
    // SAFETY: non-null; the loader owns it for this call.
    let mut next_create_info = unsafe { *layer_info };
    let next_info = next_create_info.next_info;
    if next_info.is_null() {
        log(
            "error",
            "xrCreateApiLayerInstance: no next layer in the chain",
        );
        return xr::Result::ERROR_INITIALIZATION_FAILED;
    }
    // SAFETY: non-null; the chain lives as long as this call.
    let this = unsafe { &*next_info };
    if this.struct_type != xr::ApiLayerNextInfo::TYPE {
        log(
            "error",
            "xrCreateApiLayerInstance: the chain's entry is not an XrApiLayerNextInfo",
        );
        return xr::Result::ERROR_INITIALIZATION_FAILED;
    }
    let (Some(next_gipa), Some(next_create)) = (
        this.next_get_instance_proc_addr,
        this.next_create_api_layer_instance,
    ) else {
        log(
            "error",
            "xrCreateApiLayerInstance: the next layer has no entry points",
        );
        return xr::Result::ERROR_INITIALIZATION_FAILED;
    };
    next_create_info.next_info = this.next;
    // SAFETY: the loader's contract: the next layer's create with the chain
    // advanced by one.
    let result = unsafe { next_create(info, &next_create_info, instance) };
    if result.into_raw() < 0 {
        return result;
    }
    // SAFETY: the next layer wrote the instance on success.
    let created = unsafe { *instance };
    let mut destroy: Option<pfn::VoidFunction> = None;
    // SAFETY: the next layer's gipa on the instance it just created.
    let r = unsafe { next_gipa(created, c"xrDestroyInstance".as_ptr(), &mut destroy) };
    let next_destroy_instance = if r.into_raw() >= 0 {
        // SAFETY: the pointer the next layer returned for this name has
        // xrDestroyInstance's signature.
        destroy
            .map(|f| unsafe { std::mem::transmute::<pfn::VoidFunction, pfn::DestroyInstance>(f) })
    } else {
        None
    };
    instances().get_or_insert_with(HashMap::new).insert(
        created.into_raw(),
        Dispatch {
            next_get_instance_proc_addr: next_gipa,
            next_destroy_instance,
        },
    );
    result
}

/// The layer's `xrGetInstanceProcAddr`: its own `xrGetInstanceProcAddr` and
/// `xrDestroyInstance` (not in pass-through mode), the next layer's pointer
/// for every other name.
///
/// # Safety
/// The caller's `name` is null or NUL-terminated, `function` null or a
/// writable slot.
unsafe extern "system" fn get_instance_proc_addr(
    instance: xr::Instance,
    name: *const c_char,
    function: *mut Option<pfn::VoidFunction>,
) -> xr::Result {
    guard::guarded(
        "xrGetInstanceProcAddr",
        // SAFETY: the caller's arguments, handed on unchanged.
        || unsafe { forward_proc_addr(instance, name, function) },
        || {
            #[cfg(feature = "test-hooks")]
            guard::test_hook("xrGetInstanceProcAddr");
            if name.is_null() || function.is_null() {
                return xr::Result::ERROR_VALIDATION_FAILURE;
            }
            // SAFETY: the caller passes a NUL-terminated name.
            let wanted = unsafe { CStr::from_ptr(name) };
            if wanted == c"xrGetInstanceProcAddr" {
                // SAFETY: `function` checked non-null; a VoidFunction slot.
                unsafe {
                    *function = Some(std::mem::transmute::<
                        pfn::GetInstanceProcAddr,
                        pfn::VoidFunction,
                    >(get_instance_proc_addr));
                }
                return xr::Result::SUCCESS;
            }
            if wanted == c"xrDestroyInstance" && !guard::pass_through() {
                if dispatch_of(instance).is_none() {
                    return xr::Result::ERROR_HANDLE_INVALID;
                }
                // SAFETY: as above.
                unsafe {
                    *function = Some(
                        std::mem::transmute::<pfn::DestroyInstance, pfn::VoidFunction>(
                            destroy_instance,
                        ),
                    );
                }
                return xr::Result::SUCCESS;
            }
            if !guard::pass_through()
                && let Some(f) = frames::proc_addr(instance, wanted)
            {
                // SAFETY: as above.
                unsafe { *function = Some(f) };
                return xr::Result::SUCCESS;
            }
            if !guard::pass_through()
                && let Some(f) = gaze::proc_addr(instance, wanted)
            {
                // SAFETY: as above.
                unsafe { *function = Some(f) };
                return xr::Result::SUCCESS;
            }
            // SAFETY: the caller's arguments, handed on unchanged.
            unsafe { forward_proc_addr(instance, name, function) }
        },
    )
}

/// The next layer's pointer for `name` (pass-through).
///
/// # Safety
/// As `xrGetInstanceProcAddr`: `name` null or NUL-terminated, `function`
/// null or a writable slot.
unsafe fn forward_proc_addr(
    instance: xr::Instance,
    name: *const c_char,
    function: *mut Option<pfn::VoidFunction>,
) -> xr::Result {
    match dispatch_of(instance) {
        // SAFETY: the caller's arguments, handed on unchanged.
        Some(d) => unsafe { (d.next_get_instance_proc_addr)(instance, name, function) },
        None => {
            if !function.is_null() {
                // SAFETY: non-null slot.
                unsafe { *function = None };
            }
            xr::Result::ERROR_HANDLE_INVALID
        }
    }
}

/// For this crate's tests: entry points the loader reaches only through
/// `xrGetInstanceProcAddr`, which hands out the next layer's in pass-through
/// mode.
#[doc(hidden)]
pub mod test_support {
    /// The layer's own `xrDestroyInstance`.
    pub fn destroy_instance_fn() -> openxr_sys::pfn::DestroyInstance {
        super::destroy_instance
    }
}

/// `xrDestroyInstance`: forgets the instance, then destroys it in the next
/// layer.
///
/// # Safety
/// `instance` is the app's instance (or any handle: an unknown one is
/// answered `XR_ERROR_HANDLE_INVALID`); called as `xrDestroyInstance`.
unsafe extern "system" fn destroy_instance(instance: xr::Instance) -> xr::Result {
    let forwarded: std::cell::Cell<Option<xr::Result>> = std::cell::Cell::new(None);
    let forward = |d: Option<Dispatch>| match d.and_then(|d| d.next_destroy_instance) {
        // SAFETY: the next layer's destroy for the instance it created.
        Some(destroy) => unsafe { destroy(instance) },
        None => xr::Result::ERROR_HANDLE_INVALID,
    };
    guard::guarded(
        "xrDestroyInstance",
        || {
            forwarded.get().unwrap_or_else(|| {
                let d = instances()
                    .as_mut()
                    .and_then(|m| m.remove(&instance.into_raw()));
                forward(d)
            })
        },
        || {
            #[cfg(feature = "test-hooks")]
            guard::test_hook("xrDestroyInstance");
            frames::stop(instance);
            gaze::stop(instance);
            let d = instances()
                .as_mut()
                .and_then(|m| m.remove(&instance.into_raw()));
            let result = forward(d);
            forwarded.set(Some(result));
            result
        },
    )
}
