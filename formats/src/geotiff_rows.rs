//! A GeoTIFF elevation raster read a row at a time, not held: for a renderer that copies
//! the heights into its own store (the GPU terrain ray-caster's textures), so that a DEM
//! is held once, there, rather than twice.
//!
//! Rows are decoded a row of chunks (tiles or strips) at a time, and of that row only the
//! chunks that hold the columns asked for: reading the raster row by row, in either
//! direction, and in column bands, decodes each chunk about once. The decoded chunks of
//! one chunk row are kept (for a tiled raster, a tile's height times the columns asked
//! for; for a stripped one, a strip).
//!
//! Samples are converted as `read_geotiff` converts them (vertical unit, the file's NoData
//! value and values out of f32's range to NaN); a chunk that fails to decode reads as
//! NaN, and the first failure is kept for the caller to report once the rows are read
//! (`failure`): the readers that copy rows are hot loops that return no errors.

use crate::error::{FormatError, Result};
use crate::geotiff::{
    cell_size_metres, open_elevation, read_chunk_at, sample_f64, sample_metres, tiff_err, Chunk, GeoTiffOptions, HeldBytes, Opened,
};
use crate::heightfield::{bilinear_height, summarise, GridGeoref, GridUnits, HeightRows, RowsSummary};
use crate::memory::Limits;
use std::collections::HashMap;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};
use tiff::decoder::Decoder;
use tiff::tags::Tag;

pub struct GeoTiffRows {
    path: PathBuf,
    georef: GridGeoref,
    /// The file's NoData value, where it declares one.
    pub nodata_value: Option<f64>,
    pub notes: Vec<String>,
    /// What `info` shows of the file (as `Heightfield::attributes`).
    pub attributes: Vec<(String, String)>,
    /// The window's first column and row in the level read.
    offset: [u32; 2],
    /// The level's width (chunks are numbered across it) and a chunk's size.
    level_width: u32,
    chunk: [u32; 2],
    nodata: Option<f64>,
    vertical: f64,
    /// The level's directory and the decoder's buffer limit, to open more decoders.
    image_index: usize,
    decoder_bytes: usize,
    held: Mutex<ChunkRow>,
    /// The elevation range and NoData count, from one pass over the rows (on first use).
    summary: OnceLock<RowsSummary>,
}

/// A chunk decoded: its elevations in metres, row by row, and its width in samples.
type DecodedChunk = (Vec<f32>, usize);

/// The decoders and the decoded chunks of one row of chunks.
struct ChunkRow {
    d: Decoder<BufReader<std::fs::File>>,
    /// More decoders of the same level, opened when a row's chunks are first decoded on
    /// several threads (one decoder reads one chunk at a time).
    spare: Vec<Decoder<BufReader<std::fs::File>>>,
    /// The chunk row held, and its chunks by column of chunks: elevations in metres, row by
    /// row, and the chunk's width in samples.
    row: Option<u32>,
    chunks: HashMap<u32, (Vec<f32>, usize)>,
    /// The first decoding failure's one-line message (naming the file).
    failure: Option<String>,
}

impl GeoTiffRows {
    /// Opens the raster (of `opts.extent` only, where given) at the finest level — the full
    /// raster or an overview — whose window fits the memory limit at `held_per_sample`
    /// bytes a sample: what the caller keeps of each sample it reads.
    pub fn open(path: &Path, opts: &GeoTiffOptions, limits: &Limits, held_per_sample: u64) -> Result<GeoTiffRows> {
        Self::open_holding(path, opts, limits, &|samples| samples.saturating_mul(held_per_sample))
    }

