//! `gazelight`: the gaze-contingent perception service and its CLI.
//!
//! ```text
//! gazelight render                       # the embedded demo: night panorama + synthetic gaze
//! gazelight render --scene city.exr --trace gaze.csv --out out/
//! gazelight psf --pupil-mm 4 --out psf/  # one glare kernel as EXR + PNG + JSON
//! ```
//!
//! Each subcommand `gazelight NAME` is the module `NAME` (`src/NAME.rs`, or
//! `src/NAME/mod.rs` when it has parts, as `run` does) with its arguments
//! (`psf::PsfArgs`) and `run`; the other modules are what subcommands share.

mod backend;
#[cfg(test)]
mod bad_pupils;
mod batch;
mod bounds;
mod calibrate;
mod config;
mod config_cmd;
mod devices;
mod export;
mod glare;
mod input_report;
mod inspect;
use gazelight_batch::inspect_timeline;
#[cfg(test)]
use gazelight_test_support::isolated;
mod layer;
mod observer;
/// What `render` writes besides the timeline: the PNG frames, the contact
/// sheet, the plot (and the chart writer `psf` shares).
mod output {
    pub use gazelight_output::font::register_font;
    pub use gazelight_output::plot::*;
    pub use gazelight_output::sheet::*;
}
mod profile_cmd;
mod psf;
mod record;
mod render;
mod replay;
mod run;
mod service_config;
mod stereo;
mod trials;
mod view_args;
mod window;

/// The embedded scene and demo trace (shared with the Python package).
use gazelight_app::{session, shutdown};
use gazelight_output::out_dir;
use gazelight_render::{demo, veil_map};
// What a live `run` publishes: the hub, the status server, the LSL
// outlets, the relay.
use gazelight_status::{hub, lsl_outlets, relay, serve};

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

/// Gaze-tracked HDR perception: adaptation, glare from the live pupil,
/// night vision.
#[derive(Parser, Debug)]
#[command(name = "gazelight", version, about, long_about = None)]
struct Cli {
    /// Log filter (e.g. `info`, `gazelight=debug`); also `RUST_LOG`.
    #[arg(long, global = true, default_value = "info")]
    log: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render a scene as the eye sees it along a gaze/pupil trace: PNG
    /// frames, a contact sheet, timeline.csv and a plot. With no options,
    /// renders the embedded demo.
    Render(render::RenderArgs),
    /// Re-render a recorded session (Neon or Pupil Core directory, EyeLink
    /// .asc, pupil .csv) on a scene: the same outputs as `render`, streamed,
    /// deterministic, faster than real time.
    Replay(replay::ReplayArgs),
    /// Many replays from a CSV/TOML manifest: one output folder per row, a
    /// summary table, resumable, `--jobs N` at once, or a Slurm job array
    /// (`--slurm`, `--collect`); docs/batch.md.
    Batch(batch::BatchArgs),
    /// A live session: a tracker source (default Pupil Capture at
    /// pupil://127.0.0.1:50020) through the filter chain, the frame loop at
    /// the display rate on a panorama for the head orientation; frames,
    /// timeline.csv and psf.csv with --out. Ctrl-C or --secs ends it.
    Run(run::RunArgs),
    /// The hardware-in-loop black/white pupil calibration against a live
    /// tracker: shows black then white (in the host application through
    /// `gazelight.stimulus`, or by hand), prints a per-eye summary and writes
    /// the profile, or refuses with the reason.
    Calibrate(calibrate::CalibrateArgs),
    /// Record a live Pupil source in Pupil's own recording layout
    /// (.pldata + _timestamps.npy + info.player.json); flushed every second,
    /// Ctrl-C keeps every received datum.
    Record(record::RecordArgs),
    /// Build one glare point spread function for a pupil diameter and write
    /// it as kernel.exr, kernel.png and psf.json.
    Psf(psf::PsfArgs),
    /// Summarise a recording (Neon directory, EyeLink .asc, pupil .csv):
    /// rates, pupil per eye, confidence, dropouts, blinks, warnings.
    Inspect(inspect::InspectArgs),
    /// Write a recording as a BIDS eye-tracking dataset (`--bids DIR`):
    /// per-eye physio files and sidecars (BIDS 1.11, PhysioType
    /// eyetrack), with gazelight's filtered pupil and blinks (and, with
    /// --timeline, a replay's light-driven pupil and luminance at gaze) in
    /// DIR/derivatives/gazelight/.
    Export(export::ExportArgs),
    /// Calibration profiles for trackers in arbitrary pupil units: from a
    /// known scale (`scale`), from a recording's dark and bright stretches
    /// (`phases`), or print the profile schema (`schema`).
    Profile(profile_cmd::ProfileArgs),
    /// Print the default configuration (`--print-default`): the one TOML
    /// schema every command's --config reads.
    Config(config_cmd::ConfigArgs),
    /// List connected HID devices (page-0x12 eye trackers and known vendor
    /// profiles marked), USB devices and serial ports, with their source
    /// URIs.
    Devices(devices::DevicesArgs),
    /// Glare numbers of a scene image (Radiance view, fisheye, perspective
    /// or panorama) at one or more gazes: vertical illuminance, luminance
    /// at the gaze with and without the veil, CIE 146 and Stiles–Holladay
    /// (evalglare's) veils, threshold increment, glare sources; --json.
    Glare(glare::GlareArgs),
    /// The per-trial table of a replay (its timeline.csv and events.csv):
    /// one row per event matching --events, with the subtractive baseline,
    /// peak and mean dilation, the light-driven and residual pupil over the
    /// window, the share without a measured pupil and a validity flag.
    Trials(trials::TrialsArgs),
    /// The OpenXR API layer (gazelight-openxr-layer): `install
    /// [--implicit]`, `uninstall` or `status` of its manifest under
    /// $XDG_DATA_HOME/openxr/1/api_layers/.
    Layer(layer::LayerArgs),
}

