//! Gradient shading in shear-warp, by the reference ray caster's rule and formula
//! (`render::volume_shading`), combined with pre-integrated classification.
//!
//! Gradients are computed on the fly at the slice samples, never stored: central
//! differences of the trilinear field one voxel either side along each axis, one-sided at
//! the volume's edge, exactly the reference's rule evaluated at the points where shear-warp
//! samples (the ±z neighbours of a slice sample lie on the neighbouring slices, so each
//! difference is two bilinear samples of the u16 slices). Per-voxel normals kept per
//! principal axis, as VolPack does, would add at least 2 bytes a voxel to each permuted
//! copy (the clinical-size memory target leaves no room for them), and would be quantised
//! where these are not. They are computed only where a segment is visible, and each slice
//! sample's gradient is reused as the next slab's front.
//!
//! With pre-integration a segment's premultiplied colour C and opacity α come from the
//! table; the shading factors (ambient + diffuse, specular) are taken as constant over the
//! segment and evaluated with the gradient interpolated linearly between the slab's front
//! and back samples to the segment's middle, at that point. Then the reference's sum
//! Σ (Cᵢ·d + s)·αᵢ·Tᵢ over the segment is exactly d·C + s·α: the shaded segment is
//! (C·d + s·α, α). The error this adds against the reference (shading at every sample) is
//! the variation of the normal within a segment — half a voxel at two samples per slab.

use super::factor::Factorization;
use super::prepare::Axis;
use super::scanline::{rows, SliceRows};
use crate::render::volume_shading::{ParallelLighting, Shader};
use crate::scene::{Light, VolumeShading};
use anyhow::Result;
use glam::{DVec3, Vec3};

/// What shading needs for one frame: the lights for this view direction, with gradients
/// in quanta per permuted voxel going straight to world, and where samples are. In
/// perspective each ray has its own direction toward the eye (and the headlight lies along
/// it, as in the reference ray caster).
pub(super) struct FrameShading<'a> {
    lighting: ParallelLighting,
    fac: &'a Factorization,
}

impl<'a> FrameShading<'a> {
    /// None when the node does not shade.
    pub(super) fn new(
        shading: Option<&VolumeShading>,
        lights: &[Light],
        fac: &'a Factorization,
        value_range: (f64, f64),
    ) -> Result<Option<FrameShading<'a>>> {
        // Permuted voxel coordinates are an index space of their own: the shader made
        // for them takes permuted gradients to world.
        let Some(shader) = Shader::new(shading, lights, fac.to_world)? else { return Ok(None) };
        let lighting = ParallelLighting::new(&shader, fac.forward, (value_range.1 - value_range.0) / 65535.0);
        Ok(Some(FrameShading { lighting, fac }))
    }

    /// The shaded premultiplied colour of a segment with table entry (c, a), gradient `g`
    /// (quanta per permuted voxel) and middle point `p` (permuted voxel coordinates).
    #[inline]
    pub(super) fn shade(&self, c: [f32; 3], a: f32, g: Vec3, p: DVec3) -> [f32; 3] {
        let (d, s) = if self.fac.is_perspective() {
            let at = self.fac.to_world.transform_point3(p);
            self.lighting.lighting_seen_from(g, at, (self.fac.eye - at).normalize_or_zero().as_vec3())
        } else {
            let at = if self.lighting.needs_position() { self.fac.to_world.transform_point3(p) } else { DVec3::ZERO };
            self.lighting.lighting(g, at)
        };
        (Vec3::from(c) * d + s * a).to_array()
    }
}

/// The rows of one slice, and of its neighbours, that the gradient at the samples of one
/// intermediate row reads: the sample's own rows (x differences), the rows up to one voxel
/// above and below (y differences), and the neighbouring slices at the sample's rows (z
/// differences), each shortened at the volume's edge.
pub(super) struct SliceGradient<'a> {
    own: SliceRows<'a>,
    y_up: SliceRows<'a>,
    y_down: SliceRows<'a>,
    /// 1 / (length of the y difference), 0 on a one-voxel axis.
    inv_dy: f32,
    z_up: SliceRows<'a>,
    z_down: SliceRows<'a>,
    inv_dz: f32,
    x_max: f64,
}

impl<'a> SliceGradient<'a> {
    /// For the samples of slice z at row y (continuous).
    pub(super) fn new(axis: &'a Axis, z: usize, y: f64) -> SliceGradient<'a> {
        let [nx, ny, nz] = axis.dims;
        let at = |z: usize, y: f64| {
            let (y0, y1, wy) = rows(y, ny);
            SliceRows::new(axis, z, y0, y1, wy)
        };
        let y_max = (ny - 1) as f64;
        let yc = y.clamp(0.0, y_max);
        let (up, down) = ((y_max - yc).min(1.0), yc.min(1.0));
        let (z_up, z_down) = ((z + 1).min(nz - 1), z.saturating_sub(1));
        SliceGradient {
            own: at(z, yc),
            y_up: at(z, yc + up),
            y_down: at(z, yc - down),
            inv_dy: if up + down > 0.0 { 1.0 / (up + down) as f32 } else { 0.0 },
            z_up: at(z_up, yc),
            z_down: at(z_down, yc),
            inv_dz: if z_up > z_down { 1.0 / (z_up - z_down) as f32 } else { 0.0 },
            x_max: (nx - 1) as f64,
        }
    }

    /// The gradient at continuous x of this row, in quanta per permuted voxel.
    #[inline]
    pub(super) fn at(&self, x: f64) -> Vec3 {
        let xc = x.clamp(0.0, self.x_max);
        let (up, down) = ((self.x_max - xc).min(1.0), xc.min(1.0));
        let gx = if up + down > 0.0 { (self.own.at(xc + up) - self.own.at(xc - down)) / (up + down) as f32 } else { 0.0 };
        let gy = (self.y_up.at(xc) - self.y_down.at(xc)) * self.inv_dy;
        let gz = (self.z_up.at(xc) - self.z_down.at(xc)) * self.inv_dz;
        Vec3::new(gx, gy, gz)
    }
}
