//! Eye gaze for the app (issue 33, step 2): `XR_EXT_eye_gaze_interaction`
//! served from the configured gazelight source.
//!
//! Served when the config says `gaze = "gazelight"` and the app enabled
//! `XR_EXT_eye_gaze_interaction`, which the layer's manifest lists (the
//! loader offers it and accepts it whether the runtime has it or not).
//! Then the layer takes the extension out of the create info it passes
//! down (the runtime never serves it), enables
//! `XR_KHR_convert_timespec_time` below itself (for the sample times),
//! starts gazelight-tracker's live eye task on the configured `source`, and
//! intercepts:
//! - `xrGetSystemProperties`: `XrSystemEyeGazeInteractionPropertiesEXT`
//!   says supported (the runtime may have no eye tracker);
//! - `xrSuggestInteractionProfileBindings`: for
//!   `/interaction_profiles/ext/eye_gaze_interaction` it records the
//!   actions bound to `/user/eyes_ext/input/gaze_ext/pose` (a runtime's
//!   rejection of that profile is answered with success);
//! - `xrCreateActionSpace` / `xrDestroySpace` / `xrDestroySession`: which
//!   spaces are gaze spaces;
//! - `xrGetActionStatePose`: a gaze action is active;
//! - `xrLocateSpace` of a gaze space: the binocular gaze ray in VIEW space
//!   (origin between the views, direction the mean of the rays through the
//!   EyeState's `gaze_uv` in each view's field of view), in the asked base
//!   space at the asked time, with `XrEyeGazeSampleTimeEXT` (the newest
//!   sample's time as `XrTime`, at most the time it is served) when chained. The newest state is served
//!   (no prediction). Not tracked (no location flags) during a blink, with
//!   no valid gaze, or when the newest sample is older than
//!   [`STALE_SECS`].
//!
//! Everything else is forwarded untouched.

use std::collections::{HashMap, HashSet};
use std::ffi::{CStr, c_char};
use std::sync::{Mutex, MutexGuard, PoisonError};

use gazelight_tracker::EyeState;
use gazelight_tracker::LiveEyeState;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::live::LiveConfig;
use gazelight_tracker::profile::PupilCalibration;
use gazelight_tracker::pupil::clock::host_now_secs;
use gazelight_tracker::transport::{self, OpenOptions};
use openxr_sys as xr;
use openxr_sys::Handle as _;
use openxr_sys::pfn;
use tokio::sync::watch;

use crate::config::{GazeMode, LayerConfig};
use crate::{guard, log};

/// The extension the layer serves.
pub const EYE_GAZE_EXT: &CStr = c"XR_EXT_eye_gaze_interaction";
/// Its version, as the layer's manifest lists it (the spec's
/// `XR_EXT_eye_gaze_interaction_SPEC_VERSION`).
pub const EYE_GAZE_EXT_VERSION: u32 = xr::EXT_eye_gaze_interaction_SPEC_VERSION;
/// The extension the layer enables below itself for the sample times.
pub const CONVERT_TIMESPEC_EXT: &CStr = c"XR_KHR_convert_timespec_time";
const PROFILE: &str = "/interaction_profiles/ext/eye_gaze_interaction";
const GAZE_POSE: [&str; 2] = [
    "/user/eyes_ext/input/gaze_ext/pose",
    "/user/eyes_ext/input/gaze_ext",
];
/// A newest sample older than this (host clock) is a dropout: not tracked.
/// Sources send at 30..1000 Hz; 0.1 s is three frames at 30 Hz.
pub const STALE_SECS: f64 = 0.1;

/// The next layer's functions the gaze path calls.
#[derive(Clone, Copy)]
struct Next {
    get_system_properties: pfn::GetSystemProperties,
    suggest: pfn::SuggestInteractionProfileBindings,
    path_to_string: pfn::PathToString,
    create_action_space: pfn::CreateActionSpace,
    create_reference_space: pfn::CreateReferenceSpace,
    destroy_space: pfn::DestroySpace,
    destroy_session: pfn::DestroySession,
    locate_space: pfn::LocateSpace,
    locate_views: pfn::LocateViews,
    get_action_state_pose: pfn::GetActionStatePose,
    timespec_to_time: pfn::ConvertTimespecTimeToTimeKHR,
}

#[derive(Clone, Copy)]
struct GazeSpace {
    session: xr::Session,
    pose_in_action: xr::Posef,
}

/// The gaze service of the one instance that has it.
struct Served {
    instance: xr::Instance,
    /// Whether the app's eye gaze is served (else the eye task runs only
    /// for the frame effects).
    serve_gaze: bool,
    next: Next,
    eye: watch::Receiver<LiveEyeState>,
    /// `CLOCK_MONOTONIC` − host clock, s: both tick on the same clock (Rust's
    /// `Instant` is `CLOCK_MONOTONIC` on Linux), so the offset is read once
    /// and sample times keep their order.
    mono_minus_host_secs: f64,
    shutdown: watch::Sender<bool>,
    runtime: Option<tokio::runtime::Runtime>,
    actions: HashSet<u64>,
    spaces: HashMap<u64, GazeSpace>,
    /// Per session: the layer's own VIEW reference space.
    view_spaces: HashMap<u64, xr::Space>,
}

static SERVED: Mutex<Option<Served>> = Mutex::new(None);

fn served() -> MutexGuard<'static, Option<Served>> {
    SERVED.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Whether the app's create info enables `XR_EXT_eye_gaze_interaction`
/// and the config asks the layer to serve it.
///
/// # Safety
/// `info` is null or a valid `XrInstanceCreateInfo`.
pub unsafe fn wanted(info: *const xr::InstanceCreateInfo, config: &LayerConfig) -> bool {
    // SAFETY: `info` as this function's caller guarantees.
    config.gaze == GazeMode::Gazelight && unsafe { enables(info, EYE_GAZE_EXT) }
}

