//! `gazelight run`: a live session. A tracker source (default Pupil Core
//! at `pupil://127.0.0.1:50020`; `replay://PATH`, `synthetic://demo`, any
//! URI `gazelight-tracker` opens) runs through the tracker's live eye task
//! (the one filter chain) on a tokio runtime, which publishes the latest
//! `EyeState` on the hub's `watch` channel; the frame loop — a dedicated
//! thread at the display rate — renders the panorama view for the head
//! orientation through the perception pipeline, reading the newest state
//! without ever waiting for it, and records the age of the state each frame
//! used (see ARCHITECTURE.md, "Threads").
//!
//! Ctrl-C or `--secs` ends the run: the hub's shutdown is requested, the
//! frame loop finishes its frame, the outputs are flushed and a summary
//! (frames, late frames, `EyeState` age median/p99) is printed. `--out` is
//! checked after the inputs, before anything starts, by the one `--out`
//! rule ([`crate::out_dir`]); a write
//! error during the run (a full disk) is printed when it happens, the
//! summary still follows, and the run then exits with an error.
//!
//! Frames are shown in the service's window (winit + gazelight-gpu's presenter, vsync;
//! see [`crate::window`]) unless `--headless`; the window takes the newest
//! frame and never slows the loop. With `--mouse-gaze` the cursor is the
//! gaze, with `--head mouse` it turns the head. Frames also go to `--out`
//! and to the hub (status page, relay).

pub mod frame_loop;
pub mod head;
pub mod source_task;
pub use gazelight_output::live as writer;
pub mod xr;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, bail};
use clap::Args;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::profile::PupilCalibration;
use gazelight_vision::RgbImage;
use gazelight_vision::scene::{PanoramaView, Scene};

use crate::backend::BackendChoice;
use crate::demo;
use crate::service_config::{self, HeadSpec, ServiceConfig};
use crate::session::{Origin, SessionSettings};
use crate::window::{self, Content, DisplaySlot, MouseGaze, WindowOptions};
use frame_loop::{FrameLoop, FrameLoopSetup, MouseControl, RunSummary};
use head::{Head, HeadTrace};
use source_task::DemoContext;
use writer::OutputWriter;

/// The default source: Pupil Capture's Pupil Remote on this machine (one
/// default for every front end).
pub use gazelight_tracker::uri::DEFAULT_SOURCE;
/// The default display rate, Hz (the Vive Pro's).
pub const DEFAULT_FPS: f64 = 90.0;

