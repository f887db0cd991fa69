//! Cropping a volume: a box and clipping planes per volume node (vtkVolumeMapper's
//! cropping region and clipping planes), both in the node's own coordinates — the
//! millimetres its data file gives, before the node's `transform` — so they move with the
//! node. What is drawn is the intersection of the box and the kept sides of the planes: a
//! convex region, which every volume renderer honours along each ray (the exact interval
//! a ray spends inside it, not whole samples or voxels).

use glam::{DMat4, DVec3};
use serde::{Deserialize, Serialize};

/// The cropping box: the part of the volume between `min` and `max` (millimetres, node
/// coordinates) is drawn.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CropBox {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

/// A clipping plane through `origin` (millimetres, node coordinates); the side its
/// `normal` points to is kept.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ClipPlane {
    pub origin: [f64; 3],
    pub normal: [f64; 3],
}

/// The kept half-space n·p + c ≥ 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HalfSpace {
    pub normal: DVec3,
    pub offset: f64,
}

impl CropBox {
    pub fn validate(&self) -> anyhow::Result<()> {
        for k in 0..3 {
            let (lo, hi) = (self.min[k], self.max[k]);
            if !(lo.is_finite() && hi.is_finite()) {
                anyhow::bail!("crop.min and crop.max must be finite millimetres");
            }
            if lo > hi {
                anyhow::bail!("crop.min[{k}] = {lo} lies above crop.max[{k}] = {hi}");
            }
        }
        Ok(())
    }

    /// The box as six half-spaces (x ≥ min.x, x ≤ max.x, …).
    pub fn half_spaces(&self) -> [HalfSpace; 6] {
        std::array::from_fn(|i| {
            let (k, upper) = (i / 2, i % 2 == 1);
            let mut n = DVec3::ZERO;
            n[k] = if upper { -1.0 } else { 1.0 };
            HalfSpace { normal: n, offset: if upper { self.max[k] } else { -self.min[k] } }
        })
    }
}

impl ClipPlane {
    pub fn validate(&self) -> anyhow::Result<()> {
        let n = DVec3::from(self.normal);
        if !self.origin.iter().all(|v| v.is_finite()) || !n.is_finite() || n.length() == 0.0 {
            anyhow::bail!("clip planes need a finite origin and a finite, non-zero normal");
        }
        Ok(())
    }

    pub fn half_space(&self) -> HalfSpace {
        let n = DVec3::from(self.normal).normalize();
        HalfSpace { normal: n, offset: -n.dot(DVec3::from(self.origin)) }
    }
}

impl HalfSpace {
    /// n·p + c: ≥ 0 inside.
    #[inline]
    pub fn at(&self, p: DVec3) -> f64 {
        self.normal.dot(p) + self.offset
    }

    /// The same half-space in the coordinates that `m` (an affine map) takes to this one's:
    /// {q : n·(m q) + c ≥ 0}.
    pub fn pulled_back(&self, m: DMat4) -> HalfSpace {
        let lin = glam::DMat3::from_mat4(m);
        HalfSpace { normal: lin.transpose() * self.normal, offset: self.normal.dot(m.w_axis.truncate()) + self.offset }
    }
}

/// The region a node keeps, as half-spaces in node coordinates (empty: everything).
pub fn region(crop: Option<&CropBox>, clip: &[ClipPlane]) -> Vec<HalfSpace> {
    crop.map(|c| c.half_spaces().to_vec()).unwrap_or_default().into_iter().chain(clip.iter().map(ClipPlane::half_space)).collect()
}

/// The part [t0, t1] of the interval [t_lo, t_hi] of the ray o + t·d inside every
/// half-space (None where it misses). A ray running along a plane is inside or outside
/// as its origin is.
pub fn clip_interval(o: DVec3, d: DVec3, (t_lo, t_hi): (f64, f64), region: &[HalfSpace]) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (t_lo, t_hi);
    for h in region {
        let (a, b) = (h.at(o), h.normal.dot(d));
        if b == 0.0 {
            if a < 0.0 {
                return None;
            }
        } else if b > 0.0 {
            t0 = t0.max(-a / b);
        } else {
            t1 = t1.min(-a / b);
        }
    }
    (t0 <= t1).then_some((t0, t1))
}
