//! `gazelight replay`: a recorded session (any format the device crate
//! imports: a Neon or Pupil Core recording directory, an EyeLink `.asc`, a
//! pupil `.csv`) + a scene → the same outputs as `render` (frames, contact
//! sheet, `timeline.csv`, plot).
//!
//! The recording is streamed, never loaded whole: one pass reads only the
//! time range (for the frame count and the progress bar), a second pass
//! feeds the samples through the tracker's one chain (the live eye task's,
//! on the recording's clock) just ahead of the frame clock. Frames are placed on the recording's own clock at `--fps`,
//! so a replay is deterministic and runs as fast as the pipeline allows.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use gazelight_output::EVENTS_COLUMNS;
use gazelight_render::feed::{ImporterSamples, Scan, scan};
use gazelight_tracker::PupilUnit;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::import;
use gazelight_tracker::profile::PupilCalibration;

use gazelight_render::display_light::{DisplayGeometry, DisplayLight, DisplayLightTable};
use gazelight_render::pupil_light::{
    self, ParamSource, PupilLight, PupilLightOptions, PupilLightPlan, which_eye,
};

use crate::input_report;
use crate::render::{self, RenderArgs, SampleFeed};
use crate::service_config::ConfigUser;
use crate::session::Origin;
use crate::stereo::{MONO, STEREO, View};

/// Arguments of `gazelight replay`.
#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The recording: a Neon or Pupil Core directory, an EyeLink `.asc`, or
    /// a pupil `.csv`.
    #[arg(value_name = "RECORDING")]
    pub recording: PathBuf,
    /// Calibration profile (JSON, `calibration/schema.json`) mapping the
    /// tracker's raw pupil units onto millimetres. Needed for recordings
    /// whose pupil is not in mm (EyeLink, Pupil Core 2D).
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
    /// Start this many seconds into the recording (samples before it still
    /// warm up the filters).
    #[arg(long, value_name = "S", default_value_t = 0.0)]
    pub from_secs: f64,
    /// Replay at most this many seconds.
    #[arg(long, value_name = "S")]
    pub secs: Option<f64>,
    /// Fit the observer's pupil light response on a baseline block of the
    /// recording, FROM..TO seconds from its first sample (a first pass
    /// over the block), and use the fitted parameters for the whole
    /// replay (docs/pupil-light-response.md).
    #[arg(long, value_name = "FROM..TO")]
    pub pupil_fit: Option<String>,
    /// Luminance of the display's black phase when the calibration profile
    /// was made, cd/m² (maps the profile's pupils onto the light model).
    #[arg(long, value_name = "CD_M2")]
    pub pupil_black_cd_m2: Option<f64>,
    /// Luminance of the display's white phase when the calibration profile
    /// was made, cd/m².
    #[arg(long, value_name = "CD_M2")]
    pub pupil_white_cd_m2: Option<f64>,
    /// The display's light drives the pupil light response instead of the
    /// scene: a CSV of `t_secs,luminance_cd_m2` (seconds from the first
    /// sample, each value held until the next row) or of
    /// `event,luminance_cd_m2` (an event pattern and the luminance the
    /// display shows from each matching event on); docs/screen-experiment.md.
    #[arg(long, value_name = "FILE")]
    pub display_light: Option<PathBuf>,
    /// The display's angular size, WxH degrees (with --display-light;
    /// default 40x30 unless --display-cm gives it).
    #[arg(long, value_name = "WxH", conflicts_with = "display_cm")]
    pub display_deg: Option<String>,
    /// The display's size, WxH cm, seen from --viewing-distance-cm.
    #[arg(long, value_name = "WxH", requires = "viewing_distance_cm")]
    pub display_cm: Option<String>,
    /// The eye's distance from the display, cm (with --display-cm).
    #[arg(long, value_name = "CM", requires = "display_cm")]
    pub viewing_distance_cm: Option<f64>,
    #[command(flatten)]
    pub render: RenderArgs,
}

