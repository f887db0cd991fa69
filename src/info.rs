//! `volterra info`: what a reader made of a file, as text or as one JSON object.

use serde_json::{json, Value};
use volterra_formats::geotiff_rows::GeoTiffRows;
use volterra_formats::heightfield::{summarise, GridGeoref, RowsSummary};
use volterra_formats::{dicom, Dataset, Heightfield, ParticleArrayNames, ParticleSet, Volume};

/// A number as people read it: integers without decimals, others to 6 significant digits
/// with trailing zeros dropped (no `563.2000122070312` from an f32).
pub fn num(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    if v == v.trunc() && v.abs() < 1e15 {
        return format!("{v:.0}");
    }
    let mag = v.abs().log10().floor() as i32;
    if !(-4..9).contains(&mag) {
        return format!("{v:.5e}");
    }
    let decimals = (5 - mag).max(0) as usize;
    let t = format!("{v:.decimals$}");
    let t = if t.contains('.') { t.trim_end_matches('0').trim_end_matches('.').to_string() } else { t };
    if t == "-0" {
        "0".into()
    } else {
        t
    }
}

/// The orientation string (nibabel's axis codes): where each voxel axis points in RAS+.
pub fn orientation(affine: &[[f64; 4]; 4]) -> String {
    (0..3)
        .map(|c| {
            let col = [affine[0][c], affine[1][c], affine[2][c]];
            let k = (0..3).max_by(|&a, &b| col[a].abs().total_cmp(&col[b].abs())).unwrap();
            let (pos, neg) = [('R', 'L'), ('A', 'P'), ('S', 'I')][k];
            if col[k] >= 0.0 {
                pos
            } else {
                neg
            }
        })
        .collect()
}

/// The raster's outer corners in CRS units (gdalinfo's Upper Left … Lower Right, and the
/// centre): sample centres are `origin + (col, −row) · cell`, so the edges lie half a cell out.
pub fn corners(g: &GridGeoref) -> [(&'static str, [f64; 2]); 5] {
    let [sx, sy] = g.cell_size_native;
    let (west, north) = (g.origin[0] - 0.5 * sx, g.origin[1] + 0.5 * sy);
    let (east, south) = (west + g.width as f64 * sx, north - g.height as f64 * sy);
    [
        ("upper left", [west, north]),
        ("lower left", [west, south]),
        ("upper right", [east, north]),
        ("lower right", [east, south]),
        ("centre", [0.5 * (west + east), 0.5 * (north + south)]),
    ]
}

/// What `info` shows of an elevation raster, whether held (`Heightfield`) or read by rows
/// (`GeoTiffRows`, which finds the range, statistics and NoData count in one pass over its
/// rows).
pub struct GridSummary<'a> {
    pub georef: GridGeoref,
    pub attributes: &'a [(String, String)],
    pub nodata_value: Option<f64>,
    pub notes: &'a [String],
    /// One pass over the valid samples: range, mean and standard deviation, NoData count.
    pub summary: RowsSummary,
}

