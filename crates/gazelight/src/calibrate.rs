//! `gazelight calibrate`: the hardware-in-loop black/white pupil calibration
//! (001 §5) against a live tracker.
//!
//! The stimulus (black, then white, then nothing) goes to a sink:
//! `--stimulus remote` sends it to the host application as the
//! `gazelight.stimulus` notification through the tracker's Pupil Remote
//! (the host shows the colour full screen); `--stimulus window` shows it full
//! screen in the service's own window; `--stimulus log` only prints it
//! (a technician switching the display by hand, or tests). The samples come
//! from the live source; each phase's robust statistics map the raw pupil
//! units linearly onto 2–8 mm per eye. A per-eye summary (samples, valid
//! fraction, raw range) is printed whether it succeeds or not; the profile
//! is written only on success — a phase with too few valid samples, or a
//! white phase whose pupil is not smaller, is refused with the reason.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use gazelight_tracker::calibrate::{CalibrateOptions, Event, StimulusTarget};
use gazelight_tracker::calibration::{
    CalibrationConfig, Phase, PhaseSummary, Stimulus, StimulusError, StimulusSink,
};
use gazelight_tracker::pupil::PupilConfig;

use crate::service_config::ConfigUser;
use crate::window::{self, Content, SolidColour, WindowOptions};

fn parse_window_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("`{s}`: expected WIDTHxHEIGHT, e.g. 800x600"))?;
    let w: u32 = w
        .trim()
        .parse()
        .map_err(|_| format!("`{s}`: width is not a number"))?;
    let h: u32 = h
        .trim()
        .parse()
        .map_err(|_| format!("`{s}`: height is not a number"))?;
    if !(16..=16384).contains(&w) || !(16..=16384).contains(&h) {
        return Err(format!("`{s}`: each side must be 16..=16384 pixels"));
    }
    Ok((w, h))
}

/// Where the stimulus goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum StimulusKind {
    /// To the host application as a `gazelight.stimulus` notification
    /// (`{"subject": "gazelight.stimulus", "color": "black"|"white"|"none"}`)
    /// through the tracker's Pupil Remote.
    Remote,
    /// Printed only: someone switches the display by hand.
    Log,
    /// Full screen in the service's own window.
    Window,
}

/// Arguments of `gazelight calibrate`.
#[derive(Args, Clone, Debug)]
pub struct CalibrateArgs {
    /// Tracker source (Pupil Capture's Pupil Remote) [default: the
    /// configuration's `source.uri`, else pupil://127.0.0.1:50020].
    #[arg(long, value_name = "URI")]
    pub source: Option<String>,
    /// Configuration file (the one schema of every command; `calibrate`
    /// uses `source.uri` and reports the other keys as ignored).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Where the black/white stimulus is shown.
    #[arg(long, value_enum, default_value = "remote")]
    pub stimulus: StimulusKind,
    /// Duration of each phase, s (001 §5: 5 s).
    #[arg(long, value_name = "S", default_value_t = 5.0)]
    pub phase_secs: f64,
    /// Samples in the first S seconds of a phase are ignored while the pupil
    /// adapts.
    #[arg(long, value_name = "S", default_value_t = 2.0)]
    pub settle_secs: f64,
    /// Show white first.
    #[arg(long)]
    pub white_first: bool,
    /// Minimum fraction of valid samples per phase and eye.
    #[arg(long, value_name = "F", default_value_t = 0.5)]
    pub min_valid_fraction: f64,
    /// Free-text description stored in the profile (tracker, operator).
    #[arg(long)]
    pub description: Option<String>,
    /// Where the profile is written (JSON, `calibration/schema.json`). An
    /// existing file is refused unless --force.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Replace an existing profile at --out (it is replaced only once the
    /// new profile is complete).
    #[arg(long)]
    pub force: bool,
    /// Size of the stimulus window when not full screen, WIDTHxHEIGHT.
    #[arg(long, value_name = "WxH", value_parser = parse_window_size, default_value = "800x600")]
    pub window_size: (u32, u32),
    /// Show the stimulus window at its size instead of full screen.
    #[arg(long)]
    pub no_fullscreen: bool,
    /// Give up when the tracker sends nothing for this long, s.
    #[arg(long, value_name = "S", default_value_t = 5.0)]
    pub silence_secs: f64,
}