    /// As `open`, where the caller holds `held(samples)` bytes for the samples it reads (the
    /// GPU's textures, and its upload's staging and driver memory that do not grow with them).
    pub fn open_holding(path: &Path, opts: &GeoTiffOptions, limits: &Limits, held: HeldBytes) -> Result<GeoTiffRows> {
        let mut o = open_elevation(path, opts, limits, Some(held))?;
        let (cw, ch) = crate::guard::third_party(path, "the TIFF decoder", || Ok(o.d.chunk_dimensions()))?;
        if cw == 0 || ch == 0 {
            return Err(FormatError::invalid(path, "TIFF tiles or strips of size 0"));
        }
        // At most one row of chunks across the level is held, decoded and in metres.
        let across = o.level[0].div_ceil(cw) as u64 * cw as u64;
        limits.check(path, "a row of the raster's tiles or strips", &[across, ch as u64, o.sample_bytes + 4])?;
        let data_type = declared_type(path, &mut o.d, o.sample_bytes)?;
        let attributes = o.attributes(data_type);
        let (w, h) = o.size();
        let Opened { d, level, win, origin, scale, crs, nodata_value, vertical, mut notes, image_index, decoder_bytes, .. } = o;
        let cell_size = cell_size_metres(path, &crs, origin[1], h, scale, &mut notes)?;
        Ok(GeoTiffRows {
            path: path.to_path_buf(),
            georef: GridGeoref {
                width: w as usize,
                height: h as usize,
                cell_size,
                cell_size_native: scale,
                origin,
                crs,
                units: GridUnits::METRES,
            },
            nodata_value,
            notes,
            attributes,
            offset: [win[0], win[1]],
            level_width: level[0],
            chunk: [cw, ch],
            nodata: nodata_value,
            vertical,
            image_index,
            decoder_bytes,
            held: Mutex::new(ChunkRow { d, spare: Vec::new(), row: None, chunks: HashMap::new(), failure: None }),
            summary: OnceLock::new(),
        })
    }

