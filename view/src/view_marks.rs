//! What the 3-D view draws over the picture so that a reader knows how it is oriented and
//! how large things are: an orientation marker (the world axes as the camera turns them, as
//! vtkOrientationMarkerWidget / Slicer's 3-D view axes) in the lower-left corner, and a
//! scale bar in the lower-right, true at the focal point's depth (in perspective, nearer
//! things look larger). World units follow the data (docs/coordinates.md): a scene with a
//! volume is in RAS+ millimetres (axes R, A, S), a terrain in metres (E, N, Up), particles
//! in their file's units (x, y, z).

use egui::{Color32, Pos2, Rect, Stroke, Vec2};
use glam::DVec3;
use volterra::scene::Camera;

/// What the world's axes and units are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum World {
    /// RAS+ millimetres.
    Patient,
    /// Metres, x east, y north, z up.
    Terrain,
    /// The data's own units.
    Plain,
}

impl World {
    pub fn axis_labels(self) -> [&'static str; 3] {
        match self {
            World::Patient => ["R", "A", "S"],
            World::Terrain => ["E", "N", "Up"],
            World::Plain => ["x", "y", "z"],
        }
    }

    /// A round length in world units as people write it.
    pub fn length_label(self, v: f64) -> String {
        match self {
            World::Patient if (10.0..1000.0).contains(&v) && (v / 10.0).fract() == 0.0 => format!("{} cm", v / 10.0),
            World::Patient if v >= 1000.0 => format!("{} m", v / 1000.0),
            World::Patient => format!("{v} mm"),
            World::Terrain if v >= 1000.0 => format!("{} km", v / 1000.0),
            World::Terrain => format!("{v} m"),
            World::Plain => format!("{v}"),
        }
    }
}

/// The world axes +x, +y, +z (RAS+: towards the patient's right, anterior, superior) as
/// screen directions (points, y down) of unit length in the view plane: the camera's
/// rotation only, as the marker is drawn without perspective. An axis along the view
/// direction has length 0.
pub fn marker_axes(cam: &Camera) -> [Vec2; 3] {
    let g = cam.rays(2, 2);
    let (_, right, up) = g.basis();
    [DVec3::X, DVec3::Y, DVec3::Z].map(|e| Vec2::new(e.dot(right) as f32, -(e.dot(up) as f32)))
}

/// World units per screen point at the focal point's depth, in a view `rect`.
pub fn mm_per_point(cam: &Camera, rect: Rect) -> f64 {
    let g = cam.rays(2, 2);
    let (_, half_h) = g.half_extent();
    let depth = if g.is_parallel() { 1.0 } else { (DVec3::from(cam.focal_point) - DVec3::from(cam.position)).dot(g.forward()) };
    2.0 * half_h * depth / rect.height().max(1.0) as f64
}

/// The scale bar: a round length (1, 2 or 5 × 10ⁿ world units) drawn at most a quarter of
/// the view's width, and its length in points.
pub fn scale_bar(cam: &Camera, rect: Rect) -> (f64, f32) {
    let mpp = mm_per_point(cam, rect);
    let most = 0.25 * rect.width().max(1.0) as f64 * mpp;
    let decade = 10f64.powf(most.log10().floor());
    let mm = [5.0, 2.0, 1.0].into_iter().map(|m| m * decade).find(|&v| v <= most).unwrap_or(decade);
    (mm, (mm / mpp) as f32)
}

