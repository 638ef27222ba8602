//! The OpenXR session: instance and system, the Vulkan device shared with
//! wgpu, per-eye swapchains as `wgpu::Texture`s, the session state
//! machine, the frame loop and the eye gaze action.

use std::ffi::c_void;

use ash::vk::{self, Handle as _};
use openxr as xr;
use wgpu::hal;
use wgpu::hal::api::Vulkan as VkApi;

use crate::error::{XrError, xr};
use crate::geometry::{Fov, Pose, gaze_to_view_uv};
use crate::vulkan;

/// `VK_FORMAT_R8G8B8A8_SRGB`.
const VK_RGBA8_SRGB: u32 = 43;
/// `VK_FORMAT_B8G8R8A8_SRGB`.
const VK_BGRA8_SRGB: u32 = 50;
const EYE_GAZE_PROFILE: &str = "/interaction_profiles/ext/eye_gaze_interaction";
const EYE_GAZE_POSE: &str = "/user/eyes_ext/input/gaze_ext/pose";
const VIEW_CONFIG: xr::ViewConfigurationType = xr::ViewConfigurationType::PRIMARY_STEREO;

/// The reference space the views and the gaze are located in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ReferenceSpace {
    /// `XR_REFERENCE_SPACE_TYPE_LOCAL`: origin at the head's starting
    /// position, seated use. Every runtime offers it.
    #[default]
    Local,
    /// `XR_REFERENCE_SPACE_TYPE_STAGE`: origin on the floor of the play
    /// area. Falls back to `Local` when the runtime has no stage.
    Stage,
}

impl ReferenceSpace {
    fn xr(self) -> xr::ReferenceSpaceType {
        match self {
            ReferenceSpace::Local => xr::ReferenceSpaceType::LOCAL,
            ReferenceSpace::Stage => xr::ReferenceSpaceType::STAGE,
        }
    }
}

/// How to open a session.
#[derive(Debug, Clone)]
pub struct XrOptions {
    /// Application name shown by the runtime (1–127 bytes, no NUL).
    pub app_name: String,
    /// Preferred reference space; `Stage` falls back to `Local` when the
    /// runtime has none (see [`XrSessionInfo::reference_space`]).
    pub reference_space: ReferenceSpace,
    /// Request `XR_EXT_eye_gaze_interaction` and, when the system supports
    /// it, create the eye gaze pose action.
    pub eye_gaze: bool,
    /// wgpu features the caller's passes need on the shared device.
    pub required_features: wgpu::Features,
    /// wgpu limits the caller's passes need on the shared device.
    pub required_limits: wgpu::Limits,
}

impl Default for XrOptions {
    fn default() -> Self {
        Self {
            app_name: "gazelight".into(),
            reference_space: ReferenceSpace::Local,
            eye_gaze: true,
            required_features: wgpu::Features::empty(),
            required_limits: wgpu::Limits::default(),
        }
    }
}

/// What was opened: runtime, system, extensions, formats, sizes.
#[derive(Debug, Clone)]
pub struct XrSessionInfo {
    /// The runtime's name, e.g. "Monado(XRT) by Collabora et al …".
    pub runtime_name: String,
    /// The runtime's version, "major.minor.patch".
    pub runtime_version: String,
    /// The system (HMD) name.
    pub system_name: String,
    /// The OpenXR extensions enabled on the instance.
    pub enabled_extensions: Vec<&'static str>,
    /// `supportsEyeGazeInteraction` of the system (false when the
    /// extension is not enabled).
    pub eye_gaze_supported: bool,
    /// Whether the eye gaze action exists (extension enabled, system
    /// supports it, and [`XrOptions::eye_gaze`] asked for it).
    pub eye_gaze_action: bool,
    /// The reference space in use.
    pub reference_space: ReferenceSpace,
    /// The environment blend mode frames are submitted with.
    pub blend_mode: String,
    /// The swapchain format (an sRGB one; shaders write linear values).
    pub swapchain_format: wgpu::TextureFormat,
    /// Per eye (left, right): the runtime's recommended image size.
    pub eye_size_px: [[u32; 2]; 2],
    /// Per eye: images in the swapchain.
    pub swapchain_images: [usize; 2],
    /// The wgpu adapter (the runtime's physical device).
    pub adapter: wgpu::AdapterInfo,
    /// The Vulkan API version of the instance, "major.minor".
    pub vulkan_version: String,
}

/// The session's lifecycle state (`XrSessionState`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SessionState {
    /// Created, or stopped and waiting: no frames.
    Idle,
    /// The runtime wants the session to begin (done in `poll_events`).
    Ready,
    /// Running; frames are paced but not shown.
    Synchronized,
    /// Frames are shown; no input focus.
    Visible,
    /// Frames are shown and input (eye gaze) is delivered.
    Focused,
    /// The runtime wants the session to end (done in `poll_events`).
    Stopping,
    /// The session is being lost; drop it (and maybe try again later).
    LossPending,
    /// The session should be dropped and the application exit.
    Exiting,
    /// A state this crate does not know.
    Other(i32),
}

