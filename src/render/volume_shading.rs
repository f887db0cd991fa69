//! Gradient shading of volume samples, as VTK's `vtkVolumeProperty` with `ShadeOn` under
//! VTK's default two-sided lighting (its fixed-point mapper's `vtkEncodedGradientShader`):
//! each sample's colour C becomes
//!
//!   C · (ambient + Σ diffuse · max(N'·L, 0) · light) + Σ specular · (N'·H)^power · light
//!
//! where N is the unit gradient of the real-valued field in world millimetres and N' the
//! one of ±N that faces the eye, L the unit vector toward the light, H the half vector of
//! L and the direction toward the eye, and `light` its colour × intensity; the highlight
//! only where N'·L > 0 and N'·H > 0.001 (VTK's). Under the headlight N'·L = |N·L|; a light
//! from the side leaves the surface that faces away from it dark, as VTK does (until
//! 2026-12-06 the normal was turned toward the light instead: |N·L|, 14.8 % from VTK's
//! fixed-point mapper on a side-lit sphere where the headlight gave 0.40 %). Opacity is
//! not changed. A scene without lights is lit by a white headlight (VTK's default light).
//! The ambient term is ambient · C, as VTK's GPU mapper applies it (its fixed-point mapper
//! scales it by the lights' ambient colour, black by default).
//! Where the gradient is exactly zero (a flat region) there is no normal: the sample is
//! lit as a surface facing the light, C · (ambient + Σ diffuse · light), so flat regions
//! are neither black nor NaN.
//!
//! The gradient: central differences of the trilinear field one voxel either side along
//! each voxel axis, shortened to stay inside the box of voxel centres (one-sided at the
//! volume's edge; 0 along a single-voxel axis), then taken to world millimetres by the
//! inverse transpose of the voxel-index-to-world matrix.

use crate::scene::{Light, LightKind, VolumeShading};
use anyhow::Result;
use glam::{DMat3, DMat4, DVec3, Mat3, Vec3};

/// One light as the volume shader uses it.
#[derive(Debug, Clone, Copy)]
pub enum Source {
    /// Toward the light, world space.
    Directional(DVec3),
    Point(DVec3),
    /// At the eye, looking along the ray.
    Head,
}

/// The scene's lights and a node's shading coefficients, ready for every sample.
pub struct Shader {
    coeffs: VolumeShading,
    lights: Vec<(Source, [f64; 3])>,
    /// Index-space gradient → world-space gradient (the inverse transpose).
    gradient_to_world: DMat3,
}

impl Shader {
    /// None when the node does not shade.
    pub fn new(shading: Option<&VolumeShading>, lights: &[Light], index_to_world: DMat4) -> Result<Option<Shader>> {
        let Some(coeffs) = shading.filter(|s| s.shade).copied() else { return Ok(None) };
        let lights = if lights.is_empty() {
            vec![(Source::Head, [1.0; 3])]
        } else {
            lights
                .iter()
                .map(|l| {
                    let colour = l.color.map(|c| c * l.intensity);
                    let source = match l.kind {
                        LightKind::Directional => Source::Directional(-l.travel_direction()?),
                        // A spot lights the volume as a point light at its position: the
                        // cone is not applied to volume shading (as VTK's volume mappers).
                        LightKind::Point | LightKind::Spot => Source::Point(l.location()?),
                    };
                    Ok((source, colour))
                })
                .collect::<Result<Vec<_>>>()?
        };
        Ok(Some(Shader { coeffs, lights, gradient_to_world: gradient_to_world(index_to_world) }))
    }

    /// The shading coefficients (ambient, diffuse, specular, power).
    pub fn coefficients(&self) -> VolumeShading {
        self.coeffs
    }

    /// The lights (the headlight where the scene has none), each with its colour ×
    /// intensity: what a renderer that shades elsewhere (the GPU) hands on.
    pub fn lights(&self) -> &[(Source, [f64; 3])] {
        &self.lights
    }

    /// The gradient of the trilinear field `f` (continuous voxel index → value) at `p`,
    /// in world units, by the rule in the module's doc.
    pub fn gradient(&self, dims: [usize; 3], p: DVec3, f: impl Fn(DVec3) -> f64) -> DVec3 {
        gradient(dims, p, &self.gradient_to_world, f)
    }

