#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Property test of the one source-clock mapping ([`SourceClock`]): any
//! sequence of time stamps — good ones with transport delays, clock steps
//! of any size, single absurd stamps, NaN and infinities, true and lying
//! offset measurements — gives
//!
//! - host times that never go back, are never later than their arrival
//!   and never older than the stated bound `D` on arrival;
//! - an `EyeState` (the filter chain fed the delivered samples) whose age
//!   right after each delivered sample is within `[0, D]`;
//! - and, once good stamps come again (their delays varying by less than
//!   `D/2`), every stamp delivered after at most two windows.
//!
//! 512 cases by default (0.4 s); `GAZELIGHT_FUZZ_CASES` sets more for
//! longer local runs.

use gazelight_eye::clock::{DEFAULT_MAX_AGE_SECS, SourceClock, SourceClockConfig};
use gazelight_eye::filter::FilterChain;
use gazelight_eye::{DetectorMethod, PupilSample, PupilUnit, Sample};
use proptest::prelude::*;

const D: f64 = DEFAULT_MAX_AGE_SECS;
/// Largest spread of the good stamps' transport delays, s (< D/2).
const JITTER: f64 = 0.12;

#[derive(Clone, Debug)]
enum Event {
    /// A good stamp arriving `dt` s after the previous one, taken `delay` s
    /// before it arrived.
    Good { dt: f64, delay: f64 },
    /// The source's clock steps by this many seconds.
    Step(f64),
    /// One stamp with this value.
    Outlier(f64),
    /// One NaN or infinite stamp.
    NonFinite(f64),
    /// A measurement of the offset, wrong by this many seconds.
    Measure(f64),
}

fn event() -> impl Strategy<Value = Event> {
    prop_oneof![
        30 => (0.0001f64..0.05, 0.0f64..JITTER).prop_map(|(dt, delay)| Event::Good { dt, delay }),
        2 => prop_oneof![
            -1.0f64..1.0,
            -1e9f64..1e9,
            Just(1e5),
            Just(-1e5),
            Just(1.7e9),
        ]
        .prop_map(Event::Step),
        2 => prop_oneof![
            Just(1e308),
            Just(-1e308),
            Just(0.0),
            Just(f64::MAX),
            Just(f64::MIN),
            -1e12f64..1e12,
            any::<f64>().prop_filter("finite", |v| v.is_finite()),
        ]
        .prop_map(Event::Outlier),
        1 => prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(f64::NEG_INFINITY)]
            .prop_map(Event::NonFinite),
        1 => prop_oneof![Just(0.0), -0.2f64..0.2, Just(1e6), Just(-1.7e9), Just(f64::NAN)]
            .prop_map(Event::Measure),
    ]
}

struct Sim {
    clock: SourceClock,
    chain: FilterChain,
    /// Host time of the newest arrival, s.
    arrival: f64,
    /// Source clock − host clock, s.
    ahead: f64,
    last: f64,
}

impl Sim {
    fn stamp(&mut self, stamp: f64) -> Result<Option<f64>, TestCaseError> {
        let out = self.clock.to_host(stamp, self.arrival);
        if let Some(t) = out {
            prop_assert!(t >= self.last, "went back: {t} after {}", self.last);
            prop_assert!(
                t <= self.arrival,
                "{t} later than its arrival {}",
                self.arrival
            );
            prop_assert!(
                t >= self.arrival - D,
                "{t} older than {D} s on arrival {}",
                self.arrival
            );
            self.last = t;
            self.chain.push(&Sample::Pupil(PupilSample {
                t_secs: t,
                eye: 0,
                diameter_raw: 4.0,
                unit: PupilUnit::Mm,
                diameter_mm: Some(4.0),
                confidence: 0.95,
                norm_pos: [0.5, 0.5],
                method: DetectorMethod::Pupil3d,
            }));
            let age = self.arrival - self.chain.state().t_secs;
            prop_assert!((0.0..=D).contains(&age), "EyeState age {age} s");
        }
        Ok(out)
    }

    fn good(&mut self, dt: f64, delay: f64) -> Result<Option<f64>, TestCaseError> {
        self.arrival += dt;
        let stamp = self.arrival - delay + self.ahead;
        self.stamp(stamp)
    }
}

fn cases() -> u32 {
    std::env::var("GAZELIGHT_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(512)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(), ..ProptestConfig::default() })]

    #[test]
    fn any_stamps_give_monotonic_bounded_host_times_and_recover(
        ahead in prop_oneof![-1e9f64..1e9, Just(0.0), Just(1.7e9)],
        measured_first in any::<bool>(),
        events in prop::collection::vec(event(), 1..400),
        tail in prop::collection::vec(0.0f64..JITTER, 400),
    ) {
        let mut sim = Sim {
            clock: SourceClock::new("property", SourceClockConfig::default()),
            chain: FilterChain::with_defaults(),
            arrival: 100.0,
            ahead,
            last: f64::NEG_INFINITY,
        };
        if measured_first {
            sim.clock.anchor(-ahead, sim.arrival);
        }
        for e in &events {
            match *e {
                Event::Good { dt, delay } => {
                    sim.good(dt, delay)?;
                }
                Event::Step(s) => sim.ahead += s,
                Event::Outlier(v) => {
                    sim.arrival += 0.001;
                    sim.stamp(v)?;
                }
                Event::NonFinite(v) => {
                    sim.arrival += 0.001;
                    prop_assert_eq!(sim.stamp(v)?, None);
                }
                Event::Measure(lie) => {
                    sim.clock.anchor(-sim.ahead + lie, sim.arrival);
                }
            }
        }
        // 4 s of good stamps at 100 Hz: the last second is all delivered.
        for (k, delay) in tail.iter().enumerate() {
            let out = sim.good(0.01, *delay)?;
            if k >= 300 {
                prop_assert!(out.is_some(), "good stamp {k} of the tail dropped: {:?}", sim.clock.stats());
            }
        }
    }
}
