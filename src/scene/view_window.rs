//! Reading only what the views see of a DEM larger than memory allows (issue 20).
//!
//! Where a GeoTIFF heightfield's full raster needs more than the memory limit, the
//! renders' cameras are known before it is read (`Scene::with_views`): each camera's
//! frustum is clipped against the terrain's box — the full raster's sample centres, from
//! its lowest to its highest elevation — and the union of what is left, seen from above,
//! is the window read, at the finest level (the full raster or an overview) where it fits.
//! The window's samples keep their place in the node's frame: it is translated by where
//! its south-west sample lies in the full raster, so the world does not move.

use super::camera::{Camera, RayGenerator};
use glam::{DMat4, DVec2, DVec3, DVec4};

/// The window read of a heightfield node, decided before its data is read.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewWindow {
    /// What the reader is handed: the samples whose centres lie in [west, south, east,
    /// north] (CRS units), at `level` (0 the full raster, k its k-th overview).
    pub extent: [f64; 4],
    pub level: usize,
    /// The window's south-west sample's centre in the node's frame: metres east and north
    /// of the full raster's south-west sample (the node's origin when read whole).
    pub offset: DVec2,
    /// The whole raster's elevation range (metres) as found on its coarsest level: the
    /// window's terrain spans it (walls as deep, elevation colours over the same range).
    pub span: [f64; 2],
    /// What is said with each frame drawn from it.
    pub note: String,
}

impl ViewWindow {
    /// The translation from the window's own frame (its south-west sample at the origin)
    /// to the node's.
    pub fn placement(&self) -> DMat4 {
        DMat4::from_translation(DVec3::new(self.offset.x, self.offset.y, 0.0))
    }
}

/// Half-spaces n · p + d ≥ 0, as (n, d).
type Plane = DVec4;

/// The half-spaces whose intersection holds every point a ray of `rays` can reach: in
/// front of the eye (perspective) or of the image plane through it (parallel), within the
/// four sides of the view.
fn frustum(rays: &RayGenerator) -> Vec<Plane> {
    let (eye, right, up) = rays.basis();
    let forward = rays.forward();
    let (hw, hh) = rays.half_extent();
    let through = |n: DVec3, p: DVec3| n.extend(-n.dot(p));
    let mut planes = vec![through(forward, eye)];
    if rays.is_parallel() {
        // |(p − eye) · right| ≤ hw, |(p − eye) · up| ≤ hh.
        planes.push(through(-right, eye + hw * right));
        planes.push(through(right, eye - hw * right));
        planes.push(through(-up, eye + hh * up));
        planes.push(through(up, eye - hh * up));
    } else {
        // |(p − eye) · right| ≤ hw (p − eye) · forward, the same for up.
        planes.push(through(hw * forward - right, eye));
        planes.push(through(hw * forward + right, eye));
        planes.push(through(hh * forward - up, eye));
        planes.push(through(hh * forward + up, eye));
    }
    planes
}

fn inside(planes: &[Plane], p: DVec3, slack: f64) -> bool {
    planes.iter().all(|q| q.truncate().dot(p) + q.w >= -slack * q.truncate().length())
}

/// The polygon `poly` cut by the half-space `plane` (Sutherland–Hodgman).
fn clip(poly: &[DVec3], plane: Plane) -> Vec<DVec3> {
    let side = |p: DVec3| plane.truncate().dot(p) + plane.w;
    let mut out = Vec::with_capacity(poly.len() + 1);
    for (i, &a) in poly.iter().enumerate() {
        let b = poly[(i + 1) % poly.len()];
        let (sa, sb) = (side(a), side(b));
        if sa >= 0.0 {
            out.push(a);
        }
        if (sa >= 0.0) != (sb >= 0.0) {
            out.push(a + (b - a) * (sa / (sa - sb)));
        }
    }
    out
}

