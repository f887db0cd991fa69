//! The heightfield as both terrain renderers see it: "grid space", where sample (i, j)
//! sits at (i, j) — i east, j north, j = 0 the southern row — and z is the elevation in
//! metres relative to `z_ref`, the middle of the elevation range. Ray parameters stay
//! world distances: a world ray o + t·d maps to grid space as o' + t·d' with d' not unit.
//!
//! Keeping positions in cells (≤ a few thousand) and heights relative to the middle of the
//! range is what lets the GPU work in f32: a UTM eye at 5·10⁶ m, or a peak at 4000 m,
//! would lose centimetres to f32 rounding if used directly.

use crate::geometry::clip_box;
use crate::scene::camera::Ray;
use anyhow::{bail, Result};
use glam::{DMat3, DMat4, DVec3};
use std::sync::Arc;
use volterra_formats::Heightfield;

/// Lid-map value of a patch that touches a NoData sample: lower than any ray.
pub const HOLE: f32 = -3.0e38;

pub use volterra_formats::heightfield::HeightRows;

/// Where a grid's heights are: a heightfield in memory, shared and not copied (a large
/// DEM is most of the memory a render holds), or a source read row by row.
#[derive(Clone)]
enum Samples {
    Held(Arc<Heightfield>),
    Rows(Arc<dyn HeightRows>),
}

impl std::fmt::Debug for Samples {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Samples::Held(hf) => write!(f, "Held({}×{})", hf.width, hf.height),
            Samples::Rows(r) => write!(f, "Rows({:?})", r.size()),
        }
    }
}

#[derive(Debug, Clone)]
pub struct TerrainGrid {
    /// Samples east-west and south-north.
    pub nx: usize,
    pub ny: usize,
    /// The heights, read relative to `z_ref` (see `height`).
    samples: Samples,
    pub z_ref: f64,
    /// Range of valid heights relative to `z_ref` (0, 0 when every sample is NoData).
    pub z_lo: f64,
    pub z_hi: f64,
    pub any_valid: bool,
    /// Cell size in metres (east, north).
    pub cell: [f64; 2],
    pub world_to_grid: DMat4,
    /// Takes a normal in the node's local frame (metres) to world space.
    pub normal_to_world: DMat3,
}

/// The point where a ray meets the terrain: cell (i, j), position (u, v) ∈ [0, 1]² inside
/// it, and the world distance `t` along the ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub cell: [usize; 2],
    pub u: f64,
    pub v: f64,
}

impl TerrainGrid {
    /// The grid of a copy of `hf` (see [`TerrainGrid::shared`] to share it).
    pub fn new(hf: &Heightfield, node_to_world: DMat4) -> Result<TerrainGrid> {
        TerrainGrid::shared(Arc::new(hf.clone()), node_to_world)
    }

    pub fn shared(hf: Arc<Heightfield>, node_to_world: DMat4) -> Result<TerrainGrid> {
        let (nx, ny) = (hf.width, hf.height);
        if hf.elevations.len() != nx * ny {
            bail!("the heightfield holds {} elevations for {nx}×{ny} samples", hf.elevations.len());
        }
        let range = hf.range();
        let cell = hf.cell_size;
        TerrainGrid::with_samples([nx, ny], cell, range, Samples::Held(hf), node_to_world)
    }

    /// The grid with its solid spanning at least `span` (metres): its box from the lower of
    /// its own lowest sample and `span[0]` (the walls at its edges reach down there) to the
    /// higher of its highest and `span[1]`, `z_ref` their middle. A view window's grid spans
    /// the whole raster's range, so it draws as the whole would (the walls at the raster's
    /// edges as deep, the same heights relative to `z_ref`). A grid with no valid sample
    /// stays as it is.
    pub fn spanning(self, span: [f64; 2], node_to_world: DMat4) -> Result<TerrainGrid> {
        if !self.any_valid {
            return Ok(self);
        }
        let [lo, hi] = self.elevations();
        let (lo, hi) = (lo.min(span[0]) as f32, hi.max(span[1]) as f32);
        TerrainGrid::with_samples([self.nx, self.ny], self.cell, Some((lo, hi)), self.samples, node_to_world)
    }

    /// The lowest and highest elevation the grid spans, in metres: its valid samples', or
    /// more where it was made `spanning`. The elevation colours span it by default.
    pub fn elevations(&self) -> [f64; 2] {
        [self.z_ref + self.z_lo, self.z_ref + self.z_hi]
    }

