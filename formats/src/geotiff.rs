//! GeoTIFF elevation rasters through the `tiff` crate (strips or tiles; none, LZW, Deflate,
//! PackBits; predictors 2 and 3; int16/uint16/int32/float32/float64), with the GeoTIFF
//! tags read here: ModelPixelScale + ModelTiepoint or ModelTransformation, the
//! GeoKeyDirectory (EPSG code, raster type, vertical units) and GDAL_NODATA.

use crate::error::{FormatError, Result};
use crate::gdal_sidecar;
use crate::heightfield::{metres_per_degree, Crs, GridUnits, Heightfield, NodataMask};
use crate::memory::{human_bytes, Limits};
use std::io::BufReader;
use std::path::Path;
use tiff::decoder::{Decoder, DecodingResult};
use tiff::tags::Tag;

pub(crate) const KEY_MODEL_TYPE: u16 = 1024;
pub(crate) const KEY_RASTER_TYPE: u16 = 1025;
pub(crate) const KEY_CITATION: u16 = 1026;
pub(crate) const KEY_GEOGRAPHIC_TYPE: u16 = 2048;
pub(crate) const KEY_PROJECTED_TYPE: u16 = 3072;
pub(crate) const KEY_PROJ_LINEAR_UNITS: u16 = 3076;
pub(crate) const KEY_VERTICAL_UNITS: u16 = 4099;

/// A decoded GeoKey value (double-valued keys are not needed and skipped).
#[derive(Debug, Clone)]
enum GeoKey {
    Short(u16),
    Ascii(String),
}

pub(crate) fn tiff_err(path: &Path, e: tiff::TiffError) -> FormatError {
    match e {
        tiff::TiffError::UnsupportedError(u) => FormatError::unsupported(path, format!("unsupported TIFF feature: {u}")),
        tiff::TiffError::IoError(io) => FormatError::invalid(path, format!("TIFF is truncated or unreadable: {io}")),
        other => FormatError::invalid(path, format!("invalid TIFF: {other}")),
    }
}

fn geo_keys<R: std::io::Read + std::io::Seek>(path: &Path, d: &mut Decoder<R>) -> Result<Vec<(u16, GeoKey)>> {
    let Some(dir) = d.find_tag(Tag::GeoKeyDirectoryTag).map_err(|e| tiff_err(path, e))? else {
        return Ok(Vec::new());
    };
    let dir = dir.into_u16_vec().map_err(|e| tiff_err(path, e))?;
    let ascii = match d.find_tag(Tag::GeoAsciiParamsTag).map_err(|e| tiff_err(path, e))? {
        Some(v) => v.into_string().map_err(|e| tiff_err(path, e))?,
        None => String::new(),
    };
    if dir.len() < 4 {
        return Err(FormatError::invalid(path, "GeoKeyDirectory is shorter than its header"));
    }
    let n = dir[3] as usize;
    if dir.len() < 4 + 4 * n {
        return Err(FormatError::invalid(path, format!("GeoKeyDirectory declares {n} keys but holds {}", (dir.len() - 4) / 4)));
    }
    let mut keys = Vec::with_capacity(n);
    for k in 0..n {
        let e = &dir[4 + 4 * k..8 + 4 * k];
        let (id, loc, count, off) = (e[0], e[1], e[2] as usize, e[3] as usize);
        let value = match loc {
            0 => GeoKey::Short(off as u16),
            34737 => GeoKey::Ascii(ascii.get(off..(off + count).min(ascii.len())).unwrap_or("").trim_end_matches(['|', '\0']).to_string()),
            34735 => GeoKey::Short(dir.get(off).copied().unwrap_or(0)),
            _ => continue,
        };
        keys.push((id, value));
    }
    Ok(keys)
}

fn short_key(keys: &[(u16, GeoKey)], id: u16) -> Option<u16> {
    keys.iter().find_map(|(k, v)| match v {
        GeoKey::Short(s) if *k == id => Some(*s),
        _ => None,
    })
}

/// Every strip or tile must lie inside the file: the tiff crate reports one that does not
/// as a bare read error ("failed to fill whole buffer") or a deflate error.
fn check_data_offsets<R: std::io::Read + std::io::Seek>(path: &Path, d: &mut Decoder<R>) -> Result<()> {
    let file_len = std::fs::metadata(path).map_err(|e| FormatError::io(path, e))?.len();
    for (offsets, counts, what) in [(Tag::StripOffsets, Tag::StripByteCounts, "strip"), (Tag::TileOffsets, Tag::TileByteCounts, "tile")] {
        let Some(offsets) = d.find_tag(offsets).map_err(|e| tiff_err(path, e))? else { continue };
        let offsets = offsets.into_u64_vec().map_err(|e| tiff_err(path, e))?;
        let counts = match d.find_tag(counts).map_err(|e| tiff_err(path, e))? {
            Some(c) => c.into_u64_vec().map_err(|e| tiff_err(path, e))?,
            None => return Err(FormatError::invalid(path, format!("{what} offsets without {what} byte counts"))),
        };
        for (i, (&o, &c)) in offsets.iter().zip(&counts).enumerate() {
            if o.checked_add(c).is_none_or(|end| end > file_len) {
                return Err(FormatError::invalid(
                    path,
                    format!("{what} {i} lies beyond the end of the file (offset {o}, {c} bytes; the file has {file_len})"),
                ));
            }
        }
    }
    Ok(())
}

/// Where a GeoTIFF's raster lies: its CRS, the map coordinates of the centre of its first
/// (north-west) pixel, the pixel size in CRS units (both positive: north-up only), whether
/// it is PixelIsPoint, its GeoKeys, its NoData value, and notes on what was assumed and
/// which sidecar file gave what.
struct Georeferencing {
    keys: Vec<(u16, GeoKey)>,
    crs: Crs,
    origin: [f64; 2],
    scale: [f64; 2],
    point: bool,
    nodata: Option<f64>,
    notes: Vec<String>,
    /// What `info` shows: where the georeferencing and the CRS came from.
    sources: Vec<(String, String)>,
}

/// A file's name for notes.
fn file_name(p: &Path) -> String {
    p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| p.display().to_string())
}

/// The centre of the first pixel and the pixel size (both positive) of a north-up
/// geotransform; a rotated, sheared or south-up one is refused, naming `source`.
fn north_up(path: &Path, source: &str, gt: [f64; 6]) -> Result<(f64, f64, f64, f64)> {
    if gt[2] != 0.0 || gt[4] != 0.0 {
        return Err(FormatError::unsupported(path, format!("{source} is rotated or sheared; only north-up rasters are supported")));
    }
    if gt[5].is_nan() || gt[5] >= 0.0 {
        return Err(FormatError::unsupported(
            path,
            format!("{source} has rows running north (pixel height {}); only north-up rasters are supported", gt[5]),
        ));
    }
    Ok((gt[0] + 0.5 * gt[1], gt[3] + 0.5 * gt[5], gt[1], -gt[5]))
}