impl SessionState {
    fn from_xr(s: xr::SessionState) -> Self {
        match s {
            xr::SessionState::IDLE => SessionState::Idle,
            xr::SessionState::READY => SessionState::Ready,
            xr::SessionState::SYNCHRONIZED => SessionState::Synchronized,
            xr::SessionState::VISIBLE => SessionState::Visible,
            xr::SessionState::FOCUSED => SessionState::Focused,
            xr::SessionState::STOPPING => SessionState::Stopping,
            xr::SessionState::LOSS_PENDING => SessionState::LossPending,
            xr::SessionState::EXITING => SessionState::Exiting,
            other => SessionState::Other(other.into_raw()),
        }
    }
}

/// Where the session stands after [`XrSession::poll_events`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionStatus {
    /// The current state.
    pub state: SessionState,
    /// The states entered during this poll, in order.
    pub changes: Vec<SessionState>,
    /// Between `xrBeginSession` and `xrEndSession`: frames may be run.
    pub running: bool,
    /// The session has been `Focused` at least once.
    pub focused_reached: bool,
    /// The session is over (`Exiting`, `LossPending` or instance loss):
    /// drop the [`XrSession`].
    pub should_exit: bool,
}

/// Left or right.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Eye {
    /// View 0 of `PRIMARY_STEREO`.
    Left,
    /// View 1 of `PRIMARY_STEREO`.
    Right,
}

/// One eye of a frame: where it is, what it sees, and the swapchain image
/// to render into.
#[derive(Debug, Clone)]
pub struct EyeView {
    /// Which eye.
    pub eye: Eye,
    /// The eye's pose in the session's reference space.
    pub pose: Pose,
    /// The eye's field of view.
    pub fov: Fov,
    /// The acquired swapchain image (usage `RENDER_ATTACHMENT | COPY_DST |
    /// COPY_SRC | TEXTURE_BINDING`, format
    /// [`XrSessionInfo::swapchain_format`]).
    pub texture: wgpu::Texture,
    /// A 2D view of `texture` to render into.
    pub view: wgpu::TextureView,
    /// Image width in pixels.
    pub width_px: u32,
    /// Image height in pixels.
    pub height_px: u32,
    /// Index of the image in its swapchain.
    pub image_index: u32,
}

/// A frame begun by [`XrSession::begin_frame`]; hand it back to
/// [`XrSession::end_frame`] once the rendering is submitted.
#[derive(Debug)]
pub struct XrFrame {
    /// When the frame will be shown, XR time in nanoseconds.
    pub predicted_display_time_ns: i64,
    /// The predicted time between displayed frames, nanoseconds.
    pub predicted_display_period_ns: i64,
    /// `predicted_display_time_ns` on CLOCK_MONOTONIC, in seconds (when
    /// `XR_KHR_convert_timespec_time` is enabled).
    pub predicted_display_monotonic_secs: Option<f64>,
    /// Whether the runtime wants this frame rendered; when false `views` is
    /// empty and `end_frame` submits no layers.
    pub should_render: bool,
    /// Left then right, when rendering.
    pub views: Vec<EyeView>,
    /// Whether both views' orientation and position are tracked (else
    /// the poses are the runtime's best guess).
    pub views_tracked: bool,
    /// The eye gaze pose in the reference space (origin between the eyes,
    /// looking along −Z), when the gaze action is active and located.
    pub gaze: Option<Pose>,
    /// The frame's eye-view poses/fovs as OpenXR returned them.
    raw_views: Vec<(xr::Posef, xr::Fovf)>,
}

impl XrFrame {
    /// The gaze in normalised view coordinates of `views[index]` (see
    /// [`gaze_to_view_uv`]); `None` without a gaze or that view.
    pub fn gaze_uv(&self, index: usize) -> Option<[f32; 2]> {
        let gaze = self.gaze?;
        let view = self.views.get(index)?;
        gaze_to_view_uv(gaze.relative_to(&view.pose).orientation, &view.fov)
    }
}

/// Acquire state of a swapchain, mirrored here because the `openxr` crate
/// asserts on out-of-order calls.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ImageState {
    Free,
    Acquired,
    Waited,
}

/// One eye's swapchain and its images wrapped for wgpu (once, at creation).
struct EyeSwapchain {
    textures: Vec<wgpu::Texture>,
    views: Vec<wgpu::TextureView>,
    width_px: u32,
    height_px: u32,
    state: ImageState,
    swapchain: xr::Swapchain<xr::Vulkan>,
}

/// The eye gaze action and its space.
struct GazeInput {
    space: xr::Space,
    action: xr::Action<xr::Posef>,
    set: xr::ActionSet,
}

