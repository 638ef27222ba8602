//! `run --display xr`: the live session into an OpenXR headset.
//!
//! On the frame thread: [`XrSession::open`] (the loader is loaded at run
//! time; no runtime is an error naming `XR_RUNTIME_JSON`) gives the
//! runtime's Vulkan device as a wgpu device; both eyes' GPU pipelines run
//! on it ([`FrameLoopSetup::device`]) at the runtime's recommended size.
//! Each frame:
//!
//! 1. `xrWaitFrame` paces the loop ([`XrSession::begin_frame`]);
//! 2. each eye's view is the panorama seen through that eye's pose and
//!    field of view from the runtime ([`PanoramaView::from_frustum`]);
//! 3. the `EyeState` is taken for the predicted display time: the runtime's
//!    XrTime is converted to CLOCK_MONOTONIC (`XR_KHR_convert_timespec_time`)
//!    and from there to the host clock, and the state's age at that time is
//!    what the summary and `timeline.csv` report;
//! 4. the eye gaze from `XR_EXT_eye_gaze_interaction` replaces the tracker's
//!    gaze when the runtime has it (the pupil still comes from the tracker);
//! 5. each eye's GPU output is drawn into its swapchain image on the device
//!    ([`TexturePresenter`]: no host round trip) and the frame is submitted.
//!
//! Session states are followed ([`XrSession::poll_events`]); a shutdown
//! (a signal, `--secs`) asks the runtime to exit and the loop ends when the
//! session reaches EXITING (bounded). With `--out`, `xr.csv` gets one row per
//! submitted frame (written by the output writer's thread, as the other
//! files): the predicted display time, the state's age there and both
//! eyes' poses.

use std::time::{Duration, Instant};

use anyhow::Context;
use gazelight_gpu::GpuContext;
use gazelight_gpu::present::TexturePresenter;
use gazelight_tracker::pupil::clock::host_now_secs;
use gazelight_vision::scene::{PanoramaView, ViewParams};
use gazelight_xr::{SessionState, XrFrame, XrOptions, XrSession, monotonic_now_secs};

use super::frame_loop::{FrameLoop, FrameLoopSetup, RunSummary};
use super::writer::XrRow;

/// How long the runtime may take to start showing frames.
const START_LIMIT: Duration = Duration::from_secs(20);
/// How long the session may take to end after an exit request.
const EXIT_LIMIT: Duration = Duration::from_secs(5);
/// Idle wait while the session is not running.
const IDLE: Duration = Duration::from_millis(5);

/// What the OpenXR side of a session did (printed after the run summary).
#[derive(Clone, Debug, Default)]
pub struct XrReport {
    pub runtime: String,
    pub system: String,
    pub eye_size_px: [u32; 2],
    pub extensions: Vec<&'static str>,
    /// Every state the session entered, in order.
    pub states: Vec<SessionState>,
    pub focused_reached: bool,
    /// Frames submitted with both eyes rendered.
    pub frames_submitted: u64,
    /// Whether every submitted frame's predicted display time was later
    /// than the previous one's.
    pub display_times_increasing: bool,
    /// The two eyes' positions in the first rendered frame, m.
    pub first_positions_m: [[f32; 3]; 2],
    /// Largest angle between any frame's left-eye orientation and the
    /// first frame's, degrees (the head turning).
    pub max_head_turn_deg: f64,
    /// Whether the runtime's eye gaze drove the gaze.
    pub eye_gaze: bool,
}

