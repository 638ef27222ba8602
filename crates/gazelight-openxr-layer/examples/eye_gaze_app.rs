//! A small OpenXR app that reads eye gaze through `XR_EXT_eye_gaze_interaction`
//! (headless, `XR_MND_headless`), for `.ci/xr/run`: with gazelight's layer it
//! gets the gaze of the layer's source.
//!
//! ```text
//! eye_gaze_app SECS EXPECT_NORM_X EXPECT_NORM_Y
//! ```
//!
//! `EXPECT_NORM_*`: the gaze the source sends, Pupil `norm_pos` (bottom-left
//! origin) in the view's image. Every 10 ms it locates the gaze space in
//! VIEW space at the runtime's time now (no frames: headless), with `XrEyeGazeSampleTimeEXT`
//! chained, and prints one line per frame
//! `gaze MONO_SECS TIME_NS AFTER_NS SAMPLE_TIME_NS TRACKED ERR_DEG` per read
//! (`MONO_SECS`: `CLOCK_MONOTONIC` when read; `AFTER_NS`: the runtime's time
//! when `xrLocateSpace` returned) (the angle between the
//! gaze's forward axis and the ray through the expected point: the mean of
//! the rays through it in each view's field of view), then a summary line
//! `summary supports=B frames=N tracked=N max_err_deg=X median_err_deg=X
//! sample_times_monotonic=B sample_times_distinct=N`. First a line
//! `layer_extensions NAME:VERSION…`: the instance extensions the loader
//! says gazelight's layer provides (from its manifest).
use anyhow::{Context, bail};
use openxr as xr;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 4 {
        bail!("usage: eye_gaze_app SECS EXPECT_NORM_X EXPECT_NORM_Y");
    }
    let secs: f64 = args[1].parse().context("SECS")?;
    let norm: [f64; 2] = [
        args[2].parse().context("EXPECT_NORM_X")?,
        args[3].parse().context("EXPECT_NORM_Y")?,
    ];
    // SAFETY: loads the system's OpenXR loader.
    let entry = unsafe { xr::Entry::load(&()) }.context("no OpenXR loader")?;
    println!(
        "layer_extensions {}",
        layer_extensions(&entry, "XR_APILAYER_GAZELIGHT_perception").join(" ")
    );
    let available = entry.enumerate_extensions()?;
    if !available.ext_eye_gaze_interaction
        || !available.mnd_headless
        || !available.khr_convert_timespec_time
    {
        bail!(
            "the runtime (or layer) lacks XR_EXT_eye_gaze_interaction, XR_MND_headless or XR_KHR_convert_timespec_time"
        );
    }
    let mut wanted = xr::ExtensionSet::default();
    wanted.ext_eye_gaze_interaction = true;
    wanted.mnd_headless = true;
    wanted.khr_convert_timespec_time = true;
    let instance = entry.create_instance(
        &xr::ApplicationInfo {
            application_name: "gazelight eye gaze test",
            application_version: 1,
            engine_name: "gazelight",
            engine_version: 1,
            api_version: xr::Version::new(1, 0, 0),
        },
        &wanted,
        &[],
        &(),
    )?;
    let system = instance.system(xr::FormFactor::HEAD_MOUNTED_DISPLAY)?;
    let supports = supports_eye_gaze(&instance, system)?;

    let set = instance.create_action_set("gaze_test", "gaze test", 0)?;
    let action = set.create_action::<xr::Posef>("gaze", "Gaze", &[])?;
    instance.suggest_interaction_profile_bindings(
        instance.string_to_path("/interaction_profiles/ext/eye_gaze_interaction")?,
        &[xr::Binding::new(
            &action,
            instance.string_to_path("/user/eyes_ext/input/gaze_ext/pose")?,
        )],
    )?;
    // SAFETY: a headless session needs no graphics binding.
    let (session, _waiter, _stream) = unsafe {
        instance.create_session::<xr::Headless>(system, &xr::headless::SessionCreateInfo {})
    }?;
    session.attach_action_sets(&[&set])?;
    let gaze_space = action.create_space(&session, xr::Path::NULL, xr::Posef::IDENTITY)?;
    let view_space =
        session.create_reference_space(xr::ReferenceSpaceType::VIEW, xr::Posef::IDENTITY)?;

    let start = std::time::Instant::now();
    let mut running = false;
    let mut focused = false;
    let mut events = xr::EventDataBuffer::new();
    let mut errs = Vec::new();
    let mut frames = 0usize;
    let mut samples: Vec<i64> = Vec::new();
    let mut active = false;
    while start.elapsed().as_secs_f64() < secs {
        while let Some(event) = instance.poll_event(&mut events)? {
            if let xr::Event::SessionStateChanged(e) = event {
                match e.state() {
                    xr::SessionState::READY => {
                        session.begin(xr::ViewConfigurationType::PRIMARY_STEREO)?;
                        running = true;
                    }
                    xr::SessionState::FOCUSED => focused = true,
                    xr::SessionState::STOPPING => {
                        session.end()?;
                        running = false;
                    }
                    xr::SessionState::EXITING | xr::SessionState::LOSS_PENDING => {
                        bail!("session ended early")
                    }
                    _ => {}
                }
            }
        }
        if !running {
            std::thread::sleep(std::time::Duration::from_millis(10));
            continue;
        }
        // Headless (Monado): no frames to submit; the gaze is read at the
        // runtime's time now, from CLOCK_MONOTONIC.
        std::thread::sleep(std::time::Duration::from_millis(10));
        let (mono_secs, t) = xr_time_now(&instance)?;
        if focused {
            session.sync_actions(&[xr::ActiveActionSet::new(&set)])?;
            active |= action.is_active(&session, xr::Path::NULL)?;
        }
        let mut sample = xr::sys::EyeGazeSampleTimeEXT {
            ty: xr::sys::EyeGazeSampleTimeEXT::TYPE,
            next: std::ptr::null_mut(),
            time: xr::Time::from_nanos(0),
        };
        let mut loc = xr::sys::SpaceLocation {
            ty: xr::sys::SpaceLocation::TYPE,
            next: (&mut sample as *mut xr::sys::EyeGazeSampleTimeEXT).cast(),
            location_flags: xr::SpaceLocationFlags::EMPTY,
            pose: xr::Posef::IDENTITY,
        };
        // SAFETY: valid spaces; `loc` and `sample` outlive the call.
        let r = unsafe {
            (instance.fp().locate_space)(gaze_space.as_raw(), view_space.as_raw(), t, &mut loc)
        };
        if r.into_raw() < 0 {
            bail!("xrLocateSpace: {r:?}");
        }
        let (_, after) = xr_time_now(&instance)?;
        let (_, views) =
            session.locate_views(xr::ViewConfigurationType::PRIMARY_STEREO, t, &view_space)?;
        frames += 1;
        let tracked = loc
            .location_flags
            .contains(xr::SpaceLocationFlags::ORIENTATION_TRACKED);
        let err = if tracked {
            let got = rotate(&loc.pose.orientation, [0.0, 0.0, -1.0]);
            let want = expected(&views, norm);
            let dot = (0..3).map(|k| got[k] * want[k]).sum::<f64>();
            errs.push(dot.clamp(-1.0, 1.0).acos().to_degrees());
            samples.push(sample.time.as_nanos());
            errs[errs.len() - 1]
        } else {
            f64::NAN
        };
        println!(
            "gaze {mono_secs:.6} {} {} {} {} {err:.4}",
            t.as_nanos(),
            after.as_nanos(),
            sample.time.as_nanos(),
            u8::from(tracked)
        );
    }
    let monotonic = samples.windows(2).all(|w| w[1] >= w[0]) && samples.iter().all(|&s| s > 0);
    let mut distinct = samples.clone();
    distinct.dedup();
    let mut sorted = errs.clone();
    sorted.sort_by(f64::total_cmp);
    println!(
        "summary supports={supports} active={active} frames={frames} tracked={} max_err_deg={:.4} median_err_deg={:.4} sample_times_monotonic={monotonic} sample_times_distinct={}",
        errs.len(),
        sorted.last().copied().unwrap_or(f64::NAN),
        sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN),
        distinct.len()
    );
    Ok(())
}