/// The x and y bounds of the box [lo, hi] cut by `planes` (a convex polytope), None where
/// nothing is left. Its vertices are those of the box's faces cut by the planes and the
/// points where three planes meet inside the box (a perspective eye inside it).
fn clipped_box_xy(lo: DVec3, hi: DVec3, planes: &[Plane]) -> Option<(DVec2, DVec2)> {
    let corner = |i: usize| {
        DVec3::new(if i & 1 == 0 { lo.x } else { hi.x }, if i & 2 == 0 { lo.y } else { hi.y }, if i & 4 == 0 { lo.z } else { hi.z })
    };
    // Each face's corners in order round it.
    const FACES: [[usize; 4]; 6] = [[0, 1, 3, 2], [4, 5, 7, 6], [0, 1, 5, 4], [2, 3, 7, 6], [0, 2, 6, 4], [1, 3, 7, 5]];
    let mut points = Vec::new();
    for face in FACES {
        let mut poly: Vec<DVec3> = face.iter().map(|&i| corner(i)).collect();
        for &p in planes {
            if poly.is_empty() {
                break;
            }
            poly = clip(&poly, p);
        }
        points.extend(poly);
    }
    let scale = (hi - lo).length().max(1.0);
    for i in 0..planes.len() {
        for j in i + 1..planes.len() {
            for k in j + 1..planes.len() {
                let (a, b, c) = (planes[i], planes[j], planes[k]);
                let (na, nb, nc) = (a.truncate(), b.truncate(), c.truncate());
                let det = na.dot(nb.cross(nc));
                if det.abs() < 1e-12 * na.length() * nb.length() * nc.length() {
                    continue;
                }
                let p = (-a.w * nb.cross(nc) - b.w * nc.cross(na) - c.w * na.cross(nb)) / det;
                let in_box = p.cmpge(lo - 1e-9 * scale).all() && p.cmple(hi + 1e-9 * scale).all();
                if in_box && inside(planes, p, 1e-9 * scale) {
                    points.push(p);
                }
            }
        }
    }
    let first = points.first()?;
    let (mut min, mut max) = (first.truncate(), first.truncate());
    for p in &points {
        min = min.min(p.truncate());
        max = max.max(p.truncate());
    }
    Some((min, max))
}

