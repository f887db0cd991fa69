//! The memory guard: every reader computes what a header asks it to allocate and asks here
//! first, so a lying header is refused before anything is allocated.

use crate::error::{ErrorKind, FormatError, Result};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

/// 0 means "not set": use the memory available on this machine.
static LIMIT_BYTES: AtomicU64 = AtomicU64::new(0);

/// Sets the largest single allocation a reader may make for file data (`--max-memory`).
pub fn set_limit(bytes: u64) {
    LIMIT_BYTES.store(bytes, Ordering::Relaxed);
}

/// The limit in force: the one set, else `MemAvailable` from /proc/meminfo, else 16 GiB.
pub fn limit() -> u64 {
    match LIMIT_BYTES.load(Ordering::Relaxed) {
        0 => available_memory().unwrap_or(16 << 30),
        n => n,
    }
}

fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// Multiplies the factors (element counts and a byte size) with overflow checks and
/// refuses the total if it exceeds the limit. Returns the byte count as usize.
pub fn check_alloc(path: &Path, what: &str, factors: &[u64]) -> Result<usize> {
    let mut total: u64 = 1;
    for &f in factors {
        total = total
            .checked_mul(f)
            .ok_or_else(|| FormatError::new(path, ErrorKind::TooLarge, format!("{what}: size overflows ({factors:?})")))?;
    }
    let limit = limit();
    if total > limit {
        return Err(FormatError::new(
            path,
            ErrorKind::TooLarge,
            format!("{what} needs {} but the memory limit is {} (set --max-memory to raise it)", human_bytes(total), human_bytes(limit)),
        ));
    }
    usize::try_from(total).map_err(|_| FormatError::new(path, ErrorKind::TooLarge, format!("{what}: too large for this platform")))
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
