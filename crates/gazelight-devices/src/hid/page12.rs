//! HID usage page 0x12 "Eye and Head Trackers" (HID Usage Tables, from
//! HUTRR74 "Usage Page for Head and Eye Trackers").
//!
//! Usage IDs used here, as listed in HUTRR74 (and in Microsoft's eye-gaze
//! HID sample header, which transcribes it):
//!
//! | usage | name | kind |
//! | --- | --- | --- |
//! | 0x01 | Eye Tracker | CA |
//! | 0x02 | Head Tracker | CA |
//! | 0x10 | Tracking Data | CP (input report) |
//! | 0x11 | Capabilities | CL (feature report) |
//! | 0x12 | Configuration | CL (feature report) |
//! | 0x13 | Status | CL (feature report) |
//! | 0x14 | Control | CL (feature report) |
//! | 0x20 | Sensor Timestamp | DV |
//! | 0x21, 0x22, 0x23 | Position X, Y, Z | DV |
//! | 0x24 | Gaze Point | CP |
//! | 0x25, 0x26 | Left / Right Eye Position | CP |
//! | 0x27, 0x28 | Head Position / Head Direction | CP |
//! | 0x29, 0x2A, 0x2B | Rotation about X / Y / Z | DV |
//! | 0x100 | Tracker Quality | SV |
//! | 0x101-0x103 | Minimum / Optimum / Maximum Tracking Distance | SV |
//! | 0x104, 0x105 | Maximum Screen Plane Width / Height | SV |
//! | 0x200-0x203 | Display Manufacturer ID / Product ID / Serial / Date | SV |
//! | 0x204, 0x205 | Calibrated Screen Width / Height | SV |
//! | 0x300 | Sampling Frequency | DV |
//! | 0x301 | Configuration Status | DV |
//! | 0x400 | Device Mode Request | DV |
//!
//! Positions (gaze point, eye and head positions, screen sizes) are in
//! micrometres and the timestamp in microseconds unless the descriptor
//! gives a Unit, in which case the Unit and Unit Exponent are applied
//! ([`super::descriptor::Field::physical`]). The gaze point is in the plane
//! of the calibrated screen, measured from its top-left corner; dividing by
//! the Calibrated Screen Width/Height of the Configuration feature report
//! gives gazelight's normalised `gaze_uv` (top-left origin).
//!
//! A field whose logical value is outside its logical range is invalid: the
//! part it belongs to (gaze point, an eye position, …) is reported as
//! `None` and counted in [`TrackingData::invalid_fields`].

use super::descriptor::{Descriptor, Field, ReportKind};

/// The usage page.
pub const PAGE: u16 = 0x12;
/// Eye Tracker application collection.
pub const EYE_TRACKER: u16 = 0x01;
/// Head Tracker application collection.
pub const HEAD_TRACKER: u16 = 0x02;
/// Tracking Data (input report collection).
pub const TRACKING_DATA: u16 = 0x10;
/// Capabilities (feature report collection).
pub const CAPABILITIES: u16 = 0x11;
/// Configuration (feature report collection).
pub const CONFIGURATION: u16 = 0x12;
/// Status (feature report collection).
pub const STATUS: u16 = 0x13;
/// Control (feature report collection).
pub const CONTROL: u16 = 0x14;
/// Sensor Timestamp.
pub const SENSOR_TIMESTAMP: u16 = 0x20;
/// Position X.
pub const POSITION_X: u16 = 0x21;
/// Position Y.
pub const POSITION_Y: u16 = 0x22;
/// Position Z.
pub const POSITION_Z: u16 = 0x23;
/// Gaze Point.
pub const GAZE_POINT: u16 = 0x24;
/// Left Eye Position.
pub const LEFT_EYE_POSITION: u16 = 0x25;
/// Right Eye Position.
pub const RIGHT_EYE_POSITION: u16 = 0x26;
/// Head Position.
pub const HEAD_POSITION: u16 = 0x27;
/// Head Direction.
pub const HEAD_DIRECTION: u16 = 0x28;
/// Rotation about X axis.
pub const ROTATION_X: u16 = 0x29;
/// Rotation about Y axis.
pub const ROTATION_Y: u16 = 0x2A;
/// Rotation about Z axis.
pub const ROTATION_Z: u16 = 0x2B;
/// Tracker Quality.
pub const TRACKER_QUALITY: u16 = 0x100;
/// Maximum Screen Plane Width.
pub const MAXIMUM_SCREEN_PLANE_WIDTH: u16 = 0x104;
/// Maximum Screen Plane Height.
pub const MAXIMUM_SCREEN_PLANE_HEIGHT: u16 = 0x105;
/// Calibrated Screen Width.
pub const CALIBRATED_SCREEN_WIDTH: u16 = 0x204;
/// Calibrated Screen Height.
pub const CALIBRATED_SCREEN_HEIGHT: u16 = 0x205;
/// Sampling Frequency.
pub const SAMPLING_FREQUENCY: u16 = 0x300;
/// Configuration Status.
pub const CONFIGURATION_STATUS: u16 = 0x301;
/// Device Mode Request.
pub const DEVICE_MODE_REQUEST: u16 = 0x400;

