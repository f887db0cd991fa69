//! What compositing one intermediate row reads of the slices: bilinear samples along two
//! neighbouring slice rows, each slice's runs of pixels per min-max block, the per-row
//! state (early-termination links, the previous slice's samples, the MIP maximum).

use super::factor::SliceMap;
use super::prepare::Axis;
use glam::Vec3;

/// Two neighbouring rows of one permuted slice and the weight between them, looked up once
/// per intermediate row and slice; `at` is then a bilinear sample at continuous x (clamped
/// into the slice), in quanta.
pub(super) struct SliceRows<'a> {
    r0: &'a [u16],
    r1: &'a [u16],
    wy: f32,
}

impl<'a> SliceRows<'a> {
    #[inline]
    pub(super) fn new(axis: &'a Axis, z: usize, y0: usize, y1: usize, wy: f32) -> Self {
        let nx = axis.dims[0];
        let base = z * nx * axis.dims[1];
        SliceRows { r0: &axis.data[base + y0 * nx..base + (y0 + 1) * nx], r1: &axis.data[base + y1 * nx..base + (y1 + 1) * nx], wy }
    }

    /// Samples per row.
    #[inline(always)]
    pub(super) fn len(&self) -> usize {
        self.r0.len()
    }

    #[inline(always)]
    pub(super) fn at(&self, x: f64) -> f32 {
        self.at_column(column(x, self.r0.len()))
    }

    /// The bilinear sample at a column found by `column` (for rows of the same length).
    #[inline(always)]
    pub(super) fn at_column(&self, (x0, x1, wx): (usize, usize, f32)) -> f32 {
        let (r0, r1) = (self.r0, self.r1);
        let a = r0[x0] as f32 + wx * (r0[x1] as f32 - r0[x0] as f32);
        let b = r1[x0] as f32 + wx * (r1[x1] as f32 - r1[x0] as f32);
        a + self.wy * (b - a)
    }
}

/// The columns either side of continuous x (clamped into a row of nx) and the weight
/// between them.
#[inline(always)]
pub(super) fn column(x: f64, nx: usize) -> (usize, usize, f32) {
    let xc = x.clamp(0.0, (nx - 1) as f64);
    let x0 = (xc as usize).min(nx.saturating_sub(2));
    (x0, (x0 + 1).min(nx - 1), (xc - x0 as f64) as f32)
}

/// Rows and weight for continuous y in [ylo, yhi].
#[inline]
pub(super) fn rows(y: f64, ny: usize) -> (usize, usize, f32) {
    let yc = y.clamp(0.0, (ny - 1) as f64);
    let y0 = (yc as usize).min(ny.saturating_sub(2));
    let y1 = (y0 + 1).min(ny - 1);
    (y0, y1, (yc - y0 as f64) as f32)
}

/// Per intermediate row: early-termination links, the previous slice's samples for
/// pre-integration, and the running maximum for MIP.
pub(super) struct RowState {
    /// links[u] == u while pixel u is live; otherwise it points further right.
    pub(super) links: Vec<u32>,
    pub(super) prev: Vec<f32>,
    /// The second volume's previous samples (fused pairs; same stamps).
    pub(super) prev2: Vec<f32>,
    /// The slice index (in compositing order) each pixel's `prev` sample comes from.
    pub(super) stamp: Vec<u32>,
    pub(super) max_level: Vec<f32>,
    pub(super) max_z: Vec<f32>,
    pub(super) grads: Gradients,
}

/// Per intermediate row, for shading: each pixel's gradient at its last slice sample
/// where one was computed, so the next slab reuses it as its front.
pub(super) struct Gradients {
    pub(super) value: Vec<Vec3>,
    /// The slice index (in compositing order) `value` comes from.
    pub(super) stamp: Vec<u32>,
}

impl RowState {
    pub(super) fn new(iw: usize) -> RowState {
        RowState {
            links: (0..=iw as u32).collect(),
            prev: vec![0.0; iw],
            prev2: vec![0.0; iw],
            stamp: vec![u32::MAX; iw],
            max_level: vec![f32::NEG_INFINITY; iw],
            max_z: vec![0.0; iw],
            grads: Gradients { value: vec![Vec3::ZERO; iw], stamp: vec![u32::MAX; iw] },
        }
    }
}

