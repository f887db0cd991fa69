//! The traced photons on disk, keyed by everything they depend on — particles, kernel,
//! medium, lights, photon count, seed, free-flight rule, bounce cap — and nothing they do
//! not (camera, image size, store, gather, grids, step). A second view of the same smoke
//! reuses them: photon tracing is view-independent.
//!
//! Location: `$VOLTERRA_CACHE_DIR`, else `$XDG_CACHE_HOME/volterra`, else
//! `~/.cache/volterra`. Files are written atomically; a cache that cannot be read or
//! written is skipped with a note, never an error.

use super::photons::{Photon, Traced};
use glam::DVec3;
use std::path::PathBuf;

const MAGIC: &[u8; 8] = b"VTPHOT01";

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
    let bytes = std::fs::read(path(key)?).ok()?;
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
pub fn store(key: u64, traced: &Traced) -> Result<PathBuf, String> {
    let Traced { photons, emitted, escaped, capped } = traced;
    let p = path(key).ok_or("no cache directory (set VOLTERRA_CACHE_DIR)")?;
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
    std::fs::create_dir_all(p.parent().unwrap()).map_err(|e| format!("{}: {e}", p.display()))?;
    volterra_formats::atomic::write_bytes_atomically(&p, &bytes).map_err(|e| e.to_string())?;
    Ok(p)
}
