//! What a scene is seen from: its cameras (keyframes, orbits, walks) and the windows of
//! its large heightfields that those cameras see (`with_views`).

use super::*;

impl Scene {
    /// The camera to render: `[camera]`, or frame `k` of `n` along the keyframes (or the
    /// orbit); with `[walk]`, its eye put `eye_height` above the ground.
    pub fn camera(&self, frame: Option<(usize, usize)>) -> Result<Camera> {
        if let (Some((k, n)), true) = (frame, self.file.keyframes.is_empty() && self.file.orbit.is_none()) {
            bail!("{}: rendering frames needs [[keyframe]]s or an [orbit] in the scene (frame {k} of {n})", self.source.display());
        }
        self.camera_at(frame.map(|(k, n)| animation::AnimationFrame {
            index: k,
            count: n,
            path: if n > 1 { k as f64 / (n - 1) as f64 } else { 0.0 },
            time: None,
        }))
    }

    /// The camera of an animation frame (`[camera]` for None): along the keyframes at
    /// `frame.path`, or turned by the orbit's angle for frame `index` of `count`.
    pub fn camera_at(&self, frame: Option<animation::AnimationFrame>) -> Result<Camera> {
        let mut cam = self.file.camera.clone();
        if let Some(f) = frame {
            let keys = &self.file.keyframes;
            if !keys.is_empty() {
                cam.position = catmull_rom(&keys.iter().map(|k| k.position).collect::<Vec<_>>(), f.path);
                cam.focal_point = catmull_rom(&keys.iter().map(|k| k.focal_point).collect::<Vec<_>>(), f.path);
            }
            if let Some(o) = &self.file.orbit {
                let turn = glam::DQuat::from_axis_angle(DVec3::from(o.axis).normalize(), o.angle(f.index, f.count).to_radians());
                let focal = DVec3::from(cam.focal_point);
                cam.position = (focal + turn * (DVec3::from(cam.position) - focal)).to_array();
                cam.view_up = (turn * DVec3::from(cam.view_up)).to_array();
            }
        }
        if let Some(w) = &self.file.walk {
            let node = self.file.nodes.iter().position(|n| n.name == w.node).expect("checked at load");
            // The heights as the GPU ray-caster reads them: a GeoTIFF is not read whole for
            // the ground under one eye.
            let heights = self.terrain_data(node)?;
            let m = self.world_transform(node);
            let local = m.inverse().transform_point3(DVec3::new(cam.position[0], cam.position[1], 0.0));
            let ground = heights.surface_height(local.x, local.y).ok_or_else(|| {
                // The ground's rows may be those of a chunk that failed to decode.
                if let Some(why) = heights.failure() {
                    return anyhow!("{}: walk: the ground under the eye could not be read: {why}", self.source.display());
                }
                anyhow!(
                    "{}: walk: the eye at ({:.1}, {:.1}) is not over the terrain of node '{}' (outside it, or over NoData)",
                    self.source.display(),
                    cam.position[0],
                    cam.position[1],
                    w.node
                )
            })?;
            let z = m.transform_point3(DVec3::new(local.x, local.y, ground)).z + w.eye_height;
            let lift = z - cam.position[2];
            cam.position[2] = z;
            cam.focal_point[2] += lift;
        }
        cam.validate().map_err(|m| anyhow!("{}: {m}", self.source.display()))?;
        Ok(cam)
    }

    /// The elevations at the ends of heightfield node `node`'s elevation colours: its
    /// `elevation_range` (None: the terrain's own span — for a view window the whole
    /// raster's, `terrain_span`).
    pub fn elevation_range(&self, node: usize) -> Option<[f64; 2]> {
        self.file.nodes[node].elevation_range
    }

    /// The elevations heightfield node `node`'s solid spans at least: for a view window the
    /// whole raster's range, so the terrain draws as the whole would (None: what is read).
    pub fn terrain_span(&self, node: usize) -> Option<[f64; 2]> {
        self.view_windows[node].as_ref().map(|w| w.span)
    }

    /// What is said of a heightfield node read in a view window (which samples, why).
    pub fn view_window_note(&self, node: usize) -> Option<&str> {
        self.view_windows[node].as_ref().map(|w| w.note.as_str())
    }

    /// The scene, knowing the `cameras` its renders will take (at the image's size), before
    /// any data is read: a GeoTIFF heightfield node that names no `extent` and whose full
    /// raster passes the memory limit (at what its renderer holds a sample) is then read
    /// only where the cameras see it (`view_window`), at the finest level where that fits
    /// — rather than the largest overview of the whole that fits, or a refusal where the
    /// file has none. Unchanged: a scene with a `[walk]` (its cameras stand on the ground
    /// read), and a raster in a geographic CRS (its cells are converted to metres at the
    /// latitude of what is read, so a window would not keep the whole's scale).
    pub fn with_views(mut self, cameras: &[Camera]) -> Result<Scene> {
        if self.file.walk.is_some() {
            return Ok(self);
        }
        for node in 0..self.file.nodes.len() {
            if self.data[node].get().is_some() || self.height_rows[node].get().is_some() {
                // What was read or opened stays, placed as it was.
                continue;
            }
            let window = self.view_window(node, cameras).with_context(|| format!("node '{}'", self.file.nodes[node].name))?;
            self.view_windows[node] = window.map(Arc::new);
        }
        Ok(self)
    }

