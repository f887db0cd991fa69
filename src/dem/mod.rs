//! DEM products as `gdaldem` makes them (GDAL's `gdaldem_lib.cpp`, Horn's 3 × 3 gradient):
//! hillshade, slope and aspect of a heightfield, written as GeoTIFF on the input's grid
//! with its georeferencing. The same window rules as GDAL's: a cell whose 3 × 3 window
//! reaches past the raster's edge, or holds a NoData cell, is NoData in the output (with
//! `compute_edges`: the window is completed — beyond the edge by linear extrapolation
//! 2a − b, a NoData neighbour by the centre — and only a NoData centre stays NoData).
//!
//! Horn's gradient over the window w0..w8 (row by row, north first): x = ((w0 + 2w3 + w6)
//! − (w2 + 2w5 + w8)) / (ewres · xscale), y = ((w6 + 2w7 + w8) − (w0 + 2w1 + w2)) / (nsres
//! · yscale), with nsres negative for a north-up raster, both multiplied by `z`.
//! Slope: atan(√(x² + y²) / 8) in degrees (or 100 · √(x² + y²) / 8 percent). Aspect: the
//! azimuth clockwise from north of the downhill direction, from the unscaled differences
//! (as GDAL: it assumes square cells), NoData where flat (0 with `zero_for_flat`, and then
//! no NoData value at all: edges and voids 0 too, as gdaldem writes them).
//! Hillshade: (sin alt − (y cos az − x sin az) cos alt · z/8) / √(1 + (z/8)² (x² + y²)),
//! as a byte 1 + 254 · that (1 where ≤ 0), 0 for NoData. A geographic DEM (degrees) needs
//! `scale` = 111120 (metres per degree), as with gdaldem's -s. Color-relief: a gdaldem
//! colour file (`parse_palette`) looked up per cell (`color_relief`), interpolated as GDAL
//! does (t between the neighbouring entries, each component truncated after adding 0.45),
//! or the nearest entry, or exact entries only (as GDAL's current source: GDAL 3.6 gives
//! the palette's own values transparent black in that mode, a bug fixed since). Contour
//! lines as `gdal_contour` draws them: `contours`.
//!
//! The rest of gdaldem: Zevenbergen–Thorne's gradient (x = (w3 − w5), y = (w7 − w1), over
//! 2 instead of 8) for slope, aspect and hillshade; multidirectional hillshade (lights from
//! 225°, 270°, 315° and 360° weighted by sin² of the aspect's difference from each) and
//! combined (1 − acos(cos i) · atan(slope) / (π/2)²); TRI (Riley: √Σ(wᵢ − w₄)²; Wilson:
//! the mean |wᵢ − w₄|), TPI (w₄ less its neighbours' mean) and roughness (the window's
//! range), each in GDAL's float order, NoData −9999.

pub mod contours;

use anyhow::{bail, Result};
use std::path::Path;
use volterra_formats::geotiff_write::{default_rows_per_strip, write_band_strips_with, writer_bytes, BandKind, StripMut, WriteOptions};
use volterra_formats::heightfield::{GridGeoref, HeightRows, Heightfield};
use volterra_formats::memory::Limits;

/// Which product.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Product {
    Hillshade,
    Slope,
    Aspect,
    /// Terrain Ruggedness Index (gdaldem TRI; `Options::tri` picks Riley's or Wilson's).
    Tri,
    /// Topographic Position Index: the centre less the mean of its 8 neighbours.
    Tpi,
    /// The largest difference between two cells of the window.
    Roughness,
}

/// The gradient slope, aspect and hillshade use (gdaldem -alg).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GradientAlg {
    /// Horn (1981): the 3 × 3 weighted differences (gdaldem's default).
    #[default]
    Horn,
    /// Zevenbergen & Thorne (1987): the 4 neighbours' central differences (smoother terrain).
    ZevenbergenThorne,
}

/// TRI's formula (gdaldem TRI -alg).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TriAlg {
    /// Riley et al. (1999), for terrestrial use: √(Σ (wᵢ − w₄)²) (gdaldem's default).
    #[default]
    Riley,
    /// Wilson et al. (2007), for bathymetry: the mean of |wᵢ − w₄|.
    Wilson,
}

/// The gradient and TRI's formula that gdaldem's `-alg` (by gdaldem's name) picks, for a
/// product that takes a gradient (slope, aspect, hillshade) or is TRI; None keeps
/// gdaldem's defaults. Other names, and a name for another kind of product, are refused
/// (the message names the choices).
pub fn algorithms(
    alg: Option<&str>,
    gradient_product: bool,
    tri_product: bool,
) -> std::result::Result<(GradientAlg, TriAlg), &'static str> {
    match (alg, gradient_product, tri_product) {
        (None, ..) | (Some("Horn"), true, _) => Ok((GradientAlg::Horn, TriAlg::Riley)),
        (Some("ZevenbergenThorne"), true, _) => Ok((GradientAlg::ZevenbergenThorne, TriAlg::Riley)),
        (Some("Riley"), _, true) => Ok((GradientAlg::Horn, TriAlg::Riley)),
        (Some("Wilson"), _, true) => Ok((GradientAlg::Horn, TriAlg::Wilson)),
        _ => Err("Horn or ZevenbergenThorne for slope, aspect and hillshade; Riley or Wilson for TRI"),
    }
}

/// How hillshade lights the terrain.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Shading {
    /// One light from `azimuth` (gdaldem's default).
    #[default]
    Single,
    /// Four lights (225°, 270°, 315°, 360°) weighted by the aspect (gdaldem
    /// -multidirectional, after USGS OF 92-422).
    MultiDirectional,
    /// Shading and slope combined (gdaldem -combined).
    Combined,
}

