//! `dem`: gdaldem's products (hillshade, slope, aspect, TRI, TPI, roughness,
//! color-relief) and gdal_contour's contours, a band of rows at a time.

use crate::args::{DemArgs, DemProduct, ReliefArgs};
use crate::progress;
use anyhow::{anyhow, bail, Context, Result};
use std::path::Path;
use volterra_formats::{self as formats, Limits, LoadOptions};

pub(crate) fn cmd_dem(
    product: DemProduct,
    input: &Path,
    output: &Path,
    options: &volterra::dem::Options,
    relief: &ReliefArgs,
    write: &formats::geotiff_write::WriteOptions,
    load: &LoadOptions,
) -> Result<()> {
    use volterra::dem::{self, Op, Product};
    // The palette first: a missing one is an error before the DEM is read.
    let palette = match product {
        DemProduct::ColorRelief => {
            let path = relief.palette.as_deref().ok_or_else(|| anyhow::anyhow!("color-relief needs --palette FILE"))?;
            let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read the palette", path.display()))?;
            Some((path, text))
        }
        _ => None,
    };
    let (src, grid, nodata_value) = dem_source(input, load)?;
    let palette = match palette {
        Some((path, text)) => {
            let no_range = std::cell::Cell::new(false);
            let palette = dem::parse_palette(&text, nodata_value, || {
                let range = dem::elevation_range(&*src);
                no_range.set(range.is_none());
                range
            });
            if no_range.get() && src.failure().is_none() {
                eprintln!(
                    "warning: {}: no valid samples, so the palette's percentages have no range: each is taken as 0 (as gdaldem)",
                    input.display()
                );
            }
            // A range pass that stopped at a row it could not read: that, not the palette.
            if let Some(why) = src.failure() {
                bail!("{why}");
            }
            Some(palette.with_context(|| path.display().to_string())?)
        }
        None => None,
    };
    let (op, what) = match product {
        DemProduct::Hillshade => (Op::Product(Product::Hillshade, *options), "hillshade"),
        DemProduct::Slope => (Op::Product(Product::Slope, *options), "slope"),
        DemProduct::Aspect => (Op::Product(Product::Aspect, *options), "aspect"),
        DemProduct::Tri => (Op::Product(Product::Tri, *options), "TRI"),
        DemProduct::Tpi => (Op::Product(Product::Tpi, *options), "TPI"),
        DemProduct::Roughness => (Op::Product(Product::Roughness, *options), "roughness"),
        DemProduct::ColorRelief => {
            let palette = palette.as_deref().expect("read above");
            (Op::Relief { palette, mode: relief.mode, alpha: relief.alpha, nodata_value }, "color-relief")
        }
        DemProduct::Contours => unreachable!("contours are drawn by cmd_contours"),
    };
    op.check(src.size()).with_context(|| input.display().to_string())?;
    // Slopes and shading compare a height step with a cell step: without metres for both
    // (a PNG heightmap given no vertical scale or cell size) the angles mean nothing.
    if matches!(product, DemProduct::Slope | DemProduct::Hillshade) && grid.units != formats::GridUnits::METRES {
        let lacks = match (grid.units.elevation_in_metres, grid.units.cell_size_in_metres) {
            (false, false) => {
                "its elevations are grey levels and its cells have no size (give --vertical-scale and --cell-size, in metres)"
            }
            (false, true) => "its elevations are grey levels (give --vertical-scale, metres per level)",
            _ => "its cells have no size (give --cell-size, in metres)",
        };
        eprintln!("warning: {}: the {what}'s angles mean nothing: {lacks}", input.display());
    }
    let progress = progress::TerminalProgress::default();
    use volterra::render::driver::Progress as _;
    progress.begin(what, grid.height as u64);
    let written = dem::write_product(&*src, &grid, &op, output, write, &load.limits, &|rows| progress.update(rows as u64));
    progress.end();
    let valid = written?;
    if valid == 0 {
        let what = match (product, op.nodata()) {
            (DemProduct::ColorRelief, _) => "every cell has the palette's NoData colour (its nv entry, else its lowest)".to_string(),
            (_, Some(v)) => format!("every cell of the output is NoData ({v})"),
            (_, None) => "every cell of the output is 0".to_string(),
        };
        eprintln!("warning: {}: no valid samples (every one NoData): {what}", input.display());
    }
    say!("wrote {} ({}×{})", output.display(), grid.width, grid.height);
    Ok(())
}

