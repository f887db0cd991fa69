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
