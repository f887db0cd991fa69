//! The camera, with vtkCamera's semantics so our images can be compared with VTK/pyvista
//! renders of the same scene: `position`, `focal_point`, `view_up`, a vertical `view_angle`
//! in degrees, or `parallel_projection` with `parallel_scale` = half the view height.

use glam::DVec3;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    pub position: [f64; 3],
    pub focal_point: [f64; 3],
    #[serde(default = "default_up")]
    pub view_up: [f64; 3],
    /// Vertical field of view in degrees (perspective).
    #[serde(default = "default_angle")]
    pub view_angle: f64,
    #[serde(default)]
    pub parallel_projection: bool,
    /// Half the view height in world units (parallel projection).
    #[serde(default = "default_scale")]
    pub parallel_scale: f64,
}

fn default_up() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}
fn default_angle() -> f64 {
    30.0
}
fn default_scale() -> f64 {
    1.0
}

/// A ray in world space; `dir` is unit length.
#[derive(Debug, Clone, Copy)]
pub struct Ray {
    pub origin: DVec3,
    pub dir: DVec3,
}

/// The camera's orthonormal frame and per-pixel ray generation for a given image size.
#[derive(Debug, Clone)]
pub struct RayGenerator {
    eye: DVec3,
    forward: DVec3,
    right: DVec3,
    up: DVec3,
    half_h: f64,
    half_w: f64,
    parallel: bool,
    width: usize,
    height: usize,
}

impl Camera {
    /// Checks the camera describes a view: distinct eye and focal point, an up vector not
    /// parallel to the view direction, a sensible angle or scale.
    pub fn validate(&self) -> anyhow::Result<()> {
        let eye = DVec3::from(self.position);
        let fp = DVec3::from(self.focal_point);
        let up = DVec3::from(self.view_up);
        if !(eye.is_finite() && fp.is_finite() && up.is_finite()) {
            anyhow::bail!("camera position, focal_point and view_up must be finite");
        }
        let f = fp - eye;
        if f.length() == 0.0 {
            anyhow::bail!("camera position and focal_point coincide");
        }
        if f.normalize().cross(up).length() < 1e-9 || up.length() == 0.0 {
            anyhow::bail!("camera view_up is parallel to the view direction");
        }
        if self.parallel_projection {
            if !(self.parallel_scale > 0.0 && self.parallel_scale.is_finite()) {
                anyhow::bail!("parallel_scale {} must be positive", self.parallel_scale);
            }
        } else if !(self.view_angle > 0.0 && self.view_angle < 180.0) {
            anyhow::bail!("view_angle {} must be between 0 and 180 degrees", self.view_angle);
        }
        Ok(())
    }

    pub fn rays(&self, width: usize, height: usize) -> RayGenerator {
        let eye = DVec3::from(self.position);
        let forward = (DVec3::from(self.focal_point) - eye).normalize();
        // As vtkCamera: view_up is orthogonalised against the direction of projection.
        let right = forward.cross(DVec3::from(self.view_up)).normalize();
        let up = right.cross(forward);
        let aspect = width as f64 / height as f64;
        let half_h = if self.parallel_projection { self.parallel_scale } else { (0.5 * self.view_angle.to_radians()).tan() };
        RayGenerator { eye, forward, right, up, half_h, half_w: half_h * aspect, parallel: self.parallel_projection, width, height }
    }
}

impl RayGenerator {
    /// The ray through image position (x, y) in pixels, (0, 0) the top-left corner of the
    /// image, pixel centres at half-integers.
    pub fn ray(&self, x: f64, y: f64) -> Ray {
        let sx = (2.0 * x / self.width as f64 - 1.0) * self.half_w;
        let sy = (1.0 - 2.0 * y / self.height as f64) * self.half_h;
        if self.parallel {
            Ray { origin: self.eye + self.right * sx + self.up * sy, dir: self.forward }
        } else {
            Ray { origin: self.eye, dir: (self.forward + self.right * sx + self.up * sy).normalize() }
        }
    }
    pub fn is_parallel(&self) -> bool {
        self.parallel
    }
    /// Image width and height in pixels.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }
    pub fn forward(&self) -> DVec3 {
        self.forward
    }
    /// Eye, then the right and up unit vectors of the view plane.
    pub fn basis(&self) -> (DVec3, DVec3, DVec3) {
        (self.eye, self.right, self.up)
    }
    /// Half the view plane's width and height: at distance 1 (perspective) or in world
    /// units (parallel).
    pub fn half_extent(&self) -> (f64, f64) {
        (self.half_w, self.half_h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_ray_points_at_the_focal_point_and_edges_match_the_view_angle() {
        let cam = Camera {
            position: [0.0, -10.0, 0.0],
            focal_point: [0.0; 3],
            view_up: [0.0, 0.0, 1.0],
            view_angle: 60.0,
            parallel_projection: false,
            parallel_scale: 1.0,
        };
        let g = cam.rays(200, 100);
        let c = g.ray(100.0, 50.0);
        assert!((c.dir - DVec3::Y).length() < 1e-12);
        let top = g.ray(100.0, 0.0);
        assert!((top.dir.angle_between(DVec3::Y).to_degrees() - 30.0).abs() < 1e-9);
        assert!(top.dir.z > 0.0, "row 0 is the top of the image");
        let right = g.ray(200.0, 50.0);
        assert!(right.dir.x > 0.0, "+x is to the right when looking along +y with z up");
    }

    #[test]
    fn parallel_rays_span_twice_the_parallel_scale() {
        let cam = Camera {
            position: [0.0, 0.0, 10.0],
            focal_point: [0.0; 3],
            view_up: [0.0, 1.0, 0.0],
            view_angle: 30.0,
            parallel_projection: true,
            parallel_scale: 5.0,
        };
        let g = cam.rays(10, 10);
        assert!((g.ray(5.0, 0.0).origin.y - 5.0).abs() < 1e-12);
        assert!((g.ray(5.0, 10.0).origin.y + 5.0).abs() < 1e-12);
        assert!((g.ray(0.0, 5.0).dir - DVec3::NEG_Z).length() < 1e-12);
    }
}
