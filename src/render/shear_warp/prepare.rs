//! The preparation shear-warp keeps per volume: the values quantised to u16 over the
//! volume's range, and per principal axis the slices permuted so that axis is z (built on
//! first use), with their min-max maps. Nothing here depends on the view or the transfer
//! function (the transparent-block masks are cached per transfer-function test).

use super::minmax::{ClearMask, OverlappedMap, ScanlineMap};
use super::preint::ClearQuanta;
use anyhow::Result;
use glam::DMat4;
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use volterra_formats::{Limits, Volume, VoxelData};

/// The volume resampled for one principal axis: permuted so that axis is z, x fastest,
/// values as u16 quanta of the volume's value range; with its min-max maps, built on
/// first use.
pub(super) struct Axis {
    pub(super) dims: [usize; 3],
    pub(super) data: Vec<u16>,
    /// Min-max maps by block size n.
    overlapped: Mutex<HashMap<usize, Arc<OverlappedMap>>>,
    scanline: Mutex<HashMap<usize, Arc<ScanlineMap>>>,
}

impl Axis {
    pub(super) fn overlapped(&self, n: usize) -> Arc<OverlappedMap> {
        self.overlapped.lock().unwrap().entry(n).or_insert_with(|| Arc::new(OverlappedMap::new(&self.data, self.dims, n))).clone()
    }
    pub(super) fn scanline(&self, n: usize) -> Arc<ScanlineMap> {
        self.scanline.lock().unwrap().entry(n).or_insert_with(|| Arc::new(ScanlineMap::new(&self.data, self.dims, n))).clone()
    }
}

/// A transparent-block mask and the key of the transparency test it was made under.
type KeyedMask = (u64, Arc<ClearMask>);

/// Which permuted copies are kept once a view has used their axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum KeepAxes {
    /// Every axis's, while the memory limit leaves room (`room_for_another_copy`): a view
    /// turning across 45° then needs no new slices.
    WhereMemoryAllows,
    /// One axis's at a time: each new axis's copy replaces the others, written into the
    /// memory of one no frame holds (the lean path, which tests force).
    #[cfg(test)]
    One,
}

/// A volume prepared for shear-warp rendering. Everything here depends only on the
/// volume: transfer-function and view changes reuse it. No quantised copy of the whole
/// volume is kept beside it: each principal axis's slices are quantised as they are
/// permuted, straight from the volume (which the scene holds anyway), so a view costs the
/// volume, one u16 copy and its min-max map.
pub struct Prepared {
    pub(super) dims: [usize; 3],
    /// Real-world value range mapped onto quanta 0..65535.
    pub lo: f64,
    pub hi: f64,
    volume: Arc<Volume>,
    /// The permuted copies made so far, by principal axis (see `axis`).
    axes: Mutex<[Option<Arc<Axis>>; 3]>,
    pub(super) affine: DMat4,
    /// Checked before each permuted copy is made.
    pub(super) limits: Limits,
    /// Each principal axis's transparent-block mask (its overlapped map's test under the
    /// last transfer function used), by (axis, block size): (the test's key, the mask).
    /// Kept when the axis's copy and map are replaced (a mask is 1/8 of its map: 6.5 MB
    /// at 512 × 512 × 400), so a view turning back to an axis seen before needs no map.
    clear_masks: Mutex<HashMap<(usize, usize), KeyedMask>>,
    /// Coarser copies made so far (voxels averaged 2³, 4³), see `coarser`.
    coarse: Mutex<[Option<Arc<Prepared>>; 2]>,
    /// Which axes' copies are kept (tests force the lean path).
    keep_axes: KeepAxes,
    /// Set when a turn replaced the copies kept for other axes because another would not
    /// fit the memory limit; the next frame reports it (`take_lean_note`).
    lean_note: Mutex<Option<String>>,
}

impl Prepared {
    /// Prepares a copy of `volume`, within `limits` (`--max-memory`); `shared` avoids the
    /// copy.
    pub fn new(volume: &Volume, limits: &Limits) -> Result<Prepared> {
        limits.check(
            Path::new("shear-warp"),
            "a copy of the volume",
            &[volume.voxel_count() as u64, volume.data.scalar_type().size() as u64],
        )?;
        Prepared::shared(Arc::new(volume.clone()), limits)
    }

    /// Prepares `volume`, kept shared with its other holders (the scene).
    pub fn shared(volume: Arc<Volume>, limits: &Limits) -> Result<Prepared> {
        let (lo, hi) = volume.value_range().unwrap_or((0.0, 1.0));
        let hi = if hi > lo { hi } else { lo + 1.0 };
        Ok(Prepared {
            dims: volume.dims,
            lo,
            hi,
            affine: crate::geometry::affine_matrix(&volume.affine),
            volume,
            axes: Mutex::new([None, None, None]),
            clear_masks: Mutex::default(),
            limits: *limits,
            coarse: Mutex::default(),
            keep_axes: KeepAxes::WhereMemoryAllows,
            lean_note: Mutex::default(),
        })
    }