/// An OpenXR session rendering through wgpu on the runtime's Vulkan device.
///
/// Drop order is part of the contract: the wrapped swapchain textures are
/// destroyed and the device is idled first, then swapchains, spaces and the
/// session, then the OpenXR instance; the wgpu device and instance (shared
/// with the caller) live on in the caller's handles.
///
/// The runtime submits on the same Vulkan queue as wgpu (in
/// `xrReleaseSwapchainImage` / `xrEndFrame`): do not call
/// `wgpu::Queue::submit` from another thread while [`XrSession::end_frame`]
/// runs.
pub struct XrSession {
    eyes: Vec<EyeSwapchain>,
    gaze: Option<GazeInput>,
    space: xr::Space,
    frame_waiter: xr::FrameWaiter,
    frame_stream: xr::FrameStream<xr::Vulkan>,
    session: xr::Session<xr::Vulkan>,
    xr_instance: xr::Instance,
    system: xr::SystemId,
    blend_mode: xr::EnvironmentBlendMode,
    info: XrSessionInfo,
    state: SessionState,
    running: bool,
    focused_reached: bool,
    should_exit: bool,
    /// Display time of a begun frame not yet ended.
    open_frame: Option<xr::Time>,
    event_buffer: xr::EventDataBuffer,
    device: wgpu::Device,
    queue: wgpu::Queue,
    _adapter: wgpu::Adapter,
    _instance: wgpu::Instance,
}

fn no_runtime(what: &str, result: xr::sys::Result) -> XrError {
    let cause = if result == xr::sys::Result::ERROR_RUNTIME_UNAVAILABLE {
        "no runtime manifest found, or its library failed to load"
    } else {
        "the runtime is installed but not working; is its service running?"
    };
    XrError::NoRuntime {
        detail: format!("{what} returned XR_{result:?} ({cause})"),
    }
}

/// Maps the results that mean "no runtime reachable" to [`XrError::NoRuntime`].
fn runtime_call(what: &'static str) -> impl FnOnce(xr::sys::Result) -> XrError {
    move |result| match result {
        xr::sys::Result::ERROR_RUNTIME_UNAVAILABLE | xr::sys::Result::ERROR_RUNTIME_FAILURE => {
            no_runtime(what, result)
        }
        _ => XrError::Xr { call: what, result },
    }
}