/// gdaldem's options for these products, with its defaults.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Vertical exaggeration (gdaldem -z).
    pub z: f64,
    /// Horizontal units per elevation unit (gdaldem -s; 111120 for degrees and metres).
    pub scale: f64,
    /// Light azimuth, degrees clockwise from north (hillshade; gdaldem -az).
    pub azimuth: f64,
    /// Light altitude above the horizon, degrees (hillshade; gdaldem -alt).
    pub altitude: f64,
    /// Slope in percent instead of degrees (gdaldem -p).
    pub percent: bool,
    /// Aspect 0 instead of NoData where flat (gdaldem -zero_for_flat).
    pub zero_for_flat: bool,
    /// Complete windows at the edges and around NoData (gdaldem -compute_edges).
    pub compute_edges: bool,
    /// Slope, aspect and hillshade's gradient (gdaldem -alg).
    pub gradient: GradientAlg,
    /// TRI's formula (gdaldem TRI -alg).
    pub tri: TriAlg,
    /// Hillshade's lighting (gdaldem -multidirectional, -combined).
    pub shading: Shading,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            z: 1.0,
            scale: 1.0,
            azimuth: 315.0,
            altitude: 45.0,
            percent: false,
            zero_for_flat: false,
            compute_edges: false,
            gradient: GradientAlg::Horn,
            tri: TriAlg::Riley,
            shading: Shading::Single,
        }
    }
}

/// A product's cells, row by row from the north, and its NoData value.
pub enum Raster {
    /// Slope and aspect (NoData −9999, as gdaldem writes them).
    F32(Vec<f32>),
    /// Hillshade (NoData 0).
    U8(Vec<u8>),
}

/// The NoData value gdaldem gives each product with options `o`: none for aspect with
/// `-zero_for_flat`, where gdaldem writes 0 for flat, edge and void cells alike and tags no
/// NoData (GDAL 3.6).
pub fn nodata_value(p: Product, o: &Options) -> Option<f64> {
    match p {
        Product::Hillshade => Some(0.0),
        Product::Aspect if o.zero_for_flat => None,
        Product::Slope | Product::Aspect | Product::Tri | Product::Tpi | Product::Roughness => Some(-9999.0),
    }
}

/// What is made of each cell: a product of its 3 × 3 window, or its colour (color-relief,
/// with the NoData value of the DEM the cell's value where it is NoData).
pub enum Op<'a> {
    Product(Product, Options),
    Relief { palette: &'a [PaletteEntry], mode: ColorMode, alpha: bool, nodata_value: Option<f64> },
}

impl Op<'_> {
    /// The output's band.
    pub fn band(&self) -> BandKind {
        match self {
            Op::Product(Product::Hillshade, _) => BandKind::U8,
            Op::Product(..) => BandKind::F32,
            Op::Relief { alpha: true, .. } => BandKind::Rgba8,
            Op::Relief { .. } => BandKind::Rgb8,
        }
    }

    /// The output's NoData value (color-relief has none: NoData cells are coloured).
    pub fn nodata(&self) -> Option<f64> {
        match self {
            Op::Product(p, o) => nodata_value(*p, o),
            Op::Relief { .. } => None,
        }
    }

    /// Refuses options gdaldem refuses, and a raster too small for a window.
    pub fn check(&self, [w, h]: [usize; 2]) -> Result<()> {
        let Op::Product(_, o) = self else { return Ok(()) };
        if w < 3 || h < 3 {
            bail!("a {w}×{h} raster has no 3×3 window");
        }
        for (name, v) in [("z", o.z), ("scale", o.scale), ("azimuth", o.azimuth), ("altitude", o.altitude)] {
            if !v.is_finite() {
                bail!("{name} {v} must be finite");
            }
        }
        if o.scale == 0.0 {
            bail!("scale must not be 0");
        }
        Ok(())
    }
}

/// The product of `hf` (elevations as read; NoData cells flagged), in memory.
pub fn compute(hf: &Heightfield, product: Product, o: &Options) -> Result<Raster> {
    let op = Op::Product(product, *o);
    op.check([hf.width, hf.height])?;
    let rows = InputRows::all(hf);
    Ok(match op.band() {
        BandKind::F32 => {
            let mut out = vec![0f32; hf.width * hf.height];
            fill_rows(&rows, hf.cell_size_native, hf.height, &op, 0, StripMut::F32(&mut out));
            Raster::F32(out)
        }
        _ => {
            let mut out = vec![0u8; hf.width * hf.height];
            fill_rows(&rows, hf.cell_size_native, hf.height, &op, 0, StripMut::U8(&mut out));
            Raster::U8(out)
        }
    })
}

/// gdaldem color-relief of `hf`, in memory: each cell's colour from `palette` (NoData
/// cells looked up by the NoData value, so an "nv" entry colours them and otherwise they
/// take the palette's lowest colour, as in GDAL), RGB or, with `alpha`, RGBA bytes.
pub fn color_relief(hf: &Heightfield, palette: &[PaletteEntry], mode: ColorMode, alpha: bool) -> Vec<u8> {
    let op = Op::Relief { palette, mode, alpha, nodata_value: hf.nodata_value };
    let mut out = vec![0u8; hf.width * hf.height * op.band().samples()];
    fill_rows(&InputRows::all(hf), hf.cell_size_native, hf.height, &op, 0, StripMut::U8(&mut out));
    out
}

