//! Points bucketed in a uniform grid of cubic cells, with the searches the SPH medium
//! makes: every point within r of a point, and of a segment (a ray's band), as runs of the
//! cell-ordered point list. Only the smoke renderer needs it (it moved here from the
//! formats crate, which holds no search structures for renderers).

/// Points bucketed in a uniform grid of cubic cells.
pub struct PointGrid {
    cell: f64,
    lo: [f64; 3],
    dims: [usize; 3],
    /// `starts[c]..starts[c + 1]` indexes `order` for cell c.
    starts: Vec<u32>,
    order: Vec<u32>,
}

impl PointGrid {
    /// Buckets `points` into cells of the given size (clamped so the grid has at most
    /// about 4 cells per point).
    pub fn new(points: &[[f64; 3]], cell: f64) -> PointGrid {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if points.is_empty() {
            lo = [0.0; 3];
            hi = [0.0; 3];
        }
        let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        let max_cells = (4 * points.len().max(1)) as f64;
        let mut cell = if cell > 0.0 && cell.is_finite() { cell } else { extent.max(1e-12) };
        let count = |c: f64| (0..3).map(|a| ((hi[a] - lo[a]) / c).floor() + 1.0).product::<f64>();
        while count(cell) > max_cells {
            cell *= 1.5;
        }
        let dims = [0, 1, 2].map(|a| ((hi[a] - lo[a]) / cell).floor() as usize + 1);
        let ncell = dims[0] * dims[1] * dims[2];
        let key = |p: &[f64; 3]| {
            let c = [0, 1, 2].map(|a| (((p[a] - lo[a]) / cell) as usize).min(dims[a] - 1));
            c[0] + dims[0] * (c[1] + dims[1] * c[2])
        };
        let mut starts = vec![0u32; ncell + 1];
        for p in points {
            starts[key(p) + 1] += 1;
        }
        for c in 0..ncell {
            starts[c + 1] += starts[c];
        }
        let mut fill = starts.clone();
        let mut order = vec![0u32; points.len()];
        for (i, p) in points.iter().enumerate() {
            let k = key(p);
            order[fill[k] as usize] = i as u32;
            fill[k] += 1;
        }
        PointGrid { cell, lo, dims, starts, order }
    }

    /// Calls `f(index)` for every point in cells overlapping the cube of half-size `r`
    /// around `p` (the caller filters by distance): cell by cell, the plain form the tests
    /// check [`Self::for_each_run`] against (the searches use runs, or the kd-tree).
    #[cfg(test)]
    pub fn for_each_candidate(&self, p: [f64; 3], r: f64, mut f: impl FnMut(usize)) {
        let lo = [0, 1, 2].map(|a| (((p[a] - r - self.lo[a]) / self.cell).floor().max(0.0) as usize).min(self.dims[a] - 1));
        let hi = [0, 1, 2].map(|a| (((p[a] + r - self.lo[a]) / self.cell).floor().max(0.0) as usize).min(self.dims[a] - 1));
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    let c = x + self.dims[0] * (y + self.dims[1] * z);
                    for &i in &self.order[self.starts[c] as usize..self.starts[c + 1] as usize] {
                        f(i as usize);
                    }
                }
            }
        }
    }

    /// Like `for_each_candidate`, but hands over runs of positions in [`Self::order`]:
    /// the cells of one grid row are consecutive there, so each (y, z) row of the search
    /// cube is one run `a..b`.
    pub fn for_each_run(&self, p: [f64; 3], r: f64, mut f: impl FnMut(usize, usize)) {
        let lo = [0, 1, 2].map(|a| (((p[a] - r - self.lo[a]) / self.cell).max(0.0) as usize).min(self.dims[a] - 1));
        let hi = [0, 1, 2].map(|a| (((p[a] + r - self.lo[a]) / self.cell).max(0.0) as usize).min(self.dims[a] - 1));
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                let row = self.dims[0] * (y + self.dims[1] * z);
                let (a, b) = (self.starts[row + lo[0]] as usize, self.starts[row + hi[0] + 1] as usize);
                if a < b {
                    f(a, b);
                }
            }
        }
    }

    /// Like `for_each_run`, for every point that may lie within `r` of the segment a–b:
    /// the runs of the cells the segment swept by a cube of half-size `r` touches, each
    /// cell once. The sweep is clipped axis by axis — z layers, then y rows within a layer,
    /// then the x extent within a row — so an oblique segment reads a slanted band of
    /// cells, not its whole bounding box. A ray marcher gathers the particles of a stretch
    /// of ray once here instead of once per sample.
    pub fn for_each_run_along(&self, a: [f64; 3], b: [f64; 3], r: f64, mut f: impl FnMut(usize, usize)) {
        // Grid coordinates: cell i spans [i, i + 1).
        let ga = [0, 1, 2].map(|k| (a[k] - self.lo[k]) / self.cell);
        let e = [0, 1, 2].map(|k| (b[k] - self.lo[k]) / self.cell - ga[k]);
        let rg = r / self.cell;
        let at = |k: usize, s: f64| ga[k] + s * e[k];
        let extent = |k: usize, s0: f64, s1: f64| {
            let (u, v) = (at(k, s0), at(k, s1));
            cell_span(u.min(v) - rg, u.max(v) + rg, self.dims[k])
        };
        let Some((z0, z1)) = extent(2, 0.0, 1.0) else { return };
        for z in z0..=z1 {
            let Some((sz0, sz1)) = clip_param(ga[2], e[2], z as f64 - rg, (z + 1) as f64 + rg, 0.0, 1.0) else { continue };
            let Some((y0, y1)) = extent(1, sz0, sz1) else { continue };
            for y in y0..=y1 {
                let Some((sy0, sy1)) = clip_param(ga[1], e[1], y as f64 - rg, (y + 1) as f64 + rg, sz0, sz1) else { continue };
                let Some((x0, x1)) = extent(0, sy0, sy1) else { continue };
                let row = self.dims[0] * (y + self.dims[1] * z);
                let (ra, rb) = (self.starts[row + x0] as usize, self.starts[row + x1 + 1] as usize);
                if ra < rb {
                    f(ra, rb);
                }
            }
        }
    }

    /// Point indices in cell order.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// The grid's lowest corner (the points' bounding box's).
    pub fn lower_corner(&self) -> [f64; 3] {
        self.lo
    }
}

