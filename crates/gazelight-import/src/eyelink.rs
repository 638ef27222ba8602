//! SR Research EyeLink ASC exports (the text form of an EDF file).
//!
//! Lines read:
//!
//! - sample lines, starting with a digit: `time  xL yL pL  xR yR pR  flags`
//!   for binocular recordings, `time x y p flags` for monocular ones (the
//!   eye is taken from the last `START`/`SAMPLES` line); times in ms of the
//!   tracker clock, gaze in screen pixels, lost values written as `.`; a
//!   pupil of `0.0` or `.` is a lost pupil. Extra trailing columns
//!   (velocity, resolution, input) are ignored;
//! - `EBLINK <L|R> start end duration` → a [`BlinkEvent`] for that eye
//!   (emitted when its end is read, so it arrives ~0.1–0.7 s after its
//!   start in the stream); `SBLINK` lines are redundant and ignored;
//! - `PUPIL AREA|DIAMETER` → the pupil unit ([`PupilUnit::ArbitraryArea`] or
//!   [`PupilUnit::Arbitrary`]);
//! - `MSG … DISPLAY_COORDS left top right bottom` → the screen size used to
//!   normalise gaze (default 1280×1024 until one is seen);
//! - everything else (`MSG`, `INPUT`, fixation and saccade events, header
//!   and calibration-report continuation lines starting with whitespace) is
//!   ignored.
//!
//! Eye ids follow Pupil: L → 1, R → 0. Each sample line becomes up to three
//! [`Sample`]s: the pupil of each recorded eye (confidence 1 when present,
//! 0 when lost, `diameter_raw` 0 when lost) and one gaze sample, the mean of
//! the eyes with valid gaze (confidence 0 and NaN gaze when both are lost).
//! A digit-led line that does not parse is skipped with a counted warning
//! naming file and line.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use super::lines::{LineRead, open_text, read_text_line};
use super::{ImportError, ImportWarnings, Importer, Pending, Position};
use gazelight_eye::sample::{
    BlinkEvent, DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample,
};

/// Default screen size (px) when no `DISPLAY_COORDS` message is present.
pub const DEFAULT_SCREEN_PX: [f32; 2] = [1280.0, 1024.0];

/// Streaming importer of an EyeLink ASC file.
pub struct AscImporter<R: BufRead = BufReader<File>> {
    path: PathBuf,
    reader: R,
    line: String,
    line_no: u64,
    screen_px: [f32; 2],
    unit: PupilUnit,
    /// Which eyes the sample columns hold: `[right, left]` recorded.
    eyes: [bool; 2],
    /// The last `SAMPLES … RATE r` line's rate, Hz.
    rate_hz: Option<f64>,
    /// The tracker model from the header (`** … (EyeLink 1000 Plus)`, else
    /// `** VERSION: …`).
    model: Option<String>,
    pending: Pending<6>,
    warnings: ImportWarnings,
    done: bool,
}

impl AscImporter<BufReader<File>> {
    /// Opens an ASC file.
    pub fn open(path: &Path) -> Result<Self, ImportError> {
        Ok(Self::from_reader(open_text(path)?, path))
    }
}

impl<R: BufRead> AscImporter<R> {
    /// Reads ASC text from any buffered reader; `path` names it in errors.
    pub fn from_reader(reader: R, path: &Path) -> Self {
        Self {
            path: path.to_owned(),
            reader,
            line: String::with_capacity(256),
            line_no: 0,
            screen_px: DEFAULT_SCREEN_PX,
            unit: PupilUnit::ArbitraryArea,
            eyes: [true, true],
            rate_hz: None,
            model: None,
            pending: Pending::new(),
            warnings: ImportWarnings::default(),
            done: false,
        }
    }

    /// Screen size currently used for gaze normalisation.
    pub fn screen_px(&self) -> [f32; 2] {
        self.screen_px
    }