/// Writes the product of the rows of `src` (on `grid`, whose NoData cells read as NaN) as
/// a GeoTIFF on that grid, a strip at a time: the rows each strip needs (its own and one
/// either side) are read in order, held only while needed, and its cells computed in
/// parallel, so a DEM of any size takes the memory of a few strips' rows. `rows_done` is
/// told how many output rows are written. What a band holds is checked against `limits`
/// first. A chunk of the input that fails to decode stops the write with its one-line
/// error (no output is left). Returns the valid (not NoData) samples read: 0 says the
/// product is of a DEM with no valid sample.
pub fn write_product(
    src: &dyn HeightRows,
    grid: &GridGeoref,
    op: &Op,
    output: &Path,
    opts: &WriteOptions,
    limits: &Limits,
    rows_done: &dyn Fn(usize),
) -> Result<usize> {
    let [w, _] = src.size();
    let kind = op.band();
    opts.check(kind).map_err(|e| anyhow::anyhow!("{}: {e}", output.display()))?;
    // Tiled, a band is a row of tiles (padded to whole tiles).
    let (rows_per_strip, width) = match opts.tiles {
        Some([tw, th]) => (th, w.div_ceil(tw) * tw),
        None => (default_rows_per_strip(w, kind), w),
    };
    // The input rows of a strip and its neighbours', and the writer's strips.
    let mut held = (rows_per_strip as u64 + 2) * w as u64 * 4 + 2 * writer_bytes(width, kind, rows_per_strip);
    if opts.cog.is_some() {
        // A COG's overviews: a row of tiles a level (together less than the full
        // raster's) and the rows each resampler spans (f64 values and masks, ≤ 9 rows).
        held += (rows_per_strip * width * kind.samples() * 4) as u64 + 9 * 16 * (w * kind.samples()) as u64;
    }
    limits.check(output, "the rows and strips of a band of the product", &[held])?;
    write_product_strips(src, grid, op, output, rows_per_strip, opts, rows_done)
}

/// `write_product` in strips of `rows_per_strip` rows.
fn write_product_strips(
    src: &dyn HeightRows,
    grid: &GridGeoref,
    op: &Op,
    output: &Path,
    rows_per_strip: usize,
    opts: &WriteOptions,
    rows_done: &dyn Fn(usize),
) -> Result<usize> {
    let [w, h] = src.size();
    op.check([w, h])?;
    let kind = op.band();
    let mut input = InputRows { first: 0, n: 0, w, cells: std::borrow::Cow::Owned(Vec::new()), valid: 0 };
    write_band_strips_with(output, grid, kind, op.nodata(), false, rows_per_strip, opts, |first, strip| -> Result<()> {
        let n = match &strip {
            StripMut::F32(s) => s.len(),
            StripMut::U8(s) => s.len(),
        } / (w * kind.samples());
        input.hold(src, first.saturating_sub(1), (first + n + 1).min(h));
        if let Some(why) = src.failure() {
            bail!("{why}");
        }
        fill_rows(&input, grid.cell_size_native, h, op, first, strip);
        rows_done(first + n);
        Ok(())
    })?;
    Ok(input.valid)
}

/// The lowest and highest valid elevation of the rows of `src` (`HeightRows::elevation_range`).
pub fn elevation_range(src: &dyn HeightRows) -> Option<(f64, f64)> {
    src.elevation_range().map(|(lo, hi)| (lo as f64, hi as f64))
}

/// Rows [first, first + n) of a raster `w` samples wide (NaN for NoData), read in order.
struct InputRows<'a> {
    first: usize,
    n: usize,
    w: usize,
    cells: std::borrow::Cow<'a, [f32]>,
    /// The valid (finite) samples of the rows read so far.
    valid: usize,
}

impl InputRows<'_> {
    /// Every row of a heightfield held (its NoData cells hold NaN), not copied.
    fn all(hf: &Heightfield) -> InputRows<'_> {
        let valid = hf.elevations.len() - hf.nodata_count();
        InputRows { first: 0, n: hf.height, w: hf.width, cells: std::borrow::Cow::Borrowed(&hf.elevations), valid }
    }

    /// Holds rows [lo, hi): those it holds already moved to the front, the rest read.
    /// Rows are asked for in order, so each is read once.
    fn hold(&mut self, src: &dyn HeightRows, lo: usize, hi: usize) {
        let w = self.w;
        let keep_from = lo.max(self.first).min(self.first + self.n);
        let kept = (self.first + self.n).min(hi).saturating_sub(keep_from);
        let cells = self.cells.to_mut();
        cells.copy_within((keep_from - self.first) * w..(keep_from - self.first + kept) * w, 0);
        let start = if kept > 0 { keep_from } else { lo };
        cells.resize((hi - start) * w, f32::NAN);
        for r in start + kept..hi {
            let at = (r - start) * w;
            src.read_row(r, 0, &mut cells[at..at + w]);
            self.valid += cells[at..at + w].iter().filter(|v| v.is_finite()).count();
        }
        self.first = start;
        self.n = hi - start;
    }

    fn at(&self, c: usize, r: usize) -> f32 {
        self.cells[(r - self.first) * self.w + c]
    }
}

/// Fills `strip` with output rows from `first` (as many as it holds), computed in parallel
/// from `input`, which holds them and their neighbours; `cell_size` in CRS units (east,
/// north), `h` the raster's rows.
fn fill_rows(input: &InputRows, cell_size: [f64; 2], h: usize, op: &Op, first: usize, strip: StripMut) {
    use rayon::prelude::*;
    let row_len = input.w * op.band().samples();
    match strip {
        StripMut::F32(s) => s.par_chunks_mut(row_len).enumerate().for_each(|(i, row)| {
            row_values(input, cell_size, h, op, first + i, |k, v| row[k] = v as f32);
        }),
        // GDAL writes its float results into a byte band rounded half up (GDALCopyWords:
        // the value plus 0.5, truncated; a libm round() per cell was a sixth of the time).
        StripMut::U8(s) => s.par_chunks_mut(row_len).enumerate().for_each(|(i, row)| {
            row_values(input, cell_size, h, op, first + i, |k, v| row[k] = (v.clamp(0.0, 255.0) + 0.5) as u8);
        }),
    }
}

