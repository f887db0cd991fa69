//! The terrain renderers for heightfield nodes: `terrain`, the GPU ray-caster over a
//! max-quadtree with a lid map and exact bilinear patches (Park, Oh & Cho), and
//! `terrain-reference`, the f64 cell-by-cell CPU reference it is measured against.
//!
//! - `grid`: the heightfield in grid space, and the exact ray/patch intersection;
//! - `reference`: the CPU reference (2-D DDA over every cell);
//! - `gpu`: wgpu resources, pyramid build, per-pixel ray casting;
//! - `shading`: colour, texture and lights, identical on both paths.

pub mod gpu;
pub mod grid;
pub mod reference;
pub mod shading;

pub use crate::catalog::terrain::{
    gpu_held_bytes, Normals, ReferenceSettings, Settings, Traversal, GPU_BYTES_PER_SAMPLE, REFERENCE_RENDERER, RENDERER,
};
use crate::colormap::Colormap;
use crate::render::Frame;
use crate::scene::camera::RayGenerator;
use crate::scene::drape::Drape;
use crate::scene::Light;
use crate::scene::TerrainData;
use anyhow::{bail, Result};
use glam::DMat4;
use volterra_formats::heightfield::GridGeoref;
use volterra_formats::{Heightfield, Limits};

impl Settings {
    pub fn step_cap(&self, grid: &grid::TerrainGrid) -> u32 {
        if self.max_steps > 0 {
            return self.max_steps;
        }
        let [cx, cy] = grid.cells();
        (4 * (cx + cy) + 64).min(u32::MAX as usize) as u32
    }
    fn check(&self) -> Result<()> {
        self.validate().map_err(|e| anyhow::anyhow!("terrain: {e}"))?;
        self.rays_per_side()?;
        Ok(())
    }

    /// k, where rays_per_pixel = k²; an error for a number that is not a square.
    pub fn rays_per_side(&self) -> Result<u32> {
        let k = (self.rays_per_pixel as f64).sqrt().round() as u32;
        if k * k != self.rays_per_pixel {
            bail!("terrain: rays_per_pixel {} is not a square (1, 4, 9, 16, …): rays lie on a k × k grid", self.rays_per_pixel);
        }
        Ok(k)
    }
}

/// What the terrain renderers draw: one heightfield node.
pub struct TerrainInput<'a> {
    pub heightfield: &'a Heightfield,
    pub texture: Option<&'a Drape>,
    pub node_to_world: DMat4,
    pub lights: &'a [Light],
}

/// What both terrain renderers build from a heightfield placed in the world, kept across
/// frames: the grid (heights in grid space), and on first GPU use the GPU's pyramid and
/// textures.
pub struct Prepared {
    pub grid: grid::TerrainGrid,
    texture: Option<std::sync::Arc<Drape>>,
    /// Where the drape lies over the grid (see `shading::LinearTexture::placement`).
    placement: [f64; 4],
    gpu: std::sync::OnceLock<gpu::GpuTerrain>,
}

/// Where a drape lies over the grid of `hf`: [s0, s1, t0, t1] with texture coordinates
/// s = s0 + s1·gx, t = t0 + t1·gy of grid point (gx, gy) (sample column gx, gy rows north
/// of the southern row; s = 0 and 1 are the image's west and east edges, t = 0 and 1 its
/// north and south). A georeferenced drape lies where its georeferencing says, and must be
/// in the heightfield's CRS and overlap it. A stretched one (a PNG) spans, along each axis,
/// the samples' cells — the raster's outer edges, half a cell beyond the first and last
/// sample centres, as GDAL places a raster — so an image of the DEM's own size has its
/// texel centres on the sample centres; except an image one texel shorter than the samples
/// (a 1024² texture over a 1025² height map), whose texel edges fall on the sample centres:
/// it spans the first to the last sample centre.
pub fn drape_placement(hf: &GridGeoref, drape: &Drape) -> Result<[f64; 4]> {
    let (cx, cy) = ((hf.width - 1) as f64, (hf.height - 1) as f64);
    let Some(g) = &drape.georef else {
        // Along an axis of n samples and m texels: s(g) = (g + o) / (n − 1 + 2o), with
        // o = 0 (vertex-registered, m = n − 1) or ½ (cell-registered, any other m).
        let offset = |samples: usize, texels: usize| if texels + 1 == samples { 0.0 } else { 0.5 };
        let (ox, oy) = (offset(hf.width, drape.width), offset(hf.height, drape.height));
        let (sx, sy) = (1.0 / (cx + 2.0 * ox), 1.0 / (cy + 2.0 * oy));
        return Ok([ox * sx, sx, 1.0 - oy * sy, -sy]);
    };
    if g.crs.epsg.is_none() || g.crs.epsg != hf.crs.epsg || g.crs.geographic != hf.crs.geographic {
        bail!(
            "the texture is in {}, the heightfield in {}: a drape must be in the heightfield's CRS (gdalwarp -t_srs …)",
            g.crs.description,
            hf.crs.description
        );
    }
    let ([hx, hy], [hsx, hsy]) = (hf.origin, hf.cell_size_native);
    let ([ox, oy], [sx, sy]) = (g.origin, g.cell_size_native);
    let (w, h) = (drape.width as f64 * sx, drape.height as f64 * sy);
    let (left, top) = (ox - 0.5 * sx, oy + 0.5 * sy);
    let placement = [(hx - left) / w, hsx / w, (top - hy + cy * hsy) / h, -hsy / h];
    // The drape's extent against the samples' extent (map units).
    let overlaps = left < hx + cx * hsx && left + w > hx && top > hy - cy * hsy && top - h < hy;
    if !overlaps {
        bail!(
            "the texture covers x {left}…{}, y {}…{top}, outside the heightfield (x {hx}…{}, y {}…{hy})",
            left + w,
            top - h,
            hx + cx * hsx,
            hy - cy * hsy
        );
    }
    Ok(placement)
}