/// One slice's place on the intermediate scanlines, the same for every row: Mapping
/// (x = U·scale + x0) and the runs of pixels whose x falls in each min-max block. Built
/// once per frame, so the compositing loop finds a pixel's block and the block's end with
/// two lookups; computing them per run (a division by n, a ceil, u64↔f64 conversions) was
/// over half the time on the aneurism at ratio 1.
pub(super) struct SliceRuns {
    /// Pixels where x lies inside the slice (clipped to the view), if any.
    pub(super) span: Option<(usize, usize)>,
    /// Block of each pixel of `span`, from its first pixel.
    pub(super) block: Vec<u32>,
    /// block_end[bx]: the first pixel past block bx.
    pub(super) block_end: Vec<usize>,
}

impl SliceRuns {
    pub(super) fn new(map: SliceMap, x_range: (f64, f64), u_clip: (usize, usize), n: usize, nbx: usize) -> SliceRuns {
        let lo = ((x_range.0 - map.x0) * map.inv_scale).ceil().max(u_clip.0 as f64);
        let hi = ((x_range.1 - map.x0) * map.inv_scale).floor().min(u_clip.1 as f64);
        let span = (lo <= hi).then_some((lo as usize, hi as usize));
        let block = match span {
            Some((ua, ub)) => (ua..=ub).map(|u| ((u as f64 * map.scale + map.x0).max(0.0) as usize / n) as u32).collect(),
            None => Vec::new(),
        };
        // Pixels whose x falls in block bx: U < (n·(bx+1) − x0) / scale.
        let block_end = (0..nbx).map(|bx| ((((bx + 1) * n) as f64 - map.x0) * map.inv_scale).ceil().max(0.0) as usize).collect();
        SliceRuns { span, block, block_end }
    }

    /// The block of pixel u (in `span`) and the end of its run, at most `limit`.
    #[inline]
    pub(super) fn run(&self, u: usize, limit: usize) -> (usize, usize) {
        let ua = self.span.map_or(0, |s| s.0);
        let bx = self.block[u - ua] as usize;
        (bx, self.block_end[bx].max(u + 1).min(limit))
    }
}

/// Next live (not yet opaque) pixel at or after u, with path halving.
#[inline]
pub(super) fn next_live(links: &mut [u32], mut u: usize) -> usize {
    while links[u] as usize != u {
        let nxt = links[u] as usize;
        links[u] = links[nxt];
        u = nxt;
    }
    u
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_and_bilinear_samples_clamp_into_the_slice() {
        assert_eq!(rows(1.25, 4), (1, 2, 0.25));
        assert_eq!(rows(-3.0, 4), (0, 1, 0.0));
        assert_eq!(rows(9.0, 4), (2, 3, 1.0));
        assert_eq!(rows(0.0, 1), (0, 0, 0.0));
        let (r0, r1) = ([0u16, 100, 200], [1000u16, 1100, 1200]);
        let s = SliceRows { r0: &r0, r1: &r1, wy: 0.5 };
        assert_eq!(s.at(0.5), 550.0);
        assert_eq!(s.at(2.0), 700.0);
        assert_eq!(s.at(-1.0), 500.0, "clamped to the first column");
        assert_eq!(s.at(7.0), 700.0, "clamped to the last column");
    }

    #[test]
    fn links_skip_opaque_pixels_and_halve_their_paths() {
        let mut state = RowState::new(6);
        assert_eq!(next_live(&mut state.links, 2), 2);
        // Pixels 1, 2, 3 turn opaque, each linking to its right neighbour.
        for u in 1..4 {
            state.links[u] = u as u32 + 1;
        }
        assert_eq!(next_live(&mut state.links, 1), 4);
        // Path halving: 1 now points past 2.
        assert_eq!(state.links[1], 3);
        assert_eq!(next_live(&mut state.links, 1), 4);
        assert_eq!(next_live(&mut state.links, 6), 6, "the sentinel past the row");
    }
}