/// Row `r` of the output, sample by sample through `out(index in the row, value)`.
fn row_values(input: &InputRows, cell_size: [f64; 2], h: usize, op: &Op, r: usize, mut out: impl FnMut(usize, f64)) {
    match op {
        Op::Product(product, o) => product_row(input, cell_size, h, *product, o, r, &mut out),
        Op::Relief { palette, mode, nodata_value, alpha } => {
            let spp = if *alpha { 4 } else { 3 };
            for c in 0..input.w {
                let z = input.at(c, r);
                let v = if z.is_nan() { nodata_value.unwrap_or(f64::NAN) } else { z as f64 };
                let rgba = palette_colour(palette, v, *mode).unwrap_or([0; 4]);
                for (k, &x) in rgba[..spp].iter().enumerate() {
                    out(c * spp + k, x as f64);
                }
            }
        }
    }
}

/// Row `r` of a window product, cell by cell through `out(column, value)`.
fn product_row(
    input: &InputRows,
    cell_size: [f64; 2],
    h: usize,
    product: Product,
    o: &Options,
    r: usize,
    out: &mut impl FnMut(usize, f64),
) {
    let w = input.w;
    let (ewres, nsres) = (cell_size[0], -cell_size[1]);
    let (inv_ew, inv_ns) = (1.0 / (ewres * o.scale), 1.0 / (nsres * o.scale));
    let nodata = |c: usize, r: usize| !input.at(c, r).is_finite();
    // Window sums in f32, in GDAL's order (it sums a float raster's window in float and an
    // integer one's in int32, which f32 matches exactly below 2^24): the same cells give
    // the same bits.
    let at = |c: usize, r: usize| input.at(c, r);
    let (sin_alt, cos_alt) = o.altitude.to_radians().sin_cos();
    let (sin_az, cos_az) = o.azimuth.to_radians().sin_cos();
    // The gradient's weights sum to 8 (Horn) or 2 (Zevenbergen–Thorne).
    let zf = if o.gradient == GradientAlg::Horn { 1.0 / 8.0 } else { 1.0 / 2.0 };
    let out_nodata = nodata_value(product, o).unwrap_or(0.0);
    // Inside the raster the window is its three rows' cells, where all are valid; at the
    // edges and next to NoData, `window`'s rules.
    let row = |r: usize| &input.cells[(r - input.first) * w..(r - input.first + 1) * w];
    let rows = (r >= 1 && r + 1 < h).then(|| (row(r - 1), row(r), row(r + 1)));
    for c in 0..w {
        let inner = match rows {
            Some((n, m, s)) if c >= 1 && c + 1 < w => {
                let win = [n[c - 1], n[c], n[c + 1], m[c - 1], m[c], m[c + 1], s[c - 1], s[c], s[c + 1]];
                win.iter().all(|v| v.is_finite()).then_some(win)
            }
            _ => None,
        };
        let Some(win) = inner.or_else(|| window(c, r, w, h, &nodata, &at, o.compute_edges)) else {
            out(c, out_nodata);
            continue;
        };
        let v = match product {
            Product::Tri | Product::Tpi | Product::Roughness => window_statistic(&win, product, o.tri),
            _ => gradient_product(&win, product, o, [inv_ew, inv_ns], zf, [sin_alt, cos_alt, sin_az, cos_az], out_nodata),
        };
        out(c, v);
    }
}

/// TRI, TPI or roughness of a window, as gdaldem computes them: sums of f32 differences
/// (TRI Wilson, TPI) scaled by 0.125 in f32, Riley's squares summed in f64, the window's
/// range.
fn window_statistic(win: &[f32; 9], product: Product, tri: TriAlg) -> f64 {
    let centre = win[4];
    let around = [win[0], win[1], win[2], win[3], win[5], win[6], win[7], win[8]];
    match (product, tri) {
        (Product::Tri, TriAlg::Wilson) => (around.iter().map(|&v| (v - centre).abs()).fold(0f32, |a, d| a + d) * 0.125f32) as f64,
        (Product::Tri, TriAlg::Riley) => (around.iter().map(|&v| ((v - centre) as f64).powi(2)).sum::<f64>().sqrt() as f32) as f64,
        (Product::Tpi, _) => (centre - around.iter().fold(0f32, |a, &v| a + v) * 0.125f32) as f64,
        _ => {
            let (lo, hi) = win.iter().fold((win[0], win[0]), |(lo, hi), &v| (lo.min(v), hi.max(v)));
            (hi - lo) as f64
        }
    }
}