/// Arguments of `gazelight run`.
#[derive(Args, Debug, Default)]
pub struct RunArgs {
    /// Tracker source: pupil://HOST:PORT (default pupil://127.0.0.1:50020),
    /// replay://PATH[?speed=S] (any recording `inspect` reads), or
    /// synthetic://demo.
    #[arg(long, value_name = "URI")]
    pub source: Option<String>,
    /// HDR panorama (OpenEXR / Radiance .hdr). Default: the embedded night
    /// scene.
    #[arg(long, value_name = "FILE")]
    pub scene: Option<PathBuf>,
    /// Head orientation: fixed, trace:FILE (CSV t_secs,yaw_deg,pitch_deg),
    /// or mouse (needs a window).
    #[arg(long, value_name = "MODE", value_parser = service_config::parse_head)]
    pub head: Option<HeadSpec>,
    #[command(flatten)]
    pub view: crate::view_args::ViewArgs,
    /// Display size per eye, WIDTHxHEIGHT (default 720x800).
    #[arg(long, value_name = "WxH", value_parser = service_config::parse_size)]
    pub size: Option<(usize, usize)>,
    /// Display rate, Hz (default 90).
    #[arg(long, value_name = "HZ")]
    pub fps: Option<f64>,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long, value_name = "S")]
    pub secs: Option<f64>,
    /// Write frames, timeline.csv and psf.csv into this directory. Refused
    /// when it holds an input or a recording, or a previous run's outputs
    /// (unless --force).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Clear a previous run's outputs in --out first (timeline.csv,
    /// psf.csv, xr.csv, contact_sheet.png, plot.png, frames/frame_*); other
    /// files are kept.
    #[arg(long)]
    pub force: bool,
    /// With --out: write timeline.csv and psf.csv only, no frame images.
    #[arg(long)]
    pub no_frames: bool,
    /// Run with no window (frames go to --out and the hub); the same as
    /// `--display none`. Without it the frames are shown in a window (winit
    /// and wgpu, vsync); when no display can be opened the run goes on
    /// headless and says so.
    #[arg(long)]
    pub headless: bool,
    /// Where frames go: `window` (the default: a desktop window, both eyes
    /// side by side with --stereo), `xr` (an OpenXR session: both eyes, each
    /// from the runtime's pose and field of view, paced by the runtime; the
    /// GPU pipeline on the runtime's Vulkan device; needs an OpenXR runtime,
    /// `XR_RUNTIME_JSON`), or `none` (as --headless).
    #[arg(long, value_enum, conflicts_with = "headless")]
    pub display: Option<DisplayMode>,
    /// Frame pipeline: auto (a hardware GPU when present, else the CPU —
    /// a software adapter is slower than the CPU pipeline), gpu, or cpu.
    #[arg(long, value_enum, default_value_t = BackendChoice::Auto)]
    pub backend: BackendChoice,
    /// Show the window full screen (borderless) instead of at the frame size.
    #[arg(long)]
    pub fullscreen: bool,
    /// Calibration profile (JSON, calibration/schema.json) mapping the
    /// tracker's raw pupil units onto millimetres.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
    #[command(flatten)]
    pub observer: crate::observer::ObserverArgs,
    /// Use the mouse as gaze (development without a tracker; needs a
    /// window).
    #[arg(long)]
    pub mouse_gaze: bool,
    /// Re-publish the filtered, calibrated stream as a Pupil-compatible
    /// Network API with Pupil Remote at this address (e.g. 127.0.0.1:50030).
    #[arg(long, value_name = "IP:PORT", value_parser = service_config::parse_addr)]
    pub relay: Option<SocketAddr>,
    /// Serve the status page and API (HTTP + WebSocket) at this address
    /// (e.g. 127.0.0.1:8080).
    #[arg(long, value_name = "IP:PORT", value_parser = service_config::parse_addr)]
    pub http: Option<SocketAddr>,
    /// Service configuration (TOML); flags override it.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Publish the session on the Lab Streaming Layer: gazelight-eye
    /// (Gaze), gazelight-frame and gazelight-markers (see `[lsl]` in the
    /// configuration; discovery stays on this machine by default).
    #[arg(long)]
    pub lsl: bool,
    /// Read an LSL marker stream (lsl://?name=NAME or lsl://?type=Markers:
    /// a string stream, such as a stimulus program's markers) into
    /// `--out`'s events.csv, beside the events the source carries itself
    /// (Pupil Capture's annotations); repeatable.
    #[arg(long = "events", value_name = "URI")]
    pub events: Vec<String>,
    /// Render both eyes every frame, each on its own gaze (where the
    /// tracker gives one per eye) and pupil: pooling, adaptation, glare
    /// kernel and acuity per eye. The window, `--out` frames and the status
    /// page show left | right side by side; `timeline.csv` has per-eye
    /// columns, `psf.csv` a `view` column.
    #[arg(long)]
    pub stereo: bool,
}

/// Where a live run's frames go (`--display`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DisplayMode {
    Window,
    Xr,
    None,
}

/// The settings of a run after merging the file and the flags.
struct Resolved {
    uri: String,
    fps: f64,
    size: (usize, usize),
    secs: Option<f64>,
    out: Option<PathBuf>,
    calibration: Option<PathBuf>,
    head: HeadSpec,
    headless: bool,
    /// `--display xr`.
    xr: bool,
    relay: Option<SocketAddr>,
    http: Option<SocketAddr>,
    config: ServiceConfig,
}

