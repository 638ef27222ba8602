//! A wgpu device on the app's own Vulkan device (XR_KHR_vulkan_enable2).
//!
//! The app asks the runtime to create its Vulkan instance and device
//! (`xrCreateVulkanInstanceKHR`, `xrCreateVulkanDeviceKHR`); the layer
//! adds what wgpu-hal 30 needs to those create infos on the way down:
//!
//! 1. [`InstancePatch`]: the instance extensions
//!    `hal::vulkan::Instance::desired_extensions` lists (those the loader
//!    has), and the API version raised to the loader's newest up to 1.3
//!    (wgpu-hal uses a device's core 1.2/1.3 functions).
//! 2. [`DevicePlan`]: the app's `VkInstance` wrapped by
//!    `hal::vulkan::Instance::from_raw` (with a drop callback: the app owns
//!    it), its physical device exposed as a wgpu adapter; the device
//!    extensions `Adapter::required_device_extensions` lists and the
//!    feature structures `Adapter::physical_device_features` builds are
//!    merged into the app's `VkDeviceCreateInfo` ([`DevicePlan::patch`]):
//!    core features OR-ed, wgpu's structures put in front of the app's
//!    chain. When the app's chain already has one of those structure types
//!    (or `VkPhysicalDeviceFeatures2` / `VkPhysicalDeviceVulkan1xFeatures`,
//!    which cover them), the layer cannot merge without knowing every
//!    field: it changes nothing and serves no frames on that device.
//! 3. At `xrCreateSession` ([`DevicePlan::open`]), with the queue family and
//!    index from `XrGraphicsBindingVulkan2KHR`: `Adapter::device_from_raw`
//!    (again with a drop callback) and `wgpu::Adapter::create_device_from_hal`
//!    give the `wgpu::Device` / `Queue` the passes run on
//!    ([`gazelight_gpu::GpuContext::from_device`]).
//!
//! Swapchain images become `wgpu::Texture`s with [`LayerGpu::wrap_image`]
//! (`Device::texture_from_raw` + `create_texture_from_hal`, initial state
//! `COLOR_TARGET`: an OpenXR Vulkan colour image is in
//! `COLOR_ATTACHMENT_OPTIMAL` whenever the app holds it).

use std::ffi::{CStr, c_char, c_void};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use ash::vk::{self, Handle as _};
use gazelight_gpu::GpuContext;
use wgpu::hal;
use wgpu::hal::api::Vulkan as VkApi;

/// Why the layer cannot put wgpu on a Vulkan instance or device.
#[derive(Debug, thiserror::Error)]
pub enum VkError {
    #[error("{0}")]
    Unsupported(String),
    #[error("{call}: {result:?}")]
    Vulkan {
        call: &'static str,
        result: vk::Result,
    },
}

fn unsupported(reason: impl Into<String>) -> VkError {
    VkError::Unsupported(reason.into())
}

/// The lowest instance API version the layer asks for (wgpu-hal's
/// multiview, maintenance and properties2 paths are core in 1.1).
const MIN_VK: u32 = vk::API_VERSION_1_1;
/// The highest Vulkan version wgpu-hal 30 uses.
const WGPU_MAX_VK: u32 = vk::API_VERSION_1_3;

/// What the layer recorded of an instance created through it.
#[derive(Clone)]
pub struct AppInstance {
    pub entry: ash::Entry,
    pub raw: vk::Instance,
    pub api_version: u32,
    /// wgpu's instance extensions, all enabled on this instance.
    pub extensions: Vec<&'static CStr>,
}

/// The app's `VkInstanceCreateInfo` with wgpu's extensions added; owns
/// what the patched info points to.
pub struct InstancePatch {
    app_info: vk::ApplicationInfo<'static>,
    names: Vec<*const c_char>,
    info: vk::InstanceCreateInfo<'static>,
    pub api_version: u32,
    pub extensions: Vec<&'static CStr>,
}

