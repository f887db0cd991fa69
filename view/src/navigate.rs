//! Camera moves the viewer makes, on the scene's own [`Camera`] (vtkCamera semantics), so
//! that a saved view is exactly what `volterra render` draws. Orbit, pan and zoom behave as
//! in ParaView/pyvista (trackball around the focal point); fly and walk as in a game
//! (mouse look about the eye, WASD along the view).

use glam::{DQuat, DVec3};
use volterra::scene::Camera;

fn frame(cam: &Camera) -> (DVec3, DVec3, DVec3, DVec3) {
    let eye = DVec3::from(cam.position);
    let fp = DVec3::from(cam.focal_point);
    let fwd = (fp - eye).normalize();
    let right = fwd.cross(DVec3::from(cam.view_up)).normalize();
    let up = right.cross(fwd);
    (eye, fp, right, up)
}

/// Rotates the eye about the focal point: `azimuth` degrees about the view-up (dragging
/// right turns the scene right), `elevation` degrees about the right vector. View-up is
/// re-orthogonalised, so the camera can go over the top without flipping.
pub fn orbit(cam: &mut Camera, azimuth: f64, elevation: f64) {
    let (eye, fp, right, up) = frame(cam);
    let q = DQuat::from_axis_angle(up, (-azimuth).to_radians()) * DQuat::from_axis_angle(right, elevation.to_radians());
    let offset = q * (eye - fp);
    let new_up = q * up;
    cam.position = (fp + offset).to_array();
    cam.view_up = new_up.to_array();
}

/// Moves eye and focal point in the view plane by (dx, dy) fractions of the view height
/// (positive dx moves the scene right, positive dy up, like dragging it).
pub fn pan(cam: &mut Camera, dx: f64, dy: f64) {
    let (eye, fp, right, up) = frame(cam);
    let height = if cam.parallel_projection {
        2.0 * cam.parallel_scale
    } else {
        2.0 * (eye - fp).length() * (0.5 * cam.view_angle.to_radians()).tan()
    };
    let shift = (-right * dx + up * dy) * height;
    cam.position = (eye + shift).to_array();
    cam.focal_point = (fp + shift).to_array();
}

/// Zooms by `factor` (> 1 magnifies): parallel views scale `parallel_scale`, perspective
/// views dolly the eye toward the focal point (as ParaView does).
pub fn zoom(cam: &mut Camera, factor: f64) {
    if !(factor.is_finite() && factor > 0.0) {
        return;
    }
    if cam.parallel_projection {
        cam.parallel_scale /= factor;
    } else {
        let (eye, fp, _, _) = frame(cam);
        cam.position = (fp + (eye - fp) / factor).to_array();
    }
}

/// Switches between perspective and parallel projection keeping what is at the focal
/// point the same size: parallel_scale = distance · tan(view_angle / 2).
pub fn set_parallel(cam: &mut Camera, parallel: bool) {
    let (eye, fp, _, _) = frame(cam);
    let half = (0.5 * cam.view_angle.to_radians()).tan();
    if parallel && !cam.parallel_projection {
        cam.parallel_scale = (eye - fp).length() * half;
    } else if !parallel && cam.parallel_projection {
        // Move the eye so the focal plane shows the same height.
        let dir = (eye - fp).normalize();
        cam.position = (fp + dir * (cam.parallel_scale / half)).to_array();
    }
    cam.parallel_projection = parallel;
}

/// Turns the view about the eye (fly/walk mouse look): `yaw` degrees about world +z,
/// `pitch` degrees about the right vector, kept within ±89° of the horizon.
pub fn look(cam: &mut Camera, yaw: f64, pitch: f64) {
    let (eye, fp, right, _) = frame(cam);
    let d = fp - eye;
    let dist = d.length();
    let dir = d / dist;
    let current = dir.z.clamp(-1.0, 1.0).asin().to_degrees();
    let pitch = (current + pitch).clamp(-89.0, 89.0) - current;
    let q = DQuat::from_rotation_z((-yaw).to_radians()) * DQuat::from_axis_angle(right, pitch.to_radians());
    cam.focal_point = (eye + q * dir * dist).to_array();
    cam.view_up = [0.0, 0.0, 1.0];
}

/// Moves eye and focal point together: `forward` along the view direction (flattened to
/// the ground when `level`, as walking does), `strafe` to the right, `rise` along +z.
pub fn travel(cam: &mut Camera, forward: f64, strafe: f64, rise: f64, level: bool) {
    let (eye, fp, right, _) = frame(cam);
    let mut dir = (fp - eye).normalize();
    if level {
        dir.z = 0.0;
        dir = dir.try_normalize().unwrap_or(DVec3::Y);
    }
    let mut r = right;
    r.z = 0.0;
    let r = r.try_normalize().unwrap_or(right);
    let shift = dir * forward + r * strafe + DVec3::Z * rise;
    cam.position = (eye + shift).to_array();
    cam.focal_point = (fp + shift).to_array();
}

