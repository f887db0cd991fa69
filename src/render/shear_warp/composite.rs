//! Compositing one slab (two neighbouring slices) of one intermediate row: the runs of
//! live pixels, K pre-integrated segments per slab, early ray termination through the
//! row's links. The per-ray core of shear-warp; `render` in mod.rs drives it over runs,
//! slices and rows.

use super::factor::Factorization;
use super::preint::PreintTable;
use super::prepare::Axis;
use super::scanline::{next_live, rows, SliceRows};
use super::MAX_SLAB_SAMPLES;

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
    pub(super) iz: f64,
    /// Inverse Mapping: x = u_over_ratio[U] + iz, one lookup and one add per pixel.
    pub(super) u_over_ratio: &'a [f64],
    /// x of the front slice's sample relative to the back slice's.
    pub(super) dxo: f64,
    pub(super) x_range: (f64, f64),
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
}

impl Slab<'_> {
    /// Composites the live pixels of u..run_end through K segments per slab and returns
    /// the next live pixel at or after run_end. Generic over K so that the paper's one
    /// segment per slab compiles without the loop over samples between the slices (a
    /// runtime count cost it a fifth of its speed).
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    pub(super) fn composite_run<const K: usize>(
        &self,
        links: &mut [u32],
        prev: &mut [f32],
        stamp: &mut [u32],
        row: &mut [[f32; 4]],
        depth: &mut [f32],
        u: usize,
        run_end: usize,
        n_samples: &mut u64,
    ) -> usize {
        let (table, q) = (self.table, self.q_to_level);
        // Slices zp and z at the rows of the K − 1 samples between them: point j lies at
        // fraction j/K from the front slice to the back one, where the trilinear value is
        // the mix of both slices at that point's (x, y). Looked up once per run.
        let between: Option<[(SliceRows, SliceRows); MAX_SLAB_SAMPLES - 1]> = (K > 1).then(|| {
            std::array::from_fn(|i| {
                let j = (i + 1).min(K.max(2) - 1);
                let yj = self.y + self.dyo * (1.0 - j as f64 / K as f64);
                let (r0, r1, rw) = rows(yj, self.axis.dims[1]);
                (SliceRows::new(self.axis, self.zp, r0, r1, rw), SliceRows::new(self.axis, self.z, r0, r1, rw))
            })
        });
        let mut uu = u;
        while uu < run_end {
            let xb = self.u_over_ratio[uu] + self.iz;
            let back = self.back.at(xb) * q;
            *n_samples += 1;
            let front = if stamp[uu] == self.zi - 1 {
                Some(prev[uu])
            } else {
                let xf = xb + self.dxo;
                match &self.front {
                    Some(front) if xf >= self.x_range.0 && xf <= self.x_range.1 => {
                        *n_samples += 1;
                        Some(front.at(xf) * q)
                    }
                    _ => None, // the ray entered the volume between these slices
                }
            };
            prev[uu] = back;
            stamp[uu] = self.zi;
            if let Some(front) = front {
                // K segments, front to back, through the trilinear values between the
                // slices; stop once the pixel is opaque.
                let mut f = front;
                for j in 0..K {
                    let b = if j + 1 == K {
                        back
                    } else {
                        let (fs, bs) = &between.as_ref().unwrap()[j];
                        let w = (j + 1) as f32 / K as f32;
                        let xj = xb + self.dxo * (1.0 - w as f64);
                        let (sf, sb) = (fs.at(xj), bs.at(xj));
                        *n_samples += 2;
                        (sf + w * (sb - sf)) * q
                    };
                    if f.max(b) >= table.clear_below {
                        let e = table.lookup(f, b);
                        if e.a > 0.0 {
                            let p = &mut row[uu];
                            let t = 1.0 - p[3];
                            let before = p[3];
                            p[0] += t * e.c[0];
                            p[1] += t * e.c[1];
                            p[2] += t * e.c[2];
                            p[3] += t * e.a;
                            if before < 0.5 && p[3] >= 0.5 {
                                // Where inside the segment opacity passed 0.5 (uniform extinction).
                                let f = if e.a < 1.0 { ((0.5 / (1.0 - before)).ln() / (1.0 - e.a).ln()).clamp(0.0, 1.0) } else { 0.0 };
                                let zf = self.zp as f64 + (j as f64 + f as f64) / K as f64 * (self.z as f64 - self.zp as f64);
                                depth[uu] = self.fac.depth(uu as f64, self.vf, zf) as f32;
                            }
                            if p[3] >= self.termination {
                                links[uu] = uu as u32 + 1; // early ray termination
                                break;
                            }
                        }
                    }
                    f = b;
                }
            }
            uu = next_live(links, uu + 1);
        }
        uu
    }
}
