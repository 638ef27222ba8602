//! Helpers for GPU tests and benchmarks (this crate's and downstream ones).
//!
//! Tests get one shared device per test binary from [`test_context`]
//! (WebGPU default limits, `WGPU_BACKEND` honoured). When no adapter exists
//! the test prints a skip line and returns, unless `GAZELIGHT_REQUIRE_GPU=1`
//! (CI), in which case it fails. Every GPU test prints the adapter it ran on.

use std::sync::OnceLock;

use crate::context::{ContextOptions, GpuContext};

/// Environment variable that turns a missing adapter into a test failure.
pub const REQUIRE_GPU_ENV: &str = "GAZELIGHT_REQUIRE_GPU";

/// Whether `GAZELIGHT_REQUIRE_GPU=1` is set.
pub fn gpu_required() -> bool {
    std::env::var(REQUIRE_GPU_ENV).is_ok_and(|v| v.trim() == "1")
}

/// The shared test device, created on first use with the WebGPU default
/// limits; `None` (after printing `SKIP <test>: …`) when there is no adapter.
///
/// # Panics
/// When there is no adapter and `GAZELIGHT_REQUIRE_GPU=1`: that is the test
/// failure CI asks for.
pub fn test_context(test: &str) -> Option<&'static GpuContext> {
    static CONTEXT: OnceLock<Result<GpuContext, String>> = OnceLock::new();
    let context = CONTEXT
        .get_or_init(|| GpuContext::new(&ContextOptions::default()).map_err(|e| e.to_string()));
    match context {
        Ok(ctx) => {
            println!("{test}: running on {}", ctx.describe());
            Some(ctx)
        }
        Err(e) if gpu_required() => panic!("{test}: {REQUIRE_GPU_ENV}=1 but no GPU device: {e}"),
        Err(e) => {
            println!(
                "SKIP {test}: no GPU device ({e}); set {REQUIRE_GPU_ENV}=1 to make this a failure"
            );
            None
        }
    }
}