fn resolve(args: &RunArgs) -> anyhow::Result<Resolved> {
    let config = match &args.config {
        Some(p) => ServiceConfig::load(p)?,
        None => ServiceConfig::default(),
    };
    let fps = match args.fps {
        Some(f) => service_config::check_fps(f).map_err(|e| anyhow::anyhow!("--fps {e}"))?,
        None => config.display.fps.unwrap_or(DEFAULT_FPS),
    };
    let size = match (args.size, &config.display.size) {
        (Some(s), _) => s,
        // Validated on load.
        (None, Some(s)) => service_config::parse_size(s).map_err(|e| anyhow::anyhow!(e))?,
        (None, None) => (720, 800),
    };
    if let Some(s) = args.secs {
        crate::bounds::secs("--secs", s)?;
    }
    let head = match (&args.head, &config.scene.head) {
        (Some(h), _) => h.clone(),
        (None, Some(h)) => service_config::parse_head(h).map_err(|e| anyhow::anyhow!(e))?,
        (None, None) => HeadSpec::Fixed,
    };
    let xr = args.display == Some(DisplayMode::Xr);
    let headless = args.headless
        || matches!(args.display, Some(DisplayMode::None | DisplayMode::Xr))
        || (args.display.is_none() && config.display.headless.unwrap_or(false));
    if xr && (args.mouse_gaze || head == HeadSpec::Mouse) {
        bail!(
            "--display xr: the gaze and head come from the tracker and the headset, not the mouse"
        );
    }
    if xr && args.backend == BackendChoice::Cpu {
        bail!(
            "--display xr renders on the OpenXR runtime's GPU device: drop --backend cpu \
             (the CPU pipeline cannot write the runtime's swapchain images without a host round trip)"
        );
    }
    if headless && args.mouse_gaze {
        bail!("--mouse-gaze needs the window: drop --headless");
    }
    if headless && head == HeadSpec::Mouse {
        head::require_window("--head mouse")?;
    }
    // Validated on load.
    let addr = |a: &Option<String>| -> anyhow::Result<Option<SocketAddr>> {
        a.as_deref()
            .map(service_config::parse_addr)
            .transpose()
            .map_err(|e| anyhow::anyhow!(e))
    };
    let relay = match args.relay {
        Some(a) => Some(a),
        None => addr(&config.relay.addr)?,
    };
    let http = match args.http {
        Some(a) => Some(a),
        None => addr(&config.http.addr)?,
    };
    Ok(Resolved {
        headless,
        xr,
        relay,
        http,
        uri: args
            .source
            .clone()
            .or_else(|| config.source.uri.clone())
            .unwrap_or_else(|| DEFAULT_SOURCE.to_owned()),
        fps,
        size,
        secs: args.secs,
        out: args.out.clone().or_else(|| config.output.dir.clone()),
        calibration: args
            .calibration
            .clone()
            .or_else(|| config.source.calibration.clone()),
        head,
        config,
    })
}