/// Columns and rows [c0, r0, c1, r1] (inclusive) of a `size` grid with `cell` metres
/// between samples (row 0 the northern one; the node's frame puts the south-west sample
/// at the origin), placed in the world by `node_to_world`, that the `cameras` can see of
/// it at `image` pixels, elevations within `z`: one sample more on every side (a patch
/// at the window's edge needs both its samples). None where no camera sees any of it.
pub fn visible_window(
    cameras: &[Camera],
    image: (usize, usize),
    node_to_world: DMat4,
    size: [u32; 2],
    cell: [f64; 2],
    z: (f64, f64),
) -> Option<[u32; 4]> {
    let lo = DVec3::new(0.0, 0.0, z.0);
    let hi = DVec3::new((size[0] - 1) as f64 * cell[0], (size[1] - 1) as f64 * cell[1], z.1);
    // A plane P in the world is Mᵀ P in the node's frame (p_world = M p_local).
    let to_local = node_to_world.transpose();
    let mut union: Option<(DVec2, DVec2)> = None;
    for camera in cameras {
        let planes: Vec<Plane> = frustum(&camera.rays(image.0, image.1)).into_iter().map(|p| to_local * p).collect();
        if let Some((a, b)) = clipped_box_xy(lo, hi, &planes) {
            union = Some(match union {
                None => (a, b),
                Some((u, v)) => (u.min(a), v.max(b)),
            });
        }
    }
    let (min, max) = union?;
    let last = [size[0] as f64 - 1.0, size[1] as f64 - 1.0];
    let col = |x: f64| (x / cell[0]).clamp(0.0, last[0]);
    // Rows count from the north: y = (height − 1 − row) · cell.
    let row = |y: f64| (last[1] - y / cell[1]).clamp(0.0, last[1]);
    // A millionth of a cell of rounding in the clipping does not add a sample.
    const ROUNDING: f64 = 1e-6;
    let c0 = ((col(min.x) + ROUNDING).floor() - 1.0).max(0.0) as u32;
    let c1 = ((col(max.x) - ROUNDING).ceil() + 1.0).min(last[0]) as u32;
    let r0 = ((row(max.y) + ROUNDING).floor() - 1.0).max(0.0) as u32;
    let r1 = ((row(min.y) - ROUNDING).ceil() + 1.0).min(last[1]) as u32;
    Some([c0, r0, c1, r1])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn looking_down(height: f64, view_angle: f64) -> Camera {
        Camera {
            position: [500.0, 300.0, height],
            focal_point: [500.0, 300.0, 0.0],
            view_up: [0.0, 1.0, 0.0],
            view_angle,
            parallel_projection: false,
            parallel_scale: 1.0,
        }
    }

    #[test]
    fn a_camera_looking_straight_down_sees_the_square_its_view_angle_spans() {
        // 2001 × 1001 samples 1 m apart, flat at 0 m (z range 0..10): from 100 m up with a
        // 90° view the ground seen is 200 m square, the lid at 10 m a 180 m one inside it.
        let w = visible_window(&[looking_down(100.0, 90.0)], (64, 64), DMat4::IDENTITY, [2001, 1001], [1.0, 1.0], (0.0, 10.0)).unwrap();
        // x 400..600 → columns 399..=601; y 200..400 → rows 1000 − 400 − 1 ..= 1000 − 200 + 1.
        assert_eq!(w, [399, 599, 601, 801]);
        // A wider image sees wider: aspect 2 spans x 300..700.
        let w = visible_window(&[looking_down(100.0, 90.0)], (128, 64), DMat4::IDENTITY, [2001, 1001], [1.0, 1.0], (0.0, 10.0)).unwrap();
        assert_eq!(w, [299, 599, 701, 801]);
        // Cells of 2 m: half the columns and rows for the same ground.
        let w = visible_window(&[looking_down(100.0, 90.0)], (64, 64), DMat4::IDENTITY, [1001, 501], [2.0, 2.0], (0.0, 10.0)).unwrap();
        assert_eq!(w, [199, 299, 301, 401]);
    }

    #[test]
    fn the_node_transform_and_several_cameras_are_taken_into_account() {
        // The node moved 100 m east: the same camera sees columns 100 to the west.
        let m = DMat4::from_translation(DVec3::new(100.0, 0.0, 0.0));
        let w = visible_window(&[looking_down(100.0, 90.0)], (64, 64), m, [2001, 1001], [1.0, 1.0], (0.0, 10.0)).unwrap();
        assert_eq!(w, [299, 599, 501, 801]);
        // Two cameras: the union of what each sees.
        let mut east = looking_down(100.0, 90.0);
        east.position[0] += 1000.0;
        east.focal_point[0] += 1000.0;
        let w =
            visible_window(&[looking_down(100.0, 90.0), east], (64, 64), DMat4::IDENTITY, [2001, 1001], [1.0, 1.0], (0.0, 10.0)).unwrap();
        assert_eq!(w, [399, 599, 1601, 801]);
        // A camera looking away sees nothing of it.
        let mut away = looking_down(100.0, 90.0);
        away.focal_point[2] = 200.0;
        assert_eq!(visible_window(&[away], (64, 64), DMat4::IDENTITY, [2001, 1001], [1.0, 1.0], (0.0, 10.0)), None);
    }

    #[test]
    fn an_eye_inside_the_box_and_a_parallel_view_are_bounded_by_what_they_see() {
        // Eye at 5 m inside a box 0..10 m high, looking north along the ground with a 60°
        // view: it sees from its own position (the eye is a vertex) to the raster's
        // northern edge, widening to ±tan 30° × 501 m there.
        let cam = Camera {
            position: [1000.0, 500.0, 5.0],
            focal_point: [1000.0, 600.0, 5.0],
            view_up: [0.0, 0.0, 1.0],
            view_angle: 60.0,
            parallel_projection: false,
            parallel_scale: 1.0,
        };
        let w = visible_window(std::slice::from_ref(&cam), (64, 64), DMat4::IDENTITY, [2001, 1001], [1.0, 1.0], (0.0, 10.0)).unwrap();
        let half = (30f64.to_radians().tan() * 500.0).ceil() as u32;
        assert_eq!(w, [1000 - half - 1, 0, 1000 + half + 1, 501]);
        // Parallel, half height 50 m looking down: a 100 m square.
        let cam = Camera { parallel_projection: true, parallel_scale: 50.0, ..looking_down(100.0, 30.0) };
        let w = visible_window(&[cam], (64, 64), DMat4::IDENTITY, [2001, 1001], [1.0, 1.0], (0.0, 10.0)).unwrap();
        assert_eq!(w, [449, 649, 551, 751]);
    }
}