    /// What the elevations are measured in, as the scalar bar prints it: "m", or "grey
    /// level" for a PNG heightmap given no vertical scale (rows read from a GeoTIFF are
    /// metres).
    pub fn elevation_unit(&self) -> &'static str {
        match &self.samples {
            Samples::Held(hf) => hf.units.elevation_unit(),
            Samples::Rows(_) => "m",
        }
    }

    /// The grid of heights read row by row from `rows` (the elevation range found by
    /// reading every row once).
    pub fn from_rows(rows: Arc<dyn HeightRows>, node_to_world: DMat4) -> Result<TerrainGrid> {
        let [nx, ny] = rows.size();
        let range = rows.elevation_range();
        if let Some(why) = rows.failure() {
            bail!("{why}");
        }
        let cell = rows.cell_size();
        TerrainGrid::with_samples([nx, ny], cell, range, Samples::Rows(rows), node_to_world)
    }

    fn with_samples(
        [nx, ny]: [usize; 2],
        [cx, cy]: [f64; 2],
        range: Option<(f32, f32)>,
        samples: Samples,
        node_to_world: DMat4,
    ) -> Result<TerrainGrid> {
        if nx < 2 || ny < 2 {
            bail!("a terrain needs at least 2×2 samples (this heightfield has {nx}×{ny})");
        }
        if !(cx > 0.0 && cy > 0.0 && cx.is_finite() && cy.is_finite()) {
            bail!("heightfield cell size {cx}×{cy} m is not positive");
        }
        if node_to_world.determinant().abs() < 1e-300 || !node_to_world.is_finite() {
            bail!("the heightfield node's transform is not invertible");
        }
        let (lo, hi) = range.map(|(a, b)| (a as f64, b as f64)).unwrap_or((0.0, 0.0));
        let z_ref = 0.5 * (lo + hi);
        let local_to_grid = DMat4::from_scale(DVec3::new(1.0 / cx, 1.0 / cy, 1.0)) * DMat4::from_translation(DVec3::new(0.0, 0.0, -z_ref));
        let world_to_grid = local_to_grid * node_to_world.inverse();
        let lin = DMat3::from_mat4(node_to_world);
        Ok(TerrainGrid {
            nx,
            ny,
            samples,
            z_ref,
            z_lo: lo - z_ref,
            z_hi: hi - z_ref,
            any_valid: range.is_some(),
            cell: [cx, cy],
            world_to_grid,
            normal_to_world: lin.inverse().transpose(),
        })
    }

    /// Heights of samples i0 … i0 + out.len() − 1 of row j (grid space: j = 0 the southern
    /// row), relative to `z_ref`; NaN for NoData.
    pub fn heights_of_row(&self, i0: usize, j: usize, out: &mut [f32]) {
        match &self.samples {
            Samples::Held(_) => {
                for (k, h) in out.iter_mut().enumerate() {
                    *h = self.height(i0 + k, j);
                }
            }
            Samples::Rows(rows) => {
                rows.read_row(self.ny - 1 - j, i0, out);
                for z in out.iter_mut() {
                    *z = if z.is_finite() { (*z as f64 - self.z_ref) as f32 } else { f32::NAN };
                }
            }
        }
    }

    /// Why the heights could not all be read, once they have been (see
    /// `HeightRows::failure`); None for a heightfield held.
    pub fn read_failure(&self) -> Option<String> {
        match &self.samples {
            Samples::Held(_) => None,
            Samples::Rows(rows) => rows.failure(),
        }
    }

    /// Number of patches (cells) east-west and south-north.
    pub fn cells(&self) -> [usize; 2] {
        [self.nx - 1, self.ny - 1]
    }

    /// The height of sample (i, j) relative to `z_ref` (f32, as the GPU holds it); NaN for
    /// NoData.
    pub fn height(&self, i: usize, j: usize) -> f32 {
        let row = self.ny - 1 - j;
        match &self.samples {
            Samples::Held(hf) => {
                let z = hf.elevations[row * self.nx + i];
                if z.is_finite() && !hf.is_nodata(i, row) {
                    (z as f64 - self.z_ref) as f32
                } else {
                    f32::NAN
                }
            }
            Samples::Rows(_) => {
                let mut z = [0f32];
                self.heights_of_row(i, j, &mut z);
                z[0]
            }
        }
    }

    /// The elevation (metres) at a point of the node's local frame — x east, y north in
    /// metres from the south-west sample — bilinear on the patch there, as the f32 heights
    /// the renderers hold; None outside the samples or on a patch touching NoData.
    pub fn surface_height(&self, x: f64, y: f64) -> Option<f64> {
        let [cx, cy] = self.cells();
        let (gx, gy) = (x / self.cell[0], y / self.cell[1]);
        if !(gx >= 0.0 && gy >= 0.0 && gx <= cx as f64 && gy <= cy as f64) {
            return None;
        }
        let (i, j) = ((gx.floor() as usize).min(cx - 1), (gy.floor() as usize).min(cy - 1));
        Some(self.z_ref + bilinear(self.patch(i, j)?, gx - i as f64, gy - j as f64))
    }

    /// The patch's corner heights (z00, z10, z01, z11), or None where one is NoData.
    pub fn patch(&self, i: usize, j: usize) -> Option<[f64; 4]> {
        let z = [self.height(i, j), self.height(i + 1, j), self.height(i, j + 1), self.height(i + 1, j + 1)];
        z.iter().all(|v| v.is_finite()).then(|| z.map(|v| v as f64))
    }

    /// A world ray in grid space (origin, direction); the parameter stays the world distance.
    pub fn ray_to_grid(&self, ray: &Ray) -> (DVec3, DVec3) {
        (self.world_to_grid.transform_point3(ray.origin), self.world_to_grid.transform_vector3(ray.dir))
    }

    /// The grid-space bounding box of the patches: [0, cells] × [z_lo, z_hi], the z slab
    /// widened by 1e-4 of the relief (at least 1e-4 m) so that a ray grazing the highest
    /// peak, or crossing a perfectly flat terrain, is not clipped away by rounding. The
    /// GPU pads the same way.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let [cx, cy] = self.cells();
        let pad = 1e-4 * (self.z_hi - self.z_lo).max(1.0);
        (DVec3::new(0.0, 0.0, self.z_lo - pad), DVec3::new(cx as f64, cy as f64, self.z_hi + pad))
    }

    /// The part t ∈ [t0, t1], t0 ≥ 0, of a grid-space ray inside the bounding box.
    pub fn clip(&self, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
        if !self.any_valid {
            return None;
        }
        let (lo, hi) = self.bounds();
        clip_box(o, d, lo, hi)
    }

    /// The unit world-space normal of the patch at (u, v).
    /// The height gradient at sample (i, j) in metres per metre (east, north): central
    /// differences, one-sided where a neighbour is NoData or beyond the edge, 0 along an
    /// axis where both are. The same rule as the shader's `axis_difference`.
    pub fn sample_gradient(&self, i: usize, j: usize) -> [f64; 2] {
        let z = self.height(i, j) as f64;
        let at = |i: Option<usize>, j: Option<usize>| -> Option<f64> {
            let (i, j) = (i?, j?);
            (i < self.nx && j < self.ny).then(|| self.height(i, j) as f64).filter(|z| z.is_finite())
        };
        let diff = |up: Option<f64>, down: Option<f64>| match (up, down) {
            (Some(a), Some(b)) => 0.5 * (a - b),
            (Some(a), None) => a - z,
            (None, Some(b)) => z - b,
            (None, None) => 0.0,
        };
        let gx = diff(at(Some(i + 1), Some(j)), at(i.checked_sub(1), Some(j))) / self.cell[0];
        let gy = diff(at(Some(i), Some(j + 1)), at(Some(i), j.checked_sub(1))) / self.cell[1];
        [gx, gy]
    }

    /// The smooth shading normal (world space, unit) at (u, v) in patch (i, j): the corner
    /// samples' gradients interpolated bilinearly, continuous across patch borders.
    pub fn smooth_world_normal(&self, i: usize, j: usize, u: f64, v: f64) -> DVec3 {
        let g = [
            self.sample_gradient(i, j),
            self.sample_gradient(i + 1, j),
            self.sample_gradient(i, j + 1),
            self.sample_gradient(i + 1, j + 1),
        ];
        let lerp = |k: usize| (1.0 - v) * ((1.0 - u) * g[0][k] + u * g[1][k]) + v * ((1.0 - u) * g[2][k] + u * g[3][k]);
        (self.normal_to_world * DVec3::new(-lerp(0), -lerp(1), 1.0)).normalize()
    }

    /// The exact normal of the bilinear patch with corner heights `z` at (u, v): faceted,
    /// discontinuous across patch borders.
    pub fn world_normal(&self, z: [f64; 4], u: f64, v: f64) -> DVec3 {
        let (a, b, c) = patch_coefficients(z);
        let local = DVec3::new(-(b + a * v) / self.cell[0], -(c + a * u) / self.cell[1], 1.0);
        (self.normal_to_world * local).normalize()
    }
}