/// The metres in one unit of a projected CRS's coordinates, from ProjLinearUnitsGeoKey.
fn linear_unit(path: &Path, keys: &[(u16, GeoKey)]) -> Result<f64> {
    Ok(match short_key(keys, KEY_PROJ_LINEAR_UNITS) {
        None | Some(9001) | Some(32767) => 1.0,
        Some(9002) => 0.3048,
        Some(9003) => 1200.0 / 3937.0,
        Some(9005) => 0.3047972654,
        Some(9036) => 1000.0,
        Some(code) => {
            return Err(FormatError::unsupported(
                path,
                format!("projected linear unit code {code} is not one of metre, foot, US survey foot, Clarke's foot, kilometre"),
            ))
        }
    })
}

/// The raster's georeferencing, as GDAL's GeoTIFF driver finds it (GEOREF_SOURCES
/// `PAM,INTERNAL,TABFILE,WORLDFILE`): the geotransform from the PAM file (`.aux.xml`),
/// else the GeoTIFF tags, else a world file (`.tfw`, `.tifw`, `.wld`); the CRS from the PAM
/// file, else the GeoKeys, else (which GDAL does not read beside a GeoTIFF) a `.prj`; the
/// NoData value from the PAM file, else GDAL_NODATA.
fn georeferencing<R: std::io::Read + std::io::Seek>(path: &Path, d: &mut Decoder<R>) -> Result<Georeferencing> {
    let keys = geo_keys(path, d)?;
    let scale = match d.find_tag(Tag::ModelPixelScaleTag).map_err(|e| tiff_err(path, e))? {
        Some(v) => Some(v.into_f64_vec().map_err(|e| tiff_err(path, e))?),
        None => None,
    };
    let tie = match d.find_tag(Tag::ModelTiepointTag).map_err(|e| tiff_err(path, e))? {
        Some(v) => Some(v.into_f64_vec().map_err(|e| tiff_err(path, e))?),
        None => None,
    };
    let transform = match d.find_tag(Tag::ModelTransformationTag).map_err(|e| tiff_err(path, e))? {
        Some(v) => Some(v.into_f64_vec().map_err(|e| tiff_err(path, e))?),
        None => None,
    };
    let pam = gdal_sidecar::read_pam(path)?;
    let pam_srs = pam.as_ref().and_then(|p| Some((p.path.clone(), p.srs.clone()?)));
    let pam_geotransform = pam.as_ref().and_then(|p| Some((p.path.clone(), p.geotransform?)));
    let internal_geotransform = scale.is_some() || transform.is_some();

    if keys.is_empty() && internal_geotransform && pam_srs.is_none() {
        // Without GeoKeys the CRS is unknown, and with it whether the pixel scale is in
        // degrees or metres: guessing would give cells 100 000 times too small or too large.
        return Err(FormatError::invalid(
            path,
            "has a pixel scale or transformation but no GeoKeys: its CRS (degrees or metres) is unknown",
        ));
    }
    let mut notes = Vec::new();
    let mut sources = Vec::new();
    let point = short_key(&keys, KEY_RASTER_TYPE) == Some(2);
    // The centre of the first pixel and the pixel size, from the first source that has them.
    // Internal tags: raster → model is X = x0 + sx·I, Y = y0 − sy·J, for raster coordinates
    // (I, J) where (0, 0) is the corner of the first pixel (PixelIsArea) or its centre
    // (PixelIsPoint).
    let internal = match (&scale, &tie, &transform) {
        (Some(s), Some(t), _) if s.len() >= 2 && t.len() >= 6 => Some((t[3] - t[0] * s[0], t[4] + t[1] * s[1], s[0], s[1])),
        (_, _, Some(m)) if m.len() >= 16 => {
            if m[1] != 0.0 || m[4] != 0.0 {
                return Err(FormatError::unsupported(
                    path,
                    "ModelTransformation is rotated or sheared; only north-up rasters are supported",
                ));
            }
            Some((m[3], m[7], m[0], -m[5]))
        }
        _ => None,
    };
    let (ox, oy, sx, sy, georeferenced) = if let Some((pam_path, gt)) = &pam_geotransform {
        let name = file_name(pam_path);
        let (ox, oy, sx, sy) = north_up(path, &format!("the geotransform in {name}"), *gt)?;
        if internal.is_some() {
            notes.push(format!("georeferencing from {name}, which GDAL reads before the GeoTIFF's own tags"));
        }
        sources.push(("georef from".to_string(), format!("{name} (PAM)")));
        (ox, oy, sx, sy, true)
    } else if let Some((x0, y0, sx, sy)) = internal {
        if !(sx.is_finite() && sy.is_finite() && sx > 0.0 && sy > 0.0 && x0.is_finite() && y0.is_finite()) {
            return Err(FormatError::invalid(path, format!("pixel scale ({sx}, {sy}) must be finite and positive (north-up)")));
        }
        let (ox, oy) = if point { (x0, y0) } else { (x0 + 0.5 * sx, y0 - 0.5 * sy) };
        (ox, oy, sx, sy, true)
    } else if let Some((world, gt)) = gdal_sidecar::read_world_file(path)? {
        let name = file_name(&world);
        let (ox, oy, sx, sy) = north_up(path, &format!("world file {name}"), gt)?;
        sources.push(("georef from".to_string(), format!("{name} (world file)")));
        (ox, oy, sx, sy, true)
    } else {
        notes.push("no georeferencing tags: unit cells at a local origin".to_string());
        (0.0, 0.0, 1.0, 1.0, false)
    };
    if !(sx.is_finite() && sy.is_finite() && sx > 0.0 && sy > 0.0 && ox.is_finite() && oy.is_finite()) {
        return Err(FormatError::invalid(path, format!("pixel scale ({sx}, {sy}) must be finite and positive (north-up)")));
    }

    // The CRS: the PAM file's, else the GeoKeys', else a .prj's.
    let crs = if let Some((pam_path, wkt)) = &pam_srs {
        let name = file_name(pam_path);
        let crs = gdal_sidecar::crs_from_wkt(pam_path, wkt)?;
        if !keys.is_empty() {
            notes.push(format!("CRS from {name}, which GDAL reads before the GeoTIFF's own GeoKeys"));
        }
        sources.push(("crs from".to_string(), format!("{name} (PAM)")));
        crs
    } else if !keys.is_empty() {
        crs_from_keys(path, &keys)?
    } else if let Some((prj, wkt)) = gdal_sidecar::read_prj(path)?.filter(|_| georeferenced) {
        let name = file_name(&prj);
        let crs = gdal_sidecar::crs_from_wkt(&prj, &wkt)?;
        notes.push(format!("CRS from {name}; GDAL does not read a .prj beside a GeoTIFF, so gdalinfo shows none"));
        sources.push(("crs from".to_string(), format!("{name} (ESRI .prj)")));
        crs
    } else if georeferenced {
        let source = sources.first().map(|(_, s)| s.clone()).unwrap_or_default();
        return Err(FormatError::invalid(
            path,
            format!(
                "is georeferenced by {source} but no CRS is given (no GeoKeys, no SRS in a .aux.xml, no .prj): \
                 its cells' units (degrees or metres) are unknown; add one with gdal_edit.py -a_srs EPSG:<code>"
            ),
        ));
    } else {
        Crs::local()
    };
    if crs.metres_per_unit != 1.0 && !crs.geographic {
        notes.push(format!("projected CRS in units of {} m: cell sizes converted to metres", crs.metres_per_unit));
    }
    let nodata = match pam.as_ref().and_then(|p| Some((p.path.clone(), p.nodata?))) {
        Some((pam_path, v)) => {
            sources.push(("nodata from".to_string(), format!("{} (PAM)", file_name(&pam_path))));
            Some(v)
        }
        None => gdal_nodata(path, d)?,
    };
    Ok(Georeferencing { keys, crs, origin: [ox, oy], scale: [sx, sy], point, nodata, notes, sources })
}

