//! Cropping a volume in the viewer: the crop box and clipping planes of a volume node
//! (`crop`, `[[node.clip]]`) as controls in the side panel, and the box drawn over the 3-D
//! view with a handle on each face that drags that face along its axis.

use egui::{Color32, Pos2, Vec2};
use glam::{DMat4, DVec3};
use volterra::geometry::affine_matrix;
use volterra::scene::{ClipPlane, CropBox};
use volterra_formats::Volume;

/// The box of a volume's voxel centres in its node coordinates: what a new crop box
/// starts as (it crops nothing).
pub fn volume_box(v: &Volume) -> CropBox {
    let m = affine_matrix(&v.affine);
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for c in 0..8 {
        let i = DVec3::new(
            if c & 1 == 0 { 0.0 } else { (v.dims[0] - 1) as f64 },
            if c & 2 == 0 { 0.0 } else { (v.dims[1] - 1) as f64 },
            if c & 4 == 0 { 0.0 } else { (v.dims[2] - 1) as f64 },
        );
        let p = m.transform_point3(i);
        (lo, hi) = (lo.min(p), hi.max(p));
    }
    CropBox { min: lo.into(), max: hi.into() }
}

/// What the controls changed: the node's new crop box and planes, and whether a value is
/// being dragged (previews until it is let go).
pub struct CropEdit {
    pub crop: Option<CropBox>,
    pub clip: Vec<ClipPlane>,
    pub moving: bool,
}

/// The side panel's cropping controls for a volume whose voxel centres span `full`.
pub fn controls(ui: &mut egui::Ui, crop: Option<CropBox>, clip: &[ClipPlane], full: CropBox) -> Option<CropEdit> {
    ui.label(egui::RichText::new("Cropping").strong());
    let (mut crop_out, mut clip_out) = (crop, clip.to_vec());
    let (mut changed, mut moving) = (false, false);
    let mut on = crop.is_some();
    if ui
        .checkbox(&mut on, "Crop box")
        .on_hover_text("Draw only what lies inside the box (mm, the volume's own coordinates); drag its handles in the 3-D view")
        .changed()
    {
        crop_out = on.then_some(full);
        changed = true;
    }
    if let Some(c) = &mut crop_out.filter(|_| on) {
        let span = (0..3).map(|k| full.max[k] - full.min[k]).fold(0.0, f64::max).max(1.0);
        egui::Grid::new("crop box").num_columns(3).show(ui, |ui| {
            for (k, axis) in ["x", "y", "z"].into_iter().enumerate() {
                ui.label(axis);
                for (end, value) in [("min", &mut c.min[k]), ("max", &mut c.max[k])] {
                    let r = ui.add(egui::DragValue::new(value).speed(span / 400.0).suffix(" mm").max_decimals(2));
                    let r = r.on_hover_text(format!("crop box {axis} {end}"));
                    changed |= r.changed();
                    moving |= r.dragged();
                }
                ui.end_row();
            }
        });
        // A face dragged past its opposite one takes it along.
        for k in 0..3 {
            if c.min[k] > c.max[k] {
                c.max[k] = c.min[k];
            }
        }
        crop_out = Some(*c);
    }
    let mut remove = None;
    for (p, plane) in clip_out.iter_mut().enumerate() {
        ui.horizontal(|ui| {
            ui.label(format!("Plane {}", p + 1));
            if ui.small_button("Remove").clicked() {
                remove = Some(p);
            }
        });
        for (what, values, speed) in [("origin", &mut plane.origin, 0.5), ("normal", &mut plane.normal, 0.01)] {
            ui.horizontal(|ui| {
                ui.label(what);
                let before = *values;
                for v in values.iter_mut() {
                    let r = ui.add(egui::DragValue::new(v).speed(speed).max_decimals(3));
                    changed |= r.changed();
                    moving |= r.dragged();
                }
                // A zero normal keeps no side: refused, the previous one stays.
                if what == "normal" && values.iter().all(|v| *v == 0.0) {
                    *values = before;
                }
            });
        }
    }
    if let Some(p) = remove {
        clip_out.remove(p);
        changed = true;
    }
    if ui.button("Add a clipping plane").on_hover_text("Keeps the side its normal points to").clicked() {
        let centre = (0..3).map(|k| 0.5 * (full.min[k] + full.max[k])).collect::<Vec<_>>();
        clip_out.push(ClipPlane { origin: [centre[0], centre[1], centre[2]], normal: [0.0, 0.0, 1.0] });
        changed = true;
    }
    changed.then_some(CropEdit { crop: crop_out, clip: clip_out, moving })
}