impl XrSession {
    /// Opens a session: loads the OpenXR loader, creates the instance
    /// (XR_KHR_vulkan_enable2, plus XR_KHR_convert_timespec_time and
    /// XR_EXT_eye_gaze_interaction when offered), the Vulkan instance and
    /// device through the runtime and wraps them for wgpu, creates the
    /// session, the reference space, one swapchain per eye at the
    /// recommended size in an sRGB format, and the eye gaze action.
    ///
    /// The session starts `Idle`; call [`XrSession::poll_events`] until it
    /// is running. The returned adapter/device/queue are the ones to render
    /// with.
    pub fn open(
        options: &XrOptions,
    ) -> Result<(XrSession, wgpu::Adapter, wgpu::Device, wgpu::Queue), XrError> {
        let name_len = options.app_name.len();
        if name_len == 0
            || name_len >= xr::sys::MAX_APPLICATION_NAME_SIZE
            || options.app_name.contains('\0')
        {
            return Err(XrError::Options {
                field: "app_name",
                reason: format!(
                    "must be 1..{} bytes without NUL, is {name_len} bytes",
                    xr::sys::MAX_APPLICATION_NAME_SIZE - 1
                ),
            });
        }

        // SAFETY: loads libopenxr_loader.so.1, a conforming OpenXR loader.
        let entry = unsafe { xr::Entry::load(&()) }.map_err(|e| XrError::NoRuntime {
            detail: match e {
                xr::EntryError::Load(err) => {
                    format!("loading the OpenXR loader libopenxr_loader.so.1 failed ({err}; install libopenxr-loader1)")
                }
                xr::EntryError::Xr(r) => format!("initialising the OpenXR loader returned {r}"),
            },
        })?;
        let available = entry
            .enumerate_extensions()
            .map_err(runtime_call("xrEnumerateInstanceExtensionProperties"))?;
        let mut wanted = xr::ExtensionSet::default();
        let mut enabled: Vec<&'static str> = Vec::new();
        wanted.khr_vulkan_enable2 = true;
        enabled.push("XR_KHR_vulkan_enable2");
        if available.khr_convert_timespec_time {
            wanted.khr_convert_timespec_time = true;
            enabled.push("XR_KHR_convert_timespec_time");
        }
        if options.eye_gaze && available.ext_eye_gaze_interaction {
            wanted.ext_eye_gaze_interaction = true;
            enabled.push("XR_EXT_eye_gaze_interaction");
        }
        if !available.khr_vulkan_enable2 {
            return Err(XrError::MissingExtension {
                runtime: "(not yet created)".into(),
                extension: "XR_KHR_vulkan_enable2",
            });
        }
        let xr_instance = entry
            .create_instance(
                &xr::ApplicationInfo {
                    application_name: &options.app_name,
                    application_version: 1,
                    engine_name: "gazelight",
                    engine_version: 1,
                    api_version: xr::Version::new(1, 0, 0),
                },
                &wanted,
                &[],
                &(),
            )
            .map_err(runtime_call("xrCreateInstance"))?;
        let props = xr_instance
            .properties()
            .map_err(xr("xrGetInstanceProperties"))?;
        let runtime_name = props.runtime_name.clone();
        let runtime_version = format!(
            "{}.{}.{}",
            props.runtime_version.major(),
            props.runtime_version.minor(),
            props.runtime_version.patch()
        );

        let system = xr_instance
            .system(xr::FormFactor::HEAD_MOUNTED_DISPLAY)
            .map_err(|result| match result {
                xr::sys::Result::ERROR_FORM_FACTOR_UNAVAILABLE => XrError::NoHeadset,
                _ => XrError::Xr {
                    call: "xrGetSystem",
                    result,
                },
            })?;
        let (system_name, eye_gaze_supported) =
            system_properties(&xr_instance, system, wanted.ext_eye_gaze_interaction)?;

        let configs = xr_instance
            .enumerate_view_configurations(system)
            .map_err(xr("xrEnumerateViewConfigurations"))?;
        if !configs.contains(&VIEW_CONFIG) {
            return Err(XrError::NoStereo {
                system: system_name,
                offered: format!("{configs:?}"),
            });
        }
        let config_views = xr_instance
            .enumerate_view_configuration_views(system, VIEW_CONFIG)
            .map_err(xr("xrEnumerateViewConfigurationViews"))?;
        if config_views.len() != 2 {
            return Err(XrError::NoStereo {
                system: system_name,
                offered: format!("PRIMARY_STEREO with {} views", config_views.len()),
            });
        }
        let blend_modes = xr_instance
            .enumerate_environment_blend_modes(system, VIEW_CONFIG)
            .map_err(xr("xrEnumerateEnvironmentBlendModes"))?;
        let blend_mode = if blend_modes.contains(&xr::EnvironmentBlendMode::OPAQUE) {
            xr::EnvironmentBlendMode::OPAQUE
        } else {
            blend_modes.first().copied().ok_or(XrError::Xr {
                call: "xrEnumerateEnvironmentBlendModes (empty list)",
                result: xr::sys::Result::ERROR_VALIDATION_FAILURE,
            })?
        };

        let vk = vulkan::create(
            &xr_instance,
            system,
            &options.app_name,
            options.required_features,
            &options.required_limits,
        )?;

        // SAFETY: the handles are the runtime's own instance / physical
        // device and a device created through it, with one queue of this
        // family; the session is dropped before them (see `XrSession`).
        let (session, frame_waiter, frame_stream) = unsafe {
            xr_instance.create_session::<xr::Vulkan>(
                system,
                &xr::vulkan::SessionCreateInfo {
                    instance: vk.raw_instance.as_raw() as *const c_void,
                    physical_device: vk.raw_physical_device.as_raw() as *const c_void,
                    device: vk.raw_device.as_raw() as *const c_void,
                    queue_family_index: vk.queue_family_index,
                    queue_index: 0,
                },
            )
        }
        .map_err(xr("xrCreateSession"))?;

        let spaces = session
            .enumerate_reference_spaces()
            .map_err(xr("xrEnumerateReferenceSpaces"))?;
        let reference_space = if spaces.contains(&options.reference_space.xr()) {
            options.reference_space
        } else {
            ReferenceSpace::Local
        };
        let space = session
            .create_reference_space(reference_space.xr(), xr::Posef::IDENTITY)
            .map_err(xr("xrCreateReferenceSpace"))?;

        let gaze = if options.eye_gaze && wanted.ext_eye_gaze_interaction && eye_gaze_supported {
            Some(create_gaze_input(&xr_instance, &session)?)
        } else {
            None
        };

        let formats = session
            .enumerate_swapchain_formats()
            .map_err(xr("xrEnumerateSwapchainFormats"))?;
        let (vk_format, format) = formats
            .iter()
            .find_map(|&f| match f {
                VK_RGBA8_SRGB => Some((f, wgpu::TextureFormat::Rgba8UnormSrgb)),
                VK_BGRA8_SRGB => Some((f, wgpu::TextureFormat::Bgra8UnormSrgb)),
                _ => None,
            })
            .ok_or_else(|| XrError::NoSrgbFormat {
                offered: formats.clone(),
            })?;

        let mut eyes = Vec::with_capacity(2);
        for (i, cv) in config_views.iter().enumerate() {
            let label = if i == 0 {
                "xr left eye"
            } else {
                "xr right eye"
            };
            eyes.push(create_eye_swapchain(
                &session,
                &vk.device,
                vk_format,
                format,
                cv.recommended_image_rect_width,
                cv.recommended_image_rect_height,
                label,
            )?);
        }

        let info = XrSessionInfo {
            runtime_name,
            runtime_version,
            system_name,
            enabled_extensions: enabled,
            eye_gaze_supported,
            eye_gaze_action: gaze.is_some(),
            reference_space,
            blend_mode: format!("{blend_mode:?}"),
            swapchain_format: format,
            eye_size_px: [
                [eyes[0].width_px, eyes[0].height_px],
                [eyes[1].width_px, eyes[1].height_px],
            ],
            swapchain_images: [eyes[0].textures.len(), eyes[1].textures.len()],
            adapter: vk.adapter.get_info(),
            vulkan_version: format!(
                "{}.{}",
                vk::api_version_major(vk.api_version),
                vk::api_version_minor(vk.api_version)
            ),
        };
        tracing::info!(
            runtime = %info.runtime_name,
            system = %info.system_name,
            adapter = %info.adapter.name,
            extensions = ?info.enabled_extensions,
            format = ?info.swapchain_format,
            eye_size_px = ?info.eye_size_px,
            "OpenXR session created"
        );

        let adapter = vk.adapter.clone();
        let device = vk.device.clone();
        let queue = vk.queue.clone();
        Ok((
            XrSession {
                eyes,
                gaze,
                space,
                frame_waiter,
                frame_stream,
                session,
                xr_instance,
                system,
                blend_mode,
                info,
                state: SessionState::Idle,
                running: false,
                focused_reached: false,
                should_exit: false,
                open_frame: None,
                event_buffer: xr::EventDataBuffer::new(),
                device: vk.device,
                queue: vk.queue,
                _adapter: vk.adapter,
                _instance: vk.instance,
            },
            adapter,
            device,
            queue,
        ))
    }

