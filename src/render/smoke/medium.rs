//! The participating medium the smoke renderer sees: a density field ρ(x) (kg/m³) with
//! σ_t = c_ext·ρ and σ_s = albedo·σ_t, a box outside which it is zero, and a coarse grid of
//! density upper bounds (majorants) for unbiased free-flight sampling and transmittance
//! estimation (delta and ratio tracking) in a heterogeneous medium.
//!
//! Two media: [`SphMedium`], the SPH density of a particle set
//! (ρ(x) = Σ m_i W(|x − x_i|, h_i)), and [`Homogeneous`], a box or sphere of constant
//! density, for the closed-form checks.

use super::point_grid::PointGrid;
pub use crate::catalog::smoke::Kernel;
use crate::geometry::clip_box;
use glam::DVec3;
use volterra_formats::sph::cubic_spline;

/// What a density query reads of a particle once its support holds the point: the
/// kernel's constants precomputed (no division per query) and the particle's index.
#[derive(Clone, Copy)]
struct Coef {
    inv_h: f64,
    /// The kernel's normalisation at this h: 1/(πh³) (cubic spline), 315/(64π(2h)⁹) (poly6).
    norm: f64,
    mass: f32,
    id: u32,
}

impl Kernel {
    /// W(r, h) from r² < (2h)² = `support2` and the particle's constants; equal to `eval`
    /// up to rounding.
    #[inline(always)]
    fn eval_coef(self, r2: f64, support2: f64, q: &Coef) -> f64 {
        match self {
            Kernel::CubicSpline => {
                let x = r2.sqrt() * q.inv_h;
                if x < 1.0 {
                    q.norm * (1.0 - 1.5 * x * x + 0.75 * x * x * x)
                } else {
                    let t = (2.0 - x).max(0.0); // r² < (2h)² may still round x to 2
                    q.norm * 0.25 * t * t * t
                }
            }
            Kernel::Poly6 => {
                let d = (support2 - r2).max(0.0);
                q.norm * d * d * d
            }
        }
    }

    /// The normalisation at h: 1/(πh³) (cubic spline), 315/(64π(2h)⁹) (poly6).
    pub fn norm(self, h: f64) -> f64 {
        match self {
            Kernel::CubicSpline => 1.0 / (std::f64::consts::PI * h * h * h),
            Kernel::Poly6 => 315.0 / (64.0 * std::f64::consts::PI * (2.0 * h).powi(9)),
        }
    }

    #[inline]
    pub fn eval(self, r: f64, h: f64) -> f64 {
        match self {
            Kernel::CubicSpline => cubic_spline(r, h),
            Kernel::Poly6 => {
                let big = 2.0 * h;
                if r >= big {
                    return 0.0;
                }
                let d = big * big - r * r;
                315.0 / (64.0 * std::f64::consts::PI * big.powi(9)) * d * d * d
            }
        }
    }
}

pub trait Medium: Sync {
    /// Density at `p` (0 outside [`Medium::bounds`]).
    fn density(&self, p: DVec3) -> f64;
    /// The box holding every point of non-zero density.
    fn bounds(&self) -> (DVec3, DVec3);
    /// Upper bounds of the density over cells of the box.
    fn majorants(&self) -> &MajorantGrid;
    /// Densities at o + t_k·d (d unit) for rising `t` into `out`: what a ray march needs
    /// for a stretch of ray at once. Equal to [`Medium::density`] at each point up to
    /// rounding.
    fn densities_along(&self, o: DVec3, d: DVec3, t: &[f64], out: &mut [f64]) {
        for (v, &tk) in out.iter_mut().zip(t) {
            *v = self.density(o + tk * d);
        }
    }
    /// [`Medium::densities_along`] for several nearby rays at once (at most
    /// [`MAX_BUNDLE`]: a pixel's rays), so that a medium can gather what lies near all of
    /// them once.
    fn densities_along_rays(&self, rays: &mut [RaySamples<'_>]) {
        for r in rays {
            self.densities_along(r.o, r.d, r.t, r.out);
        }
    }
}

/// One ray's share of [`Medium::densities_along_rays`]: o + t_k·d (d unit, `t` rising),
/// the densities into `out`.
pub struct RaySamples<'a> {
    pub o: DVec3,
    pub d: DVec3,
    pub t: &'a [f64],
    pub out: &'a mut [f64],
}

/// Rays gathered together at most.
pub const MAX_BUNDLE: usize = 8;

