//! Errors of the vision crate.

use std::path::PathBuf;

/// Everything that can go wrong in `gazelight-vision`.
///
/// Errors that come from input name the file (or parameter) and what was
/// expected.
#[derive(Debug, thiserror::Error)]
pub enum VisionError {
    /// A scene file could not be read.
    #[error("cannot read scene {path}: {reason}")]
    SceneRead { path: PathBuf, reason: String },
    /// A scene file was read but its content is unusable.
    #[error("scene {path} is unusable: {reason}")]
    SceneInvalid { path: PathBuf, reason: String },
    /// A parameter is outside its valid range.
    #[error("invalid parameter `{name}` = {value}: {expected}")]
    InvalidParameter {
        name: &'static str,
        value: String,
        expected: &'static str,
    },
    /// Image dimensions do not match.
    #[error("size mismatch: {what}: expected {expected_w}x{expected_h}, got {got_w}x{got_h}")]
    SizeMismatch {
        what: &'static str,
        expected_w: usize,
        expected_h: usize,
        got_w: usize,
        got_h: usize,
    },
}

impl VisionError {
    /// Shorthand for [`VisionError::InvalidParameter`].
    pub fn invalid(
        name: &'static str,
        value: impl std::fmt::Display,
        expected: &'static str,
    ) -> Self {
        Self::InvalidParameter {
            name,
            value: value.to_string(),
            expected,
        }
    }
}
