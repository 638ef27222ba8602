//! The light perception on the app's frames (issue 33, step 3).
//!
//! Served when the config says `effects = "on"` and the app enables
//! `XR_KHR_vulkan_enable2`. The layer intercepts:
//! - `xrCreateVulkanInstanceKHR` / `xrCreateVulkanDeviceKHR`: wgpu's
//!   instance and device extensions and features are added to the app's
//!   create infos ([`crate::vk`]); when they cannot be, the app's own
//!   create info goes down unchanged and that device's frames pass through;
//! - `xrCreateSession`: from `XrGraphicsBindingVulkan2KHR` (device, queue
//!   family and index) the layer opens its wgpu device on the app's device;
//! - `xrCreateSwapchain`: for a served format (`R8G8B8A8_SRGB`,
//!   `B8G8R8A8_SRGB`, `R16G16B16A16_SFLOAT`; colour attachment, one sample,
//!   face and mip level) it adds `TRANSFER_SRC` usage (the layer copies the
//!   image out before it draws the result back in);
//! - `xrEnumerateSwapchainImages`: each `VkImage` becomes a `wgpu::Texture`;
//! - `xrReleaseSwapchainImage` of a served swapchain is held back (answered
//!   with success) so the layer can still write the image in
//!   `xrEndFrame`; an `xrAcquireSwapchainImage` of that swapchain before
//!   then forwards the held release first (that image unprocessed);
//! - `xrEndFrame`: each view `i` of each `XrCompositionLayerProjection`
//!   whose image is held is processed with eye `i`'s gaze and pupil
//!   ([`crate::process::EyeProcessor`], state per eye across frames, time
//!   steps from the predicted display times), all views in one submission
//!   on the app's queue; then the held releases and the frame go down.
//!   Quad and other layers are untouched.
//!
//! Gaze: the eye's own gaze (`EyeState::eye_gaze_uv`, normalised
//! coordinates in the eye's nominal view: the runtime's `xrLocateViews` in
//! VIEW space at the display time) re-projected into the view the app
//! submitted: through the head's pose in the projection layer's space
//! (`xrLocateSpace` of a VIEW space the layer makes) and the submitted
//! view's pose and `XrFovf` ([`gaze::gaze_uv_in_submitted_view`]); where
//! a pose cannot be located, the tracker's coordinates as they are. The
//! pipeline's angles come from the submitted view's `XrFovf`. Not
//! tracked (blink, dropout, stale): the eye's last tracked gaze (the
//! centre before any). Pupil: `EyeState::eye_pupil_mm` (held, then the
//! model's, when the tracker loses it).
//!
//! A view's `imageRect` may be the whole image or any rectangle inside it
//! (both eyes side by side in one image): the view is read from and drawn
//! back into its rectangle only.
//!
//! Anything the layer cannot serve (another graphics API, a format, an
//! `imageRect` outside its image, an app feature chain it cannot merge)
//! passes through with one warning naming the reason; a GPU error or device
//! loss turns that session's frames to pass-through.
//!
//! `out = DIR`: `DIR/frames.csv`, one row per processed view (the layer
//! then waits for its GPU work each frame to read the timestamps and the
//! frame's scalars). `dump = DIR`: every `dump_every`th processed frame of
//! each eye as `DIR/eye-{left,right}-NNNNNN.png` (the displayed frame).

use std::collections::{HashMap, HashSet, VecDeque};
use std::ffi::{CStr, c_void};
use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard, PoisonError};

use ash::vk::{self as vkt, Handle as _};
use gazelight_render::rows::RowFile;
use gazelight_tracker::EyeState;
use gazelight_tracker::pupil::clock::host_now_secs;
use gazelight_vision::pipeline::{FrameInput, PipelineConfig};
use openxr_sys as xr;
use openxr_sys::Handle as _;
use openxr_sys::pfn;

use crate::config::{Effects, LayerConfig};
use crate::process::{EyeProcessor, EyeSpec, Fit, fov_tangents};
use crate::vk::{AppInstance, DevicePlan, InstancePatch, LayerGpu};
use crate::{gaze, guard, log};

/// The graphics extension the frame path serves.
pub const VULKAN2_EXT: &CStr = c"XR_KHR_vulkan_enable2";

/// Eye index in `EyeState` of view `i` of a stereo frame (OpenXR: view 0
/// is the left eye).
fn eye_of_view(i: usize) -> usize {
    if i == 0 {
        gazelight_tracker::EYE_LEFT
    } else {
        gazelight_tracker::EYE_RIGHT
    }
}

/// Whether the frame path is wanted for this instance.
///
/// # Safety
/// `info` is null or a valid `XrInstanceCreateInfo`.
pub unsafe fn wanted(info: *const xr::InstanceCreateInfo, config: &LayerConfig) -> bool {
    if config.effects != Effects::On {
        return false;
    }
    // SAFETY: `info` as this function's caller guarantees.
    if unsafe { gaze::enables(info, VULKAN2_EXT) } {
        true
    } else {
        warn_once_global(
            "the app does not enable XR_KHR_vulkan_enable2 (the only graphics path the frame effects serve); frames pass through",
        );
        false
    }
}

fn warn_once_global(reason: &str) {
    static WARNED: Mutex<Option<HashSet<String>>> = Mutex::new(None);
    let mut w = WARNED.lock().unwrap_or_else(PoisonError::into_inner);
    if w.get_or_insert_with(HashSet::new).insert(reason.to_owned()) {
        log("warn", &format!("frame effects: {reason}"));
    }
}

#[derive(Clone, Copy)]
struct Next {
    create_vulkan_instance: Option<pfn::CreateVulkanInstanceKHR>,
    create_vulkan_device: Option<pfn::CreateVulkanDeviceKHR>,
    create_session: pfn::CreateSession,
    destroy_session: pfn::DestroySession,
    create_swapchain: pfn::CreateSwapchain,
    destroy_swapchain: pfn::DestroySwapchain,
    enumerate_swapchain_images: pfn::EnumerateSwapchainImages,
    acquire: pfn::AcquireSwapchainImage,
    release: pfn::ReleaseSwapchainImage,
    end_frame: pfn::EndFrame,
    time_to_timespec: Option<pfn::ConvertTimeToTimespecTimeKHR>,
    /// The gaze re-projected into the submitted views (without them the
    /// tracker's coordinates are used as they are).
    create_reference_space: Option<pfn::CreateReferenceSpace>,
    locate_space: Option<pfn::LocateSpace>,
    locate_views: Option<pfn::LocateViews>,
}

struct FrameConfig {
    pipeline: PipelineConfig,
    white_cd_m2: f32,
    scene_scale_cd_m2: f32,
    out: Option<PathBuf>,
    dump: Option<PathBuf>,
    dump_every: u64,
}

#[derive(Default)]
struct EyeSlot {
    processor: Option<EyeProcessor>,
    last_display_ns: Option<i64>,
    gaze_uv: Option<[f32; 2]>,
    processed: u64,
}