/// Slope, aspect or hillshade of a window by `o.gradient`: `inv` the inverse of the cell
/// size times the scale (east, north: the latter negative), `zf` the gradient's 1/8 or
/// 1/2, `light` = [sin alt, cos alt, sin az, cos az].
fn gradient_product(
    win: &[f32; 9],
    product: Product,
    o: &Options,
    [inv_ew, inv_ns]: [f64; 2],
    zf: f64,
    light: [f64; 4],
    out_nodata: f64,
) -> f64 {
    let [sin_alt, cos_alt, sin_az, cos_az] = light;
    // West minus east and south minus north (window sums in f32, in GDAL's order).
    let (west_minus_east, south_minus_north) = match o.gradient {
        GradientAlg::Horn => (
            ((win[0] + win[3] + win[3] + win[6]) - (win[2] + win[5] + win[5] + win[8])) as f64,
            ((win[6] + win[7] + win[7] + win[8]) - (win[0] + win[1] + win[1] + win[2])) as f64,
        ),
        GradientAlg::ZevenbergenThorne => ((win[3] - win[5]) as f64, (win[7] - win[1]) as f64),
    };
    let (x, y) = (west_minus_east * o.z * inv_ew, south_minus_north * o.z * inv_ns);
    match product {
        Product::Slope => {
            let g = (x * x + y * y).sqrt() * zf;
            if o.percent {
                100.0 * g
            } else {
                g.atan().to_degrees()
            }
        }
        Product::Aspect => {
            let (dx, dy) = (-west_minus_east, south_minus_north);
            if dx == 0.0 && dy == 0.0 {
                out_nodata
            } else {
                // As GDAL: in f32, the angle from east counter-clockwise made an azimuth.
                let a = (dy.atan2(-dx).to_degrees()) as f32;
                let a = if a > 90.0 { 450.0 - a } else { 90.0 - a };
                if a == 360.0 {
                    0.0
                } else {
                    a as f64
                }
            }
        }
        _ => match o.shading {
            Shading::Single => {
                let cang = (sin_alt - (y * cos_az - x * sin_az) * cos_alt * zf) / (1.0 + zf * zf * (x * x + y * y)).sqrt();
                if cang <= 0.0 {
                    1.0
                } else {
                    1.0 + 254.0 * cang
                }
            }
            Shading::MultiDirectional => {
                // Four lights at the altitude, from 225°, 270°, 315° and 360°, each
                // weighted by sin²(aspect − its azimuth).
                let (xx, yy) = (x * x, y * y);
                let xx_plus_yy = xx + yy;
                if xx_plus_yy == 0.0 {
                    return 1.0 + 254.0 * sin_alt;
                }
                let (s127, c127) = (127.0 * sin_alt, 127.0 * cos_alt * zf);
                let c225 = 127.0 * 225f64.to_radians().cos() * cos_alt * zf;
                let v225 = (s127 + (x - y) * c225).max(0.0);
                let v270 = (s127 - x * c127).max(0.0);
                let v315 = (s127 + (x + y) * c225).max(0.0);
                let v360 = (s127 - y * c127).max(0.0);
                let w225 = 0.5 * xx_plus_yy - x * y;
                let w315 = xx_plus_yy - w225;
                let shade = (w225 * v225 + xx * v270 + w315 * v315 + yy * v360) / xx_plus_yy;
                1.0 + shade / (1.0 + zf * zf * xx_plus_yy).sqrt()
            }
            Shading::Combined => {
                let slope = (x * x + y * y) * zf * zf;
                let cos_i = (sin_alt - (y * cos_az - x * sin_az) * cos_alt * zf) / (1.0 + slope).sqrt();
                let cang =
                    1.0 - cos_i.clamp(-1.0, 1.0).acos() * slope.sqrt().atan() / (std::f64::consts::FRAC_PI_2 * std::f64::consts::FRAC_PI_2);
                if cang <= 0.0 {
                    1.0
                } else {
                    1.0 + 254.0 * cang
                }
            }
        },
    }
}

/// The 3 × 3 window about (c, r), or None where the output is NoData there.
fn window(
    c: usize,
    r: usize,
    w: usize,
    h: usize,
    nodata: &impl Fn(usize, usize) -> bool,
    at: &impl Fn(usize, usize) -> f32,
    compute_edges: bool,
) -> Option<[f32; 9]> {
    if nodata(c, r) {
        return None;
    }
    let centre = at(c, r);
    // With compute_edges, as GDAL completes a window: in the first and last rows the
    // columns beyond the edge repeat the edge column, and the rows beyond are extrapolated
    // from it (2a − b); elsewhere the columns beyond are extrapolated along the row. A
    // NoData cell (or an extrapolation from one) is replaced by the centre.
    let edge_row = r == 0 || r == h - 1;
    let inside = |cc: isize, rr: isize| cc >= 0 && rr >= 0 && (cc as usize) < w && (rr as usize) < h;
    let value = |cc: isize, rr: isize| -> Option<f32> { (!nodata(cc as usize, rr as usize)).then(|| at(cc as usize, rr as usize)) };
    let interpol = |a: Option<f32>, b: Option<f32>| Some(2.0 * a? - b?);
    let mut win = [0.0f32; 9];
    for (k, slot) in win.iter_mut().enumerate() {
        let (dc, dr) = ((k % 3) as isize - 1, (k / 3) as isize - 1);
        let (mut cc, rr) = (c as isize + dc, r as isize + dr);
        if !inside(cc, rr) && !compute_edges {
            return None;
        }
        if edge_row {
            cc = cc.clamp(0, w as isize - 1);
        }
        let v = if inside(cc, rr) {
            value(cc, rr)
        } else if inside(c as isize, rr) {
            // A middle row: beyond the left or right edge.
            interpol(value(c as isize, rr), value(c as isize - dc, rr))
        } else {
            // Beyond the first or last row.
            interpol(value(cc, r as isize), value(cc, r as isize - dr))
        };
        *slot = match v {
            Some(v) => v,
            None if compute_edges => centre,
            None => return None,
        };
    }
    Some(win)
}

/// How color-relief picks a cell's colour (gdaldem's default, -nearest_color_entry,
/// -exact_color_entry).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorMode {
    Interpolate,
    Nearest,
    Exact,
}

/// A palette entry: the value and its colour (RGBA, 0–255).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaletteEntry {
    pub value: f64,
    pub rgba: [i32; 4],
}

/// gdaldem's colour names and their colours.
const NAMED_COLOURS: [(&str, [f32; 3]); 16] = [
    ("white", [1.0, 1.0, 1.0]),
    ("black", [0.0, 0.0, 0.0]),
    ("red", [1.0, 0.0, 0.0]),
    ("green", [0.0, 1.0, 0.0]),
    ("blue", [0.0, 0.0, 1.0]),
    ("yellow", [1.0, 1.0, 0.0]),
    ("magenta", [1.0, 0.0, 1.0]),
    ("cyan", [0.0, 1.0, 1.0]),
    ("aqua", [0.0, 0.75, 0.75]),
    ("grey", [0.75, 0.75, 0.75]),
    ("gray", [0.75, 0.75, 0.75]),
    ("orange", [1.0, 0.5, 0.0]),
    ("brown", [0.75, 0.5, 0.25]),
    ("purple", [0.5, 0.0, 1.0]),
    ("violet", [0.5, 0.0, 1.0]),
    ("indigo", [0.0, 0.5, 1.0]),
];