impl InstancePatch {
    /// # Safety
    /// `info` is a valid `VkInstanceCreateInfo` that outlives the patch.
    pub unsafe fn new(
        entry: &ash::Entry,
        info: &vk::InstanceCreateInfo,
    ) -> Result<Box<Self>, VkError> {
        let app_info = if info.p_application_info.is_null() {
            vk::ApplicationInfo::default()
        } else {
            // SAFETY: the app's application info (non-null), part of the
            // valid create info the caller passes.
            unsafe { *info.p_application_info }
        };
        // SAFETY: a plain query on the app's loader.
        let loader = unsafe { entry.try_enumerate_instance_version() }
            .map_err(|result| VkError::Vulkan {
                call: "vkEnumerateInstanceVersion",
                result,
            })?
            .unwrap_or(vk::API_VERSION_1_0);
        let asked = if app_info.api_version == 0 {
            vk::API_VERSION_1_0
        } else {
            app_info.api_version
        };
        // The newest the loader has, up to wgpu-hal's 1.3: wgpu-hal uses
        // the physical device's core 1.2/1.3 functions (timeline
        // semaphores) when the device has them, and a device's core
        // functions above the instance's version are not loaded.
        let api_version = asked.max(loader.min(WGPU_MAX_VK)).max(MIN_VK);
        if loader < api_version {
            return Err(unsupported(format!(
                "the Vulkan loader offers {}.{}, the layer needs {}.{}",
                vk::api_version_major(loader),
                vk::api_version_minor(loader),
                vk::api_version_major(api_version),
                vk::api_version_minor(api_version)
            )));
        }
        let extensions = hal::vulkan::Instance::desired_extensions(
            entry,
            api_version,
            wgpu::InstanceFlags::empty(),
        )
        .map_err(|e| unsupported(format!("wgpu's instance extensions: {e}")))?;
        // SAFETY: the app's array of `enabled_extension_count` names.
        let names = unsafe {
            with_extensions(
                info.pp_enabled_extension_names,
                info.enabled_extension_count,
                &extensions,
            )
        };
        let mut patch = Box::new(Self {
            // SAFETY: (lifetime only) the app's strings outlive the patch
            // (the caller's contract: `info` outlives it).
            app_info: unsafe {
                std::mem::transmute::<vk::ApplicationInfo<'_>, vk::ApplicationInfo<'static>>(
                    vk::ApplicationInfo {
                        api_version,
                        ..app_info
                    },
                )
            },
            names,
            // SAFETY: (lifetime only) the copy points into `patch`, which is
            // boxed (does not move) and outlives every use of `info()`.
            info: unsafe {
                std::mem::transmute::<vk::InstanceCreateInfo<'_>, vk::InstanceCreateInfo<'static>>(
                    *info,
                )
            },
            api_version,
            extensions,
        });
        patch.info.p_application_info = &patch.app_info;
        patch.info.pp_enabled_extension_names = patch.names.as_ptr();
        patch.info.enabled_extension_count = patch.names.len() as u32;
        Ok(patch)
    }

    /// The patched create info (valid while `self` lives).
    pub fn info(&self) -> &vk::InstanceCreateInfo<'static> {
        &self.info
    }
}

/// An instance's physical device as a wgpu adapter, before its device
/// exists.
pub struct DevicePlan {
    instance: wgpu::Instance,
    adapter: wgpu::Adapter,
    raw_instance: vk::Instance,
    raw_physical_device: vk::PhysicalDevice,
    pub features: wgpu::Features,
    pub extensions: Vec<&'static CStr>,
    pub adapter_name: String,
}

impl std::fmt::Debug for DevicePlan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DevicePlan")
            .field("adapter", &self.adapter_name)
            .field("features", &self.features)
            .finish_non_exhaustive()
    }
}

/// The app's `VkDeviceCreateInfo` with wgpu's needs merged in; owns what
/// it points to.
pub struct DevicePatch {
    _features: Box<hal::vulkan::PhysicalDeviceFeatures>,
    core: Box<vk::PhysicalDeviceFeatures>,
    names: Vec<*const c_char>,
    info: vk::DeviceCreateInfo<'static>,
}

impl DevicePatch {
    /// The patched create info (valid while `self` lives).
    pub fn info(&self) -> &vk::DeviceCreateInfo<'static> {
        &self.info
    }
}

/// The structure types whose presence in the app's chain the layer cannot
/// merge with wgpu's own (they cover the same features).
const COVERING: [vk::StructureType; 4] = [
    vk::StructureType::PHYSICAL_DEVICE_FEATURES_2,
    vk::StructureType::PHYSICAL_DEVICE_VULKAN_1_1_FEATURES,
    vk::StructureType::PHYSICAL_DEVICE_VULKAN_1_2_FEATURES,
    vk::StructureType::PHYSICAL_DEVICE_VULKAN_1_3_FEATURES,
];