struct SessionFrames {
    gpu: LayerGpu,
    eyes: [EyeSlot; 2],
    /// `frames.csv` (the one per-frame writer; every row written at once).
    csv: Option<RowFile>,
    /// Set after a failure: this session's frames pass through.
    off: bool,
    /// The session's VIEW space (made at its first frame; `Err` after a
    /// failed try): the head's pose and the eyes' nominal views.
    view_space: Option<Result<xr::Space, ()>>,
    /// Whether a view's gaze was re-projected yet (logged once).
    reprojected: bool,
}

struct Swapchain {
    session: u64,
    /// The served format; `None`: passes through.
    format: Option<wgpu::TextureFormat>,
    width: u32,
    height: u32,
    layers: u32,
    textures: Vec<Option<wgpu::Texture>>,
    acquired: VecDeque<u32>,
    /// The image whose release the layer holds back.
    held: Option<u32>,
}

struct Frames {
    instance: xr::Instance,
    next: Next,
    config: FrameConfig,
    vk_instances: Vec<AppInstance>,
    plans: HashMap<u64, DevicePlan>,
    sessions: HashMap<u64, SessionFrames>,
    swapchains: HashMap<u64, Swapchain>,
    warned: HashSet<String>,
}

impl Frames {
    fn warn_once(&mut self, reason: &str) {
        if self.warned.insert(reason.to_owned()) {
            log(
                "warn",
                &format!("frame effects: {reason}; those frames pass through"),
            );
        }
    }
}

static FRAMES: Mutex<Option<Frames>> = Mutex::new(None);

fn frames() -> MutexGuard<'static, Option<Frames>> {
    FRAMES.lock().unwrap_or_else(PoisonError::into_inner)
}

fn next() -> Option<Next> {
    frames().as_ref().map(|f| f.next)
}

/// Resolves the next layer's functions and starts the frame path for
/// `instance`; logs and serves nothing when a function is missing.
pub fn start(instance: xr::Instance, gipa: pfn::GetInstanceProcAddr, config: &LayerConfig) {
    let get = |name: &CStr| -> Option<pfn::VoidFunction> {
        let mut f: Option<pfn::VoidFunction> = None;
        // SAFETY: the next layer's gipa on its own instance.
        let r = unsafe { gipa(instance, name.as_ptr(), &mut f) };
        f.filter(|_| r.into_raw() >= 0)
    };
    // SAFETY: (all transmutes) the pointer the next layer returned for
    // this name has that function's signature.
    let next = unsafe {
        use std::mem::transmute as t;
        (|| {
            Some(Next {
                create_vulkan_instance: get(c"xrCreateVulkanInstanceKHR")
                    .map(|f| t::<pfn::VoidFunction, pfn::CreateVulkanInstanceKHR>(f)),
                create_vulkan_device: get(c"xrCreateVulkanDeviceKHR")
                    .map(|f| t::<pfn::VoidFunction, pfn::CreateVulkanDeviceKHR>(f)),
                create_session: t::<pfn::VoidFunction, pfn::CreateSession>(get(
                    c"xrCreateSession",
                )?),
                destroy_session: t::<pfn::VoidFunction, pfn::DestroySession>(get(
                    c"xrDestroySession",
                )?),
                create_swapchain: t::<pfn::VoidFunction, pfn::CreateSwapchain>(get(
                    c"xrCreateSwapchain",
                )?),
                destroy_swapchain: t::<pfn::VoidFunction, pfn::DestroySwapchain>(get(
                    c"xrDestroySwapchain",
                )?),
                enumerate_swapchain_images: t::<pfn::VoidFunction, pfn::EnumerateSwapchainImages>(
                    get(c"xrEnumerateSwapchainImages")?,
                ),
                acquire: t::<pfn::VoidFunction, pfn::AcquireSwapchainImage>(get(
                    c"xrAcquireSwapchainImage",
                )?),
                release: t::<pfn::VoidFunction, pfn::ReleaseSwapchainImage>(get(
                    c"xrReleaseSwapchainImage",
                )?),
                end_frame: t::<pfn::VoidFunction, pfn::EndFrame>(get(c"xrEndFrame")?),
                time_to_timespec: get(c"xrConvertTimeToTimespecTimeKHR")
                    .map(|f| t::<pfn::VoidFunction, pfn::ConvertTimeToTimespecTimeKHR>(f)),
                create_reference_space: get(c"xrCreateReferenceSpace")
                    .map(|f| t::<pfn::VoidFunction, pfn::CreateReferenceSpace>(f)),
                locate_space: get(c"xrLocateSpace")
                    .map(|f| t::<pfn::VoidFunction, pfn::LocateSpace>(f)),
                locate_views: get(c"xrLocateViews")
                    .map(|f| t::<pfn::VoidFunction, pfn::LocateViews>(f)),
            })
        })()
    };
    let Some(next) = next else {
        log(
            "error",
            "frame effects: the next layer lacks a frame function; frames pass through",
        );
        return;
    };
    if next.create_vulkan_instance.is_none() || next.create_vulkan_device.is_none() {
        log(
            "warn",
            "frame effects: the runtime has no xrCreateVulkanInstanceKHR/xrCreateVulkanDeviceKHR; frames pass through",
        );
        return;
    }
    for dir in [&config.out, &config.dump].into_iter().flatten() {
        if let Err(e) = std::fs::create_dir_all(dir) {
            log(
                "warn",
                &format!("frame effects: cannot create {}: {e}", dir.display()),
            );
        }
    }
    log(
        "info",
        "frame effects: on (Vulkan apps through XR_KHR_vulkan_enable2)",
    );
    *frames() = Some(Frames {
        instance,
        next,
        config: FrameConfig {
            pipeline: config.pipeline.clone(),
            white_cd_m2: config.white_cd_m2 as f32,
            scene_scale_cd_m2: config.scene_scale_cd_m2 as f32,
            out: config.out.clone(),
            dump: config.dump.clone(),
            dump_every: u64::from(config.dump_every.max(1)),
        },
        vk_instances: Vec::new(),
        plans: HashMap::new(),
        sessions: HashMap::new(),
        swapchains: HashMap::new(),
        warned: HashSet::new(),
    });
}

/// Stops the frame path of `instance` (its GPU objects are dropped).
pub fn stop(instance: xr::Instance) {
    let old = {
        let mut f = frames();
        if f.as_ref().is_some_and(|f| f.instance == instance) {
            f.take()
        } else {
            None
        }
    };
    if let Some(mut old) = old {
        old.swapchains.clear();
        for (_, s) in old.sessions.drain() {
            let _ = s.gpu.ctx.wait_idle();
        }
    }
}