    /// Handles one line; pushes samples to `pending`.
    fn handle_line(&mut self, line: &str) {
        let line = line.trim_end_matches(['\n', '\r']);
        let first = line.as_bytes().first().copied();
        match first {
            Some(b'0'..=b'9') => self.sample_line(line),
            Some(b'E') if line.starts_with("EBLINK") => self.eblink_line(line),
            Some(b'P') if line.starts_with("PUPIL") => {
                let mut f = line.split_whitespace().skip(1);
                match f.next() {
                    Some("AREA") => self.unit = PupilUnit::ArbitraryArea,
                    Some("DIAMETER") => self.unit = PupilUnit::Arbitrary,
                    other => self.warnings.skip(
                        &self.path,
                        Position::Line(self.line_no),
                        format!("PUPIL line: expected AREA or DIAMETER, found {other:?}"),
                    ),
                }
            }
            Some(b'S') if line.starts_with("START") || line.starts_with("SAMPLES") => {
                let has_l = line.split_whitespace().any(|w| w == "LEFT");
                let has_r = line.split_whitespace().any(|w| w == "RIGHT");
                if has_l || has_r {
                    self.eyes = [has_r, has_l];
                }
                if let Some(hz) = line
                    .split_whitespace()
                    .skip_while(|w| *w != "RATE")
                    .nth(1)
                    .and_then(|w| w.parse::<f64>().ok())
                    .and_then(super::plausible_rate)
                {
                    self.rate_hz = Some(hz);
                }
            }
            Some(b'*') if line.starts_with("**") => self.header_line(line),
            Some(b'M') if line.contains("DISPLAY_COORDS") => {
                let nums: Vec<f32> = line
                    .split_whitespace()
                    .skip_while(|w| *w != "DISPLAY_COORDS")
                    .skip(1)
                    .filter_map(|w| w.parse().ok())
                    .collect();
                if nums.len() == 4 && nums[2] > nums[0] && nums[3] > nums[1] {
                    self.screen_px = [nums[2] - nums[0] + 1.0, nums[3] - nums[1] + 1.0];
                } else {
                    self.warnings.skip(
                        &self.path,
                        Position::Line(self.line_no),
                        "DISPLAY_COORDS: expected `left top right bottom` pixels",
                    );
                }
            }
            _ => {}
        }
    }

    /// A `**` header line: the tracker model, from `** EYELINK II CL v5.50
    /// … (EyeLink 1000 Plus)` (the parenthesis) or else `** VERSION:
    /// EYELINK II 1`.
    fn header_line(&mut self, line: &str) {
        let body = line.trim_start_matches('*').trim();
        let upper = body.to_ascii_uppercase();
        if let Some(v) = upper
            .starts_with("VERSION:")
            .then(|| body["VERSION:".len()..].trim())
            .filter(|v| !v.is_empty())
        {
            if self.model.is_none() {
                self.model = Some(v.chars().take(64).collect());
            }
        } else if upper.starts_with("EYELINK")
            && let (Some(a), Some(b)) = (body.rfind('('), body.rfind(')'))
            && a < b
            && body[a + 1..b].to_ascii_uppercase().starts_with("EYELINK")
        {
            self.model = Some(body[a + 1..b].chars().take(64).collect());
        }
    }

    fn eblink_line(&mut self, line: &str) {
        let line = line.trim_end();
        let f: Vec<&str> = line.split_whitespace().collect();
        let parsed = (|| {
            let eye = match *f.get(1)? {
                "L" => 1u8,
                "R" => 0u8,
                _ => return None,
            };
            let s: f64 = f.get(2)?.parse().ok()?;
            let e: f64 = f.get(3)?.parse().ok()?;
            (e >= s).then_some((eye, s, e))
        })();
        match parsed {
            Some((eye, s, e)) => self.pending.push(Sample::Blink(BlinkEvent {
                start_t_secs: s * 1e-3,
                end_t_secs: e * 1e-3,
                eye: Some(eye),
            })),
            None => self.warnings.skip(
                &self.path,
                Position::Line(self.line_no),
                format!("EBLINK: expected `EBLINK L|R start end duration`, found `{line}`"),
            ),
        }
    }

