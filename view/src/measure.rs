//! Measurements in the slice views: a distance (two clicks), an angle (three clicks: an
//! arm's end, the vertex, the other arm's end) and an elliptical region of interest (two
//! clicks: opposite corners of its box) with the statistics of the values inside — mean,
//! standard deviation, minimum, maximum — in the data's units where the file names them
//! (HU for CT, Bq/ml or SUV for PET), and its area. Kept as the scene's `[[measurement]]`s.

use crate::slices::{Plane, SliceSource};
use crate::view_marks::World;
use egui::{Color32, Pos2, Stroke, Vec2};
use glam::DVec3;
use volterra::scene::{Measurement, MeasurementKind};

/// What a click on a slice does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tool {
    /// Moves the cross-hair (a drag too).
    CrossHair,
    Measure(MeasurementKind),
}

impl Tool {
    pub const ALL: [Tool; 4] = [
        Tool::CrossHair,
        Tool::Measure(MeasurementKind::Distance),
        Tool::Measure(MeasurementKind::Angle),
        Tool::Measure(MeasurementKind::Ellipse),
    ];

    pub fn label(self) -> &'static str {
        match self {
            Tool::CrossHair => "Cross-hair",
            Tool::Measure(MeasurementKind::Distance) => "Distance",
            Tool::Measure(MeasurementKind::Angle) => "Angle",
            Tool::Measure(MeasurementKind::Ellipse) => "Ellipse ROI",
        }
    }

    pub fn hint(self) -> &'static str {
        match self {
            Tool::CrossHair => "Click or drag on a slice to move the cross-hair",
            Tool::Measure(MeasurementKind::Distance) => {
                "Click two points on a slice, or on the 3-D view's surface: their distance in millimetres"
            }
            Tool::Measure(MeasurementKind::Angle) => {
                "Click an arm's end, the vertex, then the other arm's end, on a slice or the 3-D view's surface: the angle in degrees"
            }
            Tool::Measure(MeasurementKind::Ellipse) => {
                "Click two opposite corners of the ellipse's box: mean, SD, minimum, maximum and area of what lies inside"
            }
        }
    }
}

/// The values inside an elliptical region.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoiStats {
    /// Samples inside the ellipse and the volume.
    pub count: usize,
    pub mean: f64,
    /// The sample standard deviation (n − 1).
    pub sd: f64,
    pub min: f64,
    pub max: f64,
    /// The ellipse's area, mm² (π a b).
    pub area_mm2: f64,
}