    /// The volume with its real values averaged over blocks of `factor`³ voxels (2 or 4;
    /// an axis shorter than the factor is kept whole), prepared and kept: made on first
    /// use straight from the volume, its voxel centres at its blocks' centres. At 4 it
    /// holds 1/64 of the voxels (as f32: 1/32 of an int16 volume's bytes), so all three
    /// of its permuted copies are kept and a turn of the view needs no new slices.
    pub(super) fn coarser(&self, factor: usize) -> Result<Arc<Prepared>> {
        let slot = match factor {
            2 => 0,
            4 => 1,
            _ => anyhow::bail!("shear-warp: volumes are made coarser by 2 or 4, not {factor}"),
        };
        let mut coarse = self.coarse.lock().unwrap();
        if let Some(p) = &coarse[slot] {
            return Ok(p.clone());
        }
        let v = &*self.volume;
        let f = v.dims.map(|d| if d >= factor { factor } else { 1 });
        let dims: [usize; 3] = std::array::from_fn(|a| v.dims[a] / f[a]);
        let count = dims.iter().product::<usize>();
        self.limits.check(Path::new("shear-warp"), "a coarser copy of the volume", &[count as u64, 4])?;
        // The rescale is linear: the mean of real values is the real value of the mean.
        let data: Vec<f32> = match &v.data {
            VoxelData::U8(d) => block_means(v.dims, f, dims, |i| d[i] as f64),
            VoxelData::I16(d) => block_means(v.dims, f, dims, |i| d[i] as f64),
            VoxelData::U16(d) => block_means(v.dims, f, dims, |i| d[i] as f64),
            VoxelData::F32(d) => block_means(v.dims, f, dims, |i| d[i] as f64),
            other => block_means(v.dims, f, dims, |i| other.stored(i)),
        }
        .into_iter()
        .map(|m| v.rescale.apply(m) as f32)
        .collect();
        // Coarse index c is fine index f·c + (f − 1)/2: the block's centre.
        let mut affine = v.affine;
        for row in affine.iter_mut().take(3) {
            let offset: f64 = (0..3).map(|a| row[a] * (f[a] as f64 - 1.0) / 2.0).sum();
            for (a, fa) in f.iter().enumerate() {
                row[a] *= *fa as f64;
            }
            row[3] += offset;
        }
        let volume = Volume::new(dims, affine, VoxelData::F32(data));
        let p = Arc::new(Prepared::shared(Arc::new(volume), &self.limits)?);
        coarse[slot] = Some(p.clone());
        Ok(p)
    }

    /// The transparent-block mask of principal axis `axis`'s size-n overlapped map under
    /// `clear` (`map` makes the map where the mask must be built); rebuilt only when the
    /// test changes (a new transfer function), never for a new view, nor when the view
    /// turns back to an axis whose copy was replaced meanwhile (512 × 512 × 400, 2 cores,
    /// each measured alone: the map 86–98 ms, the mask 13–18 ms).
    pub(super) fn clear_mask(
        &self,
        axis: usize,
        n: usize,
        clear: &ClearQuanta,
        map: impl FnOnce() -> Arc<OverlappedMap>,
    ) -> Arc<ClearMask> {
        // Held while a mask is built, so frames drawn at once build it once.
        let mut masks = self.clear_masks.lock().unwrap();
        match masks.get(&(axis, n)) {
            Some((key, mask)) if *key == clear.key => mask.clone(),
            _ => {
                let mask = Arc::new(map().clear_mask(|mm| clear.clear(mm.min, mm.max)));
                masks.insert((axis, n), (clear.key, mask.clone()));
                mask
            }
        }
    }

    /// Voxel i's value as a u16 quantum of [lo, hi].
    #[inline]
    fn quantum(&self, i: usize) -> u16 {
        self.quantum_of(self.volume.data.stored(i))
    }

    /// The quantum of stored value `stored` (before the rescale).
    #[inline]
    fn quantum_of(&self, stored: f64) -> u16 {
        ((self.volume.rescale.apply(stored) - self.lo) * (65535.0 / (self.hi - self.lo))).round().clamp(0.0, 65535.0) as u16
    }