/// Every setting of a run and where it came from (flag, `--config`, the
/// calibration profile, default).
fn run_settings(
    args: &RunArgs,
    r: &Resolved,
    cfg: &ServiceConfig,
    scene: &Scene,
    scale: gazelight_vision::scene::LuminanceScale,
    view: &gazelight_vision::scene::ViewParams,
    calibration: &PupilCalibration,
) -> SessionSettings {
    let mut s = SessionSettings::new("run", args.config.as_deref(), &[]);
    let c = cfg;
    s.set(
        "source.uri",
        &r.uri,
        Origin::first(args.source.as_ref(), c.source.uri.as_ref(), None),
    );
    s.set(
        "display.fps",
        r.fps,
        Origin::first(args.fps, c.display.fps, None),
    );
    s.set(
        "view.size",
        format!("{}x{}", r.size.0, r.size.1),
        Origin::first(args.size, c.display.size.as_ref().map(|_| (0, 0)), None),
    );
    s.set(
        "scene.head",
        format!("{:?}", r.head),
        Origin::first(
            args.head.as_ref(),
            c.scene.head.as_ref().map(|_| &r.head),
            None,
        ),
    );
    s.set(
        "scene.file",
        &scene.name,
        Origin::first(args.scene.as_ref(), c.scene.file.as_ref(), None),
    );
    let v = &args.view;
    let scale_origin = Origin::first(
        v.luminance_scale.or(v.scene_key_cd_m2),
        c.scene.luminance_scale.map(|_| 0.0),
        None,
    );
    s.set("scene.luminance_scale", scale, scale_origin);
    s.set("scene.cd_m2_per_unit", scene.cd_m2_per_unit, scale_origin);
    s.set_view(
        view,
        v.angle_flags(),
        crate::view_args::ViewDefaults {
            yaw_deg: c.scene.yaw_deg,
            pitch_deg: c.scene.pitch_deg,
            hfov_deg: c.scene.hfov_deg,
        },
    );
    s.set_observer(
        &cfg.pipeline.glare.psf,
        &args.observer.flags(),
        &c.observer,
        r.calibration.as_ref().map(|_| calibration.observer),
    );
    s.set_calibration(
        r.calibration.as_deref(),
        r.calibration.as_ref().map(|_| calibration),
        Origin::first(
            args.calibration.as_ref(),
            c.source.calibration.as_ref(),
            None,
        ),
    );
    s.set_models(&cfg.pipeline, cfg.filter, args.config.is_some());
    s.set_backend(args.backend);
    s
}

/// `GAZELIGHT_PARSE_ONLY`: the configuration file loaded and validated, the
/// flags resolved against it as [`run`] does before it opens anything, and
/// the source URI parsed.
pub fn check(args: &RunArgs) -> anyhow::Result<()> {
    let r = resolve(args)?;
    check_events(args, &r)?;
    gazelight_tracker::uri::SourceUri::parse(&r.uri)
        .map(|_| ())
        .map_err(|e| anyhow::anyhow!("--source {}: {e}", r.uri))
}

/// `--events`: each an LSL URI, and an `--out` to write them to.
fn check_events(args: &RunArgs, r: &Resolved) -> anyhow::Result<()> {
    use gazelight_tracker::uri::SourceUri;
    for uri in &args.events {
        match SourceUri::parse(uri) {
            Ok(SourceUri::Lsl(_)) => {}
            Ok(_) => bail!(
                "--events {uri}: events are read from an LSL marker stream \
                 (lsl://?name=NAME or lsl://?type=Markers); a pupil:// source's annotations \
                 come with it"
            ),
            Err(e) => bail!("--events {uri}: {e}"),
        }
    }
    if !args.events.is_empty() && r.out.is_none() {
        bail!("--events writes the markers to --out's events.csv: give --out DIR");
    }
    Ok(())
}

/// Checks (and with `--force` clears) `--out` against the run's inputs:
/// the scene, calibration, configuration, head trace and a `replay://`
/// recording.
fn prepare_out(args: &RunArgs, r: &Resolved, scene: Option<&Path>) -> anyhow::Result<()> {
    let Some(out) = &r.out else { return Ok(()) };
    let replayed = match gazelight_tracker::uri::SourceUri::parse(&r.uri) {
        Ok(gazelight_tracker::uri::SourceUri::Replay { path, .. }) => Some(path),
        _ => None,
    };
    let head = match &r.head {
        HeadSpec::Trace(p) => Some(p.as_path()),
        _ => None,
    };
    let inputs: Vec<&Path> = [
        scene,
        r.calibration.as_deref(),
        args.config.as_deref(),
        head,
        replayed.as_deref(),
    ]
    .into_iter()
    .flatten()
    .collect();
    Ok(crate::out_dir::prepare(
        "run",
        out,
        crate::out_dir::OutKind::Frames,
        &inputs,
        args.force,
    )?)
}