/// The flag checks of `replay` that need no file.
pub(crate) fn check_flags(args: &ReplayArgs) -> anyhow::Result<()> {
    if args.render.trace.is_some() {
        bail!("replay takes the recording as its argument; --trace belongs to `render`");
    }
    crate::bounds::from_secs("--from-secs", args.from_secs)?;
    if let Some(s) = args.secs {
        crate::bounds::secs("--secs", s)?;
    }
    if let Some(r) = &args.pupil_fit {
        pupil_light::parse_fit_range(r)?;
    }
    pupil_light::check_calibration_luminance("--pupil-black-cd-m2", args.pupil_black_cd_m2)?;
    pupil_light::check_calibration_luminance("--pupil-white-cd-m2", args.pupil_white_cd_m2)?;
    display_geometry(args)?;
    Ok(())
}

/// The display's angular size (`--display-deg`, or `--display-cm` at
/// `--viewing-distance-cm`; default 40x30 degrees).
fn display_geometry(args: &ReplayArgs) -> anyhow::Result<(DisplayGeometry, Origin)> {
    Ok(
        match (
            &args.display_deg,
            &args.display_cm,
            args.viewing_distance_cm,
        ) {
            (Some(d), _, _) => (DisplayGeometry::parse_deg(d)?, Origin::Flag),
            (None, Some(c), Some(dist)) => (DisplayGeometry::from_cm(c, dist)?, Origin::Flag),
            _ => (
                DisplayGeometry::parse_deg(DEFAULT_DISPLAY_DEG)?,
                Origin::Default,
            ),
        },
    )
}

/// The display's angular size without `--display-deg`/`--display-cm`: a
/// 24" 16:10 monitor (51.8 × 32.4 cm) at 70 cm is 40.6° × 26.1°, rounded.
const DEFAULT_DISPLAY_DEG: &str = "40x30";

/// `GAZELIGHT_PARSE_ONLY`: the flag and configuration checks of `replay`;
/// the recording is not opened.
pub(crate) fn check(args: &ReplayArgs) -> anyhow::Result<()> {
    check_flags(args)?;
    render::check(&args.render, ConfigUser::Replay)
}

