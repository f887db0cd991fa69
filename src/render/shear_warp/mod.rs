//! The shear-warp volume renderer (Kye & Kim, after Lacroute & Levoy), for parallel and
//! perspective projection: rendering along intermediate-image scanlines at any real
//! supersampling ratio, post-classification through a pre-integrated table, early ray
//! termination with links over opaque pixels, empty-space leaping with the overlapped
//! min-max map (or the paper's two baselines), maximum intensity projection, gradient
//! shading (`shading`), and a 2-D warp (bilinear samples; affine or projective). Rays are
//! composited over the whole box of voxel centres, including the pieces that enter or
//! leave it through a side face between two slices (`Slab::composite_exits` and the entry
//! case of `composite_run`).
//!
//! Perspective (the factorisation in `factor`): each slice is scaled about the eye's foot
//! as well as sheared, so a ray's step from one slice to the next varies along the
//! intermediate row (x) but not along the column (y). The pre-integrated table is made for
//! the ray through the volume's centre; each ray's segments are corrected to its own
//! length (opacity α → 1 − (1 − α)^r, colour scaled with it: exact for a constant value).
//! Empty-space leaping applies where a ray's sideways step between slices stays within the
//! voxel the overlapped map's blocks reach (always, in a parallel view); elsewhere the
//! slabs are sampled. A view from inside the volume is refused with that reason.
//!
//! Fusion (`fusion`): a second volume resampled onto this one's grid is classified by its
//! own table at the same points and fused with it segment by segment (`Input::second`).
mod composite;
pub mod factor;
pub mod fusion;
pub mod minmax;
/// The pre-integrated table, shared with the GPU ray-caster (`render::preint`).
pub use super::preint;
mod prepare;
mod scanline;
mod shading;
mod warp;

use composite::{Slab, SlabSecond, SlabShading};
pub use prepare::Prepared;
use scanline::{next_live, rows, RowState, SliceRows, SliceRuns};
use warp::warp;

use super::frame::{Frame, FrameStats};
use crate::catalog::shear_warp::MAX_SLAB_SAMPLES;
pub use crate::catalog::shear_warp::{Leaping, Settings, WarpFilter, RENDERER};
use crate::scene::{BlendMode, HalfSpace, Light, RayGenerator, TransferFunction, VolumeShading};
use anyhow::Result;
use factor::{Factorization, SliceMap};
use glam::DMat4;
use minmax::next_unclear;
use preint::PreintTable;
use rayon::prelude::*;
use shading::{FrameShading, SliceGradient};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// What to draw.
pub struct Input<'a> {
    pub prepared: &'a Prepared,
    pub node_to_world: DMat4,
    pub tf: &'a TransferFunction,
    pub blend: BlendMode,
    /// Gradient shading (None or `shade = false`: none; MIP is never shaded).
    pub shading: Option<&'a VolumeShading>,
    /// The scene's lights for shading (none: a headlight).
    pub lights: &'a [Light],
    /// The region drawn (`Scene::crop_region`: half-spaces in node coordinates; empty:
    /// the whole volume).
    pub crop: &'a [HalfSpace],
    /// A second volume fused with this one along every ray, resampled onto its grid
    /// (`fusion`; composite blending, no crop region).
    pub second: Option<fusion::Second<'a>>,
}

/// The intermediate image.
struct Intermediate {
    width: usize,
    rgba: Vec<[f32; 4]>,
    depth: Vec<f32>,
}

