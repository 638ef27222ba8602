//! A bad config: the instance is created, the layer forwards everything.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::*;
use openxr_sys as xr;
use openxr_sys::Handle as _;

#[test]
fn a_bad_config_leaves_the_app_working_and_the_layer_passing_through() {
    use_config("[pipeline]\nglare = { window_px = 256 }\n");
    let (r, request) = negotiate();
    assert_eq!(r, xr::Result::SUCCESS);
    let (r, instance) = create(&request);
    assert_eq!(r, xr::Result::SUCCESS);
    assert_eq!(instance.into_raw(), NEXT_INSTANCE);
    assert!(gazelight_openxr_layer::guard::pass_through());
    // Pass-through: even destroy is the next layer's own.
    let (_, f) = proc_addr(&request, instance, c"xrDestroyInstance");
    assert_eq!(fn_addr(f), next_destroy_addr());
    let (_, f) = proc_addr(&request, instance, c"xrEndFrame");
    assert_eq!(fn_addr(f), end_frame_addr());
}
