//! Compositing one slab (two neighbouring slices) of one intermediate row: the runs of
//! live pixels, K pre-integrated segments per slab, early ray termination through the
//! row's links. The per-ray core of shear-warp; `render` in mod.rs drives it over runs,
//! slices and rows.

use super::factor::{Factorization, SliceMap};
use super::preint::{PreintTable, Rgba};
use super::prepare::Axis;
use super::scanline::{next_live, rows, Gradients, SliceRows};
use super::shading::{FrameShading, PointGradient, SliceGradient};
use super::MAX_SLAB_SAMPLES;
use crate::scene::HalfSpace;
use glam::{DVec3, Vec3};
use std::cell::OnceCell;

/// The gradients one slab's shading reads: at the back slice's samples and, where the
/// previous slab did not leave them, at the front slice's. Their slice rows are looked up
/// on first use: most slabs of most rows have nothing visible to shade.
pub(super) struct SlabShading<'a> {
    pub(super) frame: &'a FrameShading<'a>,
    pub(super) axis: &'a Axis,
    /// The back slice and its row.
    pub(super) back_at: (usize, f64),
    /// The front slice and its row; None where that row lies outside the volume.
    pub(super) front_at: Option<(usize, f64)>,
    pub(super) back: OnceCell<SliceGradient<'a>>,
    pub(super) front: OnceCell<SliceGradient<'a>>,
}

impl<'a> SlabShading<'a> {
    pub(super) fn new(frame: &'a FrameShading<'a>, axis: &'a Axis, back_at: (usize, f64), front_at: Option<(usize, f64)>) -> Self {
        SlabShading { frame, axis, back_at, front_at, back: OnceCell::new(), front: OnceCell::new() }
    }

    fn back(&self) -> &SliceGradient<'a> {
        self.back.get_or_init(|| SliceGradient::new(self.axis, self.back_at.0, self.back_at.1))
    }

    fn front(&self) -> Option<&SliceGradient<'a>> {
        let (z, y) = self.front_at?;
        Some(self.front.get_or_init(|| SliceGradient::new(self.axis, z, y)))
    }
}

/// The second volume of a fused pair on one slab: its slice rows (on the first volume's
/// grid, so at the same points), its table and quanta-to-levels factor.
pub(super) struct SlabSecond<'a> {
    pub(super) back: SliceRows<'a>,
    pub(super) front: Option<SliceRows<'a>>,
    pub(super) axis: &'a Axis,
    pub(super) table: &'a PreintTable,
    pub(super) q_to_level: f32,
    /// Its own shading (its gradients from its own slices); None: unshaded.
    pub(super) shading: Option<SlabShading<'a>>,
}

impl SlabSecond<'_> {
    /// Its gradient at fraction w of the slab on the ray whose back sample is at xb (front
    /// at xb + dxo): linear between its back and front samples' gradients (for a piece of
    /// a slab where a ray enters or leaves the volume; whole segments take the mean of
    /// their own ends').
    fn gradient(&self, sh: &SlabShading, (xb, dxo): (f64, f64), w: f32) -> Vec3 {
        let gb = sh.back().at(xb);
        let gf = sh.front().map_or(gb, |f| f.at(xb + dxo));
        gf + (gb - gf) * w
    }
}

