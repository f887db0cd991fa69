//! Measurements taken in the viewer — distances, angles and elliptical regions of interest
//! on its slice views, distances and angles between points on the 3-D view's surface —
//! kept in the scene file (`[[measurement]]`) so that a saved scene reopens with them. Points are world millimetres (RAS+), so they stay where they were
//! taken whatever camera or window the scene is opened with. Renders do not draw them.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum MeasurementKind {
    /// Two points: the ends.
    Distance,
    /// Three points: one arm's end, the vertex, the other arm's end.
    Angle,
    /// Two points: opposite corners of the ellipse's box along the slice's axes.
    Ellipse,
}

impl MeasurementKind {
    pub fn points(self) -> usize {
        match self {
            MeasurementKind::Angle => 3,
            MeasurementKind::Distance | MeasurementKind::Ellipse => 2,
        }
    }
}

/// The slice plane a measurement lies in (world axes: axial ⟂ z, coronal ⟂ y, sagittal ⟂ x).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum SlicePlane {
    Axial,
    Coronal,
    Sagittal,
}

impl SlicePlane {
    pub const ALL: [SlicePlane; 3] = [SlicePlane::Axial, SlicePlane::Coronal, SlicePlane::Sagittal];

    /// The world axis the plane is normal to.
    pub fn normal_axis(self) -> usize {
        match self {
            SlicePlane::Axial => 2,
            SlicePlane::Coronal => 1,
            SlicePlane::Sagittal => 0,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Measurement {
    pub kind: MeasurementKind,
    /// The node it was taken on (a volume, for a slice measurement).
    pub node: String,
    /// The slice plane it lies in; none: between points on the 3-D view's surface.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane: Option<SlicePlane>,
    /// World points, as many as the kind takes; on a slice, all on it.
    pub points: Vec<[f64; 3]>,
}

impl Measurement {
    pub fn validate(&self) -> Result<(), String> {
        if self.points.len() != self.kind.points() {
            return Err(format!("a {:?} measurement takes {} points, not {}", self.kind, self.kind.points(), self.points.len()));
        }
        if self.points.iter().flatten().any(|c| !c.is_finite()) {
            return Err("measurement points must be finite".into());
        }
        let Some(plane) = self.plane else {
            if self.kind == MeasurementKind::Ellipse {
                return Err("an ellipse lies on a slice: give its plane".into());
            }
            return Ok(());
        };
        let a = plane.normal_axis();
        let spread = self.points.iter().map(|p| (p[a] - self.points[0][a]).abs()).fold(0.0, f64::max);
        if spread > 1e-6 * (1.0 + self.points[0][a].abs()) {
            return Err(format!("measurement points must lie on one {plane:?} slice (they differ by {spread} mm across it)"));
        }
        Ok(())
    }

    /// Distance: the length (mm). Angle: the angle at the vertex (degrees). Ellipse: its
    /// area (mm²).
    pub fn value(&self) -> f64 {
        let p: Vec<glam::DVec3> = self.points.iter().map(|&q| glam::DVec3::from(q)).collect();
        match self.kind {
            MeasurementKind::Distance => (p[1] - p[0]).length(),
            MeasurementKind::Angle => (p[0] - p[1]).angle_between(p[2] - p[1]).to_degrees(),
            MeasurementKind::Ellipse => {
                let (ra, rb) = self.semi_axes();
                std::f64::consts::PI * ra * rb
            }
        }
    }

    /// An ellipse's semi-axes (mm) along the slice's two in-plane world axes, in axis order
    /// (an ellipse always has its plane: `validate`).
    pub fn semi_axes(&self) -> (f64, f64) {
        let n = self.plane.map_or(2, SlicePlane::normal_axis);
        let d: Vec<f64> = (0..3).filter(|&a| a != n).map(|a| 0.5 * (self.points[1][a] - self.points[0][a]).abs()).collect();
        (d[0], d[1])
    }
}

/// What the viewer's slice views show, saved with the scene (`[slices]`) so that it
/// reopens as it was left: the volume node, its window and level, the cross-hair, and a
/// second volume fused over the slices through a colour map. Renders do not use it.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SliceViews {
    pub node: String,
    pub window: f64,
    pub level: f64,
    /// The cross-hair (world mm) the three slices pass through.
    pub cross: [f64; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub overlay: Option<SliceOverlay>,
}

/// A volume fused over the slices: its values through `colormap` between level ∓ window/2
/// (transparent below), blended over the grey at `opacity`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SliceOverlay {
    pub node: String,
    pub colormap: String,
    pub window: f64,
    pub level: f64,
    pub opacity: f64,
}

impl SliceViews {
    pub fn validate(&self) -> Result<(), String> {
        let window_level = |w: f64, l: f64| {
            if !(w.is_finite() && w > 0.0 && l.is_finite()) {
                return Err(format!("window {w} and level {l} must be finite, the window positive"));
            }
            Ok(())
        };
        window_level(self.window, self.level)?;
        if self.cross.iter().any(|c| !c.is_finite()) {
            return Err("the cross-hair must be finite".into());
        }
        if let Some(o) = &self.overlay {
            window_level(o.window, o.level).map_err(|e| format!("overlay: {e}"))?;
            if !(0.0..=1.0).contains(&o.opacity) {
                return Err(format!("overlay: opacity {} must be between 0 and 1", o.opacity));
            }
            if crate::colormap::Colormap::from_name(&o.colormap).is_none() {
                let names: Vec<&str> = crate::colormap::Colormap::ALL.iter().map(|c| c.name()).collect();
                return Err(format!("overlay: unknown colormap '{}' (known: {})", o.colormap, names.join(", ")));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(kind: MeasurementKind, plane: SlicePlane, points: Vec<[f64; 3]>) -> Measurement {
        Measurement { kind, node: "ct".into(), plane: Some(plane), points }
    }

    #[test]
    fn values_and_refusals() {
        let d = m(MeasurementKind::Distance, SlicePlane::Axial, vec![[0.0, 0.0, 5.0], [3.0, 4.0, 5.0]]);
        assert_eq!(d.validate(), Ok(()));
        assert_eq!(d.value(), 5.0);
        let a = m(MeasurementKind::Angle, SlicePlane::Coronal, vec![[1.0, 2.0, 0.0], [0.0, 2.0, 0.0], [0.0, 2.0, 1.0]]);
        assert!((a.value() - 90.0).abs() < 1e-12);
        // A sagittal ellipse (y, z axes): box 4 × 2 mm, semi-axes 2 and 1.
        let e = m(MeasurementKind::Ellipse, SlicePlane::Sagittal, vec![[7.0, -2.0, 3.0], [7.0, 2.0, 1.0]]);
        assert_eq!(e.semi_axes(), (2.0, 1.0));
        assert!((e.value() - 2.0 * std::f64::consts::PI).abs() < 1e-12);
        let few = m(MeasurementKind::Angle, SlicePlane::Axial, vec![[0.0; 3], [1.0, 0.0, 0.0]]);
        assert!(few.validate().unwrap_err().contains("takes 3 points, not 2"));
        let off = m(MeasurementKind::Distance, SlicePlane::Axial, vec![[0.0; 3], [1.0, 0.0, 0.5]]);
        assert!(off.validate().unwrap_err().contains("one Axial slice"));
        let nan = m(MeasurementKind::Distance, SlicePlane::Axial, vec![[0.0; 3], [f64::NAN, 0.0, 0.0]]);
        assert!(nan.validate().unwrap_err().contains("finite"));
        // On the 3-D surface: points anywhere; an ellipse needs a slice.
        let surface = Measurement { plane: None, ..off };
        assert_eq!(surface.validate(), Ok(()));
        let loose = Measurement { plane: None, ..e };
        assert!(loose.validate().unwrap_err().contains("give its plane"));
    }

    #[test]
    fn slice_views_are_checked() {
        let overlay = SliceOverlay { node: "pet".into(), colormap: "hot".into(), window: 8.0, level: 4.0, opacity: 0.5 };
        let v = SliceViews { node: "ct".into(), window: 400.0, level: 40.0, cross: [0.0; 3], overlay: Some(overlay.clone()) };
        assert_eq!(v.validate(), Ok(()));
        let bad = |o: SliceOverlay| SliceViews { overlay: Some(o), ..v.clone() }.validate().unwrap_err();
        assert!(bad(SliceOverlay { colormap: "jet".into(), ..overlay.clone() }).contains("unknown colormap 'jet' (known: viridis"));
        assert!(bad(SliceOverlay { opacity: 1.5, ..overlay.clone() }).contains("opacity 1.5"));
        assert!(bad(SliceOverlay { window: 0.0, ..overlay }).contains("window 0"));
        assert!(SliceViews { cross: [f64::NAN, 0.0, 0.0], ..v }.validate().unwrap_err().contains("cross-hair"));
    }
}