/// The layer's own function for `name` when the frame path runs for
/// `instance`.
pub fn proc_addr(instance: xr::Instance, name: &CStr) -> Option<pfn::VoidFunction> {
    if !frames().as_ref().is_some_and(|f| f.instance == instance) {
        return None;
    }
    // SAFETY: (all transmutes) function pointers to the loader's
    // type-erased slot; the app casts them back by name.
    unsafe {
        use std::mem::transmute as t;
        Some(match name.to_bytes() {
            b"xrCreateVulkanInstanceKHR" => {
                t::<pfn::CreateVulkanInstanceKHR, pfn::VoidFunction>(create_vulkan_instance)
            }
            b"xrCreateVulkanDeviceKHR" => {
                t::<pfn::CreateVulkanDeviceKHR, pfn::VoidFunction>(create_vulkan_device)
            }
            b"xrCreateSession" => t::<pfn::CreateSession, pfn::VoidFunction>(create_session),
            b"xrDestroySession" => t::<pfn::DestroySession, pfn::VoidFunction>(destroy_session),
            b"xrCreateSwapchain" => t::<pfn::CreateSwapchain, pfn::VoidFunction>(create_swapchain),
            b"xrDestroySwapchain" => {
                t::<pfn::DestroySwapchain, pfn::VoidFunction>(destroy_swapchain)
            }
            b"xrEnumerateSwapchainImages" => {
                t::<pfn::EnumerateSwapchainImages, pfn::VoidFunction>(enumerate_swapchain_images)
            }
            b"xrAcquireSwapchainImage" => {
                t::<pfn::AcquireSwapchainImage, pfn::VoidFunction>(acquire_swapchain_image)
            }
            b"xrReleaseSwapchainImage" => {
                t::<pfn::ReleaseSwapchainImage, pfn::VoidFunction>(release_swapchain_image)
            }
            b"xrEndFrame" => t::<pfn::EndFrame, pfn::VoidFunction>(end_frame),
            _ => return None,
        })
    }
}

const NO_NEXT: xr::Result = xr::Result::ERROR_HANDLE_INVALID;

/// `xrCreateVulkanInstanceKHR`: the app's Vulkan instance with the
/// extensions wgpu needs added.
///
/// # Safety
/// Called as `xrCreateVulkanInstanceKHR`: `info` null or valid (its
/// `vulkan_create_info` a valid `VkInstanceCreateInfo`), `vk_instance` and
/// `vk_result` null or writable.
unsafe extern "system" fn create_vulkan_instance(
    instance: xr::Instance,
    info: *const xr::VulkanInstanceCreateInfoKHR,
    vk_instance: *mut xr::platform::VkInstance,
    vk_result: *mut xr::platform::VkResult,
) -> xr::Result {
    let Some(n) = next() else { return NO_NEXT };
    let Some(down) = n.create_vulkan_instance else {
        return NO_NEXT;
    };
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = || unsafe { down(instance, info, vk_instance, vk_result) };
    guard::guarded("xrCreateVulkanInstanceKHR", forward, || {
        #[cfg(feature = "test-hooks")]
        guard::test_hook("xrCreateVulkanInstanceKHR");
        if guard::pass_through() || info.is_null() || vk_instance.is_null() {
            return forward();
        }
        // SAFETY: non-null; the app's structure for this call.
        let app = unsafe { *info };
        let Some(gipa) = app.pfn_get_instance_proc_addr else {
            return forward();
        };
        if app.vulkan_create_info.is_null() {
            return forward();
        }
        // SAFETY: identical C signatures (see gazelight-xr's vulkan module).
        let gipa = unsafe {
            std::mem::transmute::<xr::platform::VkGetInstanceProcAddr, vkt::PFN_vkGetInstanceProcAddr>(
                gipa,
            )
        };
        // SAFETY: the app's loader entry.
        let entry = unsafe {
            ash::Entry::from_static_fn(ash::StaticFn {
                get_instance_proc_addr: gipa,
            })
        };
        // SAFETY: the app's VkInstanceCreateInfo for this call.
        let vk_info = unsafe { &*(app.vulkan_create_info as *const vkt::InstanceCreateInfo) };
        // SAFETY: the app's loader entry and create info (its chain valid
        // for this call).
        let patch = match unsafe { InstancePatch::new(&entry, vk_info) } {
            Ok(p) => p,
            Err(e) => {
                warn_once_global(&format!("the Vulkan instance: {e}"));
                return forward();
            }
        };
        let changed = xr::VulkanInstanceCreateInfoKHR {
            vulkan_create_info: patch.info() as *const vkt::InstanceCreateInfo as *const c_void,
            ..app
        };
        // SAFETY: the app's create info with the patched Vulkan info, which
        // `patch` keeps alive over the call; the app's out-pointers.
        let r = unsafe { down(instance, &changed, vk_instance, vk_result) };
        // SAFETY: non-null, written by the runtime on this call.
        let vk_ok = vk_result.is_null() || unsafe { *vk_result } == 0;
        if r.into_raw() < 0 || !vk_ok {
            warn_once_global(&format!(
                "the Vulkan instance with wgpu's extensions failed ({r:?}); created as the app asked"
            ));
            return forward();
        }
        // SAFETY: written on success.
        let raw = crate::vk::instance_from_xr(unsafe { *vk_instance });
        if let Some(f) = frames().as_mut() {
            f.vk_instances.push(AppInstance {
                entry,
                raw,
                api_version: patch.api_version,
                extensions: patch.extensions.clone(),
            });
        }
        r
    })
}

/// `xrCreateVulkanDeviceKHR`: the app's Vulkan device with the extensions
/// and features wgpu needs added.
///
/// # Safety
/// Called as `xrCreateVulkanDeviceKHR`: `info` null or valid (its
/// `vulkan_create_info` a valid `VkDeviceCreateInfo`), `vk_device` and
/// `vk_result` null or writable.
unsafe extern "system" fn create_vulkan_device(
    instance: xr::Instance,
    info: *const xr::VulkanDeviceCreateInfoKHR,
    vk_device: *mut xr::platform::VkDevice,
    vk_result: *mut xr::platform::VkResult,
) -> xr::Result {
    let Some(n) = next() else { return NO_NEXT };
    let Some(down) = n.create_vulkan_device else {
        return NO_NEXT;
    };
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = || unsafe { down(instance, info, vk_device, vk_result) };
    guard::guarded("xrCreateVulkanDeviceKHR", forward, || {
        #[cfg(feature = "test-hooks")]
        guard::test_hook("xrCreateVulkanDeviceKHR");
        if guard::pass_through() || info.is_null() || vk_device.is_null() {
            return forward();
        }
        // SAFETY: non-null; the app's structure.
        let app = unsafe { *info };
        if app.vulkan_create_info.is_null() {
            return forward();
        }
        let phd = crate::vk::physical_device_from_xr(app.vulkan_physical_device);
        // The instance the physical device belongs to: the newest recorded
        // one that lists it.
        let owner = frames().as_ref().and_then(|f| {
            f.vk_instances
                .iter()
                .rev()
                .find(|i| {
                    // SAFETY: a live instance the app created through the layer.
                    let ash_i = unsafe { ash::Instance::load(i.entry.static_fn(), i.raw) };
                    // SAFETY: as above, a live instance.
                    unsafe { ash_i.enumerate_physical_devices() }.is_ok_and(|p| p.contains(&phd))
                })
                .cloned()
        });
        let Some(owner) = owner else {
            warn_once_global(
                "the app's Vulkan instance was not created through xrCreateVulkanInstanceKHR",
            );
            return forward();
        };
        let plan = match DevicePlan::new(&owner, phd) {
            Ok(p) => p,
            Err(e) => {
                warn_once_global(&format!("the Vulkan device: {e}"));
                return forward();
            }
        };
        // SAFETY: the app's VkDeviceCreateInfo for this call.
        let vk_info = unsafe { &*(app.vulkan_create_info as *const vkt::DeviceCreateInfo) };
        // SAFETY: the app's VkDeviceCreateInfo, its chain valid for this call.
        let patch = match unsafe { plan.patch(vk_info) } {
            Ok(p) => p,
            Err(e) => {
                warn_once_global(&format!("the Vulkan device: {e}"));
                return forward();
            }
        };
        let changed = xr::VulkanDeviceCreateInfoKHR {
            vulkan_create_info: patch.info() as *const vkt::DeviceCreateInfo as *const c_void,
            ..app
        };
        // SAFETY: the app's create info with the patched Vulkan info, which
        // `patch` keeps alive over the call; the app's out-pointers.
        let r = unsafe { down(instance, &changed, vk_device, vk_result) };
        // SAFETY: non-null, written by the runtime on this call.
        let vk_ok = vk_result.is_null() || unsafe { *vk_result } == 0;
        if r.into_raw() < 0 || !vk_ok {
            warn_once_global(&format!(
                "the Vulkan device with wgpu's extensions and features failed ({r:?}); created as the app asked"
            ));
            return forward();
        }
        // SAFETY: written on success.
        let raw = crate::vk::device_from_xr(unsafe { *vk_device });
        if let Some(f) = frames().as_mut() {
            f.plans.insert(raw.as_raw(), plan);
        }
        r
    })
}

