//! Lab Streaming Layer through the real liblsl, loaded at run time
//! ([`ffi`]): outlets gazelight publishes ([`Outlet`]), streams it reads
//! ([`Inlet`], and the [`LslSource`] behind `lsl://?name=…` /
//! `lsl://?type=…`), marker streams read as events ([`LslMarkers`]), and
//! the clocks between them.
//!
//! Clocks: liblsl's `local_clock()` and gazelight's host clock
//! ([`gazelight_eye::clock::host_now_secs`]) are both the process's
//! monotonic clock, with different epochs; [`LslClock`] measures the
//! epoch difference once (the tightest of several back-to-back reads) and
//! maps between them. An inlet's timestamps are on the sender's LSL clock;
//! adding the inlet's `time_correction()` puts them on this machine's LSL
//! clock, and [`LslClock`] then on the host clock; [`LslSource`] holds that
//! sum as the measured offset of its [`gazelight_eye::clock::SourceClock`],
//! which checks each sample's stamp against its arrival.

mod config;
pub(crate) mod ffi;
mod markers;
mod source;

use std::ffi::c_char;

pub use config::{InletMapping, LslConfig, ResolveScope};
pub use markers::LslMarkers;
pub use source::{
    Layout, LayoutError, LslQuery, LslQueryError, LslSource, StreamFacts, detect_layout,
};

use ffi::{Api, Ptr};

/// What went wrong with LSL.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
pub enum LslError {
    /// No liblsl could be loaded.
    #[error(
        "liblsl not found (tried {}): install it with `pip install pylsl` (its wheel ships liblsl), \
         or your distribution's liblsl package, or set GAZELIGHT_LIBLSL=/path/to/liblsl.so",
        tried.join(", ")
    )]
    NotFound { tried: Vec<String> },
    /// A library was found but could not be loaded.
    #[error(
        "cannot load liblsl {path}: {reason} (get liblsl with `pip install pylsl`, or your \
         distribution's liblsl package)"
    )]
    Load { path: String, reason: String },
    /// The library lacks a function gazelight needs (too old).
    #[error("liblsl {path} has no `{name}` ({reason}): liblsl 1.16 or newer is needed")]
    Symbol {
        path: String,
        name: &'static str,
        reason: String,
    },
    /// `[lsl]` has a bad value.
    #[error("{reason}")]
    Config { reason: String },
    /// A bad argument (a name with a NUL byte, a sample of the wrong size).
    #[error("lsl: {reason}")]
    Argument { reason: String },
    /// liblsl refused to create something.
    #[error("lsl: cannot create {what}")]
    Create { what: String },
    /// The stream is gone.
    #[error("lsl stream `{stream}` lost")]
    Lost { stream: String },
}

/// Loads liblsl (once per process) with `config` applied first. Later
/// calls return the loaded library whatever their `config`.
pub fn load(config: &LslConfig) -> Result<LibraryInfo, LslError> {
    let api = ffi::api(config)?;
    Ok(LibraryInfo {
        path: api.path.display().to_string(),
        version: api.version,
        config: api.config.clone(),
    })
}

/// Which liblsl is in use.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LibraryInfo {
    pub path: String,
    /// `lsl_library_version()` (e.g. 118 for 1.18).
    pub version: i32,
    /// How the configuration was applied.
    pub config: String,
}

/// Maps between this machine's LSL clock and gazelight's host clock.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LslClock {
    /// `lsl_local_clock() − host_now_secs()`, seconds.
    pub lsl_minus_host_secs: f64,
    /// Width of the read window the offset was taken from, seconds.
    pub uncertainty_secs: f64,
}

impl LslClock {
    /// Measures the offset: of 50 reads host, lsl, host the one with the
    /// narrowest host window wins; the lsl read is taken at its middle.
    pub fn measure(config: &LslConfig) -> Result<Self, LslError> {
        let api = ffi::api(config)?;
        let mut best = (f64::INFINITY, 0.0);
        for _ in 0..50 {
            let h0 = gazelight_eye::clock::host_now_secs();
            // SAFETY: lsl_local_clock takes no arguments.
            let l = unsafe { (api.local_clock)() };
            let h1 = gazelight_eye::clock::host_now_secs();
            if h1 - h0 < best.0 {
                best = (h1 - h0, l - 0.5 * (h0 + h1));
            }
        }
        Ok(Self {
            lsl_minus_host_secs: best.1,
            uncertainty_secs: best.0,
        })
    }

