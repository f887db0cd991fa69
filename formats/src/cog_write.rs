//! Cloud-optimised GeoTIFF output, laid out as GDAL's COG driver lays it out, so that a
//! reader fetching byte ranges gets the directories in its first read and the coarsest
//! level next: the header, GDAL's structural metadata ("ghost area"), every directory
//! (full raster first, then the overviews, largest first), then the tiles of the smallest
//! overview, …, the full raster's last, each tile between a 4-byte size leader and a
//! trailer repeating its last 4 bytes. `validate_cloud_optimized_geotiff.py --full-check`
//! accepts it.
//!
//! The product arrives a row of tiles at a time, as the tiled GeoTIFF writer takes it; each
//! row feeds the overviews as it passes (`overview`, GDAL's resampling, cascaded), and
//! every level's tiles are compressed as they fill and kept in an unnamed temporary file
//! beside the output, so that what is held stays a row of tiles a level whatever the
//! raster's size. The directories, which need every tile's size, are written last of all
//! but placed first. The tiff crate's encoder writes each directory after its image's
//! data, so the directories here are encoded by hand.

use crate::atomic::write_atomically;
use crate::error::{FormatError, Result};
use crate::geotiff_write::{compress, cut_tile, geo_tags, needs_bigtiff, BandKind, Strip, StripMut, WriteOptions};
use crate::heightfield::GridGeoref;
use crate::overview::{cog_levels, Downsampler, Resampling};
use rayon::prelude::*;
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::Path;

/// What makes a GeoTIFF a COG, beyond its compression: GDAL's COG options `BLOCKSIZE`,
/// `RESAMPLING` and `OVERVIEWS`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CogLayout {
    /// Tiles of block × block cells (GDAL's default 512).
    pub block: usize,
    /// How each overview is computed from the next larger level (GDAL's default CUBIC).
    pub resampling: Resampling,
    /// Overviews until one fits in a block (`OVERVIEWS=AUTO`), or none (`NONE`).
    pub overviews: bool,
}

/// GDAL's structural metadata, right after the header: it tells GDAL (and the validator)
/// how the file is laid out.
const GHOST: &str = "LAYOUT=IFDS_BEFORE_DATA\nBLOCK_ORDER=ROW_MAJOR\nBLOCK_LEADER=SIZE_AS_UINT4\nBLOCK_TRAILER=LAST_4_BYTES_REPEATED\nKNOWN_INCOMPATIBLE_EDITION=NO\n ";

/// One level of the pyramid being written: its size, the rows of its current row of
/// tiles, and where its tiles went in the spill file.
struct Level {
    size: [usize; 2],
    rows: Strip,
    rows_held: usize,
    rows_done: usize,
    /// (offset in the spill file, length) of each tile, row-major.
    tiles: Vec<(u64, u32)>,
}

/// What every level shares while the pyramid is built.
struct Pyramid<'a> {
    kind: BandKind,
    nodata: Option<f64>,
    opts: &'a WriteOptions,
    block: usize,
    predictor: u16,
    spill: BufWriter<File>,
    spilled: u64,
    path: &'a Path,
}