/// The Vulkan binding in a session create info's chain.
///
/// # Safety
/// `info` is a valid `XrSessionCreateInfo`.
unsafe fn vulkan_binding(info: &xr::SessionCreateInfo) -> Option<xr::GraphicsBindingVulkanKHR> {
    let mut p = info.next as *const xr::BaseInStructure;
    let mut n = 0;
    while !p.is_null() && n < 64 {
        // SAFETY: the app's chain of (type, next) structures.
        let base = unsafe { &*p };
        if base.ty == xr::GraphicsBindingVulkanKHR::TYPE {
            // SAFETY: its type says it is this structure.
            return Some(unsafe { *(p as *const xr::GraphicsBindingVulkanKHR) });
        }
        p = base.next;
        n += 1;
    }
    None
}

/// `xrCreateSession`: a Vulkan session on a device the layer planned gets
/// the layer's wgpu device on it.
///
/// # Safety
/// Called as `xrCreateSession`: `info` null or valid, `session` null or
/// writable.
unsafe extern "system" fn create_session(
    instance: xr::Instance,
    info: *const xr::SessionCreateInfo,
    session: *mut xr::Session,
) -> xr::Result {
    let Some(n) = next() else { return NO_NEXT };
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = || unsafe { (n.create_session)(instance, info, session) };
    guard::guarded("xrCreateSession", forward, || {
        let r = forward();
        if r.into_raw() < 0 || info.is_null() || session.is_null() || guard::pass_through() {
            return r;
        }
        // SAFETY: non-null; the app's info.
        let Some(binding) = (unsafe { vulkan_binding(&*info) }) else {
            if let Some(f) = frames().as_mut() {
                f.warn_once("the session has no Vulkan graphics binding (another graphics API)");
            }
            return r;
        };
        // SAFETY: written on success.
        let created = unsafe { *session };
        let device = crate::vk::device_from_xr(binding.device);
        let mut guard_f = frames();
        let Some(f) = guard_f.as_mut() else { return r };
        let Some(plan) = f.plans.get(&device.as_raw()) else {
            f.warn_once("the session's VkDevice was not created through xrCreateVulkanDeviceKHR with wgpu's needs");
            return r;
        };
        match plan.open(device, binding.queue_family_index, binding.queue_index) {
            Ok(gpu) => {
                log(
                    "info",
                    &format!(
                        "frame effects: the layer's passes run on the app's device ({}, queue family {} index {})",
                        plan.adapter_name, binding.queue_family_index, binding.queue_index
                    ),
                );
                let csv = f.config.out.as_ref().and_then(|dir| open_csv(dir));
                f.sessions.insert(
                    created.into_raw(),
                    SessionFrames {
                        gpu,
                        eyes: Default::default(),
                        csv,
                        off: false,
                        view_space: None,
                        reprojected: false,
                    },
                );
            }
            Err(e) => f.warn_once(&format!("the layer's wgpu device: {e}")),
        }
        r
    })
}

/// `frames.csv`'s columns.
const FRAMES_HEADER: &str = "display_time_ns,view,eye,gaze_u,gaze_v,gaze_tracked,pupil_mm,target_cd_m2,adaptation_cd_m2,kernel_pupil_mm,kernel_rebuilt,layer_gpu_ms,eye_state_age_ms";

/// A write error of `frames.csv`, in the layer's log (the app goes on).
fn warn_csv(msg: &str) {
    log("warn", &format!("frame effects: {msg}"));
}

/// `DIR/frames.csv`, its header written; `None` (logged) when it cannot be
/// created.
fn open_csv(dir: &std::path::Path) -> Option<RowFile> {
    let mut file = RowFile::create(&dir.join("frames.csv"), FRAMES_HEADER, warn_csv);
    file.flush();
    file.failure().is_none().then_some(file)
}

/// Forwards every held release of `session` (or of all sessions for
/// `None`). No panicking code: it is also the fallback after a panic.
fn release_held(session: Option<u64>) {
    let (release, held): (Option<pfn::ReleaseSwapchainImage>, Vec<u64>) = {
        let mut f = frames();
        match f.as_mut() {
            None => (None, Vec::new()),
            Some(f) => {
                let held = f
                    .swapchains
                    .iter_mut()
                    .filter(|(_, s)| session.is_none_or(|x| s.session == x))
                    .filter_map(|(k, s)| s.held.take().map(|_| *k))
                    .collect();
                (Some(f.next.release), held)
            }
        }
    };
    if let Some(release) = release {
        for sc in held {
            forward_release(release, xr::Swapchain::from_raw(sc));
        }
    }
}

fn forward_release(release: pfn::ReleaseSwapchainImage, sc: xr::Swapchain) {
    let info = xr::SwapchainImageReleaseInfo {
        ty: xr::SwapchainImageReleaseInfo::TYPE,
        next: std::ptr::null(),
    };
    // SAFETY: a swapchain of the app with an acquired image.
    let r = unsafe { release(sc, &info) };
    if r.into_raw() < 0 {
        log(
            "warn",
            &format!("frame effects: a held xrReleaseSwapchainImage failed: {r:?}"),
        );
    }
}