/// One slab (the front slice zp to the back slice z) of one intermediate row: what
/// compositing its runs needs.
pub(super) struct Slab<'a> {
    pub(super) back: SliceRows<'a>,
    /// None where the rays enter the volume between the slices.
    pub(super) front: Option<SliceRows<'a>>,
    pub(super) axis: &'a Axis,
    /// The back sample's row, and the front sample's relative to it.
    pub(super) y: f64,
    pub(super) dyo: f64,
    /// Inverse Mapping of the back slice: x = U·scale + x0.
    pub(super) back_map: SliceMap,
    /// x of the front slice's sample relative to the back slice's: dxo0 + U·ddxo (ddxo = 0
    /// in a parallel view).
    pub(super) dxo0: f64,
    pub(super) ddxo: f64,
    /// Each pixel's ray length between slices relative to the table's (perspective; empty
    /// in a parallel view, where every ray has the table's).
    pub(super) lengths: &'a [f32],
    /// Each pixel's unit direction toward the eye (lit perspective views; empty
    /// otherwise, where the lighting finds it itself).
    pub(super) to_eyes: &'a [Vec3],
    pub(super) x_range: (f64, f64),
    pub(super) y_range: (f64, f64),
    /// Compositing-order index of the back slice.
    pub(super) zi: u32,
    pub(super) z: usize,
    pub(super) zp: usize,
    /// The intermediate row.
    pub(super) vf: f64,
    pub(super) table: &'a PreintTable,
    pub(super) q_to_level: f32,
    pub(super) termination: f32,
    pub(super) fac: &'a Factorization,
    /// None: unshaded.
    pub(super) shading: Option<SlabShading<'a>>,
    /// The crop region as half-spaces in permuted voxel coordinates (empty: none).
    pub(super) crop: &'a [HalfSpace],
    /// The second volume of a fused pair (`fusion`), sampled at the same points.
    pub(super) second: Option<SlabSecond<'a>>,
    /// What the samples between the slices read (`slab_samples` > 1), looked up on first
    /// use and kept for every run of the slab (looked up per run, they cost 6 % of the
    /// CPU time of a shaded CT orbit).
    pub(super) between: SlabBetween<'a>,
}

