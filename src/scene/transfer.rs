//! Transfer functions with vtkVolumeProperty's semantics: piecewise-linear colour and
//! scalar opacity over the real-world scalar value (clamped outside the given points), and
//! `scalar_opacity_unit_distance`: opacity is per that distance in world units, so a step
//! Δ uses α' = 1 − (1 − α)^(Δ / unit_distance). An optional gradient opacity (VTK's
//! `SetGradientOpacity`) multiplies the scalar opacity per unit distance by a
//! piecewise-linear factor of the gradient magnitude |∇f| (value units per millimetre,
//! the gradient shading uses) before the step correction: α' = 1 − (1 − α·g(|∇f|))^(Δ/unit).

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TransferFunction {
    /// (value, opacity) points, values increasing.
    pub scalar_opacity: Vec<[f64; 2]>,
    /// (value, r, g, b) points, values increasing, linear RGB in [0, 1].
    #[serde(default = "default_color")]
    pub color: Vec<[f64; 4]>,
    #[serde(default = "one")]
    pub scalar_opacity_unit_distance: f64,
    /// (gradient magnitude in value units per mm, factor in [0, 1]) points, magnitudes
    /// increasing; empty: none (every factor 1). MIP ignores it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub gradient_opacity: Vec<[f64; 2]>,
}

fn default_color() -> Vec<[f64; 4]> {
    vec![[0.0, 1.0, 1.0, 1.0]]
}
fn one() -> f64 {
    1.0
}

impl TransferFunction {
    pub fn validate(&self) -> anyhow::Result<()> {
        if self.scalar_opacity.is_empty() {
            anyhow::bail!("transfer_function.scalar_opacity needs at least one point");
        }
        if self.color.is_empty() {
            anyhow::bail!("transfer_function.color needs at least one point");
        }
        let finite = |p: &[f64]| p.iter().all(|v| v.is_finite());
        if !self.scalar_opacity.iter().all(|p| finite(p)) || !self.color.iter().all(|p| finite(p)) {
            anyhow::bail!("transfer_function points must be finite numbers");
        }
        for w in self.scalar_opacity.windows(2) {
            if w[1][0] < w[0][0] {
                anyhow::bail!("transfer_function.scalar_opacity values must increase ({} then {})", w[0][0], w[1][0]);
            }
        }
        for w in self.color.windows(2) {
            if w[1][0] < w[0][0] {
                anyhow::bail!("transfer_function.color values must increase ({} then {})", w[0][0], w[1][0]);
            }
        }
        if self.scalar_opacity.iter().any(|p| !(0.0..=1.0).contains(&p[1])) {
            anyhow::bail!("transfer_function.scalar_opacity opacities must lie in [0, 1]");
        }
        if !self.gradient_opacity.iter().all(|p| p[0].is_finite() && (0.0..=1.0).contains(&p[1])) {
            anyhow::bail!("transfer_function.gradient_opacity points are (gradient magnitude, factor in [0, 1])");
        }
        for w in self.gradient_opacity.windows(2) {
            if w[1][0] < w[0][0] {
                anyhow::bail!("transfer_function.gradient_opacity magnitudes must increase ({} then {})", w[0][0], w[1][0]);
            }
        }
        if !(self.scalar_opacity_unit_distance > 0.0 && self.scalar_opacity_unit_distance.is_finite()) {
            anyhow::bail!("transfer_function.scalar_opacity_unit_distance must be positive");
        }
        Ok(())
    }

    /// Opacity per unit distance at real-world value `v`.
    pub fn opacity(&self, v: f64) -> f64 {
        piecewise(&self.scalar_opacity, v, |p| p[1])
    }

    pub fn color(&self, v: f64) -> [f64; 3] {
        [piecewise(&self.color, v, |p| p[1]), piecewise(&self.color, v, |p| p[2]), piecewise(&self.color, v, |p| p[3])]
    }

    /// The gradient opacity factor at gradient magnitude `g` (value units per mm); 1
    /// without a gradient opacity.
    pub fn gradient_factor(&self, g: f64) -> f64 {
        if self.gradient_opacity.is_empty() {
            1.0
        } else {
            piecewise(&self.gradient_opacity, g, |p| p[1])
        }
    }

