//! The CPU terrain reference: f64 throughout, no hierarchy. A 2-D DDA walks every cell a
//! ray crosses, in order, and intersects each cell's bilinear patch exactly. It is slow
//! and simple on purpose — the truth the GPU ray-caster's depth is measured against.

use super::grid::{intersect_patch, intersect_triangles, Hit, TerrainGrid};
use super::shading::{elevation_colour, shade, LinearTexture, Shading};
use crate::render::driver::{render_bands, Cancelled};
use crate::render::{Frame, FrameStats};
use crate::scene::camera::RayGenerator;
use glam::DVec3;
use std::time::Instant;

/// The surface each cell holds: the bilinear patch (what `terrain` draws), or two
/// triangles (what a mesh renderer draws; for comparisons with VTK).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Surface {
    #[default]
    Bilinear,
    Triangles,
}

/// The first hit of the grid-space ray o + t·d for t ∈ [t0, t1], and the number of cells
/// tested.
pub fn trace(grid: &TerrainGrid, o: DVec3, d: DVec3, t0: f64, t1: f64) -> (Option<Hit>, u32) {
    trace_surface(grid, o, d, t0, t1, Surface::Bilinear)
}

pub fn trace_surface(grid: &TerrainGrid, o: DVec3, d: DVec3, t0: f64, t1: f64, surface: Surface) -> (Option<Hit>, u32) {
    let [cx, cy] = grid.cells();
    let p = o + t0 * d;
    // The starting cell; on a cell border, the one the ray goes into.
    let start = |p: f64, d: f64, n: usize| -> i64 {
        let f = p.floor();
        let i = if f == p && d < 0.0 { f - 1.0 } else { f };
        (i as i64).clamp(0, n as i64 - 1)
    };
    let mut i = start(p.x, d.x, cx);
    let mut j = start(p.y, d.y, cy);
    let step_i: i64 = if d.x > 0.0 { 1 } else { -1 };
    let step_j: i64 = if d.y > 0.0 { 1 } else { -1 };
    let exit = |cell: i64, o: f64, d: f64| -> f64 {
        if d > 0.0 {
            (cell as f64 + 1.0 - o) / d
        } else if d < 0.0 {
            (cell as f64 - o) / d
        } else {
            f64::INFINITY
        }
    };
    let mut t = t0;
    let mut cells = 0u32;
    loop {
        cells += 1;
        let tx = exit(i, o.x, d.x);
        let ty = exit(j, o.y, d.y);
        let t_next = tx.min(ty).min(t1).max(t);
        if let Some(z) = grid.patch(i as usize, j as usize) {
            let pa = o + t * d;
            let (u0, v0) = (pa.x - i as f64, pa.y - j as f64);
            let start = DVec3::new(u0, v0, pa.z);
            let found = match surface {
                Surface::Bilinear => intersect_patch(z, start, d, t_next - t),
                Surface::Triangles => intersect_triangles(z, start, d, t_next - t),
            };
            if let Some(s) = found {
                let hit =
                    Hit { t: t + s, cell: [i as usize, j as usize], u: (u0 + s * d.x).clamp(0.0, 1.0), v: (v0 + s * d.y).clamp(0.0, 1.0) };
                return (Some(hit), cells);
            }
        }
        if t_next >= t1 {
            return (None, cells);
        }
        t = t_next;
        if tx <= ty {
            i += step_i;
        } else {
            j += step_j;
        }
        if i < 0 || j < 0 || i >= cx as i64 || j >= cy as i64 {
            return (None, cells);
        }
    }
}

/// Traces a world-space ray; returns the hit and the cells tested.
pub fn trace_world(grid: &TerrainGrid, ray: &crate::scene::camera::Ray, surface: Surface) -> (Option<Hit>, u32) {
    let (o, d) = grid.ray_to_grid(ray);
    match grid.clip(o, d) {
        Some((t0, t1)) => trace_surface(grid, o, d, t0, t1, surface),
        None => (None, 0),
    }
}

/// How far a shadow ray starts above the surface, in metres: clear of the f32 rounding of
/// the GPU's heights, far below anything visible.
pub fn shadow_lift(grid: &TerrainGrid) -> f64 {
    1e-3 * grid.cell[0].max(grid.cell[1])
}