/// Runs `gazelight run`.
pub fn run(args: RunArgs) -> anyhow::Result<()> {
    let r = resolve(&args)?;
    check_events(&args, &r)?;
    let cfg = &r.config;

    // Scene and view.
    let scale = args.view.scale(cfg.scene.luminance_scale)?;
    scale.validate().context("luminance scale")?;
    let scene_path = args.scene.clone().or_else(|| cfg.scene.file.clone());
    let mut scene = match &scene_path {
        Some(p) => Scene::load(p, scale)?,
        None => Scene::from_bytes(demo::NIGHT_EXR, demo::name_path(), scale)?,
    };
    args.view
        .apply_projection(&mut scene, cfg.scene.projection_settings()?)?;
    crate::bounds::scene_luminance(&scene)?;
    let base = demo::default_view(r.size.0, r.size.1);
    let view = args.view.view(
        crate::view_args::ViewDefaults {
            yaw_deg: cfg.scene.yaw_deg,
            pitch_deg: cfg.scene.pitch_deg,
            hfov_deg: cfg.scene.hfov_deg,
        },
        base,
        r.size,
    );
    let projection = PanoramaView::new(view).context("view")?;
    let mut view_img = RgbImage::new(view.width, view.height);
    let no_data = projection.render_scene(&scene, &mut view_img);
    if no_data > 0 {
        tracing::warn!(
            scene = %scene.name,
            "{no_data} of {} view pixels look outside the scene's field: no data: left out of pooling and glare, drawn as a dark hatch in PNG frames, NaN in EXR frames",
            view.width * view.height
        );
    }
    let head = match &r.head {
        HeadSpec::Fixed => Head::Fixed,
        HeadSpec::Trace(p) => Head::Trace(HeadTrace::load(p)?),
        // Driven by the window's cursor (refused headless in `resolve`).
        HeadSpec::Mouse => Head::Fixed,
    };
    // The frame shown and written: one view, or left | right (an OpenXR
    // session is always stereo).
    let stereo = args.stereo || r.xr;
    let views = if stereo { 2 } else { 1 };
    let window = (!r.headless).then(|| {
        (
            DisplaySlot::new((view.width * views) as u32, view.height as u32),
            Arc::new(MouseGaze::default()),
        )
    });
    let mouse = window.as_ref().and_then(|(_, cursor)| {
        (args.mouse_gaze || r.head == HeadSpec::Mouse).then(|| MouseControl {
            cursor: cursor.clone(),
            gaze: args.mouse_gaze,
            head: r.head == HeadSpec::Mouse,
        })
    });
    let display = window.as_ref().map(|(slot, _)| slot.clone());
    // The window (main thread) and the session (below) stop each other.
    let session_done = Arc::new(AtomicBool::new(false));
    let window_closed = Arc::new(AtomicBool::new(false));

    // Filter chain (+ calibration).
    let calibration = match &r.calibration {
        Some(p) => PupilCalibration::load(p)
            .with_context(|| format!("calibration profile {}", p.display()))?,
        None => PupilCalibration::identity(),
    };
    // The observer: flags, else [observer], else the profile's.
    let observed = {
        let mut c = cfg.clone();
        crate::observer::apply(
            &mut c.pipeline.glare.psf,
            &args.observer,
            Some(&cfg.observer),
            r.calibration.as_ref().map(|_| &calibration.observer),
        )?;
        c
    };
    let cfg = &observed;
    let settings = run_settings(&args, &r, cfg, &scene, scale, &view, &calibration);
    let chain = FilterChain::new(cfg.filter, calibration)
        .map_err(|e| anyhow::anyhow!("filter configuration: {e}"))?;

    // Outputs: the inputs are checked; now where the outputs go.
    prepare_out(&args, &r, scene_path.as_deref())?;
    // The events of the source and of --events, for --out's events.csv.
    let events = r
        .out
        .as_ref()
        .map(|_| Arc::new(gazelight_tracker::live_events::EventQueue::default()));
    let writer = match &r.out {
        Some(dir) => {
            let mut psf = cfg.pipeline.glare.psf.clone();
            psf.ppd = view.ppd();
            if r.xr && !args.no_frames {
                tracing::info!(
                    "--display xr: --out writes timeline.csv, psf.csv and xr.csv, no frame images \
                     (they stay on the GPU, in the runtime's swapchain)"
                );
            }
            Some(OutputWriter::start(
                dir,
                view.width * views,
                view.height,
                psf,
                !args.no_frames && !r.xr,
                stereo,
                events.clone(),
            )?)
        }
        None => None,
    };

    if let Some(dir) = &r.out {
        settings.write(dir)?;
    }
    print!("{}", settings.summary());

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .thread_name("gazelight-io")
        .build()
        .context("cannot start the tokio runtime")?;
    let session = || {
        runtime.block_on(async {
        // SIGINT, SIGTERM and SIGHUP end the run the same way (registered
        // before the source starts, so none of them kills the process with
        // half-written outputs).
        let signals = crate::shutdown::Signals::new()
            .context("cannot install the SIGINT/SIGTERM/SIGHUP handlers")?;
        let source = source_task::open_source_with(
            &r.uri,
            chain,
            &DemoContext {
                view: &view,
                view_img: &view_img,
            },
            &cfg.lsl,
            events.clone(),
        )?;
        let hub = source.hub.clone();
        // --events: each marker stream read by its own thread until the
        // session ends (dropped with `_markers`).
        let _markers = match &events {
            Some(q) => args
                .events
                .iter()
                .map(|uri| {
                    let m = gazelight_tracker::transport::open_markers(uri, &cfg.lsl, q.clone())
                        .with_context(|| format!("--events {uri}"))?;
                    tracing::info!(markers = %m.describe(), "reading events");
                    anyhow::Ok(m)
                })
                .collect::<anyhow::Result<Vec<_>>>()
                .inspect_err(|_| hub.request_shutdown())?,
            None => Vec::new(),
        };
        hub.set_settings(settings.clone());
        tracing::info!(
            source = %source.describe,
            scene = %scene.name,
            size = %format!("{}x{}", view.width, view.height),
            fps = r.fps,
            "running"
        );

        // Observers of the hub: the Pupil-compatible relay and the status
        // server. Both run until the hub's shutdown.
        let endpoints = async {
            let relay = match r.relay {
                Some(addr) => {
                    let h = crate::relay::spawn(hub.clone(), addr)
                        .await
                        .with_context(|| format!("--relay {addr}"))?;
                    tracing::info!(remote = %h.local_addr(), sub_port = h.sub_port(), "relay: Pupil Remote listening");
                    Some(h)
                }
                None => None,
            };
            let http = match r.http {
                Some(addr) => {
                    let h = crate::serve::spawn(hub.clone(), addr)
                        .await
                        .with_context(|| format!("--http {addr}"))?;
                    tracing::info!("status page at http://{}/", h.local_addr());
                    Some(h)
                }
                None => None,
            };
            anyhow::Ok((relay, http))
        }
        .await;
        let (relay, http) = match endpoints {
            Ok(e) => e,
            Err(e) => {
                hub.request_shutdown();
                return Err(e);
            }
        };
        // LSL outlets (eye, frame, markers), fed without blocking.
        let lsl = if args.lsl || cfg.lsl.outlets {
            match crate::lsl_outlets::LslOutlets::start(
                &cfg.lsl,
                hub.clone(),
                source.age_clock,
                r.fps,
                0.0,
            ) {
                Ok(o) => Some(o),
                Err(e) => {
                    hub.request_shutdown();
                    return Err(e.into());
                }
            }
        } else {
            None
        };

        // A signal, --secs and closing the window end the run the same way.
        {
            let hub = hub.clone();
            let closed = window_closed.clone();
            tokio::spawn(async move {
                let mut tick = tokio::time::interval(Duration::from_millis(50));
                while !hub.shutting_down() {
                    tick.tick().await;
                    if closed.load(Ordering::Relaxed) {
                        tracing::info!("window closed: shutting down");
                        hub.request_shutdown();
                    }
                }
            });
        }
        {
            let hub = hub.clone();
            tokio::spawn(async move {
                let name = signals.first().await;
                tracing::info!("{name}: shutting down");
                hub.request_shutdown();
            });
        }
        if let Some(secs) = r.secs {
            let hub = hub.clone();
            // Bounded in `resolve` (0 < secs ≤ 30 days).
            let secs = crate::bounds::secs("--secs", secs)?;
            tokio::spawn(async move {
                tokio::time::sleep(secs).await;
                hub.request_shutdown();
            });
        }

        let setup = FrameLoopSetup {
            hub: hub.clone(),
            age_clock: source.age_clock,
            adaptation: source.adaptation.clone(),
            pipeline: cfg.pipeline.clone(),
            backend: args.backend,
            pano: scene,
            view,
            head,
            fps: r.fps,
            writer,
            display,
            mouse,
            stereo,
            device: None,
        };
        let (done_tx, done_rx) = tokio::sync::oneshot::channel();
        let xr_display = r.xr;
        let thread_hub = hub.clone();
        std::thread::Builder::new()
            .name("gazelight-frames".into())
            .spawn(move || {
                let result = if xr_display {
                    xr::run(setup).map(|(s, x)| (s, Some(x)))
                } else {
                    FrameLoop::new(setup)
                        .and_then(FrameLoop::run)
                        .map(|s| (s, None))
                };
                thread_hub.request_shutdown();
                let _ = done_tx.send(result);
            })
            .context("cannot start the frame loop thread")?;
        let result = done_rx
            .await
            .map_err(|_| anyhow::anyhow!("the frame loop thread panicked"))
            .and_then(|r| r);
        hub.request_shutdown();
        for task in source.tasks {
            if tokio::time::timeout(Duration::from_secs(3), task)
                .await
                .is_err()
            {
                tracing::warn!("a source task did not stop within 3 s");
            }
        }
        // The relay and the status server stop on the hub's shutdown.
        if let Some(h) = relay {
            let stats = h.stats();
            tracing::info!(?stats, pub_port = h.pub_port(), "relay stopped");
            let _ = tokio::time::timeout(Duration::from_secs(2), h.join()).await;
        }
        if let Some(h) = http {
            let stats = h.stats();
            tracing::info!(?stats, "status server stopped");
            let _ = tokio::time::timeout(Duration::from_secs(2), h.join()).await;
        }
        if let Some(o) = lsl {
            o.finish().await;
        }
        let status = hub.source();
        result.map(|s| (s, status))
    })
    };
    let mut window_stats = None;
    let summary = match window {
        None => session(),
        Some((slot, cursor)) => std::thread::scope(|scope| {
            let worker = scope.spawn(|| {
                let r = session();
                session_done.store(true, Ordering::Relaxed);
                r
            });
            let options = WindowOptions {
                title: format!("gazelight — {}", r.uri),
                width: (view.width * views) as u32,
                height: view.height as u32,
                fullscreen: args.fullscreen,
            };
            let done = session_done.clone();
            let closed = window_closed.clone();
            let shown = window::run(
                options,
                Content::Frames(slot.clone()),
                Some(cursor),
                move || done.load(Ordering::Relaxed),
                move || closed.store(true, Ordering::Relaxed),
            );
            match shown {
                Ok(stats) => {
                    tracing::info!(
                        presented = stats.presented,
                        skipped = slot.skipped(),
                        "window closed"
                    );
                    window_stats = Some(stats);
                }
                Err(e) => {
                    eprintln!("no window ({e:#}); running headless");
                }
            }
            worker
                .join()
                .unwrap_or_else(|_| Err(anyhow::anyhow!("the session thread panicked")))
        }),
    };
    runtime.shutdown_timeout(Duration::from_secs(1));
    let ((summary, xr_report), source) = summary?;
    print_summary(&summary, r.fps, &source, r.out.as_deref());
    if let Some(x) = &xr_report {
        print_xr(x, &summary);
    }
    print_display(&summary, window_stats.as_ref());
    // A write error (a full disk) was printed when it happened and in the
    // summary; the run still ends with an error, as its outputs are cut.
    if let Some(w) = &summary.writer
        && !w.errors.is_empty()
    {
        bail!(
            "--out {}: {} output file(s) stopped early: {}",
            r.out
                .as_deref()
                .map_or_else(String::new, |d| d.display().to_string()),
            w.errors.len(),
            w.errors.join("; ")
        );
    }
    Ok(())
}

