//! The service configuration file (TOML) of `gazelight run`: one file for
//! the source, the display, the scene, the perception pipeline, the filter
//! chain and the network endpoints. Every field is optional (a missing one
//! takes the CLI flag or the default); unknown fields are errors that name
//! the field, and every value is validated on load with an error naming
//! the file and the field (`config run.toml: display.fps = -5: …`).
//! Relative paths are resolved against the directory of the file. Every
//! section and key, with its default and unit: `docs/configuration.md`.
//!
//! The schema, its loader and its checks are the application core's
//! (`gazelight_app::config`, shared with Python's `gazelight.render`); its
//! module documentation has the example file (loaded by its test
//! `the_module_doc_example_loads`). Here the CLI re-exports them.

pub use gazelight_app::config::{
    ConfigUser, HeadSpec, ServiceConfig, check_fps, parse_addr, parse_head, parse_size,
};
