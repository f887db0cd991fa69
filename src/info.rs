//! `volterra info`: what a reader made of a file, as text or as one JSON object.

use serde_json::{json, Value};
use volterra_formats::{dicom, Dataset, Heightfield, ParticleArrayNames, ParticleSet, Volume};

pub fn volume_json(v: &Volume) -> Value {
    let (min, max) = v.value_range().unwrap_or((f64::NAN, f64::NAN));
    json!({
        "kind": "volume",
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
    let (min, max) = h.range().map(|(a, b)| (a as f64, b as f64)).unwrap_or((f64::NAN, f64::NAN));
    json!({
        "kind": "heightfield",
        "dims": [h.width, h.height],
        "cell_size": h.cell_size,
        "cell_size_native": h.cell_size_native,
        "origin": h.origin,
        "crs": h.crs.description,
        "epsg": h.crs.epsg,
        "geographic": h.crs.geographic,
        "nodata_value": h.nodata_value,
        "nodata_count": h.nodata_count(),
        "min": min,
        "max": max,
        "notes": h.notes,
    })
}

pub fn particles_json(p: &ParticleSet, names: &ParticleArrayNames) -> Value {
    let bounds = p.bounds().map(|(lo, hi)| json!([lo, hi]));
    json!({
        "kind": "particles",
        "count": p.len(),
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
    format!("{:.6} × {:.6} × {:.6}", v[0], v[1], v[2])
}

/// A human-readable summary.
pub fn dataset_text(d: &Dataset, names: &ParticleArrayNames) -> String {
    let mut s = String::new();
    match d {
        Dataset::Volume(v) => {
            let (min, max) = v.value_range().unwrap_or((f64::NAN, f64::NAN));
            s += &format!("volume      {} × {} × {} voxels, {}\n", v.dims[0], v.dims[1], v.dims[2], v.data.scalar_type().name());
            s += &format!("spacing     {} mm\n", fmt3(v.spacing));
            s += "affine      (voxel index → RAS+ mm)\n";
            for r in &v.affine {
                s += &format!("            [{:>12.6} {:>12.6} {:>12.6} {:>12.6}]\n", r[0], r[1], r[2], r[3]);
            }
            s += &format!("rescale     value = {} · stored + {}\n", v.rescale.slope, v.rescale.intercept);
            s += &format!("modality    {}\n", v.modality.as_deref().unwrap_or("-"));
            s += &format!("range       {min} .. {max} {}\n", v.units.as_deref().unwrap_or(""));
            if v.volume_count > 1 {
                s += &format!("volumes     {} (showing {})\n", v.volume_count, v.volume_index);
            }
            for n in &v.notes {
                s += &format!("note        {n}\n");
            }
        }
        Dataset::Heightfield(h) => {
            let (min, max) = h.range().unwrap_or((f32::NAN, f32::NAN));
            s += &format!("heightfield {} × {} samples\n", h.width, h.height);
            s += &format!("cell size   {:.6} m × {:.6} m", h.cell_size[0], h.cell_size[1]);
            if h.crs.geographic {
                s += &format!(" (from {}° × {}°)", h.cell_size_native[0], h.cell_size_native[1]);
            }
            s += "\n";
            s += &format!("origin      {}, {} (centre of the north-west sample, CRS units)\n", h.origin[0], h.origin[1]);
            s += &format!("crs         {}\n", h.crs.description);
            s += &format!("elevation   {min} .. {max} m\n");
            s += &format!("nodata      {} samples (value {:?})\n", h.nodata_count(), h.nodata_value);
            for n in &h.notes {
                s += &format!("note        {n}\n");
            }
        }
        Dataset::Particles(p) => {
            s += &format!("particles   {}\n", p.len());
            s += &format!("arrays      {}\n", p.array_names(names).join(", "));
            if let Some((lo, hi)) = p.bounds() {
                s += &format!("bounds      {:?} .. {:?}\n", lo, hi);
            }
            for n in &p.notes {
                s += &format!("note        {n}\n");
            }
        }
    }
    s
}
