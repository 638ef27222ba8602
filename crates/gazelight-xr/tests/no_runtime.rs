//! Without a reachable runtime, `XrSession::open` fails with a message that
//! says what to set. Runs everywhere: with no OpenXR loader installed the
//! loader itself is missing; with one, the manifest below does not exist.

use gazelight_xr::{XrError, XrOptions, XrSession};

#[test]
fn missing_runtime_names_xr_runtime_json() {
    // SAFETY: this test binary has this one test, so no other thread reads
    // the environment concurrently.
    unsafe {
        std::env::set_var(
            "XR_RUNTIME_JSON",
            "/nonexistent/gazelight-xr/no_runtime.json",
        )
    };
    let err = match XrSession::open(&XrOptions::default()) {
        Ok(_) => panic!("opened a session with XR_RUNTIME_JSON pointing at nothing"),
        Err(e) => e,
    };
    let message = err.to_string();
    println!("{message}");
    assert!(matches!(err, XrError::NoRuntime { .. }), "{err:?}");
    assert!(message.contains("XR_RUNTIME_JSON"), "{message}");
}
