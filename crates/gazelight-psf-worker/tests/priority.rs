//! The worker's threads run at the priority asked for, as the kernel
//! reports it (`/proc/self/task/*/stat`, proc(5): field 19 the nice value,
//! field 41 the scheduling policy; `SCHED_OTHER` 0, `SCHED_IDLE` 5). One
//! test in its own process: no other test's workers share the names.
#![cfg(target_os = "linux")]
#![allow(clippy::expect_used, clippy::unwrap_used)]

use gazelight_psf_worker::{Priority, PsfWorker};
use gazelight_vision::psf::{PsfBuilder, PsfParams};

/// (nice, policy) of every thread of this process named `gazelight-psf*`.
fn psf_threads() -> Vec<(String, i64, i64)> {
    let mut out = Vec::new();
    for task in std::fs::read_dir("/proc/self/task").expect("/proc/self/task") {
        let dir = task.expect("task").path();
        let comm = std::fs::read_to_string(dir.join("comm")).unwrap_or_default();
        let comm = comm.trim().to_string();
        if !comm.starts_with("gazelight-psf") {
            continue;
        }
        let stat = std::fs::read_to_string(dir.join("stat")).expect("stat");
        // Fields after the parenthesised name, which may hold spaces.
        let rest = &stat[stat.rfind(')').expect(")") + 2..];
        let f: Vec<&str> = rest.split_whitespace().collect();
        // `rest` starts at field 3 (state).
        let nice = f[19 - 3].parse().expect("nice");
        let policy = f[41 - 3].parse().expect("policy");
        out.push((comm, nice, policy));
    }
    out
}

fn wait_for_threads(n: usize) -> Vec<(String, i64, i64)> {
    for _ in 0..500 {
        let t = psf_threads();
        // Each thread lowers itself as it starts: wait until all have.
        if t.len() == n && t.iter().all(|(_, nice, policy)| *nice != 0 || *policy != 0) {
            return t;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    psf_threads()
}

#[test]
fn background_is_nice_10_and_idle_is_sched_idle() {
    let params = PsfParams {
        field_deg: 2.0,
        ppd: 8.0,
        ..PsfParams::default()
    };
    let initial = PsfBuilder::new(params.clone())
        .expect("builder")
        .kernel()
        .clone();
    {
        let _worker = PsfWorker::start(params.clone(), &initial, None, 1, Priority::Background)
            .expect("worker");
        // The worker thread and its build pool's one thread.
        let threads = wait_for_threads(2);
        assert_eq!(threads.len(), 2, "{threads:?}");
        for (name, nice, policy) in &threads {
            assert_eq!((*nice, *policy), (10, 0), "{name}: nice 10, SCHED_OTHER");
        }
    }
    // Dropping the worker joins its thread; the build pool's thread ends
    // soon after (rayon ends a dropped pool's threads asynchronously).
    for _ in 0..500 {
        if psf_threads().is_empty() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    assert!(psf_threads().is_empty(), "{:?}", psf_threads());
    let _worker = PsfWorker::start(params, &initial, None, 1, Priority::Idle).expect("worker");
    let threads = wait_for_threads(2);
    assert_eq!(threads.len(), 2, "{threads:?}");
    for (name, _, policy) in &threads {
        assert_eq!(*policy, 5, "{name}: SCHED_IDLE");
    }
}