/// The six views along the world axes. For volumes in RAS+ these are the patient
/// directions the buttons are labelled with: Anterior looks at the face (from +y), etc.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisView {
    Anterior,
    Posterior,
    Right,
    Left,
    Superior,
    Inferior,
}

impl AxisView {
    pub const ALL: [AxisView; 6] =
        [AxisView::Anterior, AxisView::Posterior, AxisView::Right, AxisView::Left, AxisView::Superior, AxisView::Inferior];

    pub fn label(self) -> &'static str {
        match self {
            AxisView::Anterior => "A",
            AxisView::Posterior => "P",
            AxisView::Right => "R",
            AxisView::Left => "L",
            AxisView::Superior => "S",
            AxisView::Inferior => "I",
        }
    }

    /// (direction from the focal point to the eye, view-up).
    fn directions(self) -> (DVec3, DVec3) {
        match self {
            AxisView::Anterior => (DVec3::Y, DVec3::Z),
            AxisView::Posterior => (DVec3::NEG_Y, DVec3::Z),
            AxisView::Right => (DVec3::X, DVec3::Z),
            AxisView::Left => (DVec3::NEG_X, DVec3::Z),
            // From above, anterior up (as an axial slice is shown); from below likewise.
            AxisView::Superior => (DVec3::Z, DVec3::Y),
            AxisView::Inferior => (DVec3::NEG_Z, DVec3::Y),
        }
    }
}

/// Looks along a world axis at the same focal point and distance.
pub fn axis_view(cam: &mut Camera, view: AxisView) {
    let (eye, fp, _, _) = frame(cam);
    let (dir, up) = view.directions();
    cam.position = (fp + dir * (eye - fp).length()).to_array();
    cam.view_up = up.to_array();
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(parallel: bool) -> Camera {
        Camera {
            position: [0.0, -10.0, 0.0],
            focal_point: [0.0; 3],
            view_up: [0.0, 0.0, 1.0],
            view_angle: 30.0,
            parallel_projection: parallel,
            parallel_scale: 5.0,
        }
    }

    fn close(a: [f64; 3], b: [f64; 3]) -> bool {
        (DVec3::from(a) - DVec3::from(b)).length() < 1e-9
    }

    #[test]
    fn orbit_keeps_distance_and_a_full_turn_returns() {
        let mut c = cam(false);
        orbit(&mut c, 90.0, 0.0);
        // Looking along +y with z up, the right vector is +x; turning the scene right
        // moves the eye to the left (−x).
        assert!(close(c.position, [-10.0, 0.0, 0.0]), "{:?}", c.position);
        orbit(&mut c, 30.0, 50.0);
        assert!((DVec3::from(c.position).length() - 10.0).abs() < 1e-9);
        c.validate().unwrap();
        let mut d = cam(false);
        for _ in 0..4 {
            orbit(&mut d, 0.0, 90.0);
        }
        assert!(close(d.position, [0.0, -10.0, 0.0]) && close(d.view_up, [0.0, 0.0, 1.0]), "{:?} {:?}", d.position, d.view_up);
    }

    #[test]
    fn pan_moves_by_the_view_height_and_zoom_scales() {
        let mut c = cam(true);
        pan(&mut c, 0.0, 0.1);
        assert!(close(c.focal_point, [0.0, 0.0, 1.0]), "10 world units high × 0.1: {:?}", c.focal_point);
        zoom(&mut c, 2.0);
        assert_eq!(c.parallel_scale, 2.5);
        let mut p = cam(false);
        zoom(&mut p, 2.0);
        assert!(close(p.position, [0.0, -5.0, 0.0]));
    }

    #[test]
    fn look_stays_off_the_pole_and_travel_levels() {
        let mut c = cam(false);
        look(&mut c, 0.0, 120.0);
        let d = (DVec3::from(c.focal_point) - DVec3::from(c.position)).normalize();
        assert!((d.z.asin().to_degrees() - 89.0).abs() < 1e-6);
        c.validate().unwrap();
        travel(&mut c, 1.0, 0.0, 0.0, true);
        assert!((c.position[2]).abs() < 1e-12, "walking does not climb: {:?}", c.position);
        assert!((c.position[1] + 9.0).abs() < 1e-9);
    }

    #[test]
    fn switching_projection_keeps_the_focal_plane_size() {
        let mut c = cam(false);
        set_parallel(&mut c, true);
        assert!((c.parallel_scale - 10.0 * 15f64.to_radians().tan()).abs() < 1e-12);
        c.parallel_scale = 4.0;
        set_parallel(&mut c, false);
        assert!((DVec3::from(c.position).length() * 15f64.to_radians().tan() - 4.0).abs() < 1e-9);
    }

    #[test]
    fn axis_views_look_at_the_focal_point() {
        for v in AxisView::ALL {
            let mut c = cam(true);
            axis_view(&mut c, v);
            c.validate().unwrap();
            assert!((DVec3::from(c.position).length() - 10.0).abs() < 1e-9);
        }
    }
}