/// Whether `info` enables extension `name`.
///
/// # Safety
/// `info` is null or a valid `XrInstanceCreateInfo`.
pub unsafe fn enables(info: *const xr::InstanceCreateInfo, name: &CStr) -> bool {
    if info.is_null() {
        return false;
    }
    // SAFETY: checked non-null; the app owns it for the call.
    let info = unsafe { &*info };
    if info.enabled_extension_names.is_null() {
        return false;
    }
    (0..info.enabled_extension_count as usize).any(|i| {
        // SAFETY: an array of `enabled_extension_count` C strings.
        let p = unsafe { *info.enabled_extension_names.add(i) };
        // SAFETY: non-null entries are NUL-terminated names.
        !p.is_null() && unsafe { CStr::from_ptr(p) } == name
    })
}

/// Looks up the next layer's functions and starts the live eye task on the
/// config's source; from then on the instance's gaze is served. On error
/// nothing is served (the app sees the runtime's own eye gaze support).
pub fn start(
    instance: xr::Instance,
    next_gipa: pfn::GetInstanceProcAddr,
    config: &LayerConfig,
    serve_gaze: bool,
) -> Result<(), String> {
    // SAFETY: `next_gipa` is the next layer's `xrGetInstanceProcAddr` and
    // `instance` the instance it just created (lib.rs `create_next`).
    let next = unsafe { resolve(instance, next_gipa) }?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_name("gazelight-layer-eye")
        .enable_all()
        .build()
        .map_err(|e| format!("tokio runtime: {e}"))?;
    let uri = config.source.to_string();
    let chain = FilterChain::new(config.filter, PupilCalibration::identity())
        .map_err(|e| format!("filter: {e}"))?;
    let (shutdown, shutdown_rx) = watch::channel(false);
    let live = {
        let _in = runtime.enter();
        transport::open_live(
            &uri,
            &config.source,
            &OpenOptions::default(),
            chain,
            shutdown_rx,
            LiveConfig::default(),
        )
        .map_err(|e| format!("{e}: {}", e.source))?
    };
    if serve_gaze {
        log(
            "info",
            &format!(
                "eye gaze: XR_EXT_eye_gaze_interaction served from {}",
                live.describe
            ),
        );
    } else {
        log(
            "info",
            &format!("eye state for the frame effects from {}", live.describe),
        );
    }
    let mono_minus_host_secs = monotonic_now_secs()
        .map(|m| m - host_now_secs())
        .ok_or("clock_gettime(CLOCK_MONOTONIC) failed")?;
    let old = served().replace(Served {
        instance,
        serve_gaze,
        next,
        eye: live.eye,
        mono_minus_host_secs,
        shutdown,
        runtime: Some(runtime),
        actions: HashSet::new(),
        spaces: HashMap::new(),
        view_spaces: HashMap::new(),
    });
    drop_served(old);
    Ok(())
}

/// Stops the service of `instance` (at `xrDestroyInstance`).
pub fn stop(instance: xr::Instance) {
    let old = {
        let mut s = served();
        if s.as_ref().is_some_and(|s| s.instance == instance) {
            s.take()
        } else {
            None
        }
    };
    drop_served(old);
}

fn drop_served(old: Option<Served>) {
    if let Some(mut old) = old {
        let _ = old.shutdown.send(true);
        if let Some(rt) = old.runtime.take() {
            rt.shutdown_background();
        }
    }
}

/// The next layer's functions the gaze service calls, looked up by name.
///
/// # Safety
/// `gipa` is the next layer's `xrGetInstanceProcAddr` and `instance` a live
/// instance it created.
unsafe fn resolve(instance: xr::Instance, gipa: pfn::GetInstanceProcAddr) -> Result<Next, String> {
    let get = |name: &CStr| -> Result<pfn::VoidFunction, String> {
        let mut f: Option<pfn::VoidFunction> = None;
        // SAFETY: the next layer's gipa on its own instance.
        let r = unsafe { gipa(instance, name.as_ptr(), &mut f) };
        match f {
            Some(f) if r.into_raw() >= 0 => Ok(f),
            _ => Err(format!("the next layer has no {}", name.to_string_lossy())),
        }
    };
    // SAFETY: (all transmutes) the pointer the next layer returned for this
    // name has that function's signature.
    unsafe {
        use std::mem::transmute as t;
        Ok(Next {
            get_system_properties: t::<pfn::VoidFunction, pfn::GetSystemProperties>(get(
                c"xrGetSystemProperties",
            )?),
            suggest: t::<pfn::VoidFunction, pfn::SuggestInteractionProfileBindings>(get(
                c"xrSuggestInteractionProfileBindings",
            )?),
            path_to_string: t::<pfn::VoidFunction, pfn::PathToString>(get(c"xrPathToString")?),
            create_action_space: t::<pfn::VoidFunction, pfn::CreateActionSpace>(get(
                c"xrCreateActionSpace",
            )?),
            create_reference_space: t::<pfn::VoidFunction, pfn::CreateReferenceSpace>(get(
                c"xrCreateReferenceSpace",
            )?),
            destroy_space: t::<pfn::VoidFunction, pfn::DestroySpace>(get(c"xrDestroySpace")?),
            destroy_session: t::<pfn::VoidFunction, pfn::DestroySession>(get(c"xrDestroySession")?),
            locate_space: t::<pfn::VoidFunction, pfn::LocateSpace>(get(c"xrLocateSpace")?),
            locate_views: t::<pfn::VoidFunction, pfn::LocateViews>(get(c"xrLocateViews")?),
            get_action_state_pose: t::<pfn::VoidFunction, pfn::GetActionStatePose>(get(
                c"xrGetActionStatePose",
            )?),
            timespec_to_time: t::<pfn::VoidFunction, pfn::ConvertTimespecTimeToTimeKHR>(get(
                c"xrConvertTimespecTimeToTimeKHR",
            )?),
        })
    }
}