/// Device Mode Request bit: enable gaze point (Microsoft eye-gaze HID
/// sample, `MODE_REQUEST_ENABLE_GAZE_POINT`).
pub const MODE_ENABLE_GAZE_POINT: u8 = 1;
/// Device Mode Request bit: enable eye position (same source).
pub const MODE_ENABLE_EYE_POSITION: u8 = 2;
/// Device Mode Request bit: enable head position (same source).
pub const MODE_ENABLE_HEAD_POSITION: u8 = 4;

/// Why a descriptor or report cannot be used as page 0x12.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum Page12Error {
    #[error("no page-0x12 Tracking Data input report with a Gaze Point X/Y")]
    NoTrackingReport,
    #[error("report ID {got} is not the Tracking Data report ({expected})")]
    WrongReport { got: u8, expected: u8 },
    #[error("{what} report is {got} bytes, expected at least {expected}")]
    Short {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("the descriptor has no {0} feature field")]
    NoFeature(&'static str),
}

/// Field layout of a page-0x12 tracker, found from its descriptor.
#[derive(Clone, Debug)]
pub struct Page12Layout {
    uses_report_ids: bool,
    tracking_id: u8,
    tracking_len: usize,
    timestamp: Option<Field>,
    gaze: [Field; 2],
    left_eye: Option<[Field; 3]>,
    right_eye: Option<[Field; 3]>,
    head_position: Option<[Field; 3]>,
    head_direction: Option<[Field; 3]>,
    screen: Option<[Field; 2]>,
    sampling_frequency: Option<Field>,
    configuration_status: Option<Field>,
    mode_request: Option<Field>,
    descriptor: Descriptor,
}

/// One decoded Tracking Data report.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrackingData {
    /// Sensor Timestamp, µs.
    pub timestamp_us: Option<u64>,
    /// Gaze point on the calibrated screen, µm from the top-left corner.
    pub gaze_um: Option<[f64; 2]>,
    /// Left / right eye positions, µm.
    pub left_eye_um: Option<[f64; 3]>,
    pub right_eye_um: Option<[f64; 3]>,
    /// Head position, µm.
    pub head_position_um: Option<[f64; 3]>,
    /// Head direction: rotation about X/Y/Z in the descriptor's unit
    /// (radians for SI rotation, degrees for English rotation, raw
    /// otherwise).
    pub head_direction: Option<[f64; 3]>,
    /// Fields whose value was outside the logical range.
    pub invalid_fields: u32,
}

/// The Configuration feature report's screen size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScreenSize {
    pub width_um: f64,
    pub height_um: f64,
}

fn micrometres(f: &Field, logical: i128) -> f64 {
    let v = f.physical(logical);
    match f.unit.metres_per_unit() {
        Some(m) => v * m * 1e6,
        // No unit: the usage table's unit, µm.
        None => v,
    }
}

fn microseconds(f: &Field, logical: i128) -> f64 {
    let v = f.physical(logical);
    match f.unit.seconds_per_unit() {
        Some(s) => v * s * 1e6,
        None => v,
    }
}

