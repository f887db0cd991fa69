//! `volterra info`: what a reader made of a file, as text or as one JSON object.

use serde_json::{json, Value};
use volterra_formats::geotiff_rows::GeoTiffRows;
use volterra_formats::heightfield::{GridGeoref, RowsSummary};
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
/// (`GeoTiffRows`, which finds the range and NoData count in one pass over its rows).
pub struct GridSummary<'a> {
    pub georef: GridGeoref,
    pub attributes: &'a [(String, String)],
    pub nodata_value: Option<f64>,
    pub notes: &'a [String],
    /// (min, max) elevation in metres over valid samples.
    pub range: Option<(f32, f32)>,
    pub nodata_count: usize,
}

impl<'a> GridSummary<'a> {
    pub fn of_heightfield(h: &'a Heightfield) -> GridSummary<'a> {
        GridSummary {
            georef: h.georef(),
            attributes: &h.attributes,
            nodata_value: h.nodata_value,
            notes: &h.notes,
            range: h.range(),
            nodata_count: h.nodata_count(),
        }
    }
    /// Reads every row of the raster the first time (see `GeoTiffRows::summary`).
    pub fn of_rows(r: &'a GeoTiffRows) -> GridSummary<'a> {
        let RowsSummary { range, nodata } = r.summary();
        GridSummary {
            georef: r.georef().clone(),
            attributes: &r.attributes,
            nodata_value: r.nodata_value,
            notes: &r.notes,
            range,
            nodata_count: nodata,
        }
    }
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
    let (min, max) = s.range.map(|(a, b)| (a as f64, b as f64)).unwrap_or((f64::NAN, f64::NAN));
    let corner_map: serde_json::Map<String, Value> = corners(g).iter().map(|(n, c)| (n.replace(' ', "_"), json!(c))).collect();
    json!({
        "kind": "heightfield",
        "attributes": attributes_json(s.attributes),
        "corners": corner_map,
        "dims": [g.width, g.height],
        "cell_size": g.cell_size,
        "cell_size_native": g.cell_size_native,
        "origin": g.origin,
        "crs": g.crs.description,
        "epsg": g.crs.epsg,
        "geographic": g.crs.geographic,
        "nodata_value": s.nodata_value,
        "nodata_count": s.nodata_count,
        "min": min,
        "max": max,
        "notes": s.notes,
    })
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

pub fn grid_text(sm: &GridSummary) -> String {
    let g = &sm.georef;
    let mut s = String::new();
    let (min, max) = sm.range.unwrap_or((f32::NAN, f32::NAN));
    s += &format!("heightfield {} × {} samples\n", g.width, g.height);
    s += &format!("cell size   {} m × {} m", num(g.cell_size[0]), num(g.cell_size[1]));
    if g.crs.geographic {
        s += &format!(" (from {}° × {}°)", num(g.cell_size_native[0]), num(g.cell_size_native[1]));
    }
    s += "\n";
    s += &format!("origin      {}, {} (centre of the north-west sample, CRS units)\n", num(g.origin[0]), num(g.origin[1]));
    s += &format!("crs         {}\n", g.crs.description);
    attributes_text(&mut s, sm.attributes);
    let c = corners(g);
    s += &format!(
        "bounds      west {}, south {}, east {}, north {} (CRS units)\n",
        num(c[0].1[0]),
        num(c[3].1[1]),
        num(c[3].1[0]),
        num(c[0].1[1])
    );
    for (name, [x, y]) in c {
        s += &format!("{:<11} {}, {}\n", name, num(x), num(y));
    }
    s += &format!("elevation   {} .. {} m\n", num(min as f64), num(max as f64));
    let value = sm.nodata_value.map(num).unwrap_or_else(|| "none declared".into());
    s += &format!("nodata      {} samples (value {value})\n", sm.nodata_count);
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
pub fn dataset_text(d: &Dataset, names: &ParticleArrayNames) -> String {
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
        Dataset::Heightfield(h) => s += &grid_text(&GridSummary::of_heightfield(h)),
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
