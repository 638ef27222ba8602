//! `gazelight run`: a live session. A tracker source (default Pupil Core
//! at `pupil://127.0.0.1:50020`; `replay://PATH`, `synthetic://demo`) runs
//! through the filter chain on a tokio runtime and publishes the latest
//! `EyeState` on the hub's `watch` channel; the frame loop — a dedicated
//! thread at the display rate — renders the panorama view for the head
//! orientation through the perception pipeline, reading the newest state
//! without ever waiting for it, and records the age of the state each frame
//! used (see DESIGN.md, "Runtime").
//!
//! Ctrl-C or `--secs` ends the run: the hub's shutdown is requested, the
//! frame loop finishes its frame, the outputs are flushed and a summary
//! (frames, late frames, `EyeState` age median/p99) is printed.
//!
//! This build is headless (frames go to `--out` and the hub); the window
//! (winit + wgpu) is future work.

pub mod frame_loop;
pub mod head;
pub mod source_task;
pub mod writer;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, bail};
use clap::Args;
use gazelight_tracker::calibration::PupilCalibration;
use gazelight_tracker::filter::FilterChain;
use gazelight_vision::RgbImage;
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

use crate::demo;
use crate::service_config::{self, HeadSpec, ServiceConfig};
use frame_loop::{FrameLoop, FrameLoopSetup, RunSummary};
use head::{Head, HeadTrace};
use source_task::{DemoContext, open_source};
use writer::OutputWriter;

