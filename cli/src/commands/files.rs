//! `info`, `convert` and `compare`: the commands that read files and say, or write again,
//! what they hold.

use super::render::check_output_dir;
use crate::args::ReadArgs;
use crate::progress;
use anyhow::{bail, Context, Result};
use std::path::Path;
use volterra::{compare, info};
use volterra_formats::{self as formats, dicom, Dataset, Limits, LoadOptions};

/// `whole_series`: list every step of a 4-D NIfTI (no --volume given).
pub(crate) fn cmd_info(path: &Path, json: bool, stats: bool, whole_series: bool, opts: &LoadOptions) -> Result<()> {
    let series = formats::series::discover(path)?.filter(|s| whole_series || s.steps[0].volume_index.is_none());
    if let Some(series) = series {
        // Every step read in turn (one in memory at a time) for its size and ranges.
        let bar = crate::progress::bar(series.steps.len() as u64, "timesteps");
        let mut steps = Vec::with_capacity(series.steps.len());
        for step in &series.steps {
            let mut o = opts.clone();
            o.nifti.volume_index = step.volume_index.unwrap_or(0);
            let data = formats::load(&step.file, &o)?;
            steps.push(info::step_json(step, &data, &opts.particles));
            bar.inc(1);
        }
        bar.finish_and_clear();
        if json {
            let o = serde_json::json!({"series": series.source.display().to_string(), "kind": series.kind,
                "time_unit": series.time_unit, "timesteps": steps});
            println!("{}", serde_json::to_string_pretty(&o)?);
        } else {
            print!("{}", info::series_text(&series, &steps));
        }
        return Ok(());
    }
    if path.is_dir() && opts.dicom.series.is_none() {
        let list = dicom::list_series(path, &opts.limits)?;
        if list.len() > 1 {
            if json {
                println!("{}", serde_json::to_string_pretty(&info::series_json(&list))?);
            } else {
                println!("{} series (choose one with --series):", list.len());
                for (i, s) in list.iter().enumerate() {
                    println!(
                        "  {}: '{}' {}, {} files of {}×{} (UID {})",
                        i + 1,
                        s.description,
                        s.modality,
                        s.files,
                        s.columns,
                        s.rows,
                        s.uid
                    );
                }
            }
            return Ok(());
        }
    }
    let spin = crate::progress::spinner(&format!("reading {}", path.display()));
    if formats::detect(path)? == formats::FileKind::GeoTiff {
        // Read by rows, never held: the range and NoData count come from one pass, so a
        // DEM larger than memory is described at its full resolution.
        let rows =
            formats::geotiff_rows::GeoTiffRows::open(path, &opts.geotiff, &opts.limits, 0).inspect_err(|_| spin.finish_and_clear())?;
        let summary = info::GridSummary::of_rows(&rows);
        spin.finish_and_clear();
        if let Some(failure) = rows.failure() {
            bail!("{failure}");
        }
        match json {
            true => println!("{}", serde_json::to_string_pretty(&info::grid_json(&summary))?),
            false => print!("{}", info::grid_text(&summary, stats)),
        }
        return Ok(());
    }
    let data = formats::load(path, opts);
    spin.finish_and_clear();
    let data = data?;
    if json {
        println!("{}", serde_json::to_string_pretty(&info::dataset_json(&data, &opts.particles))?);
    } else {
        print!("{}", info::dataset_text(&data, &opts.particles, stats));
    }
    Ok(())
}

pub(crate) fn lower_name(p: &Path) -> String {
    p.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default()
}

