//! `[lsl]` in the service configuration: discovery scope, the liblsl
//! configuration, the outlets and the inlet's channel mapping.

use std::path::PathBuf;

use serde::Deserialize;

use super::LslError;

/// How far LSL discovery reaches (liblsl's `multicast.ResolveScope`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ResolveScope {
    /// This machine only (the default: no discovery packet leaves it).
    #[default]
    Machine,
    /// The local subnet.
    Link,
    /// The site (liblsl's own default).
    Site,
    Organization,
    Global,
}

impl ResolveScope {
    pub fn as_str(self) -> &'static str {
        match self {
            ResolveScope::Machine => "machine",
            ResolveScope::Link => "link",
            ResolveScope::Site => "site",
            ResolveScope::Organization => "organization",
            ResolveScope::Global => "global",
        }
    }
}

/// `[lsl]`.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LslConfig {
    /// Publish the outlets (same as `run --lsl`).
    pub outlets: bool,
    /// Discovery scope of the generated liblsl configuration.
    pub scope: ResolveScope,
    /// Allow IPv6 (the generated configuration disables it by default).
    pub ipv6: bool,
    /// LSL session id (liblsl `lab.SessionID`); streams of other sessions
    /// are invisible.
    pub session_id: Option<String>,
    /// A liblsl configuration file (`lsl_api.cfg`) to use instead of the
    /// generated one. Without it and without `scope`/`ipv6` set, a
    /// `LSLAPICFG` in the environment is honoured.
    pub config_file: Option<PathBuf>,
    /// Prefix of the outlet names (`gazelight` → `gazelight-eye`, …).
    pub name_prefix: Option<String>,
    /// The inlet's channel mapping for layouts gazelight does not know.
    pub inlet: InletMapping,
}

/// How an inlet's channels map onto gaze and pupil, by channel label.
/// Empty = recognise Pupil Capture's relay and Neon's layouts by labels.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InletMapping {
    /// Label of the horizontal gaze channel.
    pub gaze_x: Option<String>,
    /// Label of the vertical gaze channel.
    pub gaze_y: Option<String>,
    /// The gaze channels' full range (width, height): values are divided
    /// by it to give normalised coordinates. Default [1, 1].
    pub gaze_range: Option<[f64; 2]>,
    /// Where gaze y = 0 is: `top` (default) or `bottom`.
    pub gaze_origin: Option<String>,
    /// Label of the right eye's pupil channel.
    pub pupil_right: Option<String>,
    /// Label of the left eye's pupil channel.
    pub pupil_left: Option<String>,
    /// Unit of the pupil channels: `mm` (default), `px` or `arbitrary`.
    pub pupil_unit: Option<String>,
    /// Label of a confidence channel (0..1); none = 1.
    pub confidence: Option<String>,
    /// Neon: the scene camera size in pixels its gaze x/y are in
    /// (default 1600 × 1200, Neon's scene camera).
    pub scene_camera_px: Option<[f64; 2]>,
}

impl InletMapping {
    /// Whether any channel is mapped by hand.
    pub fn is_set(&self) -> bool {
        self.gaze_x.is_some()
            || self.gaze_y.is_some()
            || self.pupil_right.is_some()
            || self.pupil_left.is_some()
    }
}