/// The CRS the GeoKeys describe.
fn crs_from_keys(path: &Path, keys: &[(u16, GeoKey)]) -> Result<Crs> {
    let model = short_key(keys, KEY_MODEL_TYPE);
    let projected = short_key(keys, KEY_PROJECTED_TYPE).filter(|&c| c != 0 && c != 32767);
    let geographic_code = short_key(keys, KEY_GEOGRAPHIC_TYPE).filter(|&c| c != 0 && c != 32767);
    let geographic = model == Some(2) || (model.is_none() && projected.is_none() && geographic_code.is_some());
    let epsg = if geographic { geographic_code } else { projected.or(geographic_code) }.map(u32::from);
    let citation = keys.iter().find_map(|(k, v)| match v {
        GeoKey::Ascii(s) if *k == KEY_CITATION => Some(s.clone()),
        _ => None,
    });
    let mut desc = match epsg {
        Some(c) => format!("EPSG:{c}"),
        None => "user-defined CRS".to_string(),
    };
    desc.push_str(if geographic { " (geographic)" } else { " (projected)" });
    if let Some(c) = citation {
        desc.push_str(&format!(" {c}"));
    }
    let metres_per_unit = if geographic { 1.0 } else { linear_unit(path, keys)? };
    Ok(Crs { epsg, geographic, description: desc, metres_per_unit })
}

/// One image of a GeoTIFF: its directory index and size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Image {
    index: usize,
    width: u32,
    height: u32,
}

/// The decoder at the file's full-resolution image (the first directory that is neither a
/// reduced image nor a mask) and the file's images: that one first, then its overviews
/// (reduced-resolution images, as `gdaladdo` and Cloud-Optimised GeoTIFFs store them),
/// largest first. Transparency masks (NewSubfileType bit 2) are not images.
fn open_images(path: &Path) -> Result<(Decoder<BufReader<std::fs::File>>, Vec<Image>)> {
    let file = std::fs::File::open(path).map_err(|e| FormatError::io(path, e))?;
    let mut d = Decoder::new(BufReader::new(file)).map_err(|e| tiff_err(path, e))?;
    let (mut full, mut overviews) = (None, Vec::new());
    let mut index = 0;
    loop {
        // The image at `index`, where its directory reads.
        let mut visit = |d: &mut Decoder<BufReader<std::fs::File>>| -> Result<()> {
            let subfile = d.find_tag_unsigned::<u32>(Tag::NewSubfileType).map_err(|e| tiff_err(path, e))?.unwrap_or(0);
            if subfile & 4 == 0 {
                let (width, height) = d.dimensions().map_err(|e| tiff_err(path, e))?;
                let image = Image { index, width, height };
                match (subfile & 1, full) {
                    (0, None) => full = Some(image),
                    (1, _) => overviews.push(image),
                    _ => {} // a further full-resolution image (a multi-page TIFF): not this raster's
                }
            }
            Ok(())
        };
        match visit(&mut d) {
            Ok(()) => {}
            // A broken directory after the full image only ends the list of overviews.
            Err(_) if full.is_some() => break,
            Err(e) => return Err(e),
        }
        // A file lists a few dozen images at most; a loop in the directory chain would not end.
        if !d.more_images() || index >= 64 {
            break;
        }
        index += 1;
        match d.seek_to_image(index) {
            Ok(()) => {}
            Err(_) if full.is_some() => break,
            Err(e) => return Err(tiff_err(path, e)),
        }
    }
    let full = full.ok_or_else(|| FormatError::invalid(path, "TIFF holds only reduced-resolution images"))?;
    if full.width == 0 || full.height == 0 {
        return Err(FormatError::invalid(path, format!("the raster is {}×{} samples", full.width, full.height)));
    }
    // An overview is smaller than the full image in both directions.
    overviews.retain(|o| o.width < full.width && o.height < full.height && o.width > 0 && o.height > 0);
    overviews.sort_by_key(|o| std::cmp::Reverse(o.width as u64 * o.height as u64));
    d.seek_to_image(full.index).map_err(|e| tiff_err(path, e))?;
    Ok((d, std::iter::once(full).chain(overviews).collect()))
}

/// Samples per pixel and the bytes of one decoded sample of the decoder's current image.
fn sample_layout<R: std::io::Read + std::io::Seek>(path: &Path, d: &mut Decoder<R>) -> Result<(u16, u64)> {
    let spp = d.find_tag_unsigned::<u16>(Tag::SamplesPerPixel).map_err(|e| tiff_err(path, e))?.unwrap_or(1);
    // One value per sample (RGB files list three).
    let bps = match d.find_tag(Tag::BitsPerSample).map_err(|e| tiff_err(path, e))? {
        Some(v) => v.into_u16_vec().map_err(|e| tiff_err(path, e))?.into_iter().max().unwrap_or(1) as u64,
        None => 1,
    };
    Ok((spp, bps.div_ceil(8).max(1)))
}

/// Readies the decoder, at `image`, to decode no more than that raster (`bytes`) and
/// checks its data offsets against the file.
fn ready(path: &Path, d: Decoder<BufReader<std::fs::File>>, bytes: usize) -> Result<Decoder<BufReader<std::fs::File>>> {
    let mut tiff_limits = tiff::decoder::Limits::default();
    tiff_limits.decoding_buffer_size = bytes.max(1 << 20);
    tiff_limits.intermediate_buffer_size = bytes.max(1 << 20);
    tiff_limits.ifd_value_size = 64 << 20;
    let mut d = d.with_limits(tiff_limits);
    check_data_offsets(path, &mut d)?;
    Ok(d)
}