impl Pyramid<'_> {
    /// Cuts `rows` (whole rows of a level `size[0]` wide, at most a block of them) into
    /// tiles, compresses them in parallel and appends them to the spill file.
    fn spill_row_of_tiles(&mut self, rows: &Strip, width: usize, tiles: &mut Vec<(u64, u32)>) -> Result<()> {
        let (b, spp) = (self.block, self.kind.samples());
        let across = width.div_ceil(b);
        let mut cut: Vec<Strip> = (0..across).map(|_| Strip::default()).collect();
        for (t, tile) in cut.iter_mut().enumerate() {
            cut_tile(rows, tile, self.kind, [width, t * b], [b, b]);
        }
        let (kind, predictor, opts) = (self.kind, self.predictor, self.opts);
        cut.par_iter_mut().for_each(|t| compress(t, kind, predictor, b * spp, opts));
        for t in &cut {
            self.spill.write_all(&t.compressed).map_err(|e| FormatError::io(self.path, e))?;
            tiles.push((self.spilled, t.compressed.len() as u32));
            self.spilled += t.compressed.len() as u64;
        }
        Ok(())
    }

    /// A level's stored samples as the resampler takes them: values, and each one's mask
    /// (1 valid, 0 NoData; for RGBA, its cell's alpha — GDAL's alpha mask band, whose
    /// values weigh the samples).
    fn resampler_input(&self, rows: &Strip, first_sample: usize, n: usize, values: &mut Vec<f64>, valid: &mut Vec<f64>) {
        values.clear();
        valid.clear();
        match self.kind {
            BandKind::F32 => {
                let s = &rows.f32s[first_sample..first_sample + n];
                values.extend(s.iter().map(|&v| v as f64));
                match self.nodata {
                    Some(nd) if nd.is_nan() => valid.extend(s.iter().map(|v| f64::from(u8::from(!v.is_nan())))),
                    Some(nd) => valid.extend(s.iter().map(|&v| f64::from(u8::from(v != nd as f32)))),
                    None => valid.resize(n, 1.0),
                }
            }
            _ => {
                let s = &rows.bytes[first_sample..first_sample + n];
                values.extend(s.iter().map(|&v| v as f64));
                match (self.kind, self.nodata) {
                    (BandKind::Rgba8, _) => valid.extend(s.chunks_exact(4).flat_map(|c| [f64::from(c[3]); 4])),
                    (_, Some(nd)) => valid.extend(s.iter().map(|&v| f64::from(u8::from(v as f64 != nd)))),
                    _ => valid.resize(n, 1.0),
                }
            }
        }
    }

    /// A resampled row stored as the band's samples: f32, or bytes rounded half up and
    /// clamped; NoData where no valid sample contributed (0 without a NoData value).
    fn store_row(&self, values: &[f64], valid: &[bool], into: &mut Strip) {
        let fill = self.nodata.unwrap_or(0.0);
        match self.kind {
            BandKind::F32 => {
                into.f32s.extend(values.iter().zip(valid).map(|(&v, &ok)| if ok { v as f32 } else { fill as f32 }));
            }
            _ => into.bytes.extend(values.iter().zip(valid).map(|(&v, &ok)| {
                if ok {
                    ((v as f32) as f64 + 0.5).floor().clamp(0.0, 255.0) as u8
                } else {
                    fill as u8
                }
            })),
        }
    }
}

/// Hands `rows` (whole rows of `levels[0]`) to that level and what they make down the
/// pyramid: a level spills each row of tiles as it fills, and feeds the next level's
/// resampler a row at a time.
fn feed(p: &mut Pyramid, levels: &mut [Level], down: &mut [Downsampler], rows: &Strip) -> Result<()> {
    let Some((level, coarser)) = levels.split_first_mut() else { return Ok(()) };
    let (w, h) = (level.size[0], level.size[1]);
    let row = w * p.kind.samples();
    let n_rows = match p.kind {
        BandKind::F32 => rows.f32s.len(),
        _ => rows.bytes.len(),
    } / row;
    // The resampler first: it reads the rows before they are spilled.
    if let Some((d, rest)) = down.split_first_mut() {
        let (mut values, mut valid) = (Vec::new(), Vec::new());
        let mut failed = None;
        for r in 0..n_rows {
            p.resampler_input(rows, r * row, row, &mut values, &mut valid);
            d.push(&values, &valid, |_, v, m| {
                if failed.is_some() {
                    return;
                }
                let mut out = Strip::default();
                p.store_row(v, m, &mut out);
                if let Err(e) = feed(p, coarser, rest, &out) {
                    failed = Some(e);
                }
            });
            if let Some(e) = failed.take() {
                return Err(e);
            }
        }
    }
    // Whole rows of tiles go out as they are; a part row waits for the rest.
    if level.rows_held == 0 && (n_rows == p.block || level.rows_done + n_rows == h) {
        p.spill_row_of_tiles(rows, w, &mut level.tiles)?;
        level.rows_done += n_rows;
        return Ok(());
    }
    for r in 0..n_rows {
        match p.kind {
            BandKind::F32 => level.rows.f32s.extend_from_slice(&rows.f32s[r * row..(r + 1) * row]),
            _ => level.rows.bytes.extend_from_slice(&rows.bytes[r * row..(r + 1) * row]),
        }
        level.rows_held += 1;
        if level.rows_held == p.block || level.rows_done + level.rows_held == h {
            p.spill_row_of_tiles(&level.rows, w, &mut level.tiles)?;
            level.rows_done += level.rows_held;
            level.rows_held = 0;
            level.rows.f32s.clear();
            level.rows.bytes.clear();
        }
    }
    Ok(())
}

