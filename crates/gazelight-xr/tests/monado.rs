//! A real OpenXR session against the runtime named by `XR_RUNTIME_JSON`
//! (CI: Monado's simulated HMD with the null compositor on lavapipe, see
//! `.ci/xr`). Skipped when `XR_RUNTIME_JSON` is unset.
//!
//! Opens a session, runs the state machine to FOCUSED (15 s at most), then
//! renders ≥ 60 frames clearing each eye's swapchain image to its own colour
//! with a wgpu render pass (one frame is read back from the runtime's images
//! to check the clear landed), then asks to exit and expects STOPPING then
//! EXITING.
//!
//! To run it in the Monado root of `.ci/xr`, which binds the repository
//! (and so `target/`) at the same path; bind another `CARGO_TARGET_DIR`
//! with `GAZELIGHT_XR_BINDS=$CARGO_TARGET_DIR`:
//!
//! ```text
//! cargo test -p gazelight-xr --no-run        # prints the monado-<hash> path
//! .ci/xr/root exec --monado -- $PWD/target/debug/deps/monado-<hash> --nocapture
//! ```

use std::time::{Duration, Instant};

use gazelight_xr::{SessionState, XrOptions, XrSession};

const FOCUS_TIMEOUT: Duration = Duration::from_secs(15);
const EXIT_TIMEOUT: Duration = Duration::from_secs(10);
const FRAMES: usize = 60;
/// Left eye red, right eye green: 0/1 channels are exact in sRGB.
const COLOURS: [wgpu::Color; 2] = [
    wgpu::Color {
        r: 1.0,
        g: 0.0,
        b: 0.0,
        a: 1.0,
    },
    wgpu::Color {
        r: 0.0,
        g: 1.0,
        b: 0.0,
        a: 1.0,
    },
];