/// The finest of `images` (the full raster, then its overviews, largest first) whose
/// `need` (factors of its bytes) fits the memory limit, those bytes, and where it is an
/// overview a note saying which and why. None fits: the full raster's refusal. A level
/// whose `need` fails (an extent that holds none of its samples) is passed over; the full
/// raster's failure is the error.
fn finest_fitting(
    path: &Path,
    limits: &Limits,
    images: &[Image],
    what: &str,
    need: impl Fn(&Image) -> Result<[u64; 3]>,
) -> Result<(Image, usize, Option<String>)> {
    let full = images[0];
    let full_need = need(&full)?;
    let too_large = match limits.check(path, what, &full_need) {
        Ok(bytes) => return Ok((full, bytes, None)),
        Err(e) => e,
    };
    for o in &images[1..] {
        let Ok(n) = need(o) else { continue };
        if let Ok(bytes) = limits.check(path, what, &n) {
            let note = format!(
                "read the {}×{} overview ({}) of the {}×{} raster: the full {what} needs {}, more than the memory limit of {}",
                o.width,
                o.height,
                human_bytes(bytes as u64),
                full.width,
                full.height,
                human_bytes(full_need.iter().product()),
                human_bytes(limits.bytes())
            );
            return Ok((*o, bytes, Some(note)));
        }
    }
    // None fits. Without overviews, say which would (GDAL's way to read a raster coarser).
    if images.len() == 1 && too_large.kind == crate::ErrorKind::TooLarge {
        let need = full_need.iter().product::<u64>() as f64;
        let factor = (need / limits.bytes().max(1) as f64).sqrt().ceil().max(2.0) as u64;
        let levels: Vec<String> =
            std::iter::successors(Some(2u64), |l| Some(l * 2)).take_while(|&l| l / 2 < factor).map(|l| l.to_string()).collect();
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let message = format!(
            "{}; or add overviews — gdaladdo -r average {name} {} — and the largest that fits is read",
            too_large.message,
            levels.join(" ")
        );
        return Err(FormatError::new(path, too_large.kind, message));
    }
    Err(too_large)
}

/// The decoder (at the full raster, `full`) moved to `image`, checked to hold samples like
/// the full raster's, and readied to decode `bytes`.
fn at_level(
    path: &Path,
    mut d: Decoder<BufReader<std::fs::File>>,
    (full, image): (&Image, &Image),
    layout: (u16, u64),
    bytes: usize,
) -> Result<Decoder<BufReader<std::fs::File>>> {
    if image != full {
        d.seek_to_image(image.index).map_err(|e| tiff_err(path, e))?;
        if sample_layout(path, &mut d)? != layout {
            return Err(FormatError::invalid(path, "an overview's samples differ from the full raster's"));
        }
    }
    ready(path, d, bytes)
}

/// Another decoder of the image at `index` (a level `open_elevation` chose), for decoding
/// its chunks on another thread.
pub(crate) fn reopen(path: &Path, index: usize, bytes: usize) -> Result<Decoder<BufReader<std::fs::File>>> {
    let file = std::fs::File::open(path).map_err(|e| FormatError::io(path, e))?;
    let mut d = Decoder::new(BufReader::new(file)).map_err(|e| tiff_err(path, e))?;
    if index > 0 {
        d.seek_to_image(index).map_err(|e| tiff_err(path, e))?;
    }
    ready(path, d, bytes)
}

/// An overview's georeferencing (centre of its north-west sample, cell size) from the full
/// raster's, as GDAL places it: the same outer corner, cells scaled by the size ratio.
fn level_georeferencing(origin: [f64; 2], scale: [f64; 2], full: &Image, level: &Image) -> ([f64; 2], [f64; 2]) {
    let (lsx, lsy) = (scale[0] * full.width as f64 / level.width as f64, scale[1] * full.height as f64 / level.height as f64);
    ([origin[0] - 0.5 * scale[0] + 0.5 * lsx, origin[1] + 0.5 * scale[1] - 0.5 * lsy], [lsx, lsy])
}

/// The GDAL_NODATA value, where the file declares one.
fn gdal_nodata<R: std::io::Read + std::io::Seek>(path: &Path, d: &mut Decoder<R>) -> Result<Option<f64>> {
    match d.find_tag(Tag::GdalNodata).map_err(|e| tiff_err(path, e))? {
        Some(v) => {
            let s = v.into_string().map_err(|e| tiff_err(path, e))?;
            let t = s.trim_matches(|c: char| c == '\0' || c.is_whitespace());
            Ok(Some(t.parse::<f64>().map_err(|_| FormatError::invalid(path, format!("GDAL_NODATA '{t}' is not a number")))?))
        }
        None => Ok(None),
    }
}

/// A georeferenced image to drape over a terrain: one band of values (NoData as NaN), or
/// RGB / RGBA bytes, interleaved, row by row from the north.
pub enum GeoPixels {
    Values(Vec<f64>),
    Rgb8(Vec<u8>),
    Rgba8(Vec<u8>),
}

pub struct GeoImage {
    pub width: usize,
    pub height: usize,
    pub pixels: GeoPixels,
    pub crs: Crs,
    /// Map coordinates (CRS units) of the centre of pixel (0, 0), the north-west one.
    pub origin: [f64; 2],
    /// Pixel size in CRS units (east, north), both positive.
    pub cell_size_native: [f64; 2],
    pub notes: Vec<String>,
}