/// A gdaldem colour file: lines "value R G B [A]" or "value name [A]" (tokens split by
/// spaces, tabs, commas or colons; # and / start comments); the value may be "nv" (the
/// DEM's NoData value; ignored where it has none) or a percentage of the DEM's range of
/// valid elevations, `range()` (asked for only where a percentage is given: a DEM read by
/// rows is read once more for it; a DEM with no valid elevation has none, and then, as
/// gdaldem, every percentage is 0). Sorted by value (stably, as GDAL sorts). GMT .cpt
/// palettes are not read.
pub fn parse_palette(text: &str, nodata_value: Option<f64>, range: impl FnOnce() -> Option<(f64, f64)>) -> Result<Vec<PaletteEntry>> {
    if text.lines().any(|l| l.starts_with('#') && l.contains("COLOR_MODEL")) {
        bail!("GMT .cpt palettes are not read (give 'value R G B' lines)");
    }
    let mut range = Some(range);
    let mut lo_hi = None;
    let mut percent_of = |pct: f64| {
        // No valid elevation: GDAL's min/max computation fails and leaves both 0.
        let (lo, hi) = *lo_hi.get_or_insert_with(|| range.take().and_then(|r| r()).unwrap_or((0.0, 0.0)));
        lo + pct / 100.0 * (hi - lo)
    };
    let mut entries = Vec::new();
    for line in text.lines() {
        let tokens: Vec<&str> = line.split([' ', '\t', ',', ':']).filter(|t| !t.is_empty()).collect();
        if tokens.is_empty() || tokens[0].starts_with('#') || tokens[0].starts_with('/') || tokens.len() < 2 {
            continue;
        }
        let value = if tokens[0].eq_ignore_ascii_case("nv") {
            match nodata_value {
                Some(v) => v,
                None => continue, // as gdaldem: a warning, the entry ignored
            }
        } else if let Some(pct) = tokens[0].strip_suffix('%').filter(|p| !p.is_empty()) {
            let pct: f64 = pct.parse().map_err(|_| anyhow::anyhow!("'{}' is not a percentage", tokens[0]))?;
            if !(0.0..=100.0).contains(&pct) {
                bail!("wrong value for a percentage: {}", tokens[0]);
            }
            percent_of(pct)
        } else {
            tokens[0].parse().map_err(|_| anyhow::anyhow!("'{}' is not a value", tokens[0]))?
        };
        let int = |t: &str| t.parse::<i32>().map_err(|_| anyhow::anyhow!("'{t}' is not a colour component"));
        let rgba = if tokens.len() >= 4 {
            [int(tokens[1])?, int(tokens[2])?, int(tokens[3])?, tokens.get(4).map_or(Ok(255), |t| int(t))?]
        } else {
            let (_, c) = NAMED_COLOURS
                .iter()
                .find(|(n, _)| n.eq_ignore_ascii_case(tokens[1]))
                .ok_or_else(|| anyhow::anyhow!("unknown colour: {}", tokens[1]))?;
            let byte = |f: f32| (255.0 * f) as i32;
            [byte(c[0]), byte(c[1]), byte(c[2]), tokens.get(2).map_or(Ok(255), |t| int(t))?]
        };
        entries.push(PaletteEntry { value, rgba });
    }
    if entries.is_empty() {
        bail!("no colour entries");
    }
    entries.sort_by(|a, b| match (a.value.is_nan(), b.value.is_nan()) {
        (true, false) => std::cmp::Ordering::Less,
        (false, true) => std::cmp::Ordering::Greater,
        _ => a.value.partial_cmp(&b.value).unwrap_or(std::cmp::Ordering::Equal),
    });
    Ok(entries)
}

