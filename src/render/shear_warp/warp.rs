//! The 2-D warp from the intermediate image to the final one (affine in a parallel view,
//! projective in a perspective one): each final pixel samples the intermediate image
//! bilinearly (premultiplied colour and opacity; depth from the finite neighbours) or
//! takes its nearest intermediate pixel, skipping groups of pixels the intermediate image
//! leaves empty.

use super::factor::Factorization;
use super::{Intermediate, WarpFilter};
use crate::render::driver::{render_bands, Cancelled};
use crate::render::frame::Frame;
use rayon::prelude::*;

/// ⌊v⌋ without a libm call (x86-64 without SSE4.1 has no rounding instruction; the calls
/// were a quarter of the warp's time).
#[inline]
fn floor_i64(v: f64) -> i64 {
    let t = v as i64;
    if (t as f64) > v {
        t - 1
    } else {
        t
    }
}

/// Where final pixel (x, y)'s centre falls on the intermediate image: the top-left of the
/// four pixels it reads and the bilinear weights' fractions; None off the image. The warp
/// and `Footprint` share it, so the pixels composited are exactly those read.
#[inline]
fn sample_at(fac: &Factorization, x: usize, y: usize, iw: usize, ih: usize) -> Option<(i64, i64, f32, f32)> {
    let (u, v) = fac.to_intermediate(x as f64 + 0.5, y as f64 + 0.5);
    if !(u >= -1.0 && v >= -1.0 && u <= iw as f64 && v <= ih as f64) {
        return None;
    }
    let (u0, v0) = (floor_i64(u), floor_i64(v));
    Some((u0, v0, (u - u0 as f64) as f32, (v - v0 as f64) as f32))
}

/// Intermediate pixels (u, v) and their weights, the first `.1` of them used.
type Taps = ([(i64, i64, f32); 4], usize);

/// The intermediate pixels final pixel (x, y) reads and their weights: its four neighbours
/// bilinearly, or the nearest one.
#[inline]
fn taps(fac: &Factorization, x: usize, y: usize, iw: usize, ih: usize, filter: WarpFilter) -> Option<Taps> {
    let (u0, v0, tu, tv) = sample_at(fac, x, y, iw, ih)?;
    Some(match filter {
        WarpFilter::Bilinear => (
            [(u0, v0, (1.0 - tu) * (1.0 - tv)), (u0 + 1, v0, tu * (1.0 - tv)), (u0, v0 + 1, (1.0 - tu) * tv), (u0 + 1, v0 + 1, tu * tv)],
            4,
        ),
        WarpFilter::Nearest => ([(u0 + (tu >= 0.5) as i64, v0 + (tv >= 0.5) as i64, 1.0); 4], 1),
    })
}

/// The intermediate pixels the warp reads: each final pixel's four neighbours (or its
/// nearest, `WarpFilter::Nearest`: one intermediate pixel per final pixel). Where the
/// intermediate image is finer than the final one (a supersampled view, or a clinical
/// volume whose voxels are smaller than the pixels) most intermediate pixels fall between
/// the final pixels' footprints and are never read, so compositing skips them (they start
/// terminated) and the frame is bit for bit the same. 512×512×400 CT, perspective at
/// 512², ratio 3.05: a third of the intermediate pixels are read.
pub(super) struct Footprint {
    width: usize,
    /// One bit per intermediate pixel, rows of `words` words.
    bits: Vec<u64>,
    words: usize,
    /// Rows with any pixel read.
    rows: Vec<bool>,
    pub(super) count: usize,
}

impl Footprint {
    /// The pixels the warp reads where that skips work, else every pixel (`all`): only
    /// where the intermediate image holds more than twice as many pixels per final pixel
    /// (at the image's centre) as the warp reads for each (four, or one for the nearest)
    /// do most of them fall between the final pixels' taps. Elsewhere nearly every one is
    /// read and finding them cost more than it saved: 13 % of the CPU time of the paper's
    /// configuration (aneurism 512², ratio 1.5, one sample per slab), single-threaded.
    pub(super) fn of(fac: &Factorization, w: usize, h: usize, iw: usize, ih: usize, filter: WarpFilter) -> Footprint {
        let (x, y) = (0.5 * w as f64, 0.5 * h as f64);
        let c = fac.to_intermediate(x, y);
        let across = |p: (f64, f64)| (p.0 - c.0).hypot(p.1 - c.1);
        let per_pixel = across(fac.to_intermediate(x + 1.0, y)) * across(fac.to_intermediate(x, y + 1.0));
        let read = if filter == WarpFilter::Nearest { 1.0 } else { 4.0 };
        if per_pixel > 2.0 * read {
            Footprint::new(fac, w, h, iw, ih, filter)
        } else {
            Footprint::all(iw, ih)
        }
    }

