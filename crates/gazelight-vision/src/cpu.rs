//! What the CPU's caches hold, for the passes that pick their store kind
//! by it (pass A's copy: non-temporal stores pay off only when the frame
//! would not stay in cache anyway).

use std::sync::OnceLock;

/// Bytes of the largest (last-level) cache the CPU reports through CPUID
/// (leaf 4 on Intel, leaf 0x8000_001D on AMD; both describe each cache
/// as ways × partitions × line size × sets), or `None` where it reports
/// none (another vendor, another architecture, a hypervisor that hides
/// the leaves). Read once per process.
pub fn last_level_cache_bytes() -> Option<usize> {
    static LLC: OnceLock<Option<usize>> = OnceLock::new();
    *LLC.get_or_init(read_last_level_cache)
}

/// The most a frame pass may touch and still count as kept in cache,
/// whatever the CPU reports: a VM's last-level cache is shared with other
/// tenants, so its reported size overstates what stays ours. Measured on a
/// 2-core VM that reports 480 MiB (BENCHMARKS.md, pass A's stores): a
/// 13.8 MB pass (720×800) ran faster with plain stores, a 55 MB one
/// (1440×1600) slower once anything else ran between frames.
pub const CACHE_SHARE_CAP_BYTES: usize = 32 << 20;

/// Whether a pass that touches `bytes` (read and written together) keeps
/// them in the last-level cache: at most half of it (the rest left to
/// everything else the frame and the other core use) and at most
/// [`CACHE_SHARE_CAP_BYTES`]. Unknown cache: no.
pub fn frame_fits_in_cache(bytes: usize) -> bool {
    last_level_cache_bytes().is_some_and(|llc| bytes <= (llc / 2).min(CACHE_SHARE_CAP_BYTES))
}

#[cfg(target_arch = "x86_64")]
fn read_last_level_cache() -> Option<usize> {
    use std::arch::x86_64::{__cpuid_count, CpuidResult};
    #[allow(unused_unsafe)]
    // SAFETY: CPUID exists on every x86-64 CPU; the leaves read below are
    // at most the highest one the CPU says it has.
    let cpuid = |leaf: u32, sub: u32| -> CpuidResult { unsafe { __cpuid_count(leaf, sub) } };
    let id = cpuid(0, 0);
    let vendor = [id.ebx, id.edx, id.ecx]
        .iter()
        .flat_map(|r| r.to_le_bytes())
        .collect::<Vec<u8>>();
    let leaf = match &vendor[..] {
        b"GenuineIntel" if id.eax >= 4 => 4,
        b"AuthenticAMD" | b"HygonGenuine" if cpuid(0x8000_0000, 0).eax >= 0x8000_001D => {
            0x8000_001D
        }
        _ => return None,
    };
    let mut largest: Option<usize> = None;
    // At most 16 cache descriptions (real CPUs have 4 or 5).
    for sub in 0..16 {
        let c = cpuid(leaf, sub);
        // EAX[4:0]: cache type, 0 = no more caches.
        if c.eax & 0x1f == 0 {
            break;
        }
        let ways = ((c.ebx >> 22) & 0x3ff) as usize + 1;
        let partitions = ((c.ebx >> 12) & 0x3ff) as usize + 1;
        let line = (c.ebx & 0xfff) as usize + 1;
        let sets = c.ecx as usize + 1;
        let bytes = ways * partitions * line * sets;
        largest = Some(largest.map_or(bytes, |l| l.max(bytes)));
    }
    largest
}

#[cfg(not(target_arch = "x86_64"))]
fn read_last_level_cache() -> Option<usize> {
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The figure CPUID gives agrees with what Linux says of the same
    /// caches (sysfs, filled by the kernel from its own reading of the
    /// CPU): the largest cache of cpu0.
    #[test]
    fn last_level_cache_matches_sysfs() {
        let dir = std::path::Path::new("/sys/devices/system/cpu/cpu0/cache");
        let Ok(entries) = std::fs::read_dir(dir) else {
            eprintln!("SKIP: no {}", dir.display());
            return;
        };
        let mut sysfs: Option<usize> = None;
        for e in entries.flatten() {
            let Ok(size) = std::fs::read_to_string(e.path().join("size")) else {
                continue;
            };
            let size = size.trim();
            let (num, mult) = match size.strip_suffix('K') {
                Some(n) => (n, 1024),
                None => match size.strip_suffix('M') {
                    Some(n) => (n, 1024 * 1024),
                    None => (size, 1),
                },
            };
            if let Ok(n) = num.parse::<usize>() {
                sysfs = Some(sysfs.map_or(n * mult, |s| s.max(n * mult)));
            }
        }
        match (sysfs, last_level_cache_bytes()) {
            (Some(s), Some(c)) => assert_eq!(c, s, "CPUID {c} B, sysfs {s} B"),
            (s, c) => eprintln!("SKIP: sysfs {s:?}, CPUID {c:?}"),
        }
    }

    #[test]
    fn fits_uses_half_the_cache() {
        if let Some(llc) = last_level_cache_bytes() {
            let limit = (llc / 2).min(CACHE_SHARE_CAP_BYTES);
            assert!(frame_fits_in_cache(limit));
            assert!(!frame_fits_in_cache(limit + 1));
        } else {
            assert!(!frame_fits_in_cache(1));
        }
    }
}