    /// Host time of an LSL-clock time.
    pub fn to_host(&self, lsl_secs: f64) -> f64 {
        lsl_secs - self.lsl_minus_host_secs
    }

    /// LSL-clock time of a host time.
    pub fn to_lsl(&self, host_secs: f64) -> f64 {
        host_secs + self.lsl_minus_host_secs
    }
}

/// The LSL clock now (`lsl_local_clock()`).
pub fn local_clock(config: &LslConfig) -> Result<f64, LslError> {
    let api = ffi::api(config)?;
    // SAFETY: no arguments.
    Ok(unsafe { (api.local_clock)() })
}

/// Sample format of an outlet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChannelFormat {
    /// `cft_double64`.
    Double64,
    /// `cft_string` (markers).
    String,
}

/// One channel of a stream's description (XDF meta-data: `label`,
/// `unit`, `type`, and for per-eye channels `eye`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelDesc {
    pub label: String,
    pub unit: String,
    pub kind: String,
    pub eye: Option<&'static str>,
}

impl ChannelDesc {
    pub fn new(label: &str, unit: &str, kind: &str, eye: Option<&'static str>) -> Self {
        Self {
            label: label.to_owned(),
            unit: unit.to_owned(),
            kind: kind.to_owned(),
            eye,
        }
    }
}

/// What an outlet publishes.
#[derive(Clone, Debug, PartialEq)]
pub struct StreamDesc {
    pub name: String,
    pub kind: String,
    /// Samples per second; 0 = irregular.
    pub nominal_srate_hz: f64,
    pub format: ChannelFormat,
    pub source_id: String,
    /// `channels` in the description; markers have one unlabelled channel.
    pub channels: Vec<ChannelDesc>,
    /// Extra `key = value` children of `desc` (manufacturer, model, …).
    pub meta: Vec<(String, String)>,
}

/// An LSL outlet. Pushing never blocks on consumers (liblsl buffers).
pub struct Outlet {
    api: &'static Api,
    ptr: Ptr,
    channels: usize,
    name: String,
}

// SAFETY: liblsl outlets may be used from any thread (one at a time here:
// `&mut self` for pushes).
unsafe impl Send for Outlet {}