    /// The slices along `perm[2]`, quantised and permuted once and kept (checked against
    /// the memory limit the first time). The copy is kept beside those of the other axes
    /// a view has used while the memory limit leaves room (`room_for_another_copy`), as
    /// VTK keeps its volume whatever the view: a clinical CT then costs itself, three u16
    /// copies and their maps — 512 × 512 × 400 int16: a peak of 827–830 MiB measured
    /// (`bench clinical`), where VTK's fixed-point mapper with nibabel peaks at 1.41–1.48
    /// GiB — and a turn across
    /// 45° costs a further frame, not a new copy (0.07–0.12 s) and map (0.09–0.10 s). Where
    /// it does not fit, the new copy replaces the others (the lean path: the volume, one
    /// copy and its map), written into the memory of one no frame holds, and the frame says
    /// so.
    pub(super) fn axis(&self, perm: [usize; 3]) -> Result<Arc<Axis>> {
        let mut axes = self.axes.lock().unwrap();
        if let Some(a) = &axes[perm[2]] {
            return Ok(a.clone());
        }
        let bytes = self.volume.voxel_count() as u64 * 2;
        let others = axes.iter().flatten().count();
        let keep = others == 0 || (self.keep_axes == KeepAxes::WhereMemoryAllows && room_for_another_copy(&self.limits, bytes));
        let mut reuse = if keep { None } else { lent_buffer(&mut axes) };
        if !keep && self.keep_axes == KeepAxes::WhereMemoryAllows {
            *self.lean_note.lock().unwrap() = Some(format!(
                "shear-warp: the view turned to another principal axis and its slices ({}) replaced the other axes' copies, \
                 as keeping them too would pass the memory limit ({}): each such turn re-slices the volume",
                volterra_formats::memory::human_bytes(bytes),
                volterra_formats::memory::human_bytes(self.limits.bytes())
            ));
        }
        self.limits.check(Path::new("shear-warp"), "the slices along the viewing axis", &[self.volume.voxel_count() as u64, 2])?;
        let axis = Arc::new({
            let d = self.dims;
            let pd = [d[perm[0]], d[perm[1]], d[perm[2]]];
            // 8- and 16-bit integers (most scans) through a table of every stored value's
            // quantum; other types voxel by voxel.
            let table = |n: usize, stored: &dyn Fn(usize) -> f64| -> Vec<u16> { (0..n).map(|s| self.quantum_of(stored(s))).collect() };
            let data = match &self.volume.data {
                VoxelData::U8(v) => {
                    let t = table(256, &|s| s as f64);
                    permuted(reuse.take(), d, perm, |i| t[v[i] as usize])
                }
                VoxelData::I8(v) => {
                    let t = table(256, &|s| s as u8 as i8 as f64);
                    permuted(reuse.take(), d, perm, |i| t[v[i] as u8 as usize])
                }
                // A fixed-size table: indexing it by a u16 needs no bounds check.
                VoxelData::U16(v) => {
                    let t: Box<[u16; 65536]> = table(65536, &|s| s as f64).try_into().unwrap();
                    permuted(reuse.take(), d, perm, |i| t[v[i] as usize])
                }
                VoxelData::I16(v) => {
                    let t: Box<[u16; 65536]> = table(65536, &|s| s as u16 as i16 as f64).try_into().unwrap();
                    permuted(reuse.take(), d, perm, |i| t[v[i] as u16 as usize])
                }
                _ => permuted(reuse.take(), d, perm, |i| self.quantum(i)),
            };
            Axis { dims: pd, data, overlapped: Mutex::default(), scanline: Mutex::default() }
        });
        axes[perm[2]] = Some(axis.clone());
        Ok(axis)
    }

    /// The note of a turn that took the lean path since the last call, if any.
    pub(super) fn take_lean_note(&self) -> Option<String> {
        self.lean_note.lock().unwrap().take()
    }
}

/// Whether a further permuted copy of `bytes` may be kept beside the others: it, its
/// overlapped map (a quarter of its size) and as much again as the copy for the frame's
/// own buffers must fit in what the memory limit leaves (a set limit counts what the
/// process holds; the default one, the memory available, already leaves it out).
fn room_for_another_copy(limits: &Limits, bytes: u64) -> bool {
    let spare = match limits.max_bytes {
        Some(max) => max.saturating_sub(volterra_formats::memory::in_use()),
        None => limits.bytes(),
    };
    spare >= bytes.saturating_mul(9) / 4
}

/// Drops every kept copy and returns the memory of one that no frame still holds, for the
/// copy replacing them (every axis's copy has the same size): refilled rather than freed
/// and faulted in afresh.
fn lent_buffer(axes: &mut [Option<Arc<Axis>>; 3]) -> Option<Vec<u16>> {
    std::mem::take(axes).into_iter().flatten().filter_map(|old| Arc::try_unwrap(old).ok()).map(|old| old.data).last()
}

