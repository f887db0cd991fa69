//! The traced photons on disk, keyed by everything they depend on — particles, kernel,
//! medium, lights, photon count, seed, free-flight rule, bounce cap — and nothing they do
//! not (camera, image size, store, gather, grids, step). A second view of the same smoke
//! reuses them: photon tracing is view-independent.
//!
//! Location: `$VOLTERRA_CACHE_DIR`, else `$XDG_CACHE_HOME/volterra`, else
//! `~/.cache/volterra`. Files are written atomically; a cache that cannot be read or
//! written is skipped with a note, never an error.
//!
//! Size: at most `$VOLTERRA_CACHE_MAX` (a size such as 500M or 4G; default
//! [`DEFAULT_MAX_BYTES`], 0 turns the cache off). After each store the least recently used
//! files (by modification time, which a load refreshes) are removed until the cache fits; a
//! run larger than the whole limit is not stored. `volterra cache --clear` empties it.

use super::photons::{Photon, Traced};
use glam::DVec3;
use std::path::PathBuf;

const MAGIC: &[u8; 8] = b"VTPHOT01";

/// The cache's default size limit: 1 GiB (the 640k-photon paper-scale run is ≈ 46 MB, the
/// tests' largest ≈ 370 MB).
pub const DEFAULT_MAX_BYTES: u64 = 1 << 30;

/// The size limit in force: `$VOLTERRA_CACHE_MAX`, else [`DEFAULT_MAX_BYTES`].
pub fn max_bytes() -> u64 {
    std::env::var("VOLTERRA_CACHE_MAX").ok().and_then(|v| volterra_formats::memory::parse_size(&v)).unwrap_or(DEFAULT_MAX_BYTES)
}

/// Changes whenever photon tracing draws its random numbers differently (the photons for
/// a seed change): photons traced by an older version are then traced again, not reused.
/// 2: majorant bricks walked whole, f32 density geometry.
const TRACER: &str = "tracer 2";

/// FNV-1a, 64 bits: stable across runs and platforms (std's hasher is not).
pub struct Key(u64);

impl Key {
    /// A key salted with [`TRACER`].
    pub fn new() -> Key {
        let mut k = Key(0xcbf2_9ce4_8422_2325);
        k.str(TRACER);
        k
    }
    pub fn bytes(&mut self, b: &[u8]) -> &mut Key {
        for &x in b {
            self.0 ^= x as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01B3);
        }
        self
    }
    pub fn f64(&mut self, v: f64) -> &mut Key {
        self.bytes(&v.to_bits().to_le_bytes())
    }
    pub fn u64(&mut self, v: u64) -> &mut Key {
        self.bytes(&v.to_le_bytes())
    }
    pub fn str(&mut self, s: &str) -> &mut Key {
        self.u64(s.len() as u64).bytes(s.as_bytes())
    }
    pub fn finish(&self) -> u64 {
        self.0
    }
}

impl Default for Key {
    fn default() -> Self {
        Key::new()
    }
}

pub fn cache_dir() -> Option<PathBuf> {
    if let Some(d) = std::env::var_os("VOLTERRA_CACHE_DIR") {
        return Some(PathBuf::from(d));
    }
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME") {
        return Some(PathBuf::from(d).join("volterra"));
    }
    std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/volterra"))
}

fn path(key: u64) -> Option<PathBuf> {
    cache_dir().map(|d| d.join(format!("photons-{key:016x}.bin")))
}

/// The cached tracing run for `key`, if present and intact.
pub fn load(key: u64) -> Option<Traced> {
    if max_bytes() == 0 {
        return None;
    }
    let p = path(key)?;
    let bytes = std::fs::read(&p).ok()?;
    // A use counts as recent for the least-recently-used eviction.
    if let Ok(f) = std::fs::File::options().append(true).open(&p) {
        let _ = f.set_modified(std::time::SystemTime::now());
    }
    if bytes.len() < 8 + 8 + 56 || &bytes[..8] != MAGIC {
        return None;
    }
    let f = |i: usize| f64::from_le_bytes(bytes[i..i + 8].try_into().unwrap());
    let n = u64::from_le_bytes(bytes[8..16].try_into().unwrap()) as usize;
    let header = 16 + 56;
    if bytes.len() != header + n * 72 {
        return None;
    }
    let emitted = [f(16), f(24), f(32)];
    let escaped = [f(40), f(48), f(56)];
    let capped = f(64) as usize;
    let photons = (0..n)
        .map(|k| {
            let o = header + 72 * k;
            Photon {
                position: DVec3::new(f(o), f(o + 8), f(o + 16)),
                direction: DVec3::new(f(o + 24), f(o + 32), f(o + 40)),
                power: [f(o + 48), f(o + 56), f(o + 64)],
            }
        })
        .collect();
    Some(Traced { photons, emitted, escaped, capped })
}