/// The layer's own function for `name` when it serves gaze for `instance`.
pub fn proc_addr(instance: xr::Instance, name: &CStr) -> Option<pfn::VoidFunction> {
    if !served()
        .as_ref()
        .is_some_and(|s| s.instance == instance && s.serve_gaze)
    {
        return None;
    }
    // SAFETY: (all transmutes) function pointers to VoidFunction, the
    // loader's type-erased slot; the app casts them back by name.
    unsafe {
        use std::mem::transmute as t;
        Some(match name.to_bytes() {
            b"xrGetSystemProperties" => {
                t::<pfn::GetSystemProperties, pfn::VoidFunction>(get_system_properties)
            }
            b"xrSuggestInteractionProfileBindings" => {
                t::<pfn::SuggestInteractionProfileBindings, pfn::VoidFunction>(suggest)
            }
            b"xrCreateActionSpace" => {
                t::<pfn::CreateActionSpace, pfn::VoidFunction>(create_action_space)
            }
            b"xrDestroySpace" => t::<pfn::DestroySpace, pfn::VoidFunction>(destroy_space),
            b"xrDestroySession" => t::<pfn::DestroySession, pfn::VoidFunction>(destroy_session),
            b"xrLocateSpace" => t::<pfn::LocateSpace, pfn::VoidFunction>(locate_space),
            b"xrGetActionStatePose" => {
                t::<pfn::GetActionStatePose, pfn::VoidFunction>(get_action_state_pose)
            }
            _ => return None,
        })
    }
}

/// The newest eye state of `instance`'s eye task and the offset
/// `CLOCK_MONOTONIC` − host clock (s), when the task runs.
pub fn eye_snapshot(instance: xr::Instance) -> Option<(LiveEyeState, f64)> {
    let s = served();
    let s = s.as_ref().filter(|s| s.instance == instance)?;
    Some((*s.eye.borrow(), s.mono_minus_host_secs))
}

/// Forgets the gaze spaces and VIEW space of `session` (the frame path's
/// `xrDestroySession` calls this when it is the one installed).
pub fn forget_session(session: xr::Session) {
    if let Some(s) = served().as_mut() {
        s.view_spaces.remove(&session.into_raw());
        s.spaces.retain(|_, g| g.session != session);
    }
}

fn next() -> Option<Next> {
    served().as_ref().map(|s| s.next)
}

/// Runs `main` under the panic guard; the fallback (and the answer when no
/// service is running) is `forward` with the next layer's functions.
fn with_next(
    name: &'static str,
    forward: impl Fn(&Next) -> xr::Result,
    main: impl FnOnce(&Next) -> xr::Result,
) -> xr::Result {
    let Some(n) = next() else {
        return xr::Result::ERROR_HANDLE_INVALID;
    };
    guard::guarded(name, || forward(&n), || main(&n))
}

/// `xrGetSystemProperties`: the runtime's answer, with eye gaze
/// interaction marked supported.
///
/// # Safety
/// Called as `xrGetSystemProperties`: `properties` null or a valid output
/// structure whose `next` chain is the app's valid output structures.
unsafe extern "system" fn get_system_properties(
    instance: xr::Instance,
    system_id: xr::SystemId,
    properties: *mut xr::SystemProperties,
) -> xr::Result {
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = |n: &Next| unsafe { (n.get_system_properties)(instance, system_id, properties) };
    with_next("xrGetSystemProperties", forward, |n| {
        let r = forward(n);
        if r.into_raw() < 0 || properties.is_null() || guard::pass_through() {
            return r;
        }
        // SAFETY: the app's chain of output structures, each starting with
        // (type, next).
        let mut p = unsafe { (*properties).next } as *mut xr::BaseOutStructure;
        while !p.is_null() {
            // SAFETY: non-null, a structure of the app's chain (type, next).
            let base = unsafe { &mut *p };
            if base.ty == xr::SystemEyeGazeInteractionPropertiesEXT::TYPE {
                let props = p as *mut xr::SystemEyeGazeInteractionPropertiesEXT;
                // SAFETY: its type says it is this structure.
                unsafe { (*props).supports_eye_gaze_interaction = xr::TRUE };
            }
            p = base.next;
        }
        r
    })
}

/// The string of `path` (at most 255 bytes), through `xrPathToString`.
///
/// # Safety
/// `n` holds the next layer's functions for `instance`, a live instance.
unsafe fn path_string(n: &Next, instance: xr::Instance, path: xr::Path) -> Option<String> {
    let mut buf = [0 as c_char; 256];
    let mut len = 0u32;
    // SAFETY: a buffer of the capacity given.
    let r =
        unsafe { (n.path_to_string)(instance, path, buf.len() as u32, &mut len, buf.as_mut_ptr()) };
    if r.into_raw() < 0 {
        return None;
    }
    // SAFETY: the runtime wrote a NUL-terminated string into `buf`.
    Some(
        unsafe { CStr::from_ptr(buf.as_ptr()) }
            .to_string_lossy()
            .into_owned(),
    )
}