/// The means of a volume of `dims` (x fastest; voxel i's value `value_at(i)`) over blocks
/// of `f` voxels per axis, for the `out` blocks per axis that fit (x fastest).
fn block_means(dims: [usize; 3], f: [usize; 3], out: [usize; 3], value_at: impl Fn(usize) -> f64 + Sync) -> Vec<f64> {
    let (nx, ny) = (dims[0], dims[1]);
    let norm = 1.0 / (f[0] * f[1] * f[2]) as f64;
    let mut means = vec![0.0; out.iter().product()];
    means.par_chunks_mut(out[0] * out[1]).enumerate().for_each(|(k, slice)| {
        for (j, row) in slice.chunks_mut(out[0]).enumerate() {
            for kk in k * f[2]..(k + 1) * f[2] {
                for jj in j * f[1]..(j + 1) * f[1] {
                    let line = (kk * ny + jj) * nx;
                    for (i, m) in row.iter_mut().enumerate() {
                        *m += (line + i * f[0]..line + (i + 1) * f[0]).map(&value_at).sum::<f64>();
                    }
                }
            }
            row.iter_mut().for_each(|m| *m *= norm);
        }
    });
    means
}

/// The voxels of a volume of `dims` (x fastest) permuted so that index axis perm[a] is
/// axis a (x fastest), each through `q` (linear index → quantum). The loops read the
/// source in whole rows: where the copy's rows run along the source's x they are copied
/// as they are; otherwise (the principal axis x or y) each source plane that holds whole
/// copy rows is transposed tile by tile (`transpose_tiles`). 512 × 512 × 400 int16 (the
/// CT phantom), 2 cores, release build, into a lent buffer, same runs: principal axis x
/// 294–298 ms (tiles of 32 slices, each reading 64 bytes of every source row) → 107–118
/// ms; y 116–123 ms (written at a stride) → 105–123 ms; z 64–72 ms (a copy, the floor).
fn permuted(buffer: Option<Vec<u16>>, dims: [usize; 3], perm: [usize; 3], q: impl Fn(usize) -> u16 + Sync) -> Vec<u16> {
    let pd = [dims[perm[0]], dims[perm[1]], dims[perm[2]]];
    let stride = [1, dims[0], dims[0] * dims[1]];
    let (sx, sy, sz) = (stride[perm[0]], stride[perm[1]], stride[perm[2]]);
    let slice = pd[0] * pd[1];
    // Every voxel is written below: a lent buffer's old values never show.
    let mut data = match buffer {
        Some(b) if b.len() == slice * pd[2] => b,
        _ => vec![0u16; slice * pd[2]],
    };
    if sz == 1 {
        // Principal axis x: copy row (slice x, row j) runs along the source's stride sx;
        // source plane j (stride sy) holds row j of every slice. Each task takes one
        // source plane, read whole, and writes that row of every slice.
        let mut planes: Vec<Vec<&mut [u16]>> = (0..pd[1]).map(|_| Vec::with_capacity(pd[2])).collect();
        for (r, row) in data.chunks_mut(pd[0]).enumerate() {
            planes[r % pd[1]].push(row);
        }
        planes.into_par_iter().enumerate().for_each(|(j, mut rows)| transpose_tiles(&mut rows, pd[0], |x, c| q(j * sy + x + c * sx)));
    } else if sy == 1 {
        // Principal axis y: within each slice, copy row j runs along the source's z.
        data.par_chunks_mut(slice).enumerate().for_each(|(z, s)| {
            let mut rows: Vec<&mut [u16]> = s.chunks_mut(pd[0]).collect();
            transpose_tiles(&mut rows, pd[0], |y, c| q(z * sz + y + c * sx));
        });
    } else {
        data.par_chunks_mut(slice).enumerate().for_each(|(z, s)| {
            if sx <= sy {
                for y in 0..pd[1] {
                    for x in 0..pd[0] {
                        s[y * pd[0] + x] = q(x * sx + y * sy + z * sz);
                    }
                }
            } else {
                for x in 0..pd[0] {
                    for y in 0..pd[1] {
                        s[y * pd[0] + x] = q(x * sx + y * sy + z * sz);
                    }
                }
            }
        });
    }
    data
}