/// Stores a tracing run under `key`; returns why not, where it could not.
pub fn store(key: u64, traced: &Traced) -> anyhow::Result<PathBuf> {
    let Traced { photons, emitted, escaped, capped } = traced;
    let p = path(key).ok_or_else(|| anyhow::anyhow!("no cache directory (set VOLTERRA_CACHE_DIR)"))?;
    let limit = max_bytes();
    let size = 72 + 72 * photons.len() as u64;
    if size > limit {
        anyhow::bail!("{size} bytes of photons exceed the cache's limit of {limit} (VOLTERRA_CACHE_MAX)");
    }
    let mut bytes = Vec::with_capacity(72 + 72 * photons.len());
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&(photons.len() as u64).to_le_bytes());
    for v in emitted.iter().chain(escaped).chain(&[*capped as f64]) {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    for ph in photons {
        for v in ph.position.to_array().iter().chain(&ph.direction.to_array()).chain(&ph.power) {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::create_dir_all(p.parent().unwrap()).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
    volterra_formats::atomic::write_bytes_atomically(&p, &bytes)?;
    evict(p.parent().unwrap(), limit, &p);
    Ok(p)
}

/// The cache's photon files with their sizes and last use, oldest first.
fn entries(dir: &std::path::Path) -> Vec<(PathBuf, u64, std::time::SystemTime)> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("photons-") && e.file_name().to_string_lossy().ends_with(".bin"))
        .filter_map(|e| {
            let m = e.metadata().ok()?;
            Some((e.path(), m.len(), m.modified().ok()?))
        })
        .collect();
    files.sort_by_key(|f| f.2);
    files
}

/// Removes the least recently used photon files in `dir` until they total at most `limit`
/// bytes, never `keep` (the run just stored).
pub fn evict(dir: &std::path::Path, limit: u64, keep: &std::path::Path) {
    let files = entries(dir);
    let mut total: u64 = files.iter().map(|f| f.1).sum();
    for (path, size, _) in files {
        if total <= limit {
            break;
        }
        if path != keep && std::fs::remove_file(&path).is_ok() {
            total -= size;
        }
    }
}

/// (files, bytes) in the cache.
pub fn usage() -> Option<(PathBuf, usize, u64)> {
    let dir = cache_dir()?;
    let files = entries(&dir);
    Some((dir, files.len(), files.iter().map(|f| f.1).sum()))
}

/// Removes every photon file; returns how many.
pub fn clear() -> usize {
    cache_dir().map(|d| entries(&d).into_iter().filter(|f| std::fs::remove_file(&f.0).is_ok()).count()).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, SystemTime};

    #[test]
    fn eviction_removes_the_least_recently_used_until_the_cache_fits() {
        let dir = tempfile::tempdir().unwrap();
        let t0 = SystemTime::now() - Duration::from_secs(1000);
        for (k, age) in [(1u64, 5u64), (2, 1), (3, 9), (4, 3)] {
            let p = dir.path().join(format!("photons-{k:016x}.bin"));
            std::fs::write(&p, vec![0u8; 100]).unwrap();
            std::fs::File::options().append(true).open(&p).unwrap().set_modified(t0 + Duration::from_secs(100 - age)).unwrap();
        }
        std::fs::write(dir.path().join("other.txt"), vec![0u8; 500]).unwrap();
        let keep = dir.path().join(format!("photons-{:016x}.bin", 3));
        evict(dir.path(), 250, &keep);
        let left: Vec<String> = entries(dir.path()).iter().map(|e| e.0.file_name().unwrap().to_string_lossy().into_owned()).collect();
        // Oldest first: 3 (kept although oldest), then 1 and 4 go; 2, the newest, stays.
        assert_eq!(left, vec![format!("photons-{:016x}.bin", 3), format!("photons-{:016x}.bin", 2)]);
        assert!(dir.path().join("other.txt").exists(), "only photon files are evicted");
    }
}