/// `xrDestroySession`: held releases go first; the session's GPU work
/// ends before the runtime destroys it.
///
/// # Safety
/// Called as `xrDestroySession` (a handle only, no pointers).
unsafe extern "system" fn destroy_session(session: xr::Session) -> xr::Result {
    let Some(n) = next() else { return NO_NEXT };
    let forward = || {
        release_held(Some(session.into_raw()));
        // SAFETY: the app's handle, handed to the next layer unchanged.
        unsafe { (n.destroy_session)(session) }
    };
    guard::guarded("xrDestroySession", forward, || {
        gaze::forget_session(session);
        release_held(Some(session.into_raw()));
        let old = {
            let mut f = frames();
            f.as_mut().map(|f| {
                f.swapchains.retain(|_, s| s.session != session.into_raw());
                f.sessions.remove(&session.into_raw())
            })
        };
        if let Some(Some(s)) = old {
            let _ = s.gpu.ctx.wait_idle();
            for (view, slot) in s.eyes.iter().enumerate() {
                if slot.processed > 0 {
                    let psf = match &slot.processor {
                        Some(p) if p.psf_off_thread() => {
                            format!("{} kernels built off the app's thread", p.psf_builds())
                        }
                        _ => "kernels rebuilt inside the frames".into(),
                    };
                    log(
                        "info",
                        &format!(
                            "frame effects: view {view}: {} frames processed, {psf}",
                            slot.processed
                        ),
                    );
                }
            }
            drop(s);
        }
        // SAFETY: the app's handle; the layer's work on it has ended.
        unsafe { (n.destroy_session)(session) }
    })
}

/// Test hook (`test-hooks` builds only, see [`guard`]): a `VkFormat` code
/// the layer treats as not served (CI checks the fail-open path with the
/// format hello_xr picks).
#[cfg(feature = "test-hooks")]
pub const TEST_REFUSE_FORMAT_ENV: &str = "GAZELIGHT_LAYER_TEST_REFUSE_FORMAT";

/// `XR_SWAPCHAIN_USAGE_TRANSFER_SRC_BIT`, added to served swapchains.
const TRANSFER_SRC: xr::SwapchainUsageFlags = xr::SwapchainUsageFlags::TRANSFER_SRC;

/// `xrCreateSwapchain`: a served swapchain gets TRANSFER_SRC usage.
///
/// # Safety
/// Called as `xrCreateSwapchain`: `info` null or valid, `swapchain` null or
/// writable.
unsafe extern "system" fn create_swapchain(
    session: xr::Session,
    info: *const xr::SwapchainCreateInfo,
    swapchain: *mut xr::Swapchain,
) -> xr::Result {
    let Some(n) = next() else { return NO_NEXT };
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = || unsafe { (n.create_swapchain)(session, info, swapchain) };
    guard::guarded("xrCreateSwapchain", forward, || {
        if guard::pass_through() || info.is_null() || swapchain.is_null() {
            return forward();
        }
        // SAFETY: non-null; the app's info.
        let app = unsafe { *info };
        let served_session = frames()
            .as_ref()
            .is_some_and(|f| f.sessions.contains_key(&session.into_raw()));
        if !served_session {
            return forward();
        }
        #[cfg(feature = "test-hooks")]
        let refused = std::env::var(TEST_REFUSE_FORMAT_ENV)
            .ok()
            .and_then(|v| v.trim().parse::<i64>().ok())
            == Some(app.format);
        #[cfg(not(feature = "test-hooks"))]
        let refused = false;
        let format = crate::vk::served_format(app.format).filter(|_| !refused);
        let reason = if format.is_none() {
            Some(format!(
                "swapchain format {} is not served (R8G8B8A8_SRGB, B8G8R8A8_SRGB, R16G16B16A16_SFLOAT are)",
                crate::vk::format_name(app.format)
            ))
        } else if !app
            .usage_flags
            .contains(xr::SwapchainUsageFlags::COLOR_ATTACHMENT)
        {
            Some("a swapchain without colour attachment usage (depth, or sampled only) is not processed".into())
        } else if app.sample_count != 1 || app.face_count != 1 || app.mip_count != 1 {
            Some(format!(
                "swapchains with {} samples, {} faces, {} mip levels are not served (1 each)",
                app.sample_count, app.face_count, app.mip_count
            ))
        } else {
            None
        };
        let (r, format) = match reason {
            Some(reason) => {
                if let Some(f) = frames().as_mut() {
                    f.warn_once(&reason);
                }
                (forward(), None)
            }
            None => {
                let changed = xr::SwapchainCreateInfo {
                    usage_flags: app.usage_flags | TRANSFER_SRC,
                    ..app
                };
                // SAFETY: the app's info with one more usage flag; the
                // app's out-pointer (checked non-null).
                let r = unsafe { (n.create_swapchain)(session, &changed, swapchain) };
                if r.into_raw() < 0 {
                    if let Some(f) = frames().as_mut() {
                        f.warn_once(&format!(
                            "the runtime refused TRANSFER_SRC usage on a swapchain ({r:?})"
                        ));
                    }
                    (forward(), None)
                } else {
                    (r, format)
                }
            }
        };
        if r.into_raw() >= 0
            && let Some(f) = frames().as_mut()
        {
            // SAFETY: written on success.
            let created = unsafe { *swapchain };
            f.swapchains.insert(
                created.into_raw(),
                Swapchain {
                    session: session.into_raw(),
                    format,
                    width: app.width,
                    height: app.height,
                    layers: app.array_size.max(1),
                    textures: Vec::new(),
                    acquired: VecDeque::new(),
                    held: None,
                },
            );
        }
        r
    })
}

/// `xrDestroySwapchain`: a held release goes first; the layer's GPU work
/// on its images ends before the runtime frees them.
///
/// # Safety
/// Called as `xrDestroySwapchain` (a handle only, no pointers).
unsafe extern "system" fn destroy_swapchain(swapchain: xr::Swapchain) -> xr::Result {
    let Some(n) = next() else { return NO_NEXT };
    // SAFETY: the app's handle, handed to the next layer unchanged.
    let forward = || unsafe { (n.destroy_swapchain)(swapchain) };
    guard::guarded("xrDestroySwapchain", forward, || {
        let (held, old, gpu_ctx) = {
            let mut f = frames();
            match f.as_mut() {
                None => (false, None, None),
                Some(f) => {
                    let old = f.swapchains.remove(&swapchain.into_raw());
                    let ctx = old
                        .as_ref()
                        .and_then(|s| f.sessions.get(&s.session))
                        .map(|s| s.gpu.ctx.clone());
                    (old.as_ref().is_some_and(|s| s.held.is_some()), old, ctx)
                }
            }
        };
        if held {
            forward_release(n.release, swapchain);
        }
        // The layer's work on its images ends before the runtime frees them.
        if let Some(ctx) = gpu_ctx {
            let _ = ctx.wait_idle();
        }
        drop(old);
        forward()
    })
}