/// Runs `gazelight calibrate`.
use gazelight_tracker::uri::DEFAULT_SOURCE;

impl CalibrateArgs {
    /// The source: `--source`, else (after [`Self::apply_config`]) the
    /// configuration's, else [`DEFAULT_SOURCE`].
    pub fn source(&self) -> &str {
        self.source.as_deref().unwrap_or(DEFAULT_SOURCE)
    }

    /// Loads `--config` (if any) and takes its `source.uri` where no
    /// `--source` was given.
    pub fn apply_config(&mut self) -> anyhow::Result<()> {
        if let Some(path) = &self.config {
            let (config, _ignored) =
                crate::service_config::ServiceConfig::load_for(path, ConfigUser::Calibrate)?;
            if self.source.is_none() {
                self.source = config.source.uri;
            }
        }
        Ok(())
    }
}

pub fn run(mut args: CalibrateArgs) -> anyhow::Result<()> {
    args.apply_config()?;
    let mut cfg = CalibrationConfig {
        phase_duration_s: args.phase_secs,
        settle_s: args.settle_secs,
        min_valid_fraction: args.min_valid_fraction,
        ..CalibrationConfig::default()
    };
    if args.white_first {
        cfg.order = [Phase::White, Phase::Black];
    }
    crate::bounds::secs("--phase-secs", args.phase_secs)?;
    crate::bounds::secs_or_zero("--settle-secs", args.settle_secs)?;
    cfg.validate().context("calibration settings")?;
    crate::bounds::secs("--silence-secs", args.silence_secs)?;
    if let Some(parent) = args.out.parent()
        && !parent.as_os_str().is_empty()
        && !parent.is_dir()
    {
        bail!(
            "--out {}: directory {} does not exist",
            args.out.display(),
            parent.display()
        );
    }
    // Checked before the routine, so nobody calibrates for nothing.
    crate::out_dir::prepare(
        "calibrate",
        &args.out,
        crate::out_dir::OutKind::Profile,
        &[],
        args.force,
    )?;
    let pupil = gazelight_tracker::uri::pupil_config(args.source())
        .with_context(|| format!("--source {}", args.source()))?;

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    if args.stimulus != StimulusKind::Window {
        return runtime.block_on(calibrate(args, cfg, pupil, None));
    }

    // The window needs the main thread: the routine runs beside it and the
    // window shows the colour the routine sets; closing the window aborts.
    let colour = SolidColour::new(PRE_STIMULUS_RGB8);
    let control = Arc::new(WindowControl::default());
    let options = WindowOptions {
        title: "gazelight calibration".to_owned(),
        width: args.window_size.0,
        height: args.window_size.1,
        fullscreen: !args.no_fullscreen,
    };
    let worker = {
        let colour = colour.clone();
        let control = control.clone();
        std::thread::Builder::new()
            .name("calibration".into())
            .spawn(move || {
                let r =
                    runtime.block_on(calibrate(args, cfg, pupil, Some((colour, control.clone()))));
                control.done.store(true, Ordering::Relaxed);
                r
            })
            .context("cannot start the calibration thread")?
    };
    let stop = {
        let control = control.clone();
        move || control.done.load(Ordering::Relaxed)
    };
    let on_close = {
        let control = control.clone();
        move || control.cancelled.store(true, Ordering::Relaxed)
    };
    let window = window::run(options, Content::Solid(colour), None, stop, on_close);
    if window.is_err() {
        control.cancelled.store(true, Ordering::Relaxed);
    }
    let result = worker
        .join()
        .map_err(|_| anyhow::anyhow!("the calibration thread panicked"))?;
    window?;
    result
}

/// Colour of the window before the first phase and after the last (mid
/// grey, sRGB-encoded).
const PRE_STIMULUS_RGB8: [u8; 3] = [128, 128, 128];

/// Shared between the window (main thread) and the routine.
#[derive(Debug, Default)]
struct WindowControl {
    /// The routine has finished (the window closes).
    done: AtomicBool,
    /// The user closed the window (the routine aborts).
    cancelled: AtomicBool,
}

/// Shows the stimulus full screen in the service's window.
struct WindowSink(Arc<SolidColour>);

