//! Automatic scales taken over a whole time series (issue 44). Where a particle node is a
//! series and gives no `color_range`, the points renderer colours every frame over the
//! range its array takes over every step; where smoke's medium gives no `c_ext`, every
//! frame gets the c_ext of the series' densest step (its densest column at the optical
//! depth `smoke::extinction::TARGET_DEPTH`). So a colour means one value in every frame and
//! the smoke does not brighten as it thins: the change the movie should show stays in it
//! (ParaView's "over all timesteps"). `scale_over = "step"` in the node takes each step's
//! own, as before.
//!
//! How, cheaply: one pass over the series' files the first time a frame needs it — each
//! step read once, reduced to its range and its densest column, and dropped, so the pass
//! holds one step at a time — kept in the `RenderCache` for every later frame of the
//! animation (and the viewer's time slider). A Slurm task pays the pass once for all its
//! frames.

use super::points;
use super::smoke::extinction;
use crate::scene::{NodeData, Scene};
use anyhow::{Context, Result};
use glam::{DMat3, DMat4, DVec3};

/// What the pass found over every step of one particle series.
#[derive(Debug, Clone, PartialEq)]
pub struct SeriesScale {
    pub steps: usize,
    /// The coloured array's name and its lowest and highest finite value over all steps.
    pub colour: Option<(String, [f64; 2])>,
    /// The largest densest column (Σ*) over all steps, in world units, and its step.
    pub column: Option<(f64, usize)>,
}

impl SeriesScale {
    /// The c_ext every frame gets: the densest step's densest column at the target depth.
    pub fn c_ext(&self) -> Option<f64> {
        self.column.map(|(c, _)| extinction::TARGET_DEPTH / c)
    }
}

/// Reads every step of particle node `node`'s series once: the range of the array the
/// points renderer colours by (`color_by`, as it picks it) and, where `column` is asked
/// for, the densest column of the particles placed by `node_to_world` (as smoke builds its
/// medium). Progress goes to the caller's observer.
pub fn of_particles(scene: &Scene, node: usize, color_by: Option<&str>, node_to_world: DMat4, column: bool) -> Result<SeriesScale> {
    let name = &scene.nodes()[node].name;
    let steps = scene.series(node).map_or(0, |s| s.steps.len());
    let task = super::driver::Task::begin("the series' ranges", steps as u64);
    let mut colour: Option<(String, [f64; 2])> = None;
    let mut densest: Option<(f64, usize)> = None;
    let scale = DMat3::from_mat4(node_to_world).determinant().abs().cbrt();
    for k in 0..steps {
        let NodeData::Particles(p) = scene.step_data(node, k).with_context(|| format!("node '{name}': step {} of its series", k + 1))?
        else {
            anyhow::bail!("node '{name}': step {} of its series holds no particles", k + 1);
        };
        if let Some((array, values)) = points::values(&p, color_by).with_context(|| format!("node '{name}': step {}", k + 1))? {
            if let Some((lo, hi)) = volterra_formats::finite_range(values.iter().copied()) {
                colour = Some(match colour {
                    Some((_, [a, b])) => (array, [a.min(lo), b.max(hi)]),
                    None => (array, [lo, hi]),
                });
            }
        }
        if column {
            if let (Some(mass), Some(h)) = (&p.mass, &p.smoothing_length) {
                let positions: Vec<DVec3> = p.positions.iter().map(|x| node_to_world.transform_point3(DVec3::from(*x))).collect();
                let mass: Vec<f64> = mass.iter().map(|&m| m as f64).collect();
                let h: Vec<f64> = h.iter().map(|&v| v as f64 * scale).collect();
                if let Some(c) = extinction::densest_column(&positions, &mass, &h) {
                    if densest.is_none_or(|(d, _)| c > d) {
                        densest = Some((c, k));
                    }
                }
            }
        }
        task.advance(1);
    }
    Ok(SeriesScale { steps, colour, column: densest })
}