/// `xrSuggestInteractionProfileBindings`: notes the app's gaze actions and
/// accepts the eye gaze profile when the runtime refuses it.
///
/// # Safety
/// Called as `xrSuggestInteractionProfileBindings`: `suggested` null or
/// valid, its bindings an array of `count_suggested_bindings`.
unsafe extern "system" fn suggest(
    instance: xr::Instance,
    suggested: *const xr::InteractionProfileSuggestedBinding,
) -> xr::Result {
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = |n: &Next| unsafe { (n.suggest)(instance, suggested) };
    with_next("xrSuggestInteractionProfileBindings", forward, |n| {
        let r = forward(n);
        if suggested.is_null() || guard::pass_through() {
            return r;
        }
        // SAFETY: non-null; the app's structure for this call.
        let s = unsafe { &*suggested };
        // SAFETY: `n` is the next layer's table for the app's instance.
        if unsafe { path_string(n, instance, s.interaction_profile) }.as_deref() != Some(PROFILE) {
            return r;
        }
        let mut gaze_actions = Vec::new();
        if !s.suggested_bindings.is_null() {
            for i in 0..s.count_suggested_bindings as usize {
                // SAFETY: an array of `count_suggested_bindings`.
                let b = unsafe { *s.suggested_bindings.add(i) };
                // SAFETY: as above.
                let path = unsafe { path_string(n, instance, b.binding) };
                if path.as_deref().is_some_and(|p| GAZE_POSE.contains(&p)) {
                    gaze_actions.push(b.action.into_raw());
                }
            }
        }
        if let Some(s) = served().as_mut() {
            s.actions.extend(gaze_actions);
        }
        if r.into_raw() < 0 {
            log(
                "info",
                &format!(
                    "eye gaze: the runtime refused the eye gaze profile ({r:?}); the layer serves it"
                ),
            );
            return xr::Result::SUCCESS;
        }
        r
    })
}

/// `xrCreateActionSpace`: notes the spaces of the app's gaze actions.
///
/// # Safety
/// Called as `xrCreateActionSpace`: `info` null or valid, `space` null or
/// writable.
unsafe extern "system" fn create_action_space(
    session: xr::Session,
    info: *const xr::ActionSpaceCreateInfo,
    space: *mut xr::Space,
) -> xr::Result {
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = |n: &Next| unsafe { (n.create_action_space)(session, info, space) };
    with_next("xrCreateActionSpace", forward, |n| {
        let r = forward(n);
        if r.into_raw() < 0 || info.is_null() || space.is_null() {
            return r;
        }
        // SAFETY: non-null; the app's info; the runtime wrote the space.
        let (info, created) = unsafe { (&*info, *space) };
        let mut s = served();
        if let Some(s) = s.as_mut()
            && s.actions.contains(&info.action.into_raw())
        {
            s.spaces.insert(
                created.into_raw(),
                GazeSpace {
                    session,
                    pose_in_action: info.pose_in_action_space,
                },
            );
        }
        r
    })
}

/// `xrDestroySpace`: forgets a gaze space.
///
/// # Safety
/// Called as `xrDestroySpace` (handles only, no pointers).
unsafe extern "system" fn destroy_space(space: xr::Space) -> xr::Result {
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = |n: &Next| unsafe { (n.destroy_space)(space) };
    with_next("xrDestroySpace", forward, |n| {
        if let Some(s) = served().as_mut() {
            s.spaces.remove(&space.into_raw());
        }
        forward(n)
    })
}

/// Forgets the session's gaze spaces and the layer's VIEW space (the
/// runtime destroys a session's spaces with it).
///
/// # Safety
/// Called as `xrDestroySession` (a handle only, no pointers).
unsafe extern "system" fn destroy_session(session: xr::Session) -> xr::Result {
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = |n: &Next| unsafe { (n.destroy_session)(session) };
    with_next("xrDestroySession", forward, |n| {
        forget_session(session);
        forward(n)
    })
}

/// `xrGetActionStatePose`: a gaze action is active while served.
///
/// # Safety
/// Called as `xrGetActionStatePose`: `get_info` null or valid, `state` null
/// or writable.
unsafe extern "system" fn get_action_state_pose(
    session: xr::Session,
    get_info: *const xr::ActionStateGetInfo,
    state: *mut xr::ActionStatePose,
) -> xr::Result {
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = |n: &Next| unsafe { (n.get_action_state_pose)(session, get_info, state) };
    with_next("xrGetActionStatePose", forward, |n| {
        let r = forward(n);
        if r.into_raw() < 0 || get_info.is_null() || state.is_null() || guard::pass_through() {
            return r;
        }
        // SAFETY: non-null; the app's structures for this call.
        let action = unsafe { (*get_info).action };
        if served()
            .as_ref()
            .is_some_and(|s| s.actions.contains(&action.into_raw()))
        {
            // SAFETY: `state` checked non-null, the app's for this call.
            unsafe { (*state).is_active = xr::TRUE };
        }
        r
    })
}

/// What `xrLocateSpace` of a gaze space needs, copied out of the lock.
struct LocateJob {
    gaze: GazeSpace,
    view_space: Option<xr::Space>,
    state: LiveEyeState,
    instance: xr::Instance,
    mono_minus_host_secs: f64,
}

/// `xrLocateSpace`: a gaze space is located from the newest eye state.
///
/// # Safety
/// Called as `xrLocateSpace`: `location` null or a writable
/// `XrSpaceLocation` whose `next` chain is the app's valid output
/// structures.
unsafe extern "system" fn locate_space(
    space: xr::Space,
    base_space: xr::Space,
    time: xr::Time,
    location: *mut xr::SpaceLocation,
) -> xr::Result {
    // SAFETY: the app's arguments, handed to the next layer unchanged.
    let forward = |n: &Next| unsafe { (n.locate_space)(space, base_space, time, location) };
    with_next("xrLocateSpace", forward, |n| {
        if guard::pass_through() || location.is_null() {
            return forward(n);
        }
        let job = {
            let s = served();
            let Some(s) = s.as_ref() else {
                return forward(n);
            };
            let Some(gaze) = s.spaces.get(&space.into_raw()).copied() else {
                return forward(n);
            };
            LocateJob {
                gaze,
                view_space: s.view_spaces.get(&gaze.session.into_raw()).copied(),
                state: *s.eye.borrow(),
                instance: s.instance,
                mono_minus_host_secs: s.mono_minus_host_secs,
            }
        };
        let view_space = match job.view_space {
            Some(v) => v,
            // SAFETY: `n` is the next layer's table; the session is the
            // app's (a gaze space of it is being located).
            None => match unsafe { create_view_space(n, job.gaze.session) } {
                Some(v) => v,
                None => return forward(n),
            },
        };
        // SAFETY: `location` checked non-null; the app's for this call.
        unsafe { locate_gaze(n, &job, view_space, base_space, time, location) }
    })
}

