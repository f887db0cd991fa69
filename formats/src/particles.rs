//! `ParticleSet`: particle positions with the SPH quantities the smoke renderer needs
//! (mass, density, smoothing length h) and every other point array kept by name.

use serde::{Deserialize, Serialize};

/// A named per-particle array, `components` values per particle, widened to f64 (exact for
/// every VTK type up to 32-bit integers and all floats).
#[derive(Debug, Clone, PartialEq)]
pub struct PointArray {
    pub name: String,
    pub components: usize,
    pub values: Vec<f64>,
}

#[derive(Debug, Clone)]
pub struct ParticleSet {
    /// Positions in the file's units (metres for the simulations we read).
    pub positions: Vec<[f64; 3]>,
    /// Per-particle mass, where the file has the array named in the options.
    pub mass: Option<Vec<f32>>,
    /// Per-particle density.
    pub density: Option<Vec<f32>>,
    /// Per-particle SPH smoothing length h (the kernel support is 2h).
    pub smoothing_length: Option<Vec<f32>>,
    /// Every other point array, in file order.
    pub arrays: Vec<PointArray>,
    pub notes: Vec<String>,
}

/// Which point arrays hold the SPH quantities. Defaults: `mass`, `density`, `h`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ParticleArrayNames {
    pub mass: String,
    pub density: String,
    pub smoothing_length: String,
}

impl Default for ParticleArrayNames {
    fn default() -> Self {
        ParticleArrayNames { mass: "mass".into(), density: "density".into(), smoothing_length: "h".into() }
    }
}

impl ParticleSet {
    pub fn len(&self) -> usize {
        self.positions.len()
    }
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
    /// Axis-aligned bounds of the particles at finite positions: (min, max), None when
    /// there is none.
    pub fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        let mut any = false;
        for p in self.positions.iter().filter(|p| is_finite(p)) {
            any = true;
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        any.then_some((lo, hi))
    }

    /// How many particles sit at positions that are not finite (a coordinate NaN or
    /// infinite), and the first of them.
    pub fn non_finite_positions(&self) -> (usize, Option<usize>) {
        let first = self.positions.iter().position(|p| !is_finite(p));
        let count = first.map_or(0, |f| self.positions[f..].iter().filter(|p| !is_finite(p)).count());
        (count, first)
    }

    /// The rule every renderer follows for particles at positions that are not finite
    /// (a simulation's lost or blown-up particles): they cannot be drawn, so they are left
    /// out — with the note that says how many (`non_finite_note`), never silently. The set
    /// itself where every position is finite; otherwise a copy without those particles
    /// (every array with them).
    pub fn drawable(self) -> ParticleSet {
        let (count, _) = self.non_finite_positions();
        if count == 0 {
            return self;
        }
        let keep: Vec<bool> = self.positions.iter().map(is_finite).collect();
        let pick_f32 = |v: Option<Vec<f32>>| v.map(|v| v.into_iter().zip(&keep).filter(|(_, k)| **k).map(|(x, _)| x).collect());
        let arrays = self
            .arrays
            .into_iter()
            .map(|a| PointArray {
                values: a.values.chunks(a.components.max(1)).zip(&keep).filter(|(_, k)| **k).flat_map(|(c, _)| c.iter().copied()).collect(),
                ..a
            })
            .collect();
        ParticleSet {
            positions: self.positions.into_iter().filter(is_finite).collect(),
            mass: pick_f32(self.mass),
            density: pick_f32(self.density),
            smoothing_length: pick_f32(self.smoothing_length),
            arrays,
            notes: self.notes,
        }
    }

    /// What is said of the particles at positions that are not finite, where there are any.
    pub fn non_finite_note(&self) -> Option<String> {
        let (count, first) = self.non_finite_positions();
        let i = first?;
        let p = self.positions[i];
        Some(format!(
            "{count} of {} particles are at positions that are not finite (NaN or infinite; the first, particle {i}, at ({}, {}, {})): they are left out of rendering",
            self.len(),
            p[0],
            p[1],
            p[2]
        ))
    }
    /// Names of all arrays present, SPH quantities first.
    pub fn array_names(&self, names: &ParticleArrayNames) -> Vec<String> {
        let mut out = Vec::new();
        if self.mass.is_some() {
            out.push(names.mass.clone());
        }
        if self.density.is_some() {
            out.push(names.density.clone());
        }
        if self.smoothing_length.is_some() {
            out.push(names.smoothing_length.clone());
        }
        out.extend(self.arrays.iter().map(|a| a.name.clone()));
        out
    }

    /// Builds a set from positions and arrays, moving the SPH quantities out by name.
    /// Multi-component arrays with an SPH name are refused.
    pub fn from_arrays(
        positions: Vec<[f64; 3]>,
        arrays: Vec<PointArray>,
        names: &ParticleArrayNames,
        notes: Vec<String>,
    ) -> std::result::Result<ParticleSet, String> {
        let n = positions.len();
        let mut set = ParticleSet { positions, mass: None, density: None, smoothing_length: None, arrays: Vec::new(), notes };
        set.notes.extend(set.non_finite_note());
        for a in arrays {
            if a.values.len() != n * a.components {
                return Err(format!("array '{}' has {} values for {} points × {} components", a.name, a.values.len(), n, a.components));
            }
            let slot = if a.name == names.mass {
                Some(&mut set.mass)
            } else if a.name == names.density {
                Some(&mut set.density)
            } else if a.name == names.smoothing_length {
                Some(&mut set.smoothing_length)
            } else {
                None
            };
            match slot {
                Some(s) if s.is_none() => {
                    if a.components != 1 {
                        return Err(format!("array '{}' must have one component, it has {}", a.name, a.components));
                    }
                    *s = Some(a.values.iter().map(|&v| v as f32).collect());
                }
                _ => set.arrays.push(a),
            }
        }
        Ok(set)
    }
}

/// Whether every coordinate of a position is finite.
fn is_finite(p: &[f64; 3]) -> bool {
    p.iter().all(|v| v.is_finite())
}