    /// What was opened.
    pub fn info(&self) -> &XrSessionInfo {
        &self.info
    }

    /// The current session state.
    pub fn state(&self) -> SessionState {
        self.state
    }

    /// Whether the session is running (frames may be begun).
    pub fn is_running(&self) -> bool {
        self.running
    }

    /// The OpenXR system id (for callers using the `openxr` crate directly).
    pub fn system_id(&self) -> xr::SystemId {
        self.system
    }

    /// Drains the runtime's events and acts on them: `Ready` begins the
    /// session (`xrBeginSession`, PRIMARY_STEREO), `Stopping` ends it
    /// (`xrEndSession`, after closing a frame left open), `Exiting`,
    /// `LossPending` and instance loss set [`SessionStatus::should_exit`].
    pub fn poll_events(&mut self) -> Result<SessionStatus, XrError> {
        let mut changes = Vec::new();
        loop {
            let event = self
                .xr_instance
                .poll_event(&mut self.event_buffer)
                .map_err(xr("xrPollEvent"))?;
            let Some(event) = event else { break };
            match event {
                xr::Event::SessionStateChanged(e) => {
                    let state = SessionState::from_xr(e.state());
                    tracing::debug!(?state, "OpenXR session state");
                    self.state = state;
                    changes.push(state);
                    match state {
                        SessionState::Ready => {
                            self.session
                                .begin(VIEW_CONFIG)
                                .map_err(xr("xrBeginSession"))?;
                            self.running = true;
                        }
                        SessionState::Stopping => {
                            self.close_open_frame()?;
                            self.session.end().map_err(xr("xrEndSession"))?;
                            self.running = false;
                        }
                        SessionState::Focused => self.focused_reached = true,
                        SessionState::Exiting | SessionState::LossPending => {
                            self.should_exit = true;
                        }
                        _ => {}
                    }
                }
                xr::Event::InstanceLossPending(_) => {
                    tracing::warn!("OpenXR instance loss pending");
                    self.should_exit = true;
                }
                xr::Event::EventsLost(e) => {
                    tracing::warn!(lost = e.lost_event_count(), "OpenXR events lost");
                }
                _ => {}
            }
        }
        Ok(SessionStatus {
            state: self.state,
            changes,
            running: self.running,
            focused_reached: self.focused_reached,
            should_exit: self.should_exit,
        })
    }

    /// Asks the runtime to end the session (`xrRequestExitSession`); it
    /// then goes through `Stopping` (ended by `poll_events`) to `Exiting`.
    /// When the session is not running there is nothing to stop and
    /// [`SessionStatus::should_exit`] is set at once.
    pub fn request_exit(&mut self) -> Result<(), XrError> {
        if self.running {
            self.session
                .request_exit()
                .map_err(xr("xrRequestExitSession"))
        } else {
            self.should_exit = true;
            Ok(())
        }
    }