/// A DEM's rows as the products read them: a GeoTIFF a band of rows at a time (at full
/// resolution whatever its size: what is held is a few rows), other DEMs whole; where
/// they lie, and the NoData value the file declares.
pub(crate) fn dem_source(
    input: &Path,
    load: &LoadOptions,
) -> Result<(Box<dyn formats::heightfield::HeightRows>, formats::heightfield::GridGeoref, Option<f64>)> {
    if formats::detect(input)? == formats::FileKind::GeoTiff {
        let rows = formats::geotiff_rows::GeoTiffRows::open(input, &load.geotiff, &load.limits, 0)?;
        let (grid, nodata) = (rows.georef().clone(), rows.nodata_value);
        return Ok((Box::new(rows), grid, nodata));
    }
    let formats::Dataset::Heightfield(hf) = formats::load(input, load)? else {
        anyhow::bail!("{}: not a heightfield (a GeoTIFF or PNG DEM)", input.display());
    };
    let (grid, nodata) = (hf.georef(), hf.nodata_value);
    Ok((Box::new(hf), grid, nodata))
}

/// What `dem contours` writes: lines (gdal_contour's default) or band polygons (-p).
pub(crate) enum ContourOutput<'a> {
    Lines { attribute: &'a str, three_d: bool },
    Polygons { min: &'a str, max: &'a str },
}

pub(crate) fn cmd_contours(
    input: &Path,
    output: &Path,
    levels: &volterra::dem::contours::Levels,
    kind: ContourOutput,
    load: &LoadOptions,
) -> Result<()> {
    let ext = output.extension().and_then(|e| e.to_str()).unwrap_or_default().to_ascii_lowercase();
    if ext != "geojson" && ext != "json" {
        anyhow::bail!("{}: contours are written as GeoJSON; name the output .geojson", output.display());
    }
    let (src, grid, _) = dem_source(input, load)?;
    // The rows are read once for the elevation range where an interval needs it, then to
    // draw: progress counts both passes.
    let passes = if matches!(levels, volterra::dem::contours::Levels::Interval { .. }) { 2 } else { 1 };
    let progress = progress::TerminalProgress::default();
    use volterra::render::driver::Progress as _;
    progress.begin("contours", (passes * grid.height) as u64);
    let src = RowsRead { rows: &*src, progress: &progress, read: Default::default(), any_valid: Default::default() };
    let drawn = contours_to(&src, &grid, input, output, levels, kind);
    progress.end();
    if drawn.is_ok() && !src.any_valid.load(std::sync::atomic::Ordering::Relaxed) {
        eprintln!("warning: {}: no valid samples (every one NoData): the output holds no contour", input.display());
    }
    drawn
}

/// A DEM's rows, reporting the rows read to a progress bar.
pub(crate) struct RowsRead<'a> {
    rows: &'a dyn formats::heightfield::HeightRows,
    progress: &'a progress::TerminalProgress,
    read: std::sync::atomic::AtomicU64,
    /// Whether any row read held a valid (finite) sample.
    any_valid: std::sync::atomic::AtomicBool,
}