/// The structure types of a `pNext` chain.
///
/// # Safety
/// `p` is null or a valid Vulkan structure chain.
unsafe fn chain_types(mut p: *const c_void) -> Vec<vk::StructureType> {
    let mut out = Vec::new();
    while !p.is_null() && out.len() < 256 {
        // SAFETY: every Vulkan structure starts with (sType, pNext).
        let base = unsafe { &*(p as *const vk::BaseInStructure) };
        out.push(base.s_type);
        p = base.p_next as *const c_void;
    }
    out
}

impl DevicePlan {
    /// Wraps `instance` (not owned) and exposes `physical_device`.
    pub fn new(
        instance: &AppInstance,
        physical_device: vk::PhysicalDevice,
    ) -> Result<Self, VkError> {
        // SAFETY: a live instance the app created from this entry.
        let ash_instance = unsafe { ash::Instance::load(instance.entry.static_fn(), instance.raw) };
        // SAFETY: (from_raw) created from `entry` for `api_version` with
        // `extensions` among its extensions and no debug messenger; the
        // drop callback leaves it to the app.
        let hal_instance = unsafe {
            hal::vulkan::Instance::from_raw(
                instance.entry.clone(),
                ash_instance,
                instance.api_version,
                0,
                None,
                instance.extensions.clone(),
                wgpu::InstanceFlags::empty(),
                wgpu::MemoryBudgetThresholds::default(),
                false,
                Some(Box::new(|| ())),
            )
        }
        .map_err(|e| unsupported(format!("wrapping the app's VkInstance: {e}")))?;
        // SAFETY: a Vulkan hal instance; wgpu holds it.
        let wgpu_instance = unsafe { wgpu::Instance::from_hal::<VkApi>(hal_instance) };
        let exposed = {
            // SAFETY: only to expose the adapter.
            let hal_instance = unsafe { wgpu_instance.as_hal::<VkApi>() }
                .ok_or_else(|| unsupported("the wgpu instance has no Vulkan backend"))?;
            hal_instance
                .expose_adapter(physical_device)
                .ok_or_else(|| {
                    unsupported(
                        "wgpu refused the app's physical device (below wgpu's minimum Vulkan capabilities)",
                    )
                })?
        };
        let adapter_name = exposed.info.name.clone();
        // The layer's GPU time needs timestamps, where the adapter has them.
        let features = exposed.features & wgpu::Features::TIMESTAMP_QUERY;
        // SAFETY: exposed from this instance.
        let adapter = unsafe { wgpu_instance.create_adapter_from_hal(exposed) };
        let extensions = {
            // SAFETY: only to list the extensions.
            let hal_adapter = unsafe { adapter.as_hal::<VkApi>() }
                .ok_or_else(|| unsupported("the wgpu adapter has no Vulkan backend"))?;
            hal_adapter.required_device_extensions(features)
        };
        Ok(Self {
            instance: wgpu_instance,
            adapter,
            raw_instance: instance.raw,
            raw_physical_device: physical_device,
            features,
            extensions,
            adapter_name,
        })
    }