/// Creates (and keeps, per session) the layer's own VIEW reference space.
///
/// # Safety
/// `n` is the next layer's table; `session` a live session of its instance.
unsafe fn create_view_space(n: &Next, session: xr::Session) -> Option<xr::Space> {
    let info = xr::ReferenceSpaceCreateInfo {
        ty: xr::ReferenceSpaceCreateInfo::TYPE,
        next: std::ptr::null(),
        reference_space_type: xr::ReferenceSpaceType::VIEW,
        pose_in_reference_space: IDENTITY,
    };
    let mut space = xr::Space::NULL;
    // SAFETY: a valid info and out-pointer.
    let r = unsafe { (n.create_reference_space)(session, &info, &mut space) };
    if r.into_raw() < 0 {
        log(
            "warn",
            &format!("eye gaze: cannot create a VIEW space: {r:?}"),
        );
        return None;
    }
    if let Some(s) = served().as_mut() {
        s.view_spaces.insert(session.into_raw(), space);
    }
    Some(space)
}

/// The identity pose.
pub(crate) const IDENTITY: xr::Posef = xr::Posef {
    orientation: xr::Quaternionf {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        w: 1.0,
    },
    position: xr::Vector3f {
        x: 0.0,
        y: 0.0,
        z: 0.0,
    },
};

/// Whether a state gives a tracked gaze at host time `now_secs`.
pub fn tracked(state: &EyeState, now_secs: f64) -> bool {
    state.gaze_valid
        && !state.blink
        && state.gaze_uv.iter().all(|x| x.is_finite())
        && state.age_secs(now_secs) <= STALE_SECS
}

/// Writes the gaze pose (in `base_space` at `time`) into `location`, and
/// the sample's time into an `XrEyeGazeSampleTimeEXT` in its chain.
///
/// # Safety
/// `location` is non-null and writable, its `next` chain the app's valid
/// output structures; `n` is the next layer's table, the spaces live.
unsafe fn locate_gaze(
    n: &Next,
    job: &LocateJob,
    view_space: xr::Space,
    base_space: xr::Space,
    time: xr::Time,
    location: *mut xr::SpaceLocation,
) -> xr::Result {
    // SAFETY: non-null (checked by the caller); the app's structure.
    let loc = unsafe { &mut *location };
    let mut view_in_base = xr::SpaceLocation {
        ty: xr::SpaceLocation::TYPE,
        next: std::ptr::null_mut(),
        location_flags: xr::SpaceLocationFlags::EMPTY,
        pose: IDENTITY,
    };
    // SAFETY: the app's spaces and time; our own location.
    let r = unsafe { (n.locate_space)(view_space, base_space, time, &mut view_in_base) };
    if r.into_raw() < 0 {
        return r;
    }
    loc.location_flags = xr::SpaceLocationFlags::EMPTY;
    let state = &job.state.state;
    if !tracked(state, host_now_secs()) {
        return r;
    }
    let Some(gaze_in_view) =
        // SAFETY: the next layer's table; the app's session, the layer's
        // own VIEW space of it.
        (unsafe { gaze_in_view(n, job.gaze.session, view_space, time, state) })
    else {
        return r;
    };
    let pose = compose(
        &view_in_base.pose,
        &compose(&gaze_in_view, &job.gaze.pose_in_action),
    );
    loc.pose = pose;
    let f = view_in_base.location_flags;
    let mut flags = xr::SpaceLocationFlags::EMPTY;
    if f.contains(xr::SpaceLocationFlags::ORIENTATION_VALID) {
        flags |=
            xr::SpaceLocationFlags::ORIENTATION_VALID | xr::SpaceLocationFlags::ORIENTATION_TRACKED;
    }
    if f.contains(xr::SpaceLocationFlags::POSITION_VALID) {
        flags |= xr::SpaceLocationFlags::POSITION_VALID;
    }
    if f.contains(xr::SpaceLocationFlags::POSITION_TRACKED) {
        flags |= xr::SpaceLocationFlags::POSITION_TRACKED;
    }
    loc.location_flags = flags;
    // The newest sample arrived before now: a time after now is the error of
    // the source's clock offset estimate (about 1 ms for Pupil's), clamped.
    let sample_mono = state.t_secs + job.mono_minus_host_secs;
    let sample_mono = monotonic_now_secs().map_or(sample_mono, |now| sample_mono.min(now));
    // SAFETY: the next layer's table for the served instance.
    let sample_time = unsafe { host_to_xr_time(n, job.instance, sample_mono) };
    // The app's chain of output structures, each starting with (type, next).
    let mut p = loc.next as *mut xr::BaseOutStructure;
    while !p.is_null() {
        // SAFETY: non-null, a structure of the app's chain.
        let base = unsafe { &mut *p };
        if base.ty == xr::EyeGazeSampleTimeEXT::TYPE {
            let st = p as *mut xr::EyeGazeSampleTimeEXT;
            // SAFETY: its type says it is this structure.
            unsafe { (*st).time = sample_time.unwrap_or(xr::Time::from_nanos(0)) };
        }
        p = base.next;
    }
    r
}

/// The gaze pose in VIEW space: origin the mean of the views' positions,
/// forward (−Z) the mean of the rays through `gaze_uv` in each view.
///
/// # Safety
/// `n` is the next layer's table; `session` and `view_space` live handles.
unsafe fn gaze_in_view(
    n: &Next,
    session: xr::Session,
    view_space: xr::Space,
    time: xr::Time,
    state: &EyeState,
) -> Option<xr::Posef> {
    // SAFETY: the next layer's xrLocateViews on the app's session and space.
    let (views, count, _) =
        unsafe { locate_stereo_views(n.locate_views, session, view_space, time) }?;
    gaze_pose_in_view(&views[..count], state.gaze_uv)
}

