//! Transfer-function presets (CT angiography, CT bone, MR, PET) and the value statistics
//! they and the viewer's histogram are built from.
//!
//! CT presets are in Hounsfield units, as CT readers expect: contrast-filled vessels
//! ≈ 150–500 HU, cortical bone ≈ 700–2000 HU. MR and PET values have no absolute scale,
//! so their presets follow the data's own percentiles.

use super::TransferFunction;
use volterra_formats::Volume;

/// Histogram bins the statistics keep.
pub const HISTOGRAM_BINS: usize = 256;

/// Real-world value statistics of a volume.
#[derive(Debug, Clone, PartialEq)]
pub struct ValueStats {
    pub min: f64,
    pub max: f64,
    /// Counts of values in HISTOGRAM_BINS equal bins over [min, max].
    pub histogram: Vec<u64>,
    /// Voxels counted (every voxel up to 16 M; a regular subsample beyond).
    pub counted: u64,
}

impl ValueStats {
    pub fn of(volume: &Volume) -> ValueStats {
        let (min, max) = volume.value_range().unwrap_or((0.0, 1.0));
        let n = volume.voxel_count();
        // A regular stride keeps big volumes (512³ and more) interactive to open.
        let stride = n.div_ceil(16 << 20).max(1);
        let mut histogram = vec![0u64; HISTOGRAM_BINS];
        let span = if max > min { max - min } else { 1.0 };
        let mut counted = 0;
        for i in (0..n).step_by(stride) {
            let v = volume.value(i);
            let b = (((v - min) / span) * HISTOGRAM_BINS as f64) as usize;
            histogram[b.min(HISTOGRAM_BINS - 1)] += 1;
            counted += 1;
        }
        ValueStats { min, max, histogram, counted }
    }

    /// The value below which fraction `q` (0..=1) of the counted voxels lie (bin centres).
    pub fn percentile(&self, q: f64) -> f64 {
        let target = (q.clamp(0.0, 1.0) * self.counted as f64).ceil() as u64;
        let mut acc = 0;
        for (b, &c) in self.histogram.iter().enumerate() {
            acc += c;
            if acc >= target.max(1) {
                return self.bin_value(b);
            }
        }
        self.max
    }