/// Writes a COG as `geotiff_write::write_band_strips_with` writes a tiled GeoTIFF: `fill`
/// hands over a row of tiles at a time (`layout.block` rows, the last fewer).
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_cog<E: From<FormatError>>(
    path: &Path,
    grid: &GridGeoref,
    kind: BandKind,
    nodata: Option<f64>,
    elevation: bool,
    opts: &WriteOptions,
    layout: CogLayout,
    predictor: u16,
    mut fill: impl FnMut(usize, StripMut) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    let [w, h] = [grid.width, grid.height];
    let spp = kind.samples();
    let sizes: Vec<[usize; 2]> =
        std::iter::once([w, h]).chain(if layout.overviews { cog_levels([w, h], layout.block) } else { Vec::new() }).collect();
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    // Unnamed: it goes when the file is closed, whatever stops the write.
    let spill = tempfile::tempfile_in(dir).map_err(|e| FormatError::io(path, e))?;
    let mut p =
        Pyramid { kind, nodata, opts, block: layout.block, predictor, spill: BufWriter::with_capacity(1 << 20, spill), spilled: 0, path };
    let mut levels: Vec<Level> =
        sizes.iter().map(|&size| Level { size, rows: Strip::default(), rows_held: 0, rows_done: 0, tiles: Vec::new() }).collect();
    let mut down: Vec<Downsampler> = sizes.windows(2).map(|s| Downsampler::new(s[0], s[1], spp, layout.resampling)).collect();
    let mut strip = Strip::default();
    for first in (0..h).step_by(layout.block) {
        strip.fill_rows(kind, first, (h - first).min(layout.block) * w * spp, &mut fill)?;
        feed(&mut p, &mut levels, &mut down, &strip)?;
    }
    drop(strip);
    let mut spill = p.spill.into_inner().map_err(|e| FormatError::io(path, e.into_error()))?;
    let tiles: Vec<&[(u64, u32)]> = levels.iter().map(|l| &l.tiles[..]).collect();
    let ifds = |big: bool| -> Vec<Vec<Entry>> {
        let mut geo = Some(geo_tags(grid, elevation));
        sizes
            .iter()
            .enumerate()
            .map(|(i, &size)| entries(size, i > 0, kind, opts, layout.block, predictor, nodata, geo.take(), big))
            .collect()
    };
    let data_bytes: u64 = levels.iter().flat_map(|l| &l.tiles).map(|&(_, n)| n as u64 + 8).sum();
    let classic_end = data_start(&ifds(false), false) + data_bytes;
    let big = needs_bigtiff(classic_end);
    let ifds = ifds(big);
    write_atomically(path, |out| {
        let io = |e: std::io::Error| FormatError::io(path, e);
        let start = data_start(&ifds, big);
        // Where each tile's data will be: the smallest overview's first.
        let mut offsets: Vec<Vec<u64>> = vec![Vec::new(); tiles.len()];
        let mut at = start;
        for (l, level) in tiles.iter().enumerate().rev() {
            for &(_, n) in level.iter() {
                offsets[l].push(at + 4);
                at += n as u64 + 8;
            }
        }
        // Header, ghost area, directories.
        let ghost = ghost_area();
        let first_ifd = align2(header_len(big) + ghost.len() as u64);
        if big {
            out.write_all(b"II\x2b\x00\x08\x00\x00\x00").map_err(io)?;
            out.write_all(&first_ifd.to_le_bytes()).map_err(io)?;
        } else {
            out.write_all(b"II\x2a\x00").map_err(io)?;
            out.write_all(&(first_ifd as u32).to_le_bytes()).map_err(io)?;
        }
        out.write_all(ghost.as_bytes()).map_err(io)?;
        let mut pos = header_len(big) + ghost.len() as u64;
        if pos < first_ifd {
            out.write_all(&[0]).map_err(io)?;
            pos += 1;
        }
        for (l, e) in ifds.iter().enumerate() {
            let mut e = e.clone();
            set_tile_tables(&mut e, &offsets[l], tiles[l], big);
            let len = ifd_len(&e, big);
            let next = if l + 1 < ifds.len() { pos + len } else { 0 };
            let bytes = encode_ifd(&e, pos, next, big);
            debug_assert_eq!(bytes.len() as u64, len);
            out.write_all(&bytes).map_err(io)?;
            pos += len;
        }
        debug_assert_eq!(pos, start);
        // The tiles, smallest level first, each with its leader and trailer.
        let mut buf = Vec::new();
        for level in tiles.iter().rev() {
            for &(from, n) in level.iter() {
                buf.resize(n as usize, 0);
                spill.seek(SeekFrom::Start(from)).map_err(io)?;
                spill.read_exact(&mut buf).map_err(io)?;
                out.write_all(&n.to_le_bytes()).map_err(io)?;
                out.write_all(&buf).map_err(io)?;
                let mut trailer = [0u8; 4];
                let tail = &buf[buf.len().saturating_sub(4)..];
                trailer[..tail.len()].copy_from_slice(tail);
                out.write_all(&trailer).map_err(io)?;
            }
        }
        Ok(())
    })
    .map_err(E::from)
}