/// Runs `gazelight replay`.
pub fn run(args: ReplayArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    check_flags(&args)?;
    // The configuration first: its `source.calibration` stands in for
    // `--calibration`.
    let mut setup = render::prepare(&args.render, ConfigUser::Replay)?;
    let calibration_path = args
        .calibration
        .as_ref()
        .or(setup.config.calibration.as_ref());
    let calibration = match calibration_path {
        Some(path) => Some(PupilCalibration::load(path)?),
        None => None,
    };

    // Pass 1: the time range (streamed).
    let Scan {
        t_first,
        t_last,
        pupil_units,
    } = scan(&args.recording, args.secs.is_some())?;
    if calibration.is_none() && pupil_units.iter().any(|u| *u != PupilUnit::Mm) {
        tracing::warn!(
            recording = %args.recording.display(),
            "pupil samples are not in millimetres and no --calibration was given: \
             the measured pupil is written in the tracker's raw unit (pupil_raw) and the \
             glare aperture follows the light-adaptation model"
        );
    }
    // What the pupil columns carry (issue 45): the measured pupil and the
    // model aperture, never one for the other.
    let raw_units: Vec<&str> = pupil_units
        .iter()
        .filter(|u| **u != PupilUnit::Mm)
        .map(|u| unit_words(*u))
        .collect();
    setup.settings.set(
        "pupil.measured",
        if raw_units.is_empty() || pupil_units.contains(&PupilUnit::Mm) {
            "pupil_mm: the tracker's millimetres (clean samples unchanged; empty where not measured)"
                .to_string()
        } else {
            format!(
                "pupil_raw: the tracker's raw unit ({}), no physical scale{}; pupil_mm is empty",
                raw_units.join(", "),
                if calibration.as_ref().is_some_and(|c| {
                    [c.eyes.right, c.eyes.left]
                        .iter()
                        .flatten()
                        .any(|m| m.kind == gazelight_tracker::profile::MapKind::Scale)
                }) {
                    " unless the profile's scale applies"
                } else {
                    ""
                }
            )
        },
        Origin::Source,
    );
    setup.settings.set(
        "pupil.aperture",
        "aperture_mm: the model aperture the glare PSF is built for (001 §5's black/white map \
         of the profile, or the measured mm; held through blinks, eased to the light model when \
         nothing is measured) — not a measurement",
        Origin::Default,
    );
    setup.settings.set(
        "pupil_light.residual_basis",
        gazelight_render::pupil_light::ResidualBasis::of(&pupil_units).describe(),
        Origin::Source,
    );
    let t0 = t_first + args.from_secs;
    if t0 > t_last {
        bail!(
            "--from-secs {}: the recording is only {:.3} s long",
            args.from_secs,
            t_last - t_first
        );
    }
    // One time base: say which clock each output counts on, and the offset.
    setup.settings.set(
        "time.timeline_clock",
        "seconds from the first frame (timeline.csv, events.csv: t_secs); on the recording's \
         clock (inspect, Python read()) = t_secs + time.first_frame_recording_secs",
        Origin::Default,
    );
    setup
        .settings
        .set("time.first_frame_recording_secs", t0, Origin::Source)
        .note = Some(format!(
        "the recording's first sample ({t_first:.6} s) + --from-secs ({} s)",
        args.from_secs
    ));
    let mut duration = t_last - t0;
    if let Some(s) = args.secs {
        duration = duration.min(s);
    }
    tracing::info!(
        recording = %args.recording.display(),
        t_first_secs = t_first,
        duration_secs = t_last - t_first,
        "replaying {:.2} s from {:.2} s",
        duration,
        args.from_secs
    );

    // Pass 2: render, feeding the samples just ahead of the frame clock.
    // The profile's observer where neither a flag nor `[observer]` names one.
    let observer = setup.config.observer;
    crate::observer::apply(
        &mut setup.config.pipeline.glare.psf,
        &args.render.observer,
        Some(&observer),
        calibration.as_ref().map(|c| &c.observer),
    )?;
    setup.settings.set_observer(
        &setup.config.pipeline.glare.psf,
        &args.render.observer.flags(),
        &observer,
        calibration.as_ref().map(|c| c.observer),
    );
    setup.settings.set_calibration(
        calibration_path.map(|p| p.as_path()),
        calibration.as_ref(),
        Origin::first(
            args.calibration.as_ref(),
            setup.config.calibration.as_ref(),
            None,
        ),
    );
    setup.settings.set(
        "replay.recording",
        args.recording.display().to_string(),
        Origin::Flag,
    );
    // The recording's events (bounded), for events.csv.
    // Events that cannot be read are a warning, not the end of the run
    // (inspect says the same).
    let events = import::events::read(&args.recording).unwrap_or_else(|e| {
        eprintln!(
            "warning: {}: events not read: {e}",
            args.recording.display()
        );
        import::events::RecordingEvents::default()
    });
    // The inputs are checked; now where the outputs go (never over an
    // events file read, such as a Cloud export's events.csv).
    let inputs: Vec<&std::path::Path> = std::iter::once(args.recording.as_path())
        .chain(calibration_path.map(|p| p.as_path()))
        .chain(events.files.iter().map(|p| p.as_path()))
        .collect();
    render::prepare_out("replay", &args.render, &inputs)?;
    let filter = setup.config.filter;
    let new_feed = || -> anyhow::Result<SampleFeed<ImporterSamples>> {
        let importer = import::open(&args.recording)?;
        let mut chain = FilterChain::new(filter, PupilCalibration::identity())
            .map_err(|e| anyhow::anyhow!("filter configuration: {e}"))?;
        if let Some(c) = &calibration {
            chain.set_calibration(c.clone());
        }
        Ok(SampleFeed::new(ImporterSamples::new(importer), chain))
    };
    let display = load_display(&args, &events, t_first)?;
    let mut plr = pupil_light_setup(
        &args,
        &mut setup,
        calibration.as_ref(),
        display.as_ref().map(|(d, _)| d),
        t_first,
        t_last,
        &new_feed,
    )?;
    light_input(&args, &mut setup, &mut plr, display, t0 - t_first)?;
    if !events.events.is_empty() || events.dropped > 0 {
        let summary = events.summary();
        let sources: Vec<String> = summary
            .sources
            .iter()
            .map(|c| format!("{} {}", c.name, c.count))
            .collect();
        let set = setup.settings.set(
            "replay.events",
            format!(
                "{} events ({}) in events.csv, t_clock: {}",
                summary.total,
                sources.join(", "),
                events.clock
            ),
            Origin::Source,
        );
        set.note = Some(
            "each event's time on the samples' clock (recording_t_secs), from the first frame \
             (t_secs, timeline.csv's clock) and the frame it falls on"
                .to_owned(),
        );
    }
    let mut feeder = new_feed()?;
    render::render_sequence(
        &args.render,
        &setup,
        &mut feeder,
        t0,
        duration,
        started,
        Some(&mut plr),
    )?;
    let frames = match args.render.frames {
        Some(n) => n,
        None => ((duration * args.render.fps).floor() as usize).saturating_add(1),
    };
    let on_frames = write_events(
        &args.render.out.join("events.csv"),
        &events,
        t0,
        args.render.fps,
        frames,
    )?;
    if !events.events.is_empty() {
        println!(
            "wrote {}/events.csv: {} events, {on_frames} on the replayed frames",
            args.render.out.display(),
            events.events.len()
        );
    }
    for m in events.warnings.messages.iter().take(5) {
        eprintln!("warning: {}: events: {m}", args.recording.display());
    }
    let w = feeder.samples().warnings();
    if w.skipped_records > 0 {
        println!(
            "{}: skipped {} malformed records (see the log); the first: {}",
            args.recording.display(),
            w.skipped_records,
            w.messages.first().map_or("-", String::as_str)
        );
    }
    // Every note, whether or not records were skipped (e.g. a Neon
    // recording without its calibration.bin: no per-eye gaze).
    for m in w
        .messages
        .iter()
        .skip(usize::from(w.skipped_records > 0))
        .take(5)
    {
        eprintln!("warning: {}: {m}", args.recording.display());
    }
    if let Some(warning) = input_report::pupil_rejection(feeder.stats()) {
        // Said once (a log line beside it repeated it).
        eprintln!("warning: {}: {warning}", args.recording.display());
    }
    // A recording's eyes are its eyes: a monocular one in stereo.
    let samples = feeder.stats().pupil_samples;
    if args.render.stereo && (samples[0] == 0) != (samples[1] == 0) {
        let (has, lacks) = if samples[1] > 0 {
            ("left", "right")
        } else {
            ("right", "left")
        };
        eprintln!(
            "note: {}: the recording has only the {has} eye: both views show the {has} eye's \
             gaze and aperture; the {lacks} view's pupil columns are empty",
            args.recording.display()
        );
    }
    Ok(())
}

