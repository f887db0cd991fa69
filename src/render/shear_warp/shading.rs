//! Gradient shading and gradient opacity in shear-warp, by the reference ray caster's
//! rule and formula (`render::volume_shading`), combined with pre-integrated
//! classification.
//!
//! Gradients are computed on the fly at the samples, never stored: central differences of
//! the trilinear field one voxel either side along each axis, one-sided at the volume's
//! edge, exactly the reference's rule evaluated at the points where shear-warp samples —
//! the slice samples (`SliceGradient`: the ±z neighbours lie on the neighbouring slices,
//! so each difference is two bilinear samples of the u16 slices) and, with more than one
//! sample per slab, the samples between the slices (`PointGradient`, twelve bilinear
//! samples). Per-voxel normals kept per principal axis, as VolPack does, would add at
//! least 2 bytes a voxel to each permuted copy (200 MiB an axis at 512×512×400: with every
//! axis kept, 1.4 GiB in all, VTK's own peak) and would be quantised where these are not; they are
//! not kept because shading is not where a clinical frame's time goes: with shading off a
//! further frame of the 512×512×400 CT took 748–785 ms against 955–1051 ms shaded (issue
//! 45), so even free normals would gain at most 1.3×. Gradients are computed only where a
//! segment is visible, and each slice sample's gradient is reused as the next slab's front.
//!
//! With pre-integration a segment's premultiplied colour C and opacity α come from the
//! table; the shading factors (ambient + diffuse, specular) are taken as constant over the
//! segment and evaluated at its middle with the mean of the gradients at its two ends
//! (the slab's front or back sample, or a sample between the slices). Then the
//! reference's sum Σ (Cᵢ·d + s)·αᵢ·Tᵢ over the segment is exactly d·C + s·α: the shaded
//! segment is (C·d + s·α, α). The error this adds against the reference (shading at every
//! sample) is the variation of the normal within a segment, and it shrinks with the
//! samples per slab. A gradient interpolated across the whole slab instead (the slice
//! samples' only) left a floor: along an oblique ray the gradient field has kinks at
//! every voxel boundary the ray crosses between the slices. On the aneurism at 512²
//! (`volterra bench shear-warp`, five views) that floor was about 3 %: 3.63 % at the
//! defaults, 3.27 % at ratio 4 with four samples per slab; with the segments' own ends
//! 2.29 % and 1.29 %, at 1.15–1.2 times the time for the same settings.

use super::factor::Factorization;
use super::prepare::Axis;
use super::scanline::{column, rows, SliceRows};
use crate::render::volume_shading::{gradient_to_world, ParallelLighting, Shader};
use crate::scene::{Light, TransferFunction, VolumeShading};
use anyhow::Result;
use glam::{DVec3, Mat3, Vec3};

/// What shading and the gradient opacity need for one frame: the lights for this view
/// direction, with gradients in quanta per permuted voxel going straight to world, and
/// where samples are. In perspective each ray has its own direction toward the eye (and
/// the headlight lies along it, as in the reference ray caster).
pub(super) struct FrameShading<'a> {
    /// None: unshaded (the gradient opacity alone).
    lighting: Option<ParallelLighting>,
    opacity: Option<GradientOpacity>,
    fac: &'a Factorization,
}

/// The transfer function's gradient opacity for shear-warp's segments.
struct GradientOpacity {
    tf: TransferFunction,
    /// Gradient in quanta per permuted voxel → world (value units per mm).
    to_world: Mat3,
    /// The table's segment length in unit distances.
    seg_units: f32,
}

