//! What every renderer returns: premultiplied linear RGBA, a depth, optional extra
//! channels, and statistics.

use super::scalar_bar;
use crate::colormap::ColourScale;
use volterra_formats::FloatImage;

#[derive(Debug, Clone, Default)]
pub struct FrameStats {
    pub renderer: String,
    pub seconds: f64,
    /// Named counters (samples taken, rays terminated early, …).
    pub counters: Vec<(String, f64)>,
    pub notes: Vec<String>,
    /// Per node drawn: its time to read data, to prepare, and to render.
    pub nodes: Vec<NodeTime>,
}

impl FrameStats {
    /// The value of the counter `name`, if the renderer reported one.
    pub fn counter(&self, name: &str) -> Option<f64> {
        self.counters.iter().find(|c| c.0 == name).map(|c| c.1)
    }
}

/// Where one node's time went, in seconds: reading its data (0 once the scene holds it),
/// preparing what its renderer keeps across frames (0 when kept from an earlier frame),
/// and rendering.
#[derive(Debug, Clone, Default)]
pub struct NodeTime {
    pub node: String,
    pub renderer: String,
    pub load: f64,
    pub prepare: f64,
    pub render: f64,
}

#[derive(Debug, Clone)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    /// Premultiplied linear RGBA over a transparent background, row 0 at the top.
    pub rgba: Vec<[f32; 4]>,
    /// Distance along the pixel's ray to what the renderer defines as the surface
    /// (for volumes: where accumulated opacity passes 0.5); +∞ where nothing.
    pub depth: Vec<f32>,
    /// Extra named channels (step counts, …).
    pub extra: Vec<(String, Vec<f32>)>,
    /// What the frame shows through colour maps: a scalar bar each in the PNG preview.
    pub scales: Vec<ColourScale>,
    pub stats: FrameStats,
}

impl Frame {
    pub fn empty(width: usize, height: usize) -> Frame {
        Frame {
            width,
            height,
            rgba: vec![[0.0; 4]; width * height],
            depth: vec![f32::INFINITY; width * height],
            extra: Vec::new(),
            scales: Vec::new(),
            stats: FrameStats::default(),
        }
    }

    /// Composites `layers` per pixel front to back by depth (premultiplied "over").
    pub fn composite(width: usize, height: usize, layers: &[Frame]) -> Frame {
        let mut out = Frame::empty(width, height);
        let mut order: Vec<usize> = (0..layers.len()).collect();
        for p in 0..width * height {
            order.sort_by(|&a, &b| layers[a].depth[p].total_cmp(&layers[b].depth[p]));
            let mut acc = [0.0f32; 4];
            for &l in &order {
                let c = layers[l].rgba[p];
                let t = 1.0 - acc[3];
                for k in 0..4 {
                    acc[k] += t * c[k];
                }
            }
            out.rgba[p] = acc;
            out.depth[p] = order.iter().map(|&l| layers[l].depth[p]).fold(f32::INFINITY, f32::min);
        }
        for l in layers {
            out.extra.extend(l.extra.iter().cloned());
            for s in &l.scales {
                if !out.scales.contains(s) {
                    out.scales.push(s.clone());
                }
            }
            out.stats.counters.extend(l.stats.counters.iter().cloned());
            out.stats.notes.extend(l.stats.notes.iter().cloned());
            out.stats.nodes.extend(l.stats.nodes.iter().cloned());
        }
        out.stats.renderer = layers.iter().map(|l| l.stats.renderer.clone()).collect::<Vec<_>>().join("+");
        out
    }

    /// The EXR image: R, G, B composited over `background`, A = coverage, Z = depth, and
    /// the extra channels.
    pub fn to_image(&self, background: [f64; 3]) -> FloatImage {
        let mut img = FloatImage::new(self.width, self.height);
        for (k, name) in ["R", "G", "B"].iter().enumerate() {
            img.add_channel(name, self.rgba.iter().map(|p| p[k] + (1.0 - p[3]) * background[k] as f32).collect());
        }
        img.add_channel("A", self.rgba.iter().map(|p| p[3]).collect());
        img.add_channel("Z", self.depth.clone());
        for (name, v) in &self.extra {
            img.add_channel(name, v.clone());
        }
        img
    }

    /// Interleaved RGBA for a PNG preview (colour over the background, alpha 1), with a
    /// scalar bar for each of the frame's colour scales. `exposure`: stops (the composited
    /// colour times 2^exposure, background included, as a camera's exposure; the bars are
    /// not scaled); the EXR stays linear and unscaled.
    pub fn preview_rgba(&self, background: [f64; 3], exposure: f64) -> Vec<f32> {
        let mut rgba = self.picture_rgba(background, exposure);
        scalar_bar::draw(&mut rgba, self.width, self.height, &self.scales, background.map(|c| c * exposure.exp2()));
        rgba
    }

    /// The preview's picture alone, without scalar bars.
    pub fn picture_rgba(&self, background: [f64; 3], exposure: f64) -> Vec<f32> {
        let k = exposure.exp2() as f32;
        self.rgba
            .iter()
            .flat_map(|p| {
                let t = 1.0 - p[3];
                [k * (p[0] + t * background[0] as f32), k * (p[1] + t * background[1] as f32), k * (p[2] + t * background[2] as f32), 1.0]
            })
            .collect()
    }
}