/// The statistics of an ellipse measurement's values: the volume sampled (trilinear, the
/// slice views' own sampling) on a square grid of the slice's pixel size centred on the
/// ellipse, at the points inside it. None where no sample falls inside the volume.
pub fn roi_stats(source: &SliceSource, plane: Plane, m: &Measurement) -> Option<RoiStats> {
    let n = m.plane?.normal_axis();
    let (a0, a1) = match n {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    let (ra, rb) = m.semi_axes();
    let centre = 0.5 * (DVec3::from(m.points[0]) + DVec3::from(m.points[1]));
    let pitch = source.slice_pixel(plane);
    let (ni, nj) = ((ra / pitch).floor() as i64, (rb / pitch).floor() as i64);
    let mut values = Vec::new();
    for j in -nj..=nj {
        for i in -ni..=ni {
            let (x, y) = (i as f64 * pitch, j as f64 * pitch);
            // Inside: (x/a)² + (y/b)² ≤ 1 (a degenerate axis keeps its centre line).
            let q = |d: f64, r: f64| if r > 0.0 { (d / r).powi(2) } else { 0.0 };
            if q(x, ra) + q(y, rb) > 1.0 {
                continue;
            }
            let mut p = centre;
            p[a0] += x;
            p[a1] += y;
            values.extend(source.value_at(p));
        }
    }
    let count = values.len();
    if count == 0 {
        return None;
    }
    let mean = values.iter().sum::<f64>() / count as f64;
    let (min, max) = values.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    let sd = if count > 1 { (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (count - 1) as f64).sqrt() } else { 0.0 };
    Some(RoiStats { count, mean, sd, min, max, area_mm2: m.value() })
}

/// What a slice measurement reads, one line per quantity (`units`: the data's values', if
/// the file says; `suv_bw`: a PET's factor to SUVbw, which adds the ROI's SUV mean and
/// maximum).
pub fn describe(m: &Measurement, stats: Option<&RoiStats>, units: Option<&str>, suv_bw: Option<f64>) -> Vec<String> {
    let mut lines = describe_in(m, stats, units, World::Patient);
    if let (Some(s), Some(f)) = (stats, suv_bw) {
        lines.push(format!("SUVbw mean {:.2}, max {:.2}", s.mean * f, s.max * f));
    }
    lines
}

/// As `describe`, lengths in the world's units (a terrain's metres, …).
pub fn describe_in(m: &Measurement, stats: Option<&RoiStats>, units: Option<&str>, world: World) -> Vec<String> {
    let u = units.map(|u| format!(" {u}")).unwrap_or_default();
    match m.kind {
        MeasurementKind::Distance => vec![match world {
            World::Patient => format!("{:.1} mm", m.value()),
            World::Terrain => format!("{:.1} m", m.value()),
            World::Plain => format!("{:.4}", m.value()),
        }],
        MeasurementKind::Angle => vec![format!("{:.1}°", m.value())],
        MeasurementKind::Ellipse => match stats {
            Some(s) => vec![
                format!("mean {:.1}{u}, SD {:.1}", s.mean, s.sd),
                format!("min {:.1}, max {:.1}", s.min, s.max),
                format!("area {:.1} mm²", s.area_mm2),
            ],
            None => vec![format!("area {:.1} mm² (outside the volume)", m.value())],
        },
    }
}

/// Draws a measurement (complete or with the points placed so far) on a view whose visible
/// part is `painter`'s clip rectangle. A complete one gets its reading beside it, kept
/// inside the view.
pub fn draw(painter: &egui::Painter, kind: MeasurementKind, points: &[Pos2], lines: &[String]) {
    let orange = Color32::from_rgb(255, 120, 40);
    let stroke = Stroke::new(2.0, orange);
    let complete = points.len() == kind.points();
    // An ellipse's two points are its box's corners, not on it: marked only while placed.
    if !(complete && kind == MeasurementKind::Ellipse) {
        for &p in points {
            painter.circle_filled(p, 3.0, orange);
        }
    }
    match kind {
        MeasurementKind::Distance | MeasurementKind::Angle => {
            for w in points.windows(2) {
                painter.line_segment([w[0], w[1]], stroke);
            }
        }
        MeasurementKind::Ellipse if complete => {
            let (c, r) = (Pos2::new(0.5 * (points[0].x + points[1].x), 0.5 * (points[0].y + points[1].y)), (points[1] - points[0]) * 0.5);
            let outline: Vec<Pos2> = (0..=64)
                .map(|k| {
                    let t = k as f32 / 64.0 * std::f32::consts::TAU;
                    c + Vec2::new(r.x.abs() * t.cos(), r.y.abs() * t.sin())
                })
                .collect();
            painter.add(egui::Shape::line(outline, stroke));
        }
        MeasurementKind::Ellipse => {}
    }
    if complete && !lines.is_empty() {
        // Right of the shape, its top line level with the shape's top; moved left (then
        // below) where that would leave the view.
        let font = egui::FontId::proportional(13.0);
        let galleys: Vec<_> = lines.iter().map(|l| painter.layout_no_wrap(l.clone(), font.clone(), orange)).collect();
        let width = galleys.iter().map(|g| g.size().x).fold(0.0, f32::max);
        let height: f32 = galleys.iter().map(|g| g.size().y).sum();
        let (lo, hi) = points
            .iter()
            .fold((Pos2::new(f32::INFINITY, f32::INFINITY), Pos2::new(f32::NEG_INFINITY, f32::NEG_INFINITY)), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        let view = painter.clip_rect();
        let mut at = Pos2::new(hi.x + 8.0, lo.y);
        if at.x + width > view.right() {
            at = Pos2::new((view.right() - width - 2.0).max(view.left() + 2.0), hi.y + 6.0);
        }
        at.y = at.y.min(view.bottom() - height - 2.0).max(view.top() + 2.0);
        for g in galleys {
            let h = g.size().y;
            painter.galley(at, g, orange);
            at.y += h;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use volterra::scene::SlicePlane;
    use volterra_formats::volume::VoxelData;
    use volterra_formats::Volume;

    /// Values = world x (mm): 41×31×5 voxels of 0.5 mm from x = −10.
    fn ramp() -> SliceSource {
        let d = [41, 31, 5];
        let data = (0..d[0] * d[1] * d[2]).map(|i| (-10.0 + 0.5 * (i % d[0]) as f64) as f32).collect();
        let affine = [[0.5, 0.0, 0.0, -10.0], [0.0, 0.5, 0.0, -7.5], [0.0, 0.0, 0.5, 0.0], [0.0, 0.0, 0.0, 1.0]];
        SliceSource::new(Arc::new(Volume::new(d, affine, VoxelData::F32(data))), glam::DMat4::IDENTITY)
    }

    #[test]
    fn an_ellipse_over_a_ramp_has_the_ramps_moments() {
        // Centre x = 1, semi-axes 6 mm along x and 3 mm along y: the values are x, uniform
        // over the ellipse, so mean 1, SD a/2 = 3 (the continuous moments), min −5, max 7.
        let m = Measurement {
            kind: MeasurementKind::Ellipse,
            node: "v".into(),
            plane: Some(SlicePlane::Axial),
            points: vec![[-5.0, -3.0, 1.0], [7.0, 3.0, 1.0]],
        };
        let s = roi_stats(&ramp(), Plane::Axial, &m).unwrap();
        assert!((s.mean - 1.0).abs() < 1e-9, "{s:?}");
        assert!((s.sd - 3.0).abs() < 0.1, "{s:?}");
        assert!((s.min + 5.0).abs() < 1e-9 && (s.max - 7.0).abs() < 1e-9, "{s:?}");
        assert!((s.area_mm2 - std::f64::consts::PI * 18.0).abs() < 1e-9);
        // The samples cover the ellipse: count × pixel² ≈ its area.
        assert!((s.count as f64 * 0.25 / s.area_mm2 - 1.0).abs() < 0.05, "{s:?}");
        // Read as the data's units, and as SUV where the PET gives its factor.
        let lines = describe(&m, Some(&s), Some("Bq/ml"), Some(0.5));
        assert_eq!(lines[0], "mean 1.0 Bq/ml, SD 3.0", "{lines:?}");
        assert_eq!(lines.last().unwrap(), "SUVbw mean 0.50, max 3.50");
        assert_eq!(describe(&m, Some(&s), None, None).len(), 3);
        // Half outside the volume (x beyond 10): only the inside counts.
        let out = Measurement { points: vec![[4.0, -3.0, 1.0], [16.0, 3.0, 1.0]], ..m };
        let s = roi_stats(&ramp(), Plane::Axial, &out).unwrap();
        assert!(s.max <= 10.0 + 1e-9 && s.count > 0, "{s:?}");
    }
}