impl Outlet {
    /// Creates the outlet (liblsl buffers up to `max_buffered_secs` of
    /// samples for slow consumers).
    pub fn new(
        config: &LslConfig,
        desc: &StreamDesc,
        max_buffered_secs: i32,
    ) -> Result<Self, LslError> {
        let api = ffi::api(config)?;
        let channels = match desc.format {
            ChannelFormat::String => desc.channels.len().max(1),
            ChannelFormat::Double64 => desc.channels.len(),
        };
        if channels == 0 || channels > 1024 {
            return Err(LslError::Argument {
                reason: format!("outlet `{}`: {channels} channels", desc.name),
            });
        }
        let name = ffi::cstring(&desc.name, "stream name")?;
        let kind = ffi::cstring(&desc.kind, "stream type")?;
        let sid = ffi::cstring(&desc.source_id, "source id")?;
        let format = match desc.format {
            ChannelFormat::Double64 => ffi::CFT_DOUBLE64,
            ChannelFormat::String => ffi::CFT_STRING,
        };
        // SAFETY: valid C strings; liblsl copies them.
        let info = unsafe {
            (api.create_streaminfo)(
                name.as_ptr(),
                kind.as_ptr(),
                channels as i32,
                desc.nominal_srate_hz,
                format,
                sid.as_ptr(),
            )
        };
        if info.is_null() {
            return Err(LslError::Create {
                what: format!("the stream info of `{}`", desc.name),
            });
        }
        let described = (|| -> Result<(), LslError> {
            // SAFETY: `info` is a live stream info; the xml pointers belong to it.
            unsafe {
                let root = (api.get_desc)(info);
                let child_value = |parent: Ptr, k: &str, v: &str| -> Result<(), LslError> {
                    let k = ffi::cstring(k, "description key")?;
                    let v = ffi::cstring(v, "description value")?;
                    (api.append_child_value)(parent, k.as_ptr(), v.as_ptr());
                    Ok(())
                };
                for (k, v) in &desc.meta {
                    child_value(root, k, v)?;
                }
                if !desc.channels.is_empty() {
                    let chans = (api.append_child)(root, c"channels".as_ptr());
                    for ch in &desc.channels {
                        let c = (api.append_child)(chans, c"channel".as_ptr());
                        child_value(c, "label", &ch.label)?;
                        child_value(c, "unit", &ch.unit)?;
                        child_value(c, "type", &ch.kind)?;
                        if let Some(e) = ch.eye {
                            child_value(c, "eye", e)?;
                        }
                    }
                }
            }
            Ok(())
        })();
        let result = described.and_then(|()| {
            // SAFETY: `info` is live; liblsl copies it into the outlet.
            let ptr = unsafe { (api.create_outlet)(info, 0, max_buffered_secs.max(1)) };
            if ptr.is_null() {
                Err(LslError::Create {
                    what: format!("the outlet `{}`", desc.name),
                })
            } else {
                Ok(ptr)
            }
        });
        // SAFETY: the outlet holds its own copy.
        unsafe { (api.destroy_streaminfo)(info) };
        Ok(Self {
            api,
            ptr: result?,
            channels,
            name: desc.name.clone(),
        })
    }

    /// Pushes one numeric sample stamped `lsl_secs` (this machine's LSL
    /// clock).
    pub fn push(&mut self, values: &[f64], lsl_secs: f64) -> Result<(), LslError> {
        if values.len() != self.channels {
            return Err(LslError::Argument {
                reason: format!(
                    "outlet `{}`: {} values for {} channels",
                    self.name,
                    values.len(),
                    self.channels
                ),
            });
        }
        // SAFETY: `values` holds exactly the outlet's channel count.
        let ec = unsafe { (self.api.push_sample_dtp)(self.ptr, values.as_ptr(), lsl_secs, 1) };
        if ec < 0 {
            return Err(LslError::Argument {
                reason: format!("outlet `{}`: push failed ({ec})", self.name),
            });
        }
        Ok(())
    }

    /// Pushes one marker string (a one-channel string outlet).
    pub fn push_marker(&mut self, text: &str, lsl_secs: f64) -> Result<(), LslError> {
        if self.channels != 1 {
            return Err(LslError::Argument {
                reason: format!("outlet `{}` is not a marker stream", self.name),
            });
        }
        let c = ffi::cstring(text, "marker")?;
        let ptrs: [*const c_char; 1] = [c.as_ptr()];
        // SAFETY: one valid C string for a one-channel string outlet.
        let ec = unsafe { (self.api.push_sample_strtp)(self.ptr, ptrs.as_ptr(), lsl_secs, 1) };
        if ec < 0 {
            return Err(LslError::Argument {
                reason: format!("outlet `{}`: push failed ({ec})", self.name),
            });
        }
        Ok(())
    }

    /// Whether any inlet is connected.
    pub fn have_consumers(&self) -> bool {
        // SAFETY: live outlet.
        unsafe { (self.api.have_consumers)(self.ptr) > 0 }
    }
}

impl Drop for Outlet {
    fn drop(&mut self) {
        // SAFETY: created by lsl_create_outlet, destroyed once.
        unsafe { (self.api.destroy_outlet)(self.ptr) };
    }
}

/// A stream found by [`resolve`], or an inlet's full info.
pub struct StreamInfo {
    api: &'static Api,
    ptr: Ptr,
}

// SAFETY: a stream info is a plain heap object of liblsl.
unsafe impl Send for StreamInfo {}

