//! The one kd-tree of the workspace, over 3-D points: the SPH defaults' neighbour searches
//! ([`crate::sph`]) and the smoke renderer's photon map both use it.
//!
//! Balanced and stored implicitly: the range `lo..hi` of the tree order has its node at the
//! middle, split on the range's widest axis, the lower half before it. The points are kept
//! in tree order (a search reads them in sequence), each with its index in the input.
//! Unlike a uniform grid it adapts to clustered points (a star catalogue crowded near the
//! Sun: a grid sized by the mean spacing put thousands of points in a cell, and the
//! neighbour search for 108k stars took 17 s).

use std::collections::BinaryHeap;

pub struct KdTree {
    /// The points in tree order.
    points: Vec<[f64; 3]>,
    /// Each tree position's index in the input.
    index: Vec<u32>,
    /// Each node's split axis.
    axis: Vec<u8>,
}

/// A squared distance and an input index, ordered by the distance (for the max-heap of
/// the k nearest).
#[derive(PartialEq)]
struct Near(f64, usize);

impl Eq for Near {}
impl PartialOrd for Near {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Near {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&o.0)
    }
}

fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

impl KdTree {
    pub fn new(points: &[[f64; 3]]) -> KdTree {
        let mut order: Vec<u32> = (0..points.len() as u32).collect();
        let mut axis = vec![0u8; points.len()];
        build(points, &mut order, &mut axis, 0, points.len());
        KdTree { points: order.iter().map(|&i| points[i as usize]).collect(), index: order, axis }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Bytes held.
    pub fn memory(&self) -> usize {
        self.points.len() * (24 + 4 + 1)
    }

    /// The (at most) `k` nearest points to `p` closer than √`max_d2`, other than input
    /// point `skip`: (squared distance, input index), in no particular order.
    pub fn k_nearest(&self, p: [f64; 3], k: usize, max_d2: f64, skip: Option<usize>) -> Vec<(f64, usize)> {
        let mut heap: BinaryHeap<Near> = BinaryHeap::with_capacity(k + 1);
        if k == 0 {
            return Vec::new();
        }
        // The search radius shrinks to the k-th distance once k points are held.
        let mut r2 = max_d2;
        let mut stack = vec![(0usize, self.points.len())];
        while let Some((lo, hi)) = stack.pop() {
            if lo >= hi {
                continue;
            }
            let mid = lo + (hi - lo) / 2;
            let q = self.points[mid];
            let i = self.index[mid] as usize;
            let d2 = dist2(q, p);
            if d2 < r2 && Some(i) != skip {
                heap.push(Near(d2, i));
                if heap.len() > k {
                    heap.pop();
                }
                if heap.len() == k {
                    r2 = heap.peek().expect("k > 0 held").0;
                }
            }
            if hi - lo == 1 {
                continue;
            }
            let a = self.axis[mid] as usize;
            let delta = p[a] - q[a];
            let (near, far) = if delta < 0.0 { ((lo, mid), (mid + 1, hi)) } else { ((mid + 1, hi), (lo, mid)) };
            if delta * delta < r2 {
                stack.push(far);
            }
            stack.push(near);
        }
        heap.into_iter().map(|e| (e.0, e.1)).collect()
    }

    /// The distance from `p` to its k-th nearest point other than input point `skip` (the
    /// largest distance found when fewer than k others exist; 0 when none).
    pub fn kth_distance(&self, p: [f64; 3], k: usize, skip: usize) -> f64 {
        self.k_nearest(p, k, f64::INFINITY, Some(skip)).iter().map(|e| e.0).fold(0.0, f64::max).sqrt()
    }

    /// Calls `f(input index, squared distance)` for every point within `r` of `p`, in tree
    /// order (the same order for the same points, so sums over it are reproducible).
    pub fn for_each_within(&self, p: [f64; 3], r: f64, mut f: impl FnMut(usize, f64)) {
        self.within(p, r * r, 0, self.points.len(), &mut f);
    }

    fn within(&self, p: [f64; 3], r2: f64, lo: usize, hi: usize, f: &mut impl FnMut(usize, f64)) {
        if lo >= hi {
            return;
        }
        let mid = (lo + hi) / 2;
        let q = self.points[mid];
        let d2 = dist2(p, q);
        if d2 <= r2 {
            f(self.index[mid] as usize, d2);
        }
        let a = self.axis[mid] as usize;
        let diff = p[a] - q[a];
        if diff <= 0.0 || diff * diff <= r2 {
            self.within(p, r2, lo, mid, f);
        }
        if diff >= 0.0 || diff * diff <= r2 {
            self.within(p, r2, mid + 1, hi, f);
        }
    }
}

/// Orders `order[lo..hi]` as the subtree of that range: its median on the widest axis in
/// the middle, the halves built the same way.
fn build(points: &[[f64; 3]], order: &mut [u32], axis: &mut [u8], lo: usize, hi: usize) {
    if hi - lo <= 1 {
        return;
    }
    let (mut min, mut max) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for &i in &order[lo..hi] {
        let p = points[i as usize];
        for a in 0..3 {
            min[a] = min[a].min(p[a]);
            max[a] = max[a].max(p[a]);
        }
    }
    let split = (0..3).max_by(|&a, &b| (max[a] - min[a]).total_cmp(&(max[b] - min[b]))).unwrap_or(0);
    let mid = (lo + hi) / 2;
    order[lo..hi].select_nth_unstable_by(mid - lo, |&i, &j| points[i as usize][split].total_cmp(&points[j as usize][split]));
    axis[mid] = split as u8;
    build(points, order, axis, lo, mid);
    build(points, order, axis, mid + 1, hi);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    #[test]
    fn k_nearest_and_radius_searches_equal_brute_force() {
        let mut rng = SplitMix64(3);
        let mut p: Vec<[f64; 3]> = (0..2000)
            .map(|k| {
                let s = if k % 4 == 0 { 50.0 } else { 1.0 };
                [s * rng.range(-0.5, 0.5), s * rng.range(-0.5, 0.5), s * rng.range(-0.5, 0.5)]
            })
            .collect();
        // Duplicates and a lattice row: ties the search must not lose.
        p.extend_from_within(..30);
        p.extend((0..20).map(|i| [i as f64 * 0.1, 0.0, 0.0]));
        let tree = KdTree::new(&p);
        assert_eq!(tree.len(), p.len());
        for q in (0..p.len()).step_by(37) {
            let x = p[q];
            let mut all: Vec<(f64, usize)> = (0..p.len()).map(|j| (dist2(x, p[j]), j)).collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0));
            for (k, max_d2) in [(1, f64::INFINITY), (8, f64::INFINITY), (50, 0.01), (5000, 0.04)] {
                let mut got: Vec<f64> = tree.k_nearest(x, k, max_d2, None).iter().map(|e| e.0).collect();
                got.sort_by(f64::total_cmp);
                let want: Vec<f64> = all.iter().map(|e| e.0).filter(|&d| d < max_d2).take(k).collect();
                assert_eq!(got, want, "point {q}, k {k}, r² {max_d2}");
            }
            let mut within = Vec::new();
            tree.for_each_within(x, 0.2, |j, d2| within.push((j, d2)));
            within.sort_by_key(|e| e.0);
            let want: Vec<(usize, f64)> = (0..p.len()).map(|j| (j, dist2(x, p[j]))).filter(|e| e.1 <= 0.04).collect();
            assert_eq!(within, want, "point {q}");
        }
        assert!(tree.k_nearest([0.0; 3], 0, f64::INFINITY, None).is_empty());
        assert!(KdTree::new(&[]).k_nearest([0.0; 3], 3, f64::INFINITY, None).is_empty());
    }
}