/// The shaded colour of a hit (linear RGB), with shadow rays where asked for. `ray_z` is
/// the ray's grid-space height at the hit: a ray that meets the terrain below its surface
/// came in through a side of the box or under the ground through a NoData void — the
/// solid's side is drawn as a wall of soil.
/// `ramp`: the elevation colour table (`shading::elevation_ramp`).
pub fn hit_colour(
    grid: &TerrainGrid,
    texture: Option<&LinearTexture>,
    ramp: &[[f32; 3]],
    shading: &Shading,
    hit: &Hit,
    ray_z: f64,
) -> [f64; 3] {
    let [i, j] = hit.cell;
    let z = grid.patch(i, j).expect("a hit lies on a valid patch");
    let gx = i as f64 + hit.u;
    let gy = j as f64 + hit.v;
    let surface = super::grid::bilinear(z, hit.u, hit.v);
    if surface - ray_z > wall_tolerance(grid) {
        // The solid's side where the ray enters this cell (through a side of the box, or
        // under the ground through a NoData void), facing out of the cell edge nearest the hit.
        let faces = [(hit.u, DVec3::NEG_X), (1.0 - hit.u, DVec3::X), (hit.v, DVec3::NEG_Y), (1.0 - hit.v, DVec3::Y)];
        let face = faces.iter().min_by(|a, b| a.0.total_cmp(&b.0)).unwrap().1;
        let normal = (grid.normal_to_world * face).normalize();
        return shade(WALL_COLOUR, normal, shading, &|_| true);
    }
    let span = (grid.z_hi - grid.z_lo).max(1e-9);
    let elevation = elevation_colour(ramp, (surface - grid.z_lo) / span);
    let base = match texture {
        Some(tex) => tex.base(gx, gy, elevation),
        None => elevation,
    };
    let normal = if shading.smooth { grid.smooth_world_normal(i, j, hit.u, hit.v) } else { grid.world_normal(z, hit.u, hit.v) };
    let lit = |k: usize| {
        if !shading.shadows {
            return true;
        }
        // The surface itself facing away from the light (where a smooth normal still leans
        // toward it) is in its own shadow.
        if grid.world_normal(z, hit.u, hit.v).dot(shading.lights[k].to_light) <= 0.0 {
            return false;
        }
        let o = DVec3::new(gx, gy, surface + shadow_lift(grid));
        let d = grid.world_to_grid.transform_vector3(shading.lights[k].to_light);
        match grid.clip(o, d) {
            Some((t0, t1)) => trace(grid, o, d, t0, t1).0.is_none(),
            None => true,
        }
    };
    shade(base, normal, shading, &lit)
}

/// The colour of the terrain's sides (linear RGB).
pub const WALL_COLOUR: [f64; 3] = [0.20, 0.14, 0.09];

/// How far below the surface a hit must be to count as a wall hit, in metres.
pub fn wall_tolerance(grid: &TerrainGrid) -> f64 {
    1e-3 * (grid.z_hi - grid.z_lo).max(1.0)
}

/// Renders the terrain with the reference: colour, depth (`Z`, world distance along the
/// ray) and `steps` (cells tested per ray).
pub fn render(grid: &TerrainGrid, texture: Option<&LinearTexture>, rays: &RayGenerator, shading: &Shading) -> Result<Frame, Cancelled> {
    render_surface(grid, texture, rays, shading, Surface::Bilinear)
}

/// [`render`] with a choice of surface; with triangles only the depth is exact (colour is
/// still the bilinear patch's).
pub fn render_surface(
    grid: &TerrainGrid,
    texture: Option<&LinearTexture>,
    rays: &RayGenerator,
    shading: &Shading,
    surface: Surface,
) -> Result<Frame, Cancelled> {
    let start = Instant::now();
    let (w, h) = rays.size();
    let ramp = super::shading::elevation_ramp(shading.colormap, grid.elevations(), shading.colour_range);
    let mut frame = Frame::empty(w, h);
    let mut steps = vec![0f32; w * h];
    let mut walls = vec![0f32; w * h];
    render_bands("terrain reference", w, 1, &mut frame.rgba, &mut frame.depth, &mut [&mut steps, &mut walls], |band| {
        let (y, rgba, depth) = (band.y0, band.rgba, band.depth);
        let [steps, walls] = <[&mut [f32]; 2]>::try_from(band.extra).expect("two extra planes");
        // The ray through image point (px, py): its colour (transparent black on a miss),
        // and its hit with the ray's height there.
        let cast = |px: f64, py: f64| {
            let ray = rays.ray(px, py);
            let (hit, n) = trace_world(grid, &ray, surface);
            let Some(hit) = hit else { return ([0.0; 4], None, n) };
            let (o, d) = grid.ray_to_grid(&ray);
            let ray_z = o.z + hit.t * d.z;
            let c = hit_colour(grid, texture, &ramp, shading, &hit, ray_z);
            ([c[0], c[1], c[2], 1.0], Some((hit, ray_z)), n)
        };
        // k × k rays on a stratified grid, as the GPU: colours averaged; depth, steps and
        // the wall flag from the ray through the centre.
        let k = shading.rays_per_side.max(1) as usize;
        for x in 0..w {
            let mut sum = [0.0f64; 4];
            for b in 0..k {
                for a in 0..k {
                    let (c, ..) = cast(x as f64 + (a as f64 + 0.5) / k as f64, y as f64 + (b as f64 + 0.5) / k as f64);
                    (0..4).for_each(|i| sum[i] += c[i]);
                }
            }
            rgba[x] = sum.map(|v| (v / (k * k) as f64) as f32);
            let (_, hit, n) = cast(x as f64 + 0.5, y as f64 + 0.5);
            steps[x] = n as f32;
            if let Some((hit, ray_z)) = hit {
                let z = grid.patch(hit.cell[0], hit.cell[1]).expect("a hit lies on a valid patch");
                if super::grid::bilinear(z, hit.u, hit.v) - ray_z > wall_tolerance(grid) {
                    walls[x] = 1.0;
                }
                depth[x] = hit.t as f32;
            }
        }
    })?;
    let hits = frame.depth.iter().filter(|d| d.is_finite()).count();
    frame.stats = FrameStats {
        renderer: super::REFERENCE_RENDERER.name.into(),
        seconds: start.elapsed().as_secs_f64(),
        counters: vec![
            ("rays".into(), (w * h) as f64),
            ("hits".into(), hits as f64),
            ("mean cells per ray".into(), steps.iter().map(|&s| s as f64).sum::<f64>() / (w * h) as f64),
        ],
        notes: vec![],
        nodes: vec![],
    };
    frame.extra.push(("steps".into(), steps));
    // 1 where the ray met a side of the terrain's box (a wall), not its surface.
    frame.extra.push(("wall".into(), walls));
    Ok(frame)
}