pub(crate) fn cmd_convert(input: &Path, output: &Path, read: &ReadArgs, opts: &LoadOptions) -> Result<()> {
    check_output_dir(output)?;
    let out = lower_name(output);
    let nifti_out = out.ends_with(".nii") || out.ends_with(".nii.gz");
    // A 4-D NIfTI converts whole (a 4-D file out) unless --volume names one: never only the
    // first volume without a word.
    if read.volume.is_none() && nifti_out && formats::detect(input)? == formats::FileKind::Nifti {
        let header = formats::nifti::read_nifti_header(input)?;
        if (4..=header.dim[0]).any(|i| header.dim[i as usize] > 1) {
            let spin = crate::progress::spinner(&format!("reading {}", input.display()));
            let all = formats::nifti::read_nifti_volumes(input, &opts.limits);
            spin.finish_and_clear();
            let all = all?;
            formats::nifti::write_nifti_volumes(output, &all.volumes, &all.extra_dims, all.time_step, all.time_unit)?;
            say!("wrote {} ({} volumes)", output.display(), all.volumes.len());
            return Ok(());
        }
    }
    if (out.ends_with(".tif") || out.ends_with(".tiff")) && formats::detect(input)? == formats::FileKind::GeoTiff {
        return convert_geotiff(input, output, opts);
    }
    let spin = crate::progress::spinner(&format!("reading {}", input.display()));
    let data = formats::load(input, opts);
    spin.finish_and_clear();
    let data = data?;
    match data {
        Dataset::Volume(v) if out.ends_with(".nii") || out.ends_with(".nii.gz") => formats::nifti::write_nifti(output, &v)?,
        Dataset::Volume(v) if out.ends_with(".nrrd") => formats::nrrd::write_nrrd(output, &v)?,
        Dataset::Heightfield(h) if out.ends_with(".tif") || out.ends_with(".tiff") => formats::geotiff::write_geotiff(output, &h)?,
        Dataset::Heightfield(h) if out.ends_with(".exr") => {
            let mut img = formats::FloatImage::new(h.width, h.height);
            img.add_channel("Y", h.elevations.clone());
            formats::exr_io::write_exr(output, &img)?
        }
        Dataset::Particles(p) if out.ends_with(".vtp") => formats::vtk::write_vtp(output, &p, &opts.particles)?,
        d => {
            let (kind, allowed) = match d {
                Dataset::Volume(_) => ("a volume", ".nii, .nii.gz or .nrrd"),
                Dataset::Heightfield(_) => ("a heightfield", ".tif or .exr"),
                Dataset::Particles(_) => ("a particle set", ".vtp"),
            };
            bail!("{}: {} converts to {allowed}", output.display(), kind);
        }
    }
    say!("wrote {}", output.display());
    Ok(())
}

/// A GeoTIFF DEM (or its `--extent`) to a float32 GeoTIFF in metres, as `write_geotiff`
/// writes a heightfield held, but read by rows and written strip by strip at full
/// resolution: what is held is a few strips, whatever the DEM's size.
pub(crate) fn convert_geotiff(input: &Path, output: &Path, opts: &LoadOptions) -> Result<()> {
    use formats::geotiff_write::{default_rows_per_strip, write_band_strips, BandKind, StripMut, NODATA_WHERE_NONE_DECLARED};
    let rows = formats::geotiff_rows::GeoTiffRows::open(input, &opts.geotiff, &opts.limits, 0)?;
    let grid = rows.georef().clone();
    // A NoData value is declared where the file declares one or where samples are NoData
    // (values out of range, NaN): that takes a pass over the rows first.
    let nodata = rows.nodata_value.or_else(|| (rows.summary().nodata > 0).then_some(NODATA_WHERE_NONE_DECLARED));
    let rows_per_strip = default_rows_per_strip(grid.width, BandKind::F32);
    let writer = formats::geotiff_write::writer_bytes(grid.width, BandKind::F32, rows_per_strip);
    opts.limits.check(output, "the GeoTIFF writer's strips", &[writer])?;
    let progress = progress::TerminalProgress::default();
    use volterra::render::driver::Progress as _;
    progress.begin("converting", grid.height as u64);
    let w = grid.width;
    let written = write_band_strips(output, &grid, BandKind::F32, nodata, true, rows_per_strip, |first, strip| -> Result<()> {
        let StripMut::F32(cells) = strip else { unreachable!("a float band") };
        for (k, row) in cells.chunks_exact_mut(w).enumerate() {
            rows.read_row(first + k, 0, row);
        }
        if let Some(why) = rows.failure() {
            bail!("{why}");
        }
        if let Some(v) = nodata {
            cells.iter_mut().filter(|z| !z.is_finite()).for_each(|z| *z = v as f32);
        }
        progress.update((first + cells.len() / w) as u64);
        Ok(())
    });
    progress.end();
    written?;
    say!("wrote {} ({}×{})", output.display(), grid.width, grid.height);
    Ok(())
}

pub(crate) fn cmd_compare(a: &Path, b: &Path, json: bool, limits: &Limits) -> Result<()> {
    let ia = formats::exr_io::read_exr(a, limits)?;
    let ib = formats::exr_io::read_exr(b, limits)?;
    let c = compare::compare(&ia, &ib).with_context(|| format!("{} vs {}", a.display(), b.display()))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&c)?);
    } else {
        println!("{:<8} {:>12} {:>10} {:>12} {:>12}", "channel", "RMSE", "PSNR dB", "max |err|", "rel. RMSE");
        for s in c.channels.iter().chain(std::iter::once(&c.overall)) {
            println!("{:<8} {:>12.6} {:>10.2} {:>12.6} {:>11.4}%", s.channel, s.rmse, s.psnr_db, s.max_abs, 100.0 * s.relative_rmse);
        }
        println!("coverage mismatch: {} pixels", c.coverage_mismatch);
    }
    Ok(())
}
