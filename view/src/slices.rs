//! Three orthogonal slices through a volume — axial, coronal, sagittal, in world (RAS+)
//! axes, so oblique acquisitions show as they lie in the patient — through a shared
//! cross-hair point, with window/level grey mapping and patient-direction labels.
//!
//! Display follows the radiological convention of Slicer and every PACS: axial slices are
//! seen from the feet and coronal ones from the front (the patient's right on the screen's
//! left); sagittal slices are seen from the patient's left (anterior on the screen's left).

use glam::{DMat4, DVec3};
use std::sync::Arc;
use volterra_formats::Volume;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plane {
    Axial,
    Coronal,
    Sagittal,
}

impl Plane {
    pub const ALL: [Plane; 3] = [Plane::Axial, Plane::Coronal, Plane::Sagittal];

    pub fn label(self) -> &'static str {
        match self {
            Plane::Axial => "Axial",
            Plane::Coronal => "Coronal",
            Plane::Sagittal => "Sagittal",
        }
    }

    /// World axes of the screen's +u (rightward) and +v (downward), and the normal.
    fn axes(self) -> (DVec3, DVec3, DVec3) {
        match self {
            Plane::Axial => (DVec3::NEG_X, DVec3::NEG_Y, DVec3::Z),
            Plane::Coronal => (DVec3::NEG_X, DVec3::NEG_Z, DVec3::Y),
            Plane::Sagittal => (DVec3::NEG_Y, DVec3::NEG_Z, DVec3::X),
        }
    }

    /// The plane as scene files name it (`[[measurement]]`).
    pub fn scene_plane(self) -> volterra::scene::SlicePlane {
        match self {
            Plane::Axial => volterra::scene::SlicePlane::Axial,
            Plane::Coronal => volterra::scene::SlicePlane::Coronal,
            Plane::Sagittal => volterra::scene::SlicePlane::Sagittal,
        }
    }

    /// Labels at the screen's (left, right, top, bottom) edges.
    pub fn edge_labels(self) -> [&'static str; 4] {
        match self {
            Plane::Axial => ["R", "L", "A", "P"],
            Plane::Coronal => ["R", "L", "S", "I"],
            Plane::Sagittal => ["A", "P", "S", "I"],
        }
    }
}

/// A slice image: grey values, row-major, `width` × `height`, and how its pixels map to
/// the world.
pub struct SliceImage {
    pub width: usize,
    pub height: usize,
    pub grey: Vec<u8>,
    /// World position of the centre of pixel (0, 0), and the world step per pixel along u
    /// and v.
    pub origin: DVec3,
    pub du: DVec3,
    pub dv: DVec3,
}

impl SliceImage {
    /// The world point at fractional pixel position (u, v), pixel centres at half-integers.
    pub fn world_at(&self, u: f64, v: f64) -> DVec3 {
        self.origin + self.du * (u - 0.5) + self.dv * (v - 0.5)
    }
    /// Fractional pixel position of a world point's projection.
    pub fn pixel_of(&self, p: DVec3) -> (f64, f64) {
        let d = p - self.origin;
        (d.dot(self.du) / self.du.length_squared() + 0.5, d.dot(self.dv) / self.dv.length_squared() + 0.5)
    }
}

/// A volume as the slice views sample it.
pub struct SliceSource {
    pub volume: Arc<Volume>,
    world_to_index: DMat4,
    lo: DVec3,
    hi: DVec3,
    pixel: f64,
}

impl SliceSource {
    pub fn new(volume: Arc<Volume>, node_to_world: DMat4) -> SliceSource {
        let index_to_world = node_to_world * volterra::geometry::affine_matrix(&volume.affine);
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for c in 0..8 {
            let ijk = DVec3::new(
                if c & 1 == 0 { 0.0 } else { volume.dims[0] as f64 - 1.0 },
                if c & 2 == 0 { 0.0 } else { volume.dims[1] as f64 - 1.0 },
                if c & 4 == 0 { 0.0 } else { volume.dims[2] as f64 - 1.0 },
            );
            let p = index_to_world.transform_point3(ijk);
            lo = lo.min(p);
            hi = hi.max(p);
        }
        let pixel = volume.spacing.iter().cloned().fold(f64::INFINITY, f64::min).max(1e-6);
        SliceSource { world_to_index: index_to_world.inverse(), volume, lo, hi, pixel }
    }

