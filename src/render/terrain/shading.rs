//! How a terrain hit is coloured — the same rules in f64 here (for the CPU reference) and
//! in `shaders/terrain_raycast.wgsl`: base colour from the drape (sRGB decoded, bilinear,
//! premultiplied alpha over the elevation colours, placed by `LinearTexture::placement`)
//! or the elevation colours alone (a colour map, hypsometric tints by default, looked up
//! in a 256-entry table on both paths);
//! Lambert lighting from directional lights, an ambient term, optional hard shadows.

use crate::colormap::Colormap;
use crate::scene::drape::Drape;
use crate::scene::{Light, LightKind};
use anyhow::{bail, Result};
use glam::DVec3;

/// The GPU shader has room for this many lights.
pub const MAX_LIGHTS: usize = 4;

#[derive(Debug, Clone, Copy)]
pub struct SunLight {
    /// Unit vector toward the light, world space.
    pub to_light: DVec3,
    /// Colour × intensity.
    pub radiance: [f64; 3],
}

/// The scene's lights as the terrain renderer uses them: directional only. With none, the
/// cartographers' hill-shade sun: from the north-west (azimuth 315°), 45° up.
pub fn sun_lights(lights: &[Light]) -> Result<Vec<SunLight>> {
    if lights.is_empty() {
        let (az, alt) = (315f64.to_radians(), 45f64.to_radians());
        return Ok(vec![SunLight { to_light: DVec3::new(az.sin() * alt.cos(), az.cos() * alt.cos(), alt.sin()), radiance: [1.0; 3] }]);
    }
    if lights.len() > MAX_LIGHTS {
        bail!("the terrain renderer takes at most {MAX_LIGHTS} lights (the scene has {})", lights.len());
    }
    lights
        .iter()
        .map(|l| {
            if l.kind != LightKind::Directional {
                bail!("the terrain renderer lights with directional lights (suns) only, not {:?} lights", l.kind);
            }
            Ok(SunLight { to_light: -l.travel_direction()?, radiance: l.color.map(|c| c * l.intensity) })
        })
        .collect()
}

/// Entries of the elevation colour table both paths look colours up in.
pub const RAMP_ENTRIES: usize = 256;

/// The colour table the GPU gets, and the reference uses: 256 entries evenly spaced over
/// the grid's elevations `grid_range` (metres; both paths index it by the elevation's place
/// in that range), each `colormap` at that elevation's place in `colour_range` (clamped to
/// its ends) — the same where the two ranges are one, so a colour range costs the shaders
/// nothing.
pub fn elevation_ramp(colormap: Colormap, grid_range: [f64; 2], colour_range: Option<[f64; 2]>) -> Vec<[f32; 3]> {
    let [lo, hi] = grid_range;
    let [clo, chi] = colour_range.unwrap_or(grid_range);
    let span = (chi - clo).max(1e-9);
    (0..RAMP_ENTRIES)
        .map(|i| {
            let t = i as f64 / (RAMP_ENTRIES - 1) as f64;
            if colour_range.is_none() {
                return colormap.at(t);
            }
            colormap.at(((lo + t * (hi - lo) - clo) / span).clamp(0.0, 1.0))
        })
        .collect()
}

/// The elevation colour at normalised elevation f ∈ [0, 1] (clamped): linear between the
/// table's entries, as the shader's `elevation_colour`.
pub fn elevation_colour(ramp: &[[f32; 3]], f: f64) -> [f64; 3] {
    let x = f.clamp(0.0, 1.0) * (ramp.len() - 1) as f64;
    let i = (x.floor() as usize).min(ramp.len() - 2);
    let s = x - i as f64;
    [0, 1, 2].map(|k| ramp[i][k] as f64 + s * (ramp[i + 1][k] as f64 - ramp[i][k] as f64))
}