    fn sample_line(&mut self, line: &str) {
        let line = line.trim_end();
        let mut f = line.split_whitespace();
        let n_eyes = self.eyes.iter().filter(|&&e| e).count();
        let err = |what: &str| format!("sample line: {what} in `{line}`");
        let Some(t_ms) = f.next().and_then(|w| w.parse::<f64>().ok()) else {
            self.warnings.skip(
                &self.path,
                Position::Line(self.line_no),
                err("unparsable time"),
            );
            return;
        };
        // Columns: (x, y, pupil) per recorded eye, left first.
        let mut cols = [[f32::NAN; 3]; 2]; // [right, left]
        let order: [usize; 2] = [1, 0]; // left columns come first
        let mut seen = 0;
        for &eye in order.iter() {
            if !self.eyes[eye] {
                continue;
            }
            for slot in cols[eye].iter_mut() {
                let Some(w) = f.next() else {
                    let msg = err(&format!(
                        "expected {} columns for {n_eyes} eye(s), found {}",
                        1 + 3 * n_eyes,
                        1 + seen
                    ));
                    self.warnings
                        .skip(&self.path, Position::Line(self.line_no), msg);
                    return;
                };
                seen += 1;
                *slot = if w == "." {
                    f32::NAN
                } else {
                    match w.parse::<f32>() {
                        Ok(v) => v,
                        Err(_) => {
                            let msg = err(&format!("column {} `{w}` is not a number", 1 + seen));
                            self.warnings
                                .skip(&self.path, Position::Line(self.line_no), msg);
                            return;
                        }
                    }
                };
            }
        }
        let t_secs = t_ms * 1e-3;
        let mut gaze_sum = [0.0f32; 2];
        let mut gaze_n = 0;
        for &eye in order.iter() {
            if !self.eyes[eye] {
                continue;
            }
            let [x, y, p] = cols[eye];
            let valid = p.is_finite() && p > 0.0;
            self.pending.push(Sample::Pupil(PupilSample {
                t_secs,
                eye: eye as u8,
                diameter_raw: if valid { p } else { 0.0 },
                unit: self.unit,
                diameter_mm: None,
                confidence: if valid { 1.0 } else { 0.0 },
                norm_pos: [f32::NAN, f32::NAN],
                method: DetectorMethod::Other,
            }));
            if x.is_finite() && y.is_finite() {
                gaze_sum[0] += x / self.screen_px[0];
                gaze_sum[1] += y / self.screen_px[1];
                gaze_n += 1;
            }
        }
        let right_ok = self.eyes[0] && cols[0][0].is_finite() && cols[0][1].is_finite();
        let left_ok = self.eyes[1] && cols[1][0].is_finite() && cols[1][1].is_finite();
        let eyes = match (right_ok, left_ok, self.eyes) {
            (true, false, _) => GazeEyes::Right,
            (false, true, _) => GazeEyes::Left,
            // A monocular recording's lost gaze is still that eye's.
            (false, false, [true, false]) => GazeEyes::Right,
            (false, false, [false, true]) => GazeEyes::Left,
            _ => GazeEyes::Binocular,
        };
        self.pending.push(Sample::Gaze(GazeSample {
            t_secs,
            gaze_uv: if gaze_n > 0 {
                [gaze_sum[0] / gaze_n as f32, gaze_sum[1] / gaze_n as f32]
            } else {
                [f32::NAN, f32::NAN]
            },
            confidence: if gaze_n > 0 { 1.0 } else { 0.0 },
            eyes,
        }));
        // Both eyes tracked: each eye's own gaze too, for per-eye (stereo)
        // views; the binocular mean above drives the fused gaze.
        if right_ok && left_ok {
            for (eye, which) in [(1, GazeEyes::Left), (0, GazeEyes::Right)] {
                let [x, y, _] = cols[eye];
                self.pending.push(Sample::Gaze(GazeSample {
                    t_secs,
                    gaze_uv: [x / self.screen_px[0], y / self.screen_px[1]],
                    confidence: 1.0,
                    eyes: which,
                }));
            }
        }
    }
}

impl<R: BufRead> crate::Stepped for AscImporter<R> {
    /// One line: its samples go to `pending`; a long or non-UTF-8 line is
    /// skipped with a warning.
    fn step(&mut self) -> Result<bool, ImportError> {
        let read = read_text_line(
            &mut self.reader,
            &mut self.line,
            &mut self.line_no,
            &self.path,
        )?;
        match read {
            LineRead::Eof => return Ok(false),
            LineRead::TooLong(n) => {
                self.warnings
                    .skip_long_line(&self.path, self.line_no, n, "a line");
            }
            // Not UTF-8: the line was consumed; skip it.
            LineRead::NotUtf8 => self.warnings.skip_not_utf8(&self.path, self.line_no),
            LineRead::Text => {
                let line = std::mem::take(&mut self.line);
                self.handle_line(&line);
                self.line = line;
            }
        }
        Ok(true)
    }
    fn pop_pending(&mut self) -> Option<Sample> {
        self.pending.pop()
    }
    fn done_mut(&mut self) -> &mut bool {
        &mut self.done
    }
}

impl<R: BufRead> Iterator for AscImporter<R> {
    type Item = Result<Sample, ImportError>;

    fn next(&mut self) -> Option<Self::Item> {
        crate::next_stepped(self)
    }
}