/// The slice rows and gradient rows of the K − 1 points between a slab's slices, for the
/// first volume and a fused pair's second; each set looked up on first use, for the K of
/// the first `composite_run` (a frame has one K, so every run of a slab shares it).
#[derive(Default)]
pub(super) struct SlabBetween<'a> {
    rows: OnceCell<BetweenRows<'a>>,
    rows2: OnceCell<BetweenRows<'a>>,
    grads: [OnceCell<PointGradient<'a>>; MAX_SLAB_SAMPLES - 1],
    grads2: [OnceCell<PointGradient<'a>>; MAX_SLAB_SAMPLES - 1],
}

/// Slices zp and z at the rows of the points between them.
type BetweenRows<'a> = [(SliceRows<'a>, SliceRows<'a>); MAX_SLAB_SAMPLES - 1];

/// The part of [w0, w1] of the segment from `front` (w = 0) to `back` (w = 1), permuted
/// voxel coordinates, inside every half-space of `crop` (None: none of it).
pub(super) fn crop_interval(crop: &[HalfSpace], front: DVec3, back: DVec3, (mut w0, mut w1): (f64, f64)) -> Option<(f64, f64)> {
    for h in crop {
        // Linear along the segment: h(front) at w = 0, h(back) at w = 1.
        let (vf, vb) = (h.at(front), h.at(back));
        if vf == vb {
            if vf < 0.0 {
                return None;
            }
        } else if vb > vf {
            w0 = w0.max(vf / (vf - vb));
        } else {
            w1 = w1.min(vf / (vf - vb));
        }
    }
    (w0 <= w1).then_some((w0, w1))
}

/// The trilinear value (quantised units) at (x, y) on the ray between slice zp (w = 0)
/// and slice z (w = 1), at fraction w.
pub(super) fn between_slices(axis: &Axis, (zp, z): (usize, usize), x: f64, y: f64, w: f64) -> f32 {
    let (r0, r1, rw) = rows(y, axis.dims[1]);
    let (a, b) = (SliceRows::new(axis, zp, r0, r1, rw).at(x), SliceRows::new(axis, z, r0, r1, rw).at(x));
    a + w as f32 * (b - a)
}

/// The interval of u where a + b·u ≥ 0 (empty: lo > hi).
fn half_line(a: f64, b: f64) -> (f64, f64) {
    if b > 0.0 {
        (-a / b, f64::INFINITY)
    } else if b < 0.0 {
        (f64::NEG_INFINITY, -a / b)
    } else if a >= 0.0 {
        (f64::NEG_INFINITY, f64::INFINITY)
    } else {
        (f64::INFINITY, f64::NEG_INFINITY)
    }
}

/// A table entry (premultiplied colour, opacity) for a segment `length` times the table's:
/// opacity 1 − (1 − α)^length, colour scaled with it (exact for a constant value).
#[inline(always)]
pub(super) fn for_length(e: Rgba, length: f32) -> ([f32; 3], f32) {
    if length == 1.0 || e.a <= 0.0 {
        return (e.c, e.a);
    }
    let a = if e.a >= 1.0 { 1.0 } else { 1.0 - (1.0 - e.a).powf(length) };
    let scale = a / e.a;
    (e.c.map(|c| c * scale), a)
}

impl<'a> Slab<'a> {
    /// x of pixel u's back sample.
    #[inline(always)]
    pub(super) fn xb(&self, u: usize) -> f64 {
        u as f64 * self.back_map.scale + self.back_map.x0
    }

    /// x of pixel u's front sample relative to its back sample.
    #[inline(always)]
    pub(super) fn dxo(&self, u: usize) -> f64 {
        self.dxo0 + u as f64 * self.ddxo
    }

    /// Pixel u's ray length between slices relative to the table's.
    #[inline(always)]
    fn length(&self, u: usize) -> f32 {
        if self.lengths.is_empty() {
            1.0
        } else {
            self.lengths[u]
        }
    }

    /// Composites the live pixels of u..run_end through K segments per slab and returns
    /// the next live pixel at or after run_end. Generic over K so that the paper's one
    /// segment per slab compiles without the loop over samples between the slices (a
    /// runtime count cost it a fifth of its speed), and over FUSED (a second volume,
    /// `second`, classified at the same points and fused segment by segment) so that one
    /// volume pays nothing for it.
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    pub(super) fn composite_run<const K: usize, const FUSED: bool>(
        &self,
        links: &mut [u32],
        prev: &mut [f32],
        prev2: &mut [f32],
        stamp: &mut [u32],
        grads: &mut Gradients,
        row: &mut [[f32; 4]],
        depth: &mut [f32],
        u: usize,
        run_end: usize,
        n_samples: &mut u64,
    ) -> usize {
        let (table, q) = (self.table, self.q_to_level);
        let sec = if FUSED { self.second.as_ref() } else { None };
        // Slices zp and z at the rows of the K − 1 samples between them: point j lies at
        // fraction j/K from the front slice to the back one, where the trilinear value is
        // the mix of both slices at that point's (x, y).
        let between_of = |axis: &'a Axis| -> BetweenRows<'a> {
            std::array::from_fn(|i| {
                let j = (i + 1).min(K.max(2) - 1);
                let yj = self.y + self.dyo * (1.0 - j as f64 / K as f64);
                let (r0, r1, rw) = rows(yj, axis.dims[1]);
                (SliceRows::new(axis, self.zp, r0, r1, rw), SliceRows::new(axis, self.z, r0, r1, rw))
            })
        };
        let between = (K > 1).then(|| self.between.rows.get_or_init(|| between_of(self.axis)));
        let between2 = sec.filter(|_| K > 1).map(|s| self.between.rows2.get_or_init(|| between_of(s.axis)));
        // The gradient at those points (shading).
        let between_point = |axis: &'a Axis, j: usize| {
            let t = 1.0 - j as f64 / K as f64;
            PointGradient::between(axis, self.z as f64 + (self.zp as f64 - self.z as f64) * t, self.y + self.dyo * t)
        };
        let between_grad = |j: usize| self.between.grads[j - 1].get_or_init(|| between_point(self.axis, j));
        let between_grad2 = |s: &SlabSecond<'a>, j: usize| self.between.grads2[j - 1].get_or_init(|| between_point(s.axis, j));
        let mut uu = u;
        while uu < run_end {
            let (xb, dxo) = (self.xb(uu), self.dxo(uu));
            let length = self.length(uu);
            let back = self.back.at(xb) * q;
            let back2 = sec.map_or(0.0, |s| s.back.at(xb) * s.q_to_level);
            *n_samples += 1;
            let (front, front2) = if stamp[uu] == self.zi - 1 {
                (Some(prev[uu]), if FUSED { prev2[uu] } else { 0.0 })
            } else {
                let xf = xb + dxo;
                match &self.front {
                    Some(front) if xf >= self.x_range.0 && xf <= self.x_range.1 => {
                        *n_samples += 1;
                        let f2 = sec.and_then(|s| s.front.as_ref().map(|f| f.at(xf) * s.q_to_level)).unwrap_or(0.0);
                        (Some(front.at(xf) * q), f2)
                    }
                    _ => (None, 0.0), // the ray entered the volume between these slices
                }
            };
            prev[uu] = back;
            if FUSED {
                prev2[uu] = back2;
            }
            stamp[uu] = self.zi;
            let mut g_back = None;
            if let Some(front) = front {
                // K segments, front to back, through the trilinear values between the
                // slices; stop once the pixel is opaque. The gradients at the slab's ends
                // are computed at the first visible segment (shading only).
                let mut g_front = None;
                let mut g_between: [Option<Vec3>; MAX_SLAB_SAMPLES - 1] = [None; MAX_SLAB_SAMPLES - 1];
                // The second volume's gradients at the K + 1 points (fused pairs, shaded).
                let mut g2: [Option<Vec3>; MAX_SLAB_SAMPLES + 1] = [None; MAX_SLAB_SAMPLES + 1];
                let (mut f, mut f2) = (front, front2);
                for j in 0..K {
                    let (b, b2) = if j + 1 == K {
                        (back, back2)
                    } else {
                        let (fs, bs) = &between.unwrap()[j];
                        let w = (j + 1) as f32 / K as f32;
                        let xj = xb + dxo * (1.0 - w as f64);
                        let (sf, sb) = (fs.at(xj), bs.at(xj));
                        *n_samples += 2;
                        let b2 = match (sec, &between2) {
                            (Some(s), Some(bt)) => {
                                let (fs, bs) = &bt[j];
                                let (sf, sb) = (fs.at(xj), bs.at(xj));
                                (sf + w * (sb - sf)) * s.q_to_level
                            }
                            _ => 0.0,
                        };
                        ((sf + w * (sb - sf)) * q, b2)
                    };
                    let second_clear = sec.is_none_or(|s| f2.max(b2) < s.table.clear_below);
                    if f.max(b) >= table.clear_below || !second_clear {
                        let (c, a) = if f.max(b) >= table.clear_below { for_length(table.lookup(f, b), length) } else { ([0.0; 3], 0.0) };
                        let (c2, a2) = match sec {
                            Some(s) if !second_clear => {
                                let (c2, a2) = for_length(s.table.lookup(f2, b2), length);
                                match &s.shading {
                                    Some(sh) if a2 > 0.0 => {
                                        // As the first volume's: the mean of the segment's
                                        // ends' gradients.
                                        let mut end = |i: usize| {
                                            *g2[i].get_or_insert_with(|| match i {
                                                0 => sh.front().map_or_else(|| sh.back().at(xb), |f| f.at(xb + dxo)),
                                                _ if i == K => sh.back().at(xb),
                                                _ => between_grad2(s, i).at(xb + dxo * (1.0 - i as f64 / K as f64)),
                                            })
                                        };
                                        let g = (end(j) + end(j + 1)) * 0.5;
                                        let w = (j as f32 + 0.5) / K as f32;
                                        self.shade(sh, c2, a2, g, (uu, (xb, dxo)), w as f64, length)
                                    }
                                    _ => (c2, a2),
                                }
                            }
                            _ => ([0.0; 3], 0.0),
                        };
                        if a > 0.0 || a2 > 0.0 {
                            let (c, a) = match &self.shading {
                                _ if a <= 0.0 => (c, a),
                                None => (c, a),
                                Some(sh) => {
                                    let gb = *g_back.get_or_insert_with(|| sh.back().at(xb));
                                    let gf = *g_front.get_or_insert_with(|| match sh.front() {
                                        _ if grads.stamp[uu] == self.zi - 1 => grads.value[uu],
                                        Some(front) => front.at(xb + dxo),
                                        None => gb,
                                    });
                                    // The segment's gradient: the mean of its ends' (the
                                    // slab's ends, or the samples between the slices).
                                    let mut end = |i: usize| match i {
                                        0 => gf,
                                        _ if i == K => gb,
                                        _ => *g_between[i - 1]
                                            .get_or_insert_with(|| between_grad(i).at(xb + dxo * (1.0 - i as f64 / K as f64))),
                                    };
                                    let g = (end(j) + end(j + 1)) * 0.5;
                                    let w = (j as f32 + 0.5) / K as f32;
                                    self.shade(sh, c, a, g, (uu, (xb, dxo)), w as f64, length)
                                }
                            };
                            let (c, a) = if FUSED { super::fusion::fuse(c, a, c2, a2) } else { (c, a) };
                            let seg = (j as f64 / K as f64, (j + 1) as f64 / K as f64);
                            if self.accumulate(&mut row[uu], &mut depth[uu], uu, c, a, seg) {
                                links[uu] = uu as u32 + 1; // early ray termination
                                break;
                            }
                        }
                    }
                    f = b;
                    f2 = b2;
                }
            } else if let Some((w0, _)) = self.inside((xb, dxo)) {
                // The ray entered the volume between these slices, through a side face:
                // the piece from there to the back sample.
                let g = self.shading.as_ref().map(|sh| *g_back.get_or_insert_with(|| sh.back().at(xb)));
                let f0 = (self.value_at((xb, dxo), w0), self.value_at2((xb, dxo), w0));
                *n_samples += 2;
                if self.composite_piece(K, row, depth, uu, (xb, dxo), (w0, f0), (1.0, (back, back2)), g) {
                    links[uu] = uu as u32 + 1;
                }
            }
            if let Some(g) = g_back {
                grads.value[uu] = g;
                grads.stamp[uu] = self.zi;
            }
            uu = next_live(links, uu + 1);
        }
        uu
    }

    /// Composites the pixels of `span` (pixels on this row whose ray meets the slab)
    /// that `composite_run` does not: those whose back sample lies outside the volume,
    /// where the ray leaves it (or only grazes it) between these slices through a side
    /// face, and with a crop region those whose segment it cuts. `back_span`: the pixels
    /// whose back sample is inside, if the back row is; `run_span`: those among them
    /// `composite_run` composited (all of them without a crop region).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn composite_exits(
        &self,
        k: usize,
        links: &mut [u32],
        prev: &[f32],
        prev2: &[f32],
        stamp: &[u32],
        grads: &Gradients,
        row: &mut [[f32; 4]],
        depth: &mut [f32],
        span: (usize, usize),
        back_span: Option<(usize, usize)>,
        run_span: Option<(usize, usize)>,
        n_samples: &mut u64,
    ) {
        let mut uu = next_live(links, span.0);
        while uu <= span.1 {
            if run_span.is_some_and(|(a, b)| (a..=b).contains(&uu)) {
                uu = next_live(links, run_span.unwrap().1 + 1);
                continue;
            }
            let ray = (self.xb(uu), self.dxo(uu));
            let xb = ray.0;
            let back_inside = back_span.is_some_and(|(a, b)| (a..=b).contains(&uu));
            if let Some((w0, w1)) = self.inside(ray).filter(|&(_, w1)| w1 < 1.0 || back_inside) {
                let xf = xb + ray.1;
                let front_inside = w0 == 0.0 && self.front.is_some();
                let f0 = match &self.front {
                    _ if front_inside && stamp[uu] == self.zi - 1 => prev[uu],
                    Some(front) if front_inside => front.at(xf) * self.q_to_level,
                    _ => self.value_at(ray, w0),
                };
                let f0b = match self.second.as_ref().and_then(|s| s.front.as_ref().map(|f| (s, f))) {
                    _ if self.second.is_none() => 0.0,
                    _ if front_inside && stamp[uu] == self.zi - 1 => prev2[uu],
                    Some((s, front)) if front_inside => front.at(xf) * s.q_to_level,
                    _ => self.value_at2(ray, w0),
                };
                let (f0, f1) = ((f0, f0b), (self.value_at(ray, w1), self.value_at2(ray, w1)));
                *n_samples += 3;
                let g = self.shading.as_ref().map(|sh| match sh.front() {
                    _ if grads.stamp[uu] == self.zi - 1 => grads.value[uu],
                    Some(front) => front.at(xf),
                    None => sh.back().at(xb),
                });
                if self.composite_piece(k, row, depth, uu, ray, (w0, f0), (w1, f1), g) {
                    links[uu] = uu as u32 + 1;
                }
            }
            uu = next_live(links, uu + 1);
        }
    }

    /// The crop region on this slab's row, for pixels u: where both the front and the
    /// back sample lie inside it (the whole segment then does: the region is convex), and
    /// a range outside which no part of a segment does (conservative). Real-valued ends.
    pub(super) fn crop_ranges(&self) -> ((f64, f64), (f64, f64)) {
        let (mut whole, mut any) = ((f64::NEG_INFINITY, f64::INFINITY), (f64::NEG_INFINITY, f64::INFINITY));
        let (s, x0) = (self.back_map.scale, self.back_map.x0);
        for h in self.crop {
            let n = h.normal;
            let back = half_line(n.x * x0 + n.y * self.y + n.z * self.z as f64 + h.offset, n.x * s);
            let front =
                half_line(n.x * (x0 + self.dxo0) + n.y * (self.y + self.dyo) + n.z * self.zp as f64 + h.offset, n.x * (s + self.ddxo));
            whole = (whole.0.max(back.0).max(front.0), whole.1.min(back.1).min(front.1));
            // Either end inside: the union of two half-lines, narrowed only where it is one.
            let empty = |r: (f64, f64)| r.0 > r.1;
            let either = match (empty(back), empty(front)) {
                (true, true) => (f64::INFINITY, f64::NEG_INFINITY),
                (true, false) => front,
                (false, true) => back,
                _ if back.0 <= front.1 && front.0 <= back.1 => (back.0.min(front.0), back.1.max(front.1)),
                _ => (f64::NEG_INFINITY, f64::INFINITY),
            };
            any = (any.0.max(either.0), any.1.min(either.1));
        }
        (whole, any)
    }

    /// The part of a pixel's ray (back sample at x = xb, front at xb + dxo) inside the
    /// volume's box and its crop region within this slab, as fractions [w0, w1] from the
    /// front sample (0) to the back one (1).
    fn inside(&self, (xb, dxo): (f64, f64)) -> Option<(f64, f64)> {
        let (mut w0, mut w1) = (0.0f64, 1.0f64);
        // At fraction w the ray is at x = xb + dxo·(1 − w), y = y + dyo·(1 − w).
        for (back, d, (lo, hi)) in [(xb, dxo, self.x_range), (self.y, self.dyo, self.y_range)] {
            let at_front = back + d;
            if d == 0.0 {
                if at_front < lo || at_front > hi {
                    return None;
                }
                continue;
            }
            let (t0, t1) = ((at_front - lo) / d, (at_front - hi) / d);
            w0 = w0.max(t0.min(t1));
            w1 = w1.min(t0.max(t1));
        }
        if !self.crop.is_empty() {
            let back = DVec3::new(xb, self.y, self.z as f64);
            (w0, w1) = crop_interval(self.crop, DVec3::new(xb + dxo, self.y + self.dyo, self.zp as f64), back, (w0, w1))?;
        }
        (w0 < w1).then_some((w0, w1))
    }

    /// The trilinear value (in table levels) on a pixel's ray (back sample at xb, front at
    /// xb + dxo) at fraction w of the slab.
    fn value_at(&self, (xb, dxo): (f64, f64), w: f64) -> f32 {
        let t = 1.0 - w;
        between_slices(self.axis, (self.zp, self.z), xb + dxo * t, self.y + self.dyo * t, w) * self.q_to_level
    }

    /// The second volume's value (in its table's levels) at the same point; 0 without one.
    fn value_at2(&self, (xb, dxo): (f64, f64), w: f64) -> f32 {
        let Some(s) = &self.second else { return 0.0 };
        let t = 1.0 - w;
        between_slices(s.axis, (self.zp, self.z), xb + dxo * t, self.y + self.dyo * t, w) * s.q_to_level
    }

    /// Composites the piece [w0, w1] of the slab (values f0, f1 at its ends) for pixel
    /// uu: the parts of the k segments it overlaps, each pre-integrated over its own
    /// length (the table's opacity scaled to the shorter length, exact for a constant
    /// value), shaded with gradient `g` throughout. True once the pixel is opaque.
    /// `ray`: the back sample's x and the front's relative to it.
    #[allow(clippy::too_many_arguments)]
    fn composite_piece(
        &self,
        k: usize,
        row: &mut [[f32; 4]],
        depth: &mut [f32],
        uu: usize,
        ray: (f64, f64),
        (w0, f0): (f64, (f32, f32)),
        (w1, f1): (f64, (f32, f32)),
        g: Option<Vec3>,
    ) -> bool {
        let mut f = f0;
        for j in 0..k {
            let (sa, sb) = ((j as f64 / k as f64).max(w0), ((j + 1) as f64 / k as f64).min(w1));
            if sb <= sa {
                continue;
            }
            let b = if sb >= w1 { f1 } else { (self.value_at(ray, sb), self.value_at2(ray, sb)) };
            let first = f.0.max(b.0) >= self.table.clear_below;
            let second = self.second.as_ref().filter(|s| f.1.max(b.1) >= s.table.clear_below);
            if first || second.is_some() {
                // The table is for a whole segment, 1/k of the slab: this one is r of it.
                let r = ((sb - sa) * k as f64) as f32;
                let length = r * self.length(uu);
                let (c, a) = if first { for_length(self.table.lookup(f.0, b.0), length) } else { ([0.0; 3], 0.0) };
                let (c, a) = match (&self.shading, g) {
                    (Some(sh), Some(g)) if a > 0.0 => self.shade(sh, c, a, g, (uu, ray), 0.5 * (sa + sb), length),
                    _ => (c, a),
                };
                let (c, a) = match second {
                    Some(s) => {
                        let (c2, a2) = for_length(s.table.lookup(f.1, b.1), length);
                        let w = 0.5 * (sa + sb);
                        let (c2, a2) = match &s.shading {
                            Some(sh) if a2 > 0.0 => self.shade(sh, c2, a2, s.gradient(sh, ray, w as f32), (uu, ray), w, length),
                            _ => (c2, a2),
                        };
                        super::fusion::fuse(c, a, c2, a2)
                    }
                    None => (c, a),
                };
                if a > 0.0 && self.accumulate(&mut row[uu], &mut depth[uu], uu, c, a, (sa, sb)) {
                    return true;
                }
            }
            f = b;
        }
        false
    }

    /// The shaded colour and the opacity (gradient opacity applied) of a segment
    /// (premultiplied colour c, opacity a, gradient g, `length` times the table's) whose
    /// middle lies at fraction w of the slab on pixel uu's ray, whose back sample is at
    /// xb (front at xb + dxo).
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn shade(
        &self,
        sh: &SlabShading,
        c: [f32; 3],
        a: f32,
        g: Vec3,
        (uu, (xb, dxo)): (usize, (f64, f64)),
        w: f64,
        length: f32,
    ) -> ([f32; 3], f32) {
        let t = 1.0 - w;
        let mid = DVec3::new(xb + dxo * t, self.y + self.dyo * t, self.z as f64 + (self.zp as f64 - self.z as f64) * t);
        sh.frame.shade(c, a, g, mid, length, self.to_eyes.get(uu).copied())
    }

    /// Composites one segment (premultiplied colour c, opacity a) spanning fractions
    /// `seg` of the slab under pixel uu, recording where its opacity passes 0.5; true
    /// once the pixel is opaque enough to stop.
    #[inline(always)]
    fn accumulate(&self, p: &mut [f32; 4], depth: &mut f32, uu: usize, c: [f32; 3], a: f32, seg: (f64, f64)) -> bool {
        let t = 1.0 - p[3];
        let before = p[3];
        p[0] += t * c[0];
        p[1] += t * c[1];
        p[2] += t * c[2];
        p[3] += t * a;
        if before < 0.5 && p[3] >= 0.5 {
            // Where inside the segment opacity passed 0.5 (uniform extinction).
            let f = if a < 1.0 { ((0.5 / (1.0 - before)).ln() / (1.0 - a).ln()).clamp(0.0, 1.0) } else { 0.0 };
            let zf = self.zp as f64 + (seg.0 + f as f64 * (seg.1 - seg.0)) * (self.z as f64 - self.zp as f64);
            *depth = self.fac.depth(uu as f64, self.vf, zf) as f32;
        }
        p[3] >= self.termination
    }
}