    /// Waits for the runtime's frame timing (`xrWaitFrame`, which paces the
    /// loop), begins a frame (`xrBeginFrame`) and, when the runtime wants
    /// it rendered, locates both views at the predicted display time,
    /// acquires and waits each eye's swapchain image and locates the gaze.
    ///
    /// `Ok(None)` when the session is not running (poll events and try
    /// again). Every `Some(frame)` must go back to [`XrSession::end_frame`];
    /// a frame dropped instead is closed (no layers) at the next call.
    pub fn begin_frame(&mut self) -> Result<Option<XrFrame>, XrError> {
        if !self.running {
            return Ok(None);
        }
        self.close_open_frame()?;
        let state = self.frame_waiter.wait().map_err(xr("xrWaitFrame"))?;
        self.frame_stream.begin().map_err(xr("xrBeginFrame"))?;
        let time = state.predicted_display_time;
        self.open_frame = Some(time);
        let mut frame = XrFrame {
            predicted_display_time_ns: time.as_nanos(),
            predicted_display_period_ns: state.predicted_display_period.as_nanos(),
            predicted_display_monotonic_secs: self.monotonic_secs(time),
            should_render: state.should_render,
            views: Vec::new(),
            views_tracked: false,
            gaze: None,
            raw_views: Vec::new(),
        };
        if !state.should_render {
            return Ok(Some(frame));
        }
        let (flags, views) = self
            .session
            .locate_views(VIEW_CONFIG, time, &self.space)
            .map_err(xr("xrLocateViews"))?;
        if views.len() != self.eyes.len() {
            return Err(XrError::Xr {
                call: "xrLocateViews (view count differs from the swapchains)",
                result: xr::sys::Result::ERROR_VALIDATION_FAILURE,
            });
        }
        frame.views_tracked = flags.contains(
            xr::ViewStateFlags::ORIENTATION_TRACKED | xr::ViewStateFlags::POSITION_TRACKED,
        );
        for (i, (eye, view)) in self.eyes.iter_mut().zip(&views).enumerate() {
            let index = eye
                .swapchain
                .acquire_image()
                .map_err(xr("xrAcquireSwapchainImage"))?;
            eye.state = ImageState::Acquired;
            eye.swapchain
                .wait_image(xr::Duration::INFINITE)
                .map_err(xr("xrWaitSwapchainImage"))?;
            eye.state = ImageState::Waited;
            let slot = index as usize;
            let (Some(texture), Some(tex_view)) = (eye.textures.get(slot), eye.views.get(slot))
            else {
                return Err(XrError::Xr {
                    call: "xrAcquireSwapchainImage (index beyond the enumerated images)",
                    result: xr::sys::Result::ERROR_VALIDATION_FAILURE,
                });
            };
            frame.views.push(EyeView {
                eye: if i == 0 { Eye::Left } else { Eye::Right },
                pose: pose_from_xr(&view.pose),
                fov: Fov {
                    angle_left_rad: view.fov.angle_left,
                    angle_right_rad: view.fov.angle_right,
                    angle_up_rad: view.fov.angle_up,
                    angle_down_rad: view.fov.angle_down,
                },
                texture: texture.clone(),
                view: tex_view.clone(),
                width_px: eye.width_px,
                height_px: eye.height_px,
                image_index: index,
            });
        }
        frame.raw_views = views.iter().map(|v| (v.pose, v.fov)).collect();
        frame.gaze = self.locate_gaze(time)?;
        Ok(Some(frame))
    }

    /// Ends a frame: puts the rendered images back in the layout the
    /// runtime expects (`COLOR_ATTACHMENT_OPTIMAL`, one small submit),
    /// releases them and calls `xrEndFrame` with one projection layer (no
    /// layers when the frame was not to be rendered). Submit the frame's
    /// rendering before calling this.
    pub fn end_frame(&mut self, frame: XrFrame) -> Result<(), XrError> {
        let Some(time) = self.open_frame else {
            return Err(XrError::CallOrder {
                call: "end_frame",
                reason: "no frame is open (it was already ended, or the session stopped)",
            });
        };
        if time.as_nanos() != frame.predicted_display_time_ns {
            return Err(XrError::CallOrder {
                call: "end_frame",
                reason: "this frame is not the one open (a later begin_frame closed it)",
            });
        }
        if frame.views.is_empty() {
            self.release_images()?;
            self.open_frame = None;
            return self
                .frame_stream
                .end(time, self.blend_mode, &[])
                .map_err(xr("xrEndFrame"));
        }
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("xr release layout"),
            });
        encoder.transition_resources(
            std::iter::empty(),
            frame.views.iter().map(|v| wgpu::TextureTransition {
                texture: &v.texture,
                selector: None,
                state: wgpu::TextureUses::COLOR_TARGET,
            }),
        );
        self.queue.submit([encoder.finish()]);
        self.release_images()?;
        self.open_frame = None;

        let projection_views: Vec<xr::CompositionLayerProjectionView<'_, xr::Vulkan>> = self
            .eyes
            .iter()
            .zip(&frame.raw_views)
            .map(|(eye, &(pose, fov))| {
                xr::CompositionLayerProjectionView::new()
                    .pose(pose)
                    .fov(fov)
                    .sub_image(
                        xr::SwapchainSubImage::new()
                            .swapchain(&eye.swapchain)
                            .image_array_index(0)
                            .image_rect(xr::Rect2Di {
                                offset: xr::Offset2Di { x: 0, y: 0 },
                                extent: xr::Extent2Di {
                                    width: eye.width_px as i32,
                                    height: eye.height_px as i32,
                                },
                            }),
                    )
            })
            .collect();
        let layer = xr::CompositionLayerProjection::new()
            .space(&self.space)
            .views(&projection_views);
        self.frame_stream
            .end(time, self.blend_mode, &[&layer])
            .map_err(xr("xrEndFrame"))
    }

    /// Releases every acquired image (waiting first where needed).
    fn release_images(&mut self) -> Result<(), XrError> {
        for eye in &mut self.eyes {
            if eye.state == ImageState::Acquired {
                eye.swapchain
                    .wait_image(xr::Duration::INFINITE)
                    .map_err(xr("xrWaitSwapchainImage"))?;
                eye.state = ImageState::Waited;
            }
            if eye.state == ImageState::Waited {
                eye.swapchain
                    .release_image()
                    .map_err(xr("xrReleaseSwapchainImage"))?;
                eye.state = ImageState::Free;
            }
        }
        Ok(())
    }

    /// Ends a frame that was begun but never handed to `end_frame`.
    fn close_open_frame(&mut self) -> Result<(), XrError> {
        if let Some(time) = self.open_frame.take() {
            self.release_images()?;
            self.frame_stream
                .end(time, self.blend_mode, &[])
                .map_err(xr("xrEndFrame (closing a dropped frame)"))?;
        }
        Ok(())
    }

    fn monotonic_secs(&self, time: xr::Time) -> Option<f64> {
        let ext = self.xr_instance.exts().khr_convert_timespec_time.as_ref()?;
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: a valid instance and an out-pointer to a timespec.
        let r = unsafe {
            (ext.convert_time_to_timespec_time)(self.xr_instance.as_raw(), time, &mut ts)
        };
        (r == xr::sys::Result::SUCCESS).then_some(ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9)
    }

    /// Syncs the gaze action and locates its space; `None` when inactive
    /// (e.g. not focused) or not located.
    fn locate_gaze(&self, time: xr::Time) -> Result<Option<Pose>, XrError> {
        let Some(gaze) = &self.gaze else {
            return Ok(None);
        };
        self.session
            .sync_actions(&[xr::ActiveActionSet::new(&gaze.set)])
            .map_err(xr("xrSyncActions"))?;
        let active = gaze
            .action
            .is_active(&self.session, xr::Path::NULL)
            .map_err(xr("xrGetActionStatePose"))?;
        if !active {
            return Ok(None);
        }
        let location = gaze
            .space
            .locate(&self.space, time)
            .map_err(xr("xrLocateSpace (eye gaze)"))?;
        let valid =
            xr::SpaceLocationFlags::ORIENTATION_VALID | xr::SpaceLocationFlags::POSITION_VALID;
        Ok(location
            .location_flags
            .contains(valid)
            .then(|| pose_from_xr(&location.pose)))
    }
}

