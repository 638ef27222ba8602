//! The one error of every settings check in this crate: which field is out
//! of range and what it must be.

/// A setting out of range. `field` is its path in the configuration file
/// (`physio.max_pupil_mm`); the message reads `"{field} {reason}"`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{field} {reason}")]
pub struct SettingError {
    /// The setting's path, e.g. `confidence.min_confidence`.
    pub field: String,
    /// What it must be and what it was.
    pub reason: String,
}

impl SettingError {
    /// A setting `field` that fails `reason`.
    pub fn new(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            reason: reason.into(),
        }
    }

    /// The same error for a setting nested under `section`
    /// (`pupil_model` + `age_years` → `pupil_model.age_years`).
    pub fn within(mut self, section: &str) -> Self {
        self.field = format!("{section}.{}", self.field);
        self
    }
}
