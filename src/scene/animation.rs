//! Animations: which frames a scene has and what each shows — the camera along its
//! `[[keyframe]]`s or `[orbit]`, and the time drawn from its series — and which of them a
//! shard of a cluster job renders. Everything a frame shows follows from its index and
//! the scene alone, so any shard, in any order, on any number of threads, renders the
//! same frame bit for bit.

use super::Scene;
use anyhow::{bail, Result};
use serde::{Deserialize, Serialize};

/// A turntable: the camera turns about `axis` through the focal point, `degrees` over the
/// animation (`[orbit]` in a scene file).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Orbit {
    /// The axis turned about (world coordinates; through the focal point).
    #[serde(default = "up")]
    pub axis: [f64; 3],
    /// The angle turned over the whole animation. A whole number of turns (360, 720, …)
    /// loops: frame k of N is at degrees · k / N, so the last frame leads back to the first;
    /// any other angle ends on it: degrees · k / (N − 1).
    #[serde(default = "turn")]
    pub degrees: f64,
    /// Frames when `--frames` gives no count and the scene has no time series.
    pub frames: Option<usize>,
}

fn up() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}
fn turn() -> f64 {
    360.0
}

impl Orbit {
    pub fn validate(&self) -> Result<(), String> {
        let len = self.axis.iter().map(|a| a * a).sum::<f64>().sqrt();
        if !(len.is_finite() && len > 0.0) {
            return Err(format!("orbit: axis {:?} must be a non-zero vector", self.axis));
        }
        if !self.degrees.is_finite() {
            return Err(format!("orbit: degrees {} must be finite", self.degrees));
        }
        if self.frames == Some(0) {
            return Err("orbit: frames must be at least 1".into());
        }
        Ok(())
    }

    /// The angle (degrees) of frame `k` of `n`.
    pub fn angle(&self, k: usize, n: usize) -> f64 {
        let looped = self.degrees != 0.0 && (self.degrees / 360.0).fract() == 0.0;
        let f = match (looped, n) {
            (_, 0 | 1) => 0.0,
            (true, _) => k as f64 / n as f64,
            (false, _) => k as f64 / (n - 1) as f64,
        };
        self.degrees * f
    }
}

/// One frame of an animation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnimationFrame {
    /// Its number (0-based) among `count`; output files are numbered by it.
    pub index: usize,
    pub count: usize,
    /// Where along the keyframes' path it lies, 0 to 1 (its share of the series' time,
    /// when the scene has one).
    pub path: f64,
    /// The series time it draws (None: the scene has no series).
    pub time: Option<f64>,
}

/// The frames of `scene`'s animation: with `count` None, one per timestep of its series
/// (their times merged when several nodes have one), or the `[orbit]`'s `frames`; with
/// `count` N, N frames evenly over the series' time (each node then draws its last step at
/// or before the frame's time) and the camera path.
pub fn frames(scene: &Scene, count: Option<usize>) -> Result<Vec<AnimationFrame>> {
    let src = scene.source.display();
    let timeline = scene.timeline();
    let moves = !scene.file.keyframes.is_empty() || scene.file.orbit.is_some();
    let fraction = |k: usize, n: usize| if n > 1 { k as f64 / (n - 1) as f64 } else { 0.0 };
    match (count, timeline.as_slice()) {
        (Some(0), _) => bail!("--frames must be at least 1"),
        (None, []) => match scene.file.orbit.as_ref().and_then(|o| o.frames) {
            Some(n) => Ok((0..n).map(|k| AnimationFrame { index: k, count: n, path: fraction(k, n), time: None }).collect()),
            None => bail!("{src}: --frames without a count needs a time series (a node whose file is a .pvd, a numbered pattern such as plume_####.vtp, or a 4-D NIfTI) or an [orbit] with frames"),
        },
        (Some(n), []) => {
            if !moves {
                bail!("{src}: --frames needs [[keyframe]]s, an [orbit] or a time series in the scene");
            }
            Ok((0..n).map(|k| AnimationFrame { index: k, count: n, path: fraction(k, n), time: None }).collect())
        }
        (None, times) => {
            let (t0, t1) = (times[0], times[times.len() - 1]);
            let n = times.len();
            Ok(times
                .iter()
                .enumerate()
                .map(|(k, &t)| AnimationFrame { index: k, count: n, path: if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 }, time: Some(t) })
                .collect())
        }
        (Some(n), times) => {
            let (t0, t1) = (times[0], times[times.len() - 1]);
            Ok((0..n)
                .map(|k| {
                    let s = fraction(k, n);
                    // The last frame lands exactly on the last step (no rounding short of it).
                    let t = if k + 1 == n && n > 1 { t1 } else { t0 + s * (t1 - t0) };
                    AnimationFrame { index: k, count: n, path: s, time: Some(t) }
                })
                .collect())
        }
    }
}