    /// Where the samples lie (the window read, at the level read).
    pub fn georef(&self) -> &GridGeoref {
        &self.georef
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Elevations (metres; NaN for NoData) of `out.len()` samples of row `row` (0 the
    /// northernmost) from column `col`, of the window read. Samples outside the raster,
    /// and those of a chunk that fails to decode, read as NaN (see `failure`).
    pub fn read_row(&self, row: usize, col: usize, out: &mut [f32]) {
        out.fill(f32::NAN);
        if row >= self.georef.height || col >= self.georef.width {
            return;
        }
        let n = out.len().min(self.georef.width - col);
        let [cw, ch] = self.chunk.map(|c| c as usize);
        let y = self.offset[1] as usize + row;
        let x0 = self.offset[0] as usize + col;
        let (chunk_row, y_in) = ((y / ch) as u32, y % ch);
        let mut held = self.held.lock().unwrap_or_else(|p| p.into_inner());
        if held.row != Some(chunk_row) {
            held.chunks.clear();
            held.row = Some(chunk_row);
        }
        let (first, last) = ((x0 / cw) as u32, ((x0 + n - 1) / cw) as u32);
        let missing: Vec<u32> = (first..=last).filter(|tx| !held.chunks.contains_key(tx)).collect();
        if !missing.is_empty() {
            self.decode_chunks(&mut held, chunk_row, &missing);
        }
        let mut x = x0;
        while x < x0 + n {
            let tx = (x / cw) as u32;
            let (samples, width) = &held.chunks[&tx];
            let chunk_x0 = tx as usize * cw;
            let end = (chunk_x0 + cw).min(x0 + n);
            let stop = end.min(chunk_x0 + width);
            let row_start = y_in * width;
            if let Some(cells) = samples.get(row_start + x - chunk_x0..row_start + stop.max(x) - chunk_x0) {
                out[x - x0..x - x0 + cells.len()].copy_from_slice(cells);
            }
            x = end;
        }
    }

    /// Decodes chunks `txs` of chunk row `ty` into `held` — on as many threads as there are
    /// chunks, up to rayon's, each with its own decoder — keeping the first failure.
    fn decode_chunks(&self, held: &mut ChunkRow, ty: u32, txs: &[u32]) {
        use rayon::prelude::*;
        let threads = rayon::current_num_threads().min(txs.len()).max(1);
        while held.spare.len() + 1 < threads {
            match crate::geotiff::reopen(&self.path, self.image_index, self.decoder_bytes) {
                Ok(d) => held.spare.push(d),
                Err(_) => break, // fewer threads, not a failure
            }
        }
        let ChunkRow { d, spare, chunks, failure, .. } = held;
        let mut decoders: Vec<&mut Decoder<BufReader<std::fs::File>>> = std::iter::once(d).chain(spare.iter_mut()).collect();
        let k = decoders.len();
        let decoded: Vec<Vec<(u32, Result<DecodedChunk>)>> = decoders
            .par_iter_mut()
            .enumerate()
            .map(|(i, d)| txs.iter().skip(i).step_by(k).map(|&tx| (tx, self.decode(d, ty, tx))).collect())
            .collect();
        // In column order, so that the failure kept is the same whatever the threads.
        let mut decoded: Vec<_> = decoded.into_iter().flatten().collect();
        decoded.sort_by_key(|(tx, _)| *tx);
        for (tx, r) in decoded {
            match r {
                Ok(c) => {
                    chunks.insert(tx, c);
                }
                Err(e) => {
                    failure.get_or_insert(e.to_string());
                    chunks.insert(tx, (Vec::new(), 0));
                }
            }
        }
    }

    /// Why a chunk failed to decode (one line naming the file), if one did.
    pub fn failure(&self) -> Option<String> {
        self.held.lock().unwrap_or_else(|p| p.into_inner()).failure.clone()
    }

    /// The elevation range and NoData count, from one pass over every row, in order (made
    /// on first use and kept: `info`, a view's framing and the terrain's preparation each
    /// need the range). A chunk that fails to decode counts as NoData (see `failure`).
    pub fn summary(&self) -> RowsSummary {
        *self.summary.get_or_init(|| summarise(self))
    }

    /// As `Heightfield::surface_height`: the bilinear elevation at (x, y) metres east and
    /// north of the south-west sample's centre (two rows read).
    pub fn surface_height(&self, x: f64, y: f64) -> Option<f64> {
        let g = &self.georef;
        bilinear_height([g.width, g.height], g.cell_size, x, y, |col, row| {
            let mut z = [0f32];
            self.read_row(row, col, &mut z);
            z[0].is_finite().then_some(z[0] as f64)
        })
    }

    /// Chunk (`tx`, `ty`) of the level decoded into metres, row by row (its width second).
    fn decode(&self, d: &mut Decoder<BufReader<std::fs::File>>, ty: u32, tx: u32) -> Result<(Vec<f32>, usize)> {
        let [cw, _] = self.chunk;
        let Chunk { raw, width: dw, rows: dh, stride } = read_chunk_at(&self.path, d, (tx, ty), (cw, self.level_width.div_ceil(cw)))?;
        let mut out = Vec::with_capacity(dw * dh);
        for r in 0..dh {
            for c in 0..dw {
                out.push(sample_metres(sample_f64(&raw, r * stride + c), self.nodata, self.vertical).unwrap_or(f32::NAN));
            }
        }
        Ok((out, dw))
    }
}

/// The sample type the file declares (SampleFormat and BitsPerSample), as GDAL names it.
fn declared_type(path: &Path, d: &mut Decoder<BufReader<std::fs::File>>, sample_bytes: u64) -> Result<&'static str> {
    let format = d.find_tag_unsigned::<u16>(Tag::SampleFormat).map_err(|e| tiff_err(path, e))?.unwrap_or(1);
    Ok(match (format, sample_bytes) {
        (1, 1) => "uint8",
        (1, 2) => "uint16",
        (1, 4) => "uint32",
        (2, 1) => "int8",
        (2, 2) => "int16",
        (2, 4) => "int32",
        (3, 4) => "float32",
        (3, 8) => "float64",
        _ => return Err(FormatError::unsupported(path, "sample type is not one of int8/16/32, uint8/16/32, float32/64")),
    })
}

/// A GeoTIFF read by windows of tiles or strips, not held.
impl HeightRows for GeoTiffRows {
    fn size(&self) -> [usize; 2] {
        [self.georef.width, self.georef.height]
    }
    fn cell_size(&self) -> [f64; 2] {
        self.georef.cell_size
    }
    fn read_row(&self, row: usize, col: usize, out: &mut [f32]) {
        GeoTiffRows::read_row(self, row, col, out)
    }
    fn failure(&self) -> Option<String> {
        GeoTiffRows::failure(self)
    }
    fn elevation_range(&self) -> Option<(f32, f32)> {
        self.summary().range
    }
}