/// Runs the live session into the OpenXR runtime: on the frame thread.
/// `setup` is the windowless setup of a stereo run; its view size and field
/// are replaced by the runtime's.
pub fn run(mut setup: FrameLoopSetup) -> anyhow::Result<(RunSummary, XrReport)> {
    let options = XrOptions {
        app_name: "gazelight".to_owned(),
        eye_gaze: true,
        ..XrOptions::default()
    };
    let (mut xr, _adapter, device, queue) =
        XrSession::open(&options).context("--display xr: cannot open an OpenXR session")?;
    let info = xr.info().clone();
    let mut report = XrReport {
        runtime: format!("{} {}", info.runtime_name, info.runtime_version),
        system: info.system_name.clone(),
        eye_size_px: info.eye_size_px[0],
        extensions: info.enabled_extensions.clone(),
        eye_gaze: info.eye_gaze_action,
        display_times_increasing: true,
        ..XrReport::default()
    };
    tracing::info!(
        runtime = %report.runtime,
        system = %report.system,
        eye_size = ?info.eye_size_px,
        format = ?info.swapchain_format,
        extensions = ?info.enabled_extensions,
        eye_gaze = info.eye_gaze_action,
        "OpenXR session"
    );

    // The eyes' field comes with the first frame: run it empty.
    let first = first_views(&mut xr, &setup, &mut report)?;
    let [w, h] = info.eye_size_px[0];
    let (w, h) = (w as usize, h as usize);
    let hfov_deg = f64::from(first[1] - first[0]).to_degrees();
    setup.view = ViewParams {
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        hfov_deg,
        width: w,
        height: h,
    };
    setup.stereo = true;
    setup.display = None;
    setup.mouse = None;
    setup.device = Some(GpuContext::from_device(device, queue));
    let hub = setup.hub.clone();
    let mut fl = FrameLoop::new(setup)?;
    let presenters = (0..2)
        .map(|k| {
            let source = fl
                .frame_source(k)
                .context("--display xr renders on the runtime's GPU device")?;
            Ok(TexturePresenter::new(&source, info.swapchain_format)?)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let start = Instant::now();
    fl.start_clock(start);
    let mut exit_asked: Option<Instant> = None;
    let mut prev_display_ns: Option<i64> = None;
    let mut first_orientation: Option<[f32; 4]> = None;
    let mut frames: u64 = 0;
    let result: anyhow::Result<()> = loop {
        let status = match xr.poll_events() {
            Ok(s) => s,
            Err(e) => break Err(e.into()),
        };
        report.states.extend(status.changes.iter().copied());
        report.focused_reached |= status.focused_reached;
        if status.should_exit {
            break Ok(());
        }
        if hub.shutting_down() {
            match exit_asked {
                None => {
                    exit_asked = Some(Instant::now());
                    if let Err(e) = xr.request_exit() {
                        break Err(e.into());
                    }
                }
                Some(t) if t.elapsed() > EXIT_LIMIT => {
                    tracing::warn!(
                        "the OpenXR session did not reach EXITING within {EXIT_LIMIT:?}"
                    );
                    break Ok(());
                }
                Some(_) => {}
            }
        }
        if !status.running {
            std::thread::sleep(IDLE);
            continue;
        }
        let frame = match xr.begin_frame() {
            Ok(Some(f)) => f,
            Ok(None) => {
                std::thread::sleep(IDLE);
                continue;
            }
            Err(e) => break Err(e.into()),
        };
        if !(frame.should_render && frame.views.len() == 2) {
            if let Err(e) = xr.end_frame(frame) {
                break Err(e.into());
            }
            continue;
        }
        let step = render_frame(&mut fl, &frame, w, h, start, prev_display_ns);
        let (status_frame, display_host) = match step {
            Ok(s) => s,
            Err(e) => break Err(e),
        };
        for (p, eye) in presenters.iter().zip(&frame.views) {
            p.present(&eye.view);
        }
        // Late: the frame was submitted after the time it was to be shown.
        let display_mono = frame.predicted_display_monotonic_secs;
        let late = display_mono.is_some_and(|d| monotonic_now_secs() > d);
        let skipped = match prev_display_ns {
            Some(p) if frame.predicted_display_period_ns > 0 => {
                let periods = (frame.predicted_display_time_ns - p) as f64
                    / frame.predicted_display_period_ns as f64;
                (periods.round() as i64 - 1).max(0) as u64
            }
            _ => 0,
        };
        fl.count_late(late, skipped);
        if let Some(p) = prev_display_ns
            && frame.predicted_display_time_ns <= p
        {
            report.display_times_increasing = false;
        }
        prev_display_ns = Some(frame.predicted_display_time_ns);
        let [left, right] = [&frame.views[0].pose, &frame.views[1].pose];
        let q0 = *first_orientation.get_or_insert(left.orientation);
        if frames == 0 {
            report.first_positions_m = [left.position_m, right.position_m];
        }
        report.max_head_turn_deg = report
            .max_head_turn_deg
            .max(angle_deg(q0, left.orientation));
        fl.write_xr(XrRow {
            frame: status_frame.frames,
            predicted_display_time_ns: frame.predicted_display_time_ns,
            display_host_secs: display_host,
            eye_state_age_ms: status_frame.eye_state_age_ms,
            poses: [
                [
                    left.position_m[0],
                    left.position_m[1],
                    left.position_m[2],
                    left.orientation[0],
                    left.orientation[1],
                    left.orientation[2],
                    left.orientation[3],
                ],
                [
                    right.position_m[0],
                    right.position_m[1],
                    right.position_m[2],
                    right.orientation[0],
                    right.orientation[1],
                    right.orientation[2],
                    right.orientation[3],
                ],
            ],
            gaze_uv_left: status_frame.gaze_uv,
            target_cd_m2_left: status_frame.target_cd_m2,
            view_mean_cd_m2: fl.view_means(),
        });
        if let Err(e) = xr.end_frame(frame) {
            break Err(e.into());
        }
        frames += 1;
        report.frames_submitted = frames;
    };
    let summary = fl.finish(start.elapsed().as_secs_f64(), result)?;
    // The session (and its Vulkan device) ends after the pipelines.
    drop(xr);
    Ok((summary, report))
}

/// Renders both eyes of `frame` through the frame loop, for its predicted
/// display time.
fn render_frame(
    fl: &mut FrameLoop,
    frame: &XrFrame,
    w: usize,
    h: usize,
    start: Instant,
    prev_display_ns: Option<i64>,
) -> anyhow::Result<(crate::hub::FrameStatus, f64)> {
    let mut views = [None, None];
    for (slot, v) in views.iter_mut().zip(&frame.views) {
        let f = &v.fov;
        *slot = Some(PanoramaView::from_frustum(
            v.pose.orientation,
            [
                f.angle_left_rad,
                f.angle_right_rad,
                f.angle_up_rad,
                f.angle_down_rad,
            ],
            w,
            h,
        )?);
    }
    let [Some(left), Some(right)] = views else {
        anyhow::bail!("the runtime gave {} views, expected 2", frame.views.len());
    };
    // The host time of the predicted display time (CLOCK_MONOTONIC is the
    // clock `Instant` and the host clock read).
    let now_host = host_now_secs();
    let display_host = match frame.predicted_display_monotonic_secs {
        Some(d) => now_host + (d - monotonic_now_secs()),
        None => now_host,
    };
    let dt_secs = match prev_display_ns {
        Some(p) => ((frame.predicted_display_time_ns - p) as f64 * 1e-9) as f32,
        None => 0.0,
    };
    let gaze = [frame.gaze_uv(0), frame.gaze_uv(1)];
    let t_secs = start.elapsed().as_secs_f64();
    let status = fl.step_views(display_host, t_secs, dt_secs, Some(&[left, right]), gaze)?;
    Ok((status, display_host))
}

/// Waits for the first frame the runtime wants rendered and submits it
/// empty; returns the left eye's field (left, right, up, down, radians).
fn first_views(
    xr: &mut XrSession,
    setup: &FrameLoopSetup,
    report: &mut XrReport,
) -> anyhow::Result<[f32; 4]> {
    let started = Instant::now();
    loop {
        if started.elapsed() > START_LIMIT {
            anyhow::bail!(
                "--display xr: the OpenXR runtime showed no frame within {START_LIMIT:?} (states: {:?})",
                report.states
            );
        }
        if setup.hub.shutting_down() {
            anyhow::bail!("stopped before the OpenXR session showed a frame");
        }
        let status = xr.poll_events()?;
        report.states.extend(status.changes.iter().copied());
        report.focused_reached |= status.focused_reached;
        if status.should_exit {
            anyhow::bail!("the OpenXR session ended before its first frame");
        }
        if !status.running {
            std::thread::sleep(IDLE);
            continue;
        }
        let Some(frame) = xr.begin_frame()? else {
            std::thread::sleep(IDLE);
            continue;
        };
        let fov = frame.views.first().map(|v| {
            let f = &v.fov;
            [
                f.angle_left_rad,
                f.angle_right_rad,
                f.angle_up_rad,
                f.angle_down_rad,
            ]
        });
        let rendered = frame.should_render && frame.views.len() == 2;
        xr.end_frame(frame)?;
        if let (true, Some(fov)) = (rendered, fov) {
            return Ok(fov);
        }
    }
}

/// Angle between two unit quaternions, degrees.
fn angle_deg(a: [f32; 4], b: [f32; 4]) -> f64 {
    let dot: f64 = a
        .iter()
        .zip(&b)
        .map(|(x, y)| f64::from(*x) * f64::from(*y))
        .sum();
    2.0 * dot.abs().min(1.0).acos().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_angles() {
        let id = [0.0, 0.0, 0.0, 1.0];
        assert!(angle_deg(id, id).abs() < 1e-6);
        let s = std::f32::consts::FRAC_1_SQRT_2;
        // 90° about +y.
        assert!((angle_deg(id, [0.0, s, 0.0, s]) - 90.0).abs() < 1e-3);
        // q and −q are the same rotation (f32 rounding: acos near 1 is
        // steep, ~0.04° here).
        assert!(angle_deg([0.0, s, 0.0, s], [0.0, -s, 0.0, -s]).abs() < 0.1);
    }
}