    /// The shaded colour of a sample of colour `colour` at world point `at` with world
    /// gradient `gradient`, seen along the unit ray direction `dir`.
    pub fn shade(&self, colour: [f64; 3], gradient: DVec3, at: DVec3, dir: DVec3) -> [f64; 3] {
        let l = self.lighting(gradient, at, dir);
        [0, 1, 2].map(|k| colour[k] * l.diffuse[k] + l.specular[k])
    }

    /// The two factors of the shading formula at one sample: what multiplies its colour
    /// (ambient and diffuse) and what adds to it (specular).
    pub fn lighting(&self, gradient: DVec3, at: DVec3, dir: DVec3) -> Lighting {
        let VolumeShading { ambient, diffuse, specular, specular_power, .. } = self.coeffs;
        let len = gradient.length();
        let normal = (len > 0.0 && len.is_finite()).then(|| gradient / len);
        let to_eye = -dir;
        let (mut d, mut s) = ([ambient; 3], [0.0; 3]);
        for &(source, light) in &self.lights {
            let to_light = match source {
                Source::Directional(l) => l,
                Source::Point(q) => (q - at).normalize_or_zero(),
                Source::Head => to_eye,
            };
            let (lambert, highlight) = match normal {
                None => (1.0, 0.0),
                Some(n) => {
                    // Two-sided, as VTK: the side of the surface that faces the eye.
                    let n = if n.dot(to_eye) < 0.0 { -n } else { n };
                    let h = (to_light + to_eye).normalize_or_zero();
                    let (nl, nh) = (n.dot(to_light), n.dot(h));
                    (nl.max(0.0), if nl > 0.0 && nh > 0.001 { nh.powf(specular_power) } else { 0.0 })
                }
            };
            for k in 0..3 {
                d[k] += diffuse * lambert * light[k];
                s[k] += specular * highlight * light[k];
            }
        }
        Lighting { diffuse: d, specular: s }
    }
}

/// Voxel-index gradients → world gradients for a volume placed by `index_to_world`: the
/// inverse transpose of its linear part.
pub fn gradient_to_world(index_to_world: DMat4) -> DMat3 {
    DMat3::from_mat4(index_to_world).inverse().transpose()
}

/// The gradient of the trilinear field `f` (continuous voxel index → value) at `p`, by
/// the rule in the module's doc, taken to world units by `to_world`
/// (`gradient_to_world`). Shading and the gradient opacity both use it.
pub fn gradient(dims: [usize; 3], p: DVec3, to_world: &DMat3, f: impl Fn(DVec3) -> f64) -> DVec3 {
    let mut g = DVec3::ZERO;
    for a in 0..3 {
        let max = (dims[a] - 1) as f64;
        let x = p[a].clamp(0.0, max);
        let (up, down) = ((max - x).min(1.0), x.min(1.0));
        if up + down > 0.0 {
            let (mut hi, mut lo) = (p, p);
            hi[a] = x + up;
            lo[a] = x - down;
            g[a] = (f(hi) - f(lo)) / (up + down);
        }
    }
    *to_world * g
}

/// The same formula in f32 for a renderer whose rays all run along one direction (a
/// parallel view): each directional light's (and the headlight's) L and half vector H are
/// computed once per frame, an integer specular power is a product, not a `powf`, and
/// gradients go from the renderer's index space to world by one f32 matrix. Shear-warp's
/// per-segment shading; the reference keeps the f64 `Shader::lighting` it is measured by.
pub struct ParallelLighting {
    ambient: f32,
    diffuse: f32,
    specular: f32,
    power: f32,
    /// `power` when it is a small whole number.
    power_int: Option<i32>,
    /// Directional lights and the headlight: (L, H, colour, whether it is the headlight).
    fixed: Vec<(Vec3, Vec3, Vec3, bool)>,
    /// Point lights: (position, colour).
    points: Vec<(DVec3, Vec3)>,
    to_eye: Vec3,
    /// Index-space gradient (times `value_scale`) → world-space gradient.
    gradient_to_world: Mat3,
}