/// The sRGB transfer function inverted (IEC 61966-2-1), as a GPU's `*Srgb` formats decode.
pub fn srgb_to_linear(v: u8) -> f64 {
    let c = v as f64 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// A drape decoded to linear RGBA (premultiplied), sampled bilinearly with clamp-to-edge
/// as a GPU's linear sampler does, and placed over the grid: texture coordinates
/// s = s0 + s1·gx, t = t0 + t1·gy of grid point (gx, gy) (`placement` = [s0, s1, t0, t1]).
pub struct LinearTexture {
    width: usize,
    height: usize,
    texels: Vec<[f64; 4]>,
    pub placement: [f64; 4],
}

impl LinearTexture {
    pub fn new(drape: &Drape, placement: [f64; 4]) -> LinearTexture {
        let lut: Vec<f64> = (0..=255u8).map(srgb_to_linear).collect();
        let texels =
            drape.rgba.chunks_exact(4).map(|p| [lut[p[0] as usize], lut[p[1] as usize], lut[p[2] as usize], p[3] as f64 / 255.0]).collect();
        LinearTexture { width: drape.width, height: drape.height, texels, placement }
    }

    /// (s, t) ∈ [0, 1]²: s east, t south (t = 0 the top row).
    pub fn sample(&self, s: f64, t: f64) -> [f64; 4] {
        let x = s * self.width as f64 - 0.5;
        let y = t * self.height as f64 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let texel = |xi: f64, yi: f64| {
            let xi = (xi.max(0.0) as usize).min(self.width - 1);
            let yi = (yi.max(0.0) as usize).min(self.height - 1);
            self.texels[yi * self.width + xi]
        };
        let (a, b, c, d) = (texel(x0, y0), texel(x0 + 1.0, y0), texel(x0, y0 + 1.0), texel(x0 + 1.0, y0 + 1.0));
        [0, 1, 2, 3].map(|k| (1.0 - fy) * ((1.0 - fx) * a[k] + fx * b[k]) + fy * ((1.0 - fx) * c[k] + fx * d[k]))
    }

    /// The base colour at grid point (gx, gy) over `under` (the elevation colour): the drape
    /// where it covers the point, premultiplied over `under`; `under` beyond its edges.
    pub fn base(&self, gx: f64, gy: f64, under: [f64; 3]) -> [f64; 3] {
        let [s0, s1, t0, t1] = self.placement;
        let (s, t) = (s0 + s1 * gx, t0 + t1 * gy);
        if !((0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&t)) {
            return under;
        }
        let c = self.sample(s, t);
        [0, 1, 2].map(|k| c[k] + (1.0 - c[3]) * under[k])
    }
}

/// Shading settings shared by the GPU renderer and the reference.
#[derive(Debug, Clone)]
pub struct Shading {
    pub lights: Vec<SunLight>,
    pub ambient: f64,
    pub shadows: bool,
    /// Normals interpolated across patches (else each patch's own, faceted).
    pub smooth: bool,
    /// k: k × k rays per pixel on a stratified grid, colours averaged (1: one ray through
    /// the pixel's centre). Depth stays the centre ray's.
    pub rays_per_side: u32,
    /// The colour map elevations are shown through (low at the lowest valid sample, high at
    /// the highest, unless `colour_range` says otherwise).
    pub colormap: Colormap,
    /// The elevations (metres) at the colour map's ends; None: the grid's valid range.
    pub colour_range: Option<[f64; 2]>,
}

/// Lambert shading: base · (ambient + Σ radiance · max(0, n·l) · lit).
pub fn shade(base: [f64; 3], normal: DVec3, shading: &Shading, lit: &dyn Fn(usize) -> bool) -> [f64; 3] {
    let mut e = [shading.ambient; 3];
    for (k, l) in shading.lights.iter().enumerate() {
        let cos = normal.dot(l.to_light);
        if cos > 0.0 && lit(k) {
            for c in 0..3 {
                e[c] += l.radiance[c] * cos;
            }
        }
    }
    [0, 1, 2].map(|c| base[c] * e[c])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_colour_range_remaps_the_table_over_the_grids_elevations() {
        let map = Colormap::Hypsometric;
        let plain = elevation_ramp(map, [100.0, 600.0], None);
        // The grid's own range as the colour range: the same table (to rounding).
        let same = elevation_ramp(map, [100.0, 600.0], Some([100.0, 600.0]));
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= 1e-6);
        assert!(plain.iter().zip(&same).all(|(a, b)| close(*a, *b)));
        // Colours over 0..1100 m: the grid's 100..600 m take the map's 1/11..6/11.
        let wide = elevation_ramp(map, [100.0, 600.0], Some([0.0, 1100.0]));
        for (i, c) in wide.iter().enumerate() {
            let e = 100.0 + 500.0 * i as f64 / (RAMP_ENTRIES - 1) as f64;
            assert!(close(*c, map.at(e / 1100.0)), "entry {i}");
        }
        // A narrower range clamps at its ends: below 300 m the low colour, above 400 m the high.
        let narrow = elevation_ramp(map, [100.0, 600.0], Some([300.0, 400.0]));
        assert!(close(narrow[0], map.at(0.0)) && close(narrow[RAMP_ENTRIES - 1], map.at(1.0)));
        assert!(!close(plain[0], narrow[RAMP_ENTRIES / 2]), "the middle moved along the map");
    }
}