    /// Every pixel of an iw × ih image.
    pub(super) fn all(iw: usize, ih: usize) -> Footprint {
        let words = iw.div_ceil(64);
        let row: Vec<u64> = (0..words).map(|k| if iw - 64 * k >= 64 { u64::MAX } else { (1u64 << (iw - 64 * k)) - 1 }).collect();
        Footprint { width: iw, bits: row.repeat(ih), words, rows: vec![true; ih], count: iw * ih }
    }

    /// The pixels the taps of the w × h final pixels read, found in parallel by final row.
    pub(super) fn new(fac: &Factorization, w: usize, h: usize, iw: usize, ih: usize, filter: WarpFilter) -> Footprint {
        use std::sync::atomic::{AtomicU64, Ordering};
        let words = iw.div_ceil(64);
        let shared: Vec<AtomicU64> = (0..words * ih).map(|_| AtomicU64::new(0)).collect();
        (0..h).into_par_iter().for_each(|y| {
            for x in 0..w {
                let Some((taps, n)) = taps(fac, x, y, iw, ih, filter) else { continue };
                for &(pu, pv, _) in &taps[..n] {
                    if pu >= 0 && pv >= 0 && (pu as usize) < iw && (pv as usize) < ih {
                        let (pu, pv) = (pu as usize, pv as usize);
                        shared[pv * words + pu / 64].fetch_or(1 << (pu % 64), Ordering::Relaxed);
                    }
                }
            }
        });
        let bits: Vec<u64> = shared.into_iter().map(AtomicU64::into_inner).collect();
        let rows = bits.chunks(words).map(|r| r.iter().any(|&b| b != 0)).collect();
        let count = bits.iter().map(|b| b.count_ones() as usize).sum();
        Footprint { width: iw, bits, words, rows, count }
    }

    /// Whether any pixel of intermediate row v is read.
    #[inline]
    pub(super) fn row(&self, v: usize) -> bool {
        self.rows[v]
    }

    /// Whether intermediate pixel (u, v) is read.
    #[inline]
    pub(super) fn read(&self, u: usize, v: usize) -> bool {
        debug_assert!(u < self.width);
        self.bits[v * self.words + u / 64] >> (u % 64) & 1 == 1
    }
}