/// `CLOCK_MONOTONIC` seconds and the runtime's `XrTime` now.
fn xr_time_now(instance: &xr::Instance) -> anyhow::Result<(f64, xr::Time)> {
    let Some(ext) = instance.exts().khr_convert_timespec_time.as_ref() else {
        bail!("XR_KHR_convert_timespec_time not enabled");
    };
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: an out-pointer to a timespec.
    if unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) } != 0 {
        bail!("clock_gettime failed");
    }
    let mut t = xr::Time::from_nanos(0);
    // SAFETY: a valid instance, timespec and out-pointer.
    let r = unsafe { (ext.convert_timespec_time_to_time)(instance.as_raw(), &ts, &mut t) };
    if r.into_raw() < 0 {
        bail!("xrConvertTimespecTimeToTimeKHR: {r:?}");
    }
    Ok((ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9, t))
}

fn supports_eye_gaze(instance: &xr::Instance, system: xr::SystemId) -> anyhow::Result<bool> {
    let mut gaze = xr::sys::SystemEyeGazeInteractionPropertiesEXT {
        ty: xr::sys::SystemEyeGazeInteractionPropertiesEXT::TYPE,
        next: std::ptr::null_mut(),
        supports_eye_gaze_interaction: xr::sys::FALSE,
    };
    // SAFETY: all-zero XrSystemProperties is valid plain data.
    let mut props: xr::sys::SystemProperties = unsafe { std::mem::zeroed() };
    props.ty = xr::sys::SystemProperties::TYPE;
    props.next = (&mut gaze as *mut xr::sys::SystemEyeGazeInteractionPropertiesEXT).cast();
    // SAFETY: valid instance, system and chain.
    let r = unsafe { (instance.fp().get_system_properties)(instance.as_raw(), system, &mut props) };
    if r.into_raw() < 0 {
        bail!("xrGetSystemProperties: {r:?}");
    }
    Ok(gaze.supports_eye_gaze_interaction == xr::sys::TRUE)
}

