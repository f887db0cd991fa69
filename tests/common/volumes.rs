//! Volumes, cameras and transfer functions the volume renderers' tests share
//! (tests/shear_warp.rs, tests/gpu_volume.rs), and their error measure.

use volterra::render::Frame;
use volterra::scene::{Camera, TransferFunction};
use volterra_formats::{Volume, VoxelData};

/// A smooth blob with a shell: values 0..255, non-power-of-two dims.
pub fn blob_values(dims: [usize; 3]) -> Vec<f64> {
    let mut out = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let p = [i, j, k].map(|v| v as f64);
                let r = (0..3).map(|a| ((p[a] - 0.5 * (dims[a] - 1) as f64) / (0.5 * dims[a] as f64)).powi(2)).sum::<f64>().sqrt();
                let v = 200.0 * (-((r - 0.6) / 0.15).powi(2)).exp() + 120.0 * (-(r / 0.25).powi(2)).exp();
                out.push(v.min(255.0));
            }
        }
    }
    out
}

pub fn blob(dims: [usize; 3]) -> Volume {
    Volume::centred(dims, [1.0; 3], VoxelData::U8(blob_values(dims).iter().map(|&v| v as u8).collect()))
}

pub fn camera(dir: [f64; 3], scale: f64) -> Camera {
    let d = glam::DVec3::from(dir).normalize() * 500.0;
    let up = if dir[2].abs() > 0.9 * glam::DVec3::from(dir).length() { [0.0, 1.0, 0.0] } else { [0.0, 0.0, 1.0] };
    Camera {
        position: [-d.x, -d.y, -d.z],
        focal_point: [0.0; 3],
        view_up: up,
        view_angle: 30.0,
        parallel_projection: true,
        parallel_scale: scale,
    }
}

pub fn perspective(dir: [f64; 3], dist: f64, angle: f64) -> Camera {
    let mut cam = camera(dir, 1.0);
    let d = glam::DVec3::from(dir).normalize() * dist;
    cam.position = [-d.x, -d.y, -d.z];
    cam.parallel_projection = false;
    cam.view_angle = angle;
    cam
}

pub fn tf_ramp(lo: f64, hi: f64, a: f64) -> TransferFunction {
    TransferFunction {
        scalar_opacity: vec![[lo, 0.0], [hi, a]],
        color: vec![[lo, 1.0, 0.3, 0.1], [hi, 0.9, 0.9, 1.0]],
        scalar_opacity_unit_distance: 1.0,
        gradient_opacity: Vec::new(),
    }
}

pub fn rel_rmse(a: &Frame, b: &Frame) -> f64 {
    let (mut se, mut rs) = (0.0, 0.0);
    for (p, q) in a.rgba.iter().zip(&b.rgba) {
        for k in 0..4 {
            // A highlight may take a shaded colour past 1, as in the reference.
            assert!(p[k].is_finite() && p[k] >= -1e-6 && p[k] <= 1.5, "value {} out of range", p[k]);
            se += ((p[k] - q[k]) as f64).powi(2);
            rs += (q[k] as f64).powi(2);
        }
    }
    (se / rs.max(1e-300)).sqrt()
}