/// The primary stereo views in `space` at `time` through the next layer's
/// `locate_views`: the views, how many were written (≥ 1), the view state
/// flags; `None` when the call fails or writes none.
///
/// # Safety
/// `locate_views` is the next layer's `xrLocateViews`; `session` and
/// `space` are the app's live handles.
pub(crate) unsafe fn locate_stereo_views(
    locate_views: pfn::LocateViews,
    session: xr::Session,
    space: xr::Space,
    time: xr::Time,
) -> Option<([xr::View; 2], usize, xr::ViewStateFlags)> {
    let info = xr::ViewLocateInfo {
        ty: xr::ViewLocateInfo::TYPE,
        next: std::ptr::null(),
        view_configuration_type: xr::ViewConfigurationType::PRIMARY_STEREO,
        display_time: time,
        space,
    };
    let mut vs = xr::ViewState {
        ty: xr::ViewState::TYPE,
        next: std::ptr::null_mut(),
        view_state_flags: xr::ViewStateFlags::EMPTY,
    };
    let empty = xr::View {
        ty: xr::View::TYPE,
        next: std::ptr::null_mut(),
        pose: IDENTITY,
        fov: xr::Fovf {
            angle_left: 0.0,
            angle_right: 0.0,
            angle_up: 0.0,
            angle_down: 0.0,
        },
    };
    let mut views = [empty; 2];
    let mut count = 0u32;
    // SAFETY: valid info, state and a 2-view array.
    let r = unsafe { locate_views(session, &info, &mut vs, 2, &mut count, views.as_mut_ptr()) };
    (r.into_raw() >= 0 && count > 0).then(|| (views, (count as usize).min(2), vs.view_state_flags))
}

/// The binocular gaze pose from `views` (poses and fields of view in VIEW
/// space) and a gaze at normalised image coordinates `gaze_uv` (top-left
/// origin): origin the mean of the views' positions, forward (−Z) the mean
/// of the unit rays through `gaze_uv` in each view. `None` without views or
/// for a degenerate direction.
pub fn gaze_pose_in_view(views: &[xr::View], gaze_uv: [f32; 2]) -> Option<xr::Posef> {
    if views.is_empty() {
        return None;
    }
    let [u, v] = gaze_uv.map(f64::from);
    let mut dir = [0.0f64; 3];
    let mut pos = [0.0f64; 3];
    for view in views {
        let fov = view.fov;
        let (tl, tr) = (
            f64::from(fov.angle_left).tan(),
            f64::from(fov.angle_right).tan(),
        );
        let (tu, td) = (
            f64::from(fov.angle_up).tan(),
            f64::from(fov.angle_down).tan(),
        );
        let d = normalize([tl + u * (tr - tl), tu - v * (tu - td), -1.0]);
        let d = rotate(&view.pose.orientation, d);
        for (acc, x) in dir.iter_mut().zip(d) {
            *acc += x;
        }
        let p = &view.pose.position;
        for (k, x) in [p.x, p.y, p.z].into_iter().enumerate() {
            pos[k] += f64::from(x) / views.len() as f64;
        }
    }
    let d = normalize(dir);
    if !d.iter().all(|x| x.is_finite()) || d[2] >= 1.0 - 1e-9 {
        return None;
    }
    // Shortest arc from −Z to d: axis (−Z × d) = (d_y, −d_x, 0), w = 1 − d_z.
    let q = normalize4([d[1], -d[0], 0.0, 1.0 - d[2]]);
    Some(xr::Posef {
        orientation: xr::Quaternionf {
            x: q[0] as f32,
            y: q[1] as f32,
            z: q[2] as f32,
            w: q[3] as f32,
        },
        position: xr::Vector3f {
            x: pos[0] as f32,
            y: pos[1] as f32,
            z: pos[2] as f32,
        },
    })
}

/// Where a gaze lands in the view the app submitted.
///
/// The tracker's `gaze_uv` (normalised image coordinates, top-left origin)
/// is in the eye's nominal view, `nominal` (its pose and field of view in
/// VIEW space, from `xrLocateViews`); the app submitted the frame with its
/// own `submitted` pose and `submitted_fov`, in a space where VIEW is at
/// `head`. The gaze ray (a direction: the fixated point is taken as far)
/// is carried from the nominal view through VIEW into that space and
/// projected through the submitted view. With the submitted view equal to
/// the nominal one, `gaze_uv` comes back. `None` when the ray points away
/// from the submitted view's image plane or an input is degenerate.
pub fn gaze_uv_in_submitted_view(
    gaze_uv: [f32; 2],
    nominal: &xr::View,
    head: &xr::Posef,
    submitted: &xr::Posef,
    submitted_fov: &xr::Fovf,
) -> Option<[f32; 2]> {
    let [u, v] = gaze_uv.map(f64::from);
    let t = |f: &xr::Fovf| {
        [f.angle_left, f.angle_right, f.angle_up, f.angle_down].map(|a| f64::from(a).tan())
    };
    let [tl, tr, tu, td] = t(&nominal.fov);
    let d = [tl + u * (tr - tl), tu - v * (tu - td), -1.0];
    let d = rotate(&head.orientation, rotate(&nominal.pose.orientation, d));
    let q = &submitted.orientation;
    let inverse = xr::Quaternionf {
        x: -q.x,
        y: -q.y,
        z: -q.z,
        w: q.w,
    };
    let d = rotate(&inverse, d);
    let [sl, sr, su, sd] = t(submitted_fov);
    if d[2].is_nan() || d[2] >= -1e-9 || !(sr - sl).is_normal() || !(su - sd).is_normal() {
        return None;
    }
    let (x, y) = (d[0] / -d[2], d[1] / -d[2]);
    let uv = [(x - sl) / (sr - sl), (su - y) / (su - sd)];
    uv.iter()
        .all(|c| c.is_finite())
        .then(|| uv.map(|c| c as f32))
}