/// `xrEnumerateSwapchainImages`: a served swapchain's Vulkan images are
/// wrapped as wgpu textures.
///
/// # Safety
/// Called as `xrEnumerateSwapchainImages`: `count` null or writable,
/// `images` null or an array of `capacity` structures of one type.
unsafe extern "system" fn enumerate_swapchain_images(
    swapchain: xr::Swapchain,
    capacity: u32,
    count: *mut u32,
    images: *mut xr::SwapchainImageBaseHeader,
) -> xr::Result {
    let Some(n) = next() else { return NO_NEXT };
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = || unsafe { (n.enumerate_swapchain_images)(swapchain, capacity, count, images) };
    guard::guarded("xrEnumerateSwapchainImages", forward, || {
        let r = forward();
        if r.into_raw() < 0
            || capacity == 0
            || images.is_null()
            || count.is_null()
            || guard::pass_through()
        {
            return r;
        }
        // SAFETY: the runtime wrote `*count` structures.
        let written = unsafe { *count }.min(capacity) as usize;
        // SAFETY: `images` non-null with `capacity` > 0 structures.
        if unsafe { (*images).ty } != xr::SwapchainImageVulkanKHR::TYPE {
            return r;
        }
        let vk_images: Vec<vkt::Image> = (0..written)
            .map(|i| {
                // SAFETY: an array of XrSwapchainImageVulkanKHR (checked type).
                let img = unsafe { *(images as *const xr::SwapchainImageVulkanKHR).add(i) };
                vkt::Image::from_raw(img.image)
            })
            .collect();
        let mut guard_f = frames();
        let Some(f) = guard_f.as_mut() else { return r };
        let Some(sc) = f.swapchains.get_mut(&swapchain.into_raw()) else {
            return r;
        };
        let Some(format) = sc.format else { return r };
        let Some(session) = f.sessions.get(&sc.session) else {
            return r;
        };
        let mut textures = Vec::with_capacity(vk_images.len());
        for image in vk_images {
            // SAFETY: the runtime's image of this swapchain, on the session's
            // device, created with the swapchain's size, format and layers
            // and (the layer added it) TRANSFER_SRC and COLOR_ATTACHMENT
            // usage; it lives until xrDestroySwapchain, which drops the
            // texture first.
            match unsafe {
                session
                    .gpu
                    .wrap_image(image, format, sc.width, sc.height, sc.layers)
            } {
                Ok(t) => textures.push(Some(t)),
                Err(e) => {
                    log("warn", &format!("frame effects: a swapchain image: {e}"));
                    textures.push(None);
                }
            }
        }
        sc.textures = textures;
        r
    })
}

/// `xrAcquireSwapchainImage`: a held release goes first; the acquired
/// index is noted.
///
/// # Safety
/// Called as `xrAcquireSwapchainImage`: `info` null or valid, `index` null
/// or writable.
unsafe extern "system" fn acquire_swapchain_image(
    swapchain: xr::Swapchain,
    info: *const xr::SwapchainImageAcquireInfo,
    index: *mut u32,
) -> xr::Result {
    let Some(n) = next() else { return NO_NEXT };
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = || unsafe { (n.acquire)(swapchain, info, index) };
    guard::guarded("xrAcquireSwapchainImage", forward, || {
        // A held release goes first, that image unprocessed.
        let held = frames()
            .as_mut()
            .and_then(|f| f.swapchains.get_mut(&swapchain.into_raw()))
            .and_then(|s| s.held.take());
        if held.is_some() {
            forward_release(n.release, swapchain);
        }
        let r = forward();
        if r.into_raw() >= 0
            && !index.is_null()
            && let Some(s) = frames()
                .as_mut()
                .and_then(|f| f.swapchains.get_mut(&swapchain.into_raw()))
        {
            // SAFETY: written on success.
            s.acquired.push_back(unsafe { *index });
        }
        r
    })
}

/// `xrReleaseSwapchainImage`: a served image's release is held until the
/// layer has processed it in `xrEndFrame`.
///
/// # Safety
/// Called as `xrReleaseSwapchainImage`: `info` null or valid.
unsafe extern "system" fn release_swapchain_image(
    swapchain: xr::Swapchain,
    info: *const xr::SwapchainImageReleaseInfo,
) -> xr::Result {
    let Some(n) = next() else { return NO_NEXT };
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = || unsafe { (n.release)(swapchain, info) };
    guard::guarded("xrReleaseSwapchainImage", forward, || {
        let hold = {
            let mut f = frames();
            let Some(f) = f.as_mut() else {
                return forward();
            };
            let session_on = |s: u64| {
                f.sessions
                    .get(&s)
                    .is_some_and(|s| !s.off && !s.gpu.has_failed())
            };
            let Some(sc) = f.swapchains.get(&swapchain.into_raw()) else {
                return forward();
            };
            let served = !guard::pass_through()
                && sc.format.is_some()
                && sc.held.is_none()
                && !sc.textures.is_empty()
                && session_on(sc.session);
            let sc = f.swapchains.get_mut(&swapchain.into_raw());
            match sc {
                Some(sc) => {
                    let image = sc.acquired.pop_front();
                    match image {
                        Some(i) if served => {
                            sc.held = Some(i);
                            true
                        }
                        _ => false,
                    }
                }
                None => false,
            }
        };
        if hold { xr::Result::SUCCESS } else { forward() }
    })
}

/// One view to process, copied out of the app's frame.
struct ViewJob {
    view: usize,
    swapchain: u64,
    layer: u32,
    rect: xr::Rect2Di,
    tan_lrud: [f64; 4],
    /// The projection layer's space, and the pose and field of view the
    /// app submitted for this view in it.
    space: xr::Space,
    pose: xr::Posef,
    fov: xr::Fovf,
}

/// `xrEndFrame`: each projection view is processed, then the held
/// releases and the frame go down.
///
/// # Safety
/// Called as `xrEndFrame`: `info` null or a valid `XrFrameEndInfo` (its
/// layers and views arrays valid for this call).
unsafe extern "system" fn end_frame(
    session: xr::Session,
    info: *const xr::FrameEndInfo,
) -> xr::Result {
    let Some(n) = next() else { return NO_NEXT };
    let forward = || {
        release_held(Some(session.into_raw()));
        // SAFETY: the app's arguments, handed to the next layer unchanged.
        unsafe { (n.end_frame)(session, info) }
    };
    guard::guarded("xrEndFrame", forward, || {
        if !guard::pass_through() && !info.is_null() {
            // The test hook panics with the frame's releases still held.
            #[cfg(feature = "test-hooks")]
            guard::test_hook("xrEndFrame");
            // SAFETY: non-null; the app's frame for this call.
            let jobs = unsafe { view_jobs(&*info) };
            // SAFETY: as above.
            let display_ns = unsafe { (*info).display_time.as_nanos() };
            if !jobs.is_empty() {
                process_views(session, display_ns, &jobs);
            }
        }
        forward()
    })
}

/// The projection views of a frame (at most two: a stereo frame's eyes).
///
/// # Safety
/// `info` is a valid `XrFrameEndInfo`.
unsafe fn view_jobs(info: &xr::FrameEndInfo) -> Vec<ViewJob> {
    let mut jobs = Vec::new();
    if info.layers.is_null() {
        return jobs;
    }
    for l in 0..info.layer_count as usize {
        // SAFETY: an array of `layer_count` layer pointers.
        let p = unsafe { *info.layers.add(l) };
        // SAFETY: non-null entries are the app's composition layers, each
        // starting with its type.
        if p.is_null() || unsafe { (*p).ty } != xr::CompositionLayerProjection::TYPE {
            continue;
        }
        // SAFETY: a projection layer (checked type).
        let proj = unsafe { &*(p as *const xr::CompositionLayerProjection) };
        if proj.views.is_null() {
            continue;
        }
        for v in 0..(proj.view_count as usize).min(2) {
            // SAFETY: an array of `view_count` views.
            let view = unsafe { &*proj.views.add(v) };
            let fov = view.fov;
            jobs.push(ViewJob {
                view: v,
                swapchain: view.sub_image.swapchain.into_raw(),
                layer: view.sub_image.image_array_index,
                rect: view.sub_image.image_rect,
                tan_lrud: fov_tangents(
                    fov.angle_left,
                    fov.angle_right,
                    fov.angle_up,
                    fov.angle_down,
                ),
                space: proj.space,
                pose: view.pose,
                fov,
            });
        }
    }
    jobs
}