/// Draws the orientation marker and the scale bar over the 3-D view.
pub fn draw(painter: &egui::Painter, cam: &Camera, rect: Rect, world: World) {
    let font = egui::FontId::proportional(13.0);
    let centre = Pos2::new(rect.left() + 44.0, rect.bottom() - 44.0);
    let colours = [Color32::from_rgb(230, 70, 70), Color32::from_rgb(80, 200, 90), Color32::from_rgb(90, 140, 255)];
    for ((d, label), c) in marker_axes(cam).into_iter().zip(world.axis_labels()).zip(colours) {
        let end = centre + d * 30.0;
        painter.line_segment([centre, end], Stroke::new(2.5, c));
        if d.length() > 0.2 {
            painter.text(centre + d * 38.0, egui::Align2::CENTER_CENTER, label, font.clone(), c);
        }
    }
    let (mm, len) = scale_bar(cam, rect);
    let y = rect.bottom() - 18.0;
    let x1 = rect.right() - 16.0;
    let x0 = x1 - len;
    let white = Stroke::new(2.0, Color32::from_gray(230));
    painter.line_segment([Pos2::new(x0, y), Pos2::new(x1, y)], white);
    for x in [x0, x1] {
        painter.line_segment([Pos2::new(x, y - 5.0), Pos2::new(x, y + 1.0)], white);
    }
    painter.text(Pos2::new(0.5 * (x0 + x1), y - 6.0), egui::Align2::CENTER_BOTTOM, world.length_label(mm), font, Color32::from_gray(230));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(parallel: bool) -> Camera {
        Camera {
            position: [40.0, -250.0, 90.0],
            focal_point: [5.0, 10.0, -3.0],
            view_up: [0.1, 0.2, 1.0],
            view_angle: 35.0,
            parallel_projection: parallel,
            parallel_scale: 80.0,
        }
    }

    /// The view's own projection (the 3-D view's overlays use it) of a world point.
    fn projected(c: &Camera, rect: Rect, p: DVec3) -> glam::DVec2 {
        let g = c.rays(rect.width() as usize, rect.height() as usize);
        let (eye, right, up) = g.basis();
        let (hw, hh) = g.half_extent();
        let d = p - eye;
        let z = if g.is_parallel() { 1.0 } else { d.dot(g.forward()) };
        glam::DVec2::new(0.5 * (d.dot(right) / z / hw + 1.0) * rect.width() as f64, 0.5 * (1.0 - d.dot(up) / z / hh) * rect.height() as f64)
    }

    #[test]
    fn the_marker_turns_with_the_camera_and_the_bar_measures_at_the_focal_point() {
        let rect = Rect::from_min_size(Pos2::ZERO, Vec2::new(640.0, 480.0));
        for parallel in [false, true] {
            let c = cam(parallel);
            let f = DVec3::from(c.focal_point);
            // Each axis points where a short step along it from the focal point moves on screen.
            for (d, e) in marker_axes(&c).into_iter().zip([DVec3::X, DVec3::Y, DVec3::Z]) {
                let step = projected(&c, rect, f + e * 1e-4) - projected(&c, rect, f);
                let d64 = glam::DVec2::new(d.x as f64, d.y as f64);
                let fwd = (f - DVec3::from(c.position)).normalize();
                let in_plane = (e - fwd * e.dot(fwd)).length() as f32;
                assert!((step.normalize() - d64.normalize()).length() < 1e-4, "{parallel}: {step:?} vs {d:?}");
                assert!((d.length() - in_plane).abs() < 1e-6);
            }
            // The bar's millimetres over its points: what 10 mm across the view at the focal
            // point measures on screen.
            let g = c.rays(2, 2);
            let (_, right, _) = g.basis();
            let across = (projected(&c, rect, f + right * 10.0) - projected(&c, rect, f)).length();
            let (mm, len) = scale_bar(&c, rect);
            assert!((mm / len as f64 - 10.0 / across).abs() < 1e-6 * mm, "{parallel}: {mm} mm over {len} points; 10 mm over {across}");
            assert!(len <= 0.25 * rect.width() && len > 0.25 * rect.width() / 2.5 - 1.0, "{len}");
            assert!([1.0, 2.0, 5.0].contains(&(mm / 10f64.powf(mm.log10().floor())).round()), "{mm} is round");
        }
        assert_eq!(World::Patient.length_label(50.0), "5 cm");
        assert_eq!(World::Patient.length_label(2.0), "2 mm");
        assert_eq!(World::Patient.length_label(0.5), "0.5 mm");
        assert_eq!(World::Terrain.length_label(2000.0), "2 km");
        assert_eq!(World::Terrain.length_label(200.0), "200 m");
    }
}