impl formats::heightfield::HeightRows for RowsRead<'_> {
    fn size(&self) -> [usize; 2] {
        self.rows.size()
    }
    fn cell_size(&self) -> [f64; 2] {
        self.rows.cell_size()
    }
    fn read_row(&self, row: usize, col: usize, out: &mut [f32]) {
        use volterra::render::driver::Progress as _;
        self.rows.read_row(row, col, out);
        if out.iter().any(|z| z.is_finite()) {
            self.any_valid.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        self.progress.update(self.read.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
    }
    fn failure(&self) -> Option<String> {
        self.rows.failure()
    }
}

/// An error of the contours, named by the input file unless it names a file already (the
/// output's errors name the output; the reader's name the input).
pub(crate) fn named_input(e: anyhow::Error, input: &Path) -> anyhow::Error {
    let named = e.is::<formats::FormatError>() || e.to_string().starts_with(&input.display().to_string());
    if named {
        e
    } else {
        e.context(input.display().to_string())
    }
}

pub(crate) fn contours_to(
    src: &dyn formats::heightfield::HeightRows,
    grid: &formats::heightfield::GridGeoref,
    input: &Path,
    output: &Path,
    levels: &volterra::dem::contours::Levels,
    kind: ContourOutput,
) -> Result<()> {
    match kind {
        ContourOutput::Lines { attribute, three_d } => {
            // Each line written as soon as it is complete: what is held is two rows and the
            // lines still open, not every line of the DEM.
            let (mut count, mut vertices) = (0usize, 0usize);
            formats::geojson::write_lines_from(output, "contour", &grid.crs, attribute, three_d, |emit| -> Result<()> {
                volterra::dem::contours::contours_each(src, grid, levels, |l| {
                    (count, vertices) = (count + 1, vertices + l.points.len());
                    Ok(emit(formats::geojson::LineFeature { points: &l.points, value: l.level })?)
                })
                .map_err(|e| named_input(e, input))
            })?;
            say!("wrote {} ({count} lines, {vertices} vertices)", output.display());
        }
        ContourOutput::Polygons { min, max } => {
            let bands = volterra::dem::contours::contour_polygons(src, grid, levels).map_err(|e| named_input(e, input))?;
            let features = bands.iter().map(|b| formats::geojson::PolygonFeature { polygons: &b.polygons, min: b.min, max: b.max });
            formats::geojson::write_polygons(output, "contour", &grid.crs, (min, max), features)?;
            let polygons: usize = bands.iter().map(|b| b.polygons.len()).sum();
            say!("wrote {} ({} bands, {polygons} polygons)", output.display(), bands.len());
        }
    }
    Ok(())
}

/// `volterra dem`: checks the flags as gdaldem does, then the contours or the raster product.
pub(crate) fn run(args: DemArgs, limits: Limits) -> Result<()> {
    let DemArgs {
        product,
        input,
        output,
        output_format,
        creation_options,
        z,
        scale,
        azimuth,
        altitude,
        percent,
        zero_for_flat,
        compute_edges,
        alg,
        multidirectional,
        combined,
        palette,
        alpha,
        exact_color_entry,
        nearest_color_entry,
        interval,
        offset,
        levels,
        attribute,
        three_d,
        polygons,
        attribute_min,
        attribute_max,
        read,
    } = args;
    let contour_args = interval.is_some() || levels.is_some() || three_d || polygons || attribute != "elev";
    let contours = match (product, interval, levels) {
        (DemProduct::Contours, Some(interval), None) => Some(volterra::dem::contours::Levels::Interval { interval, offset }),
        (DemProduct::Contours, None, Some(levels)) => Some(volterra::dem::contours::Levels::Fixed(levels)),
        (DemProduct::Contours, ..) => anyhow::bail!("contours need --interval or --levels"),
        _ if contour_args => anyhow::bail!("--interval, --levels, --attribute, --3d and --polygons are for contours only"),
        _ => None,
    };
    if contours.is_some() && (output_format != "GTiff" || !creation_options.is_empty()) {
        anyhow::bail!("-of and -co are for the raster products; contours are written as GeoJSON");
    }
    if let Some(levels) = contours {
        let output_kind = if polygons {
            ContourOutput::Polygons { min: &attribute_min, max: &attribute_max }
        } else {
            ContourOutput::Lines { attribute: &attribute, three_d }
        };
        return cmd_contours(&input, &output, &levels, output_kind, &read.options(limits)?);
    }
    use volterra::dem::Shading;
    let gradient_product = matches!(product, DemProduct::Slope | DemProduct::Aspect | DemProduct::Hillshade);
    // The flag's value names are gdaldem's, as the library takes them.
    let alg_name = alg.map(|a| clap::ValueEnum::to_possible_value(&a).expect("every -alg value is listed").get_name().to_string());
    let (gradient, tri) =
        volterra::dem::algorithms(alg_name.as_deref(), gradient_product, product == DemProduct::Tri).map_err(|m| anyhow!("--alg: {m}"))?;
    if (multidirectional || combined) && product != DemProduct::Hillshade {
        anyhow::bail!("--multidirectional and --combined are for hillshade");
    }
    let shading = match (multidirectional, combined) {
        (true, _) => Shading::MultiDirectional,
        (_, true) => Shading::Combined,
        _ => Shading::Single,
    };
    let options = volterra::dem::Options { z, scale, azimuth, altitude, percent, zero_for_flat, compute_edges, gradient, tri, shading };
    let mode = match (exact_color_entry, nearest_color_entry) {
        (true, _) => volterra::dem::ColorMode::Exact,
        (_, true) => volterra::dem::ColorMode::Nearest,
        _ => volterra::dem::ColorMode::Interpolate,
    };
    let write = match output_format.to_ascii_uppercase().as_str() {
        "GTIFF" => formats::geotiff_write::WriteOptions::from_creation_options(&creation_options).map_err(|e| anyhow!("-co: {e}"))?,
        "COG" => formats::geotiff_write::WriteOptions::from_cog_creation_options(&creation_options).map_err(|e| anyhow!("-co: {e}"))?,
        other => anyhow::bail!("-of {other}: volterra dem writes GTiff or COG"),
    };
    cmd_dem(product, &input, &output, &options, &ReliefArgs { palette, alpha, mode }, &write, &read.options(limits)?)
}
