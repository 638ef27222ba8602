//! A fake "next layer" (what the loader chains this layer to: another
//! layer or the runtime) and the loader's side of the negotiation, as the
//! OpenXR loader spec describes them (XrNegotiateLoaderInfo,
//! XrApiLayerCreateInfo with its XrApiLayerNextInfo chain).
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use std::ffi::{CStr, c_char};
use std::sync::atomic::{AtomicUsize, Ordering};

use openxr_sys as xr;
use openxr_sys::Handle as _;
use openxr_sys::pfn;

pub const NEXT_INSTANCE: u64 = 0x5eed;
pub static NEXT_CREATES: AtomicUsize = AtomicUsize::new(0);
pub static NEXT_DESTROYS: AtomicUsize = AtomicUsize::new(0);
pub static NEXT_END_FRAMES: AtomicUsize = AtomicUsize::new(0);
/// Whether the next layer's create saw the chain advanced past ours.
pub static NEXT_SAW_END_OF_CHAIN: AtomicUsize = AtomicUsize::new(0);

/// The fake next layer's `xrCreateApiLayerInstance`.
///
/// # Safety
/// `layer_info` valid and `instance` writable, as the layer passes them.
unsafe extern "system" fn next_create(
    _info: *const xr::InstanceCreateInfo,
    layer_info: *const xr::ApiLayerCreateInfo,
    instance: *mut xr::Instance,
) -> xr::Result {
    NEXT_CREATES.fetch_add(1, Ordering::SeqCst);
    // SAFETY: the layer passes its (advanced) chain, valid for the call.
    if unsafe { (*layer_info).next_info.is_null() } {
        NEXT_SAW_END_OF_CHAIN.fetch_add(1, Ordering::SeqCst);
    }
    // SAFETY: the layer's out-pointer (checked non-null by the layer).
    unsafe { *instance = xr::Instance::from_raw(NEXT_INSTANCE) };
    xr::Result::SUCCESS
}

/// The fake next layer's `xrDestroyInstance`.
///
/// # Safety
/// None beyond the signature: it reads no pointers.
pub unsafe extern "system" fn next_destroy(instance: xr::Instance) -> xr::Result {
    assert_eq!(instance.into_raw(), NEXT_INSTANCE);
    NEXT_DESTROYS.fetch_add(1, Ordering::SeqCst);
    xr::Result::SUCCESS
}

/// The fake next layer's `xrEndFrame`.
///
/// # Safety
/// None beyond the signature: it reads no pointers.
pub unsafe extern "system" fn next_end_frame(
    _session: xr::Session,
    _info: *const xr::FrameEndInfo,
) -> xr::Result {
    NEXT_END_FRAMES.fetch_add(1, Ordering::SeqCst);
    xr::Result::SUCCESS
}

/// The fake next layer's `xrGetInstanceProcAddr`.
///
/// # Safety
/// `name` NUL-terminated, `function` writable.
unsafe extern "system" fn next_gipa(
    instance: xr::Instance,
    name: *const c_char,
    function: *mut Option<pfn::VoidFunction>,
) -> xr::Result {
    // SAFETY: the caller's NUL-terminated name.
    let name = unsafe { CStr::from_ptr(name) };
    let f: Option<pfn::VoidFunction> = if instance.into_raw() != NEXT_INSTANCE {
        None
    } else if name == c"xrDestroyInstance" {
        // SAFETY: a function pointer into the loader's type-erased slot.
        Some(unsafe {
            std::mem::transmute::<pfn::DestroyInstance, pfn::VoidFunction>(next_destroy)
        })
    } else if name == c"xrEndFrame" {
        // SAFETY: as above.
        Some(unsafe { std::mem::transmute::<pfn::EndFrame, pfn::VoidFunction>(next_end_frame) })
    } else {
        None
    };
    // SAFETY: the caller's writable slot.
    unsafe { *function = f };
    if f.is_some() {
        xr::Result::SUCCESS
    } else {
        xr::Result::ERROR_FUNCTION_UNSUPPORTED
    }
}

fn name_array(name: &str) -> [c_char; xr::MAX_API_LAYER_NAME_SIZE] {
    let mut a = [0 as c_char; xr::MAX_API_LAYER_NAME_SIZE];
    for (d, s) in a.iter_mut().zip(name.bytes()) {
        *d = s as c_char;
    }
    a
}

