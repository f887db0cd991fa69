//! A scene in time: the nodes' series, the timeline of their steps, and the scene at
//! one time (what a frame of an animation draws), keeping what its steps share.

use super::*;

impl Scene {
    /// Node `node`'s time series, if its file names one.
    pub fn series(&self, node: usize) -> Option<&TimeSeries> {
        self.series[node].as_deref()
    }

    /// The times of every series in the scene, merged and sorted (empty: none).
    pub fn timeline(&self) -> Vec<f64> {
        let mut t: Vec<f64> = self.series.iter().flatten().flat_map(|s| s.times()).collect();
        t.sort_by(f64::total_cmp);
        t.dedup();
        t
    }

    /// The animation time this scene draws (None: a still).
    pub fn time(&self) -> Option<f64> {
        self.time
    }

    /// The step of node `node`'s series drawn now (None: the node is no series).
    pub fn step(&self, node: usize) -> Option<usize> {
        let s = self.series[node].as_ref()?;
        match self.time {
            Some(t) => Some(s.step_at(t)),
            // A still draws a 4-D NIfTI's `volume_index` (as before series), others their
            // first step.
            None => Some(if s.steps[0].volume_index.is_some() { self.file.nodes[node].volume_index.min(s.steps.len() - 1) } else { 0 }),
        }
    }

    /// This scene at animation time `t`: each series node draws its step at `t` (the
    /// last at or before it); data already read is kept for every other node and for
    /// series nodes whose step did not change. Dropping the old scene (and
    /// `RenderCache::keep_only_for` the new one) frees the steps no longer drawn, so an
    /// animation holds the step of each series it draws.
    pub fn at_time(&self, t: f64) -> Scene {
        let n = self.file.nodes.len();
        let next = Scene {
            file: self.file.clone(),
            base_dir: self.base_dir.clone(),
            source: self.source.clone(),
            world: self.world.clone(),
            renderers: self.renderers.clone(),
            data: (0..n).map(|_| OnceLock::new()).collect(),
            textures: (0..n).map(|_| OnceLock::new()).collect(),
            height_rows: (0..n).map(|_| OnceLock::new()).collect(),
            stats: (0..n).map(|_| OnceLock::new()).collect(),
            series: self.series.clone(),
            time: Some(t),
            limits: self.limits,
            view_windows: self.view_windows.clone(),
        };
        for i in 0..n {
            let same_step = self.step(i) == next.step(i);
            self.carry_over(i, &next, i, same_step, true);
        }
        next
    }

    /// Hands what node `from` has read to node `to` of `next`: its data and value statistics
    /// when `same_data`, its texture when `same_texture`.
    pub(super) fn carry_over(&self, from: usize, next: &Scene, to: usize, same_data: bool, same_texture: bool) {
        if let (true, Some(d)) = (same_data, self.data[from].get()) {
            let _ = next.data[to].set(d.clone());
        }
        if let (true, Some(r)) = (same_data, self.height_rows[from].get()) {
            let _ = next.height_rows[to].set(r.clone());
        }
        if let (true, Some(s)) = (same_data, self.stats[from].get()) {
            let _ = next.stats[to].set(s.clone());
        }
        if let (true, Some(t)) = (same_texture, self.textures[from].get()) {
            let _ = next.textures[to].set(t.clone());
        }
    }
}