/// What the CSV and dumps need of one processed view.
struct Done {
    view: usize,
    eye: usize,
    input: FrameInput,
    tracked: bool,
    encoded: gazelight_gpu::EncodedFrame,
}

/// A view's `imageRect` as (origin, size) in pixels when it is a
/// non-empty rectangle inside an image of `image` = `[width, height]`.
pub fn rect_in_image(rect: xr::Rect2Di, image: [u32; 2]) -> Option<([u32; 2], [u32; 2])> {
    let origin = [
        u32::try_from(rect.offset.x).ok()?,
        u32::try_from(rect.offset.y).ok()?,
    ];
    let size = [
        u32::try_from(rect.extent.width).ok().filter(|&w| w > 0)?,
        u32::try_from(rect.extent.height).ok().filter(|&h| h > 0)?,
    ];
    let fits = |k: usize| {
        origin[k]
            .checked_add(size[k])
            .is_some_and(|end| end <= image[k])
    };
    (fits(0) && fits(1)).then_some((origin, size))
}

/// The poses one frame's gaze re-projection needs (see
/// [`gaze::gaze_uv_in_submitted_view`]).
struct FramePoses {
    /// The eyes' nominal views in VIEW space at the display time.
    nominal: Option<[xr::View; 2]>,
    /// VIEW's pose in each projection layer space of the frame.
    head: Vec<(u64, xr::Posef)>,
}

impl FramePoses {
    /// Locates them through the next layer; what cannot be located is
    /// left out (the views then take the tracker's coordinates as they
    /// are).
    ///
    /// # Safety
    /// `next` holds the next layer's functions for the session's instance;
    /// `session` and the jobs' spaces are the app's live handles.
    unsafe fn locate(
        next: &Next,
        session: xr::Session,
        s: &mut SessionFrames,
        display_ns: i64,
        jobs: &[ViewJob],
    ) -> Self {
        let mut out = Self {
            nominal: None,
            head: Vec::new(),
        };
        let (Some(create), Some(locate_space), Some(locate_views)) = (
            next.create_reference_space,
            next.locate_space,
            next.locate_views,
        ) else {
            return out;
        };
        let view_space = *s.view_space.get_or_insert_with(|| {
            let info = xr::ReferenceSpaceCreateInfo {
                ty: xr::ReferenceSpaceCreateInfo::TYPE,
                next: std::ptr::null(),
                reference_space_type: xr::ReferenceSpaceType::VIEW,
                pose_in_reference_space: gaze::IDENTITY,
            };
            let mut space = xr::Space::NULL;
            // SAFETY: a valid info and out-pointer on the app's session.
            let r = unsafe { create(session, &info, &mut space) };
            if r.into_raw() < 0 {
                log(
                    "warn",
                    &format!("frame effects: no VIEW space ({r:?}); the gaze is not re-projected into the submitted views"),
                );
                return Err(());
            }
            Ok(space)
        });
        let Ok(view_space) = view_space else {
            return out;
        };
        let time = xr::Time::from_nanos(display_ns);
        // SAFETY: the next layer's xrLocateViews on the app's session.
        let located = unsafe { gaze::locate_stereo_views(locate_views, session, view_space, time) };
        if let Some((views, 2, flags)) = located
            && flags.contains(xr::ViewStateFlags::ORIENTATION_VALID)
        {
            out.nominal = Some(views);
        }
        for job in jobs {
            let raw = job.space.into_raw();
            if out.head.iter().any(|(s, _)| *s == raw) {
                continue;
            }
            let mut location = xr::SpaceLocation {
                ty: xr::SpaceLocation::TYPE,
                next: std::ptr::null_mut(),
                location_flags: xr::SpaceLocationFlags::EMPTY,
                pose: gaze::IDENTITY,
            };
            // SAFETY: the app's spaces of this session and an out-pointer.
            let r = unsafe { locate_space(view_space, job.space, time, &mut location) };
            if r.into_raw() >= 0
                && location
                    .location_flags
                    .contains(xr::SpaceLocationFlags::ORIENTATION_VALID)
            {
                out.head.push((raw, location.pose));
            }
        }
        out
    }

    /// The tracker's `gaze_uv` (in the eye's nominal view) in the view the
    /// app submitted for `job`.
    fn gaze_uv(&self, job: &ViewJob, gaze_uv: [f32; 2]) -> Option<[f32; 2]> {
        let nominal = self.nominal.as_ref()?.get(job.view)?;
        let raw = job.space.into_raw();
        let head = self.head.iter().find(|(s, _)| *s == raw).map(|(_, p)| p)?;
        gaze::gaze_uv_in_submitted_view(gaze_uv, nominal, head, &job.pose, &job.fov)
    }
}