/// A regular grid over a box with, per cell, an upper bound of the density inside it, and
/// the same bound per brick of 4×4×4 cells, so that a walk crosses an empty brick (62 % of
/// the 110k plume's cells are empty) or an optically thin one in one step.
pub struct MajorantGrid {
    pub lo: DVec3,
    pub hi: DVec3,
    pub dims: [usize; 3],
    pub max: Vec<f64>,
    brick_dims: [usize; 3],
    brick_max: Vec<f64>,
}

/// Cells per brick edge.
const BRICK: usize = 4;

/// A 3D DDA's state along one ray: the current cell, the direction of the steps, and the
/// ray parameters at which it next crosses a cell boundary on each axis.
struct Dda {
    cell: [usize; 3],
    step: [i64; 3],
    next: [f64; 3],
    delta: [f64; 3],
}

impl Dda {
    /// Starts in the cell of o + t·d among cells of `size` from `lo`, the cell index
    /// clamped to `first..=last` per axis (a point on a boundary may round outside).
    fn new(o: DVec3, d: DVec3, t: f64, lo: DVec3, size: DVec3, first: [usize; 3], last: [usize; 3]) -> Dda {
        let p = o + t * d;
        let mut dda = Dda { cell: [0; 3], step: [0; 3], next: [f64::INFINITY; 3], delta: [f64::INFINITY; 3] };
        for k in 0..3 {
            let c = ((p[k] - lo[k]) / size[k]).floor().clamp(first[k] as f64, last[k] as f64);
            dda.cell[k] = c as usize;
            if d[k] > 0.0 {
                dda.step[k] = 1;
                dda.next[k] = (lo[k] + (c + 1.0) * size[k] - o[k]) / d[k];
                dda.delta[k] = size[k] / d[k];
            } else if d[k] < 0.0 {
                dda.step[k] = -1;
                dda.next[k] = (lo[k] + c * size[k] - o[k]) / d[k];
                dda.delta[k] = -size[k] / d[k];
            }
        }
        dda
    }

    /// The axis of the next boundary crossing.
    #[inline]
    fn axis(&self) -> usize {
        if self.next[0] <= self.next[1] && self.next[0] <= self.next[2] {
            0
        } else if self.next[1] <= self.next[2] {
            1
        } else {
            2
        }
    }

    /// The stretch [t, tb] in the current cell ending no later than `t_end`, and whether
    /// it is the last before `t_end` or before leaving `first..=last`; else steps on.
    #[inline]
    fn advance(&mut self, t: f64, t_end: f64, first: &[usize; 3], last: &[usize; 3]) -> (f64, bool) {
        let k = self.axis();
        let c = self.cell[k] as i64 + self.step[k];
        let leaves = c < first[k] as i64 || c > last[k] as i64;
        if self.next[k] >= t_end || leaves {
            return (t_end, true);
        }
        let tb = self.next[k].max(t);
        self.cell[k] = c as usize;
        self.next[k] += self.delta[k];
        (tb, false)
    }
}

