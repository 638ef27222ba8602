//! Gaze/pupil traces as samples: one [`TraceSample`] becomes a pupil
//! sample of each eye (mm) and a binocular gaze sample at its time. The
//! one expansion used by `synthetic://demo` (looped, [`LoopedTrace`]) and
//! by `render`'s trace feed ([`expand`]).

use gazelight_eye::{
    DetectorMethod, EYE_LEFT, EYE_RIGHT, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample,
    TraceSample,
};

/// The three samples of one trace point at `t_secs`: right pupil, left
/// pupil, gaze. A missing pupil (`None`) is a raw 0 (the chain's blink and
/// dropout stages see a closed eye).
pub fn expand(s: &TraceSample, t_secs: f64) -> [Sample; 3] {
    let pupil = |eye: usize| {
        Sample::Pupil(PupilSample {
            t_secs,
            eye: eye as u8,
            diameter_raw: s.pupil_mm.unwrap_or(0.0),
            unit: PupilUnit::Mm,
            diameter_mm: s.pupil_mm,
            confidence: s.confidence,
            norm_pos: [f32::NAN; 2],
            method: DetectorMethod::Other,
        })
    };
    [
        pupil(EYE_RIGHT),
        pupil(EYE_LEFT),
        Sample::Gaze(GazeSample {
            t_secs,
            gaze_uv: s.gaze_uv,
            confidence: s.confidence,
            eyes: GazeEyes::Binocular,
        }),
    ]
}

/// A trace as samples, looped forever with the times advanced by
/// `lap_secs` each lap (an empty trace ends at once).
pub struct LoopedTrace {
    trace: Vec<TraceSample>,
    lap_secs: f64,
    lap: u64,
    index: usize,
    part: usize,
}

impl LoopedTrace {
    pub fn new(trace: Vec<TraceSample>, lap_secs: f64) -> Self {
        Self {
            trace,
            lap_secs,
            lap: 0,
            index: 0,
            part: 0,
        }
    }
}

impl Iterator for LoopedTrace {
    type Item = Result<Sample, std::convert::Infallible>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.trace.is_empty() {
            return None;
        }
        if self.index >= self.trace.len() {
            self.index = 0;
            self.lap += 1;
        }
        let s = &self.trace[self.index];
        let t_secs = s.t_secs + self.lap as f64 * self.lap_secs;
        let sample = expand(s, t_secs)[self.part];
        self.part += 1;
        if self.part == 3 {
            self.part = 0;
            self.index += 1;
        }
        Some(Ok(sample))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(t: f64) -> TraceSample {
        TraceSample {
            t_secs: t,
            gaze_uv: [0.5, 0.5],
            pupil_mm: Some(4.0),
            confidence: 1.0,
        }
    }

    #[test]
    fn a_looped_trace_advances_its_time_each_lap() {
        let ts: Vec<f64> = LoopedTrace::new(vec![point(0.0), point(1.0)], 2.0)
            .take(9)
            .map(|s| match s {
                Ok(s) => s.t_secs(),
                Err(e) => match e {},
            })
            .collect();
        assert_eq!(ts, vec![0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0]);
        assert!(LoopedTrace::new(Vec::new(), 1.0).next().is_none());
    }

    #[test]
    fn a_point_is_both_pupils_then_the_gaze() {
        let [r, l, g] = expand(&point(3.0), 3.5);
        assert!(
            matches!(r, Sample::Pupil(p) if p.eye == 0 && p.diameter_mm == Some(4.0) && p.t_secs == 3.5)
        );
        assert!(matches!(l, Sample::Pupil(p) if p.eye == 1));
        assert!(matches!(g, Sample::Gaze(g) if g.eyes == GazeEyes::Binocular && g.t_secs == 3.5));
        let missing = TraceSample {
            pupil_mm: None,
            ..point(0.0)
        };
        assert!(matches!(expand(&missing, 0.0)[0], Sample::Pupil(p) if p.diameter_raw == 0.0));
    }
}