impl StimulusSink for WindowSink {
    fn show(&mut self, stimulus: Stimulus, _at_t_secs: f64) -> Result<(), StimulusError> {
        self.0.set(match stimulus {
            Stimulus::Black => [0, 0, 0],
            Stimulus::White => [255, 255, 255],
            Stimulus::None => PRE_STIMULUS_RGB8,
        });
        Ok(())
    }
}

/// The routine ([`gazelight_tracker::calibrate`]) with the signals, the
/// printing and the profile written.
async fn calibrate(
    args: CalibrateArgs,
    cfg: CalibrationConfig,
    pupil: PupilConfig,
    window: Option<(Arc<SolidColour>, Arc<WindowControl>)>,
) -> anyhow::Result<()> {
    // SIGINT, SIGTERM and SIGHUP abort the routine the same way: the
    // stimulus is turned off and no profile is written.
    let signals = crate::shutdown::Signals::new()
        .context("cannot install the SIGINT/SIGTERM/SIGHUP handlers")?;
    let opts = CalibrateOptions {
        uri: args.source().to_owned(),
        silence: crate::bounds::secs("--silence-secs", args.silence_secs)?,
        silence_secs: args.silence_secs,
    };
    let mut window_sink = window.as_ref().map(|(c, _)| WindowSink(c.clone()));
    let target = match (args.stimulus, &mut window_sink) {
        (StimulusKind::Remote, _) => StimulusTarget::Remote,
        (_, Some(w)) => StimulusTarget::Sink(w),
        (_, None) => StimulusTarget::Log,
    };
    let control = window.as_ref().map(|(_, ctl)| ctl.clone());
    let cancelled = || {
        control
            .as_ref()
            .is_some_and(|c| c.cancelled.load(Ordering::Relaxed))
    };
    let on_event = |event: Event<'_>| match event {
        Event::Connected { version } => eprintln!(
            "connected to {} ({version}); calibrating: {:?} then {:?}, {:.1} s each, {:.1} s settle",
            args.source(),
            cfg.order[0],
            cfg.order[1],
            cfg.phase_duration_s,
            cfg.settle_s
        ),
        Event::Stimulus {
            stimulus: Stimulus::None,
            since_first_secs,
        } => eprintln!("[{since_first_secs:5.1} s] stimulus off"),
        Event::Stimulus {
            stimulus,
            since_first_secs,
        } => eprintln!(
            "[{since_first_secs:5.1} s] showing {} for {:.1} s",
            format!("{stimulus:?}").to_uppercase(),
            cfg.phase_duration_s
        ),
        Event::Summary(summary) => print_summary(summary),
    };
    let mut profile = gazelight_tracker::calibrate::calibrate(
        pupil,
        cfg,
        &opts,
        target,
        cancelled,
        signals.first(),
        on_event,
    )
    .await?;
    profile.description = args.description.clone().or_else(|| {
        Some(format!(
            "gazelight calibrate --source {} ({:?} stimulus)",
            args.source(),
            args.stimulus
        ))
    });
    profile
        .save(&args.out)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    for (name, eye) in [
        ("right (0)", profile.eyes.right),
        ("left (1)", profile.eyes.left),
    ] {
        if let Some(c) = eye {
            println!(
                "eye {name}: raw {:.3} (black) → {:.1} mm, raw {:.3} (white) → {:.1} mm [raw: {}]",
                c.raw_black,
                c.mm_max,
                c.raw_white,
                c.mm_min,
                crate::session::raw_pupil_words(c.raw_unit)
            );
        }
    }
    println!("wrote {}", args.out.display());
    Ok(())
}

fn print_summary(summary: &[PhaseSummary]) {
    if summary.is_empty() {
        println!("no pupil samples were received");
        return;
    }
    println!("eye    phase  samples  valid   raw min   raw median   raw max  raw unit");
    for s in summary {
        println!(
            "{:<6} {:<6} {:>7}  {:>5.1}%  {:>8.3}  {:>10.3}  {:>8.3}  {}",
            if s.eye == 0 { "right" } else { "left" },
            format!("{:?}", s.phase).to_lowercase(),
            s.samples,
            100.0 * s.valid_fraction(),
            s.raw_min,
            s.raw_median,
            s.raw_max,
            crate::session::raw_pupil_words(s.unit)
        );
    }
}
