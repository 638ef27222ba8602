//! The test hook forces a panic in each entry point in turn: no unwinding
//! reaches the caller (an unwinding panic through `extern "system"` aborts
//! the test process), each call still does what the loader and the app
//! need, nothing is done twice, and the layer ends in pass-through mode.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::sync::atomic::Ordering;

use common::*;
use gazelight_openxr_layer::guard::{TEST_PANIC_ENV, pass_through};
use openxr_sys as xr;
use openxr_sys::Handle as _;

fn force_panic_in(entry: &str) {
    // SAFETY: one test in this binary; the layer reads it on its calls,
    // made from this thread.
    unsafe { std::env::set_var(TEST_PANIC_ENV, entry) };
}

#[test]
fn a_panic_in_any_entry_point_is_caught_and_the_layer_passes_through() {
    use_config("gaze = \"gazelight\"\n");

    force_panic_in("xrNegotiateLoaderApiLayerInterface");
    let (r, request) = negotiate();
    assert_eq!(r, xr::Result::SUCCESS);
    assert!(
        request.get_instance_proc_addr.is_some() && request.create_api_layer_instance.is_some()
    );
    assert!(pass_through());

    // After the next layer created the instance: not a second one.
    force_panic_in("xrCreateApiLayerInstance");
    let (r, instance) = create(&request);
    assert_eq!(r, xr::Result::SUCCESS);
    assert_eq!(instance.into_raw(), NEXT_INSTANCE);
    assert_eq!(NEXT_CREATES.load(Ordering::SeqCst), 1);

    force_panic_in("xrGetInstanceProcAddr");
    let (r, f) = proc_addr(&request, instance, c"xrEndFrame");
    assert_eq!(r, xr::Result::SUCCESS);
    assert_eq!(fn_addr(f), end_frame_addr());
    let (_, f) = proc_addr(&request, instance, c"xrDestroyInstance");
    assert_eq!(fn_addr(f), next_destroy_addr());

    // The layer's own destroy, taken before the panics: it panics on entry,
    // and the fallback destroys once.
    force_panic_in("xrDestroyInstance");
    let destroy = gazelight_openxr_layer::test_support::destroy_instance_fn();
    // SAFETY: the instance created above, destroyed once.
    assert_eq!(unsafe { destroy(instance) }, xr::Result::SUCCESS);
    assert_eq!(NEXT_DESTROYS.load(Ordering::SeqCst), 1);
}