/// `CLOCK_MONOTONIC` seconds → `XrTime` through
/// `xrConvertTimespecTimeToTimeKHR`.
///
/// # Safety
/// `n` is the next layer's table for `instance`, a live instance with
/// `XR_KHR_convert_timespec_time` enabled.
unsafe fn host_to_xr_time(n: &Next, instance: xr::Instance, mono: f64) -> Option<xr::Time> {
    if !mono.is_finite() || mono < 0.0 {
        return None;
    }
    let ts = libc::timespec {
        tv_sec: mono.floor() as libc::time_t,
        tv_nsec: ((mono - mono.floor()) * 1e9) as libc::c_long,
    };
    let mut t = xr::Time::from_nanos(0);
    // SAFETY: a valid timespec and out-pointer.
    let r = unsafe { (n.timespec_to_time)(instance, &ts, &mut t) };
    (r.into_raw() >= 0).then_some(t)
}

pub fn monotonic_now_secs() -> Option<f64> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: an out-pointer to a timespec.
    let r = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    (r == 0).then_some(ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9)
}

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|x| x / l)
}

fn normalize4(v: [f64; 4]) -> [f64; 4] {
    let l = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    v.map(|x| x / l)
}

fn quat(q: &xr::Quaternionf) -> [f64; 4] {
    [q.x, q.y, q.z, q.w].map(f64::from)
}

fn rotate(q: &xr::Quaternionf, v: [f64; 3]) -> [f64; 3] {
    let [x, y, z, w] = quat(q);
    // v' = v + 2w(u × v) + 2 u × (u × v), u = (x, y, z).
    let c = [
        y * v[2] - z * v[1],
        z * v[0] - x * v[2],
        x * v[1] - y * v[0],
    ];
    let cc = [
        y * c[2] - z * c[1],
        z * c[0] - x * c[2],
        x * c[1] - y * c[0],
    ];
    [0, 1, 2].map(|k| v[k] + 2.0 * w * c[k] + 2.0 * cc[k])
}

/// `a ∘ b`: pose `b` given in `a`'s frame, expressed in `a`'s parent.
fn compose(a: &xr::Posef, b: &xr::Posef) -> xr::Posef {
    let [ax, ay, az, aw] = quat(&a.orientation);
    let [bx, by, bz, bw] = quat(&b.orientation);
    let q = normalize4([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]);
    let bp = &b.position;
    let p = rotate(&a.orientation, [bp.x, bp.y, bp.z].map(f64::from));
    let ap = &a.position;
    xr::Posef {
        orientation: xr::Quaternionf {
            x: q[0] as f32,
            y: q[1] as f32,
            z: q[2] as f32,
            w: q[3] as f32,
        },
        position: xr::Vector3f {
            x: (f64::from(ap.x) + p[0]) as f32,
            y: (f64::from(ap.y) + p[1]) as f32,
            z: (f64::from(ap.z) + p[2]) as f32,
        },
    }
}

#[cfg(test)]
#[allow(clippy::expect_used)]
mod tests {
    use super::*;

    fn view(x_m: f32, half_deg: f32) -> xr::View {
        let a = half_deg.to_radians();
        xr::View {
            ty: xr::View::TYPE,
            next: std::ptr::null_mut(),
            pose: xr::Posef {
                position: xr::Vector3f {
                    x: x_m,
                    y: 0.0,
                    z: 0.0,
                },
                ..IDENTITY
            },
            fov: xr::Fovf {
                angle_left: -a,
                angle_right: a,
                angle_up: a,
                angle_down: -a,
            },
        }
    }

    fn forward(p: &xr::Posef) -> [f64; 3] {
        rotate(&p.orientation, [0.0, 0.0, -1.0])
    }

    fn close(a: [f64; 3], b: [f64; 3]) -> bool {
        (0..3).all(|k| (a[k] - b[k]).abs() < 1e-6)
    }

    /// A rotation of `deg` about +Y (a yaw to the left, OpenXR's
    /// right-handed, Y-up frame).
    fn yaw(deg: f64) -> xr::Quaternionf {
        let h = deg.to_radians() / 2.0;
        xr::Quaternionf {
            x: 0.0,
            y: h.sin() as f32,
            z: 0.0,
            w: h.cos() as f32,
        }
    }

    fn pose(q: xr::Quaternionf) -> xr::Posef {
        xr::Posef {
            orientation: q,
            position: xr::Vector3f {
                x: 0.0,
                y: 0.0,
                z: 0.0,
            },
        }
    }

    fn fov_deg(l: f64, r: f64, u: f64, d: f64) -> xr::Fovf {
        let a = |x: f64| x.to_radians() as f32;
        xr::Fovf {
            angle_left: a(l),
            angle_right: a(r),
            angle_up: a(u),
            angle_down: a(d),
        }
    }

    fn near(a: [f32; 2], b: [f64; 2]) -> bool {
        (f64::from(a[0]) - b[0]).abs() < 1e-5 && (f64::from(a[1]) - b[1]).abs() < 1e-5
    }

    #[test]
    fn a_submitted_view_equal_to_the_nominal_one_keeps_the_gaze() {
        // An asymmetric field (a canted left eye), the eye 32 mm left and
        // turned 5° out, the head turned 30° in the layer's space, the
        // app's view where the runtime put it.
        let mut nominal = view(-0.032, 45.0);
        nominal.fov = fov_deg(-52.0, 41.0, 44.0, -49.0);
        nominal.pose.orientation = yaw(5.0);
        let head = pose(yaw(30.0));
        let submitted = compose(&head, &nominal.pose);
        for uv in [[0.5, 0.5], [0.1, 0.9], [0.83, 0.27], [0.0, 1.0]] {
            let got = gaze_uv_in_submitted_view(uv, &nominal, &head, &submitted, &nominal.fov)
                .expect("in view");
            assert!(near(got, uv.map(f64::from)), "{uv:?} -> {got:?}");
        }
    }

