//! A regular grid of values over the smoke's box, each computed on first use and then
//! interpolated trilinearly: the irradiance map (multiply-scattered source per grid point)
//! and the transmittance grid (light reaching each grid point). Only the grid points a
//! view's rays come near are ever computed — points outside the view cost nothing.

use glam::DVec3;
use std::sync::OnceLock;

pub struct LazyGrid {
    lo: DVec3,
    cell: f64,
    dims: [usize; 3],
    values: Vec<OnceLock<[f32; 3]>>,
    /// Cap on grid points, so that a tiny cell cannot exhaust memory.
    pub computed: std::sync::atomic::AtomicUsize,
}

/// At most this many grid points (≈ 400 MB of cells at 16 bytes each would be too many;
/// 16.7 M is 268 MB).
pub const MAX_POINTS: usize = 1 << 24;

impl LazyGrid {
    /// A grid over [lo, hi] with points `cell` apart (enlarged if it would exceed
    /// [`MAX_POINTS`]).
    pub fn new(lo: DVec3, hi: DVec3, cell: f64) -> LazyGrid {
        let extent = (hi - lo).max(DVec3::splat(1e-12));
        let mut cell = if cell > 0.0 && cell.is_finite() { cell } else { extent.max_element() / 64.0 };
        let dims_for = |c: f64| [0, 1, 2].map(|k| (extent[k] / c).ceil() as usize + 1);
        while dims_for(cell).iter().product::<usize>() > MAX_POINTS {
            cell *= 1.25;
        }
        let dims = dims_for(cell);
        let n = dims.iter().product();
        LazyGrid { lo, cell, dims, values: (0..n).map(|_| OnceLock::new()).collect(), computed: Default::default() }
    }

    pub fn cell(&self) -> f64 {
        self.cell
    }

    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Points computed so far.
    pub fn computed_points(&self) -> usize {
        self.computed.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Bytes held.
    pub fn memory(&self) -> usize {
        self.values.len() * std::mem::size_of::<OnceLock<[f32; 3]>>()
    }

    /// The trilinear interpolation at `x` of `eval` at the 8 surrounding grid points (each
    /// evaluated once, on first need).
    pub fn sample(&self, x: DVec3, eval: &(dyn Fn(DVec3) -> [f64; 3] + Sync)) -> [f64; 3] {
        let g = (x - self.lo) / self.cell;
        let mut base = 0usize;
        let mut f = [0.0f64; 3];
        // Index strides per axis; 0 along an axis of one point (its "second" corner is the
        // first again, with weight 0).
        let mut stride = [0usize; 3];
        let mut scale = 1;
        for k in 0..3 {
            let c = g[k].clamp(0.0, (self.dims[k] - 1) as f64);
            let i = (c as usize).min(self.dims[k].saturating_sub(2));
            base += i * scale;
            if self.dims[k] > 1 {
                f[k] = c - i as f64;
                stride[k] = scale;
            }
            scale *= self.dims[k];
        }
        let mut out = [0.0; 3];
        for corner in 0..8 {
            let mut w = 1.0;
            let mut i = base;
            for k in 0..3 {
                if corner >> k & 1 == 1 {
                    w *= f[k];
                    i += stride[k];
                } else {
                    w *= 1.0 - f[k];
                }
            }
            if w == 0.0 {
                continue;
            }
            let v = self.values[i].get_or_init(|| {
                self.computed.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let (ix, rest) = (i % self.dims[0], i / self.dims[0]);
                let (iy, iz) = (rest % self.dims[1], rest / self.dims[1]);
                let p = self.lo + DVec3::new(ix as f64, iy as f64, iz as f64) * self.cell;
                eval(p).map(|v| v as f32)
            });
            for c in 0..3 {
                out[c] += w * v[c] as f64;
            }
        }
        out
    }
}
