//! The Henyey–Greenstein phase function: density and importance sampling. Angles are
//! between propagation directions: cos θ = ω_in · ω_out, so g > 0 scatters forward.

use glam::DVec3;
use std::f64::consts::PI;

/// p(cos θ) = (1 − g²) / (4π (1 + g² − 2g cos θ)^{3/2}); integrates to 1 over the sphere.
pub fn hg(cos: f64, g: f64) -> f64 {
    let denom = 1.0 + g * g - 2.0 * g * cos;
    (1.0 - g * g) / (4.0 * PI * denom * denom.sqrt())
}

/// cos θ drawn from HG by inverting its CDF (the paper's formula). Near g = 0 the formula
/// divides 0 by 0, so |g| < 1e-3 samples the isotropic 1 − 2ξ instead (the difference in
/// the density is below 0.3 %); for |g| → 1 the result is clamped into [−1, 1].
pub fn sample_hg_cos(g: f64, xi: f64) -> f64 {
    if g.abs() < 1e-3 {
        return 1.0 - 2.0 * xi;
    }
    let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * xi);
    ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
}

/// A new propagation direction for a photon travelling along `dir` (unit).
pub fn sample_hg(dir: DVec3, g: f64, xi1: f64, xi2: f64) -> DVec3 {
    let cos = sample_hg_cos(g, xi1);
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let phi = 2.0 * PI * xi2;
    let (u, v) = orthonormal(dir);
    (u * (sin * phi.cos()) + v * (sin * phi.sin()) + dir * cos).normalize()
}

/// Two unit vectors completing `n` (unit) to an orthonormal frame (Duff et al. 2017).
pub fn orthonormal(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x), DVec3::new(b, sign + n.y * n.y * a, -n.y))
}
