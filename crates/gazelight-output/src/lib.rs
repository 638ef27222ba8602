//! What gazelight writes, for every front end: [`out_dir`], the one rule
//! for "may this command write its `--out` here" (inputs never
//! overwritten, other programs' recordings never written into, a previous
//! run's outputs cleared only with `--force`) and [`write_atomic`], the
//! whole-file write a reader never sees half of.

pub mod out_dir;

pub use out_dir::{OutError, OutKind, write_atomic};
