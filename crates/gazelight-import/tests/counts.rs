#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Every sample read is counted (issue 45 item 6): `inspect`'s summary
//! (`summarize_importer`, what the command prints) of each shipped
//! recording has as many samples as the recording itself holds — counted
//! here from the files, not by the importers: the EyeLink file's sample
//! lines (a lost eye, `.` or a 0 pupil, is a sample too), Neon's `.time`
//! files (one u64 per record). The XDF and CSV counts are in `xdf.rs`
//! (against pyxdf) and `csv.rs`.

use gazelight_eye::filter::FilterChain;
use gazelight_import::summary::summarize_importer;

fn data(rel: &str) -> std::path::PathBuf {
    gazelight_test_support::data_path("eye").join(rel)
}

#[test]
fn eyelink_every_sample_line_is_a_sample_of_each_eye() {
    let path = data("eyelink-psa/both_eyes.asc");
    let text = std::fs::read_to_string(&path).unwrap();
    let lines = text
        .lines()
        .filter(|l| l.starts_with(|c: char| c.is_ascii_digit()))
        .count() as u64;
    // Lines where an eye is lost (its pupil `.` or 0): still samples.
    let lost = text
        .lines()
        .filter(|l| l.starts_with(|c: char| c.is_ascii_digit()))
        .filter(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            f.len() >= 7 && (f[3] == "." || f[3] == "0.0")
        })
        .count();
    let eblinks = |eye: &str| {
        text.lines()
            .filter(|l| l.starts_with("EBLINK") && l.split_whitespace().nth(1) == Some(eye))
            .count() as u64
    };
    let mut imp = gazelight_import::open(&path).unwrap();
    let s = summarize_importer(imp.as_mut(), FilterChain::with_defaults()).unwrap();
    assert_eq!(s.samples.pupil, [lines, lines], "sample lines {lines}");
    // Gaze: each line one sample — binocular, or that eye's when only one
    // eye has a gaze — plus each eye's own where both have one.
    let (mut both, mut one) = (0u64, 0u64);
    for l in text
        .lines()
        .filter(|l| l.starts_with(|c: char| c.is_ascii_digit()))
    {
        let f: Vec<&str> = l.split_whitespace().collect();
        let ok = |a: usize| f.get(a) != Some(&".") && f.get(a + 1) != Some(&".");
        match (ok(1), ok(4)) {
            (true, true) => both += 1,
            (true, false) | (false, true) => one += 1,
            _ => {}
        }
    }
    assert_eq!(
        (s.samples.gaze, s.samples.gaze_per_eye),
        (lines - one, 2 * both + one)
    );
    assert_eq!(s.skipped_records, 0);
    // The tracker's own blinks: right (eye 0), left (eye 1).
    assert_eq!(
        [s.blinks.recording[0], s.blinks.recording[1]],
        [eblinks("R"), eblinks("L")]
    );
    eprintln!(
        "both_eyes.asc: {lines} sample lines ({lost} with the left eye lost) → pupils {:?}, \
         gaze {} (+{} per eye), blinks {:?}",
        s.samples.pupil, s.samples.gaze, s.samples.gaze_per_eye, s.blinks
    );
}

#[test]
fn neon_every_record_is_a_sample() {
    let dir = data("neon-demo");
    let records = |name: &str| std::fs::metadata(dir.join(name)).unwrap().len() / 8;
    let eye = records("eye_state ps1.time");
    let gaze = records("gaze ps1.time");
    let mut imp = gazelight_import::open(&dir).unwrap();
    let s = summarize_importer(imp.as_mut(), FilterChain::with_defaults()).unwrap();
    assert_eq!(s.samples.pupil, [eye, eye]);
    assert_eq!(s.samples.gaze, gaze);
    assert_eq!(s.skipped_records, 0);
    eprintln!(
        "neon-demo: {eye} eye-state and {gaze} gaze records → pupils {:?}, gaze {}",
        s.samples.pupil, s.samples.gaze
    );
}
