//! `gazelight config --print-default`: the one configuration file every
//! command reads, with every default in effect, ready to edit.

use clap::Args;
use gazelight_tracker::filter::FilterConfig;
use gazelight_tracker::profile::{DEFAULT_AGE_YEARS, DEFAULT_PIGMENTATION};
use gazelight_vision::pipeline::PipelineConfig;
use gazelight_vision::scene::LuminanceScale;

use crate::demo;
use crate::run::{DEFAULT_FPS, DEFAULT_SOURCE};

/// Arguments of `gazelight config`.
#[derive(Args, Debug)]
pub struct ConfigArgs {
    /// Print the default configuration (TOML, every section and key with
    /// its default) on stdout.
    #[arg(long)]
    pub print_default: bool,
}

/// What the printed file says first.
const HEADER: &str = "\
# gazelight configuration: the one file `render`, `replay`, `run` and
# `calibrate` read with --config (each uses the keys that apply to it and
# reports the others as ignored). Every value below is the default in
# effect; flags override the file. Optional keys without a default:
# scene.file (an HDR panorama), scene.head (\"fixed\", \"mouse\" or
# \"trace:FILE\"), source.calibration (a profile JSON), [output] dir,
# [http] addr, [relay] addr, [lsl]. Every key: docs/configuration.md.
";

/// The default configuration as TOML text.
pub fn default_toml() -> anyhow::Result<String> {
    let view = demo::default_view(720, 800);
    let table_of = |pairs: Vec<(&str, toml::Value)>| -> toml::Value {
        toml::Value::Table(pairs.into_iter().map(|(k, v)| (k.to_owned(), v)).collect())
    };
    let mut table = toml::Table::new();
    table.insert(
        "source".into(),
        table_of(vec![("uri", DEFAULT_SOURCE.into())]),
    );
    table.insert(
        "display".into(),
        table_of(vec![
            ("fps", DEFAULT_FPS.into()),
            ("size", "720x800".into()),
            ("headless", false.into()),
        ]),
    );
    table.insert(
        "scene".into(),
        table_of(vec![
            (
                "luminance_scale",
                toml::Value::try_from(LuminanceScale::default())?,
            ),
            ("yaw_deg", view.yaw_deg.into()),
            ("pitch_deg", view.pitch_deg.into()),
            ("hfov_deg", view.hfov_deg.into()),
        ]),
    );
    table.insert(
        "pipeline".into(),
        toml::Value::try_from(PipelineConfig::default())?,
    );
    table.insert(
        "filter".into(),
        toml::Value::try_from(FilterConfig::default())?,
    );
    table.insert(
        "observer".into(),
        table_of(vec![
            ("age_years", DEFAULT_AGE_YEARS.into()),
            ("pigmentation", DEFAULT_PIGMENTATION.into()),
        ]),
    );
    table.insert(
        "limits".into(),
        toml::Value::try_from(gazelight_tracker::pupil::limits::ZmqLimits::default())?,
    );
    Ok(format!("{HEADER}\n{}", toml::to_string(&table)?))
}

/// Runs `gazelight config`.
pub fn run(args: ConfigArgs) -> anyhow::Result<()> {
    if !args.print_default {
        anyhow::bail!("gazelight config: nothing to do; give --print-default");
    }
    print!("{}", default_toml()?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RenderConfig;
    use crate::service_config::{ConfigUser, ServiceConfig};

    /// The printed defaults load for every command with nothing ignored
    /// by `run`, and give the models' own defaults back (so the file and
    /// the code cannot drift apart).
    #[test]
    fn the_printed_default_loads_everywhere_and_is_the_default() {
        let text = default_toml().unwrap();
        let dir = std::env::temp_dir().join(format!("gazelight-default-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("default.toml");
        std::fs::write(&path, &text).unwrap();
        let (config, ignored) = ServiceConfig::load_for(&path, ConfigUser::Run).unwrap();
        assert!(ignored.is_empty(), "{ignored:?}");
        assert_eq!(config.pipeline, PipelineConfig::default());
        assert_eq!(config.filter, FilterConfig::default());
        assert_eq!(config.display.fps, Some(DEFAULT_FPS));
        assert_eq!(config.observer.age_years, Some(DEFAULT_AGE_YEARS));
        assert_eq!(
            config.limits,
            gazelight_tracker::pupil::limits::ZmqLimits::default()
        );
        let render = RenderConfig::load(&path, ConfigUser::Render).unwrap();
        assert_eq!(render.pipeline, PipelineConfig::default());
        assert_eq!(render.size, Some((720, 800)));
        // What render does not use is named, not refused.
        assert!(
            render.ignored.iter().any(|k| k == "source")
                && render.ignored.iter().any(|k| k == "display.fps"),
            "{:?}",
            render.ignored
        );
        let (_, ignored) = ServiceConfig::load_for(&path, ConfigUser::Calibrate).unwrap();
        assert!(ignored.iter().any(|k| k == "pipeline"), "{ignored:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// `[limits]` in a config reaches the sockets opened afterwards (the
    /// relay's and the `pupil://` client's); a limit out of range is
    /// refused with its key. Alone in a process: the limits are the
    /// process's.
    #[test]
    fn limits_in_the_config_reach_the_sockets() {
        if !crate::isolated::in_own_process(
            "config_cmd::tests::limits_in_the_config_reach_the_sockets",
        ) {
            return;
        }
        use gazelight_tracker::pupil::PupilConfig;
        use gazelight_tracker::pupil::relay::RelayLimits;
        let dir = std::env::temp_dir().join(format!("gazelight-limits-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("limits.toml");
        std::fs::write(
            &path,
            "[limits]\nrelay_bus_max_message_bytes = 4096\npupil_bus_max_message_bytes = 2000000\nmax_message_frames = 8\n",
        )
        .unwrap();
        let (config, ignored) = ServiceConfig::load_for(&path, ConfigUser::Run).unwrap();
        assert!(ignored.is_empty(), "{ignored:?}");
        assert_eq!(config.limits.relay_bus_max_message_bytes, 4096);
        let relay = RelayLimits::default();
        assert_eq!(relay.bus_max_message_bytes, 4096);
        assert_eq!(relay.max_message_frames, 8);
        let client = PupilConfig::default();
        assert_eq!(client.bus_max_message_bytes, 2_000_000);
        assert_eq!(client.max_message_frames, 8);
        // Render does not open sockets: its limits are ignored, not applied.
        std::fs::write(&path, "[limits]\nmax_message_frames = 3\n").unwrap();
        let (_, ignored) = ServiceConfig::load_for(&path, ConfigUser::Render).unwrap();
        assert_eq!(ignored, vec!["limits".to_owned()]);
        assert_eq!(RelayLimits::default().max_message_frames, 8);
        std::fs::write(&path, "[limits]\nrelay_remote_max_message_bytes = 0\n").unwrap();
        let e = ServiceConfig::load_for(&path, ConfigUser::Run).unwrap_err();
        assert!(
            e.to_string()
                .contains("limits.relay_remote_max_message_bytes = 0"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
