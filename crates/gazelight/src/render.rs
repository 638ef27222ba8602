//! `gazelight render`: a scene + a gaze/pupil trace → PNG frames, a contact
//! sheet, `timeline.csv` and a plot. The per-frame step (the eye state at
//! each frame's time → the frame pipelines → the display frame and the
//! timeline rows) is `gazelight_render`'s, which the Python package's
//! `gazelight.render` runs too; this module adds the flags, the
//! configuration file, the backend choice and the files.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use gazelight_render::analysis::{AnalysisStep, SheetFrames};
use gazelight_render::frame::FrameStep;
use gazelight_render::gaze_glare::{GlareNumbers, ViewGlare};
use gazelight_render::pupil_light::PupilLight;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::profile::PupilCalibration;
use gazelight_tracker::trace_source;
use gazelight_tracker::{GazeTrace, Sample};
use gazelight_vision::RgbImage;
use gazelight_vision::pipeline::PipelineConfig;
use gazelight_vision::scene::{PanoramaView, Scene, ViewParams};

use crate::backend::{BackendChoice, Renderer};
use crate::config::RenderConfig;
use crate::demo;
use crate::output::{self, TimelineRow};
use crate::service_config::ConfigUser;
use crate::session::{Origin, SessionSettings};
use crate::stereo::{MONO, STEREO, View};

/// The frame rate of a rendered sequence unless `--fps` says otherwise.
const DEFAULT_RENDER_FPS: f64 = 30.0;

/// Arguments of `gazelight render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// HDR scene: an equirectangular panorama (OpenEXR or Radiance .hdr).
    /// Default: the embedded night panorama.
    #[arg(long, value_name = "FILE")]
    pub scene: Option<PathBuf>,
    /// Gaze/pupil trace CSV (t_secs,gaze_u,gaze_v,pupil_mm[,confidence]).
    /// Default: on the embedded scene the built-in demo trace (ground →
    /// street lamp → ground); on a scene of your own a slow horizontal
    /// gaze sweep across the view at a fixed 4 mm pupil over 12 s.
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// Output directory (created). Refused when it holds an input or a
    /// recording, or a previous run's outputs (unless --force).
    #[arg(long, value_name = "DIR", default_value = "out")]
    pub out: PathBuf,
    /// Clear a previous run's outputs in --out first (timeline.csv,
    /// session.json, psf.csv, xr.csv, contact_sheet.png, plot.png,
    /// frames/frame_*), so
    /// none is left stale beside the new ones; other files are kept.
    #[arg(long)]
    pub force: bool,
    /// Number of frames (default: the trace's duration × fps).
    #[arg(long, value_name = "N")]
    pub frames: Option<usize>,
    /// Frame rate of the rendered sequence.
    #[arg(long, value_name = "HZ", default_value_t = DEFAULT_RENDER_FPS)]
    pub fps: f64,
    /// Display size per eye, WIDTHxHEIGHT (default 720x800, half the Vive
    /// Pro's 1440x1600).
    #[arg(long, value_name = "WxH", value_parser = crate::service_config::parse_size)]
    pub size: Option<(usize, usize)>,
    #[command(flatten)]
    pub view: crate::view_args::ViewArgs,
    /// TOML configuration (models and parameters); flags override it.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Write only the contact sheet, timeline and plot, not every frame.
    /// The numbers are then computed without the image pipeline (the same
    /// values, the stage timing columns empty); it draws only the contact
    /// sheet's frames (docs/replay.md, "Analysis at study speed").
    #[arg(long)]
    pub no_frames: bool,
    /// Frame pipeline: `gpu` = the wgpu pipeline on the best adapter
    /// (hardware, else a software one such as lavapipe; an error when there
    /// is none); `cpu` = the CPU reference pipeline; `auto` = a hardware GPU
    /// when present, else the CPU, because a software adapter runs on the
    /// same cores and is slower than the CPU pipeline. The choice is logged
    /// and named in the summary.
    #[arg(long, value_enum, default_value_t = BackendChoice::Auto)]
    pub backend: BackendChoice,
    #[command(flatten)]
    pub observer: crate::observer::ObserverArgs,
    /// Also write each frame's retinal image — linear RGB in cd/m² after
    /// glare and acuity, before tone mapping — as frames/frame_NNNNN.exr
    /// (NaN where the view has no data), and the view's CIE 146 veil map,
    /// cd/m², as frames/veil.exr (see docs/lighting-research.md).
    #[arg(long, conflicts_with = "no_frames")]
    pub exr: bool,
    /// Write the PNG frames' pixels without data (outside the scene's
    /// field) as transparent (RGBA, alpha 0), for compositing, instead of
    /// the opaque dark hatch the contact sheet's legend explains.
    #[arg(long, conflicts_with = "no_frames")]
    pub no_data_alpha: bool,
    /// Render both eyes: one pipeline per eye on that eye's own gaze (where
    /// the tracker gives one) and pupil, so pooling, adaptation, glare and
    /// acuity run per eye. Frames are left | right side by side;
    /// `timeline.csv` has per-eye columns (`pupil_mm_left`, …). The eyes
    /// share one glare kernel while their pupils agree.
    #[arg(long)]
    pub stereo: bool,
    /// Also write, per frame and view, the glare along the eye's gaze into
    /// `timeline.csv`: the CIE 146 veil at the gaze (cd/m²) and the DGP
    /// and UGR of its line of sight (`glare_veil_cie146_cd_m2`,
    /// `glare_dgp`, `glare_ugr`, suffixed per view), computed as
    /// `gazelight glare` computes them on the frame's scene view (the
    /// observer's age and pigmentation). Off by default: each frame then
    /// costs a pass over the view's pixels per view.
    #[arg(long)]
    pub glare_numbers: bool,
    /// Run the whole image pipeline for every frame even when no frame
    /// image is written (`--no-frames`). Without it such a run computes
    /// only what its numbers need (`gazelight_render::analysis`, the same
    /// values; docs/replay.md "Analysis at study speed"). For comparing
    /// the two paths and for timing the pipeline.
    #[arg(long, hide = true)]
    pub full_pipeline: bool,
}