/// z(u, v) = z00 + B u + C v + A u v, returned as (A, B, C).
pub fn patch_coefficients(z: [f64; 4]) -> (f64, f64, f64) {
    let [z00, z10, z01, z11] = z;
    (z11 - z10 - z01 + z00, z10 - z00, z01 - z00)
}

pub fn bilinear(z: [f64; 4], u: f64, v: f64) -> f64 {
    let (a, b, c) = patch_coefficients(z);
    z[0] + b * u + c * v + a * u * v
}

/// The first s ∈ [0, len] where the ray `start` + s·d, `start` = (u0, v0, z0) in the patch's own coordinates
/// (u, v ∈ [0, 1] across the cell), meets the bilinear patch coming from above.
///
/// Along the ray, height above the patch is f(s) = a s² + b s + c with
/// a = −A·dx·dy, b = dz − B·dx − C·dy − A·(u0·dy + v0·dx), c = z0 − z(u0, v0)
/// (the paper's eq. 4 is typeset garbled; this is the derivation). The roots use the
/// stable form q = −(b + sign(b)·√(b² − 4ac))/2, s ∈ {q/a, c/q}: c/q stays accurate as
/// a → 0 (every planar cell, rays along an axis) and no root loses digits to cancellation.
///
/// Below the surface at the cell's entry (c < 0) is a hit at s = 0: the terrain is a solid.
/// At the ray's first cell that is an eye under the ground, or a ray entering the terrain's
/// box through a side (a wall of the box); elsewhere either rounding put the crossing of a
/// shared edge here (a hit at the edge, so no crack opens between cells), or the ray went
/// under the surface through a NoData void and meets the void's wall here.
pub fn intersect_patch(z: [f64; 4], start: DVec3, d: DVec3, len: f64) -> Option<f64> {
    let (u0, v0, z0) = (start.x, start.y, start.z);
    let (pa, pb, pc) = patch_coefficients(z);
    let c = z0 - (z[0] + pb * u0 + pc * v0 + pa * u0 * v0);
    let b = d.z - pb * d.x - pc * d.y - pa * (u0 * d.y + v0 * d.x);
    let a = -pa * d.x * d.y;
    if c < 0.0 {
        return Some(0.0);
    }
    if c == 0.0 && (b < 0.0 || (b == 0.0 && a <= 0.0)) {
        return Some(0.0);
    }
    // Roots a hair past the far edge belong to this cell: the polynomial is smooth there,
    // and rejecting them could let a ray through the shared edge of two cells.
    let limit = len * (1.0 + 1e-12) + 1e-12;
    let s = if a == 0.0 {
        if b >= 0.0 {
            return None;
        }
        -c / b
    } else {
        let disc = b * b - 4.0 * a * c;
        if disc < 0.0 {
            return None;
        }
        let q = -0.5 * (b + disc.sqrt().copysign(b));
        let mut best = f64::INFINITY;
        for r in [q / a, if q != 0.0 { c / q } else { f64::INFINITY }] {
            if r >= 0.0 && r < best {
                best = r;
            }
        }
        best
    };
    (s <= limit).then(|| s.min(len))
}