/// The 2-D warp: each final pixel samples the intermediate image bilinearly (premultiplied
/// colour and opacity; depth from the finite neighbours) or takes its nearest pixel.
pub(super) fn warp(inter: &Intermediate, fac: &Factorization, w: usize, h: usize, filter: WarpFilter) -> Result<Frame, Cancelled> {
    let mut f = Frame::empty(w, h);
    let ih = inter.rgba.len() / inter.width;
    let iw = inter.width;
    // Which groups of 8 intermediate pixels hold anything (opacity > 0; colour and depth
    // come only with opacity): a final pixel whose four neighbours lie in empty groups
    // stays empty without being filtered. Most of an angiogram is background.
    let words = iw.div_ceil(8 * 64);
    let mut occupied = vec![0u64; words * ih];
    occupied.par_chunks_mut(words).zip(inter.rgba.par_chunks(iw)).for_each(|(bits, row)| {
        for (u, p) in row.iter().enumerate() {
            if p[3] > 0.0 {
                bits[u / 512] |= 1 << ((u / 8) % 64);
            }
        }
    });
    let group_empty = |u: i64, v: i64| {
        let (g, v) = (u as usize / 8, v as usize);
        occupied[v * words + g / 64] >> (g % 64) & 1 == 0
    };
    render_bands("warp", w, 1, &mut f.rgba, &mut f.depth, &mut [], |band| {
        let (y, row, depth) = (band.y0, band.rgba, band.depth);
        for x in 0..w {
            let Some((taps, n)) = taps(fac, x, y, iw, ih, filter) else { continue };
            let taps = &taps[..n];
            let inside = taps.iter().all(|&(u, v, _)| u >= 0 && v >= 0 && u < iw as i64 && v < ih as i64);
            if inside && taps.iter().all(|&(u, v, _)| group_empty(u, v)) {
                continue;
            }
            let mut acc = [0f32; 4];
            let (mut zsum, mut zw) = (0f32, 0f32);
            for &(pu, pv, wgt) in taps {
                // Inside the image the bounds tests are known to pass; a zero weight adds
                // exactly nothing, so skipping it is only needed at the edges.
                if !inside && (pu < 0 || pv < 0 || pu >= iw as i64 || pv >= ih as i64 || wgt == 0.0) {
                    continue;
                }
                let i = pv as usize * iw + pu as usize;
                let p = inter.rgba[i];
                for k in 0..4 {
                    acc[k] += wgt * p[k];
                }
                let d = inter.depth[i];
                if d.is_finite() {
                    zsum += wgt * d;
                    zw += wgt;
                }
            }
            row[x] = acc;
            if zw >= 0.5 {
                depth[x] = zsum / zw;
            }
        }
    })?;
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat4, DVec3};

    /// A factorisation whose warp is U = x + du, V = y + dv (one intermediate pixel per
    /// final pixel, shifted).
    fn shifted(du: f64, dv: f64) -> Factorization {
        Factorization {
            perm: [0, 1, 2],
            dims: [1, 1, 1],
            projection: super::super::factor::Projection::Parallel { sx: 0.0, sy: 0.0, warp: [[du, 1.0, 0.0], [dv, 0.0, 1.0]] },
            z_forward: true,
            umin: 0.0,
            vmin: 0.0,
            ratio: 1.0,
            width: 4,
            height: 4,
            slab_length: 1.0,
            to_world: DMat4::IDENTITY,
            forward: DVec3::Z,
            eye: DVec3::ZERO,
        }
    }

    /// The footprint is found only where the intermediate image is finer than the warp's
    /// taps cover: 4 intermediate pixels a final pixel (2 × 2) are more than twice the one
    /// the nearest warp reads, not twice the bilinear's four, 9 (3 × 3) are; elsewhere
    /// every pixel counts as read, the last word of each row only up to the width.
    #[test]
    fn the_footprint_is_found_only_where_it_skips_pixels() {
        let mut fac = shifted(0.0, 0.0);
        let scaled = |k: f64| super::super::factor::Projection::Parallel { sx: 0.0, sy: 0.0, warp: [[0.0, k, 0.0], [0.0, 0.0, k]] };
        fac.projection = scaled(2.0);
        assert_eq!(Footprint::of(&fac, 3, 3, 6, 6, WarpFilter::Nearest).count, 9);
        let all = Footprint::of(&fac, 3, 3, 6, 6, WarpFilter::Bilinear);
        assert_eq!(all.count, 36);
        assert!((0..6).all(|v| all.row(v) && (0..6).all(|u| all.read(u, v))));
        fac.projection = scaled(3.0);
        assert_eq!(Footprint::of(&fac, 3, 3, 9, 9, WarpFilter::Bilinear).count, 36);
        let wide = Footprint::all(70, 3);
        assert_eq!((wide.count, wide.bits.len()), (210, 6));
        assert!((0..3).all(|v| (0..70).all(|u| wide.read(u, v))));
        assert_eq!(wide.bits[1], (1 << 6) - 1, "no pixel past the width");
    }

    #[test]
    fn the_footprint_is_the_pixels_the_warp_reads() {
        // U = 3x, V = 3y: final pixel centres land on 1.5, 4.5, 7.5, so each reads columns
        // and rows {1, 2}, {4, 5}, {7, 8} of a 9 × 9 intermediate image, and nothing else.
        let mut fac = shifted(0.0, 0.0);
        fac.projection = super::super::factor::Projection::Parallel { sx: 0.0, sy: 0.0, warp: [[0.0, 3.0, 0.0], [0.0, 0.0, 3.0]] };
        let fp = Footprint::new(&fac, 3, 3, 9, 9, WarpFilter::Bilinear);
        let read = [1, 2, 4, 5, 7, 8];
        assert_eq!(fp.count, 36);
        for v in 0..9 {
            assert_eq!(fp.row(v), read.contains(&v), "row {v}");
            for u in 0..9 {
                assert_eq!(fp.read(u, v), read.contains(&u) && read.contains(&v), "({u}, {v})");
            }
        }
        // A pixel outside the footprint changes nothing the warp writes.
        let mut inter = Intermediate { width: 9, rgba: vec![[0.5; 4]; 81], depth: vec![2.0; 81] };
        let a = warp(&inter, &fac, 3, 3, WarpFilter::Bilinear).unwrap();
        for (i, p) in inter.rgba.iter_mut().enumerate() {
            if !fp.read(i % 9, i / 9) {
                *p = [f32::NAN; 4];
            }
        }
        let b = warp(&inter, &fac, 3, 3, WarpFilter::Bilinear).unwrap();
        assert_eq!(a.rgba, b.rgba);
    }

    #[test]
    fn the_nearest_filter_reads_and_takes_one_pixel_per_final_pixel() {
        // U = 3x + 0.2, V = 3y + 0.2: final pixel centres land on 1.7, 4.7, 7.7, nearest to
        // columns and rows 2, 5 and 8 of a 9 × 9 intermediate image.
        let mut fac = shifted(0.0, 0.0);
        fac.projection = super::super::factor::Projection::Parallel { sx: 0.0, sy: 0.0, warp: [[0.2, 3.0, 0.0], [0.2, 0.0, 3.0]] };
        let fp = Footprint::new(&fac, 3, 3, 9, 9, WarpFilter::Nearest);
        let read = [2, 5, 8];
        assert_eq!(fp.count, 9);
        for v in 0..9 {
            assert_eq!(fp.row(v), read.contains(&v), "row {v}");
            for u in 0..9 {
                assert_eq!(fp.read(u, v), read.contains(&u) && read.contains(&v), "({u}, {v})");
            }
        }
        // Each final pixel is its nearest intermediate pixel, colour and depth, unmixed.
        let inter = Intermediate {
            width: 9,
            rgba: (0..81).map(|i| [i as f32 / 81.0, 0.5, 0.25, 1.0]).collect(),
            depth: (0..81).map(|i| 10.0 + i as f32).collect(),
        };
        let f = warp(&inter, &fac, 3, 3, WarpFilter::Nearest).unwrap();
        for (y, x) in (0..3).flat_map(|y| (0..3).map(move |x| (y, x))) {
            let i = (3 * y + 2) * 9 + 3 * x + 2;
            assert_eq!(f.rgba[y * 3 + x], inter.rgba[i], "({x}, {y})");
            assert_eq!(f.depth[y * 3 + x], inter.depth[i], "({x}, {y})");
        }
    }

    #[test]
    fn floor_matches_the_library_on_both_sides_of_zero() {
        for v in [-2.5, -2.0, -0.5, -1e-12, 0.0, 0.3, 1.0, 7.99] {
            assert_eq!(floor_i64(v), v.floor() as i64, "{v}");
        }
    }

    #[test]
    fn the_warp_samples_the_intermediate_image_bilinearly() {
        // One opaque intermediate pixel at (1, 1) with depth 5; the final pixel centres
        // land half a pixel off the intermediate grid, so each of the four final pixels
        // around it gets a quarter of it.
        let mut inter = Intermediate { width: 4, rgba: vec![[0.0; 4]; 16], depth: vec![f32::INFINITY; 16] };
        inter.rgba[4 + 1] = [0.8, 0.4, 0.0, 1.0];
        inter.depth[4 + 1] = 5.0;
        let f = warp(&inter, &shifted(0.0, 0.0), 3, 3, WarpFilter::Bilinear).unwrap();
        for (x, y) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            assert_eq!(f.rgba[y * 3 + x], [0.2, 0.1, 0.0, 0.25], "({x}, {y})");
            // A quarter of the weight on a finite depth is below the half needed.
            assert!(f.depth[y * 3 + x].is_infinite());
        }
        assert_eq!(f.rgba[2 * 3 + 2], [0.0; 4]);
        // Shifted by half a pixel the final pixel (1, 1) sits on it exactly.
        let f = warp(&inter, &shifted(-0.5, -0.5), 3, 3, WarpFilter::Bilinear).unwrap();
        assert_eq!(f.rgba[3 + 1], [0.8, 0.4, 0.0, 1.0]);
        assert_eq!(f.depth[3 + 1], 5.0);
        assert_eq!(f.rgba[0], [0.0; 4]);
    }
}