    /// Node `node`'s view window for `cameras`; None where it is read as before: not a
    /// GeoTIFF heightfield drawn, an `extent` named, a PNG drape (stretched over what is
    /// read), the whole fitting, a geographic CRS, or the whole of the level that fits seen
    /// anyway.
    fn view_window(&self, node: usize, cameras: &[Camera]) -> Result<Option<view_window::ViewWindow>> {
        use volterra_formats::geotiff::{elevation_plan, GeoTiffOptions};
        let n = &self.file.nodes[node];
        if n.kind != NodeKind::Heightfield || !n.visible || n.extent.is_some() || self.renderer(node).is_none() {
            return Ok(None);
        }
        let (path, _) = self.load_plan(node)?;
        if volterra_formats::detect(&path)? != volterra_formats::FileKind::GeoTiff {
            return Ok(None);
        }
        // A PNG drape is stretched over what is read: over a window it would shrink.
        if n.texture.as_deref().is_some_and(drape::is_stretched) {
            return Ok(None);
        }
        let held_by_renderer = self.renderer(node).and_then(|r| r.heights_held);
        let held = held_by_renderer.as_ref().map(|h| h as HeldBytes);
        let whole = GeoTiffOptions::default();
        let read_whole = elevation_plan(&path, &whole, &self.limits, held).ok();
        if read_whole.as_ref().is_some_and(|p| p.level == 0) {
            return Ok(None);
        }
        // The full raster's grid: the whole's plan carries it; where nothing of the whole
        // fits, a plan holding nothing (any level "fits").
        let full = match &read_whole {
            Some(p) => p.clone(),
            None => elevation_plan(&path, &whole, &self.limits, Some(&|_| 0))?,
        };
        if full.crs.geographic {
            return Ok(None);
        }
        // Its elevation range from its coarsest level, one pass over the rows; an overview
        // averages, so its range is widened by a tenth either way.
        let coarsest = GeoTiffOptions { level: Some(full.levels - 1), ..whole };
        let Some((lo, hi)) = GeoTiffRows::open(&path, &coarsest, &self.limits, 0)?.summary().range else {
            return Ok(None);
        };
        let widen = if full.levels > 1 { 0.1 * (hi - lo) as f64 + 1.0 } else { 0.0 };
        let z = (lo as f64 - widen, hi as f64 + widen);
        let image = (self.file.image.width, self.file.image.height);
        // In the node's frame the full raster's south-west sample is the origin; a
        // projected CRS's units are metres.
        let cell = full.full_cell_size_native;
        let Some([c0, r0, c1, r1]) = view_window::visible_window(cameras, image, self.world[node], full.full_size, cell, z) else {
            return Ok(None);
        };
        // Those samples' centres, a quarter cell of slack round them.
        let [ox, oy] = full.full_origin;
        let extent = [
            ox + (c0 as f64 - 0.25) * cell[0],
            oy - (r1 as f64 + 0.25) * cell[1],
            ox + (c1 as f64 + 0.25) * cell[0],
            oy - (r0 as f64 - 0.25) * cell[1],
        ];
        let plan = elevation_plan(&path, &GeoTiffOptions { extent: Some(extent), level: None }, &self.limits, held)?;
        let [w0, v0, w1, v1] = plan.window;
        if read_whole.is_some_and(|p| p.level == plan.level) && [w0, v0, w1 + 1, v1 + 1] == [0, 0, plan.level_size[0], plan.level_size[1]] {
            // The views see the whole of the level read anyway: nothing to gain.
            return Ok(None);
        }
        // Where the window's south-west sample lies, east and north of the full raster's.
        let south_west =
            |origin: [f64; 2], scale: [f64; 2], rows: u32| DVec3::new(origin[0], origin[1] - (rows - 1) as f64 * scale[1], 0.0);
        let offset = south_west(plan.origin, plan.cell_size_native, v1 - v0 + 1) - south_west(full.full_origin, cell, full.full_size[1]);
        let level =
            if plan.level == 0 { "full raster".to_string() } else { format!("{}×{} overview", plan.level_size[0], plan.level_size[1]) };
        let note = format!(
            "read only what the views see: columns {w0}..={w1}, rows {v0}..={v1} of the {level} ({}×{} samples), the whole {}×{} raster needing more than the memory limit",
            w1 - w0 + 1,
            v1 - v0 + 1,
            full.full_size[0],
            full.full_size[1]
        );
        let span = [lo as f64, hi as f64];
        Ok(Some(view_window::ViewWindow { extent, level: plan.level, offset: offset.truncate(), span, note }))
    }
}

/// The point at s ∈ [0, 1] on a uniform Catmull-Rom spline through `points` (ends
/// repeated), so that every key is passed through at s = i / (len − 1).
fn catmull_rom(points: &[[f64; 3]], s: f64) -> [f64; 3] {
    let n = points.len();
    if n == 1 {
        return points[0];
    }
    let u = s.clamp(0.0, 1.0) * (n - 1) as f64;
    let i = (u.floor() as usize).min(n - 2);
    let f = u - i as f64;
    let p = |k: i64| DVec3::from(points[k.clamp(0, n as i64 - 1) as usize]);
    let (p0, p1, p2, p3) = (p(i as i64 - 1), p(i as i64), p(i as i64 + 1), p(i as i64 + 2));
    let v =
        0.5 * ((2.0 * p1) + (p2 - p0) * f + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * f * f + (3.0 * p1 - p0 - 3.0 * p2 + p3) * f * f * f);
    v.to_array()
}