/// GDAL's structural metadata block: its size line, then the metadata.
fn ghost_area() -> String {
    format!("GDAL_STRUCTURAL_METADATA_SIZE={:06} bytes\n{GHOST}", GHOST.len())
}

fn header_len(big: bool) -> u64 {
    if big {
        16
    } else {
        8
    }
}

fn align2(x: u64) -> u64 {
    x + (x & 1)
}

/// Where the first tile's leader goes: after the header, ghost area and directories.
fn data_start(ifds: &[Vec<Entry>], big: bool) -> u64 {
    align2(header_len(big) + ghost_area().len() as u64) + ifds.iter().map(|e| ifd_len(e, big)).sum::<u64>()
}

/// A directory entry: its tag, TIFF type and value (little-endian bytes of `count` items).
#[derive(Debug, Clone)]
struct Entry {
    tag: u16,
    typ: u16,
    count: u64,
    value: Vec<u8>,
}

const SHORT: u16 = 3;
const LONG: u16 = 4;
const ASCII: u16 = 2;
const DOUBLE: u16 = 12;
const LONG8: u16 = 16;
const TILE_OFFSETS: u16 = 324;
const TILE_BYTE_COUNTS: u16 = 325;

fn shorts(tag: u16, v: &[u16]) -> Entry {
    Entry { tag, typ: SHORT, count: v.len() as u64, value: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}

fn long(tag: u16, v: u32) -> Entry {
    Entry { tag, typ: LONG, count: 1, value: v.to_le_bytes().to_vec() }
}

fn doubles(tag: u16, v: &[f64]) -> Entry {
    Entry { tag, typ: DOUBLE, count: v.len() as u64, value: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}

/// Offsets (LONG, or LONG8 in a BigTIFF) of `n` items.
fn offsets_entry(tag: u16, v: impl Iterator<Item = u64>, big: bool) -> Entry {
    let value: Vec<u8> = if big { v.flat_map(|x| x.to_le_bytes()).collect() } else { v.flat_map(|x| (x as u32).to_le_bytes()).collect() };
    let item = if big { 8 } else { 4 };
    Entry { tag, typ: if big { LONG8 } else { LONG }, count: (value.len() / item) as u64, value }
}

/// One level's directory, its tile tables filled with zeros (`set_tile_tables` fills them).
#[allow(clippy::too_many_arguments)]
fn entries(
    [w, h]: [usize; 2],
    overview: bool,
    kind: BandKind,
    opts: &WriteOptions,
    block: usize,
    predictor: u16,
    nodata: Option<f64>,
    geo: Option<crate::geotiff_write::GeoTags>,
    big: bool,
) -> Vec<Entry> {
    let spp = kind.samples();
    let n_tiles = w.div_ceil(block) * h.div_ceil(block);
    let mut e = Vec::new();
    if overview {
        e.push(long(254, 1)); // NewSubfileType: a reduced image
    }
    e.push(long(256, w as u32));
    e.push(long(257, h as u32));
    e.push(shorts(258, &vec![if kind == BandKind::F32 { 32 } else { 8 }; spp]));
    e.push(shorts(259, &[opts.compression.tiff_code()]));
    e.push(shorts(262, &[if spp >= 3 { 2 } else { 1 }]));
    e.push(shorts(277, &[spp as u16]));
    e.push(shorts(284, &[1]));
    if predictor != 1 {
        e.push(shorts(317, &[predictor]));
    }
    e.push(long(322, block as u32));
    e.push(long(323, block as u32));
    e.push(offsets_entry(TILE_OFFSETS, std::iter::repeat_n(0, n_tiles), big));
    e.push(offsets_entry(TILE_BYTE_COUNTS, std::iter::repeat_n(0, n_tiles), big));
    if kind == BandKind::Rgba8 {
        e.push(shorts(338, &[2])); // unassociated alpha
    }
    e.push(shorts(339, &vec![if kind == BandKind::F32 { 3 } else { 1 }; spp]));
    if let Some(g) = geo {
        e.push(doubles(33550, &g.pixel_scale));
        e.push(doubles(33922, &g.tiepoint));
        e.push(shorts(34735, &g.keys));
    }
    if let Some(v) = nodata {
        let mut s = format!("{v}").into_bytes();
        s.push(0);
        e.push(Entry { tag: 42113, typ: ASCII, count: s.len() as u64, value: s });
    }
    e
}

/// Fills a directory's tile tables: where each tile's data is, and its length.
fn set_tile_tables(e: &mut [Entry], offsets: &[u64], tiles: &[(u64, u32)], big: bool) {
    for entry in e.iter_mut() {
        match entry.tag {
            TILE_OFFSETS => *entry = offsets_entry(TILE_OFFSETS, offsets.iter().copied(), big),
            TILE_BYTE_COUNTS => *entry = offsets_entry(TILE_BYTE_COUNTS, tiles.iter().map(|&(_, n)| n as u64), big),
            _ => {}
        }
    }
}

/// A directory's bytes: its entries, the next directory's offset, then the values too
/// long to sit in an entry, each on an even offset.
fn ifd_len(e: &[Entry], big: bool) -> u64 {
    let (count, entry, next, inline) = if big { (8, 20, 8, 8) } else { (2, 12, 4, 4) };
    let mut len = count + entry * e.len() as u64 + next;
    for x in e {
        if x.value.len() as u64 > inline {
            len = align2(len) + x.value.len() as u64;
        }
    }
    align2(len)
}

fn encode_ifd(e: &[Entry], at: u64, next: u64, big: bool) -> Vec<u8> {
    let (count, entry, next_len, inline) = if big { (8u64, 20u64, 8u64, 8usize) } else { (2, 12, 4, 4) };
    let mut head = Vec::new();
    let mut tail = Vec::new();
    let mut tail_at = count + entry * e.len() as u64 + next_len;
    if big {
        head.extend_from_slice(&(e.len() as u64).to_le_bytes());
    } else {
        head.extend_from_slice(&(e.len() as u16).to_le_bytes());
    }
    for x in e {
        head.extend_from_slice(&x.tag.to_le_bytes());
        head.extend_from_slice(&x.typ.to_le_bytes());
        if big {
            head.extend_from_slice(&x.count.to_le_bytes());
        } else {
            head.extend_from_slice(&(x.count as u32).to_le_bytes());
        }
        if x.value.len() <= inline {
            let mut v = x.value.clone();
            v.resize(inline, 0);
            head.extend_from_slice(&v);
        } else {
            if tail_at & 1 == 1 {
                tail.push(0);
                tail_at += 1;
            }
            let off = at + tail_at;
            if big {
                head.extend_from_slice(&off.to_le_bytes());
            } else {
                head.extend_from_slice(&(off as u32).to_le_bytes());
            }
            tail.extend_from_slice(&x.value);
            tail_at += x.value.len() as u64;
        }
    }
    if big {
        head.extend_from_slice(&next.to_le_bytes());
    } else {
        head.extend_from_slice(&(next as u32).to_le_bytes());
    }
    head.extend_from_slice(&tail);
    if head.len() & 1 == 1 {
        head.push(0);
    }
    head
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geotiff_write::tests::grid;

    #[test]
    fn a_cog_reads_back_with_its_overviews_and_directories_first() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (300, 170);
        let cells: Vec<f32> = (0..w * h).map(|i| ((i % w) as f32 * 0.1).sin() * 50.0 + (i / w) as f32).collect();
        let opts = WriteOptions::from_cog_creation_options(&["BLOCKSIZE=64".into()]).unwrap();
        let path = dir.path().join("c.tif");
        crate::geotiff_write::write_band_strips_with::<FormatError>(
            &path,
            &grid(w, h),
            BandKind::F32,
            Some(-9999.0),
            true,
            64,
            &opts,
            |first, s| {
                let StripMut::F32(s) = s else { unreachable!() };
                s.copy_from_slice(&cells[first * w..first * w + s.len()]);
                Ok(())
            },
        )
        .unwrap();
        let hf = crate::geotiff::read_geotiff(&path, &Default::default()).unwrap();
        assert_eq!((hf.width, hf.height), (w, h));
        assert_eq!(hf.elevations, cells);
        assert_eq!(hf.crs.epsg, Some(32610));
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[8..38], b"GDAL_STRUCTURAL_METADATA_SIZE=");
        assert_eq!(u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as u64, align2(8 + ghost_area().len() as u64));
        // 300×170 in blocks of 64: overviews 150×85, 75×42, 37×21; each the resampling of
        // the one before, as read back.
        let sizes = cog_levels([w, h], 64);
        assert_eq!(sizes, vec![[150, 85], [75, 42], [37, 21]]);
        let mut larger = ([w, h], cells.clone());
        for (k, size) in sizes.iter().enumerate() {
            let opts = crate::geotiff::GeoTiffOptions { level: Some(k + 1), ..Default::default() };
            let o = crate::geotiff::read_geotiff_with(&path, &opts, &Default::default()).unwrap();
            assert_eq!([o.width, o.height], *size);
            let mut d = Downsampler::new(larger.0, *size, 1, Resampling::Cubic);
            let mut want = Vec::new();
            for row in larger.1.chunks_exact(larger.0[0]) {
                let v: Vec<f64> = row.iter().map(|&x| x as f64).collect();
                d.push(&v, &vec![1.0; v.len()], |_, v, _| want.extend(v.iter().map(|&x| x as f32)));
            }
            assert_eq!(o.elevations, want, "overview {}", k + 1);
            larger = ([o.width, o.height], o.elevations);
        }
    }
}