impl MajorantGrid {
    pub fn new(lo: DVec3, hi: DVec3, dims: [usize; 3], max: Vec<f64>) -> MajorantGrid {
        let brick_dims = dims.map(|n| n.div_ceil(BRICK));
        let mut brick_max = vec![0.0f64; brick_dims[0] * brick_dims[1] * brick_dims[2]];
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let b = &mut brick_max[x / BRICK + brick_dims[0] * (y / BRICK + brick_dims[1] * (z / BRICK))];
                    *b = b.max(max[x + dims[0] * (y + dims[1] * z)]);
                }
            }
        }
        MajorantGrid { lo, hi, dims, max, brick_dims, brick_max }
    }

    fn cell_size(&self) -> DVec3 {
        (self.hi - self.lo) / DVec3::new(self.dims[0] as f64, self.dims[1] as f64, self.dims[2] as f64)
    }

    /// The density below which a brick is optically thin for σ_t = c_ext·ρ: a ray crossing
    /// it meets on average at most one tentative collision at the brick's majorant, so
    /// walking it as one cell costs less than stepping through its cells. (Photon tracing
    /// of the 110k plume, one thread, medians of five alternating runs: 2.96 s cell by
    /// cell, 3.01 s skipping empty bricks only, 2.56 / 2.53 / 2.64 s with bricks thinner
    /// than 1/2, 1, 4 tentative collisions walked whole.)
    pub fn thin_below(&self, c_ext: f64) -> f64 {
        let diagonal = (self.cell_size() * BRICK as f64).length();
        if c_ext > 0.0 {
            1.0 / (c_ext * diagonal)
        } else {
            f64::INFINITY
        }
    }

    /// Walks the ray o + t·d (d unit) through the grid for t ∈ [t0, t1], calling
    /// `f(ta, tb, majorant)` per cell in order until it returns false. A brick whose
    /// majorant is at most `coarse` (0: empty bricks only) comes as one stretch with the
    /// brick's majorant. The stretches cover [t0, t1] ∩ box without gaps.
    pub fn walk(&self, o: DVec3, d: DVec3, t0: f64, t1: f64, coarse: f64, mut f: impl FnMut(f64, f64, f64) -> bool) {
        let Some((a, b)) = clip_box(o, d, self.lo, self.hi) else { return };
        let (mut t, t_end) = (a.max(t0), b.min(t1));
        if t >= t_end {
            return;
        }
        let size = self.cell_size();
        let brick_size = size * BRICK as f64;
        let brick_last = self.brick_dims.map(|n| n - 1);
        let cell_last = self.dims.map(|n| n - 1);
        let mut bricks = Dda::new(o, d, t, self.lo, brick_size, [0; 3], brick_last);
        loop {
            let brick = bricks.cell;
            let (tb, done) = bricks.advance(t, t_end, &[0; 3], &brick_last);
            let bmax = self.brick_max[brick[0] + self.brick_dims[0] * (brick[1] + self.brick_dims[1] * brick[2])];
            if bmax <= coarse {
                if !f(t, tb, bmax) {
                    return;
                }
            } else {
                let first = brick.map(|b| b * BRICK);
                let last = [0, 1, 2].map(|k| (first[k] + BRICK - 1).min(cell_last[k]));
                let mut cells = Dda::new(o, d, t, self.lo, size, first, last);
                let mut tc = t;
                loop {
                    let c = cells.cell;
                    let (tcb, end) = cells.advance(tc, tb, &first, &last);
                    if !f(tc, tcb, self.max[c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])]) {
                        return;
                    }
                    if end {
                        break;
                    }
                    tc = tcb;
                }
            }
            if done {
                return;
            }
            t = tb;
        }
    }
}

/// The SPH density of a particle set.
pub struct SphMedium {
    positions: Vec<[f64; 3]>,
    mass: Vec<f64>,
    h: Vec<f64>,
    kernel: Kernel,
    /// Particles binned by smoothing length (each class within a factor of √2), one grid
    /// per class with cells of half that class's largest support: a query then reads
    /// 25 runs of 5 cells per class whatever the spread of h (smoke h varies 8× in one
    /// plume), each run one stretch of memory.
    classes: Vec<HClass>,
    lo: DVec3,
    hi: DVec3,
    majorants: MajorantGrid,
}