/// Hidden switch: with `GAZELIGHT_PARSE_ONLY=1` in the environment the
/// binary stops right after parsing its arguments (clap's own errors exit
/// with status 2 as usual) and loading and validating the command's
/// configuration (`--config` of `render`, `replay` and `run`, with the same
/// flag checks the command makes before it opens anything): status 0 when
/// both are good, 1 with the error otherwise. Nothing is opened, rendered or
/// written. The doc-command test (`tests/doc_commands.rs`) checks with it the
/// commands and configuration files of README.md and docs/ that need a live
/// tracker, a headset or hardware.
const PARSE_ONLY_ENV: &str = "GAZELIGHT_PARSE_ONLY";

/// Whether [`PARSE_ONLY_ENV`] is set to something other than empty or `0`.
fn parse_only() -> bool {
    std::env::var_os(PARSE_ONLY_ENV).is_some_and(|v| !v.is_empty() && v != "0")
}

/// The parse-only checks of one command: its configuration file loaded and
/// validated, its source URI parsed, and the flag checks it makes before
/// opening anything.
fn check(command: &Command) -> anyhow::Result<()> {
    match command {
        Command::Render(args) => render::check(args, service_config::ConfigUser::Render),
        Command::Replay(args) => replay::check(args),
        Command::Run(args) => run::check(args),
        Command::Calibrate(args) => {
            let mut args = args.clone();
            args.apply_config()?;
            gazelight_tracker::uri::pupil_config(args.source())
                .map(|_| ())
                .map_err(|e| anyhow::anyhow!("--source {}: {e}", args.source()))
        }
        Command::Record(args) => gazelight_tracker::uri::SourceUri::parse(&args.source)
            .map(|_| ())
            .map_err(|e| anyhow::anyhow!("--source {}: {e}", args.source)),
        Command::Batch(args) => batch::load_rows(args).map(|_| ()),
        Command::Layer(args) => layer::check(args),
        Command::Psf(_)
        | Command::Inspect(_)
        | Command::Export(_)
        | Command::Devices(_)
        | Command::Config(_)
        | Command::Profile(_)
        | Command::Glare(_)
        | Command::Trials(_) => Ok(()),
    }
}

/// Mesa's implicit Vulkan layer `VK_LAYER_MESA_device_select` connects to
/// Wayland while listing GPUs and, on a machine without a Wayland session,
/// prints `error: XDG_RUNTIME_DIR is invalid or not set` on stderr — an
/// error line on every successful GPU run. gazelight picks its adapter
/// itself, so where no Wayland display is set and the user has not asked
/// the layer for a device, the layer is switched off (`NODEVICE_SELECT=1`,
/// its documented switch). Called first in `main`, before any thread.
fn quiet_mesa_device_select() {
    let unset = |k: &str| std::env::var_os(k).is_none();
    if unset("WAYLAND_DISPLAY") && unset("NODEVICE_SELECT") && unset("MESA_VK_DEVICE_SELECT") {
        // SAFETY: runs at the top of `main`, before any other thread
        // exists, so nothing reads the environment concurrently.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}

fn main() -> std::process::ExitCode {
    quiet_mesa_device_select();
    // Negative numbers are values, not flags (`--yaw-deg -78`, `--secs -1`
    // reaches the range check that names the flag instead of clap's
    // "unexpected argument"), for every subcommand's options.
    let command = Cli::command().mut_subcommands(|sub| sub.allow_negative_numbers(true));
    let cli = match Cli::from_arg_matches(&command.get_matches()) {
        Ok(cli) => cli,
        Err(e) => e.exit(),
    };
    if parse_only() {
        return match check(&cli.command) {
            Ok(()) => std::process::ExitCode::SUCCESS,
            Err(err) => {
                eprintln!("error: {err:#}");
                std::process::ExitCode::FAILURE
            }
        };
    }
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .or_else(|_| tracing_subscriber::EnvFilter::try_new(&cli.log))
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        // Colour codes only on a terminal: log files stay plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let result = match cli.command {
        Command::Render(args) => render::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Batch(args) => batch::run(args),
        Command::Run(args) => run::run(args),
        Command::Calibrate(args) => calibrate::run(args),
        Command::Record(args) => record::run(args),
        Command::Psf(args) => psf::run(args),
        Command::Inspect(args) => inspect::run(args),
        Command::Export(args) => export::run(args),
        Command::Devices(args) => devices::run(args),
        Command::Config(args) => config_cmd::run(args),
        Command::Glare(args) => glare::run(args),
        Command::Trials(args) => trials::run(args),
        Command::Profile(args) => profile_cmd::run(args),
        Command::Layer(args) => layer::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