/// Face f of the box (f / 2: the axis; f % 2: 0 the min face, 1 the max face): its centre
/// in node coordinates.
fn face_centre(c: &CropBox, f: usize) -> DVec3 {
    let mut p = (DVec3::from(c.min) + DVec3::from(c.max)) * 0.5;
    p[f / 2] = if f.is_multiple_of(2) { c.min[f / 2] } else { c.max[f / 2] };
    p
}

/// Draws the box's edges and its face handles; `project` takes a world point to the window.
pub fn draw(painter: &egui::Painter, c: &CropBox, to_world: DMat4, project: impl Fn(DVec3) -> Option<Pos2>) {
    let corner = |i: usize| {
        DVec3::new(
            if i & 1 == 0 { c.min[0] } else { c.max[0] },
            if i & 2 == 0 { c.min[1] } else { c.max[1] },
            if i & 4 == 0 { c.min[2] } else { c.max[2] },
        )
    };
    let stroke = egui::Stroke::new(1.0, Color32::from_rgb(90, 200, 255));
    for i in 0..8usize {
        for bit in [1, 2, 4] {
            if i & bit == 0 {
                if let (Some(a), Some(b)) =
                    (project(to_world.transform_point3(corner(i))), project(to_world.transform_point3(corner(i | bit))))
                {
                    painter.line_segment([a, b], stroke);
                }
            }
        }
    }
    for f in 0..6 {
        if let Some(p) = handle_position(c, f, to_world, &project) {
            painter.circle(p, HANDLE_RADIUS, Color32::from_rgba_unmultiplied(90, 200, 255, 160), stroke);
        }
    }
}

const HANDLE_RADIUS: f32 = 5.0;

/// Where face f's handle is drawn.
pub fn handle_position(c: &CropBox, f: usize, to_world: DMat4, project: impl Fn(DVec3) -> Option<Pos2>) -> Option<Pos2> {
    project(to_world.transform_point3(face_centre(c, f)))
}

/// The face whose handle lies under window position `pos`, if any.
pub fn handle_at(c: &CropBox, to_world: DMat4, pos: Pos2, project: impl Fn(DVec3) -> Option<Pos2>) -> Option<usize> {
    (0..6)
        .filter_map(|f| handle_position(c, f, to_world, &project).map(|p| (f, p.distance(pos))))
        .filter(|&(_, d)| d <= 2.0 * HANDLE_RADIUS)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(f, _)| f)
}

/// Face f moved by a pointer drag of `delta` pixels: along its axis by the drag's part
/// along the axis as drawn (millimetres per pixel from two projected points). A face
/// stops at its opposite one.
pub fn drag_face(c: &mut CropBox, f: usize, delta: Vec2, to_world: DMat4, project: impl Fn(DVec3) -> Option<Pos2>) {
    let (k, p) = (f / 2, face_centre(c, f));
    let mut axis = DVec3::ZERO;
    axis[k] = 1.0;
    let (Some(a), Some(b)) = (project(to_world.transform_point3(p)), project(to_world.transform_point3(p + axis))) else { return };
    let s = b - a; // pixels per millimetre along the axis
    if s.length_sq() < 1e-6 {
        return; // the axis points at the eye: no drag along it can be read
    }
    let mm = (delta.dot(s) / s.length_sq()) as f64;
    if f.is_multiple_of(2) {
        c.min[k] = (c.min[k] + mm).min(c.max[k]);
    } else {
        c.max[k] = (c.max[k] + mm).max(c.min[k]);
    }
}
