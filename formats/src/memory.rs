//! The memory guard: a [`Limits`] value that every reader and preparation asks before its
//! large allocations, and the counting allocator that says what the process holds.
//!
//! Where the program installs [`CountingAllocator`] (the `volterra` binary does), every heap
//! allocation is counted, and a request is refused when what is already in use plus the
//! request would pass the limit. What is allocated in small pieces is bounded by the large
//! requests. [`peak`] reports the most the command held, so tests can check that it stayed
//! within the limit.

use crate::error::{ErrorKind, FormatError, Result};
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::OnceLock;

static IN_USE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
/// Allocations at least this large update the peak at once; smaller ones are folded in at the
/// next large one or when [`peak`] is read (one relaxed add per small allocation).
const PEAK_STEP: usize = 1 << 16;

/// The system allocator, counting the bytes in use (install with `#[global_allocator]`).
pub struct CountingAllocator;

// SAFETY: every call is forwarded to the system allocator unchanged; only counters are added.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc(layout);
        if !p.is_null() {
            counted(layout.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(layout);
        if !p.is_null() {
            counted(layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout);
        IN_USE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = System.realloc(ptr, layout, new_size);
        if !p.is_null() {
            if new_size >= layout.size() {
                counted(new_size - layout.size());
            } else {
                IN_USE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

fn counted(bytes: usize) {
    let now = IN_USE.fetch_add(bytes, Ordering::Relaxed) + bytes;
    if bytes >= PEAK_STEP {
        PEAK.fetch_max(now, Ordering::Relaxed);
    }
}

/// What the process held outside its heap when a GPU whose memory is the host's was
/// opened (code, libraries, the driver itself): growth beyond it is the GPU's textures and
/// buffers (and the driver's own work), allocated by the driver, not through this
/// allocator. u64::MAX: no such GPU opened.
static NON_HEAP_BASELINE: AtomicU64 = AtomicU64::new(u64::MAX);
static HOST_GPU: OnceLock<String> = OnceLock::new();

/// Says that the GPU `name` keeps its textures and buffers in host memory (a software
/// renderer such as lavapipe, or an integrated GPU): from now on what the process holds
/// outside the heap beyond what it held now counts as in use, against the limit and in the
/// peak (`--max-memory` covered only the heap, and a terrain on lavapipe grew to 1.7× the
/// limit while the report said a third of it).
///
/// Only where [`CountingAllocator`] is installed (the heap is counted, so what lies outside
/// it is known): elsewhere (a test harness, a Python process) the growth outside a heap
/// that is not counted would be the whole process's, other threads' work included.
pub fn gpu_memory_is_host(name: &str) {
    // The GPU's instance and adapter are on the heap now: a count of 0 means none is kept.
    if in_heap() == 0 {
        return;
    }
    if HOST_GPU.set(name.to_string()).is_ok() {
        let non_heap = resident().map_or(0, |r| r.saturating_sub(in_heap()));
        NON_HEAP_BASELINE.store(non_heap, Ordering::Relaxed);
    }
}

/// The GPU whose memory is the host's, where one was opened.
pub fn host_gpu() -> Option<&'static str> {
    HOST_GPU.get().map(String::as_str)
}

/// A memory line of /proc/self/status ("VmRSS:", "VmHWM:"), in bytes (None: not Linux).
pub fn proc_status_bytes(key: &str) -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let kib: u64 = text.lines().find(|l| l.starts_with(key))?.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// The process's resident memory (bytes).
fn resident() -> Option<u64> {
    proc_status_bytes("VmRSS:")
}

fn in_heap() -> u64 {
    IN_USE.load(Ordering::Relaxed) as u64
}

/// Bytes in use now: the heap (0 where [`CountingAllocator`] is not installed), and where a
/// GPU keeps its memory in the host's (`gpu_memory_is_host`), what the process has grown
/// outside its heap since that GPU opened.
pub fn in_use() -> u64 {
    let heap = in_heap();
    let baseline = NON_HEAP_BASELINE.load(Ordering::Relaxed);
    if baseline == u64::MAX {
        return heap;
    }
    let outside = resident().map_or(0, |r| r.saturating_sub(heap).saturating_sub(baseline));
    heap + outside
}

/// The most bytes held at once so far, as `in_use` counts them (the heap's within the small
/// allocations between two large ones; with a GPU in host memory, the process's peak
/// resident memory less what it held outside the heap when the GPU opened).
pub fn peak() -> u64 {
    let now = IN_USE.load(Ordering::Relaxed);
    let heap_peak = PEAK.fetch_max(now, Ordering::Relaxed).max(now) as u64;
    let baseline = NON_HEAP_BASELINE.load(Ordering::Relaxed);
    if baseline == u64::MAX {
        return heap_peak;
    }
    proc_status_bytes("VmHWM:").map_or(heap_peak, |hwm| heap_peak.max(hwm.saturating_sub(baseline)))
}

/// What one command may allocate, handed to every reader and every renderer's preparation
/// (as image-rs hands its `Limits` to each decoder): each computes what a header or a
/// setting asks it to allocate and asks [`Limits::check`] first, so a lying header is
/// refused before anything is allocated.
///
/// The limit covers the whole command, not one allocation: with a set limit, what the
/// process already holds (counted by [`CountingAllocator`] where it is installed) is added to
/// each request.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Limits {
    /// The most heap bytes the command may hold (`--max-memory`); `None`: the memory
    /// available on this machine when each request is made.
    pub max_bytes: Option<u64>,
}

impl Limits {
    /// A limit of `bytes` for the whole command.
    pub fn max(bytes: u64) -> Limits {
        Limits { max_bytes: Some(bytes) }
    }

    /// The limit in force: the one set, else `MemAvailable` from /proc/meminfo, else 16 GiB.
    pub fn bytes(&self) -> u64 {
        self.max_bytes.unwrap_or_else(|| available_memory().unwrap_or(16 << 30))
    }

    /// Multiplies the factors (element counts and a byte size) with overflow checks and
    /// refuses the total if it, with what is already in use, would pass the limit. Returns
    /// the byte count as usize.
    pub fn check(&self, path: &Path, what: &str, factors: &[u64]) -> Result<usize> {
        let mut total: u64 = 1;
        for &f in factors {
            total = total
                .checked_mul(f)
                .ok_or_else(|| FormatError::new(path, ErrorKind::TooLarge, format!("{what}: size overflows ({factors:?})")))?;
        }
        let limit = self.bytes();
        if total > limit {
            return Err(FormatError::new(
                path,
                ErrorKind::TooLarge,
                format!(
                    "{what} needs {} but the memory limit is {} (set --max-memory to raise it)",
                    human_bytes(total),
                    human_bytes(limit)
                ),
            ));
        }
        // The default limit is the memory still available, which already leaves out what this
        // process holds; a set limit counts it.
        let used = if self.max_bytes.is_some() { in_use() } else { 0 };
        if used.saturating_add(total) > limit {
            return Err(FormatError::new(
                path,
                ErrorKind::TooLarge,
                format!(
                    "{what} needs {} more, and with {} already in use that passes the memory limit of {} (set --max-memory to raise it)",
                    human_bytes(total),
                    human_bytes(used),
                    human_bytes(limit)
                ),
            ));
        }
        usize::try_from(total).map_err(|_| FormatError::new(path, ErrorKind::TooLarge, format!("{what}: too large for this platform")))
    }
}

fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

pub fn human_bytes(n: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = n as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{n} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

/// Parses sizes such as `512M`, `8G`, `1.5GiB`, `1000000`.
pub fn parse_size(text: &str) -> Option<u64> {
    let t = text.trim();
    let split = t.find(|c: char| c.is_ascii_alphabetic()).unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let value: f64 = num.trim().parse().ok()?;
    let mult: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kb" | "kib" => 1024.0,
        "m" | "mb" | "mib" => 1024.0 * 1024.0,
        "g" | "gb" | "gib" => 1024.0 * 1024.0 * 1024.0,
        "t" | "tb" | "tib" => 1024.0f64.powi(4),
        _ => return None,
    };
    if !(value.is_finite() && value >= 0.0) {
        return None;
    }
    Some((value * mult) as u64)
}