pub fn render(input: &Input, rays: &RayGenerator, settings: &Settings) -> Result<Frame> {
    settings.validate().map_err(|e| anyhow::anyhow!("{}: {e}", RENDERER.name))?;
    if settings.coarsening == 3 {
        anyhow::bail!("{}: coarsening must be 0 (auto), 1, 2 or 4, not 3", RENDERER.name);
    }
    // A coarser copy where asked (none for a fused pair: the second volume is on this grid).
    let coarsening = match settings.coarsening {
        _ if input.second.is_some() => 1,
        0 => auto_coarsening(input, rays)?,
        c => c,
    };
    if coarsening > 1 {
        let coarse = input.prepared.coarser(coarsening)?;
        let coarse_input = Input {
            prepared: &coarse,
            node_to_world: input.node_to_world,
            tf: input.tf,
            blend: input.blend,
            shading: input.shading,
            lights: input.lights,
            crop: input.crop,
            second: None,
        };
        let mut frame = render(&coarse_input, rays, &Settings { coarsening: 1, ..settings.clone() })?;
        frame.stats.counters.push(("coarsening".into(), coarsening as f64));
        return Ok(frame);
    }
    let start = std::time::Instant::now();
    let prep = input.prepared;
    let tf = input.tf;
    let index_to_world = crate::geometry::index_to_world(input.node_to_world, prep.affine)?;
    let ratio = (settings.supersampling > 0.0).then_some(settings.supersampling);
    let fac = Factorization::new(index_to_world, prep.dims, rays, ratio).map_err(|e| anyhow::anyhow!("{}: {e}", RENDERER.name))?;
    let perspective = fac.is_perspective();
    let axis_copy = prep.axis(fac.perm)?;
    let axis = &*axis_copy;
    let [nx, ny, nz] = axis.dims;
    // The second volume of a fused pair: its slices along the same axis, on the same grid.
    let second_axis = match &input.second {
        Some(sec) => {
            if sec.prepared.dims != prep.dims {
                anyhow::bail!("{}: the fused volume is not on the first one's grid", RENDERER.name);
            }
            if input.blend == BlendMode::Mip || !input.crop.is_empty() || nz == 1 {
                anyhow::bail!("{}: fusion needs composite blending, no crop region and more than one slice", RENDERER.name);
            }
            Some(sec.prepared.axis(fac.perm)?)
        }
        None => None,
    };
    // The crop region in permuted voxel coordinates (permuted axis a is index axis perm[a]).
    let crop: Vec<HalfSpace> = input
        .crop
        .iter()
        .map(|h| {
            // A plane through voxel centres keeps the samples on it whatever the rounding
            // (1e-7 voxel of slack): dropping a row of them would fray the cut's edge.
            let hi = h.pulled_back(prep.affine);
            HalfSpace { normal: glam::DVec3::from(fac.perm.map(|a| hi.normal[a])), offset: hi.offset + 1e-7 * hi.normal.length() }
        })
        .collect();
    let kept = |p: glam::DVec3| crop.iter().all(|h| h.at(p) >= 0.0);
    let n_levels = if settings.table_levels >= 2 { settings.table_levels.min(4096) } else { preint::level_count(tf, prep.lo, prep.hi) };
    // A one-slice stack has no slab between slices: its slab is the slice itself, one
    // voxel thick, and nothing lies between slices.
    let k = if nz == 1 { 1 } else { settings.slab_samples };
    let table = PreintTable::new(tf, prep.lo, prep.hi, n_levels, fac.slab_length / k as f64);
    let q_to_level = (n_levels - 1) as f32 / 65535.0;
    let level_to_value = |l: f32| prep.lo + (prep.hi - prep.lo) * l as f64 / (n_levels - 1) as f64;
    let mip = input.blend == BlendMode::Mip;
    // The second volume's table (its own levels, over its own value range) and quanta.
    let second = input.second.as_ref().map(|sec| {
        let levels = if settings.table_levels >= 2 {
            settings.table_levels.min(4096)
        } else {
            preint::level_count(sec.tf, sec.prepared.lo, sec.prepared.hi)
        };
        (PreintTable::new(sec.tf, sec.prepared.lo, sec.prepared.hi, levels, fac.slab_length / k as f64), (levels - 1) as f32 / 65535.0)
    });
    // Shading and the gradient opacity read the gradient at the segments they touch.
    let seg_units = (fac.slab_length / k as f64 / tf.scalar_opacity_unit_distance) as f32;
    let shading = if mip { None } else { FrameShading::new(input.shading, input.lights, &fac, (prep.lo, prep.hi), tf, seg_units)? };
    // The second volume's own shading and gradient opacity, on its own value range.
    let shading2 = match &input.second {
        Some(sec) => {
            let units = (fac.slab_length / k as f64 / sec.tf.scalar_opacity_unit_distance) as f32;
            FrameShading::new(sec.shading, input.lights, &fac, (sec.prepared.lo, sec.prepared.hi), sec.tf, units)?
        }
        None => None,
    };
    // (Fused: one transparency test for both volumes, the overlapped map's masks ANDed.)
    let leaping =
        if (mip || second.is_some()) && settings.leaping == Leaping::MultiScanline { Leaping::Overlapped } else { settings.leaping };
    let n = settings.block;
    let clear = table.clear_quanta(q_to_level);
    // Built once per volume, axis and block size; reused across views and transfer functions.
    // MIP tests the map itself; compositing only its transparent-block mask, kept per axis
    // (a turn back to an axis whose copy was replaced needs no new map).
    let overlapped = leaping == Leaping::Overlapped && nz > 1;
    let over_map = (overlapped && mip).then(|| axis.overlapped(n));
    let scan_map = (leaping == Leaping::MultiScanline && nz > 1).then(|| axis.scanline(n));
    let clear_mask = (overlapped && !mip).then(|| prep.clear_mask(fac.perm[2], n, &clear, || axis.overlapped(n)));
    // A block is clear for a fused pair where it is clear for both volumes.
    let clear_mask = match (clear_mask, &second_axis, &input.second, &second) {
        (Some(m1), Some(a2), Some(sec), Some((t2, q2))) => {
            let m2 = sec.prepared.clear_mask(fac.perm[2], n, &t2.clear_quanta(*q2), || a2.overlapped(n));
            Some(Arc::new(m1.and(&m2)))
        }
        (m, _, _, _) => m,
    };
    let (over_map, scan_map, clear_mask) = (over_map.as_deref(), scan_map.as_deref(), clear_mask.as_deref());

    // View clipping: only intermediate pixels the final image can see (in perspective the
    // factorisation made the intermediate image no larger than that).
    let (w, h) = rays.size();
    let (u_clip_lo, u_clip_hi, v_clip_lo, v_clip_hi) = if perspective {
        (0, fac.width as f64 - 1.0, 0, fac.height as f64 - 1.0)
    } else {
        let corners = [(0.0, 0.0), (w as f64, 0.0), (0.0, h as f64), (w as f64, h as f64)].map(|(x, y)| fac.to_intermediate(x, y));
        (
            (corners.iter().map(|c| c.0).fold(f64::INFINITY, f64::min).floor() - 1.0).max(0.0) as usize,
            (corners.iter().map(|c| c.0).fold(f64::NEG_INFINITY, f64::max).ceil() + 1.0).min(fac.width as f64 - 1.0),
            (corners.iter().map(|c| c.1).fold(f64::INFINITY, f64::min).floor() - 1.0).max(0.0) as usize,
            (corners.iter().map(|c| c.1).fold(f64::NEG_INFINITY, f64::max).ceil() + 1.0).min(fac.height as f64 - 1.0),
        )
    };
    if u_clip_hi < 0.0 || v_clip_hi < 0.0 || u_clip_lo as f64 > u_clip_hi || v_clip_lo as f64 > v_clip_hi {
        let mut f = Frame::empty(w, h);
        f.stats = FrameStats { renderer: RENDERER.name.into(), seconds: start.elapsed().as_secs_f64(), ..Default::default() };
        return Ok(f);
    }
    let (u_clip_hi, v_clip_hi) = (u_clip_hi as usize, v_clip_hi as usize);

    let iw = fac.width;
    // Colour, opacity and depth: 20 bytes per intermediate pixel.
    prep.limits.check(std::path::Path::new("shear-warp"), "the intermediate image", &[iw as u64, fac.height as u64, 20])?;
    let mut inter = Intermediate { width: iw, rgba: filled(iw * fac.height, [0.0; 4]), depth: filled(iw * fac.height, f32::INFINITY) };
    // Only the intermediate pixels the warp reads are composited.
    let footprint = warp::Footprint::of(&fac, w, h, iw, fac.height, settings.warp);
    let samples = AtomicU64::new(0);
    let slabs_leapt = AtomicU64::new(0);
    let pairs = AtomicU64::new(0);
    let termination = settings.termination as f32;
    // x extent of the slices (a one-voxel axis spans ±0.5).
    let (x_lo, x_hi) = if nx == 1 { (-0.5, 0.5) } else { (0.0, (nx - 1) as f64) };
    let (y_lo, y_hi) = if ny == 1 { (-0.5, 0.5) } else { (0.0, (ny - 1) as f64) };
    let slice_at = |zi: usize| if fac.z_forward { zi } else { nz - 1 - zi };
    let nbx = nx / n + 2;
    // Each slice's place on the intermediate image (Inverse Mapping: x = U·scale + x0).
    let maps: Vec<SliceMap> = (0..nz).map(|z| fac.slice_map(z as f64)).collect();
    let slice_runs: Vec<SliceRuns> =
        (0..nz).into_par_iter().map(|z| SliceRuns::new(maps[z], (x_lo, x_hi), (u_clip_lo, u_clip_hi), n, nbx)).collect();

    // Bands of intermediate rows, one task each; inside a band the slices come first
    // (object order), so the slice rows that neighbouring intermediate rows read are
    // still in cache.
    const BAND: usize = 8;
    super::driver::render_bands("shear-warp", iw, BAND, &mut inter.rgba, &mut inter.depth, &mut [], |band| {
        let (band_rgba, band_depth, band_rows, v_first) = (band.rgba, band.depth, band.rows, band.y0);
        let live = |r: usize| (v_clip_lo..=v_clip_hi).contains(&(v_first + r)) && footprint.row(v_first + r);
        // Pixels the warp never reads start terminated (composite: linked past; MIP: a
        // maximum nothing exceeds, which never blocks a leap and is never drawn).
        let mut states: Vec<RowState> = (0..band_rows)
            .map(|r| {
                let mut st = RowState::new(iw);
                if live(r) {
                    for u in (0..iw).filter(|&u| !footprint.read(u, v_first + r)) {
                        st.links[u] = u as u32 + 1;
                        st.max_level[u] = f32::INFINITY;
                    }
                }
                st
            })
            .collect();
        // Each ray's length between slices relative to the table's (perspective only; for
        // the pixels composited, the others are never looked up).
        let lengths: Vec<Vec<f32>> = if perspective {
            (0..band_rows)
                .map(|r| {
                    let v = v_first + r;
                    if !live(r) {
                        return Vec::new();
                    }
                    (0..iw).map(|u| if footprint.read(u, v) { fac.length_ratio(u as f64, v as f64) as f32 } else { 1.0 }).collect()
                })
                .collect()
        } else {
            vec![Vec::new(); band_rows]
        };
        // And each ray's direction toward the eye, for the lighting's view vector (lit
        // perspective views only): a world transform and a normalisation per pixel, where
        // they were per shaded segment (2–3 % of a shaded clinical frame).
        let lit = shading.as_ref().is_some_and(|s| s.is_lit()) || shading2.as_ref().is_some_and(|s| s.is_lit());
        let to_eyes: Vec<Vec<glam::Vec3>> = if perspective && lit {
            (0..band_rows)
                .map(|r| {
                    let v = v_first + r;
                    if !live(r) {
                        return Vec::new();
                    }
                    (0..iw).map(|u| if footprint.read(u, v) { fac.to_eye(u as f64, v as f64) } else { glam::Vec3::ZERO }).collect()
                })
                .collect()
        } else {
            vec![Vec::new(); band_rows]
        };
        let mut n_samples = 0u64;
        let mut n_leapt = 0u64;
        // (Intermediate row, slice pair)s set up for compositing (issue 45 measured their
        // cost: skipping those whose every block is clear, 0–94 % of them on the clinical
        // orbit's views, bit for bit the same frames, left the frame time unchanged).
        let mut n_pairs = 0u64;
        let x_of = |u: usize, m: &SliceMap| u as f64 * m.scale + m.x0;
        let y_at = |vf: f64, z: usize| vf * maps[z].scale + maps[z].y0;

        for r in (0..band_rows).filter(|&r| nz == 1 && live(r)) {
            // One slice: one slab of constant value, one voxel thick.
            let vf = (v_first + r) as f64;
            let (row, depth) = (&mut band_rgba[r * iw..(r + 1) * iw], &mut band_depth[r * iw..(r + 1) * iw]);
            let max_level = &mut states[r].max_level;
            let y = y_at(vf, 0);
            if y < y_lo || y > y_hi {
                continue;
            }
            let (y0, y1, wy) = rows(y, ny);
            if let Some((ua, ub)) = slice_runs[0].span {
                let slice = SliceRows::new(axis, 0, y0, y1, wy);
                for u in ua..=ub {
                    let x = x_of(u, &maps[0]);
                    if !footprint.read(u, v_first + r) || !kept(glam::DVec3::new(x, y, 0.0)) {
                        continue;
                    }
                    let s = slice.at(x) * q_to_level;
                    n_samples += 1;
                    if mip {
                        max_level[u] = s;
                    } else {
                        let length = lengths[r].get(u).copied().unwrap_or(1.0);
                        let to_eye = to_eyes[r].get(u).copied();
                        let (c, a) = composite::for_length(table.lookup(s, s), length);
                        let (c, a) = match &shading {
                            Some(sh) if a > 0.0 => {
                                sh.shade(c, a, SliceGradient::new(axis, 0, y).at(x), glam::DVec3::new(x, y, 0.0), length, to_eye)
                            }
                            _ => (c, a),
                        };
                        row[u] = [c[0], c[1], c[2], a];
                        if a >= 0.5 {
                            depth[u] = fac.depth(u as f64, vf, 0.0) as f32;
                        }
                    }
                }
            }
        }

        for zi in 0..nz {
            for r in (0..band_rows).filter(|&r| live(r)) {
                let vf = (v_first + r) as f64;
                let (row, depth) = (&mut band_rgba[r * iw..(r + 1) * iw], &mut band_depth[r * iw..(r + 1) * iw]);
                let RowState { links, prev, prev2, stamp, max_level, max_z, grads } = &mut states[r];
                let z = slice_at(zi);
                let y = y_at(vf, z);
                if nz == 1 {
                    continue;
                }
                let runs = &slice_runs[z];
                let back_map = &maps[z];
                // The pixels whose sample on this slice lies inside it. Where there are
                // none, a ray may still leave the volume through a side face between the
                // previous slice and this one (composite only).
                let back_span = runs.span.filter(|_| y >= y_lo && y <= y_hi);
                if back_span.is_none() && (mip || zi == 0) {
                    continue;
                }
                let (ua, ub) = back_span.unwrap_or((1, 0));
                let (y0, y1, wy) = rows(y, ny);
                let back_slice = SliceRows::new(axis, z, y0, y1, wy);
                // The front slice (the previous in compositing order) relative to this
                // one: its sample for pixel u lies at x + dxo0 + u·ddxo, y + dyo.
                let front = (zi > 0).then(|| {
                    let zp = slice_at(zi - 1);
                    let fm = &maps[zp];
                    (zp, fm.x0 - back_map.x0, fm.scale - back_map.scale, y_at(vf, zp) - y)
                });
                if mip {
                    // Sample every slice (and, with k samples per slab, k − 1 trilinear
                    // samples between it and the previous one: the maximum along an
                    // oblique ray often lies between slices); skip runs whose block
                    // cannot raise any pixel's max.
                    let between = front.filter(|_| k > 1).map(|(zp, dxo0, ddxo, dyo)| {
                        // Points outside the volume (the ray enters between the slices)
                        // are not samples.
                        let pairs: [Option<(f64, SliceRows, SliceRows)>; MAX_SLAB_SAMPLES - 1] = std::array::from_fn(|i| {
                            let w = (i + 1) as f64 / k as f64;
                            let yj = y + dyo * (1.0 - w);
                            (i + 1 < k && yj >= y_lo && yj <= y_hi).then(|| {
                                let (r0, r1, rw) = rows(yj, ny);
                                (w, SliceRows::new(axis, zp, r0, r1, rw), SliceRows::new(axis, z, r0, r1, rw))
                            })
                        });
                        // The composite loop's block: both slices over the whole segment.
                        let row_start = if dyo < 0.0 { y0 as isize - 1 } else { y0 as isize };
                        (zp, dxo0, ddxo, dyo, z.min(zp), row_start, pairs)
                    });
                    let mut u = ua;
                    while u <= ub {
                        let (bx, run_end) = runs.run(u, ub + 1);
                        if let Some(map) = over_map {
                            let mm = match &between {
                                Some((_, dxo0, ddxo, dyo, zs, row_start, _)) => {
                                    let dxo = |u: usize| dxo0 + u as f64 * ddxo;
                                    leap_variant(dxo(u), dxo(run_end - 1), *dyo).map(|v| map.get(*zs, *row_start, v, bx))
                                }
                                None => Some(map.get(if z + 1 < nz { z } else { z - 1 }, y0 as isize, 0, bx)),
                            };
                            if let Some(mm) = mm {
                                let block_max = mm.max as f32 * q_to_level;
                                let run_min = max_level[u..run_end].iter().cloned().fold(f32::INFINITY, f32::min);
                                if block_max <= run_min {
                                    n_leapt += 1;
                                    u = run_end;
                                    continue;
                                }
                            }
                        }
                        for uu in u..run_end {
                            if max_level[uu] == f32::INFINITY {
                                continue; // not read by the warp
                            }
                            let xb = x_of(uu, back_map);
                            let s = if crop.is_empty() || kept(glam::DVec3::new(xb, y, z as f64)) {
                                n_samples += 1;
                                back_slice.at(xb) * q_to_level
                            } else {
                                f32::NEG_INFINITY
                            };
                            if s > max_level[uu] {
                                max_level[uu] = s;
                                max_z[uu] = z as f32;
                            }
                            // Where the crop region cuts the ray between the slices, its
                            // value where it enters and leaves the region are samples too
                            // (the maximum often lies on a cut face).
                            if let Some((zp, dxo0, ddxo, dyo)) = front.filter(|_| !crop.is_empty()) {
                                let dxo = dxo0 + uu as f64 * ddxo;
                                let (fp, bp) = (glam::DVec3::new(xb + dxo, y + dyo, zp as f64), glam::DVec3::new(xb, y, z as f64));
                                if let Some((w0, w1)) =
                                    composite::crop_interval(&crop, fp, bp, (0.0, 1.0)).filter(|&(a, b)| a > 0.0 || b < 1.0)
                                {
                                    for w in [w0, w1].into_iter().filter(|&w| w > 0.0 && w < 1.0) {
                                        let (xj, yj) = (xb + dxo * (1.0 - w), y + dyo * (1.0 - w));
                                        if xj < x_lo || xj > x_hi || yj < y_lo || yj > y_hi {
                                            continue;
                                        }
                                        let s = composite::between_slices(axis, (zp, z), xj, yj, w) * q_to_level;
                                        n_samples += 2;
                                        if s > max_level[uu] {
                                            max_level[uu] = s;
                                            max_z[uu] = (zp as f64 + w * (z as f64 - zp as f64)) as f32;
                                        }
                                    }
                                }
                            }
                            if let Some((zp, dxo0, ddxo, dyo, _, _, pairs)) = &between {
                                let dxo = dxo0 + uu as f64 * ddxo;
                                for (w, fs, bs) in pairs.iter().flatten() {
                                    let xj = xb + dxo * (1.0 - w);
                                    let zj = *zp as f64 + w * (z as f64 - *zp as f64);
                                    if xj < x_lo || xj > x_hi || !kept(glam::DVec3::new(xj, y + dyo * (1.0 - w), zj)) {
                                        continue;
                                    }
                                    let (a, b) = (fs.at(xj), bs.at(xj));
                                    let s = (a + *w as f32 * (b - a)) * q_to_level;
                                    n_samples += 2;
                                    if s > max_level[uu] {
                                        max_level[uu] = s;
                                        max_z[uu] = zj as f32;
                                    }
                                }
                            }
                        }
                        u = run_end;
                    }
                    continue;
                }
                // The first slice only starts rays; its samples are taken below.
                let Some((zp, dxo0, ddxo, dyo)) = front else { continue };
                let zs = z.min(zp);
                let yp = y + dyo;
                if back_span.is_none() && !(y_lo..=y_hi).contains(&yp) {
                    continue;
                }
                n_pairs += 1;
                let front_slice = (yp >= y_lo && yp <= y_hi).then(|| {
                    let (f0, f1, fw) = rows(yp, ny);
                    SliceRows::new(axis, zp, f0, f1, fw)
                });
                let slab_shading =
                    shading.as_ref().map(|frame| SlabShading::new(frame, axis, (z, y), front_slice.is_some().then_some((zp, yp))));
                let slab = Slab {
                    back: back_slice,
                    front: front_slice,
                    axis,
                    y,
                    dyo,
                    back_map: *back_map,
                    dxo0,
                    ddxo,
                    lengths: &lengths[r],
                    to_eyes: &to_eyes[r],
                    x_range: (x_lo, x_hi),
                    y_range: (y_lo, y_hi),
                    zi: zi as u32,
                    z,
                    zp,
                    vf,
                    table: &table,
                    q_to_level,
                    termination,
                    fac: &fac,
                    shading: slab_shading,
                    crop: &crop,
                    between: Default::default(),
                    second: second_axis.as_deref().zip(second.as_ref()).map(|(a2, (t2, q2))| SlabSecond {
                        back: SliceRows::new(a2, z, y0, y1, wy),
                        front: (yp >= y_lo && yp <= y_hi).then(|| {
                            let (f0, f1, fw) = rows(yp, ny);
                            SliceRows::new(a2, zp, f0, f1, fw)
                        }),
                        axis: a2,
                        table: t2,
                        q_to_level: *q2,
                        shading: shading2
                            .as_ref()
                            .map(|frame| SlabShading::new(frame, a2, (z, y), (yp >= y_lo && yp <= y_hi).then_some((zp, yp)))),
                    }),
                };
                // With a crop region, composite_run takes the pixels whose whole segment
                // it keeps; composite_exits the ones it cuts (between `reach`'s ends).
                let (ua, ub, reach) = if crop.is_empty() {
                    (ua, ub, None)
                } else {
                    let (whole, any) = slab.crop_ranges();
                    let (a, b) = (whole.0.ceil().max(ua as f64), whole.1.floor().min(ub as f64));
                    let (ua, ub) = if a <= b { (a as usize, b as usize) } else { (1, 0) };
                    (ua, ub, Some(any))
                };
                let run_span = (ua <= ub).then_some((ua, ub));
                let row_start = if dyo < 0.0 { y0 as isize - 1 } else { y0 as isize };
                let mask_rows = [0, 1].map(|variant| clear_mask.map(|m| m.row(zs, row_start, variant)));
                let block_clear = |bx: usize, variant: usize| match leaping {
                    Leaping::None => false,
                    Leaping::Overlapped => mask_rows[variant].unwrap()[bx / 64] >> (bx % 64) & 1 == 1,
                    Leaping::MultiScanline => {
                        let xl = (n * bx) as isize - variant as isize;
                        let mm = scan_map.unwrap().region(xl, xl + n as isize + 1, row_start, row_start + 2, zs, zs + 1);
                        clear.clear(mm.min, mm.max)
                    }
                };
                // The blocks' variant for pixels a..=b (None: not leapable there).
                let variant_of = |a: usize, b: usize| leap_variant(slab.dxo(a), slab.dxo(b), dyo);
                // Perspective rays far off the principal axis step more than a voxel
                // sideways between slices, beyond one block's reach: their run is tested
                // over every block and row start its samples can touch (variant 0 blocks
                // cover x from n·b to n·b + n + 1, row starts s rows s to s + 2).
                let (rows_lo, rows_hi) = (
                    (y0 as isize + dyo.min(0.0).floor() as isize).max(0),
                    (y0 as isize + 1 + dyo.max(0.0).ceil() as isize).min(ny as isize - 1),
                );
                let wide_clear = |bx: usize, d_lo: f64, d_hi: f64| -> bool {
                    let xa = ((n * bx) as isize + d_lo.min(0.0).floor() as isize).max(0);
                    let xb = ((n * bx + n) as isize + d_hi.max(0.0).ceil() as isize).min(nx as isize - 1);
                    match leaping {
                        Leaping::None => false,
                        Leaping::MultiScanline => {
                            let mm = scan_map.unwrap().region(xa, xb, rows_lo, rows_hi, zs, zs + 1);
                            clear.clear(mm.min, mm.max)
                        }
                        Leaping::Overlapped => {
                            let mask = clear_mask.unwrap();
                            let (b_lo, b_hi) = (xa as usize / n, ((xb - n as isize - 1).max(0) as usize).div_ceil(n).min(nbx - 1));
                            let mut start = rows_lo;
                            loop {
                                let row = mask.row(zs, start, 0);
                                if (b_lo..=b_hi.max(b_lo)).any(|b| row[b / 64] >> (b % 64) & 1 == 0) {
                                    return false;
                                }
                                if start + 2 >= rows_hi {
                                    return true;
                                }
                                start = (start + 3).min(rows_hi);
                            }
                        }
                    }
                };
                let mut u = next_live(links, ua);
                while u <= ub {
                    let (bx, run_end) = runs.run(u, ub + 1);
                    let variant = variant_of(u, run_end - 1);
                    if variant.is_none() && perspective {
                        let (d0, d1) = (slab.dxo(u), slab.dxo(run_end - 1));
                        if wide_clear(bx, d0.min(d1), d0.max(d1)) {
                            n_leapt += 1;
                            u = if run_end > ub { ub + 1 } else { next_live(links, run_end) };
                            continue;
                        }
                    }
                    if let Some(variant) = variant.filter(|&v| block_clear(bx, v)) {
                        // Leap this block and the transparent blocks after it (one bit
                        // scan with the overlapped map's mask, one test per block for
                        // the multi-scanline baseline), then find the next live pixel.
                        let (b, end) = match mask_rows[variant] {
                            Some(mask_row) => {
                                let b = next_unclear(mask_row, bx + 1, nbx);
                                (b, if b < nbx { runs.block_end[b - 1].max(run_end) } else { usize::MAX })
                            }
                            None => {
                                let (mut b, mut end) = (bx + 1, run_end);
                                while end <= ub && b < nbx && block_clear(b, variant) {
                                    end = runs.block_end[b];
                                    b += 1;
                                }
                                (b, end)
                            }
                        };
                        // In perspective the front samples may change side within the
                        // leap: then leap this block alone.
                        let (b, end) =
                            if end > run_end && variant_of(u, end.min(ub + 1) - 1) != Some(variant) { (bx + 1, run_end) } else { (b, end) };
                        n_leapt += (b - bx) as u64;
                        u = if end > ub { ub + 1 } else { next_live(links, end) };
                        continue;
                    }
                    u = match (k, slab.second.is_some()) {
                        (1, false) => {
                            slab.composite_run::<1, false>(links, prev, prev2, stamp, grads, row, depth, u, run_end, &mut n_samples)
                        }
                        (2, false) => {
                            slab.composite_run::<2, false>(links, prev, prev2, stamp, grads, row, depth, u, run_end, &mut n_samples)
                        }
                        (3, false) => {
                            slab.composite_run::<3, false>(links, prev, prev2, stamp, grads, row, depth, u, run_end, &mut n_samples)
                        }
                        (_, false) => {
                            slab.composite_run::<4, false>(links, prev, prev2, stamp, grads, row, depth, u, run_end, &mut n_samples)
                        }
                        (1, true) => {
                            slab.composite_run::<1, true>(links, prev, prev2, stamp, grads, row, depth, u, run_end, &mut n_samples)
                        }
                        (2, true) => {
                            slab.composite_run::<2, true>(links, prev, prev2, stamp, grads, row, depth, u, run_end, &mut n_samples)
                        }
                        (3, true) => {
                            slab.composite_run::<3, true>(links, prev, prev2, stamp, grads, row, depth, u, run_end, &mut n_samples)
                        }
                        (_, true) => {
                            slab.composite_run::<4, true>(links, prev, prev2, stamp, grads, row, depth, u, run_end, &mut n_samples)
                        }
                    };
                }
                // The rays that leave the volume through a side face between the slices.
                let spans = [runs.span, slice_runs[zp].span].into_iter().flatten();
                let span = spans.reduce(|a, b| (a.0.min(b.0), a.1.max(b.1))).and_then(|(a, b)| match reach {
                    None => Some((a, b)),
                    Some((lo, hi)) => {
                        let (a, b) = (lo.floor().max(a as f64), hi.ceil().min(b as f64));
                        (a <= b).then_some((a as usize, b as usize))
                    }
                });
                let all_clear = table.all_clear() && second.as_ref().is_none_or(|(t2, _)| t2.all_clear());
                if let Some(span) = span.filter(|_| !all_clear) {
                    slab.composite_exits(k, links, prev, prev2, stamp, grads, row, depth, span, back_span, run_span, &mut n_samples);
                }
            }
        }
        for r in (0..band_rows).filter(|&r| mip && live(r)) {
            let vf = (v_first + r) as f64;
            let (row, depth) = (&mut band_rgba[r * iw..(r + 1) * iw], &mut band_depth[r * iw..(r + 1) * iw]);
            let RowState { max_level, max_z, .. } = &states[r];
            for u in 0..iw {
                if max_level[u].is_finite() {
                    let value = level_to_value(max_level[u]);
                    let a = tf.opacity(value).min(1.0) as f32;
                    let c = tf.color(value);
                    row[u] = [c[0] as f32 * a, c[1] as f32 * a, c[2] as f32 * a, a];
                    if a > 0.0 {
                        depth[u] = fac.depth(u as f64, vf, max_z[u] as f64) as f32;
                    }
                }
            }
        }
        samples.fetch_add(n_samples, Ordering::Relaxed);
        slabs_leapt.fetch_add(n_leapt, Ordering::Relaxed);
        pairs.fetch_add(n_pairs, Ordering::Relaxed);
    })?;

    let mut frame = warp(&inter, &fac, w, h, settings.warp)?;
    frame.stats = FrameStats {
        renderer: RENDERER.name.into(),
        seconds: start.elapsed().as_secs_f64(),
        counters: vec![
            ("samples".into(), samples.load(Ordering::Relaxed) as f64),
            ("runs_leapt".into(), slabs_leapt.load(Ordering::Relaxed) as f64),
            ("row_slice_pairs".into(), pairs.load(Ordering::Relaxed) as f64),
            ("supersampling".into(), fac.ratio),
            ("intermediate_pixels".into(), ((u_clip_hi + 1 - u_clip_lo) * (v_clip_hi + 1 - v_clip_lo)) as f64),
            ("intermediate_pixels_read".into(), footprint.count as f64),
            ("table_levels".into(), n_levels as f64),
            ("principal_axis".into(), fac.perm[2] as f64),
        ],
        notes: prep.take_lean_note().into_iter().collect(),
        nodes: vec![],
    };
    Ok(frame)
}