/// The parameters s ∈ [s0, s1] at which u + s·e lies in [lo, hi], if any.
#[inline]
fn clip_param(u: f64, e: f64, lo: f64, hi: f64, s0: f64, s1: f64) -> Option<(f64, f64)> {
    let (a, b) = if e == 0.0 {
        if u < lo || u > hi {
            return None;
        }
        (s0, s1)
    } else {
        let (p, q) = ((lo - u) / e, (hi - u) / e);
        (p.min(q).max(s0), p.max(q).min(s1))
    };
    (a <= b).then_some((a, b))
}

/// The cells [i, i + 1) of an axis with `dims` cells that overlap [lo, hi] (grid units).
#[inline]
fn cell_span(lo: f64, hi: f64, dims: usize) -> Option<(usize, usize)> {
    if !(hi >= 0.0 && lo < dims as f64) {
        return None;
    }
    Some(((lo.max(0.0) as usize).min(dims - 1), (hi.max(0.0) as usize).min(dims - 1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
        (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
    }

    fn uniform_stream(seed: u64) -> impl FnMut() -> f64 {
        let mut rng = volterra_formats::rng::SplitMix64(seed);
        move || rng.next_f64()
    }

    #[test]
    fn runs_along_a_segment_hold_every_point_near_it_once() {
        let mut next = uniform_stream(11);
        let pts: Vec<[f64; 3]> = (0..4000).map(|_| [next(), 2.0 * next(), 0.5 * next()]).collect();
        let grid = PointGrid::new(&pts, 0.04);
        let seg_dist2 = |p: [f64; 3], a: [f64; 3], b: [f64; 3]| {
            let e = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let ee = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
            let t =
                if ee > 0.0 { (((p[0] - a[0]) * e[0] + (p[1] - a[1]) * e[1] + (p[2] - a[2]) * e[2]) / ee).clamp(0.0, 1.0) } else { 0.0 };
            dist2(p, [a[0] + t * e[0], a[1] + t * e[1], a[2] + t * e[2]])
        };
        let mut total = (0usize, 0usize);
        for case in 0..300 {
            let a = [1.4 * next() - 0.2, 2.4 * next() - 0.2, 0.7 * next() - 0.1];
            let mut b = [a[0] + 0.3 * next() - 0.15, a[1] + 0.3 * next() - 0.15, a[2] + 0.3 * next() - 0.15];
            match case % 5 {
                0 => b = [a[0], a[1], b[2]], // along z
                1 => b = [b[0], a[1], a[2]], // along x
                2 => b = a,                  // a point
                _ => {}
            }
            let r = 0.08 * next();
            let mut runs = Vec::new();
            grid.for_each_run_along(a, b, r, |x, y| runs.extend(grid.order()[x..y].iter().map(|&i| i as usize)));
            runs.sort_unstable();
            let n = runs.len();
            runs.dedup();
            assert_eq!(runs.len(), n, "a point was handed over twice");
            for (i, q) in pts.iter().enumerate() {
                if seg_dist2(*q, a, b) <= r * r {
                    assert!(runs.binary_search(&i).is_ok(), "case {case}: point {i} within r of the segment is missed");
                }
            }
            let lo = [0, 1, 2].map(|k| a[k].min(b[k]) - r);
            let hi = [0, 1, 2].map(|k| a[k].max(b[k]) + r);
            total.0 += n;
            total.1 += pts.iter().filter(|q| (0..3).all(|k| q[k] >= lo[k] - 0.04 && q[k] <= hi[k] + 0.04)).count();
        }
        assert!(total.0 < total.1, "the band read {} candidates, the bounding boxes hold {}", total.0, total.1);
    }

    /// The runs hold exactly the candidates the cell-by-cell search gives, and every point
    /// within r of the query is among them.
    #[test]
    fn runs_cover_the_same_candidates_as_cells() {
        let mut next = uniform_stream(7);
        let pts: Vec<[f64; 3]> = (0..3000).map(|_| [next(), 2.0 * next(), 0.5 * next()]).collect();
        let grid = PointGrid::new(&pts, 0.05);
        for _ in 0..200 {
            let p = [1.2 * next() - 0.1, 2.2 * next() - 0.1, 0.6 * next() - 0.05];
            let r = 0.1 * next();
            let mut cells = Vec::new();
            grid.for_each_candidate(p, r, |i| cells.push(i));
            let mut runs = Vec::new();
            grid.for_each_run(p, r, |a, b| runs.extend(grid.order()[a..b].iter().map(|&i| i as usize)));
            cells.sort_unstable();
            runs.sort_unstable();
            assert_eq!(cells, runs);
            for (i, q) in pts.iter().enumerate() {
                if dist2(*q, p) <= r * r {
                    assert!(runs.binary_search(&i).is_ok(), "point {i} within r is missed");
                }
            }
        }
    }
}