    /// Value at the centre of histogram bin `b`.
    pub fn bin_value(&self, b: usize) -> f64 {
        self.min + (b as f64 + 0.5) / HISTOGRAM_BINS as f64 * (self.max - self.min)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preset {
    CtAngiography,
    CtBone,
    Mr,
    Pet,
}

impl Preset {
    pub const ALL: [Preset; 4] = [Preset::CtAngiography, Preset::CtBone, Preset::Mr, Preset::Pet];

    pub fn label(self) -> &'static str {
        match self {
            Preset::CtAngiography => "CT angiography",
            Preset::CtBone => "CT bone",
            Preset::Mr => "MR",
            Preset::Pet => "PET",
        }
    }

    /// The preset that suits a volume: by its DICOM modality, else CT presets for data
    /// whose values reach below −500 (HU of air), else the percentile-based MR preset.
    pub fn for_volume(volume: &Volume, stats: &ValueStats) -> Preset {
        match volume.modality.as_deref() {
            Some("CT") => Preset::CtAngiography,
            Some("PT") | Some("NM") => Preset::Pet,
            Some("MR") => Preset::Mr,
            _ if stats.min < -500.0 => Preset::CtAngiography,
            _ => Preset::Mr,
        }
    }

    /// The transfer function; `unit_distance` (mm) is the opacity's unit distance, usually
    /// the smallest voxel spacing so that an opacity reads as "per voxel".
    pub fn transfer_function(self, stats: &ValueStats, unit_distance: f64) -> TransferFunction {
        let (lo, hi) = (stats.min, stats.max);
        // Points must increase and lie inside or at the data range's ends; clamp the fixed
        // HU points into it and drop repeats so the function stays valid on any data.
        let clamp =
            |pts: Vec<[f64; 2]>| -> Vec<[f64; 2]> { monotone(pts.into_iter().map(|[v, a]| [v.clamp(lo, hi.max(lo)), a]).collect()) };
        let clamp4 = |pts: Vec<[f64; 4]>| -> Vec<[f64; 4]> {
            let mut out: Vec<[f64; 4]> = Vec::new();
            for [v, r, g, b] in pts {
                let v = v.clamp(lo, hi.max(lo));
                if out.last().is_none_or(|l| v > l[0]) {
                    out.push([v, r, g, b]);
                }
            }
            out
        };
        let (opacity, color) = match self {
            Preset::CtAngiography => (
                clamp(vec![[lo, 0.0], [120.0, 0.0], [250.0, 0.25], [500.0, 0.6], [1200.0, 0.85], [hi, 0.9]]),
                clamp4(vec![
                    [lo, 0.5, 0.05, 0.02],
                    [120.0, 0.55, 0.08, 0.04],
                    [250.0, 0.85, 0.25, 0.15],
                    [500.0, 1.0, 0.8, 0.6],
                    [1200.0, 1.0, 1.0, 0.95],
                ]),
            ),
            Preset::CtBone => (
                clamp(vec![[lo, 0.0], [200.0, 0.0], [450.0, 0.2], [1000.0, 0.9], [hi, 1.0]]),
                clamp4(vec![[lo, 0.6, 0.45, 0.3], [200.0, 0.75, 0.6, 0.45], [700.0, 0.95, 0.9, 0.8], [1500.0, 1.0, 1.0, 1.0]]),
            ),
            Preset::Mr => {
                let (a, b) = (stats.percentile(0.60), stats.percentile(0.995));
                let b = if b > a { b } else { hi };
                (
                    monotone(vec![[lo, 0.0], [a, 0.0], [b, 0.5], [hi, 0.7]]),
                    clamp4(vec![[lo, 0.0, 0.0, 0.0], [a, 0.3, 0.3, 0.3], [b, 1.0, 1.0, 1.0]]),
                )
            }
            Preset::Pet => {
                // Uptake: transparent below the 90th percentile, hot colours up to the maximum.
                let a = stats.percentile(0.90);
                let m = |f: f64| a + f * (hi - a);
                (
                    monotone(vec![[lo, 0.0], [a, 0.0], [m(0.3), 0.15], [m(1.0), 0.8]]),
                    clamp4(vec![
                        [lo, 0.0, 0.0, 0.0],
                        [a, 0.3, 0.0, 0.0],
                        [m(0.35), 1.0, 0.2, 0.0],
                        [m(0.7), 1.0, 0.85, 0.1],
                        [m(1.0), 1.0, 1.0, 1.0],
                    ]),
                )
            }
        };
        TransferFunction { scalar_opacity: opacity, color, scalar_opacity_unit_distance: unit_distance }
    }
}

/// Keeps points whose values increase strictly (the first of equal values wins).
fn monotone(pts: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    let mut out: Vec<[f64; 2]> = Vec::new();
    for p in pts {
        if out.last().is_none_or(|l| p[0] > l[0]) {
            out.push(p);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use volterra_formats::volume::{identity_affine, VoxelData};

    fn volume(values: Vec<i16>, modality: Option<&str>) -> Volume {
        let n = values.len();
        Volume { modality: modality.map(str::to_string), ..Volume::new([n, 1, 1], identity_affine(), VoxelData::I16(values)) }
    }

    #[test]
    fn percentiles_follow_the_histogram() {
        let v = volume((0..1000).map(|i| i as i16).collect(), None);
        let s = ValueStats::of(&v);
        assert_eq!(s.counted, 1000);
        assert!((s.percentile(0.5) - 500.0).abs() < 4.0, "{}", s.percentile(0.5));
        assert!((s.percentile(0.9) - 900.0).abs() < 4.0);
    }

    #[test]
    fn every_preset_is_valid_on_any_range() {
        for (vals, modality) in [
            ((-1024..3000).step_by(7).collect::<Vec<i16>>(), Some("CT")),
            (vec![0, 0, 0, 10, 20, 255], None),
            (vec![5; 10], Some("PT")),
            (vec![-3, -2], Some("MR")),
        ] {
            let v = volume(vals, modality);
            let s = ValueStats::of(&v);
            for p in Preset::ALL {
                let tf = p.transfer_function(&s, 0.7);
                tf.validate().unwrap_or_else(|e| panic!("{p:?} on {:?}: {e}", (s.min, s.max)));
            }
        }
        let ct = volume(vec![-1024, 0, 400, 2000], Some("CT"));
        let s = ValueStats::of(&ct);
        assert_eq!(Preset::for_volume(&ct, &s), Preset::CtAngiography);
        let tf = Preset::CtAngiography.transfer_function(&s, 1.0);
        assert_eq!(tf.opacity(0.0), 0.0, "soft tissue is transparent");
        assert!(tf.opacity(400.0) > 0.3, "contrast-filled vessels are visible");
    }
}
