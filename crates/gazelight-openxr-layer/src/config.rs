//! The layer's configuration: one TOML file, `GAZELIGHT_LAYER_CONFIG` when
//! set, else `$XDG_CONFIG_HOME/gazelight/layer.toml` (`~/.config/…` when
//! `XDG_CONFIG_HOME` is unset). No file at the default place means the
//! defaults; a file named by `GAZELIGHT_LAYER_CONFIG` must exist.
//!
//! The schema, the loader and its rules (the run's other sections refused,
//! the 1 MiB bounded reader, errors naming the file, line, column and
//! field) are the application core's, `gazelight_app::layer_config`, whose
//! documentation shows every key; the layer only calls it.

pub use gazelight_app::layer_config::*;
