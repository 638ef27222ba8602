//! Errors of the OpenXR output.

/// Where to point a user whose machine has no usable OpenXR runtime.
pub const RUNTIME_HINT: &str = "set XR_RUNTIME_JSON to the runtime's manifest \
     (e.g. XR_RUNTIME_JSON=/usr/share/openxr/1/openxr_monado.json) or make one the active \
     runtime (~/.config/openxr/1/active_runtime.json or /etc/xdg/openxr/1/active_runtime.json), \
     and start the runtime's service if it has one (monado-service)";

/// Everything that can go wrong opening or running an OpenXR session. Each
/// variant names the call or object that failed.
#[derive(Debug, thiserror::Error)]
pub enum XrError {
    /// No OpenXR runtime could be reached: the loader library is missing, no
    /// runtime manifest was found, or the runtime is not running.
    #[error("no OpenXR runtime: {detail}; {hint}", hint = RUNTIME_HINT)]
    NoRuntime {
        /// What failed (loader library, `xrCreateInstance`, …) and how.
        detail: String,
    },
    /// The runtime has no head-mounted display connected right now.
    #[error(
        "xrGetSystem(HEAD_MOUNTED_DISPLAY): no headset available \
         (XR_ERROR_FORM_FACTOR_UNAVAILABLE); connect and power on the HMD"
    )]
    NoHeadset,
    /// An OpenXR call failed.
    #[error("{call} failed: XR_{result:?} ({result})")]
    Xr {
        /// The OpenXR function (or step) that failed.
        call: &'static str,
        /// Its result code.
        result: openxr::sys::Result,
    },
    /// A Vulkan call (made by us or by the runtime for us) failed.
    #[error("{call} failed: {result}")]
    Vulkan {
        /// The Vulkan function (or the OpenXR function that made it).
        call: &'static str,
        /// Its result code.
        result: ash::vk::Result,
    },
    /// The Vulkan loader (libvulkan.so.1) could not be opened.
    #[error("loading the Vulkan loader (libvulkan.so.1) failed: {0}")]
    VulkanLoader(String),
    /// The runtime does not offer an extension this crate cannot work without.
    #[error("the OpenXR runtime '{runtime}' does not offer {extension}, which is required")]
    MissingExtension {
        /// The runtime's name.
        runtime: String,
        /// The extension.
        extension: &'static str,
    },
    /// The Vulkan API versions the runtime accepts do not meet those of the
    /// Vulkan loader or of wgpu (1.0 … 1.3).
    #[error(
        "the OpenXR runtime needs Vulkan {min_major}.{min_minor}…{max_major}.{max_minor}, \
         the Vulkan loader offers {loader_major}.{loader_minor}"
    )]
    VulkanVersion {
        /// Lowest version the runtime supports.
        min_major: u16,
        /// Lowest version the runtime supports.
        min_minor: u16,
        /// Highest version the runtime supports.
        max_major: u16,
        /// Highest version the runtime supports.
        max_minor: u16,
        /// The loader's instance version.
        loader_major: u32,
        /// The loader's instance version.
        loader_minor: u32,
    },
    /// The system has no primary stereo view configuration.
    #[error(
        "the OpenXR system '{system}' has no PRIMARY_STEREO view configuration (offers {offered})"
    )]
    NoStereo {
        /// The system's name.
        system: String,
        /// The view configurations it offers.
        offered: String,
    },
    /// None of the runtime's swapchain formats is an 8-bit sRGB colour format.
    #[error(
        "the OpenXR session offers no sRGB RGBA/BGRA swapchain format \
         (VkFormat 43 or 50); it offers {offered:?}"
    )]
    NoSrgbFormat {
        /// The `VkFormat` values the session lists.
        offered: Vec<u32>,
    },
    /// wgpu-hal could not use the physical device the runtime chose.
    #[error("wgpu-hal cannot use the runtime's Vulkan physical device '{device}': {reason}")]
    Adapter {
        /// The device name (or its handle when unnamed).
        device: String,
        /// Why.
        reason: String,
    },
    /// A field of [`crate::XrOptions`] that cannot be used.
    #[error("invalid XrOptions.{field}: {reason}")]
    Options {
        /// The field.
        field: &'static str,
        /// Why.
        reason: String,
    },
    /// wgpu rejected creating or wrapping an object.
    #[error("wgpu rejected {what}: {message}")]
    Wgpu {
        /// What was being created.
        what: String,
        /// wgpu's message.
        message: String,
    },
    /// A frame call made in a state where OpenXR forbids it.
    #[error("{call}: {reason}")]
    CallOrder {
        /// The call.
        call: &'static str,
        /// Why it cannot be made now.
        reason: &'static str,
    },
}

/// `map_err` helper: an OpenXR result into [`XrError::Xr`] naming the call.
pub(crate) fn xr(call: &'static str) -> impl FnOnce(openxr::sys::Result) -> XrError {
    move |result| XrError::Xr { call, result }
}