impl Drop for XrSession {
    fn drop(&mut self) {
        // The runtime owns the images: wgpu must be done with them (and
        // drop its views) before the swapchains go.
        for eye in &self.eyes {
            for texture in &eye.textures {
                texture.destroy();
            }
        }
        if let Err(e) = self.device.poll(wgpu::PollType::wait_indefinitely()) {
            tracing::warn!(error = %e, "waiting for the GPU before destroying the OpenXR swapchains");
        }
        for eye in &mut self.eyes {
            eye.views.clear();
            eye.textures.clear();
        }
        // Fields drop next, in declaration order: swapchains, gaze, space,
        // frame objects, session, instance; then the wgpu handles.
    }
}

fn pose_from_xr(p: &xr::Posef) -> Pose {
    Pose {
        position_m: [p.position.x, p.position.y, p.position.z],
        orientation: [
            p.orientation.x,
            p.orientation.y,
            p.orientation.z,
            p.orientation.w,
        ],
    }
}

/// System name and `supportsEyeGazeInteraction` (chained only when the
/// extension is enabled).
fn system_properties(
    instance: &xr::Instance,
    system: xr::SystemId,
    eye_gaze_ext: bool,
) -> Result<(String, bool), XrError> {
    let mut gaze = xr::sys::SystemEyeGazeInteractionPropertiesEXT {
        ty: xr::sys::SystemEyeGazeInteractionPropertiesEXT::TYPE,
        next: std::ptr::null_mut(),
        supports_eye_gaze_interaction: xr::sys::FALSE,
    };
    // SAFETY: an all-zero XrSystemProperties is valid plain data; type and
    // chain are set before the call.
    let mut props: xr::sys::SystemProperties = unsafe { std::mem::zeroed() };
    props.ty = xr::sys::SystemProperties::TYPE;
    if eye_gaze_ext {
        props.next = (&mut gaze as *mut xr::sys::SystemEyeGazeInteractionPropertiesEXT).cast();
    }
    // SAFETY: valid instance and system; `props` (and `gaze` it may point
    // to) outlive the call.
    let r = unsafe { (instance.fp().get_system_properties)(instance.as_raw(), system, &mut props) };
    if r.into_raw() < 0 {
        return Err(XrError::Xr {
            call: "xrGetSystemProperties",
            result: r,
        });
    }
    let name: Vec<u8> = props
        .system_name
        .iter()
        .take_while(|&&c| c != 0)
        .map(|&c| c as u8)
        .collect();
    Ok((
        String::from_utf8_lossy(&name).into_owned(),
        eye_gaze_ext && gaze.supports_eye_gaze_interaction == xr::sys::TRUE,
    ))
}

