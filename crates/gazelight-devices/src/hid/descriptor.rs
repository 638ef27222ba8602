//! HID report-descriptor parser (Device Class Definition for HID 1.11,
//! §6.2.2 "Report Descriptor").
//!
//! A descriptor is a sequence of items. A short item is a prefix byte
//! `tag(4 bits) | type(2) | size(2)` followed by 0, 1, 2 or 4 data bytes
//! (size code 3 = 4 bytes) (§6.2.2.2); the prefix 0xFE starts a long item
//! (§6.2.2.3), which carries no report fields and is skipped. Types: 0 main,
//! 1 global, 2 local.
//!
//! - Main items (§6.2.2.4): Input 0x8, Output 0x9, Feature 0xB,
//!   Collection 0xA, End Collection 0xC. Input/Output/Feature create
//!   `Report Count` fields of `Report Size` bits each, placed after the
//!   fields already in that report (per report kind and report ID). Data
//!   bit 0 = Constant, bit 1 = Variable.
//! - Global items (§6.2.2.7): Usage Page 0x0, Logical Minimum 0x1, Logical
//!   Maximum 0x2, Physical Minimum 0x3, Physical Maximum 0x4, Unit Exponent
//!   0x5, Unit 0x6, Report Size 0x7, Report ID 0x8, Report Count 0x9,
//!   Push 0xA, Pop 0xB.
//! - Local items (§6.2.2.8): Usage 0x0, Usage Minimum 0x1, Usage Maximum 0x2
//!   (a 4-byte usage carries its usage page in the high 16 bits). Local
//!   state is cleared after every main item.
//!
//! Values: minima/maxima are signed two's-complement of the item's size; a
//! field is signed when its logical minimum is negative. When the logical
//! maximum reads negative but the minimum is not (the common `0 … 0xFF…`
//! idiom for unsigned ranges) the maximum is taken unsigned. When both
//! physical extents are 0 they default to the logical ones (§6.2.2.7). A
//! value outside `[logical min, logical max]` is invalid (§5.8 "Null
//! values"); fields wider than 32 bits have no expressible range and are
//! not range-checked.
//!
//! Units (§6.2.2.7, Unit item): nibble 0 is the system (1 SI linear,
//! 2 SI rotation, 3 English linear, 4 English rotation), nibbles 1-6 are the
//! signed 4-bit exponents of length, mass, time, temperature, current and
//! luminous intensity. SI linear length is the centimetre, English linear
//! the inch, time the second. The Unit Exponent item is a signed 4-bit
//! power of ten.

/// Which report a field is in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ReportKind {
    Input,
    Output,
    Feature,
}

/// A decoded Unit item.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Unit {
    /// 0 none, 1 SI linear, 2 SI rotation, 3 English linear, 4 English
    /// rotation.
    pub system: u8,
    /// Exponents of length, mass, time, temperature, current, luminous
    /// intensity.
    pub exponents: [i8; 6],
}

impl Unit {
    /// Decode a Unit item's data.
    pub fn from_raw(raw: u32) -> Self {
        let nib = |i: u32| -> i8 {
            let n = ((raw >> (4 * i)) & 0xF) as i8;
            if n >= 8 { n - 16 } else { n }
        };
        Self {
            system: (raw & 0xF) as u8,
            exponents: [nib(1), nib(2), nib(3), nib(4), nib(5), nib(6)],
        }
    }

    /// Whether the field has no unit.
    pub fn is_none(&self) -> bool {
        self.system == 0 || self.exponents == [0; 6]
    }

    /// Metres per unit when this is a pure length (cm or inch), else `None`.
    pub fn metres_per_unit(&self) -> Option<f64> {
        if self.exponents != [1, 0, 0, 0, 0, 0] {
            return None;
        }
        match self.system {
            1 => Some(0.01),   // SI linear: centimetre (HID 1.11 §6.2.2.7)
            3 => Some(0.0254), // English linear: inch (HID 1.11 §6.2.2.7)
            _ => None,
        }
    }

