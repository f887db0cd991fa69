//! A scene for one data file, for `volterra view FILE`: one node with the renderer its
//! kind draws best, a camera that frames it, a light, and for volumes the transfer-function
//! preset that suits the modality.

use super::{Camera, ImageSettings, Light, LightKind, Medium, NodeData, NodeDesc, NodeKind, Scene, SceneFile, TerrainData};
use anyhow::{anyhow, Result};
use glam::{DMat4, DVec3};
use std::path::{Component, Path, PathBuf};
use volterra_formats::heightfield::GridGeoref;
use volterra_formats::LoadOptions;

/// Reads `path` and builds a scene showing it. The data read is handed to the scene, so
/// nothing is read twice.
pub fn scene_for_file(path: &Path, opts: &LoadOptions) -> Result<Scene> {
    // A series (a .pvd, a numbered pattern) is framed by its first step; the scene finds
    // the series again from the node's file and draws its steps over time.
    let first = match volterra_formats::series::is_series_name(path) {
        true => volterra_formats::series::discover(path)?.map(|s| s.steps[0].file.clone()),
        false => None,
    };
    // A GeoTIFF is not read here: the terrain ray-caster reads it by rows into its own
    // store (`Scene::terrain_data`), so a DEM larger than memory opens too.
    let geotiff = first.is_none() && volterra_formats::detect(path)? == volterra_formats::FileKind::GeoTiff;
    let data = match geotiff {
        true => None,
        false => Some(NodeData::from(volterra_formats::load(first.as_deref().unwrap_or(path), opts)?)),
    };
    let kind = data.as_ref().map_or(NodeKind::Heightfield, NodeData::kind);
    let name = node_name(path);
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from("."));
    let file_name = PathBuf::from(path.file_name().ok_or_else(|| anyhow!("{}: not a file name", path.display()))?);
    let mut node = NodeDesc {
        file: Some(file_name),
        series: opts.dicom.series.clone(),
        volume_index: opts.nifti.volume_index,
        resample: opts.dicom.resample,
        extent: opts.geotiff.extent,
        ..NodeDesc::new(&name, kind)
    };
    // The fast renderer for the kind (shear-warp, the GPU terrain ray-caster, points;
    // smoke is a click away: the node keeps a medium and a light for it).
    node.renderer = crate::catalog::fast_for(kind).map(|r| r.name.to_string());
    let mut image = ImageSettings::default();
    let mut lights = Vec::new();
    match kind {
        // A volume gets no transfer function of its own: the preset of its modality
        // classifies it (`Scene::transfer_function`), so choosing a modality changes it.
        NodeKind::Volume | NodeKind::Group => {}
        NodeKind::Heightfield => {
            if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
                node.png = Some(opts.png.clone());
            }
            image.background = [0.55, 0.7, 0.9];
            lights.push(Light {
                kind: LightKind::Directional,
                direction: Some([1.0, 1.0, -1.0]),
                position: None,
                color: [1.0; 3],
                intensity: 1.0,
                cone_angle: None,
            });
        }
        NodeKind::Particles => {
            node.arrays = Some(opts.particles.clone());
            // An optically moderate medium for particles in metres with SPH densities
            // near 1 kg/m³ (the SPH defaults): about one mean free path across 0.1 m.
            node.medium = Some(Medium { c_ext: None, albedo: 0.9, g: 0.3 });
            image.background = [0.02, 0.02, 0.03];
            lights.push(Light {
                kind: LightKind::Directional,
                direction: Some([-1.0, 0.6, -0.5]),
                position: None,
                color: [1.0; 3],
                intensity: 3.0,
                cone_angle: None,
            });
        }
    }
    let file = SceneFile {
        image,
        // Framed below, once the scene reads the data's extent as its renderer will.
        camera: fit_camera(kind, (DVec3::ZERO, DVec3::ONE)),
        walk: None,
        keyframes: vec![],
        orbit: None,
        lights,
        nodes: vec![node],
        measurements: vec![],
        slices: None,
    };
    let mut scene = Scene::from_file(file, dir, path.to_path_buf())?.with_limits(opts.limits);
    if let Some(data) = data {
        scene.provide_data(0, data);
    }
    let bounds = scene.bounds(0)?.ok_or_else(|| anyhow!("{}: the data has no finite extent to frame", path.display()))?;
    scene.file.camera = fit_camera(kind, bounds);
    Ok(scene)
}

fn node_name(path: &Path) -> String {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "data".into());
    let stem = name.trim_end_matches(".gz");
    let stem = stem.rsplit_once('.').map(|(s, _)| s).filter(|s| !s.is_empty()).unwrap_or(stem);
    stem.to_string()
}

/// World-space bounding box of a node's data (corners of the voxel cells, the terrain
/// surface, the particle centres), or None where nothing finite is there.
pub fn data_bounds(data: &NodeData, node_to_world: DMat4) -> Option<(DVec3, DVec3)> {
    let mut pts: Vec<DVec3> = Vec::new();
    match data {
        NodeData::Volume(v) => {
            let a = node_to_world * crate::geometry::affine_matrix(&v.affine);
            for c in 0..8 {
                let ijk = DVec3::new(
                    if c & 1 == 0 { -0.5 } else { v.dims[0] as f64 - 0.5 },
                    if c & 2 == 0 { -0.5 } else { v.dims[1] as f64 - 0.5 },
                    if c & 4 == 0 { -0.5 } else { v.dims[2] as f64 - 0.5 },
                );
                pts.push(a.transform_point3(ijk));
            }
        }
        NodeData::Heightfield(h) => return grid_bounds(&h.georef(), h.range()?, node_to_world),
        NodeData::Particles(p) => {
            pts.extend(p.positions.iter().map(|&q| node_to_world.transform_point3(DVec3::from(q))).filter(|q| q.is_finite()));
        }
    }
    let lo = pts.iter().copied().reduce(DVec3::min)?;
    let hi = pts.iter().copied().reduce(DVec3::max)?;
    (lo.is_finite() && hi.is_finite()).then_some((lo, hi))
}