/// The automatic coarsening: 4 or 2 where an output pixel spans at least that many voxels
/// (the smallest spacing) at the volume's centre, else 1. The pixel's span there: the
/// distance between the rays through the central pixel and its neighbour, each at its
/// point nearest the centre.
fn auto_coarsening(input: &Input, rays: &RayGenerator) -> Result<usize> {
    let prep = input.prepared;
    let index_to_world = crate::geometry::index_to_world(input.node_to_world, prep.affine)?;
    let centre = index_to_world.transform_point3(glam::DVec3::from(prep.dims.map(|d| (d as f64 - 1.0) / 2.0)));
    let (w, h) = rays.size();
    let nearest = |x: f64| {
        let r = rays.ray(x, 0.5 * h as f64);
        r.origin + r.dir * (centre - r.origin).dot(r.dir) / r.dir.length_squared()
    };
    let pixel = (nearest(0.5 * w as f64 + 1.0) - nearest(0.5 * w as f64)).length();
    let voxel = (0..3).map(|a| index_to_world.col(a).truncate().length()).fold(f64::INFINITY, f64::min);
    let per_pixel = pixel / voxel;
    Ok(if per_pixel >= 4.0 {
        4
    } else if per_pixel >= 2.0 {
        2
    } else {
        1
    })
}

