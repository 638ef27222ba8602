#!/usr/bin/env python3
"""Probe the OpenXR runtime from inside the XR root (ctypes, no compiler).

Run with monado-service up:  .ci/xr/root exec --monado -- python3 .ci/xr/probe.py

Prints: the runtime's name and version; whether XR_KHR_convert_timespec_time,
XR_EXT_eye_gaze_interaction and XR_KHR_vulkan_enable2 are offered; the HMD
system (name, max swapchain size, tracking); supportsEyeGazeInteraction; the
primary stereo view configuration (view count, recommended/max sizes); the
Vulkan API range of xrGetVulkanGraphicsRequirements2KHR; and a
CLOCK_MONOTONIC -> XrTime conversion. Exit status 1 when an XR call fails.
"""
import ctypes as C
import sys
import time

xr = C.CDLL("libopenxr_loader.so.1")

XrResult = C.c_int32
XrInstance = C.c_void_p
XrSystemId = C.c_uint64
XrTime = C.c_int64

T_EXTENSION_PROPERTIES = 2
T_INSTANCE_CREATE_INFO = 3
T_SYSTEM_GET_INFO = 4
T_SYSTEM_PROPERTIES = 5
T_INSTANCE_PROPERTIES = 32
T_VIEW_CONFIGURATION_VIEW = 41
T_GRAPHICS_REQUIREMENTS_VULKAN_KHR = 1000025002
T_SYSTEM_EYE_GAZE_INTERACTION_PROPERTIES_EXT = 1000030000
FORM_FACTOR_HMD = 1
VIEW_CONFIG_PRIMARY_STEREO = 2


class ExtensionProperties(C.Structure):
    _fields_ = [("type", C.c_int32), ("next", C.c_void_p),
                ("extensionName", C.c_char * 128), ("extensionVersion", C.c_uint32)]


class ApplicationInfo(C.Structure):
    _fields_ = [("applicationName", C.c_char * 128), ("applicationVersion", C.c_uint32),
                ("engineName", C.c_char * 128), ("engineVersion", C.c_uint32),
                ("apiVersion", C.c_uint64)]


class InstanceCreateInfo(C.Structure):
    _fields_ = [("type", C.c_int32), ("next", C.c_void_p), ("createFlags", C.c_uint64),
                ("applicationInfo", ApplicationInfo),
                ("enabledApiLayerCount", C.c_uint32),
                ("enabledApiLayerNames", C.POINTER(C.c_char_p)),
                ("enabledExtensionCount", C.c_uint32),
                ("enabledExtensionNames", C.POINTER(C.c_char_p))]


class InstanceProperties(C.Structure):
    _fields_ = [("type", C.c_int32), ("next", C.c_void_p),
                ("runtimeVersion", C.c_uint64), ("runtimeName", C.c_char * 128)]


class SystemGetInfo(C.Structure):
    _fields_ = [("type", C.c_int32), ("next", C.c_void_p), ("formFactor", C.c_int32)]


class EyeGazeProps(C.Structure):
    _fields_ = [("type", C.c_int32), ("next", C.c_void_p),
                ("supportsEyeGazeInteraction", C.c_uint32)]


class SystemProperties(C.Structure):
    _fields_ = [("type", C.c_int32), ("next", C.c_void_p), ("systemId", C.c_uint64),
                ("vendorId", C.c_uint32), ("systemName", C.c_char * 256),
                ("maxSwapchainImageHeight", C.c_uint32),
                ("maxSwapchainImageWidth", C.c_uint32), ("maxLayerCount", C.c_uint32),
                ("orientationTracking", C.c_uint32), ("positionTracking", C.c_uint32)]


class ViewConfigurationView(C.Structure):
    _fields_ = [("type", C.c_int32), ("next", C.c_void_p),
                ("recommendedImageRectWidth", C.c_uint32), ("maxImageRectWidth", C.c_uint32),
                ("recommendedImageRectHeight", C.c_uint32), ("maxImageRectHeight", C.c_uint32),
                ("recommendedSwapchainSampleCount", C.c_uint32),
                ("maxSwapchainSampleCount", C.c_uint32)]


class GraphicsRequirementsVulkan(C.Structure):
    _fields_ = [("type", C.c_int32), ("next", C.c_void_p),
                ("minApiVersionSupported", C.c_uint64), ("maxApiVersionSupported", C.c_uint64)]


class Timespec(C.Structure):
    _fields_ = [("tv_sec", C.c_long), ("tv_nsec", C.c_long)]


def check(res, what):
    if res < 0:
        print(f"FAIL {what}: XrResult {res}")
        sys.exit(1)


def version(v):
    return f"{v >> 48}.{(v >> 32) & 0xFFFF}.{v & 0xFFFFFFFF}"


def proc(instance, name, *argtypes):
    fn = C.c_void_p()
    check(xr.xrGetInstanceProcAddr(instance, name.encode(), C.byref(fn)), name)
    return C.CFUNCTYPE(XrResult, *argtypes)(fn.value)