    /// The app's device create info with wgpu's extensions and features
    /// merged in (module docs); an error when they cannot be merged.
    ///
    /// # Safety
    /// `info` is a valid `VkDeviceCreateInfo` that outlives the patch.
    pub unsafe fn patch(&self, info: &vk::DeviceCreateInfo) -> Result<Box<DevicePatch>, VkError> {
        // SAFETY: only to build the feature structures.
        let hal_adapter = unsafe { self.adapter.as_hal::<VkApi>() }
            .ok_or_else(|| unsupported("the wgpu adapter has no Vulkan backend"))?;
        let mut features =
            Box::new(hal_adapter.physical_device_features(&self.extensions, self.features));
        drop(hal_adapter);
        // SAFETY: the app's chain.
        let app_types = unsafe { chain_types(info.p_next) };
        let mut ours = features.add_to_device_create(vk::DeviceCreateInfo::default());
        let core = if ours.p_enabled_features.is_null() {
            vk::PhysicalDeviceFeatures::default()
        } else {
            // SAFETY: points into `features`.
            unsafe { *ours.p_enabled_features }
        };
        // SAFETY: wgpu's own chain, in `features`.
        let our_types = unsafe { chain_types(ours.p_next) };
        if let Some(t) = app_types
            .iter()
            .find(|t| COVERING.contains(t) || our_types.contains(t))
        {
            return Err(unsupported(format!(
                "the app's VkDeviceCreateInfo chains {t:?}, which the layer cannot merge with wgpu's features"
            )));
        }
        let app_core = if info.p_enabled_features.is_null() {
            vk::PhysicalDeviceFeatures::default()
        } else {
            // SAFETY: the app's features.
            unsafe { *info.p_enabled_features }
        };
        // VkPhysicalDeviceFeatures is an array of VkBool32: OR them.
        let mut merged = app_core;
        {
            const N: usize = size_of::<vk::PhysicalDeviceFeatures>() / size_of::<vk::Bool32>();
            // SAFETY: repr(C) struct of N VkBool32 fields.
            let m = unsafe {
                &mut *(&mut merged as *mut vk::PhysicalDeviceFeatures as *mut [vk::Bool32; N])
            };
            // SAFETY: as above, a shared view of `core`.
            let c =
                unsafe { &*(&core as *const vk::PhysicalDeviceFeatures as *const [vk::Bool32; N]) };
            for (a, b) in m.iter_mut().zip(c) {
                *a = u32::from(*a != 0 || *b != 0);
            }
        }
        // Put wgpu's chain in front of the app's.
        if ours.p_next.is_null() {
            ours.p_next = info.p_next;
        } else {
            let mut p = ours.p_next as *mut vk::BaseOutStructure;
            // SAFETY: wgpu's chain in `features`, which this function owns.
            unsafe {
                while !(*p).p_next.is_null() {
                    p = (*p).p_next;
                }
                (*p).p_next = info.p_next as *mut vk::BaseOutStructure;
            }
        }
        // SAFETY: the app's array of `enabled_extension_count` names.
        let names = unsafe {
            with_extensions(
                info.pp_enabled_extension_names,
                info.enabled_extension_count,
                &self.extensions,
            )
        };
        let chain = ours.p_next;
        let mut patch = Box::new(DevicePatch {
            _features: features,
            core: Box::new(merged),
            names,
            // SAFETY: (lifetime only) the copy points into `patch`, boxed,
            // and the app's info outlives the patch (the caller's contract).
            info: unsafe {
                std::mem::transmute::<vk::DeviceCreateInfo<'_>, vk::DeviceCreateInfo<'static>>(
                    *info,
                )
            },
        });
        patch.info.p_next = chain;
        patch.info.p_enabled_features = &*patch.core;
        patch.info.pp_enabled_extension_names = patch.names.as_ptr();
        patch.info.enabled_extension_count = patch.names.len() as u32;
        Ok(patch)
    }