impl Page12Layout {
    /// Find the page-0x12 layout in a descriptor.
    pub fn from_descriptor(d: &Descriptor) -> Result<Self, Page12Error> {
        let input = ReportKind::Input;
        let within = |c: u16| Some((PAGE, c));
        let gx = d
            .find(input, PAGE, POSITION_X, within(GAZE_POINT))
            .ok_or(Page12Error::NoTrackingReport)?;
        let gy = d
            .fields
            .iter()
            .find(|f| {
                f.kind == input
                    && f.variable
                    && f.usage_page == PAGE
                    && f.usage == POSITION_Y
                    && f.report_id == gx.report_id
                    && f.in_collection(PAGE, GAZE_POINT)
            })
            .ok_or(Page12Error::NoTrackingReport)?;
        let id = gx.report_id;
        let same = |f: &&Field| f.report_id == id;
        let xyz = |c: u16| -> Option<[Field; 3]> {
            let g = |u: u16| d.find(input, PAGE, u, within(c)).filter(same).cloned();
            Some([g(POSITION_X)?, g(POSITION_Y)?, g(POSITION_Z)?])
        };
        let rot = || -> Option<[Field; 3]> {
            let g = |u: u16| {
                d.find(input, PAGE, u, within(HEAD_DIRECTION))
                    .filter(same)
                    .cloned()
            };
            Some([g(ROTATION_X)?, g(ROTATION_Y)?, g(ROTATION_Z)?])
        };
        let feat = |u: u16| d.find(ReportKind::Feature, PAGE, u, None).cloned();
        let screen = match (
            feat(CALIBRATED_SCREEN_WIDTH),
            feat(CALIBRATED_SCREEN_HEIGHT),
        ) {
            (Some(w), Some(h)) => Some([w, h]),
            _ => None,
        };
        Ok(Self {
            uses_report_ids: d.uses_report_ids,
            tracking_id: id,
            tracking_len: d.report_len(input, id),
            timestamp: d
                .find(input, PAGE, SENSOR_TIMESTAMP, None)
                .filter(same)
                .cloned(),
            gaze: [gx.clone(), gy.clone()],
            left_eye: xyz(LEFT_EYE_POSITION),
            right_eye: xyz(RIGHT_EYE_POSITION),
            head_position: xyz(HEAD_POSITION),
            head_direction: rot(),
            screen,
            sampling_frequency: feat(SAMPLING_FREQUENCY),
            configuration_status: feat(CONFIGURATION_STATUS),
            mode_request: feat(DEVICE_MODE_REQUEST),
            descriptor: d.clone(),
        })
    }

    /// Whether a descriptor has a page-0x12 Tracking Data report.
    pub fn is_tracker(d: &Descriptor) -> bool {
        Self::from_descriptor(d).is_ok()
    }

    /// Report ID of the Tracking Data input report (0 when none is used).
    pub fn tracking_report_id(&self) -> u8 {
        self.tracking_id
    }

    /// Bytes of a Tracking Data report as read from the device (including
    /// the report-ID byte when IDs are used).
    pub fn tracking_report_len(&self) -> usize {
        self.tracking_len + usize::from(self.uses_report_ids)
    }

