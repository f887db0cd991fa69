//! Small geometry shared by the renderers (and the viewer's slice views).

use glam::{DMat4, DVec3};
use volterra_formats::volume::Affine;

/// A volume's voxel-index → node affine (row-major, as the readers give it) as a matrix.
pub fn affine_matrix(affine: &Affine) -> DMat4 {
    DMat4::from_cols_array_2d(affine).transpose()
}

/// Voxel index → world: the node's placement after the volume's affine; refused when the
/// product is singular (a zero spacing or scale), which no ray could be traced through.
pub fn index_to_world(node_to_world: DMat4, affine: DMat4) -> anyhow::Result<DMat4> {
    let m = node_to_world * affine;
    if m.determinant().abs() < 1e-300 {
        anyhow::bail!("volume affine is singular");
    }
    Ok(m)
}

/// Trilinear interpolation at the continuous voxel index `p` of a grid of `dims` whose
/// value at linear index i (x fastest) is `at(i)`; `p` is clamped into [0, dims − 1], the
/// box of voxel centres (a single-voxel axis is constant along itself).
#[inline]
pub fn trilinear(dims: [usize; 3], p: DVec3, at: impl Fn(usize) -> f64) -> f64 {
    let [nx, ny, nz] = dims;
    let fx = p.x.clamp(0.0, (nx - 1) as f64);
    let fy = p.y.clamp(0.0, (ny - 1) as f64);
    let fz = p.z.clamp(0.0, (nz - 1) as f64);
    let (x0, y0, z0) = (fx.floor() as usize, fy.floor() as usize, fz.floor() as usize);
    let (x1, y1, z1) = ((x0 + 1).min(nx - 1), (y0 + 1).min(ny - 1), (z0 + 1).min(nz - 1));
    let (tx, ty, tz) = (fx - x0 as f64, fy - y0 as f64, fz - z0 as f64);
    let v = |x: usize, y: usize, z: usize| at(x + nx * (y + ny * z));
    let c00 = v(x0, y0, z0) * (1.0 - tx) + v(x1, y0, z0) * tx;
    let c10 = v(x0, y1, z0) * (1.0 - tx) + v(x1, y1, z0) * tx;
    let c01 = v(x0, y0, z1) * (1.0 - tx) + v(x1, y0, z1) * tx;
    let c11 = v(x0, y1, z1) * (1.0 - tx) + v(x1, y1, z1) * tx;
    let c0 = c00 * (1.0 - ty) + c10 * ty;
    let c1 = c01 * (1.0 - ty) + c11 * ty;
    c0 * (1.0 - tz) + c1 * tz
}

/// As [`trilinear`], but None outside the box of voxel centres (beyond 1e-9 voxel of
/// rounding) instead of the clamped value.
#[inline]
pub fn trilinear_within(dims: [usize; 3], p: DVec3, at: impl Fn(usize) -> f64) -> Option<f64> {
    let inside = (0..3).all(|a| p[a] >= -1e-9 && p[a] <= dims[a] as f64 - 1.0 + 1e-9);
    inside.then(|| trilinear(dims, p, at))
}

/// The interval t ∈ [t0, t1], t0 ≥ 0, where the ray o + t·d is inside the box [lo, hi]
/// (slab test). A zero-length interval (a ray touching an edge) counts as inside.
pub fn clip_box(o: DVec3, d: DVec3, lo: DVec3, hi: DVec3) -> Option<(f64, f64)> {
    let mut t0 = 0.0f64;
    let mut t1 = f64::INFINITY;
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return None;
            }
        } else {
            let a = (lo[k] - o[k]) / d[k];
            let b = (hi[k] - o[k]) / d[k];
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
    }
    (t0 <= t1).then_some((t0, t1))
}