    /// Seconds per unit when this is a pure time (the second in every
    /// system), else `None`.
    pub fn seconds_per_unit(&self) -> Option<f64> {
        (self.system != 0 && self.exponents == [0, 0, 1, 0, 0, 0]).then_some(1.0)
    }
}

/// One field of a report.
#[derive(Clone, Debug, PartialEq)]
pub struct Field {
    pub kind: ReportKind,
    /// Report ID (0 when the descriptor uses none).
    pub report_id: u8,
    /// Bit offset in the report, after the report-ID byte.
    pub bit_offset: u32,
    pub bit_size: u32,
    pub usage_page: u16,
    pub usage: u16,
    pub logical_min: i64,
    pub logical_max: i64,
    pub physical_min: i64,
    pub physical_max: i64,
    pub unit: Unit,
    pub unit_exponent: i8,
    pub constant: bool,
    pub variable: bool,
    /// `(usage page, usage)` of the enclosing collections, outermost first.
    pub collections: Vec<(u16, u16)>,
}

impl Field {
    /// Whether the field is signed (its logical minimum is negative).
    pub fn signed(&self) -> bool {
        self.logical_min < 0
    }

    /// The raw logical value in `report` (which starts after the report-ID
    /// byte). `None` when the report is too short.
    pub fn extract(&self, report: &[u8]) -> Option<i128> {
        if self.bit_size == 0 || self.bit_size > 64 {
            return None;
        }
        let end_bit = self.bit_offset as usize + self.bit_size as usize;
        if end_bit > report.len() * 8 {
            return None;
        }
        let mut v: u128 = 0;
        for i in 0..self.bit_size as usize {
            let bit = self.bit_offset as usize + i;
            if report[bit / 8] >> (bit % 8) & 1 == 1 {
                v |= 1 << i;
            }
        }
        let n = self.bit_size;
        if self.signed() && v >> (n - 1) & 1 == 1 {
            Some(v as i128 - (1i128 << n))
        } else {
            Some(v as i128)
        }
    }

    /// Whether `logical` lies in the logical range (always true for fields
    /// wider than 32 bits, whose range a descriptor cannot express).
    pub fn in_range(&self, logical: i128) -> bool {
        self.bit_size > 32
            || (logical >= self.logical_min as i128 && logical <= self.logical_max as i128)
    }

    /// The value in the field's unit, with the unit exponent applied:
    /// `(logical − lmin)·(pmax − pmin)/(lmax − lmin) + pmin`, times
    /// `10^unit_exponent` (HID 1.11 §6.2.2.7).
    pub fn physical(&self, logical: i128) -> f64 {
        let (pmin, pmax) = if self.physical_min == 0 && self.physical_max == 0 {
            (self.logical_min, self.logical_max)
        } else {
            (self.physical_min, self.physical_max)
        };
        let scale = 10f64.powi(self.unit_exponent as i32);
        let lspan = (self.logical_max - self.logical_min) as f64;
        let v = if self.bit_size > 32
            || lspan == 0.0
            || (pmin, pmax) == (self.logical_min, self.logical_max)
        {
            logical as f64
        } else {
            (logical as f64 - self.logical_min as f64) * (pmax - pmin) as f64 / lspan + pmin as f64
        };
        v * scale
    }

    /// Whether the field sits inside a collection with this usage.
    pub fn in_collection(&self, page: u16, usage: u16) -> bool {
        self.collections.contains(&(page, usage))
    }
}

/// A parsed report descriptor.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Descriptor {
    pub fields: Vec<Field>,
    /// `(usage page, usage)` of every collection, in order of appearance.
    pub collections: Vec<(u16, u16)>,
    /// Whether Report ID items are used (reports then start with their ID).
    pub uses_report_ids: bool,
}

/// Why a descriptor could not be parsed.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DescriptorError {
    #[error("report descriptor byte {offset}: item needs {needed} data bytes, {left} left")]
    Truncated {
        offset: usize,
        needed: usize,
        left: usize,
    },
    #[error("report descriptor byte {offset}: {what}")]
    Invalid { offset: usize, what: String },
}