/// What the OpenXR session did (the lines `.ci/xr/run` checks).
fn print_xr(x: &xr::XrReport, s: &RunSummary) {
    let [l, r] = x.first_positions_m;
    let ipd_mm =
        ((l[0] - r[0]).powi(2) + (l[1] - r[1]).powi(2) + (l[2] - r[2]).powi(2)).sqrt() * 1e3;
    println!(
        "xr: {} on {} ({}x{} per eye); states {:?}; focused {}; {} frames submitted, predicted display times {}; eye views {:.1} mm apart; head turned up to {:.2}°; EyeState age at display median {:.2} ms, p99 {:.2} ms; eye gaze from {}; extensions {}",
        x.system,
        x.runtime,
        x.eye_size_px[0],
        x.eye_size_px[1],
        x.states,
        if x.focused_reached { "yes" } else { "no" },
        x.frames_submitted,
        if x.display_times_increasing {
            "increasing"
        } else {
            "NOT increasing"
        },
        ipd_mm,
        x.max_head_turn_deg,
        s.eye_state_age_median_ms,
        s.eye_state_age_p99_ms,
        if x.eye_gaze {
            "the runtime"
        } else {
            "the tracker"
        },
        x.extensions.join(" "),
    );
}

/// One line on where the frames went: presented by the window (and how
/// late), uploaded, read back from the GPU.
fn print_display(s: &RunSummary, w: Option<&window::WindowStats>) {
    match w {
        Some(w) => println!(
            "display: window presented {} images, {} frames shown ({}), {} uploaded, {} frames read back; render to present median {:.2} ms, p99 {:.2} ms",
            w.presented,
            w.frames_shown,
            if w.on_pipeline_device {
                "drawn from the GPU pipeline's output buffer"
            } else {
                "host frames"
            },
            w.frames_uploaded,
            s.frames_read_back,
            w.latency_quantile_ms(0.5),
            w.latency_quantile_ms(0.99),
        ),
        None => println!(
            "display: no window, {} frames read back",
            s.frames_read_back
        ),
    }
}