/// `n` copies of `v`, written in parallel. `vec![0.0; n]` would map the zero page, and the
/// first write to each of its pages then faults again and flushes every core's TLB: 13 %
/// of a clinical-size frame's time went there (60 MB of intermediate image). (Keeping the
/// last frame's buffers for the next saved under 2 % of a clinical frame and added their
/// 84 MB to the peak while the viewer's previews made their coarse copies.)
fn filled<T: Copy + Send + Sync>(n: usize, v: T) -> Vec<T> {
    let mut out = Vec::with_capacity(n);
    out.par_extend(rayon::iter::repeat_n(v, n));
    out
}

/// The overlapped map's variant whose blocks hold the front samples of a run of pixels
/// whose sideways step from the back sample to the front one runs from `dxo_first` to
/// `dxo_last` (linear between) and whose row step is `dyo`: the blocks reach one voxel
/// beyond the back samples on one side (variant 1: left, x − 1; 0: right) and one row
/// either way. None where a step leaves that reach (perspective rays far off the principal
/// axis) or the side changes within the run. A parallel view always has one (|sx|, |sy| ≤
/// 1; the tolerance keeps exactly 45° views leaping through rounding).
#[inline]
fn leap_variant(dxo_first: f64, dxo_last: f64, dyo: f64) -> Option<usize> {
    const REACH: f64 = 1.0 + 1e-9;
    let ok = dxo_first.abs() <= REACH && dxo_last.abs() <= REACH && dyo.abs() <= REACH && (dxo_first < 0.0) == (dxo_last < 0.0);
    ok.then_some(usize::from(dxo_first < 0.0))
}