/// A CSV field: quoted (RFC 4180) when it holds a comma, quote or line
/// break.
fn csv_field(s: &str) -> std::borrow::Cow<'_, str> {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\"")).into()
    } else {
        s.into()
    }
}

/// Writes `events.csv`: every event of the recording with its time from
/// the first frame (`t_secs`, timeline.csv's clock), on the samples' clock
/// (`recording_t_secs`) and the recording's own (`t_clock`), its source,
/// text, trial id and the frame it falls on (frame i shows
/// `[t0 + i/fps, t0 + (i+1)/fps)`; empty outside the replayed frames).
/// Returns how many fall on a frame.
pub(crate) fn write_events(
    path: &std::path::Path,
    events: &import::events::RecordingEvents,
    t0: f64,
    fps: f64,
    frames: usize,
) -> anyhow::Result<usize> {
    use std::io::Write;
    let f =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut w = std::io::BufWriter::new(f);
    let mut on_frames = 0;
    writeln!(w, "{}", EVENTS_COLUMNS.join(","))?;
    for e in &events.events {
        let rel = e.t_secs - t0;
        // A small tolerance: an event at a frame's own time is that frame's.
        let k = (rel * fps + 1e-6).floor();
        let frame = (k >= 0.0 && k < frames as f64).then_some(k as usize);
        on_frames += usize::from(frame.is_some());
        let trial = e
            .trial
            .and_then(|k| events.trials.get(k as usize))
            .map_or("", |t| t.id.as_str());
        writeln!(
            w,
            "{rel:.6},{:.6},{},{},{},{},{},{}",
            e.t_secs,
            e.t_clock,
            e.duration_secs.map_or(String::new(), |d| format!("{d:.6}")),
            csv_field(&e.source),
            csv_field(&e.text),
            csv_field(trial),
            frame.map_or(String::new(), |f| f.to_string()),
        )?;
    }
    w.flush()
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(on_frames)
}