/// What makes a run's frames: the image pipeline per view, or, for a run
/// that writes no frame image, only its numbers (and the contact sheet's
/// frames drawn in the state they carried).
enum Frames {
    Full(Box<FrameStep<Renderer>>),
    Numbers(Box<AnalysisStep>, Box<SheetFrames>),
}

/// What `render` and `replay` share: the configuration, the scene and its
/// view for the head orientation.
pub(crate) struct Setup {
    pub config: RenderConfig,
    pub scene: Scene,
    pub view: ViewParams,
    pub view_img: RgbImage,
    /// Every setting in effect and where it came from (printed after the
    /// summary, written as `session.json`).
    pub settings: SessionSettings,
}

/// The configuration (loaded and validated) with the observer flags
/// applied, after the flag checks that need no file but the configuration.
fn load_config(args: &RenderArgs, user: ConfigUser) -> anyhow::Result<RenderConfig> {
    let mut config = match &args.config {
        Some(p) => RenderConfig::load(p, user)?,
        None => RenderConfig::default(),
    };
    let observer = config.observer;
    crate::observer::apply(
        &mut config.pipeline.glare.psf,
        &args.observer,
        Some(&observer),
        None,
    )?;
    crate::bounds::fps("--fps", args.fps)?;
    Ok(config)
}

/// `GAZELIGHT_PARSE_ONLY`: the configuration and flag checks of `render`
/// (and `replay`), nothing loaded or written.
pub(crate) fn check(args: &RenderArgs, user: ConfigUser) -> anyhow::Result<()> {
    load_config(args, user)?;
    if let Some(n) = args.frames {
        crate::bounds::frames(&format!("--frames {n}"), n)?;
    }
    Ok(())
}

/// Loads the configuration (for `user`: `render` or `replay`) and scene and
/// renders the panorama view.
pub(crate) fn prepare(args: &RenderArgs, user: ConfigUser) -> anyhow::Result<Setup> {
    let config = load_config(args, user)?;

    // Scene.
    let scale = args.view.scale(config.luminance_scale)?;
    let scene_path = args.scene.as_ref().or(config.scene_file.as_ref());
    let mut scene = match scene_path {
        Some(path) => Scene::load(path, scale)?,
        None => Scene::from_bytes(demo::NIGHT_EXR, demo::name_path(), scale)?,
    };
    args.view.apply_projection(&mut scene, config.projection)?;
    crate::bounds::scene_luminance(&scene)?;
    if scene.repaired_components > 0 {
        tracing::info!(
            scene = %scene.name,
            "clamped {} negative/NaN values to 0 (lossy compression leaves some)",
            scene.repaired_components
        );
    }
    let (width, height) = args.size.or(config.size).unwrap_or((720, 800));
    let view = args.view.view(
        config.view,
        demo::default_view(width, height),
        (width, height),
    );
    let projection = PanoramaView::new(view).context("view")?;
    let mut view_img = RgbImage::new(width, height);
    let no_data = projection.render_scene(&scene, &mut view_img);
    if no_data > 0 {
        tracing::warn!(
            scene = %scene.name,
            "{no_data} of {} view pixels look outside the scene's field ({}): no data: left out of pooling and glare, drawn as a dark hatch in PNG frames and the contact sheet (transparent with --no-data-alpha), NaN in EXR frames",
            width * height,
            scene.effective_projection().kind.name()
        );
    }

    let mut settings = SessionSettings::new(user.name(), args.config.as_deref(), &config.ignored);
    let v = &args.view;
    let c = &config;
    let scene_origin = Origin::first(args.scene.as_ref(), c.scene_file.as_ref(), None);
    settings.set("scene.file", &scene.name, scene_origin);
    let scale_origin = Origin::first(
        v.luminance_scale.or(v.scene_key_cd_m2),
        c.luminance_scale.map(|_| 0.0),
        None,
    );
    settings.set("scene.luminance_scale", scale, scale_origin);
    let factor = settings.set("scene.cd_m2_per_unit", scene.cd_m2_per_unit, scale_origin);
    if let Some(note) = unscaled_scene_note(scene_path.map(|p| p.as_path()), scale_origin, &scene) {
        tracing::warn!(scene = %scene.name, "{note}");
        factor.note = Some(note);
    }
    settings.set_view(&view, v.angle_flags(), c.view);
    settings.set(
        "view.size",
        format!("{width}x{height}"),
        Origin::first(args.size, c.size, None),
    );
    settings.set_observer(
        &config.pipeline.glare.psf,
        &args.observer.flags(),
        &c.observer,
        None,
    );
    settings.set_models(&config.pipeline, config.filter, args.config.is_some());
    settings.set(
        "render.fps",
        args.fps,
        if args.fps == DEFAULT_RENDER_FPS {
            Origin::Default
        } else {
            Origin::Flag
        },
    );
    settings.set_backend(args.backend);
    Ok(Setup {
        config,
        scene,
        view,
        view_img,
        settings,
    })
}