    /// The world box the slices cover (voxel centres).
    pub fn bounds(&self) -> (DVec3, DVec3) {
        (self.lo, self.hi)
    }

    pub fn centre(&self) -> DVec3 {
        0.5 * (self.lo + self.hi)
    }

    /// Trilinear value at a world point, None outside the voxel centres' box.
    pub fn value_at(&self, p: DVec3) -> Option<f64> {
        let q = self.world_to_index.transform_point3(p);
        let d = self.volume.dims;
        // Inside the box of voxel centres (within rounding), else nothing is drawn there.
        volterra::geometry::trilinear_within(d, q, |i| self.volume.value(i))
    }

    /// The slice through `cross` in `plane`, grey = (value − (level − window/2)) / window.
    /// The world size of a slice pixel in `plane`: the finest voxel spacing, coarser where
    /// the slice would exceed 512 pixels.
    pub fn slice_pixel(&self, plane: Plane) -> f64 {
        let (u, v, _) = plane.axes();
        let ext = |axis: DVec3| ((self.hi - self.lo).dot(axis.abs())).max(self.pixel);
        self.pixel.max(ext(u).max(ext(v)) / 512.0)
    }

    pub fn slice(&self, plane: Plane, cross: DVec3, window: f64, level: f64) -> SliceImage {
        let (u, v, _) = plane.axes();
        // Extent along u and v: the box's, at the finest voxel spacing, at most 512 pixels.
        let ext = |axis: DVec3| ((self.hi - self.lo).dot(axis.abs())).max(self.pixel);
        let (eu, ev) = (ext(u), ext(v));
        let pixel = self.slice_pixel(plane);
        let (w, h) = ((eu / pixel).round() as usize + 1, (ev / pixel).round() as usize + 1);
        // Screen-left/top corner: where u and v start (their negative ends).
        let start = |axis: DVec3| if axis.max_element() > 0.0 { self.lo.dot(axis.abs()) } else { self.hi.dot(axis.abs()) };
        let normal_part = |p: DVec3| p - u.abs() * p.dot(u.abs()) - v.abs() * p.dot(v.abs());
        let origin = normal_part(cross) + u.abs() * start(u) + v.abs() * start(v);
        let (du, dv) = (u * pixel, v * pixel);
        let lo = level - 0.5 * window;
        let inv = 255.0 / window.max(1e-12);
        let mut grey = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let p = origin + du * x as f64 + dv * y as f64;
                if let Some(val) = self.value_at(p) {
                    grey[y * w + x] = ((val - lo) * inv).clamp(0.0, 255.0) as u8;
                }
            }
        }
        SliceImage { width: w, height: h, grey, origin, du, dv }
    }
}

/// A secondary volume fused over the slices (PET over CT, say): its values through a colour
/// map between `level − window/2` (transparent below) and `level + window/2`, blended over
/// the primary's grey at `opacity`.
pub struct Overlay<'a> {
    pub source: &'a SliceSource,
    pub window: f64,
    pub level: f64,
    pub colormap: volterra::colormap::Colormap,
    pub opacity: f64,
}

/// The colours of `img` (sRGB, opaque): its grey, with `overlay` blended over it where the
/// secondary volume covers a pixel and its value lies above the window's lower end.
pub fn fused(img: &SliceImage, overlay: Option<&Overlay>) -> Vec<[u8; 3]> {
    let mut out: Vec<[u8; 3]> = img.grey.iter().map(|&g| [g; 3]).collect();
    let Some(o) = overlay else { return out };
    let lo = o.level - 0.5 * o.window;
    for y in 0..img.height {
        for x in 0..img.width {
            let Some(v) = o.source.value_at(img.world_at(x as f64 + 0.5, y as f64 + 0.5)) else { continue };
            let t = (v - lo) / o.window.max(1e-12);
            if t <= 0.0 {
                continue;
            }
            let c = o.colormap.at(t.min(1.0));
            let p = &mut out[y * img.width + x];
            for k in 0..3 {
                p[k] = (p[k] as f64 * (1.0 - o.opacity) + crate::transfer_editor::srgb(c[k] as f64) as f64 * o.opacity).round() as u8;
            }
        }
    }
    out
}