impl Prepared {
    /// `heights` are shared, not copied (a GeoTIFF read row by row is held only in the
    /// GPU's textures, once they are built).
    /// `span`: elevations (metres) the terrain's solid spans at least (a view window's: the
    /// whole raster's range; see `TerrainGrid::spanning`).
    pub fn new(
        heights: &TerrainData,
        texture: Option<std::sync::Arc<Drape>>,
        node_to_world: DMat4,
        span: Option<[f64; 2]>,
        limits: &Limits,
    ) -> Result<Prepared> {
        // The GPU's textures, against the memory limit (where they live in host memory, as
        // on lavapipe, the limit counts what the process holds outside its heap too; the grid
        // shares the heights): 4 bytes a sample of heights (up to 5 % more in tiles) and a
        // pyramid of a sixth of that. (The GPU ray-caster checks its uploads' staging and
        // the driver's working memory too, in `check_gpu_upload`.)
        let georef = heights.georef();
        let samples = (georef.width * georef.height) as u64;
        limits.check(std::path::Path::new("terrain"), "the height pyramid", &[samples, GPU_BYTES_PER_SAMPLE])?;
        let placement = match &texture {
            Some(t) => drape_placement(&georef, t)?,
            None => [0.0; 4],
        };
        let grid = match heights {
            TerrainData::Held(hf) => grid::TerrainGrid::shared(hf.clone(), node_to_world)?,
            TerrainData::Rows(rows) => grid::TerrainGrid::from_rows(rows.clone(), node_to_world)?,
        };
        let grid = match span {
            Some(span) => grid.spanning(span, node_to_world)?,
            None => grid,
        };
        Ok(Prepared { grid, texture, placement, gpu: std::sync::OnceLock::new() })
    }

    /// Checks against `limits`, before the GPU's textures are made, all they take
    /// (`gpu_held_bytes`). Nothing where they are made already.
    pub fn check_gpu_upload(&self, limits: &Limits) -> Result<()> {
        if self.gpu.get().is_some() {
            return Ok(());
        }
        let bytes = gpu_held_bytes((self.grid.nx * self.grid.ny) as u64);
        limits.check(std::path::Path::new("terrain"), "the height pyramid and its upload", &[bytes])?;
        Ok(())
    }

    /// Builds the GPU's pyramid and textures now (else on the first GPU render).
    pub fn prepare_gpu(&self) -> Result<()> {
        self.gpu_terrain(gpu::gpu()?).map(|_| ())
    }

    fn gpu_terrain(&self, gpu: &gpu::Gpu) -> Result<&gpu::GpuTerrain> {
        if let Some(t) = self.gpu.get() {
            return Ok(t);
        }
        let t = gpu::GpuTerrain::new(gpu, &self.grid, self.texture.as_deref().map(|d| (d, self.placement)))?;
        Ok(self.gpu.get_or_init(|| t))
    }

    fn shading(&self, lights: &[Light], settings: &Settings, colour_range: Option<[f64; 2]>) -> Result<shading::Shading> {
        settings.check()?;
        Ok(shading::Shading {
            lights: shading::sun_lights(lights)?,
            ambient: settings.ambient,
            shadows: settings.shadows,
            smooth: settings.normals == Normals::Smooth,
            rays_per_side: settings.rays_per_side()?,
            colormap: settings.colormap,
            colour_range,
        })
    }

    /// Renders with the GPU ray-caster (the pyramid is built on first use).
    /// `colour_range`: the elevations at the colour map's ends (None: the valid range read).
    pub fn render(&self, lights: &[Light], rays: &RayGenerator, settings: &Settings, colour_range: Option<[f64; 2]>) -> Result<Frame> {
        let shading = self.shading(lights, settings, colour_range)?;
        let gpu = gpu::gpu()?;
        let terrain = self.gpu_terrain(gpu)?;
        let view = gpu::View {
            grid: &self.grid,
            rays,
            shading: &shading,
            traversal: settings.traversal,
            max_steps: settings.step_cap(&self.grid),
        };
        let mut frame = terrain.render(gpu, &view)?;
        frame.scales.extend(self.elevation_scale(settings.colormap, colour_range));
        Ok(frame)
    }

