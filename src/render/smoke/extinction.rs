//! The extinction coefficient when a scene gives none: chosen from the data so that the
//! densest part of the smoke has an optical depth of about [`TARGET_DEPTH`], whatever the
//! units — a plume in metres and kg/m³, a star catalogue in parsecs and solar masses, a
//! halo in code units all come out as smoke, not as opaque blobs or nothing.
//!
//! The rule: the particles' mass is binned into a grid of cubic cells (at most 64 along
//! the longest side, and no finer than two median smoothing lengths, so a column averages
//! over at least a kernel's width); each column of cells along x, y and z gives a column
//! density Σ (mass per area); Σ* is the median over the three axes of each axis's largest
//! column (a view along a long axis of the smoke, through its whole length, does not set
//! it). Then c_ext = TARGET_DEPTH / Σ*: the optical depth c_ext·Σ through the densest
//! column along the median axis is TARGET_DEPTH. Scaling lengths by s and masses by m
//! scales Σ* by m/s² and c_ext by s²/m: the picture is the same in any units.

use super::medium::SphMedium;
use glam::DVec3;

/// The optical depth the densest column gets.
pub const TARGET_DEPTH: f64 = 2.0;

/// The chosen coefficient and the column density it was chosen from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AutoExtinction {
    pub c_ext: f64,
    /// Σ*: mass per area (the particles' mass unit per squared length unit).
    pub column: f64,
}

/// None when the particles have no mass (nothing to see).
pub fn auto_extinction(m: &SphMedium) -> Option<AutoExtinction> {
    let n = m.len();
    let positions: Vec<DVec3> = (0..n).map(|i| m.position(i)).collect();
    let mass: Vec<f64> = (0..n).map(|i| m.mass(i)).collect();
    let h: Vec<f64> = (0..n).map(|i| m.smoothing_length(i)).collect();
    densest_column(&positions, &mass, &h).map(|column| AutoExtinction { c_ext: TARGET_DEPTH / column, column })
}

/// Σ*, the column density the rule above sets c_ext by, of particles at `positions` (world
/// coordinates) with masses `mass` and smoothing lengths `h` (world units); None where they
/// have no mass. (A time series takes the largest over its steps: `render::series_scale`.)
pub fn densest_column(positions: &[DVec3], mass: &[f64], h: &[f64]) -> Option<f64> {
    let n = positions.len();
    if n == 0 {
        return None;
    }
    let mut h = h.to_vec();
    h.sort_by(f64::total_cmp);
    let h = h[n / 2];
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for &p in positions {
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let extent = (hi - lo).max_element();
    let cell = (extent / 64.0).max(2.0 * h);
    if !(cell.is_finite() && cell > 0.0) {
        return None;
    }
    let dims = ((hi - lo) / cell).floor().as_uvec3().min(glam::UVec3::splat(63)) + 1;
    let [nx, ny, nz] = [dims.x as usize, dims.y as usize, dims.z as usize];
    let mut binned = vec![0.0f64; nx * ny * nz];
    for (&p, &m) in positions.iter().zip(mass) {
        let c = ((p - lo) / cell).floor().as_uvec3().min(dims - 1);
        binned[c.x as usize + nx * (c.y as usize + ny * c.z as usize)] += m;
    }
    let at = |x: usize, y: usize, z: usize| binned[x + nx * (y + ny * z)];
    let area = cell * cell;
    // The largest column along each axis.
    let mut best = [0.0f64; 3];
    for z in 0..nz {
        for y in 0..ny {
            best[0] = best[0].max((0..nx).map(|x| at(x, y, z)).sum::<f64>() / area);
        }
    }
    for z in 0..nz {
        for x in 0..nx {
            best[1] = best[1].max((0..ny).map(|y| at(x, y, z)).sum::<f64>() / area);
        }
    }
    for y in 0..ny {
        for x in 0..nx {
            best[2] = best[2].max((0..nz).map(|z| at(x, y, z)).sum::<f64>() / area);
        }
    }
    best.sort_by(f64::total_cmp);
    let column = best[1];
    (column > 0.0 && column.is_finite()).then_some(column)
}