    /// The wgpu device on the app's `device` (created from [`Self::patch`]'s
    /// info), using queue `queue_index` of `family`.
    pub fn open(
        &self,
        raw_device: vk::Device,
        family: u32,
        queue_index: u32,
    ) -> Result<LayerGpu, VkError> {
        // SAFETY: only to create the device.
        let hal_adapter = unsafe { self.adapter.as_hal::<VkApi>() }
            .ok_or_else(|| unsupported("the wgpu adapter has no Vulkan backend"))?;
        let ash_instance = hal_adapter.shared_instance().raw_instance();
        // SAFETY: a physical device of this instance.
        let families = unsafe {
            ash_instance.get_physical_device_queue_family_properties(self.raw_physical_device)
        };
        let Some(props) = families.get(family as usize) else {
            return Err(unsupported(format!("queue family {family} does not exist")));
        };
        if !props
            .queue_flags
            .contains(vk::QueueFlags::COMPUTE | vk::QueueFlags::GRAPHICS)
        {
            return Err(unsupported(format!(
                "the app's queue family {family} lacks graphics and compute ({:?})",
                props.queue_flags
            )));
        }
        if queue_index >= props.queue_count {
            return Err(unsupported(format!(
                "queue {queue_index} of family {family} does not exist"
            )));
        }
        // SAFETY: the app's device, created on this instance.
        let ash_device = unsafe { ash::Device::load(ash_instance.fp_v1_0(), raw_device) };
        // The WebGPU defaults, as gazelight-gpu's own devices (its passes
        // fit them; alignments are computed for them).
        let limits = wgpu::Limits::default();
        let mut over = Vec::new();
        limits.check_limits_with_fail_fn(&self.adapter.limits(), false, |name, want, have| {
            over.push(format!("{name} {want} (adapter: {have})"))
        });
        if !over.is_empty() {
            return Err(unsupported(format!(
                "the adapter is below the WebGPU default limits: {}",
                over.join(", ")
            )));
        }
        let hints = wgpu::MemoryHints::MemoryUsage;
        // SAFETY: the device was created from this adapter with
        // `extensions` and `physical_device_features` merged in
        // (`patch`); the drop callback leaves it to the app.
        let open = unsafe {
            hal_adapter.device_from_raw(
                ash_device,
                Some(Box::new(|| ())),
                &self.extensions,
                self.features,
                &limits,
                &hints,
                family,
                queue_index,
            )
        }
        .map_err(|e| unsupported(format!("device_from_raw: {e}")))?;
        drop(hal_adapter);
        // SAFETY: opened from this adapter with `features`.
        let (device, queue) = unsafe {
            self.adapter.create_device_from_hal(
                open,
                &wgpu::DeviceDescriptor {
                    label: Some("gazelight-openxr-layer"),
                    required_features: self.features,
                    required_limits: limits,
                    experimental_features: wgpu::ExperimentalFeatures::disabled(),
                    memory_hints: hints,
                    trace: wgpu::Trace::Off,
                },
            )
        }
        .map_err(|e| unsupported(format!("the app's VkDevice as a wgpu::Device: {e}")))?;
        let failed = Arc::new(AtomicBool::new(false));
        {
            let failed = Arc::clone(&failed);
            device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
                crate::log(
                    "error",
                    &format!("GPU error: {e}; frames pass through from now on"),
                );
                failed.store(true, Ordering::Relaxed);
            }));
        }
        {
            let failed = Arc::clone(&failed);
            device.set_device_lost_callback(move |reason, message| {
                crate::log(
                    "error",
                    &format!(
                        "GPU device lost ({reason:?}): {message}; frames pass through from now on"
                    ),
                );
                failed.store(true, Ordering::Relaxed);
            });
        }
        Ok(LayerGpu {
            _instance: self.instance.clone(),
            ctx: GpuContext::from_device(device, queue),
            raw_instance: self.raw_instance,
            raw_device,
            failed,
        })
    }
}

/// The wgpu device on the app's Vulkan device.
pub struct LayerGpu {
    _instance: wgpu::Instance,
    pub ctx: GpuContext,
    pub raw_instance: vk::Instance,
    pub raw_device: vk::Device,
    /// Set by a GPU error or device loss: frames pass through from then on.
    pub failed: Arc<AtomicBool>,
}

impl LayerGpu {
    /// Whether a GPU error or device loss stopped the layer's frame work.
    pub fn has_failed(&self) -> bool {
        self.failed.load(Ordering::Relaxed)
    }

