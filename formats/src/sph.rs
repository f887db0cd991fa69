//! SPH utilities for particle data: the cubic-spline (M4) kernel and the documented
//! defaults for particle files that lack mass, smoothing length or density.
//!
//! Defaults (applied by [`fill_defaults`], reported in the set's notes):
//! - **mass**: equal masses summing to 1 kg (`1/N` each) — only ratios matter to a
//!   renderer whose extinction is `c_ext · ρ`;
//! - **h**: half the distance to the 32nd nearest neighbour, so the kernel support `2h`
//!   holds about 32 neighbours (the usual SPH choice);
//! - **density**: the SPH sum `ρ_i = Σ_j m_j W(|r_i − r_j|, h_i)` with the cubic spline.
//!
//! The neighbour searches run on the workspace's one kd-tree ([`crate::kdtree`]).

use crate::kdtree::KdTree;
use crate::particles::ParticleSet;

/// The normalised cubic-spline (M4) kernel in 3-D with support 2h.
#[inline]
pub fn cubic_spline(r: f64, h: f64) -> f64 {
    let q = r / h;
    let sigma = 1.0 / (std::f64::consts::PI * h * h * h);
    if q < 1.0 {
        sigma * (1.0 - 1.5 * q * q + 0.75 * q * q * q)
    } else if q < 2.0 {
        sigma * 0.25 * (2.0 - q).powi(3)
    } else {
        0.0
    }
}

#[cfg(test)]
fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// Distance from each point to its k-th nearest other point (or the farthest, when there
/// are fewer than k others; 0 for a single point).
pub fn kth_neighbour_distance(points: &[[f64; 3]], k: usize) -> Vec<f64> {
    use rayon::prelude::*;
    let n = points.len();
    if n < 2 || k == 0 {
        return vec![0.0; n];
    }
    let k = k.min(n - 1);
    let tree = KdTree::new(points);
    points.par_iter().enumerate().map(|(i, &p)| tree.kth_distance(p, k, i)).collect()
}

/// SPH density at each particle with its own h: ρ_i = Σ_j m_j W(|r_i − r_j|, h_i).
pub fn sph_density(points: &[[f64; 3]], mass: &[f32], h: &[f32]) -> Vec<f32> {
    use rayon::prelude::*;
    let tree = KdTree::new(points);
    points
        .par_iter()
        .enumerate()
        .map(|(i, &p)| {
            let hi = h[i] as f64;
            if hi <= 0.0 {
                return 0.0;
            }
            let mut rho = 0.0;
            tree.for_each_within(p, 2.0 * hi, |j, d2| rho += mass[j] as f64 * cubic_spline(d2.sqrt(), hi));
            rho as f32
        })
        .collect()
}