    fn body<'a>(
        &self,
        report: &'a [u8],
        id: u8,
        len: usize,
        what: &'static str,
    ) -> Result<&'a [u8], Page12Error> {
        let body = if self.uses_report_ids {
            match report.first() {
                Some(&got) if got == id => &report[1..],
                Some(&got) => {
                    return Err(Page12Error::WrongReport { got, expected: id });
                }
                None => {
                    return Err(Page12Error::Short {
                        what,
                        got: 0,
                        expected: len + 1,
                    });
                }
            }
        } else {
            report
        };
        if body.len() < len {
            return Err(Page12Error::Short {
                what,
                got: report.len(),
                expected: len + usize::from(self.uses_report_ids),
            });
        }
        Ok(body)
    }

    /// Decode a Tracking Data input report (as read, report-ID byte first
    /// when IDs are used).
    pub fn decode_tracking(&self, report: &[u8]) -> Result<TrackingData, Page12Error> {
        let body = self.body(report, self.tracking_id, self.tracking_len, "Tracking Data")?;
        let mut out = TrackingData::default();
        let mut read = |f: &Field, conv: fn(&Field, i128) -> f64| -> Option<f64> {
            let v = f.extract(body)?;
            if f.in_range(v) {
                Some(conv(f, v))
            } else {
                out.invalid_fields += 1;
                None
            }
        };
        let timestamp = self
            .timestamp
            .as_ref()
            .and_then(|f| read(f, microseconds))
            .map(|us| us.max(0.0) as u64);
        let gx = read(&self.gaze[0], micrometres);
        let gy = read(&self.gaze[1], micrometres);
        let gaze = gx.zip(gy).map(|(x, y)| [x, y]);
        let mut triple = |fs: &Option<[Field; 3]>, conv: fn(&Field, i128) -> f64| {
            let fs = fs.as_ref()?;
            let a = read(&fs[0], conv);
            let b = read(&fs[1], conv);
            let c = read(&fs[2], conv);
            Some([a?, b?, c?])
        };
        let left = triple(&self.left_eye, micrometres);
        let right = triple(&self.right_eye, micrometres);
        let head = triple(&self.head_position, micrometres);
        let dir = triple(&self.head_direction, |f, v| f.physical(v));
        out.timestamp_us = timestamp;
        out.gaze_um = gaze;
        out.left_eye_um = left;
        out.right_eye_um = right;
        out.head_position_um = head;
        out.head_direction = dir;
        Ok(out)
    }

    fn feature_field_report(&self, f: &Field) -> (u8, usize) {
        (
            f.report_id,
            self.descriptor.report_len(ReportKind::Feature, f.report_id),
        )
    }

    /// Report ID and buffer length (including the ID byte) of the
    /// Configuration feature report; `None` when the descriptor has no
    /// calibrated screen size.
    pub fn configuration_report(&self) -> Option<(u8, usize)> {
        let [w, _] = self.screen.as_ref()?;
        let (id, len) = self.feature_field_report(w);
        Some((id, len + 1))
    }

    /// Decode the Configuration feature report's calibrated screen size.
    pub fn decode_screen(&self, report: &[u8]) -> Result<ScreenSize, Page12Error> {
        let [wf, hf] = self
            .screen
            .as_ref()
            .ok_or(Page12Error::NoFeature("Calibrated Screen Width/Height"))?;
        let (id, len) = self.feature_field_report(wf);
        let body = self.body(report, id, len, "Configuration")?;
        let get = |f: &Field| -> Result<f64, Page12Error> {
            let v = f.extract(body).ok_or(Page12Error::Short {
                what: "Configuration",
                got: report.len(),
                expected: len,
            })?;
            if !f.in_range(v) {
                return Err(Page12Error::NoFeature(
                    "valid Calibrated Screen Width/Height",
                ));
            }
            Ok(micrometres(f, v))
        };
        let s = ScreenSize {
            width_um: get(wf)?,
            height_um: get(hf)?,
        };
        if !(s.width_um > 0.0 && s.height_um > 0.0) {
            return Err(Page12Error::NoFeature(
                "non-zero Calibrated Screen Width/Height",
            ));
        }
        Ok(s)
    }

    /// Report ID and length (with ID byte) of the Status feature report.
    pub fn status_report(&self) -> Option<(u8, usize)> {
        let f = self
            .sampling_frequency
            .as_ref()
            .or(self.configuration_status.as_ref())?;
        let (id, len) = self.feature_field_report(f);
        Some((id, len + 1))
    }

    /// Decode the Status feature report: `(sampling frequency in Hz,
    /// configuration status)`, each `None` when absent or out of range.
    pub fn decode_status(&self, report: &[u8]) -> Result<(Option<f64>, Option<u32>), Page12Error> {
        let Some((id, len1)) = self.status_report() else {
            return Err(Page12Error::NoFeature("Sampling Frequency"));
        };
        let body = self.body(report, id, len1 - 1, "Status")?;
        let get = |f: &Option<Field>| {
            let f = f.as_ref()?;
            let v = f.extract(body)?;
            f.in_range(v).then(|| f.physical(v))
        };
        Ok((
            get(&self.sampling_frequency),
            get(&self.configuration_status).map(|v| v as u32),
        ))
    }

    /// A Control feature report carrying a Device Mode Request, ready for
    /// `send_feature_report` (ID byte first, 0 when IDs are not used).
    pub fn control_report(&self, mode: u8) -> Option<Vec<u8>> {
        let f = self.mode_request.as_ref()?;
        let (id, len) = self.feature_field_report(f);
        let mut buf = vec![0u8; len + 1];
        buf[0] = id;
        let body = &mut buf[1..];
        for i in 0..f.bit_size.min(8) as usize {
            if mode >> i & 1 == 1 {
                let bit = f.bit_offset as usize + i;
                body[bit / 8] |= 1 << (bit % 8);
            }
        }
        Some(buf)
    }

    /// Normalised gaze (top-left origin) from a gaze point in µm.
    pub fn normalise(gaze_um: [f64; 2], screen: &ScreenSize) -> [f32; 2] {
        [
            (gaze_um[0] / screen.width_um) as f32,
            (gaze_um[1] / screen.height_um) as f32,
        ]
    }
}
