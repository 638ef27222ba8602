//! The configuration of `render` and `replay`: the one configuration file
//! of every command ([`crate::service_config::ServiceConfig`], the schema
//! `run` reads), of which these two use `[scene]` (scene file, luminance
//! scale, view), `display.size`, `[pipeline]`, `[filter]` and `[observer]`
//! (and `replay` `source.calibration`); other keys are reported as ignored.
//! Every section and key, with its default and unit:
//! `docs/configuration.md`. The part these two take and its loader are the
//! application core's (`gazelight_app::config::RenderConfig`, which
//! Python's `gazelight.render` loads too; its module documentation has the
//! example file, loaded by its test `the_module_doc_example_loads`).

pub use gazelight_app::config::RenderConfig;