/// The ray through Pupil `norm_pos` (bottom-left origin) in each view's
/// field of view, in VIEW space; their mean, normalised.
fn expected(views: &[xr::View], norm: [f64; 2]) -> [f64; 3] {
    let mut sum = [0.0; 3];
    for v in views {
        let f = v.fov;
        let x0 = f64::from(f.angle_left).tan();
        let x1 = f64::from(f.angle_right).tan();
        let y_top = f64::from(f.angle_up).tan();
        let y_bottom = f64::from(f.angle_down).tan();
        let d = rotate(
            &v.pose.orientation,
            [
                x0 + norm[0] * (x1 - x0),
                y_bottom + norm[1] * (y_top - y_bottom),
                -1.0,
            ],
        );
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        for (acc, x) in sum.iter_mut().zip(d) {
            *acc += x / l;
        }
    }
    let l = (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]).sqrt();
    sum.map(|x| x / l)
}

fn rotate(q: &xr::Quaternionf, v: [f64; 3]) -> [f64; 3] {
    let [x, y, z, w] = [q.x, q.y, q.z, q.w].map(f64::from);
    let l = (x * x + y * y + z * z + w * w).sqrt();
    let (x, y, z, w) = (x / l, y / l, z / l, w / l);
    // Rotation matrix of a unit quaternion times v.
    [
        (1.0 - 2.0 * (y * y + z * z)) * v[0]
            + 2.0 * (x * y - w * z) * v[1]
            + 2.0 * (x * z + w * y) * v[2],
        2.0 * (x * y + w * z) * v[0]
            + (1.0 - 2.0 * (x * x + z * z)) * v[1]
            + 2.0 * (y * z - w * x) * v[2],
        2.0 * (x * z - w * y) * v[0]
            + 2.0 * (y * z + w * x) * v[1]
            + (1.0 - 2.0 * (x * x + y * y)) * v[2],
    ]
}

/// The instance extensions the loader lists for API layer `layer`
/// (`xrEnumerateInstanceExtensionProperties` with its name), as
/// `NAME:VERSION`; none when the loader does not know the layer.
fn layer_extensions(entry: &xr::Entry, layer: &str) -> Vec<String> {
    let Ok(name) = std::ffi::CString::new(layer) else {
        return Vec::new();
    };
    let f = entry.fp().enumerate_instance_extension_properties;
    let mut count = 0u32;
    // SAFETY: a NUL-terminated layer name; the count query writes one u32.
    let r = unsafe { f(name.as_ptr(), 0, &mut count, std::ptr::null_mut()) };
    if r.into_raw() < 0 {
        return Vec::new();
    }
    let empty = xr::sys::ExtensionProperties {
        ty: xr::sys::ExtensionProperties::TYPE,
        next: std::ptr::null_mut(),
        extension_name: [0; xr::sys::MAX_EXTENSION_NAME_SIZE],
        extension_version: 0,
    };
    let mut props = vec![empty; count as usize];
    // SAFETY: `props` holds `count` initialised structures.
    let r = unsafe { f(name.as_ptr(), count, &mut count, props.as_mut_ptr()) };
    if r.into_raw() < 0 {
        return Vec::new();
    }
    props
        .iter()
        .take(count as usize)
        .map(|p| {
            // SAFETY: the loader writes NUL-terminated names.
            let n = unsafe { std::ffi::CStr::from_ptr(p.extension_name.as_ptr()) };
            format!("{}:{}", n.to_string_lossy(), p.extension_version)
        })
        .collect()
}