#[derive(Clone, Copy, Debug, Default)]
struct Globals {
    usage_page: u16,
    logical_min: i64,
    logical_max: i64,
    physical_min: i64,
    physical_max: i64,
    unit_exponent: i8,
    unit: u32,
    report_size: u32,
    report_id: u8,
    report_count: u32,
}

/// Most report fields one descriptor may define (a guard against hostile
/// descriptors with huge Report Counts).
pub const MAX_FIELDS: usize = 4096;

impl Descriptor {
    /// Parse descriptor bytes.
    pub fn parse(bytes: &[u8]) -> Result<Self, DescriptorError> {
        let mut d = Descriptor::default();
        let mut g = Globals::default();
        let mut stack: Vec<Globals> = Vec::new();
        // Local state.
        let mut usages: Vec<(u16, u16)> = Vec::new();
        let mut usage_min: Option<(u16, u16)> = None;
        let mut usage_max: Option<(u16, u16)> = None;
        let mut collection_path: Vec<(u16, u16)> = Vec::new();
        // Next free bit per (kind, report id).
        let mut cursors: Vec<(ReportKind, u8, u32)> = Vec::new();

        let mut i = 0;
        while i < bytes.len() {
            let offset = i;
            let prefix = bytes[i];
            i += 1;
            if prefix == 0xFE {
                // Long item: bDataSize, bLongItemTag, data.
                if i + 2 > bytes.len() {
                    return Err(DescriptorError::Truncated {
                        offset,
                        needed: 2,
                        left: bytes.len() - i,
                    });
                }
                let size = bytes[i] as usize;
                i += 2;
                if i + size > bytes.len() {
                    return Err(DescriptorError::Truncated {
                        offset,
                        needed: size,
                        left: bytes.len() - i,
                    });
                }
                i += size;
                continue;
            }
            let size = match prefix & 0x3 {
                3 => 4,
                s => s as usize,
            };
            if i + size > bytes.len() {
                return Err(DescriptorError::Truncated {
                    offset,
                    needed: size,
                    left: bytes.len() - i,
                });
            }
            let data = &bytes[i..i + size];
            i += size;
            let mut raw: u32 = 0;
            for (k, b) in data.iter().enumerate() {
                raw |= (*b as u32) << (8 * k);
            }
            let signed: i64 = match size {
                0 => 0,
                1 => raw as u8 as i8 as i64,
                2 => raw as u16 as i16 as i64,
                _ => raw as i32 as i64,
            };
            let item_type = (prefix >> 2) & 0x3;
            let tag = prefix >> 4;
            let invalid = |what: String| DescriptorError::Invalid { offset, what };
            match item_type {
                0 => {
                    // Main.
                    match tag {
                        0x8 | 0x9 | 0xB => {
                            let kind = match tag {
                                0x8 => ReportKind::Input,
                                0x9 => ReportKind::Output,
                                _ => ReportKind::Feature,
                            };
                            let constant = raw & 1 != 0;
                            let variable = raw & 2 != 0;
                            let cursor = match cursors
                                .iter_mut()
                                .find(|(k, id, _)| *k == kind && *id == g.report_id)
                            {
                                Some(c) => c,
                                None => {
                                    cursors.push((kind, g.report_id, 0));
                                    cursors.last_mut().ok_or_else(|| invalid("cursor".into()))?
                                }
                            };
                            // Usage list: explicit usages, else the range.
                            let range: Option<(u16, u16, u16)> = match (usage_min, usage_max) {
                                (Some((p, a)), Some((_, b))) if a <= b => Some((p, a, b)),
                                (Some(_), Some(_)) => {
                                    return Err(invalid(
                                        "Usage Minimum above Usage Maximum".into(),
                                    ));
                                }
                                _ => None,
                            };
                            if d.fields.len() + g.report_count as usize > MAX_FIELDS {
                                return Err(invalid(format!(
                                    "more than {MAX_FIELDS} report fields"
                                )));
                            }
                            for n in 0..g.report_count {
                                let (page, usage) = if let Some(u) = usages
                                    .get(n as usize)
                                    .or(usages.last().filter(|_| range.is_none()))
                                {
                                    *u
                                } else if let Some((p, a, b)) = range {
                                    (p, (a as u32 + n).min(b as u32) as u16)
                                } else {
                                    (g.usage_page, 0)
                                };
                                d.fields.push(Field {
                                    kind,
                                    report_id: g.report_id,
                                    bit_offset: cursor.2,
                                    bit_size: g.report_size,
                                    usage_page: page,
                                    usage,
                                    logical_min: g.logical_min,
                                    logical_max: g.logical_max,
                                    physical_min: g.physical_min,
                                    physical_max: g.physical_max,
                                    unit: Unit::from_raw(g.unit),
                                    unit_exponent: g.unit_exponent,
                                    constant,
                                    variable,
                                    collections: collection_path.clone(),
                                });
                                cursor.2 = cursor.2.saturating_add(g.report_size);
                            }
                        }
                        0xA => {
                            let u = usages.first().copied().unwrap_or((g.usage_page, 0));
                            collection_path.push(u);
                            d.collections.push(u);
                        }
                        0xC => {
                            if collection_path.pop().is_none() {
                                return Err(invalid("End Collection without a Collection".into()));
                            }
                        }
                        _ => return Err(invalid(format!("unknown main item tag {tag:#x}"))),
                    }
                    usages.clear();
                    usage_min = None;
                    usage_max = None;
                }
                1 => match tag {
                    0x0 => g.usage_page = raw as u16,
                    0x1 => g.logical_min = signed,
                    0x2 => g.logical_max = signed,
                    0x3 => g.physical_min = signed,
                    0x4 => g.physical_max = signed,
                    0x5 => {
                        let n = (raw & 0xF) as i8;
                        g.unit_exponent = if n >= 8 { n - 16 } else { n };
                    }
                    0x6 => g.unit = raw,
                    0x7 => {
                        if raw == 0 || raw > 64 {
                            return Err(invalid(format!("Report Size {raw} (1-64 supported)")));
                        }
                        g.report_size = raw;
                    }
                    0x8 => {
                        if raw == 0 || raw > 255 {
                            return Err(invalid(format!("Report ID {raw} (1-255 allowed)")));
                        }
                        g.report_id = raw as u8;
                        d.uses_report_ids = true;
                    }
                    0x9 => g.report_count = raw,
                    0xA => stack.push(g),
                    0xB => {
                        g = stack
                            .pop()
                            .ok_or_else(|| invalid("Pop without Push".into()))?
                    }
                    _ => return Err(invalid(format!("unknown global item tag {tag:#x}"))),
                },
                2 => {
                    let u = if size == 4 {
                        ((raw >> 16) as u16, raw as u16)
                    } else {
                        (g.usage_page, raw as u16)
                    };
                    match tag {
                        0x0 => usages.push(u),
                        0x1 => usage_min = Some(u),
                        0x2 => usage_max = Some(u),
                        // Designator/string/delimiter items carry no layout.
                        _ => {}
                    }
                }
                _ => return Err(invalid("reserved item type 3".into())),
            }
            // The unsigned-maximum idiom: min ≥ 0 and max read negative.
            if item_type == 1
                && (tag == 0x1 || tag == 0x2)
                && g.logical_min >= 0
                && g.logical_max < 0
            {
                // Re-read the maximum unsigned when it was this item.
                if tag == 0x2 {
                    g.logical_max = raw as i64;
                }
            }
        }
        if !collection_path.is_empty() {
            return Err(DescriptorError::Invalid {
                offset: bytes.len(),
                what: format!("{} collection(s) not closed", collection_path.len()),
            });
        }
        Ok(d)
    }

