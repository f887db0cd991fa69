//! Two overlapping volumes fused in shear-warp (issue 19). The second volume is resampled
//! onto the first's grid once (`resample_onto`, kept with the preparations), so both are
//! sampled at the same points of every slab: each segment is classified by each volume's
//! own pre-integrated table and the two fused as the reference fuses samples — extinctions
//! add, α = 1 − (1 − α₁)(1 − α₂), and the colour is the extinction-weighted mean of the two
//! mean colours (`fuse`). Each is shaded by its own gradient (the second's from its
//! resampled copy) and lights, and its own gradient opacity applied, before they are fused.
//!
//! What the resampling costs: one trilinear sample of the second volume per voxel of the
//! first (time), an f32 copy on the first's grid and its u16 axis copies (memory); and in
//! accuracy, the second volume is seen through the first's grid: detail finer than the
//! first's voxels is lost, and its edge is blurred over one of them (outside its box of
//! voxel centres it takes its lowest value, which its transfer function must make
//! transparent).

use super::prepare::Prepared;
use crate::render::geometry;
use crate::scene::{TransferFunction, VolumeShading};
use anyhow::Result;
use glam::{DMat4, DVec3};
use rayon::prelude::*;
use std::path::Path;
use volterra_formats::{Limits, Volume, VoxelData};

/// The second volume of a fused pair, as the renderer takes it: prepared on the first
/// volume's grid (same dims, same index space), with its transfer function.
pub struct Second<'a> {
    pub prepared: &'a Prepared,
    pub tf: &'a TransferFunction,
    /// Its gradient shading (None or `shade = false`: none).
    pub shading: Option<&'a VolumeShading>,
}

/// `secondary`'s real values at the voxel centres of `primary` (trilinear; outside the
/// secondary's box of voxel centres, its lowest value), as an f32 volume on the primary's
/// grid: index space and affine the primary's. `*_to_world`: each node's placement.
pub fn resample_onto(
    primary: &Volume,
    primary_to_world: DMat4,
    secondary: &Volume,
    secondary_to_world: DMat4,
    limits: &Limits,
) -> Result<Volume> {
    limits.check(Path::new("shear-warp"), "the second volume on the first's grid", &[primary.voxel_count() as u64, 4])?;
    let p = geometry::index_to_world(primary_to_world, geometry::affine_matrix(&primary.affine))?;
    let s = geometry::index_to_world(secondary_to_world, geometry::affine_matrix(&secondary.affine))?;
    let to_secondary = s.inverse() * p;
    let [nx, ny, nz] = primary.dims;
    let d = secondary.dims;
    let lowest = secondary.value_range().map_or(0.0, |r| r.0);
    let mut data = vec![0f32; nx * ny * nz];
    data.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slice)| {
        for j in 0..ny {
            for i in 0..nx {
                let q = to_secondary.transform_point3(DVec3::new(i as f64, j as f64, k as f64));
                slice[j * nx + i] = geometry::trilinear_within(d, q, |idx| secondary.value(idx)).unwrap_or(lowest) as f32;
            }
        }
    });
    Ok(Volume {
        modality: secondary.modality.clone(),
        units: secondary.units.clone(),
        ..Volume::new(primary.dims, primary.affine, VoxelData::F32(data))
    })
}

/// Two segments over the same stretch of ray (premultiplied colour, opacity) fused:
/// α = 1 − (1 − α₁)(1 − α₂), colour α·(σ₁ĉ₁ + σ₂ĉ₂)/(σ₁ + σ₂) with σᵢ = −ln(1 − αᵢ) and ĉᵢ
/// the mean colour cᵢ/αᵢ (exact for media constant over the segment; an opaque segment
/// outweighs a translucent one, as in the reference).
#[inline(always)]
pub(super) fn fuse(c1: [f32; 3], a1: f32, c2: [f32; 3], a2: f32) -> ([f32; 3], f32) {
    if a2 <= 0.0 {
        return (c1, a1);
    }
    if a1 <= 0.0 {
        return (c2, a2);
    }
    const MOST: f32 = 1.0 - 1e-6;
    let (s1, s2) = (-(1.0 - a1.min(MOST)).ln(), -(1.0 - a2.min(MOST)).ln());
    let a = 1.0 - (1.0 - a1) * (1.0 - a2);
    let (w1, w2) = (a * s1 / ((s1 + s2) * a1), a * s2 / ((s1 + s2) * a2));
    ([c1[0] * w1 + c2[0] * w2, c1[1] * w1 + c2[1] * w2, c1[2] * w1 + c2[2] * w2], a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fused_segments_match_one_medium_of_both_extinctions() {
        // Two media over one segment: σ = 0.3 (colour red) and 0.9 (blue).
        let (s1, s2) = (0.3f32, 0.9f32);
        let (a1, a2) = (1.0 - (-s1).exp(), 1.0 - (-s2).exp());
        let (c, a) = fuse([a1, 0.0, 0.0], a1, [0.0, 0.0, a2], a2);
        let want_a = 1.0 - (-(s1 + s2)).exp();
        assert!((a - want_a).abs() < 1e-6);
        assert!((c[0] - want_a * 0.25).abs() < 1e-6 && (c[2] - want_a * 0.75).abs() < 1e-6, "{c:?}");
        // Nothing from an empty second; an opaque one dominates a faint first.
        assert_eq!(fuse([0.1, 0.2, 0.3], 0.5, [1.0; 3], 0.0), ([0.1, 0.2, 0.3], 0.5));
        let (c, a) = fuse([0.01, 0.0, 0.0], 0.01, [0.0, 0.0, 1.0], 1.0);
        assert!(a == 1.0 && c[2] > 0.99 && c[0] < 0.01, "{c:?} {a}");
    }

    #[test]
    fn resampling_puts_the_second_volumes_values_at_the_first_ones_voxels() {
        // Secondary: value = x + 10 y + 100 z (linear: trilinear is exact) on a 2 mm grid
        // turned 90° about z and shifted; primary: 1 mm voxels.
        let d2 = [6, 6, 6];
        let values: Vec<f32> = (0..216).map(|i| (i % 6) as f32 + 10.0 * ((i / 6) % 6) as f32 + 100.0 * (i / 36) as f32).collect();
        let affine2 = [[0.0, -2.0, 0.0, 10.0], [2.0, 0.0, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
        let second = Volume::new(d2, affine2, VoxelData::F32(values));
        let first = Volume::new([12, 12, 12], volterra_formats::volume::identity_affine(), VoxelData::U8(vec![0; 1728]));
        let r = resample_onto(&first, DMat4::IDENTITY, &second, DMat4::IDENTITY, &Default::default()).unwrap();
        // World (x, y, z) is secondary index (y/2, (10 − x)/2, z/2).
        for (i, j, k) in [(10, 0, 0), (4, 6, 2), (6, 5, 7), (0, 9, 10)] {
            let (si, sj, sk) = (j as f64 / 2.0, (10.0 - i as f64) / 2.0, k as f64 / 2.0);
            let want = si + 10.0 * sj + 100.0 * sk;
            let got = r.value(i + 12 * (j + 12 * k));
            assert!((got - want).abs() < 1e-4, "({i}, {j}, {k}): {got} vs {want}");
        }
        // Outside the secondary (x = 11 is index −0.5 along its second axis): its lowest value.
        assert_eq!(r.value(11), 0.0);
    }
}