/// The note (and warning) for a scene file whose values are taken as
/// cd/m² only because no scale was given: OpenEXR (and any non-Radiance
/// file) carries no absolute unit, so a relative panorama would adapt to a
/// meaningless level. `None` for Radiance files (absolute by their 179 lm/W
/// convention), the embedded scene and any scale given by flag or
/// configuration.
fn unscaled_scene_note(
    path: Option<&std::path::Path>,
    origin: Origin,
    scene: &Scene,
) -> Option<String> {
    let path = path?;
    if origin != Origin::Default {
        return None;
    }
    let radiance = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("hdr") || e.eq_ignore_ascii_case("pic"));
    if radiance {
        return None;
    }
    let median = gazelight_vision::scene::median_luminance(&scene.image);
    Some(format!(
        "{} holds no absolute luminance scale and none was given: its values are taken \
         as cd/m² (factor {}), median {median:.3} cd/m²; give --luminance-scale F \
         (cd/m² per file unit) or --scene-key-cd-m2 L, or scene.luminance_scale in the \
         configuration",
        path.display(),
        scene.cd_m2_per_unit
    ))
}

/// Checks (and with `--force` clears) `--out` for `command` (`render` or
/// `replay`) reading `inputs` besides the scene, trace and configuration.
pub(crate) fn prepare_out(
    command: &str,
    args: &RenderArgs,
    inputs: &[&std::path::Path],
) -> anyhow::Result<()> {
    let mut all: Vec<&std::path::Path> = inputs.to_vec();
    all.extend(
        [&args.scene, &args.trace, &args.config]
            .into_iter()
            .flatten()
            .map(PathBuf::as_path),
    );
    Ok(crate::out_dir::prepare(
        command,
        &args.out,
        crate::out_dir::OutKind::Frames,
        &all,
        args.force,
    )?)
}

/// Runs `gazelight render`.
pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let setup = prepare(&args, ConfigUser::Render)?;
    let trace = match &args.trace {
        Some(path) => GazeTrace::load(path)?,
        None if args.scene.is_none() && setup.config.scene_file.is_none() => {
            demo::demo_trace(&setup.view, &setup.view_img)?
        }
        None => demo::sweep_trace(),
    };
    // The inputs are checked; now where the outputs go.
    prepare_out("render", &args, &[])?;
    let t0 = trace.samples.first().map_or(0.0, |s| s.t_secs);
    let duration = trace.duration_secs();
    let samples = trace
        .samples
        .into_iter()
        .flat_map(|s| trace_source::expand(&s, s.t_secs));
    let chain = FilterChain::new(setup.config.filter, PupilCalibration::identity())
        .map_err(|e| anyhow::anyhow!("filter configuration: {e}"))?;
    // A trace's rows are what the user asks for: its pupil holds from one
    // row to the next.
    let mut feeder = SampleFeed::new(samples, chain).hold_between_samples();
    render_sequence(&args, &setup, &mut feeder, t0, duration, started, None)
}

pub(crate) use gazelight_render::feed::SampleFeed;