    /// Report byte length (without the report-ID byte) of a report.
    pub fn report_len(&self, kind: ReportKind, report_id: u8) -> usize {
        let bits = self
            .fields
            .iter()
            .filter(|f| f.kind == kind && f.report_id == report_id)
            .map(|f| f.bit_offset + f.bit_size)
            .max()
            .unwrap_or(0);
        bits.div_ceil(8) as usize
    }

    /// The first variable field with this usage inside a collection with
    /// usage `within` (any collection when `None`).
    pub fn find(
        &self,
        kind: ReportKind,
        page: u16,
        usage: u16,
        within: Option<(u16, u16)>,
    ) -> Option<&Field> {
        self.fields.iter().find(|f| {
            f.kind == kind
                && f.variable
                && !f.constant
                && f.usage_page == page
                && f.usage == usage
                && within.is_none_or(|(p, u)| f.in_collection(p, u))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A standard 3-button mouse descriptor (HID 1.11 Appendix E.10 / B.2).
    const MOUSE: [u8; 50] = [
        0x05, 0x01, 0x09, 0x02, 0xA1, 0x01, 0x09, 0x01, 0xA1, 0x00, 0x05, 0x09, 0x19, 0x01, 0x29,
        0x03, 0x15, 0x00, 0x25, 0x01, 0x95, 0x03, 0x75, 0x01, 0x81, 0x02, 0x95, 0x01, 0x75, 0x05,
        0x81, 0x01, 0x05, 0x01, 0x09, 0x30, 0x09, 0x31, 0x15, 0x81, 0x25, 0x7F, 0x75, 0x08, 0x95,
        0x02, 0x81, 0x06, 0xC0, 0xC0,
    ];

    #[test]
    fn boot_mouse_layout() {
        let d = Descriptor::parse(&MOUSE).unwrap();
        assert!(!d.uses_report_ids);
        assert_eq!(d.report_len(ReportKind::Input, 0), 3);
        let x = d.find(ReportKind::Input, 0x01, 0x30, None).unwrap();
        assert_eq!(
            (x.bit_offset, x.bit_size, x.logical_min, x.logical_max),
            (8, 8, -127, 127)
        );
        let b3 = d.find(ReportKind::Input, 0x09, 3, None).unwrap();
        assert_eq!(b3.bit_offset, 2);
        // X = -5 (0xFB), Y = +7, buttons 1 and 3.
        let report = [0b101, 0xFB, 0x07];
        assert_eq!(x.extract(&report), Some(-5));
        assert_eq!(
            d.find(ReportKind::Input, 0x01, 0x31, None)
                .unwrap()
                .extract(&report),
            Some(7)
        );
        assert_eq!(b3.extract(&report), Some(1));
        assert_eq!(d.collections, vec![(0x01, 0x02), (0x01, 0x01)]);
    }

    #[test]
    fn units_and_exponents_decode() {
        // SI linear length, exponent 1 = cm.
        let u = Unit::from_raw(0x11);
        assert_eq!(u.metres_per_unit(), Some(0.01));
        // SI linear time = s.
        let t = Unit::from_raw(0x1001);
        assert_eq!(t.seconds_per_unit(), Some(1.0));
        assert!(Unit::from_raw(0).is_none());
        // Nibble 0xF is −1.
        assert_eq!(Unit::from_raw(0xF011).exponents[2], -1);
    }

    #[test]
    fn malformed_descriptors_are_errors() {
        assert!(matches!(
            Descriptor::parse(&[0x05]),
            Err(DescriptorError::Truncated { offset: 0, .. })
        ));
        assert!(matches!(
            Descriptor::parse(&[0xA1, 0x01]),
            Err(DescriptorError::Invalid { offset: 2, .. })
        ));
        assert!(matches!(
            Descriptor::parse(&[0xC0]),
            Err(DescriptorError::Invalid { offset: 0, .. })
        ));
        assert!(matches!(
            Descriptor::parse(&[0xB4]),
            Err(DescriptorError::Invalid { offset: 0, .. })
        ));
        assert!(matches!(
            Descriptor::parse(&[0x75, 0x00]),
            Err(DescriptorError::Invalid { offset: 0, .. })
        ));
    }
}