/// Reads a GeoTIFF image to drape: one band of any sample type, or 3 or 4 bands of bytes,
/// with its georeferencing (north-up only, as elevation rasters). Where the full image
/// needs more than the memory limit, its largest overview that fits is read instead (an
/// orthophoto over a large DEM), placed as GDAL places it, with a note.
pub fn read_geotiff_image(path: &Path, limits: &Limits) -> Result<GeoImage> {
    let (mut d, images) = open_images(path)?;
    let (spp, sample_bytes) = sample_layout(path, &mut d)?;
    if !matches!(spp, 1 | 3 | 4) {
        return Err(FormatError::unsupported(path, format!("{spp} samples per pixel: a drape has 1 band, or 3 or 4 (RGB, RGBA)")));
    }
    // The tiff crate decodes one plane of a band-interleaved image (GDAL's INTERLEAVE=BAND,
    // which it chooses for some RGB outputs): refused by name, not read as a third.
    if spp > 1 && d.find_tag_unsigned::<u16>(Tag::PlanarConfiguration).map_err(|e| tiff_err(path, e))? == Some(2) {
        return Err(FormatError::unsupported(
            path,
            "bands stored as separate planes (PlanarConfiguration 2); rewrite it pixel-interleaved: gdal_translate -co INTERLEAVE=PIXEL",
        ));
    }
    // The georeferencing is the full image's (a COG's overviews carry none).
    let mut geo = georeferencing(path, &mut d)?;
    let nodata = geo.nodata;
    // Per pixel: the decoded samples, and a band's values as f64.
    let per_pixel = spp as u64 * sample_bytes + if spp == 1 { 8 } else { 0 };
    let (image, bytes, note) = finest_fitting(path, limits, &images, "draped image", |i| Ok([i.width as u64, i.height as u64, per_pixel]))?;
    geo.notes.extend(note);
    (geo.origin, geo.scale) = level_georeferencing(geo.origin, geo.scale, &images[0], &image);
    let mut d = at_level(path, d, (&images[0], &image), (spp, sample_bytes), bytes)?;
    let (w, h) = (image.width, image.height);
    let raw = crate::guard::third_party(path, "the TIFF decoder", || crate::tiff_lzw::read_image(path, &mut d, (w, h), spp as usize))?;
    let n = w as usize * h as usize;
    let pixels = match (spp, raw) {
        (3 | 4, DecodingResult::U8(v)) => {
            if v.len() < n * spp as usize {
                return Err(FormatError::invalid(path, format!("image data holds {} of {} bytes", v.len(), n * spp as usize)));
            }
            if spp == 3 {
                GeoPixels::Rgb8(v[..3 * n].to_vec())
            } else {
                GeoPixels::Rgba8(v[..4 * n].to_vec())
            }
        }
        (3 | 4, _) => return Err(FormatError::unsupported(path, "an RGB(A) drape must have 8-bit samples")),
        (_, raw) => {
            let values: Vec<f64> = match raw {
                DecodingResult::U8(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::I8(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::U16(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::I16(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::U32(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::I32(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::F32(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::F64(v) => v,
                _ => return Err(FormatError::unsupported(path, "sample type is not one of int8/16/32, uint8/16/32, float32/64")),
            };
            if values.len() < n {
                return Err(FormatError::invalid(path, format!("image data holds {} of {n} samples", values.len())));
            }
            let is_nodata = |v: f64| !v.is_finite() || nodata.is_some_and(|nd| v == nd);
            GeoPixels::Values(values[..n].iter().map(|&v| if is_nodata(v) { f64::NAN } else { v }).collect())
        }
    };
    Ok(GeoImage {
        width: w as usize,
        height: h as usize,
        pixels,
        crs: geo.crs,
        origin: geo.origin,
        cell_size_native: geo.scale,
        notes: geo.notes,
    })
}

/// A sample's elevation in metres (f32), `vertical` metres per unit; Err(true) where it
/// is declared NoData (the file's NoData value, NaN), Err(false) where it is out of f32's
/// range once converted (also NoData).
pub(crate) fn sample_metres(v: f64, nodata_value: Option<f64>, vertical: f64) -> std::result::Result<f32, bool> {
    let declared = v.is_nan() || nodata_value.is_some_and(|nd| v == nd || (nd.is_nan() && v.is_nan()));
    let metres = (v * vertical) as f32;
    match (declared, metres.is_finite()) {
        (false, true) => Ok(metres),
        _ => Err(declared),
    }
}

/// Samples to elevations in metres (f32), NoData (declared, NaN, or out of f32's range) as
/// NaN and flagged; the flags are allocated at the first NoData sample.
struct Metres {
    nodata_value: Option<f64>,
    vertical: f64,
    n: usize,
    nodata: NodataMask,
    not_finite: usize,
}

impl Metres {
    fn metres(&mut self, i: usize, v: f64) -> f32 {
        match sample_metres(v, self.nodata_value, self.vertical) {
            Ok(m) => m,
            Err(declared) => {
                self.not_finite += usize::from(!declared);
                if self.nodata.is_empty() {
                    self.nodata = NodataMask::new(self.n);
                }
                self.nodata.set(i, true);
                f32::NAN
            }
        }
    }

    /// The first n samples converted (fewer when the image holds fewer: the caller refuses).
    fn convert<T: Copy>(&mut self, v: &[T], to_f64: impl Fn(T) -> f64) -> Vec<f32> {
        v.iter().take(self.n).enumerate().map(|(i, &x)| self.metres(i, to_f64(x))).collect()
    }
}

/// What to read of a GeoTIFF elevation raster.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct GeoTiffOptions {
    /// Only the samples whose centres lie in [west, south, east, north] (CRS units): the
    /// tiles or strips holding them are decoded, no others.
    pub extent: Option<[f64; 4]>,
    /// Read this level only — 0 the full raster, k its k-th overview, largest first —
    /// refused where its window passes the memory limit; None: the finest level whose
    /// window fits. A caller that placed the data before reading it (the scene's view
    /// windows) fixes the level so that a read later, with other memory in use, cannot
    /// move it.
    pub level: Option<usize>,
}

/// Columns and rows [c0, c1] × [r0, r1] (inclusive) of a w × h raster, origin (ox, oy) at
/// the centre of its north-west sample and cells (sx, sy), whose sample centres lie in
/// `extent` (1e-9 cell of slack for rounding); None where none do.
fn window_of(extent: [f64; 4], (ox, oy): (f64, f64), (sx, sy): (f64, f64), (w, h): (u32, u32)) -> Option<[u32; 4]> {
    let [west, south, east, north] = extent;
    const SLACK: f64 = 1e-9;
    let c0 = ((west - ox) / sx - SLACK).ceil().max(0.0);
    let c1 = ((east - ox) / sx + SLACK).floor().min(w as f64 - 1.0);
    let r0 = ((oy - north) / sy - SLACK).ceil().max(0.0);
    let r1 = ((oy - south) / sy + SLACK).floor().min(h as f64 - 1.0);
    (c0 <= c1 && r0 <= r1).then_some([c0 as u32, r0 as u32, c1 as u32, r1 as u32])
}

/// The sample type of decoded data, as GDAL names it.
fn type_name(raw: &DecodingResult) -> &'static str {
    match raw {
        DecodingResult::U8(_) => "uint8",
        DecodingResult::I8(_) => "int8",
        DecodingResult::U16(_) => "uint16",
        DecodingResult::I16(_) => "int16",
        DecodingResult::U32(_) => "uint32",
        DecodingResult::I32(_) => "int32",
        DecodingResult::F32(_) => "float32",
        DecodingResult::F64(_) => "float64",
        _ => "other",
    }
}

/// Sample k of a decoded chunk as f64.
#[inline]
pub(crate) fn sample_f64(raw: &DecodingResult, k: usize) -> f64 {
    match raw {
        DecodingResult::U8(v) => v[k] as f64,
        DecodingResult::I8(v) => v[k] as f64,
        DecodingResult::U16(v) => v[k] as f64,
        DecodingResult::I16(v) => v[k] as f64,
        DecodingResult::U32(v) => v[k] as f64,
        DecodingResult::I32(v) => v[k] as f64,
        DecodingResult::F32(v) => v[k] as f64,
        DecodingResult::F64(v) => v[k],
        _ => f64::NAN,
    }
}

/// A decoded tile or strip: its samples, the data's width and rows (edge tiles hold fewer
/// than a full tile's), and the samples between the starts of its rows.
pub(crate) struct Chunk {
    pub(crate) raw: DecodingResult,
    pub(crate) width: usize,
    pub(crate) rows: usize,
    pub(crate) stride: usize,
}

/// Chunk (`tx`, `ty`) of the decoder's current image, chunks `cw` samples wide and
/// `across` to a row, decoded (LZW chunks the tiff crate fails through `tiff_lzw`) and
/// checked to hold its rows.
pub(crate) fn read_chunk_at<R: std::io::Read + std::io::Seek>(
    path: &Path,
    d: &mut Decoder<R>,
    (tx, ty): (u32, u32),
    (cw, across): (u32, u32),
) -> Result<Chunk> {
    let index = ty.checked_mul(across).and_then(|i| i.checked_add(tx)).ok_or_else(|| FormatError::invalid(path, "too many TIFF chunks"))?;
    let (raw, (dw, dh)) = crate::guard::third_party(path, "the TIFF decoder", || {
        let raw = crate::tiff_lzw::read_chunk(path, d, index)?;
        Ok((raw, d.chunk_data_dimensions(index)))
    })?;
    let len = match &raw {
        DecodingResult::U8(v) => v.len(),
        DecodingResult::I8(v) => v.len(),
        DecodingResult::U16(v) => v.len(),
        DecodingResult::I16(v) => v.len(),
        DecodingResult::U32(v) => v.len(),
        DecodingResult::I32(v) => v.len(),
        DecodingResult::F32(v) => v.len(),
        DecodingResult::F64(v) => v.len(),
        _ => return Err(FormatError::unsupported(path, "sample type is not one of int8/16/32, uint8/16/32, float32/64")),
    };
    let (dw, dh) = (dw as usize, dh as usize);
    if dw == 0 || dh == 0 {
        return Err(FormatError::invalid(path, format!("chunk {index} is empty")));
    }
    // Tiles at the right and bottom edges may be stored whole or clipped.
    let stride = if len >= cw as usize * dh { cw as usize } else { dw };
    if len < stride * (dh - 1) + dw {
        return Err(FormatError::invalid(path, format!("chunk {index} holds {len} samples, fewer than its {dw}×{dh}")));
    }
    Ok(Chunk { raw, width: dw, rows: dh, stride })
}

/// The samples of `window` ([c0, r0, c1, r1], inclusive) of the decoder's current w × h
/// image in metres, decoding only the chunks (tiles or strips) that hold them.
fn read_window(
    path: &Path,
    d: &mut Decoder<BufReader<std::fs::File>>,
    w: u32,
    window: [u32; 4],
    conv: &mut Metres,
) -> Result<(Vec<f32>, &'static str)> {
    let [c0, r0, c1, r1] = window;
    let ww = (c1 - c0 + 1) as usize;
    let mut out = vec![f32::NAN; ww * (r1 - r0 + 1) as usize];
    let (cw, ch) = crate::guard::third_party(path, "the TIFF decoder", || {
        let (cw, ch) = d.chunk_dimensions();
        if cw == 0 || ch == 0 {
            return Err(FormatError::invalid(path, "TIFF tiles or strips of size 0"));
        }
        Ok((cw, ch))
    })?;
    let across = w.div_ceil(cw);
    let mut data_type = "other";
    let mut written = 0usize;
    for ty in r0 / ch..=r1 / ch {
        for tx in c0 / cw..=c1 / cw {
            let Chunk { raw, width: dw, rows: dh, stride } = read_chunk_at(path, d, (tx, ty), (cw, across))?;
            data_type = type_name(&raw);
            let (dw, dh) = (dw as u32, dh as u32);
            let (x0, y0) = (tx * cw, ty * ch);
            for y in y0.max(r0)..y0.saturating_add(dh).min(r1 + 1) {
                for x in x0.max(c0)..x0.saturating_add(dw).min(c1 + 1) {
                    let i = (y - r0) as usize * ww + (x - c0) as usize;
                    out[i] = conv.metres(i, sample_f64(&raw, (y - y0) as usize * stride + (x - x0) as usize));
                    written += 1;
                }
            }
        }
    }
    if written != out.len() {
        return Err(FormatError::invalid(path, format!("the tiles or strips cover {written} of the window's {} samples", out.len())));
    }
    Ok((out, data_type))
}

/// Reads a GeoTIFF elevation raster in metres. Where the full-resolution raster needs more
/// memory than `limits` allow and the file has overviews (`gdaladdo`, a Cloud-Optimised
/// GeoTIFF), the largest overview that fits is read instead, with a note: its cells are
/// the full raster's scaled by the size ratio, its corner the same (GDAL's rule), so it
/// lies exactly where the full raster does.
pub fn read_geotiff(path: &Path, limits: &Limits) -> Result<Heightfield> {
    read_geotiff_with(path, &GeoTiffOptions::default(), limits)
}

/// A GeoTIFF elevation raster opened at the level and window to read, its georeferencing
/// settled; nothing decoded yet.
pub(crate) struct Opened {
    pub(crate) d: Decoder<BufReader<std::fs::File>>,
    /// The level's directory and the decoder's buffer limit: for `reopen`.
    pub(crate) image_index: usize,
    pub(crate) decoder_bytes: usize,
    /// The level's size in samples (its chunks are numbered across it).
    pub(crate) level: [u32; 2],
    /// Columns and rows [c0, r0, c1, r1] (inclusive) of the level read.
    pub(crate) win: [u32; 4],
    /// The centre of the window's north-west sample and the level's cells (CRS units).
    pub(crate) origin: [f64; 2],
    pub(crate) scale: [f64; 2],
    pub(crate) crs: Crs,
    pub(crate) nodata_value: Option<f64>,
    /// Metres per unit of the file's values.
    pub(crate) vertical: f64,
    pub(crate) sample_bytes: u64,
    pub(crate) notes: Vec<String>,
    /// What `info` shows of the storage, after the data type (see `Opened::attributes`).
    pub(crate) storage: Vec<(String, String)>,
    /// The level read (0 the full raster, k its k-th overview) and how many the file has.
    pub(crate) level_number: usize,
    pub(crate) levels: usize,
    /// The full raster's size, the centre of its north-west sample and its cells.
    pub(crate) full: ([u32; 2], [f64; 2], [f64; 2]),
}

impl Opened {
    pub(crate) fn size(&self) -> (u32, u32) {
        (self.win[2] - self.win[0] + 1, self.win[3] - self.win[1] + 1)
    }

    /// `info`'s attributes of the raster, given its data type.
    pub(crate) fn attributes(&self, data_type: &str) -> Vec<(String, String)> {
        let mut a = vec![("data type".to_string(), data_type.to_string())];
        a.extend(self.storage.iter().cloned());
        a
    }
}

/// What a caller holds (bytes) for a number of samples it reads: textures of so many bytes a
/// sample, say, and buffers or working memory that do not grow with them.
pub type HeldBytes<'a> = &'a dyn Fn(u64) -> u64;

/// Opens a GeoTIFF elevation raster at the finest level (the full raster or an overview)
/// whose window (`opts.extent`, else the whole level) fits the memory limit when the caller
/// holds `held(samples)` bytes for the window's samples (None: the decoded samples' size).
pub(crate) fn open_elevation(path: &Path, opts: &GeoTiffOptions, limits: &Limits, held: Option<HeldBytes>) -> Result<Opened> {
    let (mut d, images) = open_images(path)?;
    let (spp, sample_bytes) = sample_layout(path, &mut d)?;
    if spp != 1 {
        return Err(FormatError::unsupported(path, format!("{spp} samples per pixel: an elevation raster has one band")));
    }
    let full = images[0];
    let Georeferencing { keys, crs, origin: [ox, oy], scale: [sx, sy], point, nodata: nodata_value, mut notes, sources } =
        georeferencing(path, &mut d)?;
    let full_geo = ([full.width, full.height], [ox, oy], [sx, sy]);
    // Each level's georeferencing: an overview's cells are the full raster's scaled by the
    // size ratio, its corner the same.
    let level_geo = |i: &Image| {
        let ([lox, loy], [lsx, lsy]) = level_georeferencing([ox, oy], [sx, sy], &full, i);
        (lox, loy, lsx, lsy)
    };
    // Each level's window: the whole image, or the samples inside the extent.
    let window = |i: &Image| -> Result<[u32; 4]> {
        match opts.extent {
            None => Ok([0, 0, i.width - 1, i.height - 1]),
            Some(extent) => {
                let (lox, loy, lsx, lsy) = level_geo(i);
                window_of(extent, (lox, loy), (lsx, lsy), (i.width, i.height)).ok_or_else(|| {
                    let bounds = [ox - 0.5 * sx, oy - (full.height as f64 - 0.5) * sy, ox + (full.width as f64 - 0.5) * sx, oy + 0.5 * sy];
                    FormatError::invalid(path, format!("extent {extent:?} holds no sample of the raster, whose bounds are {bounds:?}"))
                })
            }
        }
    };
    let need = |i: &Image| {
        window(i).map(|win| {
            let samples = (win[2] - win[0] + 1) as u64 * (win[3] - win[1] + 1) as u64;
            match held {
                Some(held) => [held(samples), 1, 1],
                None => [samples, sample_bytes, 1],
            }
        })
    };
    let what = match (opts.extent.is_some(), held.is_some()) {
        (true, false) => "elevation raster's window",
        (false, false) => "elevation raster",
        // The caller's own copies (a GPU's textures, say) are what is counted.
        (true, true) => "elevation raster's window, as its renderer holds it,",
        (false, true) => "elevation raster, as its renderer holds it,",
    };
    let candidates = match opts.level {
        None => &images[..],
        Some(k) if k < images.len() => &images[k..=k],
        Some(k) => {
            return Err(FormatError::invalid(
                path,
                format!("level {k} asked for, but the raster has {} (the full raster and its overviews)", images.len()),
            ))
        }
    };
    let (image, bytes, note) = finest_fitting(path, limits, candidates, what, need)?;
    let level_number = images.iter().position(|i| *i == image).unwrap_or(0);
    notes.extend(note);
    let win = window(&image)?;
    let mut d = at_level(path, d, (&full, &image), (spp, sample_bytes), bytes)?;
    let (ox, oy, sx, sy) = level_geo(&image);
    // The window's north-west sample.
    let origin = [ox + win[0] as f64 * sx, oy - win[1] as f64 * sy];
    // What gdalinfo users look for: the storage, before the image is read.
    let compression = match d.get_tag_u32(tiff::tags::Tag::Compression).unwrap_or(1) {
        1 => "none".to_string(),
        5 => "LZW".into(),
        8 | 32946 => "Deflate".into(),
        32773 => "PackBits".into(),
        34887 => "LERC".into(),
        50000 => "ZSTD".into(),
        7 => "JPEG".into(),
        other => format!("code {other}"),
    };
    if compression == "LERC" {
        // No Rust crate decodes LERC (GDAL's limited-error raster compression).
        return Err(FormatError::unsupported(
            path,
            "compression LERC is not supported (no Rust decoder): convert with gdal_translate -co COMPRESS=ZSTD",
        ));
    }
    let predictor = d.get_tag_u32(tiff::tags::Tag::Predictor).unwrap_or(1);
    let layout = match (d.get_tag_u32(tiff::tags::Tag::TileWidth), d.get_tag_u32(tiff::tags::Tag::TileLength)) {
        (Ok(tw), Ok(th)) => format!("tiles of {tw}×{th}"),
        _ => "strips".into(),
    };
    let mut storage = vec![
        ("compression".to_string(), if predictor > 1 { format!("{compression}, predictor {predictor}") } else { compression.clone() }),
        ("layout".to_string(), layout),
        ("raster type".to_string(), if point { "PixelIsPoint".into() } else { "PixelIsArea".into() }),
    ];
    storage.extend(sources);
    if images.len() > 1 {
        let sizes: Vec<String> = images[1..].iter().map(|o| format!("{}×{}", o.width, o.height)).collect();
        storage.push(("overviews".to_string(), sizes.join(", ")));
    }
    if win != [0, 0, image.width - 1, image.height - 1] {
        storage.push(("window".to_string(), format!("columns {}..={}, rows {}..={}", win[0], win[2], win[1], win[3])));
    }
    let vertical = match short_key(&keys, KEY_VERTICAL_UNITS) {
        Some(9002) => {
            notes.push("vertical unit: foot, converted to metres".into());
            0.3048
        }
        Some(9003) => {
            notes.push("vertical unit: US survey foot, converted to metres".into());
            1200.0 / 3937.0
        }
        _ => 1.0,
    };
    Ok(Opened {
        d,
        image_index: image.index,
        decoder_bytes: bytes,
        level: [image.width, image.height],
        win,
        origin,
        scale: [sx, sy],
        crs,
        nodata_value,
        vertical,
        sample_bytes,
        notes,
        storage,
        level_number,
        levels: images.len(),
        full: full_geo,
    })
}

/// Where a read of a GeoTIFF elevation raster would come from, found without reading its
/// samples: what `open_elevation` chooses for `opts` where the caller holds `held(samples)`
/// bytes (None: the decoded samples' size), and the full raster's grid beside it.
#[derive(Debug, Clone, PartialEq)]
pub struct ElevationPlan {
    /// The level chosen (0 the full raster, k its k-th overview, largest first) and how
    /// many the file has.
    pub level: usize,
    pub levels: usize,
    /// The chosen level's size, and the window's columns and rows [c0, r0, c1, r1]
    /// (inclusive) in it.
    pub level_size: [u32; 2],
    pub window: [u32; 4],
    /// The centre of the window's north-west sample and the level's cells (CRS units).
    pub origin: [f64; 2],
    pub cell_size_native: [f64; 2],
    /// The full raster's size, the centre of its north-west sample and its cells.
    pub full_size: [u32; 2],
    pub full_origin: [f64; 2],
    pub full_cell_size_native: [f64; 2],
    pub crs: Crs,
}

pub fn elevation_plan(path: &Path, opts: &GeoTiffOptions, limits: &Limits, held: Option<HeldBytes>) -> Result<ElevationPlan> {
    let o = open_elevation(path, opts, limits, held)?;
    let (full_size, full_origin, full_cell_size_native) = o.full;
    Ok(ElevationPlan {
        level: o.level_number,
        levels: o.levels,
        level_size: o.level,
        window: o.win,
        origin: o.origin,
        cell_size_native: o.scale,
        full_size,
        full_origin,
        full_cell_size_native,
        crs: o.crs,
    })
}

/// As `read_geotiff`, of `opts.extent` only where given: the window of samples inside it,
/// at the finest level (the full raster or an overview) whose window fits the limit.
pub fn read_geotiff_with(path: &Path, opts: &GeoTiffOptions, limits: &Limits) -> Result<Heightfield> {
    let mut o = open_elevation(path, opts, limits, None)?;
    let (w, h) = o.size();
    let n = w as usize * h as usize;
    let mut conversion = Metres { nodata_value: o.nodata_value, vertical: o.vertical, n, nodata: NodataMask::default(), not_finite: 0 };
    if o.win != [0, 0, o.level[0] - 1, o.level[1] - 1] {
        // A window: only the chunks that hold it.
        let (elevations, data_type) = read_window(path, &mut o.d, o.level[0], o.win, &mut conversion)?;
        let attributes = o.attributes(data_type);
        let Opened { origin, scale, crs, nodata_value, notes, .. } = o;
        return finish(path, Raster { w, h, origin, scale, crs, elevations, nodata_value, notes, attributes }, conversion);
    }
    let raw = match crate::guard::third_party(path, "the TIFF decoder", || Ok(o.d.read_image()))
        .map(|r| r.map_err(|e| (crate::tiff_lzw::is_lzw_end_error(&e), e)))
    {
        Ok(Ok(raw)) => raw,
        // An LZW chunk the tiff crate cannot finish: the raster read chunk by chunk, each
        // such chunk decoded by `tiff_lzw`.
        Ok(Err((true, _))) => {
            let (elevations, data_type) = read_window(path, &mut o.d, o.level[0], o.win, &mut conversion)?;
            let attributes = o.attributes(data_type);
            let Opened { origin, scale, crs, nodata_value, notes, .. } = o;
            return finish(path, Raster { w, h, origin, scale, crs, elevations, nodata_value, notes, attributes }, conversion);
        }
        Ok(Err((false, e))) => return Err(tiff_err(path, e)),
        Err(e) => return Err(e),
    };
    let attributes = o.attributes(type_name(&raw));
    // Each sample to metres as f32 straight from the decoded type: no f64 copy of the raster
    // (at the peak that copy alone was twice the f32 elevations), and float32 samples are
    // converted in place.
    let elevations: Vec<f32> = match raw {
        DecodingResult::U8(v) => conversion.convert(&v, f64::from),
        DecodingResult::I8(v) => conversion.convert(&v, f64::from),
        DecodingResult::U16(v) => conversion.convert(&v, f64::from),
        DecodingResult::I16(v) => conversion.convert(&v, f64::from),
        DecodingResult::U32(v) => conversion.convert(&v, f64::from),
        DecodingResult::I32(v) => conversion.convert(&v, f64::from),
        DecodingResult::F32(mut v) if v.len() >= n => {
            v.truncate(n);
            for (i, x) in v.iter_mut().enumerate() {
                *x = conversion.metres(i, *x as f64);
            }
            v
        }
        DecodingResult::F32(v) => conversion.convert(&v, f64::from),
        DecodingResult::F64(v) => conversion.convert(&v, |x| x),
        _ => return Err(FormatError::unsupported(path, "sample type is not one of int8/16/32, uint8/16/32, float32/64")),
    };
    if elevations.len() < n {
        return Err(FormatError::invalid(path, format!("image data holds {} of {n} samples", elevations.len())));
    }
    let Opened { origin, scale, crs, nodata_value, notes, .. } = o;
    finish(path, Raster { w, h, origin, scale, crs, elevations, nodata_value, notes, attributes }, conversion)
}

/// A raster read, before its cell size in metres and its notes are settled.
struct Raster {
    w: u32,
    h: u32,
    origin: [f64; 2],
    scale: [f64; 2],
    crs: Crs,
    elevations: Vec<f32>,
    nodata_value: Option<f64>,
    notes: Vec<String>,
    attributes: Vec<(String, String)>,
}

/// The heightfield of a raster read: cell size in metres (from degrees at the centre
/// latitude for a geographic CRS), NoData flags and notes.
fn finish(path: &Path, raster: Raster, conversion: Metres) -> Result<Heightfield> {
    let Raster { w, h, origin, scale, crs, elevations, nodata_value, mut notes, attributes } = raster;
    let Metres { nodata, not_finite, .. } = conversion;
    if not_finite > 0 {
        notes.push(format!("{not_finite} infinite or out-of-range sample(s) treated as NoData"));
    }
    let cell_size = cell_size_metres(path, &crs, origin[1], h, scale, &mut notes)?;
    Ok(Heightfield {
        width: w as usize,
        height: h as usize,
        cell_size,
        cell_size_native: scale,
        origin,
        crs,
        elevations,
        nodata,
        nodata_value,
        notes,
        attributes,
        units: GridUnits::METRES,
    })
}

/// Metres between samples (east, north) of `h` rows whose northern row's centre lies at
/// map y `oy`, cells `[sx, sy]` in CRS units: converted from degrees at the centre latitude
/// (with a note) for a geographic CRS.
pub(crate) fn cell_size_metres(path: &Path, crs: &Crs, oy: f64, h: u32, [sx, sy]: [f64; 2], notes: &mut Vec<String>) -> Result<[f64; 2]> {
    let cell_size = if crs.geographic {
        let centre_lat = oy - 0.5 * (h as f64 - 1.0) * sy;
        if !(-90.0..=90.0).contains(&centre_lat) {
            return Err(FormatError::invalid(path, format!("geographic raster centred at latitude {centre_lat}°, outside ±90°")));
        }
        let (mx, my) = metres_per_degree(centre_lat);
        notes.push(format!(
            "geographic CRS: cell size {sx}°×{sy}° converted to {:.3} m × {:.3} m at the centre latitude {centre_lat:.5}°",
            sx * mx,
            sy * my
        ));
        [sx * mx, sy * my]
    } else {
        [sx * crs.metres_per_unit, sy * crs.metres_per_unit]
    };
    if !cell_size.iter().all(|c| c.is_finite() && *c > 0.0) {
        return Err(FormatError::invalid(path, format!("cell size {cell_size:?} m is not positive and finite")));
    }
    Ok(cell_size)
}

pub use crate::geotiff_write::{write_band, write_geotiff, Band};