impl SphMedium {
    /// `positions`, `mass` (kg) and `h` (m) per particle. Fails on an empty set or on a
    /// smoothing length or mass that is not a positive finite number.
    pub fn new(positions: Vec<[f64; 3]>, mass: Vec<f64>, h: Vec<f64>, kernel: Kernel) -> anyhow::Result<SphMedium> {
        if positions.is_empty() {
            anyhow::bail!("the particle set is empty: there is no smoke to render");
        }
        if let Some(i) = h.iter().position(|v| !(v.is_finite() && *v > 0.0)) {
            anyhow::bail!("particle {i} has smoothing length h = {}; h must be a positive number", h[i]);
        }
        if let Some(i) = mass.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
            anyhow::bail!("particle {i} has mass {}; masses must be non-negative numbers", mass[i]);
        }
        if let Some(i) = positions.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            anyhow::bail!("particle {i} has a position that is not finite: {:?}", positions[i]);
        }
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for (p, &hh) in positions.iter().zip(&h) {
            let p = DVec3::from(*p);
            lo = lo.min(p - 2.0 * hh);
            hi = hi.max(p + 2.0 * hh);
        }
        let mut sorted = h.clone();
        sorted.sort_by(f64::total_cmp);
        // Majorant cells of h/2 (at most 96 per axis): tighter bounds than cells of a
        // support, so fewer tentative collisions in delta tracking (the 110k plume, 640k
        // photons: 2.56M density queries with cells of h, 1.94M with h/2, which the cap
        // makes 96³); cells finer still cost more in walking and building than they save.
        let typical = 0.5 * sorted[sorted.len() / 2];
        let h_min = sorted[0];
        let mut members: Vec<Vec<u32>> = Vec::new();
        for (i, &hh) in h.iter().enumerate() {
            // A query reads its class's cells out to the class's largest support, so
            // narrower classes read fewer particles beyond their own supports: photon
            // tracing of the 110k plume ran ~10 % faster with classes of √2 than of 2
            // (six same-session A/B pairs, median 3.9 s vs 4.3 s).
            let k = ((2.0 * (hh / h_min).log2()).floor().max(0.0) as usize).min(80);
            if members.len() <= k {
                members.resize(k + 1, Vec::new());
            }
            members[k].push(i as u32);
        }
        let classes = members
            .into_iter()
            .filter(|m| !m.is_empty())
            .map(|index| {
                let support = 2.0 * index.iter().map(|&i| h[i as usize]).fold(0.0, f64::max);
                let pts: Vec<[f64; 3]> = index.iter().map(|&i| positions[i as usize]).collect();
                // Cells of half the support: the 5×5×5 cells a query reads hold 42 % fewer
                // candidates than 3×3×3 cells of the whole support (the 110k plume at
                // 250², 640k photons: 9.9 s → 9.2 s).
                let grid = PointGrid::new(&pts, 0.5 * support);
                let origin = DVec3::from(grid.lower_corner());
                let (scan, coef) = grid
                    .order()
                    .iter()
                    .map(|&k| {
                        let i = index[k as usize] as usize;
                        let hh = h[i];
                        let r = (DVec3::from(positions[i]) - origin).as_vec3();
                        let coef = Coef { inv_h: 1.0 / hh, norm: kernel.norm(hh), mass: mass[i] as f32, id: i as u32 };
                        ([r.x, r.y, r.z, (4.0 * hh * hh) as f32], coef)
                    })
                    .unzip();
                HClass { grid, scan, coef, origin, support }
            })
            .collect();
        let majorants = sph_majorants(&positions, &mass, &h, kernel, lo, hi, typical);
        Ok(SphMedium { positions, mass, h, kernel, classes, lo, hi, majorants })
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    pub fn position(&self, i: usize) -> DVec3 {
        DVec3::from(self.positions[i])
    }

    pub fn smoothing_length(&self, i: usize) -> f64 {
        self.h[i]
    }

    pub fn mass(&self, i: usize) -> f64 {
        self.mass[i]
    }

    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// Calls `f(particle, W(|p − x_i|, h_i))` for every particle whose support holds `p`.
    #[inline]
    fn for_each_coef(&self, p: DVec3, mut f: impl FnMut(&Coef, f64)) {
        let pa = p.to_array();
        for class in &self.classes {
            let pf = class.relative(p);
            class.grid.for_each_run(pa, class.support, |a, b| {
                for (k, s) in class.scan[a..b].iter().enumerate() {
                    let r2 = (pf[0] - s[0]).powi(2) + (pf[1] - s[1]).powi(2) + (pf[2] - s[2]).powi(2);
                    if r2 < s[3] {
                        let q = &class.coef[a + k];
                        f(q, self.kernel.eval_coef(r2 as f64, s[3] as f64, q));
                    }
                }
            });
        }
    }

    /// Calls `f(i, W(|p − x_i|, h_i))` for every particle whose support holds `p`.
    pub fn for_each_neighbour(&self, p: DVec3, mut f: impl FnMut(usize, f64)) {
        self.for_each_coef(p, |q, w| f(q.id as usize, w));
    }
}

