//! The panic guard around every exported entry point: no unwinding across
//! `extern "system"`, and after a panic the layer only forwards.
//!
//! Test hook (compiled only with the `test-hooks` feature, which the
//! product build leaves off: `cargo test -p gazelight-openxr-layer
//! --features test-hooks`, and `.ci/xr/run`'s second build of the
//! library): `GAZELIGHT_LAYER_TEST_PANIC` set to an entry point's name
//! (`xrNegotiateLoaderApiLayerInterface`, `xrCreateApiLayerInstance`,
//! `xrGetInstanceProcAddr`, `xrDestroyInstance`; with the frame effects
//! running `xrCreateVulkanInstanceKHR`, `xrCreateVulkanDeviceKHR`,
//! `xrEndFrame`), or a comma-separated list
//! of them, or `all`, makes that entry point panic where it does its own
//! work: `xrCreateApiLayerInstance` after the next layer created the
//! instance (so the fallback must not create a second one), the others on
//! entry.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, Ordering};

use crate::log::log;

/// The variable of the test hook.
#[cfg(feature = "test-hooks")]
pub const TEST_PANIC_ENV: &str = "GAZELIGHT_LAYER_TEST_PANIC";

static PASS_THROUGH: AtomicBool = AtomicBool::new(false);

/// Whether the layer has turned into pass-through mode (a panic, or a bad
/// config).
pub fn pass_through() -> bool {
    PASS_THROUGH.load(Ordering::Relaxed)
}

/// Turns the layer into pass-through mode for the rest of the process.
pub fn set_pass_through() {
    PASS_THROUGH.store(true, Ordering::Relaxed);
}

/// Runs `body`; when it panics, logs the panic with the entry point's name,
/// sets pass-through mode and returns `fallback()` instead. `fallback` must
/// not panic (it forwards with plain pointer work).
pub fn guarded<R>(
    entry: &'static str,
    fallback: impl FnOnce() -> R,
    body: impl FnOnce() -> R,
) -> R {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(r) => r,
        Err(payload) => {
            let what = payload
                .downcast_ref::<&str>()
                .map(|s| (*s).to_owned())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "a panic without a message".to_owned());
            log(
                "error",
                &format!(
                    "panic in {entry}: {what}; the layer passes everything through from now on"
                ),
            );
            set_pass_through();
            fallback()
        }
    }
}

/// Panics when the test hook names `entry` (see the module docs). Only in
/// a `test-hooks` build: the product's entry points read no test variable.
#[cfg(feature = "test-hooks")]
pub fn test_hook(entry: &str) {
    if let Some(v) = std::env::var_os(TEST_PANIC_ENV) {
        let v = v.to_string_lossy();
        if v.split(',').any(|n| n.trim() == entry || n.trim() == "all") {
            panic!("{TEST_PANIC_ENV} forces a panic in {entry}");
        }
    }
}
