//! The Vulkan instance and device of an OpenXR session, created by the
//! runtime (XR_KHR_vulkan_enable2) from the create-infos wgpu-hal would use,
//! and handed to wgpu through wgpu-hal's raw interop.
//!
//! Steps (wgpu / wgpu-hal 30.0.1):
//! 1. `hal::vulkan::Instance::desired_extensions` lists the instance
//!    extensions wgpu wants; `xrCreateVulkanInstanceKHR` creates the
//!    instance with them plus whatever the runtime adds;
//!    `hal::vulkan::Instance::from_raw` + `wgpu::Instance::from_hal` wrap it
//!    (wgpu owns and destroys it).
//! 2. `xrGetVulkanGraphicsDevice2KHR` names the physical device;
//!    `Instance::expose_adapter` + `wgpu::Instance::create_adapter_from_hal`
//!    make it a `wgpu::Adapter`.
//! 3. `Adapter::required_device_extensions` / `physical_device_features`
//!    give the device extensions and feature chain wgpu needs;
//!    `xrCreateVulkanDeviceKHR` creates the device with them plus the
//!    runtime's; `Adapter::device_from_raw` +
//!    `wgpu::Adapter::create_device_from_hal` wrap it (wgpu owns it).

use std::ffi::{CStr, c_char, c_void};

use ash::vk::{self, Handle as _};
use openxr as xr;
use wgpu::hal;
use wgpu::hal::api::Vulkan as VkApi;

use crate::error::{XrError, xr};

/// The highest Vulkan version wgpu-hal 30 uses (its `init` asks for 1.3).
const WGPU_MAX_VK: u32 = vk::API_VERSION_1_3;

/// What the session needs of the Vulkan objects the runtime created.
pub(crate) struct VulkanContext {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub raw_instance: vk::Instance,
    pub raw_physical_device: vk::PhysicalDevice,
    pub raw_device: vk::Device,
    pub queue_family_index: u32,
    /// The Vulkan API version the instance was created for.
    pub api_version: u32,
}

fn vk_err(call: &'static str) -> impl FnOnce(vk::Result) -> XrError {
    move |result| XrError::Vulkan { call, result }
}

fn xr_version_to_vk(v: xr::Version) -> u32 {
    vk::make_api_version(0, u32::from(v.major()), u32::from(v.minor()), 0)
}

/// The `VkGetInstanceProcAddr` of `entry`, as OpenXR's binding type.
fn get_instance_proc_addr(entry: &ash::Entry) -> xr::sys::platform::VkGetInstanceProcAddr {
    let gipa: vk::PFN_vkGetInstanceProcAddr = entry.static_fn().get_instance_proc_addr;
    // SAFETY: identical C signatures (VkInstance is a pointer-sized handle,
    // the name a C string, the result an optional function pointer); only
    // the Rust spelling of the types differs.
    unsafe {
        std::mem::transmute::<vk::PFN_vkGetInstanceProcAddr, xr::sys::platform::VkGetInstanceProcAddr>(
            gipa,
        )
    }
}

