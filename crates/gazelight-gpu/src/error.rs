//! Errors of the GPU backend.

/// Everything that can go wrong creating a device, building a pass or
/// running it. Each variant names what failed and where.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter of the requested kind exists (or none could give a device).
    #[error("no GPU adapter ({choice}) on backends {backends}: {reason}")]
    NoAdapter {
        /// The adapter choice that was asked for.
        choice: String,
        /// The backends that were searched (`WGPU_BACKEND` or all).
        backends: String,
        /// What was tried and why it failed.
        reason: String,
    },
    /// WGSL source that naga cannot parse.
    #[error("shader '{shader}': WGSL parse error:\n{message}")]
    ShaderParse {
        /// Shader file name.
        shader: &'static str,
        /// naga's diagnostic, with source excerpt.
        message: String,
    },
    /// WGSL that parses but does not validate.
    #[error("shader '{shader}': validation error:\n{message}")]
    ShaderValidation {
        /// Shader file name.
        shader: &'static str,
        /// naga's diagnostic, with source excerpt.
        message: String,
    },
    /// An entry point's `var<workgroup>` storage exceeds the device limit.
    #[error(
        "shader '{shader}': entry point '{entry_point}' uses {bytes} bytes of workgroup storage, \
         over the device limit max_compute_workgroup_storage_size = {limit}"
    )]
    WorkgroupStorage {
        /// Shader file name.
        shader: &'static str,
        /// Compute entry point.
        entry_point: String,
        /// Bytes of `var<workgroup>` globals used by the entry point.
        bytes: u64,
        /// The device's limit.
        limit: u32,
    },
    /// An entry point's workgroup size exceeds a device limit.
    #[error(
        "shader '{shader}': entry point '{entry_point}' has workgroup size {size:?}, \
         over the device limit {limit_name} = {limit}"
    )]
    WorkgroupSize {
        /// Shader file name.
        shader: &'static str,
        /// Compute entry point.
        entry_point: String,
        /// `@workgroup_size(x, y, z)`.
        size: [u32; 3],
        /// The wgpu limit that is exceeded.
        limit_name: &'static str,
        /// The device's value of that limit.
        limit: u32,
    },
    /// A shader's entry point was not found.
    #[error("shader '{shader}': no compute entry point named '{entry_point}'")]
    MissingEntryPoint {
        /// Shader file name.
        shader: &'static str,
        /// The entry point asked for.
        entry_point: String,
    },
    /// wgpu reported a validation or out-of-memory error creating an object.
    #[error("wgpu rejected {what}: {message}")]
    Wgpu {
        /// What was being created.
        what: String,
        /// wgpu's message.
        message: String,
    },
    /// An FFT plan with sizes it cannot handle.
    #[error("FFT of {width}x{height}x{channels}: {reason}")]
    FftSize {
        /// Width (row length) in elements.
        width: u32,
        /// Height (column length) in elements.
        height: u32,
        /// Number of planes.
        channels: u32,
        /// What is wrong.
        reason: String,
    },
    /// Host data of the wrong length handed to a pass.
    #[error("{what}: expected {expected} elements, got {got}")]
    Length {
        /// Which buffer.
        what: &'static str,
        /// Elements the pass holds.
        expected: usize,
        /// Elements given.
        got: usize,
    },
    /// Parameters of a pass that the CPU model rejects (e.g. the glare PSF's
    /// `psf.*` fields, or a pupil outside the supported range).
    #[error("invalid parameters for {what}: {source}")]
    InvalidParams {
        /// Which pass.
        what: &'static str,
        /// The model's error, naming the field and the valid range.
        #[source]
        source: gazelight_vision::VisionError,
    },
    /// Waiting for the device failed.
    #[error("waiting for the GPU failed: {0}")]
    Poll(#[from] wgpu::PollError),
    /// Mapping a buffer for reading failed.
    #[error("mapping {what} for reading failed: {source}")]
    Map {
        /// Which buffer.
        what: &'static str,
        /// wgpu's error.
        #[source]
        source: wgpu::BufferAsyncError,
    },
}