impl StreamInfo {
    /// An inlet on this stream: a buffer of 10 (seconds of a regular
    /// stream, hundreds of samples of an irregular one such as markers),
    /// no chunking, no automatic recovery (a lost stream is resolved again
    /// by the caller).
    pub(crate) fn create_inlet(&self) -> Result<Ptr, LslError> {
        // SAFETY: live info; liblsl copies it.
        let ptr = unsafe { (self.api.create_inlet)(self.ptr, 10, 0, 0) };
        if ptr.is_null() {
            return Err(LslError::Create {
                what: format!("an inlet for `{}`", self.name()),
            });
        }
        Ok(ptr)
    }

    fn text(&self, f: unsafe extern "C" fn(Ptr) -> *const c_char) -> String {
        // SAFETY: live info; liblsl returns a string it owns.
        unsafe { ffi::copy_str(f(self.ptr)) }.unwrap_or_default()
    }
    pub fn name(&self) -> String {
        self.text(self.api.get_name)
    }
    pub fn kind(&self) -> String {
        self.text(self.api.get_type)
    }
    pub fn source_id(&self) -> String {
        self.text(self.api.get_source_id)
    }
    pub fn channel_count(&self) -> usize {
        // SAFETY: live info.
        unsafe { (self.api.get_channel_count)(self.ptr) }.max(0) as usize
    }
    pub fn nominal_srate_hz(&self) -> f64 {
        // SAFETY: live info.
        unsafe { (self.api.get_nominal_srate)(self.ptr) }
    }
    /// Whether the samples are numbers (not strings).
    pub fn numeric(&self) -> bool {
        // SAFETY: live info.
        unsafe { (self.api.get_channel_format)(self.ptr) != ffi::CFT_STRING }
    }

    /// The `desc/channels/channel/label` values in order (empty strings
    /// where a channel has none; empty when there is no description).
    pub fn channel_labels(&self) -> Vec<String> {
        let mut out = Vec::new();
        // SAFETY: the xml pointers belong to the live info; lsl_empty
        // marks the end.
        unsafe {
            let desc = (self.api.get_desc)(self.ptr);
            let chans = (self.api.child)(desc, c"channels".as_ptr());
            if (self.api.empty)(chans) != 0 {
                return out;
            }
            let mut ch = (self.api.first_child)(chans);
            while (self.api.empty)(ch) == 0 && out.len() < 4096 {
                out.push(
                    ffi::copy_str((self.api.child_value_n)(ch, c"label".as_ptr()))
                        .unwrap_or_default(),
                );
                ch = (self.api.next_sibling)(ch);
            }
        }
        out
    }
}

impl Drop for StreamInfo {
    fn drop(&mut self) {
        // SAFETY: owned, destroyed once.
        unsafe { (self.api.destroy_streaminfo)(self.ptr) };
    }
}

/// Finds the first stream whose `prop` (`name`, `type`, `source_id`)
/// equals `value`, waiting at most `timeout_secs`.
pub fn resolve(
    config: &LslConfig,
    prop: &str,
    value: &str,
    timeout_secs: f64,
) -> Result<Option<StreamInfo>, LslError> {
    let api = ffi::api(config)?;
    let p = ffi::cstring(prop, "query property")?;
    let v = ffi::cstring(value, "query value")?;
    let mut found: [Ptr; 4] = [std::ptr::null_mut(); 4];
    // SAFETY: the buffer holds 4 entries; liblsl fills at most that many.
    let n = unsafe {
        (api.resolve_byprop)(
            found.as_mut_ptr(),
            found.len() as u32,
            p.as_ptr(),
            v.as_ptr(),
            1,
            timeout_secs,
        )
    };
    let n = n.clamp(0, found.len() as i32) as usize;
    let mut infos: Vec<StreamInfo> = found[..n]
        .iter()
        .filter(|p| !p.is_null())
        .map(|&ptr| StreamInfo { api, ptr })
        .collect();
    Ok(if infos.is_empty() {
        None
    } else {
        Some(infos.swap_remove(0))
    })
}

/// An LSL inlet (numeric streams).
pub struct Inlet {
    api: &'static Api,
    ptr: Ptr,
    channels: usize,
    name: String,
}