/// Creates instance, adapter, device and queue for `system` through the
/// runtime. `features` / `limits` are what the caller's passes need.
pub(crate) fn create(
    xr_instance: &xr::Instance,
    system: xr::SystemId,
    app_name: &str,
    features: wgpu::Features,
    limits: &wgpu::Limits,
) -> Result<VulkanContext, XrError> {
    let reqs = xr_instance
        .graphics_requirements::<xr::Vulkan>(system)
        .map_err(xr("xrGetVulkanGraphicsRequirements2KHR"))?;

    // SAFETY: loading libvulkan.so.1 runs its initialisers; the Vulkan
    // loader is a well-behaved shared library.
    let entry = unsafe { ash::Entry::load() }.map_err(|e| XrError::VulkanLoader(e.to_string()))?;
    // SAFETY: plain query on a loaded entry.
    let loader_version = unsafe { entry.try_enumerate_instance_version() }
        .map_err(vk_err("vkEnumerateInstanceVersion"))?
        .unwrap_or(vk::API_VERSION_1_0);
    let min = xr_version_to_vk(reqs.min_api_version_supported);
    let max = xr_version_to_vk(reqs.max_api_version_supported);
    // The newest version all three accept: the loader, the runtime, wgpu.
    let api_version = loader_version.min(max).min(WGPU_MAX_VK);
    let api_version = vk::make_api_version(
        0,
        vk::api_version_major(api_version),
        vk::api_version_minor(api_version),
        0,
    );
    if api_version < min {
        return Err(XrError::VulkanVersion {
            min_major: reqs.min_api_version_supported.major(),
            min_minor: reqs.min_api_version_supported.minor(),
            max_major: reqs.max_api_version_supported.major(),
            max_minor: reqs.max_api_version_supported.minor(),
            loader_major: vk::api_version_major(loader_version),
            loader_minor: vk::api_version_minor(loader_version),
        });
    }

    let flags = wgpu::InstanceFlags::from_env_or_default();
    let extensions = hal::vulkan::Instance::desired_extensions(&entry, api_version, flags)
        .map_err(|e| XrError::Adapter {
            device: "(instance)".into(),
            reason: format!("listing the Vulkan instance extensions: {e}"),
        })?;
    let raw_instance = create_instance(
        xr_instance,
        system,
        &entry,
        app_name,
        api_version,
        &extensions,
    )?;
    // SAFETY: `raw_instance` was just created from `entry`'s loader.
    let ash_instance = unsafe { ash::Instance::load(entry.static_fn(), raw_instance) };
    // SAFETY: (from_raw) the instance was created from `entry` for
    // `api_version` with exactly `extensions` (the runtime may have added
    // more, which wgpu-hal does not need to know) and no debug messenger;
    // with no drop callback wgpu-hal owns it and destroys it last. Wrapped
    // at once so that every error below still destroys it.
    let hal_instance = unsafe {
        hal::vulkan::Instance::from_raw(
            entry,
            ash_instance,
            api_version,
            0,
            None,
            extensions,
            flags,
            wgpu::MemoryBudgetThresholds::default(),
            false,
            None,
        )
    }
    .map_err(|e| XrError::Adapter {
        device: "(instance)".into(),
        reason: format!("wrapping the runtime's VkInstance: {e}"),
    })?;
    // SAFETY: a valid Vulkan hal instance; wgpu takes ownership.
    let instance = unsafe { wgpu::Instance::from_hal::<VkApi>(hal_instance) };

    // SAFETY: the runtime created the instance for this system.
    let raw_physical_device = unsafe {
        xr_instance.vulkan_graphics_device(system, raw_instance.as_raw() as *const c_void)
    }
    .map_err(xr("xrGetVulkanGraphicsDevice2KHR"))?;
    let raw_physical_device = vk::PhysicalDevice::from_raw(raw_physical_device as u64);

    let (exposed, queue_family_index) = {
        // SAFETY: only used to expose the adapter below.
        let hal_instance =
            unsafe { instance.as_hal::<VkApi>() }.ok_or_else(|| XrError::Adapter {
                device: format!("{raw_physical_device:?}"),
                reason: "the wgpu instance has no Vulkan backend".into(),
            })?;
        let queue_family_index = graphics_queue_family(
            hal_instance.shared_instance().raw_instance(),
            raw_physical_device,
        )?;
        let exposed = hal_instance
            .expose_adapter(raw_physical_device)
            .ok_or_else(|| XrError::Adapter {
                device: device_name(
                    hal_instance.shared_instance().raw_instance(),
                    raw_physical_device,
                ),
                reason: "expose_adapter refused it (below wgpu's minimum Vulkan \
                         capabilities; see the wgpu-hal debug log)"
                    .into(),
            })?;
        (exposed, queue_family_index)
    };
    let adapter_name = exposed.info.name.clone();
    // SAFETY: `exposed` was made from this instance's hal instance.
    let adapter = unsafe { instance.create_adapter_from_hal(exposed) };

    let missing = features - adapter.features();
    if !missing.is_empty() {
        return Err(XrError::Adapter {
            device: adapter_name,
            reason: format!("it lacks the requested features {missing:?}"),
        });
    }
    let mut over = Vec::new();
    limits.check_limits_with_fail_fn(&adapter.limits(), false, |name, want, have| {
        over.push(format!("{name} {want} (adapter: {have})"))
    });
    if !over.is_empty() {
        return Err(XrError::Adapter {
            device: adapter_name,
            reason: format!("the requested limits exceed it: {}", over.join(", ")),
        });
    }

    let memory_hints = wgpu::MemoryHints::Performance;
    let (open, raw_device) = {
        // SAFETY: the hal adapter is only used to create the device below.
        let hal_adapter = unsafe { adapter.as_hal::<VkApi>() }.ok_or_else(|| XrError::Adapter {
            device: adapter_name.clone(),
            reason: "the wgpu adapter has no Vulkan backend".into(),
        })?;
        let enabled_extensions = hal_adapter.required_device_extensions(features);
        let mut phd_features = hal_adapter.physical_device_features(&enabled_extensions, features);
        let priorities = [1.0f32];
        let queue_infos = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(queue_family_index)
            .queue_priorities(&priorities)];
        let ext_ptrs: Vec<*const c_char> = enabled_extensions.iter().map(|e| e.as_ptr()).collect();
        let pre_info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_infos)
            .enabled_extension_names(&ext_ptrs);
        let info = phd_features.add_to_device_create(pre_info);
        let ash_instance = hal_adapter.shared_instance().raw_instance();
        // SAFETY: `info` and everything it points to live until the call
        // returns; the physical device is the runtime's own choice.
        let created = unsafe {
            xr_instance.create_vulkan_device(
                system,
                get_instance_proc_addr(hal_adapter.shared_instance().entry()),
                raw_physical_device.as_raw() as *const c_void,
                &info as *const vk::DeviceCreateInfo as *const c_void,
            )
        }
        .map_err(xr("xrCreateVulkanDeviceKHR"))?
        .map_err(|r| XrError::Vulkan {
            call: "vkCreateDevice (in xrCreateVulkanDeviceKHR)",
            result: vk::Result::from_raw(r),
        })?;
        let raw_device = vk::Device::from_raw(created as u64);
        // SAFETY: a device just created on this instance.
        let ash_device = unsafe { ash::Device::load(ash_instance.fp_v1_0(), raw_device) };
        // SAFETY: created from this adapter with `enabled_extensions` (the
        // runtime may add more), `phd_features` and one queue of
        // `queue_family_index`; no drop callback: wgpu-hal destroys it.
        let open = unsafe {
            hal_adapter.device_from_raw(
                ash_device,
                None,
                &enabled_extensions,
                features,
                limits,
                &memory_hints,
                queue_family_index,
                0,
            )
        }
        .map_err(|e| XrError::Adapter {
            device: adapter_name.clone(),
            reason: format!("device_from_raw: {e}"),
        })?;
        (open, raw_device)
    };
    // SAFETY: `open` was made from this adapter with `features`.
    let (device, queue) = unsafe {
        adapter.create_device_from_hal(
            open,
            &wgpu::DeviceDescriptor {
                label: Some("gazelight-xr"),
                required_features: features,
                required_limits: limits.clone(),
                experimental_features: wgpu::ExperimentalFeatures::disabled(),
                memory_hints,
                trace: wgpu::Trace::Off,
            },
        )
    }
    .map_err(|e| XrError::Wgpu {
        what: "the runtime's VkDevice as a wgpu::Device".into(),
        message: e.to_string(),
    })?;

    Ok(VulkanContext {
        instance,
        adapter,
        device,
        queue,
        raw_instance,
        raw_physical_device,
        raw_device,
        queue_family_index,
        api_version,
    })
}