impl<'a> FrameShading<'a> {
    /// None when the node neither shades nor has a gradient opacity. `seg_units`: the
    /// pre-integration table's segment length in unit distances.
    pub(super) fn new(
        shading: Option<&VolumeShading>,
        lights: &[Light],
        fac: &'a Factorization,
        value_range: (f64, f64),
        tf: &TransferFunction,
        seg_units: f32,
    ) -> Result<Option<FrameShading<'a>>> {
        // Permuted voxel coordinates are an index space of their own: the shader made
        // for them takes permuted gradients to world.
        let value_scale = (value_range.1 - value_range.0) / 65535.0;
        let lighting = Shader::new(shading, lights, fac.to_world)?.map(|shader| ParallelLighting::new(&shader, fac.forward, value_scale));
        let opacity = (!tf.gradient_opacity.is_empty()).then(|| GradientOpacity {
            tf: tf.clone(),
            to_world: (gradient_to_world(fac.to_world) * value_scale).as_mat3(),
            seg_units,
        });
        if lighting.is_none() && opacity.is_none() {
            return Ok(None);
        }
        Ok(Some(FrameShading { lighting, opacity, fac }))
    }

    /// Whether it lights (not the gradient opacity alone).
    pub(super) fn is_lit(&self) -> bool {
        self.lighting.is_some()
    }

    /// The shaded premultiplied colour and the opacity of a segment with table entry
    /// (c, a) for `length` times the table's segment, gradient `g` (quanta per permuted
    /// voxel) and middle point `p` (permuted voxel coordinates), seen along `to_eye` where
    /// the caller knows its ray's direction toward the eye (perspective; None: found from
    /// p). The gradient opacity
    /// scales the opacity per unit distance as the reference does — exact for a segment
    /// of constant value: α per unit is recovered from the segment's, scaled, and taken
    /// back to the segment's length; the colour follows the opacity.
    #[inline]
    pub(super) fn shade(&self, c: [f32; 3], a: f32, g: Vec3, p: DVec3, length: f32, to_eye: Option<Vec3>) -> ([f32; 3], f32) {
        let (mut c, mut a) = (c, a);
        if let Some(go) = &self.opacity {
            let factor = go.tf.gradient_factor((go.to_world * g).length() as f64) as f32;
            if factor < 1.0 {
                let units = go.seg_units * length;
                let per_unit = 1.0 - (1.0 - a).max(0.0).powf(1.0 / units);
                let scaled = 1.0 - (1.0 - factor * per_unit).powf(units);
                let k = if a > 0.0 { scaled / a } else { 0.0 };
                (c, a) = (c.map(|v| v * k), scaled);
            }
        }
        let Some(lighting) = &self.lighting else { return (c, a) };
        let (d, s) = if self.fac.is_perspective() {
            let at = if to_eye.is_none() || lighting.needs_position() { self.fac.to_world.transform_point3(p) } else { DVec3::ZERO };
            lighting.lighting_seen_from(g, at, to_eye.unwrap_or_else(|| (self.fac.eye - at).normalize_or_zero().as_vec3()))
        } else {
            let at = if lighting.needs_position() { self.fac.to_world.transform_point3(p) } else { DVec3::ZERO };
            lighting.lighting(g, at)
        };
        ((Vec3::from(c) * d + s * a).to_array(), a)
    }
}

/// Where a gradient reads one row of the field: bilinear samples along a slice row
/// (`SliceRows`), or those of two neighbouring slices mixed (`MixedRows`).
pub(super) trait FieldRow {
    fn sample(&self, x: f64) -> f32;
    /// The sample at a column found by `column`.
    fn sample_column(&self, col: (usize, usize, f32)) -> f32;
}

impl FieldRow for SliceRows<'_> {
    #[inline(always)]
    fn sample(&self, x: f64) -> f32 {
        self.at(x)
    }
    #[inline(always)]
    fn sample_column(&self, col: (usize, usize, f32)) -> f32 {
        self.at_column(col)
    }
}

/// The rows that the gradient at the points of one intermediate row reads — the points'
/// own row (x differences), the rows up to one voxel above and below (y differences), and
/// up to one slice either side (z differences), each shortened at the volume's edge — and
/// the rule itself (`at`), one for both kinds of row.
pub(super) struct RowGradient<R> {
    own: R,
    y_up: R,
    y_down: R,
    /// 1 / (length of the y difference), 0 on a one-voxel axis.
    inv_dy: f32,
    z_up: R,
    z_down: R,
    inv_dz: f32,
    x_max: f64,
}