// SAFETY: liblsl inlets may be used from any thread (one at a time here).
unsafe impl Send for Inlet {}

/// What [`Inlet::pull`] got.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pulled {
    /// A sample with its timestamp on the sender's LSL clock.
    Sample(f64),
    /// Nothing within the timeout.
    Nothing,
}

impl Inlet {
    /// Opens an inlet on a resolved stream (no automatic recovery: a lost
    /// stream is reported and the caller resolves again).
    pub fn new(info: &StreamInfo) -> Result<Self, LslError> {
        let name = info.name();
        if !info.numeric() {
            return Err(LslError::Argument {
                reason: format!("stream `{name}` carries strings, not samples"),
            });
        }
        let channels = info.channel_count();
        if channels == 0 || channels > 4096 {
            return Err(LslError::Argument {
                reason: format!("stream `{name}`: {channels} channels"),
            });
        }
        let ptr = info.create_inlet()?;
        Ok(Self {
            api: info.api,
            ptr,
            channels,
            name,
        })
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    fn check(&self, ec: i32) -> Result<bool, LslError> {
        match ec {
            0 => Ok(true),
            ffi::LSL_TIMEOUT_ERROR => Ok(false),
            ffi::LSL_LOST_ERROR => Err(LslError::Lost {
                stream: self.name.clone(),
            }),
            other => Err(LslError::Argument {
                reason: format!("stream `{}`: liblsl error {other}", self.name),
            }),
        }
    }

    /// The stream's full info (with its description), waiting at most
    /// `timeout_secs`; `None` on timeout.
    pub fn full_info(&self, timeout_secs: f64) -> Result<Option<StreamInfo>, LslError> {
        let mut ec = 0;
        // SAFETY: live inlet; `ec` is written by liblsl.
        let ptr = unsafe { (self.api.get_fullinfo)(self.ptr, timeout_secs, &mut ec) };
        if !self.check(ec)? || ptr.is_null() {
            return Ok(None);
        }
        Ok(Some(StreamInfo { api: self.api, ptr }))
    }

    /// Subscribes (waits at most `timeout_secs`); `false` on timeout.
    pub fn open(&self, timeout_secs: f64) -> Result<bool, LslError> {
        let mut ec = 0;
        // SAFETY: live inlet.
        unsafe { (self.api.open_stream)(self.ptr, timeout_secs, &mut ec) };
        self.check(ec)
    }

    /// The next sample into `buf` (exactly [`Inlet::channels`] long).
    pub fn pull(&mut self, buf: &mut [f64], timeout_secs: f64) -> Result<Pulled, LslError> {
        if buf.len() != self.channels {
            return Err(LslError::Argument {
                reason: format!(
                    "stream `{}`: buffer of {} for {} channels",
                    self.name,
                    buf.len(),
                    self.channels
                ),
            });
        }
        let mut ec = 0;
        // SAFETY: `buf` holds exactly the stream's channel count.
        let ts = unsafe {
            (self.api.pull_sample_d)(
                self.ptr,
                buf.as_mut_ptr(),
                buf.len() as i32,
                timeout_secs,
                &mut ec,
            )
        };
        if !self.check(ec)? || ts == 0.0 {
            return Ok(Pulled::Nothing);
        }
        Ok(Pulled::Sample(ts))
    }

    /// `time_correction()`: add to a sample's timestamp to get this
    /// machine's LSL clock. `None` on timeout.
    pub fn time_correction(&self, timeout_secs: f64) -> Result<Option<f64>, LslError> {
        let mut ec = 0;
        // SAFETY: live inlet.
        let c = unsafe { (self.api.time_correction)(self.ptr, timeout_secs, &mut ec) };
        Ok(self.check(ec)?.then_some(c).filter(|c| c.is_finite()))
    }
}

impl Drop for Inlet {
    fn drop(&mut self) {
        // SAFETY: created by lsl_create_inlet, destroyed once.
        unsafe { (self.api.destroy_inlet)(self.ptr) };
    }
}