/// Renders frames from `t0` over `duration_secs` (or `--frames`) and writes
/// the outputs; with `pupil_light` (`replay`), each view's predicted pupil
/// and residual too.
pub(crate) fn render_sequence<I: Iterator<Item = Sample>>(
    args: &RenderArgs,
    setup: &Setup,
    eye: &mut SampleFeed<I>,
    t0: f64,
    duration_secs: f64,
    started: Instant,
    mut pupil_light: Option<&mut PupilLight>,
) -> anyhow::Result<()> {
    let Setup {
        config,
        scene,
        view,
        view_img,
        settings,
    } = setup;
    let (width, height) = (view.width, view.height);
    let frames = match args.frames {
        Some(n) => crate::bounds::frames(&format!("--frames {n}"), n)?,
        None => {
            // Saturating float → int: an absurd span gives usize::MAX and
            // is refused by the bound, never allocated.
            let n = ((duration_secs * args.fps).floor() as usize).saturating_add(1);
            crate::bounds::frames(&format!("{duration_secs:.1} s at --fps {}", args.fps), n)?
        }
    };
    // SIGINT, SIGTERM and SIGHUP stop the sequence after the current frame;
    // what was rendered is written out whole.
    let stop = crate::shutdown::stop_flag();

    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let frames_dir = args.out.join("frames");
    if !args.no_frames {
        std::fs::create_dir_all(&frames_dir)
            .with_context(|| format!("cannot create {}", frames_dir.display()))?;
    }
    if args.exr {
        // The CIE 146 veil of the scene on each direction of the view
        // (one map: it depends on neither the gaze nor the pupil).
        let psf = &config.pipeline.glare.psf;
        let path = frames_dir.join("veil.exr");
        let map = crate::veil_map::write(
            &path,
            scene,
            view,
            psf.age_years,
            psf.pigmentation,
            config.pipeline.pooling_downsample.unwrap_or(8),
        )?;
        println!(
            "veil map (CIE 146, age {} y, pigmentation {}): {} ({}x{} samples, one per {} px)",
            psf.age_years,
            psf.pigmentation,
            path.display(),
            map.width,
            map.height,
            map.step_px
        );
    }

    let views: &[View] = if args.stereo { &STEREO } else { &MONO };
    let n_views = views.len();
    tracing::info!(
        scene = %scene.name,
        size = %format!("{width}x{height}"),
        ppd = format!("{:.2}", view.ppd()),
        frames,
        eyes = n_views,
        "rendering"
    );
    // A run that writes no frame image runs only what its numbers need
    // (`gazelight_render::analysis`: the same rows, stage timings empty).
    let numbers_only = args.no_frames && !args.exr && !args.full_pipeline;
    let mut frames_src = if numbers_only {
        let analysis =
            AnalysisStep::new(args.stereo, &config.pipeline, view, view_img, t0, args.fps)?;
        let sheet = SheetFrames::new(&analysis, &config.pipeline, view)?;
        // Said once, where a renderer says its backend.
        eprintln!(
            "backend: none (--no-frames: the numbers without the image pipeline, \
             the contact sheet's frames on the CPU; --full-pipeline renders every frame)"
        );
        Frames::Numbers(Box::new(analysis), Box::new(sheet))
    } else {
        // The CPU pipeline keeps the retinal image only for the EXR frames.
        let pipeline_config = PipelineConfig {
            keep_retinal: args.exr,
            ..config.pipeline.clone()
        };
        let pipelines = views
            .iter()
            .map(|_| {
                Renderer::new(
                    args.backend,
                    &pipeline_config,
                    width,
                    height,
                    view.deg_per_px(),
                )
                .and_then(|mut r| {
                    // Pooling measures angles through the view's projection.
                    r.set_view_frustum(PanoramaView::new(*view)?.frustum_tans())?;
                    Ok(r)
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        // The per-frame step (gazelight_render::frame, shared with the
        // Python package): state → each view's pipeline → the display
        // frame and rows.
        Frames::Full(Box::new(FrameStep::new(
            pipelines,
            args.stereo,
            &config.pipeline,
            view,
            t0,
            args.fps,
            args.exr,
        )?))
    };
    let mut timeline: Vec<Vec<TimelineRow>> = views
        .iter()
        .map(|_| Vec::with_capacity(frames.min(4096)))
        .collect();
    // timeline.csv is written as the frames are made and flushed every
    // second: a replay killed half-way keeps its rows (the rows are also
    // kept for the plot and the summary, ≤ MAX_FRAMES of them).
    let timeline_path = args.out.join("timeline.csv");
    let suffixes: Vec<&str> = views.iter().map(|v| v.suffix()).collect();
    // The one per-frame writer; its errors name the file.
    let mut timeline_out = gazelight_render::timeline::TimelineWriter::create(
        &timeline_path,
        &suffixes,
        pupil_light.is_some(),
        args.glare_numbers,
    )?;
    // --glare-numbers: the view is the same every frame, so its pixels are
    // prepared once; each frame asks for each view's gaze.
    let view_glare = if args.glare_numbers {
        let psf = &config.pipeline.glare.psf;
        Some(ViewGlare::new(
            view_img,
            view,
            psf.age_years,
            psf.pigmentation,
        )?)
    } else {
        None
    };
    let mut glare_numbers: Vec<GlareNumbers> = Vec::with_capacity(n_views);
    let sheet_every = frames.div_ceil(output::SHEET_TILES).max(1);
    let mut sheet = output::ContactSheet::new(width * n_views, height, n_views > 1);
    let no_data_style = if args.no_data_alpha {
        gazelight_render::png::NoDataStyle::Transparent
    } else {
        gazelight_render::png::NoDataStyle::Hatch
    };
    let progress = indicatif::ProgressBar::new(frames as u64);
    progress.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} {bar:40} {pos}/{len} frames {per_sec} eta {eta}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut rendered = 0usize;
    for i in 0..frames {
        if stop.as_ref().is_some_and(|s| s.requested()) {
            break;
        }
        let mut frame = match &mut frames_src {
            Frames::Full(step) => step.step(eye, view_img)?,
            Frames::Numbers(analysis, _) => analysis.step(eye)?,
        };
        let t_secs = frame.t_secs;
        let rows = &mut frame.rows;
        // The pupil light response: fed every frame with each view's
        // pooled luminance (no allocation).
        if let Some(plr) = pupil_light.as_deref_mut() {
            plr.apply(t_secs - t0, &frame.state, &frame.inputs, rows);
        }
        glare_numbers.clear();
        if let Some(vg) = &view_glare {
            glare_numbers.extend(frame.inputs.iter().map(|(input, _)| vg.at(input.gaze_uv)));
        }
        timeline_out.push_with_glare(&frame.rows, &glare_numbers)?;
        for (k, row) in frame.rows.iter().enumerate() {
            timeline[k].push(*row);
        }
        let on_sheet = i % sheet_every == 0;
        let out = match &mut frames_src {
            Frames::Full(step) => {
                if args.exr {
                    let path = frames_dir.join(format!("frame_{i:05}.exr"));
                    let last: Vec<&TimelineRow> =
                        timeline.iter().filter_map(|r| r.last()).collect();
                    let attributes = exr_frame_attributes(t_secs - t0, i, view, views, &last);
                    gazelight_vision::scene::write_exr_with_attributes(
                        &path,
                        step.retinal(),
                        Some(1.0),
                        &attributes,
                    )
                    .with_context(|| format!("cannot write {}", path.display()))?;
                }
                Some(step.display())
            }
            // Only the contact sheet's frames are drawn.
            Frames::Numbers(analysis, sheet) if on_sheet => {
                Some(sheet.draw(analysis, &frame, view_img)?)
            }
            Frames::Numbers(..) => None,
        };
        if !args.no_frames
            && let Some(out) = out
        {
            let path = frames_dir.join(format!("frame_{i:05}.png"));
            gazelight_render::png::write_styled(
                &path,
                out,
                output::PngCompression::Default,
                no_data_style,
            )?;
        }
        if on_sheet && let Some(out) = out {
            let rows: Vec<&TimelineRow> = timeline.iter().filter_map(|r| r.last()).collect();
            let gaze: Vec<[f32; 2]> = rows
                .iter()
                .enumerate()
                .map(|(k, r)| [(k as f32 + r.gaze_u) / n_views as f32, r.gaze_v])
                .collect();
            let join = |f: &dyn Fn(&TimelineRow) -> f64| {
                rows.iter()
                    .map(|r| output::engineering(f(r)))
                    .collect::<Vec<_>>()
                    .join(" | ")
            };
            let caption = vec![
                format!("t = {:.2} s", t_secs - t0),
                format!("pupil {} mm", join(&|r| f64::from(r.pupil_mm))),
                format!("adapt. {} cd/m²", join(&|r| r.stats.adaptation_cd_m2)),
            ];
            sheet.add(out, &gaze, caption);
        }
        rendered += 1;
        progress.inc(1);
    }
    progress.finish_and_clear();
    let requested = frames;
    let frames = rendered;
    let interrupted = stop.as_ref().and_then(|s| s.signal());
    if let Some(sig) = interrupted
        && frames == 0
    {
        bail!("{sig}: stopped before the first frame; nothing written");
    }
    let eyes: Vec<(&str, &[TimelineRow])> = views
        .iter()
        .zip(&timeline)
        .map(|(v, rows)| (v.suffix(), rows.as_slice()))
        .collect();
    timeline_out.finish()?;
    sheet.write(&args.out.join("contact_sheet.png"))?;
    output::write_plot(
        &args.out.join("plot.png"),
        &eyes,
        config.pipeline.glare.psf.pupil_range_mm,
    )?;
    let all_rows = || timeline.iter().flatten();
    let (stereo_builds, own_gaze_frames) = match &frames_src {
        Frames::Full(step) => (step.stereo_kernel_builds(), step.own_gaze_frames()),
        Frames::Numbers(a, _) => (a.stereo_kernel_builds(), a.own_gaze_frames()),
    };
    let rebuilds = match stereo_builds {
        Some(builds) => builds as usize,
        None => all_rows().filter(|r| r.stats.psf_rebuilt).count(),
    };
    let mut settings = settings.clone();
    let elapsed_secs = started.elapsed().as_secs_f64();
    match &frames_src {
        Frames::Full(step) => {
            let mean_ms = all_rows().map(|r| r.stats.timings.total_ms).sum::<f64>() / frames as f64;
            let backend = step
                .pipelines()
                .first()
                .map_or_else(String::new, Renderer::describe);
            println!(
                "rendered {frames} {}frames ({width}x{height}{}, {:.2} ppd) of {} in {elapsed_secs:.1} s: {mean_ms:.1} ms/frame in the pipeline ({backend}), {rebuilds} PSF rebuilds",
                if n_views > 1 { "stereo " } else { "" },
                if n_views > 1 { " per eye" } else { "" },
                view.ppd(),
                scene.name,
            );
            println!("backend {backend}");
        }
        Frames::Numbers(..) => {
            println!(
                "analysed {frames} {}frames ({width}x{height}{}, {:.2} ppd) of {} in {elapsed_secs:.1} s: numbers only, no image pipeline but the contact sheet's {} frames (CPU), {rebuilds} PSF rebuilds decided",
                if n_views > 1 { "stereo " } else { "" },
                if n_views > 1 { " per eye" } else { "" },
                view.ppd(),
                scene.name,
                frames.div_ceil(sheet_every),
            );
            settings
                .set(
                    "render.path",
                    "numbers only: no frame image is written, so the image pipeline does not \
                     run; each row is computed from the view's block-mean luminance plane \
                     (the same values as the CPU pipeline's); the stage timing columns \
                     (pooling_ms … total_ms) are empty",
                    Origin::Flag,
                )
                .note = Some(
                "--full-pipeline runs the image pipeline anyway (docs/replay.md, \
                 \"Analysis at study speed\"); the contact sheet's frames are drawn by the CPU \
                 pipeline in the state the numbers carried"
                    .to_owned(),
            );
        }
    }
    if n_views == 2 {
        // Said once: in the settings summary below and session.json.
        let (value, note) = per_eye_gaze_setting(own_gaze_frames, rendered);
        settings.set("gaze.per_eye", value, Origin::Source).note = Some(note);
    }
    if let Some(plr) = pupil_light.as_deref() {
        for s in plr.spreads() {
            let eye = if s.suffix.is_empty() {
                String::new()
            } else {
                format!(" ({} eye)", s.suffix.trim_start_matches('_'))
            };
            if s.frames == 0 || !(s.residual_sd_mm.is_finite() && s.raw_sd_mm.is_finite()) {
                // Not a NaN spread: say why there is none.
                println!(
                    "pupil light response{eye}: no residual: no frame has a measured pupil in \
                     mm or in a calibration profile's mm (a raw unit without --calibration)"
                );
                continue;
            }
            println!(
                "pupil light response{eye}: residual SD {:.3} mm vs raw pupil SD {:.3} mm over {} measured frames",
                s.residual_sd_mm, s.raw_sd_mm, s.frames
            );
        }
    }
    settings.write(&args.out)?;
    print!("{}", settings.summary());
    println!(
        "wrote {}/{{{}contact_sheet.png, timeline.csv, plot.png, session.json}}",
        args.out.display(),
        if args.no_frames { "" } else { "frames/, " }
    );
    if let Some(sig) = interrupted {
        bail!(
            "{sig}: stopped after {frames} of {requested} frames; the outputs hold those {frames}"
        );
    }
    Ok(())
}

/// The header attributes of an EXR frame (docs/lighting-research.md): the
/// unit, the eye(s), the frame's time and index, each view's gaze and the
/// view. `rows` are the frame's timeline rows, one per view.
fn exr_frame_attributes(
    t_secs: f64,
    frame: usize,
    view: &ViewParams,
    views: &[View],
    rows: &[&TimelineRow],
) -> Vec<(String, gazelight_vision::scene::ExrAttribute)> {
    use gazelight_vision::scene::ExrAttribute::{F64, Text, Vec2};
    let eye = if views.len() > 1 {
        "left | right (side by side: the left half is the left eye)"
    } else {
        "mono (the binocular gaze)"
    };
    let mut a = vec![
        (
            "gazelight.unit".to_owned(),
            Text(
                "cd/m^2: linear RGB, Y = 0.2126 R + 0.7152 G + 0.0722 B is the luminance; \
                 NaN = no data (outside the scene's field)"
                    .to_owned(),
            ),
        ),
        ("gazelight.eye".to_owned(), Text(eye.to_owned())),
        ("gazelight.t_secs".to_owned(), F64(t_secs)),
        (
            "gazelight.t_clock".to_owned(),
            Text(
                "seconds from the first sample of the trace or recording (timeline.csv's t_secs)"
                    .to_owned(),
            ),
        ),
        ("gazelight.frame".to_owned(), F64(frame as f64)),
        ("gazelight.view.yaw_deg".to_owned(), F64(view.yaw_deg)),
        ("gazelight.view.pitch_deg".to_owned(), F64(view.pitch_deg)),
        ("gazelight.view.hfov_deg".to_owned(), F64(view.hfov_deg)),
        (
            "gazelight.view.size_px".to_owned(),
            Vec2([view.width as f32, view.height as f32]),
        ),
        (
            "gazelight.gaze_uv.convention".to_owned(),
            Text("each view's gaze, u from its left edge, v from its top edge, 0..1".to_owned()),
        ),
    ];
    for (v, row) in views.iter().zip(rows) {
        let name = if views.len() > 1 {
            format!("gazelight.gaze_uv{}", v.suffix())
        } else {
            "gazelight.gaze_uv".to_owned()
        };
        a.push((name, Vec2([row.gaze_u, row.gaze_v])));
    }
    a
}

/// What a stereo render says of its gaze: whether each eye had its own
/// (the source's per-eye gaze) or the binocular gaze stood in, as the
/// `gaze.per_eye` setting (frames with each eye's own gaze, [left, right])
/// and a sentence.
fn per_eye_gaze_setting(own: [usize; 2], frames: usize) -> (serde_json::Value, String) {
    let value = serde_json::json!({ "own_gaze_frames": own, "frames": frames });
    let note = if own == [0, 0] {
        "the source gives no per-eye gaze: the binocular gaze stood in for both eyes".to_owned()
    } else {
        format!(
            "each eye's own gaze from the source in {} (left) and {} (right) of {frames} frames, \
             the binocular gaze in the others",
            own[0], own[1]
        )
    };
    (value, note)
}

#[cfg(test)]
mod tests {
    use clap::Parser;
    use gazelight_vision::scene::LuminanceScale;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        render: RenderArgs,
    }

    /// Renders two frames of a uniform coloured panorama with `--exr`
    /// (and `--config` when given) and returns each frame's EXR read back.
    fn render_uniform(dir: &std::path::Path, rgb: [f32; 3], config: Option<&str>) -> Vec<RgbImage> {
        std::fs::create_dir_all(dir).unwrap();
        let scene_path = dir.join("uniform.exr");
        let scene = RgbImage::from_pixels(128, 64, vec![rgb; 128 * 64]).unwrap();
        gazelight_vision::scene::write_exr(&scene_path, &scene).unwrap();
        let out = dir.join("out");
        let mut argv: Vec<String> = [
            "render",
            "--scene",
            scene_path.to_str().unwrap(),
            "--luminance-scale",
            "1",
            "--size",
            "64x48",
            "--hfov-deg",
            "8",
            "--frames",
            "2",
            "--backend",
            "cpu",
            "--exr",
            "--out",
            out.to_str().unwrap(),
        ]
        .map(String::from)
        .to_vec();
        if let Some(text) = config {
            let path = dir.join("config.toml");
            std::fs::write(&path, text).unwrap();
            argv.extend(["--config".to_owned(), path.to_str().unwrap().to_owned()]);
        }
        run(Cli::try_parse_from(argv).unwrap().render).unwrap();
        (0..2)
            .map(|i| {
                let frames = out.join("frames");
                assert!(frames.join(format!("frame_{i:05}.png")).exists());
                let path = frames.join(format!("frame_{i:05}.exr"));
                let back = Scene::load(&path, LuminanceScale::CdM2PerUnit { factor: 1.0 }).unwrap();
                assert_eq!((back.image.width, back.image.height), (64, 48));
                back.image
            })
            .collect()
    }

    #[test]
    fn exr_frames_are_the_retinal_image_in_cd_m2() {
        let dir = std::env::temp_dir().join(format!("gazelight-exr-{}", std::process::id()));
        let rgb = [6.0f32, 5.0, 4.0];
        // Glare off: acuity leaves L* ≈ 27 alone (σ = 0 above L* = 1), so
        // the retinal image is the scene in cd/m², channel by channel.
        let off = render_uniform(
            &dir.join("off"),
            rgb,
            Some("[pipeline.glare]\nenabled = false\n"),
        );
        for img in &off {
            for p in &img.pixels {
                for c in 0..3 {
                    assert!((p[c] / rgb[c] - 1.0).abs() < 1e-3, "{p:?}");
                }
            }
        }
        // Glare on: energy is moved, not rescaled. The kernel (±20°) is
        // wider than this 8° frame, so light scattered past the edges is
        // lost; the frame's mean stays within 15 % of the scene and the
        // centre brighter than the corners.
        let on = render_uniform(&dir.join("on"), rgb, None);
        for (i, img) in on.iter().enumerate() {
            let n = img.pixels.len() as f64;
            for c in 0..3 {
                let mean = img.pixels.iter().map(|p| f64::from(p[c])).sum::<f64>() / n;
                eprintln!(
                    "exr frame {i} channel {c}: mean {mean:.4} cd/m² (scene {}), centre {:.4}, corner {:.4}",
                    rgb[c],
                    img.get(32, 24)[c],
                    img.get(0, 0)[c]
                );
                assert!((mean / f64::from(rgb[c]) - 1.0).abs() < 0.15, "{c}: {mean}");
                assert!(img.get(32, 24)[c] > img.get(0, 0)[c]);
            }
        }
        // --exr needs the frames.
        assert!(Cli::try_parse_from(["render", "--exr", "--no-frames"]).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A view past a real fisheye's field (evalglare's 182° test image,
    /// turned 60° right with a 90° field), with `--no-data-alpha`: the PNG
    /// frame is written as RGBA and marks exactly the view's no-data
    /// pixels with alpha 0; every other pixel is opaque. (Without the flag
    /// they are an opaque hatch: `tests/images.rs`.)
    #[test]
    fn png_frames_mark_no_data_with_alpha_0_when_asked() {
        let dir = std::env::temp_dir().join(format!("gazelight-nodata-{}", std::process::id()));
        let scene_path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/data/radiance/evalglare_testimage.hdr");
        let out = dir.join("out");
        let argv = [
            "render",
            "--scene",
            scene_path.to_str().unwrap(),
            "--size",
            "96x72",
            "--hfov-deg",
            "90",
            "--yaw-deg",
            "60",
            "--pitch-deg",
            "0",
            "--frames",
            "1",
            "--no-data-alpha",
            "--backend",
            "cpu",
            "--out",
            out.to_str().unwrap(),
        ];
        run(Cli::try_parse_from(argv).unwrap().render).unwrap();
        let png = image::open(out.join("frames").join("frame_00000.png")).unwrap();
        assert!(png.color().has_alpha(), "{:?}", png.color());
        let png = png.to_rgba8();
        // The view's own no-data pixels.
        let scene = Scene::load(&scene_path, LuminanceScale::default()).unwrap();
        let view = gazelight_vision::scene::PanoramaView::new(ViewParams {
            yaw_deg: 60.0,
            pitch_deg: 0.0,
            hfov_deg: 90.0,
            width: 96,
            height: 72,
        })
        .unwrap();
        let mut img = RgbImage::new(96, 72);
        let missing = view.render_scene(&scene, &mut img);
        assert!(missing > 0);
        for (i, p) in img.pixels.iter().enumerate() {
            let a = png.as_raw()[4 * i + 3];
            let want = if gazelight_vision::image::is_no_data(*p) {
                0
            } else {
                255
            };
            assert_eq!(a, want, "pixel {i}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// `render --exr` writes the view's CIE 146 veil map beside the frames.
    /// At map points around a real fisheye's window (evalglare's test
    /// image, a 70-year-old observer with light eyes) its value is the
    /// `veil_cie146_cd_m2` that `gazelight glare` reports (its JSON) for a
    /// gaze in the same direction, within 0.1 %: the map stores f32 and
    /// its directions come from the view's f32 geometry (about 1e-7 rad,
    /// a relative change of the veil under 1e-5 this far from the window
    /// edges' brightest pixels), everything else is the same sum — which
    /// crates/gazelight/tests/radiance.rs checks against the test's own
    /// CIE 146 evaluation.
    #[test]
    fn exr_veil_map_is_the_glare_commands_cie146_veil() {
        #[derive(clap::Parser)]
        struct GlareCli {
            #[command(flatten)]
            glare: crate::glare::GlareArgs,
        }
        let dir = std::env::temp_dir().join(format!("gazelight-veil-{}", std::process::id()));
        let scene_path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/data/radiance/evalglare_testimage.hdr");
        let out = dir.join("out");
        let argv = [
            "render",
            "--scene",
            scene_path.to_str().unwrap(),
            "--size",
            "96x72",
            "--hfov-deg",
            "90",
            "--yaw-deg",
            "20",
            "--pitch-deg",
            "5",
            "--frames",
            "1",
            "--backend",
            "cpu",
            "--exr",
            "--age-years",
            "70",
            "--pigmentation",
            "1.0",
            "--out",
            out.to_str().unwrap(),
        ];
        run(Cli::try_parse_from(argv).unwrap().render).unwrap();
        let map = Scene::load(
            &out.join("frames").join("veil.exr"),
            LuminanceScale::CdM2PerUnit { factor: 1.0 },
        )
        .unwrap()
        .image;
        assert_eq!((map.width, map.height), (12, 9));
        let view = ViewParams {
            yaw_deg: 20.0,
            pitch_deg: 5.0,
            hfov_deg: 90.0,
            width: 96,
            height: 72,
        };
        let grid = crate::veil_map::VeilMap {
            width: 12,
            height: 9,
            step_px: 8,
        };
        let projection = PanoramaView::new(view).unwrap();
        let mut checked = Vec::new();
        for (i, j) in [(1, 1), (6, 4), (10, 7), (3, 6)] {
            let [x, y] = crate::veil_map::view_point(&grid, &view, i, j);
            let d = projection.direction(x, y).as_dvec3();
            let [az, el] = gazelight_vision::scene::projection::angles_from_direction(d);
            let json = dir.join(format!("glare_{i}_{j}.json"));
            let gaze = format!("{az:.12},{el:.12}");
            let args = GlareCli::try_parse_from([
                "glare",
                scene_path.to_str().unwrap(),
                "--gaze-deg",
                &gaze,
                "--age-years",
                "70",
                "--pigmentation",
                "1.0",
                "--json",
                json.to_str().unwrap(),
            ])
            .unwrap()
            .glare;
            crate::glare::run(args).unwrap();
            let doc: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
            let want = doc["gazes"][0]["veil_cie146_cd_m2"].as_f64().unwrap();
            let got = f64::from(map.get(i, j)[0]);
            eprintln!(
                "veil at map ({i}, {j}), gaze {az:.2},{el:.2}°: map {got} cd/m², glare {want}"
            );
            assert!(want > 0.0);
            assert!(
                (got / want - 1.0).abs() < 1e-3,
                "({i}, {j}): {got} vs {want}"
            );
            checked.push(want);
        }
        // The points see different veils (the map is not one value).
        let (lo, hi) = checked
            .iter()
            .fold((f64::MAX, 0.0f64), |(a, b), &v| (a.min(v), b.max(v)));
        assert!(hi > 1.5 * lo, "{checked:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