impl<R: FieldRow> RowGradient<R> {
    /// The gradient at continuous x of this row, in quanta per permuted voxel.
    #[inline]
    pub(super) fn at(&self, x: f64) -> Vec3 {
        let xc = x.clamp(0.0, self.x_max);
        // x's column, found once: every sample shares its weight (found per sample, it cost
        // 3–6 % of the steady frames of a shaded clinical orbit).
        let nx = self.x_max as usize + 1;
        let col @ (x0, x1, wx) = column(xc, nx);
        let gx = if x0 >= 1 && x0 + 2 < nx {
            // At least a voxel from both ends of the row: one column either side.
            (self.own.sample_column((x0 + 1, x1 + 1, wx)) - self.own.sample_column((x0 - 1, x0, wx))) * 0.5
        } else {
            let (up, down) = ((self.x_max - xc).min(1.0), xc.min(1.0));
            if up + down > 0.0 {
                (self.own.sample(xc + up) - self.own.sample(xc - down)) / (up + down) as f32
            } else {
                0.0
            }
        };
        let gy = (self.y_up.sample_column(col) - self.y_down.sample_column(col)) * self.inv_dy;
        let gz = (self.z_up.sample_column(col) - self.z_down.sample_column(col)) * self.inv_dz;
        Vec3::new(gx, gy, gz)
    }
}

/// The gradient at the samples of one slice (their ±z neighbours lie on the neighbouring
/// slices: six bilinear samples a gradient).
pub(super) type SliceGradient<'a> = RowGradient<SliceRows<'a>>;

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
        RowGradient {
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
}

/// The gradient at points between two neighbouring slices, at one fractional slice zf and
/// one row y, for any x: the same rule, each value a mix of two slices' bilinear samples —
/// twelve samples per gradient where a slice sample's takes six. Used at the samples
/// between slices (`slab_samples` > 1), so that each segment's gradient is interpolated
/// between its own ends rather than across the whole slab: along an oblique ray the
/// gradient field has kinks at every voxel boundary, and across the slab that
/// interpolation left a floor of about 3 % relative RMSE on the shaded aneurism however
/// many samples and pixels (3.3 % at ×4 with 4 per slab; 1.3 % with this).
pub(super) type PointGradient<'a> = RowGradient<MixedRows<'a>>;

/// One row of the trilinear field at a fractional slice: two slices' rows and the weight
/// between them.
pub(super) struct MixedRows<'a> {
    a: SliceRows<'a>,
    b: SliceRows<'a>,
    w: f32,
}

impl<'a> MixedRows<'a> {
    fn new(axis: &'a Axis, z: f64, y: f64) -> MixedRows<'a> {
        let [_, ny, nz] = axis.dims;
        let (z0, z1, w) = rows(z, nz);
        let (y0, y1, wy) = rows(y, ny);
        MixedRows { a: SliceRows::new(axis, z0, y0, y1, wy), b: SliceRows::new(axis, z1, y0, y1, wy), w }
    }
}

impl FieldRow for MixedRows<'_> {
    /// At continuous x: both slices' samples from one column lookup.
    #[inline(always)]
    fn sample(&self, x: f64) -> f32 {
        self.sample_column(column(x, self.a.len()))
    }
    #[inline(always)]
    fn sample_column(&self, col: (usize, usize, f32)) -> f32 {
        let a = self.a.at_column(col);
        a + self.w * (self.b.at_column(col) - a)
    }
}

impl<'a> PointGradient<'a> {
    /// For the points of slice position zf (continuous) at row y.
    pub(super) fn between(axis: &'a Axis, zf: f64, y: f64) -> PointGradient<'a> {
        let [nx, ny, nz] = axis.dims;
        let (y_max, z_max) = ((ny - 1) as f64, (nz - 1) as f64);
        let (yc, zc) = (y.clamp(0.0, y_max), zf.clamp(0.0, z_max));
        let (up, down) = ((y_max - yc).min(1.0), yc.min(1.0));
        let (zu, zd) = ((z_max - zc).min(1.0), zc.min(1.0));
        RowGradient {
            own: MixedRows::new(axis, zc, yc),
            y_up: MixedRows::new(axis, zc, yc + up),
            y_down: MixedRows::new(axis, zc, yc - down),
            inv_dy: if up + down > 0.0 { 1.0 / (up + down) as f32 } else { 0.0 },
            z_up: MixedRows::new(axis, zc + zu, yc),
            z_down: MixedRows::new(axis, zc - zd, yc),
            inv_dz: if zu + zd > 0.0 { 1.0 / (zu + zd) as f32 } else { 0.0 },
            x_max: (nx - 1) as f64,
        }
    }
}