/// The eye gaze pose action bound to the eye gaze interaction profile.
fn create_gaze_input(
    instance: &xr::Instance,
    session: &xr::Session<xr::Vulkan>,
) -> Result<GazeInput, XrError> {
    let set = instance
        .create_action_set("gazelight_gaze", "gazelight eye gaze", 0)
        .map_err(xr("xrCreateActionSet"))?;
    let action = set
        .create_action::<xr::Posef>("eye_gaze", "Eye gaze", &[])
        .map_err(xr("xrCreateAction (eye gaze pose)"))?;
    let profile = instance
        .string_to_path(EYE_GAZE_PROFILE)
        .map_err(xr("xrStringToPath (eye gaze profile)"))?;
    let pose_path = instance
        .string_to_path(EYE_GAZE_POSE)
        .map_err(xr("xrStringToPath (eye gaze pose)"))?;
    instance
        .suggest_interaction_profile_bindings(profile, &[xr::Binding::new(&action, pose_path)])
        .map_err(xr("xrSuggestInteractionProfileBindings (eye gaze)"))?;
    session
        .attach_action_sets(&[&set])
        .map_err(xr("xrAttachSessionActionSets"))?;
    let space = action
        .create_space(session, xr::Path::NULL, xr::Posef::IDENTITY)
        .map_err(xr("xrCreateActionSpace (eye gaze)"))?;
    Ok(GazeInput { space, action, set })
}

/// One eye's swapchain, its images wrapped as wgpu textures + views.
fn create_eye_swapchain(
    session: &xr::Session<xr::Vulkan>,
    device: &wgpu::Device,
    vk_format: u32,
    format: wgpu::TextureFormat,
    width_px: u32,
    height_px: u32,
    label: &'static str,
) -> Result<EyeSwapchain, XrError> {
    let swapchain = session
        .create_swapchain(&xr::SwapchainCreateInfo {
            create_flags: xr::SwapchainCreateFlags::EMPTY,
            usage_flags: xr::SwapchainUsageFlags::COLOR_ATTACHMENT
                | xr::SwapchainUsageFlags::TRANSFER_DST
                | xr::SwapchainUsageFlags::TRANSFER_SRC
                | xr::SwapchainUsageFlags::SAMPLED,
            format: vk_format,
            sample_count: 1,
            width: width_px,
            height: height_px,
            face_count: 1,
            array_size: 1,
            mip_count: 1,
        })
        .map_err(xr("xrCreateSwapchain"))?;
    let images = swapchain
        .enumerate_images()
        .map_err(xr("xrEnumerateSwapchainImages"))?;
    let size = wgpu::Extent3d {
        width: width_px,
        height: height_px,
        depth_or_array_layers: 1,
    };
    let hal_desc = hal::TextureDescriptor {
        label: Some(label),
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUses::COLOR_TARGET
            | wgpu::TextureUses::COPY_DST
            | wgpu::TextureUses::COPY_SRC
            | wgpu::TextureUses::RESOURCE,
        memory_flags: hal::MemoryFlags::empty(),
        view_formats: Vec::new(),
    };
    let desc = wgpu::TextureDescriptor {
        label: Some(label),
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT
            | wgpu::TextureUsages::COPY_DST
            | wgpu::TextureUsages::COPY_SRC
            | wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    };
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let mut textures = Vec::with_capacity(images.len());
    {
        // SAFETY: only used to wrap the images below.
        let hal_device = unsafe { device.as_hal::<VkApi>() }.ok_or_else(|| XrError::Wgpu {
            what: "the device's Vulkan hal device".into(),
            message: "not a Vulkan device".into(),
        })?;
        for &image in &images {
            // SAFETY: the runtime created the image on this device with the
            // size, format, one mip/layer/sample and a superset of the
            // usages in `hal_desc`, and keeps it until the swapchain is
            // destroyed, which `XrSession` does only after dropping these
            // textures; the no-op drop callback leaves the image to the
            // runtime, and `External` memory is not freed by wgpu.
            let hal_texture = unsafe {
                hal_device.texture_from_raw(
                    vk::Image::from_raw(image),
                    &hal_desc,
                    Some(Box::new(|| {})),
                    hal::vulkan::TextureMemory::External,
                )
            };
            // SAFETY: made on this device respecting `desc`; per
            // XR_KHR_vulkan_enable2 an image is in COLOR_ATTACHMENT_OPTIMAL
            // when xrWaitSwapchainImage returns, the state wgpu is told.
            let texture = unsafe {
                device.create_texture_from_hal::<VkApi>(
                    hal_texture,
                    &desc,
                    wgpu::TextureUses::COLOR_TARGET,
                )
            };
            textures.push(texture);
        }
    }
    let views: Vec<wgpu::TextureView> = textures
        .iter()
        .map(|t| t.create_view(&wgpu::TextureViewDescriptor::default()))
        .collect();
    if let Some(err) = pollster::block_on(scope.pop()) {
        return Err(XrError::Wgpu {
            what: format!("{label} swapchain images ({width_px}x{height_px} {format:?})"),
            message: err.to_string(),
        });
    }
    Ok(EyeSwapchain {
        textures,
        views,
        width_px,
        height_px,
        state: ImageState::Free,
        swapchain,
    })
}