/// A raw pupil unit in a user's words.
fn unit_words(u: PupilUnit) -> &'static str {
    match u {
        PupilUnit::Px => "eye-camera pixels",
        PupilUnit::Mm => "millimetres",
        PupilUnit::ArbitraryArea => "arbitrary area units",
        PupilUnit::Arbitrary => "arbitrary diameter units",
    }
}

/// `--display-light`: the display's light over the recording (times from
/// its first sample, `t_first` on its clock; an event table matched
/// against its events), with the table it came from.
fn load_display(
    args: &ReplayArgs,
    events: &import::events::RecordingEvents,
    t_first: f64,
) -> anyhow::Result<Option<(DisplayLight, DisplayLightTable)>> {
    let Some(path) = &args.display_light else {
        return Ok(None);
    };
    let (geometry, _) = display_geometry(args)?;
    let table = DisplayLightTable::load(path)?;
    let display = DisplayLight::new(
        &table,
        geometry,
        events
            .events
            .iter()
            .map(|e| (e.t_secs - t_first, e.text.as_str())),
        &path.display().to_string(),
    )?;
    Ok(Some((display, table)))
}

/// Which light drives the pupil light response, in `session.json`
/// (`pupil_light.input`) and said once where it is the embedded demo
/// panorama; with `--display-light` ([`load_display`]), the display's
/// light over time, `first_frame_secs` after the first sample at frame 0.
fn light_input(
    args: &ReplayArgs,
    setup: &mut render::Setup,
    plr: &mut PupilLight,
    display: Option<(DisplayLight, DisplayLightTable)>,
    first_frame_secs: f64,
) -> anyhow::Result<()> {
    let scene = args
        .render
        .scene
        .as_ref()
        .or(setup.config.scene_file.as_ref());
    let (Some(path), Some((display, table))) = (&args.display_light, display) else {
        let what = match scene {
            Some(p) => format!("the scene {} at the gaze", p.display()),
            None => {
                eprintln!(
                    "note: the pupil light response's light input is the embedded demo panorama \
                     (a night street): no --scene and no --display-light was given, so \
                     pupil_light_mm and pupil_residual_mm are not about this recording's light \
                     (docs/screen-experiment.md)"
                );
                "the embedded demo panorama (no --scene, no --display-light)".to_owned()
            }
        };
        setup
            .settings
            .set("pupil_light.input", what, Origin::Default);
        return Ok(());
    };
    let (geometry, origin) = display_geometry(args)?;
    let form = match &table {
        DisplayLightTable::Times(t) => format!("{} rows of t_secs → cd/m²", t.len()),
        DisplayLightTable::Events(p) => format!(
            "{} event patterns → cd/m², {} of the recording's events matched",
            p.len(),
            display.events_matched
        ),
    };
    let set = setup.settings.set(
        "pupil_light.input",
        format!("display light: {} ({form})", path.display()),
        Origin::Flag,
    );
    set.note = Some(
        "the display's luminance at the gaze and over its field replaces the scene's (a uniform \
         screen); pupil_light.field_mean_cd_m2 is the scene's, unused"
            .to_owned(),
    );
    setup.settings.set(
        "pupil_light.display_deg",
        [geometry.width_deg, geometry.height_deg],
        origin,
    );
    setup.settings.set(
        "pupil_light.display_area_deg2",
        geometry.solid_angle_deg2(),
        origin,
    );
    plr.set_display(display, first_frame_secs);
    Ok(())
}