    /// A swapchain image (not owned) as a texture of `format`, `width ×
    /// height`, `layers` array layers, whose usage includes `COPY_SRC` and
    /// `RENDER_ATTACHMENT`; wgpu takes it to be in
    /// `COLOR_ATTACHMENT_OPTIMAL`.
    ///
    /// # Safety
    /// `image` is a live image of this device created with those
    /// properties, in `COLOR_ATTACHMENT_OPTIMAL` whenever wgpu uses it, and
    /// it outlives the texture.
    pub unsafe fn wrap_image(
        &self,
        image: vk::Image,
        format: wgpu::TextureFormat,
        width: u32,
        height: u32,
        layers: u32,
    ) -> Result<wgpu::Texture, VkError> {
        let size = wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: layers,
        };
        let usage = wgpu::TextureUsages::COPY_SRC | wgpu::TextureUsages::RENDER_ATTACHMENT;
        let hal_desc = hal::TextureDescriptor {
            label: Some("gazelight-layer swapchain image"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUses::COPY_SRC | wgpu::TextureUses::COLOR_TARGET,
            memory_flags: hal::MemoryFlags::empty(),
            view_formats: Vec::new(),
        };
        let device = self.ctx.device();
        // SAFETY: the caller's contract; the drop callback leaves the image
        // to the runtime.
        let hal_texture = {
            // SAFETY: only to make the texture; the guard is dropped at the
            // end of this block.
            let hal_device = unsafe { device.as_hal::<VkApi>() }
                .ok_or_else(|| unsupported("the wgpu device has no Vulkan backend"))?;
            // SAFETY: see above (the caller's contract on `image`).
            unsafe {
                hal_device.texture_from_raw(
                    image,
                    &hal_desc,
                    Some(Box::new(|| ())),
                    hal::vulkan::TextureMemory::External,
                )
            }
        };
        let desc = wgpu::TextureDescriptor {
            label: Some("gazelight-layer swapchain image"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        };
        // SAFETY: made from this device's hal device with `desc`; the
        // image is in COLOR_ATTACHMENT_OPTIMAL (the caller's contract).
        Ok(unsafe {
            device.create_texture_from_hal::<VkApi>(
                hal_texture,
                &desc,
                wgpu::TextureUses::COLOR_TARGET,
            )
        })
    }
}

/// The raw handle of a Vulkan image wgpu made (tests: an image "of the
/// app" on the app's device).
pub fn raw_image(texture: &wgpu::Texture) -> Option<vk::Image> {
    // SAFETY: only reads the handle.
    let hal = unsafe { texture.as_hal::<VkApi>() }?;
    // SAFETY: only reads the handle.
    Some(unsafe { hal.raw_handle() })
}

/// `VkInstance`/`VkDevice` etc. from OpenXR's pointer-typed handles.
pub fn instance_from_xr(p: *const c_void) -> vk::Instance {
    vk::Instance::from_raw(p as u64)
}

pub fn physical_device_from_xr(p: *const c_void) -> vk::PhysicalDevice {
    vk::PhysicalDevice::from_raw(p as u64)
}

pub fn device_from_xr(p: *const c_void) -> vk::Device {
    vk::Device::from_raw(p as u64)
}

/// The wgpu format of a swapchain's `VkFormat`, when the layer serves it.
pub fn served_format(vk_format: i64) -> Option<wgpu::TextureFormat> {
    let f = vk::Format::from_raw(i32::try_from(vk_format).ok()?);
    match f {
        vk::Format::R8G8B8A8_SRGB => Some(wgpu::TextureFormat::Rgba8UnormSrgb),
        vk::Format::B8G8R8A8_SRGB => Some(wgpu::TextureFormat::Bgra8UnormSrgb),
        vk::Format::R16G16B16A16_SFLOAT => Some(wgpu::TextureFormat::Rgba16Float),
        _ => None,
    }
}

/// A `VkFormat` code's name for a warning.
pub fn format_name(vk_format: i64) -> String {
    match i32::try_from(vk_format) {
        Ok(f) => format!("{:?}", vk::Format::from_raw(f)),
        Err(_) => format!("VkFormat {vk_format}"),
    }
}

/// The app's `count` extension names at `app` (null: none) and then each
/// of `extra` the app does not name already.
///
/// # Safety
/// `app` is null or points at `count` pointers, each null or a
/// NUL-terminated string, alive while the result is used.
unsafe fn with_extensions(
    app: *const *const c_char,
    count: u32,
    extra: &[&'static CStr],
) -> Vec<*const c_char> {
    let mut names: Vec<*const c_char> = if app.is_null() {
        Vec::new()
    } else {
        // SAFETY: the caller's array of `count` names.
        unsafe { std::slice::from_raw_parts(app, count as usize) }.to_vec()
    };
    for e in extra {
        let named = names.iter().any(|&n| {
            // SAFETY: the app's non-null names are NUL-terminated (the
            // caller's contract).
            !n.is_null() && unsafe { CStr::from_ptr(n) } == *e
        });
        if !named {
            names.push(e.as_ptr());
        }
    }
    names
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_served_formats_are_the_vulkan_codes_of_the_issue() {
        // VkFormat codes from the Vulkan registry: 43 R8G8B8A8_SRGB,
        // 50 B8G8R8A8_SRGB, 97 R16G16B16A16_SFLOAT, 37 R8G8B8A8_UNORM.
        assert_eq!(served_format(43), Some(wgpu::TextureFormat::Rgba8UnormSrgb));
        assert_eq!(served_format(50), Some(wgpu::TextureFormat::Bgra8UnormSrgb));
        assert_eq!(served_format(97), Some(wgpu::TextureFormat::Rgba16Float));
        assert_eq!(served_format(37), None);
        assert_eq!(served_format(1 << 40), None);
        assert_eq!(format_name(43), "R8G8B8A8_SRGB");
    }
}