    /// The elevation colours' scalar bar for the PNG preview: the colour map over
    /// `colour_range`, else from the lowest to the highest valid elevation (metres) — unless
    /// an opaque drape (a PNG, or a GeoTIFF placed over all of it) covers the whole grid,
    /// so that no elevation colour shows.
    fn elevation_scale(&self, colormap: Colormap, colour_range: Option<[f64; 2]>) -> Option<crate::colormap::ColourScale> {
        let g = &self.grid;
        let [s0, s1, t0, t1] = self.placement;
        let (cx, cy) = ((g.nx - 1) as f64, (g.ny - 1) as f64);
        let inside = |v: f64| (-1e-9..=1.0 + 1e-9).contains(&v);
        let spans = inside(s0) && inside(s0 + s1 * cx) && inside(t0) && inside(t0 + t1 * cy);
        let covered = spans && self.texture.as_ref().is_some_and(|t| t.rgba.chunks_exact(4).all(|p| p[3] == 255));
        (!covered && g.any_valid).then(|| crate::colormap::ColourScale {
            title: format!("elevation ({})", g.elevation_unit()),
            colormap,
            range: colour_range.unwrap_or(g.elevations()),
        })
    }

    /// Renders with the f64 CPU reference (`traversal` and `max_steps` do not apply).
    pub fn render_reference(
        &self,
        lights: &[Light],
        rays: &RayGenerator,
        settings: &Settings,
        colour_range: Option<[f64; 2]>,
    ) -> Result<Frame> {
        let shading = self.shading(lights, settings, colour_range)?;
        let texture = self.texture.as_deref().map(|d| shading::LinearTexture::new(d, self.placement));
        let mut frame = reference::render(&self.grid, texture.as_ref(), rays, &shading)?;
        frame.scales.extend(self.elevation_scale(settings.colormap, colour_range));
        Ok(frame)
    }
}

impl TerrainInput<'_> {
    /// A one-off preparation, within the memory available on this machine (a scene hands
    /// its own limits to [`Prepared::new`]).
    fn prepare(&self) -> Result<Prepared> {
        let hf = TerrainData::Held(std::sync::Arc::new(self.heightfield.clone()));
        Prepared::new(&hf, self.texture.map(|t| std::sync::Arc::new(t.clone())), self.node_to_world, None, &Limits::default())
    }
}

/// Renders with the GPU ray-caster.
pub fn render(input: &TerrainInput, rays: &RayGenerator, settings: &Settings) -> Result<Frame> {
    input.prepare()?.render(input.lights, rays, settings, None)
}

/// Renders with the f64 CPU reference (`traversal` and `max_steps` do not apply).
pub fn render_reference(input: &TerrainInput, rays: &RayGenerator, settings: &Settings) -> Result<Frame> {
    input.prepare()?.render_reference(input.lights, rays, settings, None)
}

/// How closely two terrain renders agree on what they hit and how far away it is.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct DepthAgreement {
    /// Pixels that hit in one image and not the other.
    pub mismatched: usize,
    /// ... of which not within one pixel of a silhouette of the reference.
    pub mismatched_off_silhouette: usize,
    /// Pixels that hit in both.
    pub both_hit: usize,
    /// Relative depth error |a − b| / b over pixels that hit in both.
    pub median_rel: f64,
    pub p999_rel: f64,
    pub max_rel: f64,
}

/// Compares the depth of `a` against the reference `b`. A silhouette pixel of `b` is one
/// whose 8 neighbours include a pixel of the other hit state, or one more than 5 % nearer
/// or farther (a ridge in front of distant terrain).
pub fn depth_agreement(a: &Frame, b: &Frame) -> DepthAgreement {
    let (w, h) = (b.width, b.height);
    let silhouette = |x: usize, y: usize| {
        let z = b.depth[y * w + x];
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                    continue;
                }
                let n = b.depth[ny as usize * w + nx as usize];
                if n.is_finite() != z.is_finite() || (z.is_finite() && (n - z).abs() > 0.05 * z.min(n)) {
                    return true;
                }
            }
        }
        false
    };
    let mut out = DepthAgreement::default();
    let mut rel = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let (za, zb) = (a.depth[y * w + x], b.depth[y * w + x]);
            match (za.is_finite(), zb.is_finite()) {
                (true, true) => rel.push(((za as f64 - zb as f64).abs() / (zb as f64).max(1e-30), silhouette(x, y))),
                (false, false) => {}
                _ => {
                    out.mismatched += 1;
                    if !silhouette(x, y) {
                        out.mismatched_off_silhouette += 1;
                    }
                }
            }
        }
    }
    out.both_hit = rel.len();
    let mut all: Vec<f64> = rel.iter().map(|r| r.0).collect();
    all.sort_by(f64::total_cmp);
    if !all.is_empty() {
        out.median_rel = all[all.len() / 2];
        out.p999_rel = all[((all.len() as f64 * 0.999).ceil() as usize).clamp(1, all.len()) - 1];
        out.max_rel = all[all.len() - 1];
    }
    out
}