fn print_summary(
    s: &RunSummary,
    fps: f64,
    source: &gazelight_tracker::live::SourceStatus,
    out: Option<&std::path::Path>,
) {
    println!(
        "run: {} frames in {:.1} s ({:.1} Hz, target {fps} Hz), {} late, {} dropped deadlines ({} of them in the {} frames beside a PSF build or install), {:.1} ms/frame; EyeState age median {:.2} ms, p99 {:.2} ms, max {:.1} ms; {} PSF rebuilds ({} kernels built, {} of them partly beside frames); source {} ({:?}, {} samples, {} reconnects)",
        s.frames,
        s.wall_secs,
        s.frames as f64 / s.wall_secs.max(1e-9),
        s.frames_late,
        s.frames_dropped,
        s.frames_dropped_near_rebuilds,
        s.frames_near_rebuilds,
        s.mean_frame_ms,
        s.eye_state_age_median_ms,
        s.eye_state_age_p99_ms,
        s.eye_state_age_max_ms,
        s.psf_rebuilds,
        s.kernels_built,
        s.kernels_unpaced,
        source.uri,
        source.health,
        source.samples_total,
        source.reconnects,
    );
    if let (Some(dir), Some(w)) = (out, &s.writer) {
        println!(
            "wrote {}/{{timeline.csv ({} rows), psf.csv ({} kernels), frames/ ({} images, {} skipped while the encoder was busy)}}",
            dir.display(),
            w.rows,
            w.psf_rows,
            w.frames_written,
            s.frames_not_written
        );
        if let Some(n) = w.events {
            println!(
                "wrote {}/events.csv ({n} events, {} dropped: more than the queue holds)",
                dir.display(),
                w.events_dropped
            );
        }
        for e in &w.errors {
            println!("write error: {e}");
        }
    }
}