fn process_views(session: xr::Session, display_ns: i64, jobs: &[ViewJob]) {
    let mut guard_f = frames();
    let Some(f) = guard_f.as_mut() else { return };
    let instance = f.instance;
    let (state, mono_minus_host) = match gaze::eye_snapshot(instance) {
        Some((live, off)) => (Some(live.state), off),
        None => (None, 0.0),
    };
    let now_host = host_now_secs();
    let Frames {
        sessions,
        swapchains,
        config,
        warned,
        next,
        ..
    } = f;
    let Some(s) = sessions.get_mut(&session.into_raw()) else {
        return;
    };
    if s.off || s.gpu.has_failed() {
        return;
    }
    let mut warn = |reason: String| {
        if warned.insert(reason.clone()) {
            log(
                "warn",
                &format!("frame effects: {reason}; those frames pass through"),
            );
        }
    };
    // The eyes' nominal views and the head's pose in each projection
    // layer's space at the display time: the gaze re-projected into the
    // views the app submitted.
    // SAFETY: the next layer's table; the app's session and the spaces of
    // the frame it is ending.
    let poses = unsafe { FramePoses::locate(next, session, s, display_ns, jobs) };
    let ctx = s.gpu.ctx.clone();
    let mut encoder = ctx
        .device()
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("gazelight-layer frame"),
        });
    let timed = config.out.is_some();
    let mut done = Vec::new();
    for job in jobs {
        let Some(sc) = swapchains.get(&job.swapchain) else {
            continue;
        };
        let (Some(format), Some(image)) = (sc.format, sc.held) else {
            continue;
        };
        let Some(Some(texture)) = sc.textures.get(image as usize) else {
            continue;
        };
        // The view's rectangle of the image: the whole image, or one
        // eye's half of an image holding both side by side.
        let Some((origin, [width, height])) = rect_in_image(job.rect, [sc.width, sc.height]) else {
            warn("a projection view's imageRect outside its image (or empty) is not served".into());
            continue;
        };
        if job.layer >= sc.layers {
            continue;
        }
        let eye = eye_of_view(job.view);
        let slot = &mut s.eyes[job.view];
        let scale = if format == wgpu::TextureFormat::Rgba16Float {
            config.scene_scale_cd_m2
        } else {
            config.white_cd_m2
        };
        let fit = slot
            .processor
            .as_ref()
            .map_or(Fit::Rebuild, |p| p.fit(format, width, height, job.tan_lrud));
        if fit == Fit::Frustum
            && let Some(p) = slot.processor.as_mut()
            && let Err(e) = p.set_view(job.tan_lrud)
        {
            warn(format!("a projection view's field of view: {e}"));
            continue;
        }
        if fit == Fit::Rebuild {
            slot.processor = None;
            match EyeProcessor::new(
                &ctx,
                &config.pipeline,
                EyeSpec {
                    format,
                    width,
                    height,
                    tan_lrud: job.tan_lrud,
                    scale,
                    timed,
                },
            ) {
                Ok(p) => slot.processor = Some(p),
                Err(e) => {
                    log(
                        "error",
                        &format!(
                            "frame effects: the eye's pipeline: {e}; this session's frames pass through"
                        ),
                    );
                    s.off = true;
                    return;
                }
            }
        }
        let tracked = state.is_some_and(|st| gaze::tracked(&st, now_host));
        if tracked && let Some(st) = &state {
            slot.gaze_uv = Some(st.eye_gaze_uv(eye));
        }
        let pupil_mm = state.map_or(
            gazelight_vision::kernel_policy::INITIAL_PUPIL_MM as f32,
            |st| st.eye_pupil_mm(eye),
        );
        let dt_secs = slot
            .last_display_ns
            .map_or(0.0, |t| ((display_ns - t) as f64 * 1e-9).max(0.0) as f32);
        slot.last_display_ns = Some(display_ns);
        let tracker_uv = slot.gaze_uv.unwrap_or([0.5, 0.5]);
        let reprojected = poses.gaze_uv(job, tracker_uv);
        if reprojected.is_some() && !s.reprojected {
            s.reprojected = true;
            log(
                "info",
                "frame effects: each eye's gaze re-projected from its nominal view into the view the app submitted",
            );
        }
        let slot = &mut s.eyes[job.view];
        let input = FrameInput {
            gaze_uv: reprojected.unwrap_or(tracker_uv),
            pupil_mm,
            dt_secs,
        };
        let Some(p) = slot.processor.as_mut() else {
            continue;
        };
        let encoded = match p.encode(&mut encoder, texture, job.layer, origin, &input) {
            Ok(e) => e,
            Err(e) => {
                log(
                    "error",
                    &format!(
                        "frame effects: installing the eye's PSF: {e}; this session's frames pass through"
                    ),
                );
                s.off = true;
                return;
            }
        };
        slot.processed += 1;
        done.push(Done {
            view: job.view,
            eye,
            input,
            tracked,
            encoded,
        });
    }
    ctx.queue().submit([encoder.finish()]);
    if done.is_empty() || (config.out.is_none() && config.dump.is_none()) {
        return;
    }
    // The EyeState's age at the predicted display time (host clock).
    let age_ms = state.filter(|st| st.t_secs > 0.0).and_then(|st| {
        let f = next.time_to_timespec?;
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: the app's instance and a timespec out-pointer.
        let r = unsafe {
            f(
                instance,
                xr::Time::from_nanos(display_ns),
                &mut ts as *mut libc::timespec as *mut _,
            )
        };
        (r.into_raw() >= 0).then(|| {
            let mono = ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9;
            (mono - mono_minus_host - st.t_secs) * 1e3
        })
    });
    for d in done {
        let slot = &mut s.eyes[d.view];
        let Some(p) = slot.processor.as_mut() else {
            continue;
        };
        if let Some(csv) = s.csv.as_mut() {
            let gpu_ms = p.read_gpu_ms();
            let st = p.pipeline().read_state().ok();
            let row = format!(
                "{display_ns},{},{},{:.5},{:.5},{},{:.4},{},{},{:.4},{},{},{}\n",
                d.view,
                if d.eye == gazelight_tracker::EYE_LEFT {
                    "left"
                } else {
                    "right"
                },
                d.input.gaze_uv[0],
                d.input.gaze_uv[1],
                u8::from(d.tracked),
                d.input.pupil_mm,
                st.map_or(String::new(), |s| format!("{:.5}", s.target_cd_m2)),
                st.map_or(String::new(), |s| format!("{:.5}", s.adaptation_cd_m2)),
                d.encoded.psf_pupil_mm,
                u8::from(d.encoded.psf_rebuilt),
                gpu_ms.map_or(String::new(), |v| format!("{v:.3}")),
                age_ms.map_or(String::new(), |v| format!("{v:.2}")),
            );
            // Each row reaches the file at once: an app killed at any
            // moment keeps every processed view's row.
            csv.push(&row);
            csv.flush();
        }
        if let Some(dir) = &config.dump
            && (slot.processed - 1) % config.dump_every == 0
        {
            let name = format!(
                "eye-{}-{:06}.png",
                if d.eye == gazelight_tracker::EYE_LEFT {
                    "left"
                } else {
                    "right"
                },
                slot.processed - 1
            );
            match p.pipeline().display() {
                Ok(frame) => {
                    if let Err(e) = image::save_buffer(
                        dir.join(&name),
                        &frame.rgba8,
                        frame.width as u32,
                        frame.height as u32,
                        image::ExtendedColorType::Rgba8,
                    ) {
                        warn(format!("cannot write dumps into {}: {e}", dir.display()));
                    }
                }
                Err(e) => warn(format!("reading a frame back for a dump: {e}")),
            }
        }
    }
}

/// `EyeState` for tests of the gaze choice.
#[doc(hidden)]
pub fn view_gaze(state: &EyeState, view: usize) -> [f32; 2] {
    state.eye_gaze_uv(eye_of_view(view))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(x: i32, y: i32, w: i32, h: i32) -> xr::Rect2Di {
        xr::Rect2Di {
            offset: xr::Offset2Di { x, y },
            extent: xr::Extent2Di {
                width: w,
                height: h,
            },
        }
    }

    #[test]
    fn image_rects_inside_the_image_are_served_and_others_are_not() {
        let image = [2880, 1600];
        // The whole image, and each eye's half of a side-by-side image.
        assert_eq!(
            rect_in_image(rect(0, 0, 2880, 1600), image),
            Some(([0, 0], [2880, 1600]))
        );
        assert_eq!(
            rect_in_image(rect(0, 0, 1440, 1600), image),
            Some(([0, 0], [1440, 1600]))
        );
        assert_eq!(
            rect_in_image(rect(1440, 0, 1440, 1600), image),
            Some(([1440, 0], [1440, 1600]))
        );
        // Past an edge, negative, empty, or overflowing.
        for r in [
            rect(1441, 0, 1440, 1600),
            rect(0, 1, 2880, 1600),
            rect(-1, 0, 100, 100),
            rect(0, 0, 0, 100),
            rect(0, 0, 100, -5),
            rect(i32::MAX, 0, i32::MAX, 100),
        ] {
            assert_eq!(rect_in_image(r, image), None, "{r:?}");
        }
    }
}