impl<R: BufRead> Importer for AscImporter<R> {
    fn warnings(&self) -> &ImportWarnings {
        &self.warnings
    }
    fn format(&self) -> &'static str {
        "eyelink-asc"
    }
    fn nominal_rate_hz(&self) -> Option<f64> {
        self.rate_hz
    }
    fn device(&self) -> super::Device {
        super::Device {
            manufacturer: Some("SR Research".into()),
            model: self.model.clone(),
        }
    }
    fn position(&self) -> Position {
        Position::Line(self.line_no)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn import(text: &str) -> (Vec<Sample>, ImportWarnings) {
        let mut imp = AscImporter::from_reader(text.as_bytes(), Path::new("t.asc"));
        let v = imp.by_ref().map(|s| s.unwrap()).collect();
        (v, imp.warnings().clone())
    }

    #[test]
    fn binocular_sample_line_maps_eyes_and_normalises_gaze() {
        let text = "MSG\t1 DISPLAY_COORDS 0 0 1919 1079\nSTART\t10 \tLEFT\tRIGHT\tSAMPLES\tEVENTS\nPUPIL\tAREA\n\
                    100\t  960.0\t  540.0\t 1425.0\t  480.0\t  270.0\t 1387.0\t.....\n";
        let (s, w) = import(text);
        assert_eq!(w.skipped_records, 0);
        assert_eq!(s.len(), 5);
        let Sample::Pupil(left) = s[0] else { panic!() };
        assert_eq!(
            (left.eye, left.diameter_raw, left.unit),
            (1, 1425.0, PupilUnit::ArbitraryArea)
        );
        assert!((left.t_secs - 0.1).abs() < 1e-12);
        let Sample::Pupil(right) = s[1] else { panic!() };
        assert_eq!((right.eye, right.diameter_raw), (0, 1387.0));
        let Sample::Gaze(g) = s[2] else { panic!() };
        assert!((g.gaze_uv[0] - 0.375).abs() < 1e-6);
        assert!((g.gaze_uv[1] - 0.375).abs() < 1e-6);
        assert_eq!(g.eyes, GazeEyes::Binocular);
        // Each eye's own gaze follows: left (960, 540), right (480, 270) on
        // the 1920×1080 display.
        let Sample::Gaze(l) = s[3] else { panic!() };
        assert_eq!(l.eyes, GazeEyes::Left);
        assert!((l.gaze_uv[0] - 0.5).abs() < 1e-6 && (l.gaze_uv[1] - 0.5).abs() < 1e-6);
        let Sample::Gaze(r) = s[4] else { panic!() };
        assert_eq!(r.eyes, GazeEyes::Right);
        assert!((r.gaze_uv[0] - 0.25).abs() < 1e-6 && (r.gaze_uv[1] - 0.25).abs() < 1e-6);
    }

    #[test]
    fn lost_eye_and_blink_events() {
        let text = "350599\t   .\t   .\t    0.0\t 1040.3\t 1267.2\t  401.0\t.C...\nEBLINK L 350599\t350789\t192\n";
        let (s, _) = import(text);
        let Sample::Pupil(left) = s[0] else { panic!() };
        assert_eq!((left.diameter_raw, left.confidence), (0.0, 0.0));
        let Sample::Gaze(g) = s[2] else { panic!() };
        assert_eq!(g.eyes, GazeEyes::Right);
        let Sample::Blink(b) = s[3] else { panic!() };
        assert_eq!(b.eye, Some(1));
        assert!((b.end_t_secs - b.start_t_secs - 0.190).abs() < 1e-9);
    }

    #[test]
    fn malformed_lines_are_counted_not_fatal() {
        let text = "** header\n\t  -0  117.22\n100\t1.0\t2.0\n102\t1.0\tx\t3\t4\t5\t6\t...\nEBLINK Q 1 2 3\n104\t1\t2\t3\t4\t5\t6\t.....\n";
        let (s, w) = import(text);
        assert_eq!(w.skipped_records, 3);
        assert!(w.messages[0].contains("t.asc (line 3)"), "{:?}", w.messages);
        assert!(w.messages[1].contains("line 4"));
        // Two pupils, the binocular gaze and each eye's own gaze.
        assert_eq!(
            s.len(),
            5,
            "the good line after the bad ones still comes through"
        );
    }

    #[test]
    fn monocular_recording_uses_start_line_eye() {
        let text = "START\t1\tRIGHT\tSAMPLES\tEVENTS\n200\t640.0\t512.0\t900.0\t...\n";
        let (s, w) = import(text);
        assert_eq!(w.skipped_records, 0);
        assert_eq!(s.len(), 2);
        let Sample::Pupil(p) = s[0] else { panic!() };
        assert_eq!((p.eye, p.diameter_raw), (0, 900.0));
    }
}