/// The default source: Pupil Capture's Pupil Remote on this machine.
pub const DEFAULT_SOURCE: &str = "pupil://127.0.0.1:50020";
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
    /// Head yaw, degrees (positive right).
    #[arg(long, allow_hyphen_values = true)]
    pub yaw_deg: Option<f64>,
    /// Head pitch, degrees (positive up).
    #[arg(long, allow_hyphen_values = true)]
    pub pitch_deg: Option<f64>,
    /// Horizontal field of view, degrees.
    #[arg(long)]
    pub hfov_deg: Option<f64>,
    /// Display size per eye, WIDTHxHEIGHT (default 720x800).
    #[arg(long, value_name = "WxH", value_parser = service_config::parse_size)]
    pub size: Option<(usize, usize)>,
    /// Display rate, Hz (default 90).
    #[arg(long, value_name = "HZ")]
    pub fps: Option<f64>,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long, value_name = "S")]
    pub secs: Option<f64>,
    /// Write frames, timeline.csv and psf.csv into this directory.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// With --out: write timeline.csv and psf.csv only, no frame images.
    #[arg(long)]
    pub no_frames: bool,
    /// Run with no window (this build has none yet: always headless).
    #[arg(long)]
    pub headless: bool,
    /// Calibration profile (JSON, calibration/schema.json) mapping the
    /// tracker's raw pupil units onto millimetres.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
    /// Use the mouse as gaze (development without a tracker; needs a
    /// window).
    #[arg(long)]
    pub mouse_gaze: bool,
    /// cd/m² per scene-file unit.
    #[arg(long, conflicts_with = "scene_key_cd_m2")]
    pub luminance_scale: Option<f64>,
    /// Scale the scene so its median luminance is this many cd/m².
    #[arg(long)]
    pub scene_key_cd_m2: Option<f64>,
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
    if let Some(s) = args.secs
        && !(s.is_finite() && s > 0.0)
    {
        bail!("--secs {s}: expected a duration > 0");
    }
    let head = match (&args.head, &config.scene.head) {
        (Some(h), _) => h.clone(),
        (None, Some(h)) => service_config::parse_head(h).map_err(|e| anyhow::anyhow!(e))?,
        (None, None) => HeadSpec::Fixed,
    };
    let headless = args.headless || config.display.headless.unwrap_or(false);
    if !headless {
        tracing::warn!(
            "this build has no window yet: running headless (frames go to --out and the hub)"
        );
    }
    if args.mouse_gaze {
        tracing::warn!(
            "--mouse-gaze is only meaningful with a window, and this run has none: ignored"
        );
    }
    if head == HeadSpec::Mouse {
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

/// Runs `gazelight run`.
pub fn run(args: RunArgs) -> anyhow::Result<()> {
    let r = resolve(&args)?;
    let cfg = &r.config;

    // Scene and view.
    let scale = match (args.luminance_scale, args.scene_key_cd_m2) {
        (Some(factor), _) => LuminanceScale::CdM2PerUnit { factor },
        (None, Some(key_cd_m2)) => LuminanceScale::MedianKey { key_cd_m2 },
        (None, None) => cfg.scene.luminance_scale.unwrap_or_default(),
    };
    scale.validate().context("luminance scale")?;
    let scene_path = args.scene.clone().or_else(|| cfg.scene.file.clone());
    let scene = match &scene_path {
        Some(p) => Scene::load(p, scale)?,
        None => Scene::from_bytes(demo::NIGHT_EXR, demo::name_path(), scale)?,
    };
    let base = demo::default_view(r.size.0, r.size.1);
    let view = ViewParams {
        yaw_deg: args.yaw_deg.or(cfg.scene.yaw_deg).unwrap_or(base.yaw_deg),
        pitch_deg: args
            .pitch_deg
            .or(cfg.scene.pitch_deg)
            .unwrap_or(base.pitch_deg),
        hfov_deg: args
            .hfov_deg
            .or(cfg.scene.hfov_deg)
            .unwrap_or(base.hfov_deg),
        width: r.size.0,
        height: r.size.1,
    };
    let projection = PanoramaView::new(view).context("view")?;
    let mut view_img = RgbImage::new(view.width, view.height);
    projection.render(&scene.image, &mut view_img);
    let head = match &r.head {
        HeadSpec::Fixed => Head::Fixed,
        HeadSpec::Trace(p) => Head::Trace(HeadTrace::load(p)?),
        HeadSpec::Mouse => unreachable!("refused in resolve"),
    };

    // Filter chain (+ calibration).
    let calibration = match &r.calibration {
        Some(p) => PupilCalibration::load(p)
            .with_context(|| format!("calibration profile {}", p.display()))?,
        None => PupilCalibration::identity(),
    };
    let chain = FilterChain::new(cfg.filter, calibration)
        .map_err(|e| anyhow::anyhow!("filter configuration: {e}"))?;

    // Outputs.
    let writer = match &r.out {
        Some(dir) => {
            let mut psf = cfg.pipeline.glare.psf.clone();
            psf.ppd = view.ppd();
            Some(OutputWriter::start(
                dir,
                view.width,
                view.height,
                psf,
                !args.no_frames,
            )?)
        }
        None => None,
    };

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .thread_name("gazelight-io")
        .build()
        .context("cannot start the tokio runtime")?;
    let summary = runtime.block_on(async {
        let source = open_source(
            &r.uri,
            chain,
            &DemoContext {
                view: &view,
                view_img: &view_img,
            },
        )?;
        let hub = source.hub.clone();
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
        let _endpoints = match endpoints {
            Ok(e) => e,
            Err(e) => {
                hub.request_shutdown();
                return Err(e);
            }
        };

        // Ctrl-C and --secs end the run the same way.
        {
            let hub = hub.clone();
            tokio::spawn(async move {
                if tokio::signal::ctrl_c().await.is_ok() {
                    tracing::info!("Ctrl-C: shutting down");
                    hub.request_shutdown();
                }
            });
        }
        if let Some(secs) = r.secs {
            let hub = hub.clone();
            tokio::spawn(async move {
                tokio::time::sleep(Duration::from_secs_f64(secs)).await;
                hub.request_shutdown();
            });
        }

        let setup = FrameLoopSetup {
            hub: hub.clone(),
            age_clock: source.age_clock,
            adaptation: source.adaptation.clone(),
            pipeline: cfg.pipeline.clone(),
            filter: cfg.filter,
            pano: scene.image,
            view,
            head,
            fps: r.fps,
            writer,
        };
        let (done_tx, done_rx) = tokio::sync::oneshot::channel();
        let thread_hub = hub.clone();
        std::thread::Builder::new()
            .name("gazelight-frames".into())
            .spawn(move || {
                let result = FrameLoop::new(setup).and_then(FrameLoop::run);
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
        let status = hub.source();
        result.map(|s| (s, status))
    });
    runtime.shutdown_timeout(Duration::from_secs(1));
    let (summary, source) = summary?;
    print_summary(&summary, r.fps, &source, r.out.as_deref());
    Ok(())
}

fn print_summary(
    s: &RunSummary,
    fps: f64,
    source: &crate::hub::SourceStatus,
    out: Option<&std::path::Path>,
) {
    println!(
        "run: {} frames in {:.1} s ({:.1} Hz, target {fps} Hz), {} late, {} dropped deadlines, {:.1} ms/frame; EyeState age median {:.2} ms, p99 {:.2} ms, max {:.1} ms; {} PSF rebuilds; source {} ({:?}, {} samples, {} reconnects)",
        s.frames,
        s.wall_secs,
        s.frames as f64 / s.wall_secs.max(1e-9),
        s.frames_late,
        s.frames_dropped,
        s.mean_frame_ms,
        s.eye_state_age_median_ms,
        s.eye_state_age_p99_ms,
        s.eye_state_age_max_ms,
        s.psf_rebuilds,
        source.uri,
        source.health,
        source.samples_total,
        source.reconnects,
    );
    if let (Some(dir), Some(w)) = (out, s.writer) {
        println!(
            "wrote {}/{{timeline.csv ({} rows), psf.csv ({} kernels), frames/ ({} images, {} skipped while the encoder was busy)}}",
            dir.display(),
            w.rows,
            w.psf_rows,
            w.frames_written,
            s.frames_not_written
        );
    }
}