/// The pupil light response of this replay: each view's parameters (a
/// `--pupil-fit` block, else the calibration profile, else W&Y with the
/// observer's age, `gazelight_render::pupil_light`), recorded in the
/// session settings.
fn pupil_light_setup(
    args: &ReplayArgs,
    setup: &mut render::Setup,
    calibration: Option<&PupilCalibration>,
    display: Option<&DisplayLight>,
    t_first: f64,
    t_last: f64,
    new_feed: &dyn Fn() -> anyhow::Result<SampleFeed<ImporterSamples>>,
) -> anyhow::Result<PupilLight> {
    let views: &'static [View] = if args.render.stereo { &STEREO } else { &MONO };
    let age = setup.config.pipeline.glare.psf.age_years;
    let mut plan = PupilLightPlan::new(
        views,
        &setup.view_img,
        &setup.view,
        &setup.config.pipeline,
        &PupilLightOptions {
            age_years: age,
            calibration,
            black_cd_m2: args.pupil_black_cd_m2,
            white_cd_m2: args.pupil_white_cd_m2,
            pupil_fit: args.pupil_fit.as_deref(),
        },
        t_last - t_first,
    )?;
    if let Some([from, to_clamped]) = plan.fit_block_secs {
        // The block sees the light the replay's models will see.
        if let Some(d) = display {
            plan.set_fit_display(d.clone());
        }
        let mut feed = new_feed()?;
        let fits = plan.fit(&mut feed, t_first, args.render.fps)?;
        for (v, fit) in views.iter().zip(&fits) {
            let d = &fit.params.dynamics;
            let r = &fit.params.range;
            println!(
                "pupil light fit{} over {from}..{to_clamped} s: latency {:.3} s, constriction τ {:.3} s, \
                 redilation τ {:.3} s, range {:.4}·W&Y + {:.4} mm; R² = {:.4}, rms {:.4} mm, {} samples used",
                which_eye(*v),
                d.latency_secs,
                d.constriction_tau_secs,
                d.redilation_tau_secs,
                r.scale,
                r.offset_mm,
                fit.r_squared,
                fit.rms_mm,
                fit.samples_used
            );
        }
        setup.settings.set(
            "pupil_light.fit_block_secs",
            [from, to_clamped],
            Origin::Flag,
        );
    }
    let (black, white) = (plan.black_cd_m2, plan.white_cd_m2);
    let scene = &plan.scene;
    let field = setup.settings.set(
        "pupil_light.field_mean_cd_m2",
        scene.field.field_mean_cd_m2,
        Origin::Default,
    );
    field.note = Some(
        "the mean of the view's luminance, each pixel weighted by its solid angle (the head does not move in a replay)"
            .to_owned(),
    );
    setup.settings.set(
        "pupil_light.field_area_deg2",
        scene.field.field_area_deg2,
        Origin::Default,
    );
    setup.settings.set(
        "pupil_light.age_years",
        age,
        setup
            .settings
            .settings
            .get("observer.age_years")
            .map_or(Origin::Default, |s| s.source),
    );
    if calibration.is_some() {
        setup.settings.set(
            "pupil_light.calibration_black_cd_m2",
            black,
            Origin::first(args.pupil_black_cd_m2, None, None),
        );
        setup.settings.set(
            "pupil_light.calibration_white_cd_m2",
            white,
            Origin::first(args.pupil_white_cd_m2, None, None),
        );
    }
    for ((v, p), s) in views.iter().zip(&plan.params).zip(&plan.sources) {
        let key = |k: &str| format!("pupil_light{}.{k}", v.suffix());
        let origin = match s {
            ParamSource::Default => Origin::Default,
            ParamSource::Profile => Origin::Profile,
            ParamSource::Fit(_) => Origin::Flag,
        };
        let dyn_origin = if matches!(s, ParamSource::Fit(_)) {
            Origin::Flag
        } else {
            Origin::Default
        };
        let d = &p.dynamics;
        setup
            .settings
            .set(&key("latency_secs"), d.latency_secs, dyn_origin);
        setup.settings.set(
            &key("constriction_tau_secs"),
            d.constriction_tau_secs,
            dyn_origin,
        );
        setup.settings.set(
            &key("redilation_tau_secs"),
            d.redilation_tau_secs,
            dyn_origin,
        );
        setup
            .settings
            .set(&key("range_scale"), p.range.scale, origin);
        setup
            .settings
            .set(&key("range_offset_mm"), p.range.offset_mm, origin);
        if let ParamSource::Fit(f) = s {
            setup
                .settings
                .set(&key("fit_r_squared"), f.r_squared, Origin::Flag);
            setup
                .settings
                .set(&key("fit_rms_mm"), f.rms_mm, Origin::Flag);
            setup
                .settings
                .set(&key("fit_samples_used"), f.samples_used, Origin::Flag);
        }
    }
    Ok(plan.start()?)
}