/// Fills `rows[r][c] = at(r, c)` for c < `cols`, where `at` is read fastest along r
/// (consecutive source voxels): tiles of 32 × 32 are read down r into a buffer and
/// written along c, so both the source and every row are walked in runs of whole cache
/// lines.
fn transpose_tiles(rows: &mut [&mut [u16]], cols: usize, at: impl Fn(usize, usize) -> u16) {
    const T: usize = 32;
    let mut tile = [[0u16; T]; T];
    let n = rows.len();
    let tiles = (0..n).step_by(T).flat_map(|r0| (0..cols).step_by(T).map(move |c0| (r0, c0)));
    for (r0, c0) in tiles {
        let (nr, nc) = (T.min(n - r0), T.min(cols - c0));
        for c in 0..nc {
            for (r, t) in tile.iter_mut().enumerate().take(nr) {
                t[c] = at(r0 + r, c0 + c);
            }
        }
        for (row, t) in rows[r0..r0 + nr].iter_mut().zip(&tile) {
            row[c0..c0 + nc].copy_from_slice(&t[..nc]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use volterra_formats::{Rescale, VoxelData};

    fn volume(dims: [usize; 3], values: Vec<i16>) -> Volume {
        let affine = volterra_formats::volume::identity_affine();
        Volume { rescale: Rescale { slope: 2.0, intercept: -10.0 }, ..Volume::new(dims, affine, VoxelData::I16(values)) }
    }

    /// Every voxel of axis copy `a` (permutation `perm`) is the volume's quantum there.
    fn assert_holds_every_voxel(p: &Prepared, a: &Axis, perm: [usize; 3]) {
        let (dims, pd) = (p.dims, a.dims);
        for k in 0..pd[2] {
            for j in 0..pd[1] {
                for i in 0..pd[0] {
                    let mut idx = [0; 3];
                    (idx[perm[0]], idx[perm[1]], idx[perm[2]]) = (i, j, k);
                    let want = p.quantum(idx[0] + dims[0] * (idx[1] + dims[1] * idx[2]));
                    assert_eq!(a.data[i + pd[0] * (j + pd[1] * k)], want, "perm {perm:?} at {idx:?}");
                }
            }
        }
    }

    #[test]
    fn every_axis_copy_holds_every_voxel_across_tile_edges() {
        // More than one 32-voxel tile along every axis, none a multiple of 32.
        let dims = [70, 37, 33];
        let n = dims[0] * dims[1] * dims[2];
        let v = volume(dims, (0..n).map(|i| ((i * 7919) % 20011) as i16 - 10000).collect());
        let p = Prepared::new(&v, &Default::default()).unwrap();
        for perm in [[1, 2, 0], [2, 0, 1], [0, 1, 2]] {
            let a = p.axis(perm).unwrap();
            assert_holds_every_voxel(&p, &a, perm);
        }
    }

    /// A volume too large to keep every axis's copy: each new axis replaces the last, the
    /// replaced copy lending its memory where no frame holds it, and every voxel is
    /// rewritten. (Addresses are compared only where the buffer is handed over: a freed
    /// block and a fresh one often share an address anyway.)
    #[test]
    fn a_replaced_copy_lends_its_memory_to_the_next_axis_and_every_voxel_is_rewritten() {
        let dims = [37, 41, 35];
        let n = dims[0] * dims[1] * dims[2];
        let v = volume(dims, (0..n).map(|i| ((i * 7919) % 20011) as i16 - 10000).collect());
        let p = Prepared { keep_axes: KeepAxes::One, ..Prepared::new(&v, &Default::default()).unwrap() };
        for perm in [[1, 2, 0], [2, 0, 1], [0, 1, 2], [1, 2, 0]] {
            let a = p.axis(perm).unwrap();
            assert_holds_every_voxel(&p, &a, perm);
        }
        // Only a copy no frame holds is lent; the kept copies are dropped either way.
        let held = p.axis([2, 0, 1]).unwrap();
        let mut axes = std::mem::take(&mut *p.axes.lock().unwrap());
        assert!(lent_buffer(&mut axes).is_none(), "a held copy is not lent");
        assert!(axes.iter().all(Option::is_none));
        let address = held.data.as_ptr();
        let mut axes = [None, Some(held), None];
        let lent = lent_buffer(&mut axes).expect("an unheld copy is lent");
        assert_eq!(lent.as_ptr(), address);
        // The lent buffer itself holds the new copy, every voxel rewritten.
        let q = |i: usize| p.quantum(i);
        let data = permuted(Some(lent), dims, [0, 1, 2], q);
        assert_eq!(data.as_ptr(), address, "written into the lent memory");
        assert_eq!(data, (0..n).map(q).collect::<Vec<_>>());
        // A buffer of another size is not used.
        let small = vec![7u16; 5];
        let small_address = small.as_ptr();
        let fresh = permuted(Some(small), dims, [0, 1, 2], q);
        assert_ne!(fresh.as_ptr(), small_address);
        assert_eq!(fresh, data);
    }

    /// Every axis's copy is kept while the memory limit leaves room for it, its map and the
    /// frame; where it does not, a new axis's copy replaces the others and the next frame
    /// says so, once.
    #[test]
    fn every_axis_copy_is_kept_where_the_limit_leaves_room_else_the_lean_turn_says_so() {
        let dims = [37, 41, 35];
        let n = dims[0] * dims[1] * dims[2];
        let v = volume(dims, (0..n).map(|i| ((i * 7919) % 20011) as i16 - 10000).collect());
        let perms = [[1, 2, 0], [2, 0, 1], [0, 1, 2]];
        let roomy = Prepared::new(&v, &Limits::max(1 << 30)).unwrap();
        for perm in perms {
            assert_holds_every_voxel(&roomy, &roomy.axis(perm).unwrap(), perm);
        }
        assert_eq!(roomy.axes.lock().unwrap().iter().flatten().count(), 3, "every axis's copy kept");
        assert_eq!(roomy.take_lean_note(), None);
        // Room for the volume's copy and one permuted copy, not for two more.
        let tight = Prepared::new(&v, &Limits::max(4 * n as u64)).unwrap();
        tight.axis(perms[0]).unwrap();
        assert_eq!(tight.take_lean_note(), None, "the first copy replaces nothing");
        let a = tight.axis(perms[1]).unwrap();
        assert_holds_every_voxel(&tight, &a, perms[1]);
        assert_eq!(tight.axes.lock().unwrap().iter().flatten().count(), 1, "the lean path keeps one copy");
        let note = tight.take_lean_note().expect("the lean turn is reported");
        assert!(note.contains("replaced the other axes' copies") && note.contains("memory limit"), "{note}");
        assert_eq!(tight.take_lean_note(), None, "reported once");
    }

    /// A view turning back to an axis whose copy (and map) another axis replaced uses the
    /// transparent-block mask kept for it, and draws the same image bit for bit.
    #[test]
    fn a_turn_back_to_an_axis_reuses_its_mask_and_draws_the_same() {
        use crate::render::shear_warp::{render, Input, Settings};
        use crate::scene::{BlendMode, Camera, TransferFunction};
        // A ball of bright values in a dark box: blocks of both kinds.
        let dims = [40, 36, 32];
        let values = (0..dims[0] * dims[1] * dims[2])
            .map(|i| {
                let p = [i % dims[0], i / dims[0] % dims[1], i / (dims[0] * dims[1])];
                let r2: f64 = (0..3).map(|a| (p[a] as f64 - dims[a] as f64 / 2.0).powi(2)).sum();
                if r2 < 100.0 {
                    400 + (i % 7) as i16 * 20
                } else {
                    -50
                }
            })
            .collect();
        let v = volume(dims, values);
        let p = Prepared { keep_axes: KeepAxes::One, ..Prepared::new(&v, &Default::default()).unwrap() };
        let tf = TransferFunction {
            scalar_opacity: vec![[0.0, 0.0], [700.0, 0.4]],
            color: vec![[0.0, 1.0, 0.5, 0.2], [900.0, 1.0, 1.0, 1.0]],
            scalar_opacity_unit_distance: 1.0,
            gradient_opacity: Vec::new(),
        };
        let draw = |dir: [f64; 3]| {
            let cam = Camera {
                position: dir.map(|d| 200.0 * d),
                focal_point: [20.0, 18.0, 16.0],
                view_up: if dir[2].abs() > 0.9 { [0.0, 1.0, 0.0] } else { [0.0, 0.0, 1.0] },
                view_angle: 30.0,
                parallel_projection: false,
                parallel_scale: 1.0,
            };
            let input = Input {
                prepared: &p,
                node_to_world: DMat4::IDENTITY,
                tf: &tf,
                blend: BlendMode::Composite,
                shading: None,
                lights: &[],
                crop: &[],
                second: None,
            };
            render(&input, &cam.rays(48, 48), &Settings::default()).unwrap()
        };
        let mask_of = |axis: usize| p.clear_masks.lock().unwrap().iter().find(|((a, _), _)| *a == axis).map(|(_, (_, m))| m.clone());
        let first = draw([0.2, 0.1, 1.0]);
        assert!(first.rgba.iter().any(|px| px[3] > 0.1), "the ball is drawn");
        let z_mask = mask_of(2).expect("a mask for the z axis");
        draw([1.0, 0.2, 0.1]);
        assert!(p.axes.lock().unwrap()[2].is_none(), "the z axis's copy was replaced");
        assert!(mask_of(0).is_some(), "a mask for the x axis");
        let again = draw([0.2, 0.1, 1.0]);
        assert!(Arc::ptr_eq(&mask_of(2).unwrap(), &z_mask), "the z axis's mask was rebuilt");
        assert!(again.rgba == first.rgba && again.depth == first.depth, "the image differs on the way back");
    }

    /// Issue 45's hard cases for kept copies: a view turning across 45° and back with
    /// every axis's copy kept draws each view as a fresh preparation does, bit for bit; a
    /// transfer-function change keeps the copies (the same memory) and draws as a fresh
    /// preparation under the new one; a memory limit too tight for another copy takes
    /// the lean path, says so on that frame, and draws the same images.
    #[test]
    fn kept_copies_draw_as_fresh_ones_through_turns_tf_changes_and_the_lean_path() {
        use crate::render::shear_warp::{render, Input, Settings};
        use crate::render::Frame;
        use crate::scene::{BlendMode, Camera, TransferFunction, VolumeShading};
        // A shaded shell and a bright core in a dark box, 64 × 60 × 56.
        let dims = [64, 60, 56];
        let values = (0..dims[0] * dims[1] * dims[2])
            .map(|i| {
                let p = [i % dims[0], i / dims[0] % dims[1], i / (dims[0] * dims[1])];
                let r = (0..3).map(|a| (p[a] as f64 - dims[a] as f64 / 2.0).powi(2)).sum::<f64>().sqrt();
                (if r < 6.0 {
                    900.0
                } else if (18.0..22.0).contains(&r) {
                    400.0 + 10.0 * (p[0] % 5) as f64
                } else {
                    -50.0
                }) as i16
            })
            .collect();
        let v = volume(dims, values);
        let tf = |a: f64| TransferFunction {
            scalar_opacity: vec![[0.0, 0.0], [700.0, a], [2000.0, 0.9]],
            color: vec![[0.0, 1.0, 0.5, 0.2], [1800.0, 1.0, 1.0, 1.0]],
            scalar_opacity_unit_distance: 1.0,
            gradient_opacity: Vec::new(),
        };
        let shading = VolumeShading { shade: true, ..Default::default() };
        // Ratio 1 keeps the intermediate image below the tight limit's room.
        let settings = Settings { supersampling: 1.0, ..Default::default() };
        let draw = |p: &Prepared, dir: [f64; 3], tf: &TransferFunction| -> Frame {
            let cam = Camera {
                position: dir.map(|d| 300.0 * d),
                focal_point: [32.0, 30.0, 28.0],
                view_up: if dir[2].abs() > 0.9 { [0.0, 1.0, 0.0] } else { [0.0, 0.0, 1.0] },
                view_angle: 30.0,
                parallel_projection: false,
                parallel_scale: 1.0,
            };
            let input = Input {
                prepared: p,
                node_to_world: DMat4::IDENTITY,
                tf,
                blend: BlendMode::Composite,
                shading: Some(&shading),
                lights: &[],
                crop: &[],
                second: None,
            };
            render(&input, &cam.rays(24, 24), &settings).unwrap()
        };
        let same = |a: &Frame, b: &Frame| a.rgba == b.rgba && a.depth == b.depth;
        let (z_view, x_view) = ([0.2, 0.1, 1.0], [1.0, 0.2, 0.1]);
        let (tf1, tf2) = (tf(0.4), tf(0.1));
        let fresh = |dir: [f64; 3], tf: &TransferFunction| draw(&Prepared::new(&v, &Default::default()).unwrap(), dir, tf);
        let (want_z, want_x, want_z2) = (fresh(z_view, &tf1), fresh(x_view, &tf1), fresh(z_view, &tf2));
        assert!(want_z.rgba.iter().any(|px| px[3] > 0.1) && want_z.rgba.iter().flatten().all(|c| c.is_finite()));

        let roomy = Prepared::new(&v, &Limits::max(1 << 30)).unwrap();
        let first = draw(&roomy, z_view, &tf1);
        assert!(same(&first, &want_z) && first.stats.notes.is_empty());
        assert!(same(&draw(&roomy, x_view, &tf1), &want_x), "the turn to x");
        let z_copy = roomy.axes.lock().unwrap()[2].clone().expect("z's copy kept");
        assert!(same(&draw(&roomy, z_view, &tf1), &want_z), "the turn back to z");
        // A transfer-function change: the same copy, the new function's image.
        assert!(same(&draw(&roomy, z_view, &tf2), &want_z2), "after the transfer function changed");
        assert!(Arc::ptr_eq(&z_copy, roomy.axes.lock().unwrap()[2].as_ref().unwrap()), "the copy was remade");

        // Room for one copy and the frame, not for a second copy: the lean path.
        let copy = 2 * v.voxel_count() as u64;
        let tight = Prepared::new(&v, &Limits::max(2 * copy)).unwrap();
        let f = draw(&tight, z_view, &tf1);
        assert!(same(&f, &want_z) && f.stats.notes.is_empty());
        let f = draw(&tight, x_view, &tf1);
        assert!(same(&f, &want_x), "the lean turn to x");
        assert!(f.stats.notes.iter().any(|n| n.contains("replaced the other axes' copies")), "{:?}", f.stats.notes);
        assert_eq!(tight.axes.lock().unwrap().iter().flatten().count(), 1);
        let f = draw(&tight, z_view, &tf1);
        assert!(same(&f, &want_z), "the lean turn back to z");
    }

    #[test]
    fn values_are_quantised_over_their_real_range_and_slices_permuted_per_axis() {
        let dims = [4, 3, 2];
        let v = volume(dims, (0..24).map(|i| i as i16 * 3).collect());
        let p = Prepared::new(&v, &Default::default()).unwrap();
        // Real values 2·stored − 10: −10 … 128.
        assert_eq!((p.lo, p.hi), (-10.0, 128.0));
        assert_eq!((p.quantum(0), p.quantum(23)), (0, 65535));
        let q = |x: usize, y: usize, z: usize| p.quantum(x + 4 * (y + 3 * z));
        // Principal axis x: permuted (y, z, x); slices of 3 × 2 along x.
        let a = p.axis([1, 2, 0]).unwrap();
        assert_eq!(a.dims, [3, 2, 4]);
        for (x, y, z) in [(0, 0, 0), (3, 2, 1), (1, 2, 0), (2, 0, 1)] {
            assert_eq!(a.data[y + 3 * (z + 2 * x)], q(x, y, z), "({x}, {y}, {z})");
        }
        // Kept: the same slices the second time.
        assert!(Arc::ptr_eq(&a, &p.axis([1, 2, 0]).unwrap()));
        // Principal axis y: permuted (z, x, y).
        let a = p.axis([2, 0, 1]).unwrap();
        assert_eq!(a.dims, [2, 4, 3]);
        for (x, y, z) in [(0, 0, 0), (3, 2, 1), (1, 2, 0), (2, 0, 1)] {
            assert_eq!(a.data[z + 2 * (x + 4 * y)], q(x, y, z), "({x}, {y}, {z})");
        }
        let z = p.axis([0, 1, 2]).unwrap();
        assert_eq!(z.data, (0..24).map(|i| p.quantum(i)).collect::<Vec<_>>());
    }

    /// A coarser copy holds the means of the real values over its blocks (the rescale
    /// applied), an axis shorter than the factor kept whole and a remainder dropped, and
    /// places each coarse voxel at its block's centre in the world.
    #[test]
    fn coarser_copies_average_blocks_and_sit_at_their_centres() {
        let dims = [9, 4, 1];
        let n = dims[0] * dims[1] * dims[2];
        let mut v = volume(dims, (0..n).map(|i| (i * 37 % 101) as i16).collect());
        v.affine = [[0.5, 0.0, 0.0, 10.0], [0.0, 0.0, -2.0, 20.0], [0.0, 1.5, 0.0, -5.0], [0.0, 0.0, 0.0, 1.0]];
        let p = Prepared::new(&v, &Default::default()).unwrap();
        for f in [2usize, 4] {
            let c = p.coarser(f).unwrap();
            assert!(Arc::ptr_eq(&c, &p.coarser(f).unwrap()), "kept");
            let cv = &c.volume;
            assert_eq!(cv.dims, [9 / f, 4 / f, 1]);
            for (ci, cj) in [(0, 0), (9 / f - 1, 4 / f - 1), (1, 0)] {
                let mut sum = 0.0;
                for j in cj * f..(cj + 1) * f {
                    for i in ci * f..(ci + 1) * f {
                        sum += v.value(v.index(i, j, 0));
                    }
                }
                let want = sum / (f * f) as f64;
                let got = cv.value(cv.index(ci, cj, 0));
                assert!((got - want).abs() < 1e-4 * want.abs().max(1.0), "factor {f} block ({ci}, {cj}): {got} vs {want}");
                // The block's centre: fine index (f·c + (f − 1)/2) in both frames.
                let centre = |i: f64, j: f64| v.index_to_world([i, j, 0.0]);
                let fine = centre(f as f64 * ci as f64 + (f as f64 - 1.0) / 2.0, f as f64 * cj as f64 + (f as f64 - 1.0) / 2.0);
                let coarse = cv.index_to_world([ci as f64, cj as f64, 0.0]);
                assert!((0..3).all(|a| (fine[a] - coarse[a]).abs() < 1e-12), "factor {f}: {coarse:?} vs {fine:?}");
            }
        }
        assert!(p.coarser(3).is_err());
    }

    #[test]
    fn a_constant_volume_gets_a_unit_range() {
        let p = Prepared::new(&volume([2, 2, 2], vec![7; 8]), &Default::default()).unwrap();
        assert_eq!((p.lo, p.hi), (4.0, 5.0));
        assert!((0..8).all(|i| p.quantum(i) == 0));
    }
}
