#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Decode (import) + filter throughput, samples per second on one core.
//! Target: ≥ 1 M samples/s.
//!
//! - `filter/synthetic`: the filter chain alone over 60 s of a synthetic
//!   200 Hz binocular trace (pupil + gaze + blink events), pre-generated;
//! - `import+filter/eyelink_asc`: parsing the real 4.4 MB EyeLink ASC file
//!   from memory and filtering every sample;
//! - `import+filter/piprkit_csv`: the same for the 360 s piprkit CSV trace;
//! - `import+filter/neon`: the Neon recording read from disk.

use std::hint::black_box;
use std::path::{Path, PathBuf};

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use gazelight_tracker::Sample;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::import::{self, csv::CsvPupilImporter, eyelink::AscImporter};
use gazelight_tracker::synthetic::{SyntheticConfig, SyntheticTrace};

fn data(rel: &str) -> PathBuf {
    gazelight_test_support::data_path("eye").join(rel)
}

fn run(chain: &mut FilterChain, samples: impl Iterator<Item = Sample>) -> f32 {
    let mut acc = 0.0f32;
    for s in samples {
        acc += chain.push(&s).state.eyes[0].pupil_mm;
    }
    acc
}

fn bench(c: &mut Criterion) {
    let synthetic: Vec<Sample> = SyntheticTrace::new(
        SyntheticConfig {
            duration_s: 60.0,
            ..Default::default()
        },
        |t| {
            if (t as u64 / 10).is_multiple_of(2) {
                1.0
            } else {
                500.0
            }
        },
    )
    .collect();
    let mut g = c.benchmark_group("filter");
    g.throughput(Throughput::Elements(synthetic.len() as u64));
    g.bench_function("synthetic", |b| {
        b.iter(|| {
            let mut chain = FilterChain::with_defaults();
            black_box(run(&mut chain, synthetic.iter().copied()))
        })
    });
    g.finish();

    let mut g = c.benchmark_group("import+filter");
    let asc_path = data("eyelink-psa/both_eyes.asc");
    if let Ok(asc) = std::fs::read(&asc_path) {
        let n = AscImporter::from_reader(&asc[..], &asc_path).count();
        g.throughput(Throughput::Elements(n as u64));
        g.bench_function("eyelink_asc", |b| {
            b.iter(|| {
                let mut chain = FilterChain::with_defaults();
                let imp = AscImporter::from_reader(&asc[..], Path::new("both_eyes.asc"));
                black_box(run(&mut chain, imp.map_while(Result::ok)))
            })
        });
    }
    let csv_path = data("piprkit-plr/pupil_trace.csv");
    if let Ok(csv) = std::fs::read(&csv_path) {
        let n = CsvPupilImporter::from_reader(&csv[..], &csv_path).count();
        g.throughput(Throughput::Elements(n as u64));
        g.bench_function("piprkit_csv", |b| {
            b.iter(|| {
                let mut chain = FilterChain::with_defaults();
                let imp = CsvPupilImporter::from_reader(&csv[..], Path::new("pupil_trace.csv"));
                black_box(run(&mut chain, imp.map_while(Result::ok)))
            })
        });
    }
    let neon = data("neon-demo");
    if let Ok(imp) = import::open(&neon) {
        let n = imp.count();
        g.throughput(Throughput::Elements(n as u64));
        g.bench_function("neon", |b| {
            b.iter(|| {
                let mut chain = FilterChain::with_defaults();
                let imp = import::open(&neon).expect("opened above");
                black_box(run(&mut chain, imp.map_while(Result::ok)))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