    /// Opacity for a step of length `step` in world units.
    pub fn opacity_for_step(&self, v: f64, step: f64) -> f64 {
        self.scaled_opacity_for_step(v, step, 1.0)
    }

    /// Opacity for a step of length `step` with the opacity per unit distance scaled by
    /// `factor` (the gradient opacity's).
    pub fn scaled_opacity_for_step(&self, v: f64, step: f64, factor: f64) -> f64 {
        let a = self.opacity(v) * factor;
        if a >= 1.0 {
            1.0
        } else {
            1.0 - (1.0 - a).powf(step / self.scalar_opacity_unit_distance)
        }
    }
}

/// Piecewise-linear interpolation through points sorted by their first element, clamped
/// to the end values outside.
fn piecewise<const N: usize>(pts: &[[f64; N]], v: f64, y: impl Fn(&[f64; N]) -> f64) -> f64 {
    let first = &pts[0];
    if v <= first[0] {
        return y(first);
    }
    for w in pts.windows(2) {
        if v <= w[1][0] {
            let span = w[1][0] - w[0][0];
            if span <= 0.0 {
                return y(&w[1]);
            }
            let t = (v - w[0][0]) / span;
            return y(&w[0]) + t * (y(&w[1]) - y(&w[0]));
        }
    }
    y(&pts[pts.len() - 1])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_clamps_and_corrects_for_step() {
        let tf = TransferFunction {
            scalar_opacity: vec![[10.0, 0.0], [20.0, 0.5]],
            color: vec![[0.0, 1.0, 0.0, 0.0], [100.0, 0.0, 0.0, 1.0]],
            scalar_opacity_unit_distance: 2.0,
            gradient_opacity: Vec::new(),
        };
        assert_eq!(tf.opacity(5.0), 0.0);
        assert_eq!(tf.opacity(15.0), 0.25);
        assert_eq!(tf.opacity(30.0), 0.5);
        assert_eq!(tf.color(50.0), [0.5, 0.0, 0.5]);
        // Two steps of half the unit distance compose to one step of the unit distance.
        let half = tf.opacity_for_step(20.0, 1.0);
        assert!((1.0 - (1.0 - half).powi(2) - tf.opacity_for_step(20.0, 2.0)).abs() < 1e-15);
        assert!((tf.opacity_for_step(20.0, 2.0) - 0.5).abs() < 1e-15);
    }

    #[test]
    fn shading_keys_left_out_are_vtks_defaults() {
        let s: VolumeShading = toml::from_str("shade = true\nspecular = 0.5").unwrap();
        assert_eq!(s, VolumeShading { shade: true, ambient: 0.1, diffuse: 0.7, specular: 0.5, specular_power: 10.0 });
        let off: VolumeShading = toml::from_str("").unwrap();
        assert!(!off.shade);
    }
}

/// How a volume node is shaded: `vtkVolumeProperty`'s lighting coefficients, with VTK's
/// defaults. Off unless `shade = true` (VTK's default).
/// Keys a table leaves out take the `Default` values.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct VolumeShading {
    pub shade: bool,
    pub ambient: f64,
    pub diffuse: f64,
    pub specular: f64,
    pub specular_power: f64,
}

impl Default for VolumeShading {
    fn default() -> VolumeShading {
        VolumeShading { shade: false, ambient: 0.1, diffuse: 0.7, specular: 0.2, specular_power: 10.0 }
    }
}

impl VolumeShading {
    /// The ranges VTK clamps to, refused here instead.
    pub fn validate(&self) -> anyhow::Result<()> {
        for (name, v) in [("ambient", self.ambient), ("diffuse", self.diffuse), ("specular", self.specular)] {
            if !(0.0..=1.0).contains(&v) {
                anyhow::bail!("shading.{name} = {v} must lie in [0, 1]");
            }
        }
        if !(0.0..=128.0).contains(&self.specular_power) {
            anyhow::bail!("shading.specular_power = {} must lie in [0, 128]", self.specular_power);
        }
        Ok(())
    }
}
