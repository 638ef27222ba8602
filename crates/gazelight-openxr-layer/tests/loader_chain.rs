//! The layer under a simulated loader: negotiation, creation chained to
//! the next layer, every other function forwarded, destroy forwarded once.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::sync::atomic::Ordering;

use common::*;
use openxr_sys as xr;
use openxr_sys::Handle as _;

#[test]
fn the_layer_chains_to_the_next_and_forwards_everything() {
    use_config("source = \"pupil://127.0.0.1:50020\"\n");
    let (r, request) = negotiate();
    assert_eq!(r, xr::Result::SUCCESS);
    assert_eq!(request.layer_interface_version, 1);
    // The loader offered up to 1.1.47: the layer answers no newer.
    assert_eq!(request.layer_api_version, xr::Version::new(1, 1, 47));

    let (r, instance) = create(&request);
    assert_eq!(r, xr::Result::SUCCESS);
    assert_eq!(instance.into_raw(), NEXT_INSTANCE);
    assert_eq!(NEXT_CREATES.load(Ordering::SeqCst), 1);
    assert_eq!(
        NEXT_SAW_END_OF_CHAIN.load(Ordering::SeqCst),
        1,
        "the chain was not advanced"
    );

    // Not intercepted: the next layer's own pointer.
    let (r, f) = proc_addr(&request, instance, c"xrEndFrame");
    assert_eq!(r, xr::Result::SUCCESS);
    assert_eq!(fn_addr(f), end_frame_addr());
    // Unknown to the next layer: its answer, unchanged.
    let (r, f) = proc_addr(&request, instance, c"xrNoSuchFunction");
    assert_eq!(r, xr::Result::ERROR_FUNCTION_UNSUPPORTED);
    assert!(f.is_none());
    // The layer's own gipa.
    let (_, f) = proc_addr(&request, instance, c"xrGetInstanceProcAddr");
    assert_eq!(
        fn_addr(f),
        request.get_instance_proc_addr.map_or(0, |g| g as usize)
    );

    // Intercepted: destroy is the layer's, and reaches the next layer once.
    let (r, f) = proc_addr(&request, instance, c"xrDestroyInstance");
    assert_eq!(r, xr::Result::SUCCESS);
    assert_ne!(fn_addr(f), next_destroy_addr());
    // SAFETY: the layer's pointer for xrDestroyInstance has its signature.
    let destroy: xr::pfn::DestroyInstance = unsafe { std::mem::transmute(f.unwrap()) };
    // SAFETY: the instance the layer created above, destroyed once.
    assert_eq!(unsafe { destroy(instance) }, xr::Result::SUCCESS);
    assert_eq!(NEXT_DESTROYS.load(Ordering::SeqCst), 1);
    // The instance is gone from the layer too.
    let (r, _) = proc_addr(&request, instance, c"xrEndFrame");
    assert_eq!(r, xr::Result::ERROR_HANDLE_INVALID);

    assert!(!gazelight_openxr_layer::guard::pass_through());
}