/// `xrCreateVulkanInstanceKHR` with wgpu's instance extensions.
fn create_instance(
    xr_instance: &xr::Instance,
    system: xr::SystemId,
    entry: &ash::Entry,
    app_name: &str,
    api_version: u32,
    extensions: &[&'static CStr],
) -> Result<vk::Instance, XrError> {
    let app_name = std::ffi::CString::new(app_name).map_err(|_| XrError::Options {
        field: "app_name",
        reason: "contains a NUL byte".into(),
    })?;
    let app_info = vk::ApplicationInfo::default()
        .application_name(&app_name)
        .application_version(1)
        .engine_name(c"gazelight")
        .engine_version(1)
        .api_version(api_version);
    let ext_ptrs: Vec<*const c_char> = extensions.iter().map(|e| e.as_ptr()).collect();
    let info = vk::InstanceCreateInfo::default()
        .application_info(&app_info)
        .enabled_extension_names(&ext_ptrs);
    // SAFETY: `info` and what it points to outlive the call.
    let raw = unsafe {
        xr_instance.create_vulkan_instance(
            system,
            get_instance_proc_addr(entry),
            &info as *const vk::InstanceCreateInfo as *const c_void,
        )
    }
    .map_err(xr("xrCreateVulkanInstanceKHR"))?
    .map_err(|r| XrError::Vulkan {
        call: "vkCreateInstance (in xrCreateVulkanInstanceKHR)",
        result: vk::Result::from_raw(r),
    })?;
    Ok(vk::Instance::from_raw(raw as u64))
}

/// The first queue family with graphics and compute (what wgpu's queue does).
fn graphics_queue_family(
    instance: &ash::Instance,
    phd: vk::PhysicalDevice,
) -> Result<u32, XrError> {
    // SAFETY: a physical device of this instance.
    let families = unsafe { instance.get_physical_device_queue_family_properties(phd) };
    families
        .iter()
        .position(|f| {
            f.queue_flags
                .contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE)
        })
        .map(|i| i as u32)
        .ok_or_else(|| XrError::Adapter {
            device: device_name(instance, phd),
            reason: "no queue family with graphics and compute".into(),
        })
}

fn device_name(instance: &ash::Instance, phd: vk::PhysicalDevice) -> String {
    // SAFETY: a physical device of this instance.
    let props = unsafe { instance.get_physical_device_properties(phd) };
    props
        .device_name_as_c_str()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|_| format!("{phd:?}"))
}