/// Fills in mass, h and density where the file lacks them, as documented above.
pub fn fill_defaults(set: &mut ParticleSet) {
    let n = set.len();
    if n == 0 {
        return;
    }
    if set.mass.is_none() {
        set.mass = Some(vec![1.0 / n as f32; n]);
        set.notes.push(format!("no mass array: equal masses of 1/{n} kg"));
    }
    if set.smoothing_length.is_none() {
        let d = kth_neighbour_distance(&set.positions, 32);
        set.smoothing_length = Some(d.iter().map(|&x| (0.5 * x) as f32).collect());
        set.notes.push("no smoothing-length array: h = half the distance to the 32nd nearest neighbour".into());
    }
    if set.density.is_none() {
        let rho = sph_density(&set.positions, set.mass.as_ref().unwrap(), set.smoothing_length.as_ref().unwrap());
        set.density = Some(rho);
        set.notes.push("no density array: SPH density with the cubic-spline kernel".into());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uniform numbers in [0, 1): reproducible point sets for the tests.
    fn uniform_stream(seed: u64) -> impl FnMut() -> f64 {
        let mut rng = crate::rng::SplitMix64(seed);
        move || rng.next_f64()
    }

    /// The runs along a segment hold every point within r of it, each once, and fewer
    /// candidates than the segment's bounding box would: axis-aligned, oblique, degenerate
    /// (a = b) and partly outside the grid.
    #[test]
    fn kernel_integrates_to_one() {
        let h = 0.7;
        let dr = 1e-4;
        let integral: f64 = (0..(2.0 * h / dr) as usize)
            .map(|i| {
                let r = (i as f64 + 0.5) * dr;
                4.0 * std::f64::consts::PI * r * r * cubic_spline(r, h) * dr
            })
            .sum();
        assert!((integral - 1.0).abs() < 1e-6, "{integral}");
    }

    fn lattice(n: usize, a: f64) -> Vec<[f64; 3]> {
        let mut p = Vec::new();
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    p.push([x as f64 * a, y as f64 * a, z as f64 * a]);
                }
            }
        }
        p
    }

    #[test]
    fn neighbours_on_a_regular_lattice_are_exact() {
        // On a cubic lattice of spacing a, the 6 nearest neighbours are at a, the next 12 at
        // a√2, the next 8 at a√3, then 6 at 2a: the 32nd is at 2a.
        let a = 0.1;
        let p = lattice(12, a);
        let d = kth_neighbour_distance(&p, 32);
        let centre = 6 + 12 * (6 + 12 * 6);
        assert!((d[centre] - 2.0 * a).abs() < 1e-12, "{}", d[centre]);
        assert!((d[centre] - kth_neighbour_distance(&p, 26)[centre] * 2.0 / 3f64.sqrt()).abs() < 1e-12);
        assert!((kth_neighbour_distance(&p, 6)[centre] - a).abs() < 1e-12);
        assert!((kth_neighbour_distance(&p, 7)[centre] - a * 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn lattice_density_matches_mass_per_volume() {
        let a = 0.1;
        let p = lattice(14, a);
        let m = 2.0e-3f32;
        let rho = sph_density(&p, &vec![m; p.len()], &vec![(1.3 * a) as f32; p.len()]);
        let centre = 7 + 14 * (7 + 14 * 7);
        let want = m as f64 / (a * a * a);
        assert!(((rho[centre] as f64) - want).abs() / want < 0.01, "{} vs {want}", rho[centre]);
    }

    /// Clustered points (a dense core in a sparse halo, duplicates): k-th neighbour
    /// distances and SPH densities through the kd-tree equal a brute-force search.
    #[test]
    fn kd_tree_searches_equal_brute_force_on_clustered_points() {
        let mut next = uniform_stream(5);
        let mut p: Vec<[f64; 3]> = (0..1500)
            .map(|k| {
                let s = if k % 3 == 0 { 100.0 } else { 1.0 };
                [s * (next() - 0.5), s * (next() - 0.5), s * (next() - 0.5)]
            })
            .collect();
        p.extend_from_within(..40);
        let n = p.len();
        for k in [1, 7, 32] {
            let fast = kth_neighbour_distance(&p, k);
            for i in (0..n).step_by(13) {
                let mut d: Vec<f64> = (0..n).filter(|&j| j != i).map(|j| dist2(p[i], p[j]).sqrt()).collect();
                d.sort_by(f64::total_cmp);
                assert_eq!(fast[i], d[k - 1], "point {i}, k {k}");
            }
        }
        let mass = vec![0.5f32; n];
        let h: Vec<f32> = kth_neighbour_distance(&p, 32).iter().map(|&d| (0.5 * d) as f32).collect();
        let rho = sph_density(&p, &mass, &h);
        for i in (0..n).step_by(7) {
            let exact: f64 = (0..n).map(|j| 0.5 * cubic_spline(dist2(p[i], p[j]).sqrt(), h[i] as f64)).sum();
            assert!((rho[i] as f64 - exact).abs() <= 1e-6 * exact, "point {i}: {} vs {exact}", rho[i]);
        }
    }

    #[test]
    fn coincident_and_single_points_do_not_break_the_search() {
        let p = vec![[0.5, 0.5, 0.5]; 40];
        assert!(kth_neighbour_distance(&p, 32).iter().all(|&d| d == 0.0));
        assert_eq!(kth_neighbour_distance(&[[1.0, 2.0, 3.0]], 32), vec![0.0]);
        let two = [[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]];
        assert_eq!(kth_neighbour_distance(&two, 32), vec![5.0, 5.0]);
    }
}