/// The loader's negotiation call; returns its result and the request.
pub fn negotiate() -> (xr::Result, xr::NegotiateApiLayerRequest) {
    let info = xr::NegotiateLoaderInfo {
        struct_type: xr::NegotiateLoaderInfo::TYPE,
        struct_version: xr::NegotiateLoaderInfo::VERSION,
        struct_size: size_of::<xr::NegotiateLoaderInfo>(),
        min_interface_version: 1,
        max_interface_version: 1,
        min_api_version: xr::Version::new(1, 0, 0),
        max_api_version: xr::Version::new(1, 1, 47),
    };
    let mut request = xr::NegotiateApiLayerRequest {
        struct_type: xr::NegotiateApiLayerRequest::TYPE,
        struct_version: xr::NegotiateApiLayerRequest::VERSION,
        struct_size: size_of::<xr::NegotiateApiLayerRequest>(),
        layer_interface_version: 0,
        layer_api_version: xr::Version::new(0, 0, 0),
        get_instance_proc_addr: None,
        create_api_layer_instance: None,
    };
    let name = std::ffi::CString::new(gazelight_openxr_layer::LAYER_NAME).unwrap();
    // SAFETY: valid structures and a NUL-terminated name, alive over the call.
    let r = unsafe {
        gazelight_openxr_layer::xrNegotiateLoaderApiLayerInterface(
            &info,
            name.as_ptr(),
            &mut request,
        )
    };
    (r, request)
}

/// The loader's `xrCreateInstance` through the layer (chain: this layer,
/// then the fake next layer).
pub fn create(request: &xr::NegotiateApiLayerRequest) -> (xr::Result, xr::Instance) {
    let mut next = xr::ApiLayerNextInfo {
        struct_type: xr::ApiLayerNextInfo::TYPE,
        struct_version: xr::ApiLayerNextInfo::VERSION,
        struct_size: size_of::<xr::ApiLayerNextInfo>(),
        layer_name: name_array("XR_APILAYER_TEST_next"),
        next_get_instance_proc_addr: Some(next_gipa),
        next_create_api_layer_instance: Some(next_create),
        next: std::ptr::null_mut(),
    };
    let layer_info = xr::ApiLayerCreateInfo {
        struct_type: xr::ApiLayerCreateInfo::TYPE,
        struct_version: xr::ApiLayerCreateInfo::VERSION,
        struct_size: size_of::<xr::ApiLayerCreateInfo>(),
        loader_instance: std::ptr::null_mut(),
        settings_file_location: [0; xr::API_LAYER_MAX_SETTINGS_PATH_SIZE],
        next_info: &mut next,
    };
    let app = xr::InstanceCreateInfo {
        ty: xr::InstanceCreateInfo::TYPE,
        next: std::ptr::null(),
        create_flags: xr::InstanceCreateFlags::EMPTY,
        application_info: xr::ApplicationInfo {
            application_name: [0; xr::MAX_APPLICATION_NAME_SIZE],
            application_version: 1,
            engine_name: [0; xr::MAX_ENGINE_NAME_SIZE],
            engine_version: 1,
            api_version: xr::Version::new(1, 0, 0),
        },
        enabled_api_layer_count: 0,
        enabled_api_layer_names: std::ptr::null(),
        enabled_extension_count: 0,
        enabled_extension_names: std::ptr::null(),
    };
    let mut instance = xr::Instance::NULL;
    let create = request
        .create_api_layer_instance
        .expect("the layer's create");
    // SAFETY: the app's info, the loader's chain (this layer, then the
    // fake next layer) and an out-pointer, alive over the call.
    let r = unsafe { create(&app, &layer_info, &mut instance) };
    (r, instance)
}

/// The layer's pointer for `name` on `instance`.
pub fn proc_addr(
    request: &xr::NegotiateApiLayerRequest,
    instance: xr::Instance,
    name: &CStr,
) -> (xr::Result, Option<pfn::VoidFunction>) {
    let gipa = request.get_instance_proc_addr.expect("the layer's gipa");
    let mut f = None;
    // SAFETY: a NUL-terminated name and a writable slot.
    let r = unsafe { gipa(instance, name.as_ptr(), &mut f) };
    (r, f)
}

pub fn fn_addr(f: Option<pfn::VoidFunction>) -> usize {
    f.map_or(0, |f| f as usize)
}

pub fn end_frame_addr() -> usize {
    next_end_frame as xr::pfn::EndFrame as usize
}

pub fn next_destroy_addr() -> usize {
    next_destroy as xr::pfn::DestroyInstance as usize
}

/// Points GAZELIGHT_LAYER_CONFIG at a file with `text` (each test binary is
/// its own process; this is called once, before any layer call).
pub fn use_config(text: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("gazelight-layer-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("layer.toml");
    std::fs::write(&path, text).unwrap();
    // SAFETY: set before any other thread of this test binary reads it
    // (one test per binary).
    unsafe { std::env::set_var("GAZELIGHT_LAYER_CONFIG", &path) };
    path
}