count = C.c_uint32()
check(xr.xrEnumerateInstanceExtensionProperties(None, 0, C.byref(count), None), "enumerate")
props = (ExtensionProperties * count.value)()
for p in props:
    p.type = T_EXTENSION_PROPERTIES
check(xr.xrEnumerateInstanceExtensionProperties(None, count, C.byref(count), props), "enumerate")
offered = {p.extensionName.decode(): p.extensionVersion for p in props}
wanted = ["XR_KHR_convert_timespec_time", "XR_EXT_eye_gaze_interaction", "XR_KHR_vulkan_enable2"]
for name in wanted:
    print(f"extension {name}: " + (f"offered (spec {offered[name]})" if name in offered else "NOT offered"))

enable = [n for n in wanted if n in offered]
names = (C.c_char_p * len(enable))(*[n.encode() for n in enable])
ci = InstanceCreateInfo(type=T_INSTANCE_CREATE_INFO)
ci.applicationInfo.applicationName = b"gazelight-xr-probe"
ci.applicationInfo.apiVersion = (1 << 48) | (0 << 32) | 0
ci.enabledExtensionCount = len(enable)
ci.enabledExtensionNames = names
instance = XrInstance()
check(xr.xrCreateInstance(C.byref(ci), C.byref(instance)), "xrCreateInstance")

ip = InstanceProperties(type=T_INSTANCE_PROPERTIES)
check(xr.xrGetInstanceProperties(instance, C.byref(ip)), "xrGetInstanceProperties")
print(f"runtime: {ip.runtimeName.decode()} {version(ip.runtimeVersion)}")

gi = SystemGetInfo(type=T_SYSTEM_GET_INFO, formFactor=FORM_FACTOR_HMD)
system = XrSystemId()
check(xr.xrGetSystem(instance, C.byref(gi), C.byref(system)), "xrGetSystem")
eye = EyeGazeProps(type=T_SYSTEM_EYE_GAZE_INTERACTION_PROPERTIES_EXT)
sp = SystemProperties(type=T_SYSTEM_PROPERTIES)
if "XR_EXT_eye_gaze_interaction" in enable:
    sp.next = C.cast(C.pointer(eye), C.c_void_p)
check(xr.xrGetSystemProperties(instance, system, C.byref(sp)), "xrGetSystemProperties")
print(f"system: {sp.systemName.decode()!r} vendorId={sp.vendorId} "
      f"maxSwapchain={sp.maxSwapchainImageWidth}x{sp.maxSwapchainImageHeight} "
      f"maxLayers={sp.maxLayerCount} orientation={bool(sp.orientationTracking)} "
      f"position={bool(sp.positionTracking)}")
if "XR_EXT_eye_gaze_interaction" in enable:
    print(f"supportsEyeGazeInteraction: {bool(eye.supportsEyeGazeInteraction)}")

check(xr.xrEnumerateViewConfigurationViews(instance, system, VIEW_CONFIG_PRIMARY_STEREO,
                                           0, C.byref(count), None), "views")
views = (ViewConfigurationView * count.value)()
for v in views:
    v.type = T_VIEW_CONFIGURATION_VIEW
check(xr.xrEnumerateViewConfigurationViews(instance, system, VIEW_CONFIG_PRIMARY_STEREO,
                                           count, C.byref(count), views), "views")
print(f"primary stereo: {count.value} views")
for i, v in enumerate(views):
    print(f"  view {i}: recommended {v.recommendedImageRectWidth}x{v.recommendedImageRectHeight} "
          f"max {v.maxImageRectWidth}x{v.maxImageRectHeight} "
          f"samples {v.recommendedSwapchainSampleCount}/{v.maxSwapchainSampleCount}")

if "XR_KHR_vulkan_enable2" in enable:
    get_req = proc(instance, "xrGetVulkanGraphicsRequirements2KHR",
                   XrInstance, XrSystemId, C.POINTER(GraphicsRequirementsVulkan))
    req = GraphicsRequirementsVulkan(type=T_GRAPHICS_REQUIREMENTS_VULKAN_KHR)
    check(get_req(instance, system, C.byref(req)), "xrGetVulkanGraphicsRequirements2KHR")
    print(f"vulkan api: min {version(req.minApiVersionSupported)} "
          f"max {version(req.maxApiVersionSupported)}")

if "XR_KHR_convert_timespec_time" in enable:
    conv = proc(instance, "xrConvertTimespecTimeToTimeKHR",
                XrInstance, C.POINTER(Timespec), C.POINTER(XrTime))
    ns = time.clock_gettime_ns(time.CLOCK_MONOTONIC)
    ts = Timespec(ns // 1_000_000_000, ns % 1_000_000_000)
    t = XrTime()
    check(conv(instance, C.byref(ts), C.byref(t)), "xrConvertTimespecTimeToTimeKHR")
    print(f"CLOCK_MONOTONIC {ns} ns -> XrTime {t.value} (offset {t.value - ns} ns)")

check(xr.xrDestroyInstance(instance), "xrDestroyInstance")
print("probe ok")