/// How the configuration reaches liblsl.
pub(crate) enum Applied<'a> {
    /// Generated `lsl_api.cfg` text (`lsl_set_config_content`).
    Content(&'a str),
    /// A user's file (`lsl_set_config_filename`).
    File(&'a std::path::Path),
    /// `LSLAPICFG` in the environment: liblsl reads it itself.
    Environment,
}

impl LslConfig {
    /// The generated liblsl configuration text.
    pub fn generated(&self) -> String {
        let mut s = format!(
            "[ports]\nIPv6 = {}\n\n[multicast]\nResolveScope = {}\n",
            if self.ipv6 { "allow" } else { "disable" },
            self.scope.as_str()
        );
        if let Some(id) = &self.session_id {
            s.push_str(&format!("\n[lab]\nSessionID = {id}\n"));
        }
        s
    }

    fn is_default_network(&self) -> bool {
        self.scope == ResolveScope::Machine && !self.ipv6 && self.session_id.is_none()
    }

    /// Checks the values (a session id must be one INI token, a config
    /// file must be readable).
    pub fn validate(&self) -> Result<(), LslError> {
        if let Some(id) = &self.session_id
            && (id.is_empty() || id.chars().any(|c| c.is_whitespace() || "[]=;#".contains(c)))
        {
            return Err(LslError::Config {
                reason: format!("lsl.session_id `{id}`: expected one word without spaces or []=;#"),
            });
        }
        if let Some(p) = &self.config_file
            && !super::ffi::readable(p)
        {
            return Err(LslError::Config {
                reason: format!("lsl.config_file {}: cannot be read", p.display()),
            });
        }
        if let Some(u) = &self.inlet.pupil_unit
            && !matches!(u.as_str(), "mm" | "px" | "arbitrary")
        {
            return Err(LslError::Config {
                reason: format!("lsl.inlet.pupil_unit `{u}`: expected mm, px or arbitrary"),
            });
        }
        if let Some(o) = &self.inlet.gaze_origin
            && !matches!(o.as_str(), "top" | "bottom")
        {
            return Err(LslError::Config {
                reason: format!("lsl.inlet.gaze_origin `{o}`: expected top or bottom"),
            });
        }
        for (what, r) in [
            ("gaze_range", self.inlet.gaze_range),
            ("scene_camera_px", self.inlet.scene_camera_px),
        ] {
            if let Some([w, h]) = r
                && !(w.is_finite() && h.is_finite() && w > 0.0 && h > 0.0)
            {
                return Err(LslError::Config {
                    reason: format!("lsl.inlet.{what} [{w}, {h}]: expected two positive numbers"),
                });
            }
        }
        Ok(())
    }

    /// Hands the configuration to liblsl through `set` and says which one
    /// it was: the user's file, the user's `LSLAPICFG`, or the generated
    /// text.
    pub(crate) fn apply(
        &self,
        set: impl FnOnce(Applied<'_>) -> Result<(), LslError>,
    ) -> Result<String, LslError> {
        self.validate()?;
        if let Some(p) = &self.config_file {
            set(Applied::File(p))?;
            return Ok(format!("file {}", p.display()));
        }
        if self.is_default_network()
            && let Some(env) = std::env::var_os("LSLAPICFG")
        {
            set(Applied::Environment)?;
            return Ok(format!("LSLAPICFG={}", PathBuf::from(env).display()));
        }
        let text = self.generated();
        set(Applied::Content(&text))?;
        Ok(format!(
            "generated (ResolveScope = {}, IPv6 = {})",
            self.scope.as_str(),
            if self.ipv6 { "allow" } else { "disable" }
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_keeps_discovery_on_the_machine() {
        let text = LslConfig::default().generated();
        // liblsl api_config.cpp reads `ports.IPv6` and `multicast.ResolveScope`.
        assert!(text.contains("[ports]\nIPv6 = disable"), "{text}");
        assert!(
            text.contains("[multicast]\nResolveScope = machine"),
            "{text}"
        );
    }

    #[test]
    fn toml_is_read_and_checked() {
        let c: LslConfig = toml::from_str(
            "outlets = true\nscope = \"link\"\nsession_id = \"lab7\"\n[inlet]\ngaze_x = \"gx\"\ngaze_y = \"gy\"\npupil_unit = \"px\"\n",
        )
        .unwrap();
        assert!(c.outlets && c.scope == ResolveScope::Link && c.inlet.is_set());
        assert!(c.generated().contains("SessionID = lab7"));
        c.validate().unwrap();
        let bad: LslConfig = toml::from_str("session_id = \"a b\"").unwrap();
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("session_id")
        );
        let bad: LslConfig = toml::from_str("[inlet]\npupil_unit = \"inch\"").unwrap();
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("pupil_unit")
        );
        assert!(toml::from_str::<LslConfig>("scope = \"moon\"").is_err());
    }
}