    #[test]
    fn a_view_submitted_turned_10_degrees_left_sees_the_gaze_10_degrees_right() {
        // Symmetric 90° field: a direction θ right of the view's axis lands
        // at u = (1 + tan θ) / 2.
        let nominal = view(0.0, 45.0);
        let head = pose(yaw(0.0));
        let submitted = pose(yaw(10.0));
        let got = gaze_uv_in_submitted_view([0.5, 0.5], &nominal, &head, &submitted, &nominal.fov)
            .expect("in view");
        let want = (1.0 + 10f64.to_radians().tan()) / 2.0;
        assert!(near(got, [want, 0.5]), "{got:?}, want u {want}");
        // The head turned with it (the app rendered the head's newer
        // pose): the gaze stays at the centre.
        let got = gaze_uv_in_submitted_view(
            [0.5, 0.5],
            &nominal,
            &pose(yaw(10.0)),
            &submitted,
            &nominal.fov,
        )
        .expect("in view");
        assert!(near(got, [0.5, 0.5]), "{got:?}");
    }

    #[test]
    fn a_wider_submitted_field_pulls_the_gaze_towards_the_centre() {
        // The gaze at the nominal right edge (45°), the app's view ±50°
        // wide and ±40° high: u = (tan 45° + tan 50°) / (2 tan 50°); the
        // gaze 30° up (v for a ±45° nominal field: (1 − tan 30°) / 2) lands
        // at v = (tan 40° − tan 30°) / (2 tan 40°).
        let nominal = view(0.0, 45.0);
        let v30 = (1.0 - 30f64.to_radians().tan()) / 2.0;
        let wide = fov_deg(-50.0, 50.0, 40.0, -40.0);
        let got = gaze_uv_in_submitted_view(
            [1.0, v30 as f32],
            &nominal,
            &pose(yaw(0.0)),
            &pose(yaw(0.0)),
            &wide,
        )
        .expect("in view");
        let (t45, t50, t30, t40) = (
            1.0f64,
            50f64.to_radians().tan(),
            30f64.to_radians().tan(),
            40f64.to_radians().tan(),
        );
        assert!(
            near(got, [(t45 + t50) / (2.0 * t50), (t40 - t30) / (2.0 * t40)]),
            "{got:?}"
        );
    }

    #[test]
    fn a_gaze_behind_the_submitted_view_has_no_place_in_it() {
        let nominal = view(0.0, 45.0);
        let got = gaze_uv_in_submitted_view(
            [0.5, 0.5],
            &nominal,
            &pose(yaw(0.0)),
            &pose(yaw(180.0)),
            &nominal.fov,
        );
        assert_eq!(got, None);
    }

    #[test]
    fn the_centre_is_straight_ahead_between_the_eyes() {
        let views = [view(-0.032, 45.0), view(0.032, 45.0)];
        let p = gaze_pose_in_view(&views, [0.5, 0.5]).expect("a pose");
        assert!(close(forward(&p), [0.0, 0.0, -1.0]), "{:?}", forward(&p));
        assert!(p.position.x.abs() < 1e-7);
    }

    #[test]
    fn the_right_edge_of_a_90_degree_field_is_45_degrees_right() {
        // tan 45° = 1: the ray (1, 0, -1)/√2.
        let views = [view(-0.032, 45.0), view(0.032, 45.0)];
        let p = gaze_pose_in_view(&views, [1.0, 0.5]).expect("a pose");
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!(close(forward(&p), [h, 0.0, -h]), "{:?}", forward(&p));
        // Top-left origin: v = 0 is up.
        let p = gaze_pose_in_view(&views, [0.5, 0.0]).expect("a pose");
        assert!(close(forward(&p), [0.0, h, -h]), "{:?}", forward(&p));
    }

    #[test]
    fn compose_applies_the_parent_rotation_to_the_child_offset() {
        // 90° about +Y maps -Z to -X.
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let a = xr::Posef {
            orientation: xr::Quaternionf {
                x: 0.0,
                y: s,
                z: 0.0,
                w: s,
            },
            position: xr::Vector3f {
                x: 1.0,
                y: 2.0,
                z: 3.0,
            },
        };
        let b = xr::Posef {
            position: xr::Vector3f {
                x: 0.0,
                y: 0.0,
                z: -1.0,
            },
            ..IDENTITY
        };
        let c = compose(&a, &b);
        let p = [c.position.x, c.position.y, c.position.z].map(f64::from);
        assert!(close(p, [0.0, 2.0, 3.0]), "{p:?}");
        assert!(close(forward(&c), [-1.0, 0.0, 0.0]), "{:?}", forward(&c));
    }

    #[test]
    fn blinks_dropouts_and_invalid_gaze_are_not_tracked() {
        let good = EyeState {
            t_secs: 10.0,
            gaze_uv: [0.3, 0.2],
            gaze_valid: true,
            ..EyeState::default()
        };
        assert!(tracked(&good, 10.05));
        assert!(!tracked(
            &EyeState {
                blink: true,
                ..good
            },
            10.05
        ));
        assert!(!tracked(
            &EyeState {
                gaze_valid: false,
                ..good
            },
            10.05
        ));
        assert!(!tracked(&good, 10.0 + STALE_SECS + 0.01));
        assert!(!tracked(
            &EyeState {
                gaze_uv: [f32::NAN, 0.2],
                ..good
            },
            10.05
        ));
    }
}