impl<'a> GridSummary<'a> {
    pub fn of_heightfield(h: &'a Heightfield) -> GridSummary<'a> {
        GridSummary { georef: h.georef(), attributes: &h.attributes, nodata_value: h.nodata_value, notes: &h.notes, summary: summarise(h) }
    }
    /// Reads every row of the raster the first time (see `GeoTiffRows::summary`).
    pub fn of_rows(r: &'a GeoTiffRows) -> GridSummary<'a> {
        GridSummary {
            georef: r.georef().clone(),
            attributes: &r.attributes,
            nodata_value: r.nodata_value,
            notes: &r.notes,
            summary: r.summary(),
        }
    }
}

/// A map coordinate as gdalinfo prints it: to the millimetre in projected (and local)
/// units, to 1e-7 in degrees.
pub fn coordinate(v: f64, geographic: bool) -> String {
    if geographic {
        format!("{v:.7}")
    } else {
        format!("{v:.3}")
    }
}

/// GDAL's geotransform of the grid: the north-west sample's outer corner and the steps of a
/// column and a row (north-up: [x0, sx, 0, y0, 0, −sy]).
pub fn geotransform(g: &GridGeoref) -> [f64; 6] {
    let [sx, sy] = g.cell_size_native;
    [g.origin[0] - 0.5 * sx, sx, 0.0, g.origin[1] + 0.5 * sy, 0.0, -sy]
}

fn attributes_json(a: &[(String, String)]) -> Value {
    Value::Object(a.iter().map(|(k, v)| (k.clone(), Value::String(v.clone()))).collect())
}

pub fn volume_json(v: &Volume) -> Value {
    let (min, max) = v.value_range().unwrap_or((f64::NAN, f64::NAN));
    json!({
        "kind": "volume",
        "orientation": orientation(&v.affine),
        "attributes": attributes_json(&v.attributes),
        "dims": v.dims,
        "spacing": v.spacing,
        "affine": v.affine,
        "dtype": v.data.scalar_type().name(),
        "rescale": { "slope": v.rescale.slope, "intercept": v.rescale.intercept },
        "modality": v.modality,
        "units": v.units,
        "min": min,
        "max": max,
        "volume_count": v.volume_count,
        "volume_index": v.volume_index,
        "notes": v.notes,
    })
}

pub fn heightfield_json(h: &Heightfield) -> Value {
    grid_json(&GridSummary::of_heightfield(h))
}

pub fn grid_json(s: &GridSummary) -> Value {
    let g = &s.georef;
    let (min, max) = s.summary.range.map_or((Value::Null, Value::Null), |(a, b)| (json!(a as f64), json!(b as f64)));
    let corner_map: serde_json::Map<String, Value> = corners(g).iter().map(|(n, c)| (n.replace(' ', "_"), json!(c))).collect();
    // The corners in longitude and latitude, where the CRS is one converted here.
    let lonlat: Option<serde_json::Map<String, Value>> = corners(g)
        .iter()
        .map(|(n, [x, y])| volterra_formats::projection::lonlat(&g.crs, *x, *y).map(|ll| (n.replace(' ', "_"), json!(ll))))
        .collect();
    let w = g.width as u64 * g.height as u64;
    let mut v = json!({
        "kind": "heightfield",
        "attributes": attributes_json(s.attributes),
        "corners": corner_map,
        "corners_lonlat": lonlat,
        "geotransform": geotransform(g),
        "dims": [g.width, g.height],
        "cell_size": g.cell_size,
        "cell_size_native": g.cell_size_native,
        "cell_size_unit": g.units.cell_size_unit(),
        "elevation_unit": g.units.elevation_unit(),
        "origin": g.origin,
        "crs": g.crs.description,
        "epsg": g.crs.epsg,
        "geographic": g.crs.geographic,
        "nodata_value": s.nodata_value,
        "nodata_count": s.summary.nodata,
        "valid_count": w - s.summary.nodata as u64,
        "min": min,
        "max": max,
        "notes": s.notes,
    });
    if let Some((mean, std)) = s.summary.mean_std {
        v["mean"] = json!(mean);
        v["std_dev"] = json!(std);
    }
    v
}

pub fn particles_json(p: &ParticleSet, names: &ParticleArrayNames) -> Value {
    let bounds = p.bounds().map(|(lo, hi)| json!([lo, hi]));
    json!({
        "kind": "particles",
        "count": p.len(),
        "non_finite_positions": p.non_finite_positions().0,
        "arrays": p.array_names(names),
        "bounds": bounds,
        "notes": p.notes,
    })
}

pub fn dataset_json(d: &Dataset, names: &ParticleArrayNames) -> Value {
    match d {
        Dataset::Volume(v) => volume_json(v),
        Dataset::Heightfield(h) => heightfield_json(h),
        Dataset::Particles(p) => particles_json(p, names),
    }
}

pub fn series_json(list: &[dicom::SeriesSummary]) -> Value {
    json!({ "kind": "dicom_series_list", "series": list })
}

fn fmt3(v: [f64; 3]) -> String {
    format!("{} × {} × {}", num(v[0]), num(v[1]), num(v[2]))
}

/// What `info` prints of a raster, in gdalinfo's terms: coordinates to the millimetre (or
/// 1e-7°), the geotransform, corners in longitude and latitude too where the CRS is one
/// converted here, and with `stats` the mean and standard deviation as `gdalinfo -stats`.
pub fn grid_text(sm: &GridSummary, stats: bool) -> String {
    let g = &sm.georef;
    let geo = g.crs.geographic;
    let c = |v: f64| coordinate(v, geo);
    let mut s = String::new();
    s += &format!("heightfield {} × {} samples\n", g.width, g.height);
    let (cell_unit, elevation_unit) = (g.units.cell_size_unit(), g.units.elevation_unit());
    s += &format!("cell size   {} {cell_unit} × {} {cell_unit}", num(g.cell_size[0]), num(g.cell_size[1]));
    if geo {
        s += &format!(" (from {}° × {}°)", g.cell_size_native[0], g.cell_size_native[1]);
    }
    s += "\n";
    s += &format!("origin      {}, {} (centre of the north-west sample, CRS units)\n", c(g.origin[0]), c(g.origin[1]));
    let t = geotransform(g);
    s += &format!(
        "transform   {}, {}, 0, {}, 0, {} (GDAL's geotransform: the north-west corner, a column's and a row's step)\n",
        c(t[0]),
        t[1],
        c(t[3]),
        t[5]
    );
    s += &format!("crs         {}\n", g.crs.description);
    attributes_text(&mut s, sm.attributes);
    let corners = corners(g);
    s += &format!(
        "bounds      west {}, south {}, east {}, north {} (CRS units)\n",
        c(corners[0].1[0]),
        c(corners[3].1[1]),
        c(corners[3].1[0]),
        c(corners[0].1[1])
    );
    for (name, [x, y]) in corners {
        // gdalinfo's "(%12.3f,%12.3f)" (degrees "%12.7f").
        s += &format!("{:<11} ({:>12},{:>12})", name, c(x), c(y));
        // Longitude and latitude of the corners (a geographic raster's are its
        // coordinates), in degrees, minutes and seconds as gdalinfo prints them.
        if let Some([lon, lat]) = volterra_formats::projection::lonlat(&g.crs, x, y) {
            s += &format!(" ({}, {})", volterra_formats::projection::dms(lon, "WE"), volterra_formats::projection::dms(lat, "SN"));
        }
        s += "\n";
    }
    if !geo && g.crs.epsg.is_some() && !volterra_formats::projection::knows(&g.crs) {
        s += "            (longitude and latitude: volterra converts UTM and Web Mercator only; gdalinfo gives them for any CRS)\n";
    }
    match sm.summary.range {
        Some((min, max)) => s += &format!("elevation   {} .. {} {elevation_unit}\n", num(min as f64), num(max as f64)),
        None => s += "elevation   no valid samples (every sample is NoData)\n",
    }
    if let (true, Some((mean, std))) = (stats, sm.summary.mean_std) {
        let valid = g.width * g.height - sm.summary.nodata;
        s += &format!(
            "statistics  mean {mean:.3} {elevation_unit}, standard deviation {std:.3} {elevation_unit} over {valid} valid samples (as gdalinfo -stats)\n"
        );
    }
    let value = sm.nodata_value.map(num).unwrap_or_else(|| "none declared".into());
    s += &format!("nodata      {} samples (value {value})\n", sm.summary.nodata);
    for n in sm.notes {
        s += &format!("note        {n}\n");
    }
    s
}

fn attributes_text(s: &mut String, a: &[(String, String)]) {
    for (k, v) in a {
        *s += &format!("{k:<11} {v}\n");
    }
}

/// A human-readable summary.
pub fn dataset_text(d: &Dataset, names: &ParticleArrayNames, stats: bool) -> String {
    let mut s = String::new();
    match d {
        Dataset::Volume(v) => {
            let (min, max) = v.value_range().unwrap_or((f64::NAN, f64::NAN));
            s += &format!("volume      {} × {} × {} voxels, {}\n", v.dims[0], v.dims[1], v.dims[2], v.data.scalar_type().name());
            s += &format!("spacing     {} mm\n", fmt3(v.spacing));
            s += &format!("orientation {} (where the voxel axes i, j, k point in RAS+)\n", orientation(&v.affine));
            s += "affine      (voxel index → RAS+ mm)\n";
            for r in &v.affine {
                s += &format!("            [{:>12.6} {:>12.6} {:>12.6} {:>12.6}]\n", r[0], r[1], r[2], r[3]);
            }
            s += &format!("rescale     value = {} · stored + {}\n", num(v.rescale.slope), num(v.rescale.intercept));
            s += &format!("modality    {}\n", v.modality.as_deref().unwrap_or("-"));
            s += &format!("range       {} .. {} {}\n", num(min), num(max), v.units.as_deref().unwrap_or(""));
            attributes_text(&mut s, &v.attributes);
            if v.volume_count > 1 {
                s += &format!("volumes     {} (showing {})\n", v.volume_count, v.volume_index);
            }
            for n in &v.notes {
                s += &format!("note        {n}\n");
            }
        }
        Dataset::Heightfield(h) => s += &grid_text(&GridSummary::of_heightfield(h), stats),
        Dataset::Particles(p) => {
            let (non_finite, _) = p.non_finite_positions();
            s += &format!("particles   {}", p.len());
            if non_finite > 0 {
                s += &format!(" ({non_finite} at positions that are not finite)");
            }
            s += "\n";
            s += &format!("arrays      {}\n", p.array_names(names).join(", "));
            if let Some((lo, hi)) = p.bounds() {
                s += &format!("bounds      {:?} .. {:?}{}\n", lo, hi, if non_finite > 0 { " (of the finite positions)" } else { "" });
            }
            for n in &p.notes {
                s += &format!("note        {n}\n");
            }
        }
    }
    s
}

/// What `volterra info` says of one step of a time series: its time and file, its size
/// (particles, or voxels) and the range of each scalar (a volume's values; a particle set's
/// density, mass, h and every one-component point array).
pub fn step_json(step: &volterra_formats::series::TimeStep, d: &Dataset, names: &ParticleArrayNames) -> Value {
    let range = |v: &mut dyn Iterator<Item = f64>| volterra_formats::finite_range(v).map_or(Value::Null, |(lo, hi)| json!([lo, hi]));
    let mut o = json!({"time": step.time, "file": step.file.display().to_string()});
    if let Some(k) = step.volume_index {
        o["volume_index"] = json!(k);
    }
    let mut ranges = serde_json::Map::new();
    match d {
        Dataset::Volume(v) => {
            o["dims"] = json!(v.dims);
            ranges.insert("value".into(), v.value_range().map_or(Value::Null, |(a, b)| json!([a, b])));
        }
        Dataset::Heightfield(h) => {
            o["size"] = json!([h.width, h.height]);
        }
        Dataset::Particles(p) => {
            o["particles"] = json!(p.len());
            for (name, values) in [(&names.density, &p.density), (&names.mass, &p.mass), (&names.smoothing_length, &p.smoothing_length)] {
                if let Some(v) = values {
                    ranges.insert(name.clone(), range(&mut v.iter().map(|&x| x as f64)));
                }
            }
            for a in p.arrays.iter().filter(|a| a.components == 1) {
                ranges.insert(a.name.clone(), range(&mut a.values.iter().copied()));
            }
        }
    }
    o["ranges"] = Value::Object(ranges);
    o
}

/// A time series as text: how it was found, then a line per step (from `step_json`).
pub fn series_text(s: &volterra_formats::series::TimeSeries, steps: &[Value]) -> String {
    let unit = s.time_unit.map(|u| format!(" {u}")).unwrap_or_default();
    let mut out = format!("time series {} ({}): {} timesteps", s.source.display(), s.kind, s.steps.len());
    if let (Some(a), Some(b)) = (s.steps.first(), s.steps.last()) {
        out += &format!(", time {}{unit} .. {}{unit}", num(a.time), num(b.time));
    }
    out += "\n";
    for (k, v) in steps.iter().enumerate() {
        let file = std::path::Path::new(v["file"].as_str().unwrap_or("")).file_name().map(|f| f.to_string_lossy().into_owned());
        let what = match (v.get("volume_index"), v.get("particles"), v.get("dims")) {
            (Some(i), _, Some(d)) => format!("volume {i}, {d}"),
            (_, Some(n), _) => format!("{n} particles"),
            (_, _, Some(d)) => format!("{d} voxels"),
            _ => String::new(),
        };
        let ranges: Vec<String> = v["ranges"]
            .as_object()
            .map(|m| m.iter().filter_map(|(name, r)| Some(format!("{name} {} .. {}", num(r[0].as_f64()?), num(r[1].as_f64()?)))).collect())
            .unwrap_or_default();
        out += &format!(
            "  {k:>4}  t = {:<10} {:<24} {what}; {}\n",
            format!("{}{unit}", num(v["time"].as_f64().unwrap_or(f64::NAN))),
            file.unwrap_or_default(),
            ranges.join(", ")
        );
    }
    out
}