/// Which frames a task renders: those whose index i has i mod `of` = `index`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub of: usize,
}

impl Shard {
    pub const ALL: Shard = Shard { index: 0, of: 1 };

    pub fn takes(&self, frame: usize) -> bool {
        frame % self.of == self.index
    }

    /// `K/M`; `auto` from a Slurm job array (SLURM_ARRAY_TASK_ID, with
    /// SLURM_ARRAY_TASK_COUNT, or MIN and MAX); `auto/M` from a Kubernetes Indexed Job
    /// (JOB_COMPLETION_INDEX, of M completions). `env` looks a variable up.
    pub fn parse(text: &str, env: &dyn Fn(&str) -> Option<String>) -> Result<Shard, String> {
        let number = |name: &str| -> Result<Option<usize>, String> {
            match env(name) {
                None => Ok(None),
                Some(v) => v.trim().parse::<usize>().map(Some).map_err(|_| format!("{name}='{v}' is not a whole number")),
            }
        };
        let shard = if text == "auto" {
            let id = number("SLURM_ARRAY_TASK_ID")?.ok_or(
                "--shard auto: SLURM_ARRAY_TASK_ID is not set (not a Slurm job array task; for a Kubernetes Indexed Job give --shard auto/M)",
            )?;
            let min = number("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
            let count = match (number("SLURM_ARRAY_TASK_COUNT")?, number("SLURM_ARRAY_TASK_MAX")?) {
                (Some(c), _) => c,
                (None, Some(max)) if max >= min => max - min + 1,
                _ => return Err("--shard auto: neither SLURM_ARRAY_TASK_COUNT nor SLURM_ARRAY_TASK_MAX is set".into()),
            };
            if id < min {
                return Err(format!("--shard auto: SLURM_ARRAY_TASK_ID {id} is below SLURM_ARRAY_TASK_MIN {min}"));
            }
            Shard { index: id - min, of: count }
        } else if let Some(m) = text.strip_prefix("auto/") {
            let of = m.trim().parse::<usize>().map_err(|_| format!("--shard auto/M: '{m}' is not a whole number"))?;
            let index = number("JOB_COMPLETION_INDEX")?.ok_or(
                "--shard auto/M: JOB_COMPLETION_INDEX is not set (not a Kubernetes Indexed Job; in a Slurm job array give --shard auto)",
            )?;
            Shard { index, of }
        } else {
            let (k, m) = text.split_once('/').ok_or_else(|| format!("--shard '{text}': give K/M (e.g. 0/4), auto or auto/M"))?;
            let k = k.trim().parse::<usize>().map_err(|_| format!("--shard '{text}': K is not a whole number"))?;
            let m = m.trim().parse::<usize>().map_err(|_| format!("--shard '{text}': M is not a whole number"))?;
            Shard { index: k, of: m }
        };
        if shard.of == 0 || shard.index >= shard.of {
            return Err(format!("--shard: task {} of {} does not exist (K must lie in 0..M)", shard.index, shard.of));
        }
        Ok(shard)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_come_from_the_command_line_slurm_or_kubernetes() {
        let none = |_: &str| None;
        assert_eq!(Shard::parse("2/5", &none), Ok(Shard { index: 2, of: 5 }));
        assert!(Shard::parse("5/5", &none).is_err());
        assert!(Shard::parse("auto", &none).unwrap_err().contains("SLURM_ARRAY_TASK_ID"));
        let slurm = |k: &str| match k {
            "SLURM_ARRAY_TASK_ID" => Some("7".to_string()),
            "SLURM_ARRAY_TASK_MIN" => Some("5".to_string()),
            "SLURM_ARRAY_TASK_MAX" => Some("8".to_string()),
            _ => None,
        };
        assert_eq!(Shard::parse("auto", &slurm), Ok(Shard { index: 2, of: 4 }));
        let k8s = |k: &str| (k == "JOB_COMPLETION_INDEX").then(|| "3".to_string());
        assert_eq!(Shard::parse("auto/4", &k8s), Ok(Shard { index: 3, of: 4 }));
        assert!(Shard::parse("auto/3", &k8s).is_err());
        let s = Shard { index: 1, of: 3 };
        assert_eq!((0..8).filter(|&i| s.takes(i)).collect::<Vec<_>>(), vec![1, 4, 7]);
    }

    #[test]
    fn a_whole_turn_loops_and_a_partial_one_ends_on_its_angle() {
        let o = |d: f64| Orbit { axis: [0.0, 0.0, 1.0], degrees: d, frames: None };
        assert_eq!(o(360.0).angle(3, 4), 270.0);
        assert_eq!(o(90.0).angle(3, 4), 90.0);
        assert_eq!(o(90.0).angle(0, 1), 0.0);
    }
}