impl ParallelLighting {
    /// For rays along the unit world direction `dir`; gradients given in index units
    /// times `value_scale` (for example u16 quanta → real values).
    pub fn new(shader: &Shader, dir: DVec3, value_scale: f64) -> ParallelLighting {
        let VolumeShading { ambient, diffuse, specular, specular_power, .. } = shader.coeffs;
        let to_eye = -dir;
        let (mut fixed, mut points) = (Vec::new(), Vec::new());
        for &(source, light) in &shader.lights {
            let colour = Vec3::from(light.map(|c| c as f32));
            let to_light = match source {
                Source::Directional(l) => l,
                Source::Head => to_eye,
                Source::Point(q) => {
                    points.push((q, colour));
                    continue;
                }
            };
            let head = matches!(source, Source::Head);
            fixed.push((to_light.as_vec3(), (to_light + to_eye).normalize_or_zero().as_vec3(), colour, head));
        }
        let power_int = (specular_power.fract() == 0.0 && specular_power <= 128.0).then_some(specular_power as i32);
        ParallelLighting {
            ambient: ambient as f32,
            diffuse: diffuse as f32,
            specular: specular as f32,
            power: specular_power as f32,
            power_int,
            fixed,
            points,
            to_eye: to_eye.as_vec3(),
            gradient_to_world: (shader.gradient_to_world * value_scale).as_mat3(),
        }
    }

    /// Whether `lighting` uses its sample position (a point light).
    pub fn needs_position(&self) -> bool {
        !self.points.is_empty()
    }

    /// (ambient + diffuse, specular) per channel for index-space gradient `g` at world
    /// point `at` (read only when `needs_position`), as `Shader::lighting`.
    #[inline]
    pub fn lighting(&self, g: Vec3, at: DVec3) -> (Vec3, Vec3) {
        self.lighting_along::<false>(g, at, self.to_eye)
    }

    /// As `lighting`, for a sample whose own ray reaches the eye along the unit vector
    /// `to_eye` (a perspective view): the half vectors, and the headlight, follow it.
    #[inline]
    pub fn lighting_seen_from(&self, g: Vec3, at: DVec3, to_eye: Vec3) -> (Vec3, Vec3) {
        self.lighting_along::<true>(g, at, to_eye)
    }

    /// PER_RAY: `to_eye` is the sample's own (the half vectors and the headlight follow
    /// it); else the frame's, with L and H as computed once (a constant, so the parallel
    /// path compiles without the per-ray work).
    #[inline(always)]
    fn lighting_along<const PER_RAY: bool>(&self, g: Vec3, at: DVec3, to_eye: Vec3) -> (Vec3, Vec3) {
        let g = self.gradient_to_world * g;
        let len = g.length();
        let normal = (len > 0.0 && len.is_finite()).then(|| g / len);
        let (mut d, mut s) = (Vec3::splat(self.ambient), Vec3::ZERO);
        let mut add = |to_light: Vec3, h: Vec3, colour: Vec3| {
            let (lambert, highlight) = match normal {
                None => (1.0, 0.0),
                Some(n) => {
                    // Two-sided, as VTK: the side of the surface that faces the eye.
                    let n = if n.dot(to_eye) < 0.0 { -n } else { n };
                    let (nl, nh) = (n.dot(to_light), n.dot(h));
                    (nl.max(0.0), if self.specular > 0.0 && nl > 0.0 && nh > 0.001 { self.pow(nh) } else { 0.0 })
                }
            };
            d += colour * (self.diffuse * lambert);
            s += colour * (self.specular * highlight);
        };
        for &(l, h, colour, head) in &self.fixed {
            if !PER_RAY {
                add(l, h, colour);
            } else if head {
                add(to_eye, to_eye, colour);
            } else {
                add(l, (l + to_eye).normalize_or_zero(), colour);
            }
        }
        for &(q, colour) in &self.points {
            let l = (q - at).normalize_or_zero().as_vec3();
            add(l, (l + to_eye).normalize_or_zero(), colour);
        }
        (d, s)
    }

    #[inline]
    fn pow(&self, x: f32) -> f32 {
        match self.power_int {
            Some(p) => x.powi(p),
            None => x.powf(self.power),
        }
    }
}

/// The shading of one sample: shaded colour = colour · diffuse + specular, per channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lighting {
    /// Ambient plus diffuse: multiplies the sample's colour.
    pub diffuse: [f64; 3],
    /// The highlight: added to the shaded colour.
    pub specular: [f64; 3],
}