/// As [`intersect_patch`], for the cell split into the two triangles (00, 10, 11) and
/// (00, 11, 01) — the diagonal from the south-west to the north-east corner — the surface
/// a triangle mesh of the heightfield has. For comparing with mesh renderers (VTK).
pub fn intersect_triangles(z: [f64; 4], start: DVec3, d: DVec3, len: f64) -> Option<f64> {
    let [z00, z10, z01, z11] = z;
    // Height above the triangle's plane along the ray: linear in s.
    let above = |s: f64| {
        let (u, v) = (start.x + d.x * s, start.y + d.y * s);
        let ground = if u >= v { z00 + (z10 - z00) * u + (z11 - z10) * v } else { z00 + (z11 - z01) * u + (z01 - z00) * v };
        start.z + d.z * s - ground
    };
    let slope = |s: f64| {
        let (u, v) = (start.x + d.x * s, start.y + d.y * s);
        let (gu, gv) = if u >= v { (z10 - z00, z11 - z10) } else { (z11 - z01, z01 - z00) };
        d.z - gu * d.x - gv * d.y
    };
    let c = above(0.0);
    if c < 0.0 {
        return Some(0.0);
    }
    if c == 0.0 && slope(0.0) <= 0.0 {
        return Some(0.0);
    }
    // The segment in pieces, cut where it crosses the diagonal u = v.
    let mut cuts = vec![0.0];
    if d.x != d.y {
        let s = (start.y - start.x) / (d.x - d.y);
        if s > 0.0 && s < len {
            cuts.push(s);
        }
    }
    cuts.push(len);
    for w in cuts.windows(2) {
        let (a, b) = (w[0], w[1]);
        let mid = 0.5 * (a + b);
        let k = slope(mid);
        let fa = above(a);
        if fa <= 0.0 {
            return Some(a);
        }
        if k < 0.0 {
            let s = a - fa / k;
            if s <= b * (1.0 + 1e-12) + 1e-12 {
                return Some(s.min(len));
            }
        }
    }
    None
}