/// The colour of value `v` (None: transparent black, where exact matching finds none).
fn palette_colour(p: &[PaletteEntry], v: f64, mode: ColorMode) -> Option<[i32; 4]> {
    let mut lower = 0;
    if p[0].value.is_nan() {
        if v.is_nan() {
            return Some(p[0].rgba);
        }
        lower = 1;
    }
    // The first entry not below v (p.len() where every one is).
    let i = lower + p[lower..].partition_point(|e| e.value < v);
    let exact_or = |e: &PaletteEntry| (mode != ColorMode::Exact || e.value == v).then_some(e.rgba);
    if i == 0 || (i == lower && lower == 1) {
        return exact_or(&p[i.min(p.len() - 1)]);
    }
    if i == p.len() {
        return exact_or(&p[i - 1]);
    }
    let (a, b) = (&p[i - 1], &p[i]);
    if a.value == v {
        return Some(a.rgba);
    }
    if b.value == v {
        return Some(b.rgba);
    }
    match mode {
        ColorMode::Exact => None,
        ColorMode::Nearest => Some(if v - a.value < b.value - v { a.rgba } else { b.rgba }),
        ColorMode::Interpolate if a.value.is_nan() => Some(b.rgba),
        ColorMode::Interpolate => {
            let t = (v - a.value) / (b.value - a.value);
            // As GDAL: truncated after adding 0.45.
            Some(std::array::from_fn(|k| ((0.45 + a.rgba[k] as f64 + t * (b.rgba[k] - a.rgba[k]) as f64) as i32).clamp(0, 255)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use volterra_formats::heightfield::Crs;

    #[test]
    fn alg_names_pick_gdaldems_formulas_for_their_products_only() {
        let (gradient, tri) = (true, false);
        assert_eq!(algorithms(None, false, false), Ok((GradientAlg::Horn, TriAlg::Riley)));
        assert_eq!(algorithms(Some("ZevenbergenThorne"), gradient, tri), Ok((GradientAlg::ZevenbergenThorne, TriAlg::Riley)));
        assert_eq!(algorithms(Some("Wilson"), false, true), Ok((GradientAlg::Horn, TriAlg::Wilson)));
        // A TRI formula for slope, a gradient for TRI, an unknown name: refused as gdaldem does.
        assert!(algorithms(Some("Wilson"), gradient, tri).is_err());
        assert!(algorithms(Some("Horn"), false, true).is_err());
        assert!(algorithms(Some("horn"), gradient, tri).is_err());
    }

    /// A plane z = a·x + b·y (x east, y north, metres) on 10 m cells.
    fn plane(a: f64, b: f64) -> Heightfield {
        let (w, h) = (6, 5);
        let elevations = (0..w * h)
            .map(|i| {
                let (c, r) = ((i % w) as f64, (i / w) as f64);
                (a * 10.0 * c + b * 10.0 * (h as f64 - 1.0 - r)) as f32
            })
            .collect();
        Heightfield {
            width: w,
            height: h,
            cell_size: [10.0, 10.0],
            cell_size_native: [10.0, 10.0],
            origin: [500_000.0, 4_000_000.0],
            crs: Crs::local(),
            elevations,
            nodata: Default::default(),
            nodata_value: None,
            notes: vec![],
            attributes: vec![],
            units: volterra_formats::heightfield::GridUnits::METRES,
        }
    }

    fn f32s(r: Raster) -> Vec<f32> {
        match r {
            Raster::F32(v) => v,
            Raster::U8(v) => v.into_iter().map(f32::from).collect(),
        }
    }

    #[test]
    fn a_plane_has_its_slope_and_aspect_and_edges_are_nodata() {
        // Rising 1 m per 10 m eastwards: slope atan(0.1), facing (downhill) west: 270°.
        let hf = plane(0.1, 0.0);
        let slope = f32s(compute(&hf, Product::Slope, &Options::default()).unwrap());
        let aspect = f32s(compute(&hf, Product::Aspect, &Options::default()).unwrap());
        let inner = 6 + 2; // row 1, column 2
        assert!((slope[inner] as f64 - 0.1f64.atan().to_degrees()).abs() < 1e-4, "{}", slope[inner]);
        assert!((aspect[inner] - 270.0).abs() < 1e-4, "{}", aspect[inner]);
        assert_eq!(slope[0], -9999.0, "edges are NoData without compute_edges");
        // Rising northwards: facing south, 180°; percent slope 10.
        let hf = plane(0.0, 0.1);
        assert!((f32s(compute(&hf, Product::Aspect, &Options::default()).unwrap())[inner] - 180.0).abs() < 1e-4);
        let pct = f32s(compute(&hf, Product::Slope, &Options { percent: true, ..Default::default() }).unwrap());
        assert!((pct[inner] - 10.0).abs() < 1e-4);
        // compute_edges: a plane extrapolates exactly, so the edges have its slope too —
        // but for the corners, where GDAL repeats the edge column instead.
        let edges = f32s(compute(&hf, Product::Slope, &Options { compute_edges: true, ..Default::default() }).unwrap());
        let corners = [0, 5, 24, 29];
        assert!(
            edges.iter().enumerate().all(|(i, s)| corners.contains(&i) || (*s as f64 - 0.1f64.atan().to_degrees()).abs() < 1e-4),
            "{edges:?}"
        );
        // Flat: aspect NoData (or 0), hillshade 1 + 254 sin(45°).
        let flat = plane(0.0, 0.0);
        assert_eq!(f32s(compute(&flat, Product::Aspect, &Options::default()).unwrap())[inner], -9999.0);
        assert_eq!(f32s(compute(&flat, Product::Aspect, &Options { zero_for_flat: true, ..Default::default() }).unwrap())[inner], 0.0);
        let hs = f32s(compute(&flat, Product::Hillshade, &Options::default()).unwrap());
        assert_eq!(hs[inner], (1.0 + 254.0 * 45f64.to_radians().sin()).round() as f32);
        assert_eq!(hs[0], 0.0);
    }

    /// A heightfield read row by row that counts each row's reads, and can fail.
    struct Counted<'a> {
        hf: &'a Heightfield,
        reads: Vec<std::sync::atomic::AtomicUsize>,
        fail_at: Option<usize>,
    }

    impl HeightRows for Counted<'_> {
        fn size(&self) -> [usize; 2] {
            self.hf.size()
        }
        fn cell_size(&self) -> [f64; 2] {
            self.hf.cell_size
        }
        fn read_row(&self, row: usize, col: usize, out: &mut [f32]) {
            self.reads[row].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            self.hf.read_row(row, col, out)
        }
        fn failure(&self) -> Option<String> {
            let read = |r: usize| self.reads[r].load(std::sync::atomic::Ordering::Relaxed) > 0;
            self.fail_at.filter(|&r| read(r)).map(|r| format!("dem.tif: tile of row {r} is corrupt"))
        }
    }

    /// A bumpy 41 × 23 DEM with NoData holes inside and on the edges.
    fn bumpy() -> Heightfield {
        let mut hf = plane(0.0, 0.0);
        let (w, h) = (41, 23);
        hf.width = w;
        hf.height = h;
        hf.elevations = (0..w * h).map(|i| ((i % w) as f32 * 0.7).sin() * 40.0 + ((i / w) as f32 * 0.45).cos() * 25.0 + 100.0).collect();
        let holes = |i: usize| [5 * w + 7, 5 * w + 8, 11 * w, 17 * w + 40, 22 * w + 20, 9 * w + 30].contains(&i);
        hf.nodata = (0..w * h).map(holes).collect();
        for (i, z) in hf.elevations.iter_mut().enumerate() {
            if holes(i) {
                *z = f32::NAN;
            }
        }
        hf.nodata_value = Some(-5.0);
        hf
    }

    #[test]
    fn products_written_strip_by_strip_equal_those_made_whole_and_read_each_row_once() {
        let dir = tempfile::tempdir().unwrap();
        let hf = bumpy();
        let palette = parse_palette("nv 9 9 9\n0% blue\n60 green 200\n100% white\n", hf.nodata_value, || elevation_range(&hf)).unwrap();
        let edges = Options { compute_edges: true, ..Default::default() };
        let ops = [
            Op::Product(Product::Hillshade, Options::default()),
            Op::Product(Product::Slope, edges),
            Op::Product(Product::Aspect, edges),
            Op::Relief { palette: &palette, mode: ColorMode::Interpolate, alpha: true, nodata_value: hf.nodata_value },
        ];
        for (k, op) in ops.iter().enumerate() {
            // Strips of 1, 2 and 4 rows: windows reaching into the strip before and after.
            for rows_per_strip in [1, 2, 4] {
                let src = Counted { hf: &hf, reads: (0..hf.height).map(|_| Default::default()).collect(), fail_at: None };
                let out = dir.path().join(format!("{k}_{rows_per_strip}.tif"));
                write_product_strips(&src, &hf.georef(), op, &out, rows_per_strip, &WriteOptions::default(), &|_| ()).unwrap();
                assert!(src.reads.iter().all(|n| n.load(std::sync::atomic::Ordering::Relaxed) == 1), "each row read once");
                let written = volterra_formats::geotiff::read_geotiff_image(&out, &Default::default()).unwrap();
                let whole: Vec<f64> = match op {
                    Op::Product(p, o) => f32s(compute(&hf, *p, o).unwrap()).into_iter().map(f64::from).collect(),
                    Op::Relief { .. } => color_relief(&hf, &palette, ColorMode::Interpolate, true).into_iter().map(f64::from).collect(),
                };
                let read: Vec<f64> = match written.pixels {
                    volterra_formats::geotiff::GeoPixels::Values(v) => v,
                    volterra_formats::geotiff::GeoPixels::Rgba8(v) => v.into_iter().map(f64::from).collect(),
                    volterra_formats::geotiff::GeoPixels::Rgb8(_) => panic!("RGBA written"),
                };
                // NoData reads as NaN from the image reader: compared as the NoData value.
                let nodata = op.nodata().unwrap_or(f64::NAN);
                let read: Vec<f64> = read.into_iter().map(|v| if v.is_nan() { nodata } else { v }).collect();
                assert_eq!(read, whole, "op {k}, strips of {rows_per_strip}");
            }
        }
        // NoData where a window reaches past the edge (124 cells) or holds a hole: the pair
        // inside (12 more), the hole inside (9), those on an edge (3 each).
        let hs = f32s(compute(&hf, Product::Hillshade, &Options::default()).unwrap());
        assert_eq!(hs.iter().filter(|&&v| v == 0.0).count(), 124 + 12 + 9 + 3 * 3);
    }

    #[test]
    fn a_row_that_fails_to_read_stops_the_product_with_its_error_and_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let hf = bumpy();
        let src = Counted { hf: &hf, reads: (0..hf.height).map(|_| Default::default()).collect(), fail_at: Some(13) };
        let out = dir.path().join("hs.tif");
        let op = Op::Product(Product::Hillshade, Options::default());
        let e = write_product_strips(&src, &hf.georef(), &op, &out, 4, &WriteOptions::default(), &|_| ()).unwrap_err();
        assert_eq!(e.to_string(), "dem.tif: tile of row 13 is corrupt");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "no output, no temporary file");
        let tiny = Heightfield { width: 2, elevations: vec![0.0; 2 * 23], ..bumpy() };
        assert!(op.check(tiny.size()).unwrap_err().to_string().contains("no 3×3 window"));
    }

    #[test]
    fn palettes_parse_as_gdaldem_reads_them_and_exact_entries_match_only_themselves() {
        let mut hf = plane(0.0, 0.0);
        hf.elevations = (0..30).map(|i| i as f32 * 10.0).collect();
        hf.nodata = (0..30).map(|i| i == 29).collect();
        hf.elevations[29] = f32::NAN; // as a reader holds NoData
        hf.nodata_value = Some(-1.0);
        let p =
            parse_palette("# c\n/ also a comment\nnv 1 2 3 4\n50% red 128\n0:0,0,0\n100 white\n", hf.nodata_value, || elevation_range(&hf))
                .unwrap();
        // Sorted: nv (−1), 0, 100, the middle of the valid range (0 … 280: 140).
        let values: Vec<f64> = p.iter().map(|e| e.value).collect();
        assert_eq!(values, [-1.0, 0.0, 100.0, 140.0]);
        assert_eq!(p[3].rgba, [255, 0, 0, 128]);
        let c = color_relief(&hf, &p, ColorMode::Interpolate, true);
        assert_eq!(&c[4 * 5..4 * 6], &[127, 127, 127, 255], "50 is halfway from black to white (truncated after + 0.45)");
        assert_eq!(&c[4 * 29..], &[1, 2, 3, 4], "NoData takes the nv colour");
        let exact = color_relief(&hf, &p, ColorMode::Exact, false);
        assert_eq!(&exact[3 * 10..3 * 11], &[255, 255, 255], "100 is an entry");
        assert_eq!(&exact[3 * 5..3 * 6], &[0, 0, 0], "50 is none");
        assert!(parse_palette("10 mauve\n", None, || None).unwrap_err().to_string().contains("unknown colour: mauve"));
        assert!(parse_palette("120% red\n", None, || None).unwrap_err().to_string().contains("percentage"));
        assert!(parse_palette("# COLOR_MODEL = RGB\n", None, || None).is_err());
    }
}