impl Medium for SphMedium {
    fn density(&self, p: DVec3) -> f64 {
        if p.cmplt(self.lo).any() || p.cmpgt(self.hi).any() {
            return 0.0;
        }
        let mut rho = 0.0;
        self.for_each_coef(p, |q, w| rho += q.mass as f64 * w);
        rho
    }
    fn densities_along(&self, o: DVec3, d: DVec3, t: &[f64], out: &mut [f64]) {
        self.densities_along_rays(&mut [RaySamples { o, d, t, out }]);
    }
    /// The particles near the stretch of rays are gathered once (a slanted band of grid
    /// cells round the rays' mean, widened by how far they spread from it) and each is
    /// added to just the samples its support's chord on each ray covers: per sample this
    /// reads ~4× fewer candidates than a density query per point, and a pixel's rays share
    /// one band's reads instead of four; the sums are those of point queries.
    fn densities_along_rays(&self, rays: &mut [RaySamples<'_>]) {
        assert!(rays.len() <= MAX_BUNDLE, "{} rays gathered at once, at most {MAX_BUNDLE}", rays.len());
        // The rays with samples, their first and last points.
        let mut live = [0usize; MAX_BUNDLE];
        let mut ends = [(DVec3::ZERO, DVec3::ZERO); MAX_BUNDLE];
        let mut n_live = 0;
        for (i, r) in rays.iter_mut().enumerate() {
            r.out.fill(0.0);
            if let (Some(&first), Some(&last)) = (r.t.first(), r.t.last()) {
                live[n_live] = i;
                ends[n_live] = (r.o + first * r.d, r.o + last * r.d);
                n_live += 1;
            }
        }
        if n_live == 0 {
            return;
        }
        // The band: the mean segment, wide enough that every ray's segment lies within
        // `spread` of it (a segment is within the larger of its ends' distances).
        let (mut a, mut b) = (DVec3::ZERO, DVec3::ZERO);
        for &(ea, eb) in &ends[..n_live] {
            a += ea / n_live as f64;
            b += eb / n_live as f64;
        }
        let spread = ends[..n_live].iter().map(|&(ea, eb)| (ea - a).length().max((eb - b).length())).fold(0.0, f64::max);
        // Per ray: the mean spacing of its samples, to guess the first sample at or past a
        // value, corrected by a step or two (a binary search per candidate was a tenth of
        // the time).
        let mut per_unit = [0.0; MAX_BUNDLE];
        for k in 0..n_live {
            let t = rays[live[k]].t;
            let (first, last) = (t[0], t[t.len() - 1]);
            per_unit[k] = if last > first { (t.len() - 1) as f64 / (last - first) } else { 0.0 };
        }
        let first_past = |t: &[f64], per_unit: f64, v: f64| {
            let n = t.len();
            let mut k = (((v - t[0]) * per_unit).max(0.0) as usize).min(n);
            while k > 0 && t[k - 1] > v {
                k -= 1;
            }
            while k < n && t[k] <= v {
                k += 1;
            }
            k
        };
        let mut start = [glam::Vec3::ZERO; MAX_BUNDLE];
        let mut dir = [glam::Vec3::ZERO; MAX_BUNDLE];
        let axis = (b - a).normalize_or(rays[live[0]].d).as_vec3();
        for class in &self.classes {
            for k in 0..n_live {
                start[k] = glam::Vec3::from(class.relative(ends[k].0));
                dir[k] = rays[live[k]].d.as_vec3();
            }
            // A particle whose support reaches a ray lies within its support + `spread` of
            // the mean line: (√s + spread)² ≤ s + 2·spread·support + spread². One test
            // there spares the rays' own tests for most of the band's corners.
            let centre_a = glam::Vec3::from(class.relative(a));
            let widen = (2.0 * spread * class.support + spread * spread) as f32 * 1.0001;
            let bundle = n_live > 1;
            class.grid.for_each_run_along(a.to_array(), b.to_array(), class.support + spread, |ra, rb| {
                for (j, s) in class.scan[ra..rb].iter().enumerate() {
                    let p = glam::Vec3::new(s[0], s[1], s[2]);
                    if bundle && (p - centre_a).cross(axis).length_squared() >= s[3] + widen {
                        continue;
                    }
                    for k in 0..n_live {
                        // The distance from the ray's line by the cross product (no
                        // cancellation), and how far along it the particle lies.
                        let v = p - start[k];
                        let perp2 = v.cross(dir[k]).length_squared();
                        if perp2 >= s[3] {
                            continue;
                        }
                        let q = &class.coef[ra + j];
                        let ray = &mut rays[live[k]];
                        let (support2, perp2) = (s[3] as f64, perp2 as f64);
                        // The chord of the support on the ray: |t − first − along| < half.
                        let half = (support2 - perp2).sqrt();
                        let centre = ray.t[0] + v.dot(dir[k]) as f64;
                        let k0 = first_past(ray.t, per_unit[k], centre - half);
                        for (i, &ti) in ray.t.iter().enumerate().skip(k0) {
                            let dt = ti - centre;
                            if dt >= half {
                                break;
                            }
                            let r2 = perp2 + dt * dt;
                            if r2 < support2 {
                                ray.out[i] += q.mass as f64 * self.kernel.eval_coef(r2, support2, q);
                            }
                        }
                    }
                }
            });
        }
    }
    fn bounds(&self) -> (DVec3, DVec3) {
        (self.lo, self.hi)
    }
    fn majorants(&self) -> &MajorantGrid {
        &self.majorants
    }
}

struct HClass {
    grid: PointGrid,
    /// In the grid's cell order, what a search reads of every candidate: the position
    /// relative to `origin` and the support (2h)², in f32 — 16 bytes: a query reads ~240
    /// candidates to find ~30 particles, and the reads, not the arithmetic, set its speed
    /// (photon tracing of the 110k plume spent 56 % of its time in density queries, a
    /// third of that loading 64-byte f64 records; tracing ran ~14 % faster). f32 offsets
    /// from the class's corner resolve ~1e-7 of the smoke's extent, as finely as the f32
    /// positions particle files store; densities move by ~1e-5 relative.
    scan: Vec<[f32; 4]>,
    /// The same order, what a hit reads.
    coef: Vec<Coef>,
    origin: DVec3,
    support: f64,
}

impl HClass {
    /// `p` relative to the class's origin, in f32.
    #[inline(always)]
    fn relative(&self, p: DVec3) -> [f32; 3] {
        (p - self.origin).as_vec3().to_array()
    }
}

/// Per cell, Σ m·W(d, h) over the particles, d the distance from the particle to the cell
/// (0 inside it): the kernel falls with distance, so no point of the cell can have more
/// density. (The sum of peaks m·W(0, h) would also bound it, but several times looser,
/// and every excess is a wasted tentative collision in delta tracking.)
fn sph_majorants(positions: &[[f64; 3]], mass: &[f64], h: &[f64], kernel: Kernel, lo: DVec3, hi: DVec3, typical: f64) -> MajorantGrid {
    let extent = hi - lo;
    // Cells of about the typical size (the caller's), at most 96 per axis.
    let dims = [0, 1, 2].map(|k| ((extent[k] / typical).ceil() as usize).clamp(1, 96));
    let size = extent / DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
    let mut max = vec![0.0; dims[0] * dims[1] * dims[2]];
    for ((p, &m), &hh) in positions.iter().zip(mass).zip(h) {
        let p = DVec3::from(*p);
        let a = ((p - 2.0 * hh - lo) / size).floor();
        let b = ((p + 2.0 * hh - lo) / size).floor();
        let range = |k: usize| (a[k].max(0.0) as usize).min(dims[k] - 1)..=(b[k].max(0.0) as usize).min(dims[k] - 1);
        for z in range(2) {
            for y in range(1) {
                for x in range(0) {
                    let cell_lo = lo + DVec3::new(x as f64, y as f64, z as f64) * size;
                    let nearest = p.clamp(cell_lo, cell_lo + size);
                    let w = kernel.eval((p - nearest).length(), hh);
                    max[x + dims[0] * (y + dims[1] * z)] += m * w;
                }
            }
        }
    }
    MajorantGrid::new(lo, hi, dims, max)
}

/// Constant density inside a box or a sphere, zero outside: the closed-form cases.
pub struct Homogeneous {
    pub density: f64,
    pub shape: Shape,
    majorants: MajorantGrid,
}

#[derive(Debug, Clone, Copy)]
pub enum Shape {
    Box { lo: DVec3, hi: DVec3 },
    Sphere { centre: DVec3, radius: f64 },
}

impl Homogeneous {
    pub fn new(density: f64, shape: Shape) -> Homogeneous {
        let (lo, hi) = match shape {
            Shape::Box { lo, hi } => (lo, hi),
            Shape::Sphere { centre, radius } => (centre - radius, centre + radius),
        };
        Homogeneous { density, shape, majorants: MajorantGrid::new(lo, hi, [1, 1, 1], vec![density]) }
    }
}

impl Medium for Homogeneous {
    fn density(&self, p: DVec3) -> f64 {
        let inside = match self.shape {
            Shape::Box { lo, hi } => p.cmpge(lo).all() && p.cmple(hi).all(),
            Shape::Sphere { centre, radius } => (p - centre).length_squared() <= radius * radius,
        };
        if inside {
            self.density
        } else {
            0.0
        }
    }
    fn bounds(&self) -> (DVec3, DVec3) {
        (self.majorants.lo, self.majorants.hi)
    }
    fn majorants(&self) -> &MajorantGrid {
        &self.majorants
    }
}