/// Window/level presets for CT in Hounsfield units, as common PACS viewers name and set
/// them (Radiopaedia's "Windowing (CT)" values): (name, window, level).
pub const CT_WINDOWS: &[(&str, f64, f64)] = &[
    ("Brain", 80.0, 40.0),
    ("Subdural", 200.0, 75.0),
    ("Stroke", 40.0, 40.0),
    ("Bone", 2800.0, 600.0),
    ("Lung", 1500.0, -600.0),
    ("Abdomen", 400.0, 50.0),
    ("Liver", 150.0, 30.0),
    ("Mediastinum", 350.0, 50.0),
];

#[cfg(test)]
mod tests {
    use super::*;
    use volterra_formats::volume::{identity_affine, VoxelData};

    /// 4×3×2 volume with value = 100·k + 10·j + i, 1 mm voxels at the origin.
    fn ramp() -> Arc<Volume> {
        let mut v = vec![];
        for k in 0..2 {
            for j in 0..3 {
                for i in 0..4 {
                    v.push((100 * k + 10 * j + i) as i16);
                }
            }
        }
        Arc::new(Volume::new([4, 3, 2], identity_affine(), VoxelData::I16(v)))
    }

    /// The overlay: transparent below its window, the colour map's top above it, blended
    /// at the opacity; the grey alone where the secondary volume does not reach.
    #[test]
    fn overlay_blends_the_colour_map_over_the_grey() {
        use volterra::colormap::Colormap;
        let primary = SliceSource::new(ramp(), DMat4::IDENTITY);
        let img = primary.slice(Plane::Axial, DVec3::new(0.0, 0.0, 0.0), 256.0, 128.0);
        // A secondary covering x ≤ 2 only, values 0 (x = 0), 50, 100 along x.
        let sec: Vec<f32> = (0..2 * 3 * 3).map(|n| (n % 3) as f32 * 50.0).collect();
        let secondary = SliceSource::new(Arc::new(Volume::new([3, 3, 2], identity_affine(), VoxelData::F32(sec))), DMat4::IDENTITY);
        let o = Overlay { source: &secondary, window: 50.0, level: 25.0, colormap: Colormap::Hot, opacity: 0.5 };
        let out = fused(&img, Some(&o));
        let at = |x: f64| {
            // Pixel of world x on the top row (screen left is world +x).
            let (u, _) = img.pixel_of(DVec3::new(x, 2.0, 0.0));
            out[u as usize]
        };
        let grey = |x: f64| {
            let (u, _) = img.pixel_of(DVec3::new(x, 2.0, 0.0));
            img.grey[u as usize]
        };
        assert_eq!(at(0.0), [grey(0.0); 3], "value 0 is at the window's bottom: transparent");
        assert_eq!(at(3.0), [grey(3.0); 3], "outside the secondary: grey");
        // Value 100 is above the window: hot's top (white) at half opacity over the grey.
        let g = grey(2.0) as f64;
        assert_eq!(at(2.0), [((g + 255.0) / 2.0).round() as u8; 3]);
        // Value 50 is the window's top too; 25 would be the middle.
        assert_eq!(at(1.0), [((grey(1.0) as f64 + 255.0) / 2.0).round() as u8; 3]);
    }

    #[test]
    fn trilinear_values_and_outside() {
        let s = SliceSource::new(ramp(), DMat4::IDENTITY);
        assert_eq!(s.value_at(DVec3::new(1.0, 2.0, 1.0)), Some(121.0));
        assert!((s.value_at(DVec3::new(1.5, 0.5, 0.5)).unwrap() - 56.5).abs() < 1e-12);
        assert_eq!(s.value_at(DVec3::new(3.5, 0.0, 0.0)), None);
    }

    #[test]
    fn axial_slice_puts_the_patients_right_on_the_left_and_anterior_on_top() {
        let s = SliceSource::new(ramp(), DMat4::IDENTITY);
        let img = s.slice(Plane::Axial, DVec3::new(0.0, 0.0, 1.0), 256.0, 128.0);
        assert_eq!((img.width, img.height), (4, 3));
        // Top-left pixel: largest x (right) and largest y (anterior), z = 1.
        let p = img.world_at(0.5, 0.5);
        assert_eq!(p, DVec3::new(3.0, 2.0, 1.0));
        assert_eq!(img.grey[0], ((123.0 - 0.0) * 255.0 / 256.0) as u8);
        let (u, v) = img.pixel_of(DVec3::new(0.0, 0.0, 1.0));
        assert_eq!((u, v), (3.5, 2.5));
    }
}