fn distance_m(a: [f32; 3], b: [f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[test]
fn monado_session_frames_and_exit() {
    if std::env::var_os("XR_RUNTIME_JSON").is_none() {
        println!("SKIP: XR_RUNTIME_JSON is unset (no OpenXR runtime to test against)");
        return;
    }
    let options = XrOptions {
        app_name: "gazelight-xr-test".into(),
        ..XrOptions::default()
    };
    let t_open = Instant::now();
    let (mut xr, adapter, device, queue) = XrSession::open(&options).expect("XrSession::open");
    let info = xr.info().clone();
    println!("open took {:.2} s", t_open.elapsed().as_secs_f64());
    println!("runtime: {} {}", info.runtime_name, info.runtime_version);
    println!("system: {}", info.system_name);
    println!("extensions: {:?}", info.enabled_extensions);
    println!(
        "eye gaze: supported {}, action {}",
        info.eye_gaze_supported, info.eye_gaze_action
    );
    println!(
        "adapter: {} ({:?}, {}), Vulkan {}",
        adapter.get_info().name,
        adapter.get_info().device_type,
        adapter.get_info().driver_info,
        info.vulkan_version
    );
    println!(
        "swapchains: {:?}, {:?} px, {:?} images, blend {}, space {:?}",
        info.swapchain_format,
        info.eye_size_px,
        info.swapchain_images,
        info.blend_mode,
        info.reference_space
    );
    assert!(info.swapchain_format.is_srgb());

    let srgb_bgra = info.swapchain_format == wgpu::TextureFormat::Bgra8UnormSrgb;
    let mut states: Vec<SessionState> = Vec::new();
    let mut display_times_ns: Vec<i64> = Vec::new();
    let mut monotonic_secs: Vec<f64> = Vec::new();
    let mut rendered_after_focus = 0usize;
    let mut first_views = None;
    let mut read_back_checked = false;
    let mut t_focus = None;
    let start = Instant::now();

    // Phase 1: to FOCUSED, then FRAMES rendered frames.
    while rendered_after_focus < FRAMES {
        let status = xr.poll_events().expect("poll_events");
        states.extend(&status.changes);
        assert!(
            !status.should_exit,
            "session ended early; states {states:?}"
        );
        if status.focused_reached && t_focus.is_none() {
            t_focus = Some(Instant::now());
            println!("FOCUSED after {:.2} s", start.elapsed().as_secs_f64());
        }
        assert!(
            t_focus.is_some() || start.elapsed() < FOCUS_TIMEOUT,
            "session not FOCUSED after {} s; states so far {states:?}",
            FOCUS_TIMEOUT.as_secs()
        );
        assert!(
            start.elapsed() < FOCUS_TIMEOUT + Duration::from_secs(30),
            "{rendered_after_focus} frames in 30 s after FOCUSED"
        );
        let Some(frame) = xr.begin_frame().expect("begin_frame") else {
            std::thread::sleep(Duration::from_millis(5));
            continue;
        };
        display_times_ns.push(frame.predicted_display_time_ns);
        if let Some(secs) = frame.predicted_display_monotonic_secs {
            monotonic_secs.push(secs);
        }
        if !frame.should_render {
            xr.end_frame(frame).expect("end_frame (not rendering)");
            continue;
        }
        assert_eq!(frame.views.len(), 2);
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("xr test clear"),
        });
        for (eye, colour) in frame.views.iter().zip(COLOURS) {
            let _pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("xr test clear"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &eye.view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(colour),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                ..Default::default()
            });
        }
        // Once, after FOCUSED: read the runtime's images back.
        let read_back = t_focus.is_some() && !read_back_checked;
        let mut buffers = Vec::new();
        if read_back {
            for eye in &frame.views {
                let bytes_per_row = (eye.width_px * 4).div_ceil(256) * 256;
                let buffer = device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("xr test read-back"),
                    size: u64::from(bytes_per_row * eye.height_px),
                    usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                    mapped_at_creation: false,
                });
                encoder.copy_texture_to_buffer(
                    eye.texture.as_image_copy(),
                    wgpu::TexelCopyBufferInfo {
                        buffer: &buffer,
                        layout: wgpu::TexelCopyBufferLayout {
                            offset: 0,
                            bytes_per_row: Some(bytes_per_row),
                            rows_per_image: None,
                        },
                    },
                    eye.texture.size(),
                );
                buffers.push((buffer, bytes_per_row, eye.width_px, eye.height_px));
            }
        }
        queue.submit([encoder.finish()]);
        if first_views.is_none() || rendered_after_focus == FRAMES / 2 {
            let v = &frame.views;
            println!(
                "t={} ns views: L pos {:?} ori {:?} fov(L,R,U,D) rad ({:.3},{:.3},{:.3},{:.3}); \
                 R pos {:?} ori {:?}; {}x{} px; tracked {}; gaze {:?}",
                frame.predicted_display_time_ns,
                v[0].pose.position_m,
                v[0].pose.orientation,
                v[0].fov.angle_left_rad,
                v[0].fov.angle_right_rad,
                v[0].fov.angle_up_rad,
                v[0].fov.angle_down_rad,
                v[1].pose.position_m,
                v[1].pose.orientation,
                v[0].width_px,
                v[0].height_px,
                frame.views_tracked,
                frame.gaze
            );
        }
        if first_views.is_none() {
            first_views = Some((frame.views[0].pose, frame.views[1].pose));
        }
        if t_focus.is_some() {
            rendered_after_focus += 1;
        }
        xr.end_frame(frame).expect("end_frame");

        for (i, (buffer, bytes_per_row, w, h)) in buffers.into_iter().enumerate() {
            let slice = buffer.slice(..);
            slice.map_async(wgpu::MapMode::Read, |r| r.expect("map read-back"));
            device
                .poll(wgpu::PollType::wait_indefinitely())
                .expect("poll read-back");
            let data = slice.get_mapped_range().expect("mapped read-back");
            let expect: [u8; 4] = match (i, srgb_bgra) {
                (0, false) => [255, 0, 0, 255],
                (0, true) => [0, 0, 255, 255],
                (_, _) => [0, 255, 0, 255],
            };
            for (x, y) in [(0, 0), (w / 2, h / 2), (w - 1, h - 1)] {
                let at = (y * bytes_per_row + x * 4) as usize;
                assert_eq!(
                    data[at..at + 4],
                    expect,
                    "eye {i} pixel ({x},{y}) of the runtime's image"
                );
            }
            println!("eye {i}: read back the clear colour {expect:?} from the runtime's image");
            read_back_checked = true;
        }
    }
    let t_frames = t_focus
        .map(|t| t.elapsed().as_secs_f64())
        .unwrap_or(f64::NAN);
    println!(
        "{rendered_after_focus} frames after FOCUSED in {t_frames:.2} s: {:.1} fps",
        rendered_after_focus as f64 / t_frames
    );
    println!("{} frames begun in all", display_times_ns.len());

    // Phase 2: exit.
    xr.request_exit().expect("request_exit");
    let t_exit = Instant::now();
    let mut exit_states = Vec::new();
    loop {
        let status = xr.poll_events().expect("poll_events (exiting)");
        exit_states.extend(&status.changes);
        if status.should_exit {
            break;
        }
        assert!(
            t_exit.elapsed() < EXIT_TIMEOUT,
            "no EXITING {} s after request_exit; states {exit_states:?}",
            EXIT_TIMEOUT.as_secs()
        );
        match xr.begin_frame().expect("begin_frame (exiting)") {
            Some(frame) => {
                display_times_ns.push(frame.predicted_display_time_ns);
                // No rendering: end with whatever the frame is (layers when
                // should_render, as the images were acquired).
                xr.end_frame(frame).expect("end_frame (exiting)");
            }
            None => std::thread::sleep(Duration::from_millis(5)),
        }
    }
    states.extend(&exit_states);
    println!("states: {states:?}");

    // Assertions.
    assert!(read_back_checked, "no frame was read back");
    for pair in display_times_ns.windows(2) {
        assert!(
            pair[1] > pair[0],
            "predicted display times not increasing: {pair:?}"
        );
    }
    for pair in monotonic_secs.windows(2) {
        assert!(
            pair[1] > pair[0],
            "CLOCK_MONOTONIC display times not increasing: {pair:?}"
        );
    }
    if info
        .enabled_extensions
        .contains(&"XR_KHR_convert_timespec_time")
    {
        assert!(!monotonic_secs.is_empty(), "no CLOCK_MONOTONIC times");
        let xr_span =
            (display_times_ns[monotonic_secs.len() - 1] - display_times_ns[0]) as f64 * 1e-9;
        let mono_span = monotonic_secs[monotonic_secs.len() - 1] - monotonic_secs[0];
        assert!(
            (xr_span - mono_span).abs() < 1e-3,
            "XR and CLOCK_MONOTONIC spans differ: {xr_span} vs {mono_span} s"
        );
    }
    let (left, right) = first_views.expect("no rendered frame");
    let ipd_m = distance_m(left.position_m, right.position_m);
    println!("eye separation {:.4} m", ipd_m);
    assert!(
        ipd_m > 0.01,
        "the two views' poses do not differ: {left:?} {right:?}"
    );
    let stopping = exit_states
        .iter()
        .position(|s| *s == SessionState::Stopping);
    let exiting = exit_states.iter().position(|s| *s == SessionState::Exiting);
    assert!(
        matches!((stopping, exiting), (Some(s), Some(e)) if s < e),
        "expected STOPPING then EXITING after request_exit, got {exit_states:?}"
    );
    assert_eq!(xr.state(), SessionState::Exiting);
    assert!(!xr.is_running());
    drop(xr);
    drop(queue);
    drop(device);
}