/// World-space bounding box of a heightfield's surface: the rectangle of its sample
/// centres between its lowest and highest elevation.
pub fn grid_bounds(g: &GridGeoref, (lo, hi): (f32, f32), node_to_world: DMat4) -> Option<(DVec3, DVec3)> {
    let (x, y) = ((g.width - 1) as f64 * g.cell_size[0], (g.height - 1) as f64 * g.cell_size[1]);
    let pts: Vec<DVec3> = (0..8)
        .map(|c| {
            let z = if c & 4 == 0 { lo } else { hi } as f64;
            node_to_world.transform_point3(DVec3::new(if c & 1 == 0 { 0.0 } else { x }, if c & 2 == 0 { 0.0 } else { y }, z))
        })
        .collect();
    let lo = pts.iter().copied().reduce(DVec3::min)?;
    let hi = pts.iter().copied().reduce(DVec3::max)?;
    (lo.is_finite() && hi.is_finite()).then_some((lo, hi))
}

/// World-space bounding box of a heightfield's surface as its renderer reads it: held, or
/// by rows (the range from one pass over them, kept; see `GeoTiffRows::summary`).
pub fn terrain_bounds(t: &TerrainData, node_to_world: DMat4) -> Option<(DVec3, DVec3)> {
    let range = match t {
        TerrainData::Held(h) => h.range(),
        TerrainData::Rows(r) => r.summary().range,
    };
    grid_bounds(&t.georef(), range?, node_to_world)
}

/// A camera that shows the box whole: volumes from the patient's front (anterior, head
/// up) in perspective at 30° (3D Slicer's default view); terrain from above its
/// south-west corner; particles from the south.
pub fn fit_camera(kind: NodeKind, (lo, hi): (DVec3, DVec3)) -> Camera {
    let centre = 0.5 * (lo + hi);
    let radius = (0.5 * (hi - lo).length()).max(1e-6);
    let up = [0.0, 0.0, 1.0];
    match kind {
        NodeKind::Volume | NodeKind::Group => {
            // The bounding sphere fills the view's height (2 % margin); parallel_scale frames
            // the same height at the focal point when the viewer toggles to parallel.
            let angle: f64 = 30.0;
            let dist = 1.02 * radius / (0.5 * angle.to_radians()).sin();
            Camera {
                position: (centre + DVec3::Y * dist).to_array(),
                focal_point: centre.to_array(),
                view_up: up,
                view_angle: angle,
                parallel_projection: false,
                parallel_scale: dist * (0.5 * angle.to_radians()).tan(),
            }
        }
        NodeKind::Heightfield => {
            let ext = (hi - lo).truncate().max_element().max(1e-6);
            Camera {
                position: (centre + DVec3::new(-0.75 * ext, -0.75 * ext, 0.6 * ext)).to_array(),
                focal_point: centre.to_array(),
                view_up: up,
                view_angle: 45.0,
                parallel_projection: false,
                parallel_scale: 1.0,
            }
        }
        NodeKind::Particles => {
            let angle: f64 = 35.0;
            let dist = 1.1 * radius / (0.5 * angle.to_radians()).sin();
            Camera {
                position: (centre - DVec3::Y * dist).to_array(),
                focal_point: centre.to_array(),
                view_up: up,
                view_angle: angle,
                parallel_projection: false,
                parallel_scale: 1.0,
            }
        }
    }
}

/// Rewrites the data and texture paths of `file`, relative to directory `from`, to be
/// relative to directory `to` (a scene saved elsewhere still finds its data).
pub fn relocate(file: &mut SceneFile, from: &Path, to: &Path) {
    for n in &mut file.nodes {
        if let Some(f) = &n.file {
            n.file = Some(relative_path(&from.join(f), to));
        }
        if let Some(t) = &n.texture {
            n.texture = Some(relative_path(&from.join(t), to));
        }
    }
}

/// `target` as a path relative to directory `base` where both are absolute (after
/// canonicalising what exists), else `target` made absolute. Saved scenes name their data
/// relative to themselves, as the samples do.
pub fn relative_path(target: &Path, base: &Path) -> PathBuf {
    let abs = |p: &Path| {
        std::fs::canonicalize(p).unwrap_or_else(|_| std::env::current_dir().map(|d| d.join(p)).unwrap_or_else(|_| p.to_path_buf()))
    };
    let (t, b) = (abs(target), abs(base));
    let tc: Vec<Component> = t.components().collect();
    let bc: Vec<Component> = b.components().collect();
    let common = tc.iter().zip(&bc).take_while(|(a, b)| a == b).count();
    if common == 0 {
        return t;
    }
    let mut out = PathBuf::new();
    for _ in common..bc.len() {
        out.push("..");
    }
    for c in &tc[common..] {
        out.push(c.as_os_str());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths_climb_out_of_the_base() {
        assert_eq!(relative_path(Path::new("/a/b/c/data.nii"), Path::new("/a/b/d")), PathBuf::from("../c/data.nii"));
        assert_eq!(relative_path(Path::new("/a/b/data.nii"), Path::new("/a/b")), PathBuf::from("data.nii"));
    }

    #[test]
    fn names_drop_every_extension_of_a_gzip() {
        assert_eq!(node_name(Path::new("x/aneurism.nii.gz")), "aneurism");
        assert_eq!(node_name(Path::new("plume.vtp")), "plume");
        assert_eq!(node_name(Path::new("series_dir")), "series_dir");
    }
}
