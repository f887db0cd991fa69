//! Transfer-function presets, named as 3D Slicer names them (CT-AAA, CT-Bone,
//! CT-Chest-Contrast-Enhanced, MR-Angio, MR-Default; PET-Hot and PET-Rainbow, which Slicer
//! lacks), and the value statistics they and the viewer's histogram are built from.
//!
//! CT presets are Slicer's points in Hounsfield units, as CT readers expect:
//! contrast-filled vessels ≈ 150–500 HU, cortical bone ≈ 700–2000 HU. MR and PET values
//! have no absolute scale, so their presets follow the data's own percentiles.

use super::{TransferFunction, VolumeShading};
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

/// A transfer-function preset. CT presets are 3D Slicer's (its `presets.xml`, Hounsfield
/// units, with its shading); MR presets keep the shape of Slicer's but are placed on the
/// data's own percentiles (MR values have no absolute scale: Slicer's points, in its
/// sample data's units, would show noise or nothing elsewhere); PET presets, which Slicer
/// lacks, show uptake above the 90th percentile in hot or rainbow colours.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preset {
    CtAaa,
    CtBone,
    CtChestContrastEnhanced,
    MrAngio,
    MrDefault,
    PetHot,
    PetRainbow,
}

/// Slicer's shading of its CT presets (and most others): shade on, ambient 0.1, diffuse
/// 0.9, specular 0.2, specular power 10.
const SLICER_CT_SHADING: VolumeShading = VolumeShading { shade: true, ambient: 0.1, diffuse: 0.9, specular: 0.2, specular_power: 10.0 };
/// Slicer's shading of its MR presets: shade on, ambient 0.2, diffuse 1, no specular.
const SLICER_MR_SHADING: VolumeShading = VolumeShading { shade: true, ambient: 0.2, diffuse: 1.0, specular: 0.0, specular_power: 1.0 };

/// The modalities a scene's `modality` key takes: DICOM's codes, and the names people use
/// for them (any case).
pub const MODALITIES: [(&str, &[&str]); 4] = [("CT", &[]), ("MR", &["MRI"]), ("PT", &["PET"]), ("NM", &["SPECT"])];

/// The DICOM code of a modality given by its code or its common name (`PET` → `PT`,
/// `SPECT` → `NM`), any case; None where it is neither.
pub fn modality_code(name: &str) -> Option<&'static str> {
    MODALITIES
        .iter()
        .find(|(code, names)| code.eq_ignore_ascii_case(name) || names.iter().any(|n| n.eq_ignore_ascii_case(name)))
        .map(|(code, _)| *code)
}

impl Preset {
    pub const ALL: [Preset; 7] = [
        Preset::CtAaa,
        Preset::CtBone,
        Preset::CtChestContrastEnhanced,
        Preset::MrAngio,
        Preset::MrDefault,
        Preset::PetHot,
        Preset::PetRainbow,
    ];

    /// The name a scene's `preset` key takes: 3D Slicer's where Slicer has the preset.
    pub fn name(self) -> &'static str {
        match self {
            Preset::CtAaa => "CT-AAA",
            Preset::CtBone => "CT-Bone",
            Preset::CtChestContrastEnhanced => "CT-Chest-Contrast-Enhanced",
            Preset::MrAngio => "MR-Angio",
            Preset::MrDefault => "MR-Default",
            Preset::PetHot => "PET-Hot",
            Preset::PetRainbow => "PET-Rainbow",
        }
    }

    /// The preset named `name` (case-insensitive), or an error listing the names.
    pub fn from_name(name: &str) -> Result<Preset, String> {
        Preset::ALL.into_iter().find(|p| p.name().eq_ignore_ascii_case(name)).ok_or_else(|| {
            let names: Vec<&str> = Preset::ALL.iter().map(|p| p.name()).collect();
            format!("unknown preset '{name}' (known: {})", names.join(", "))
        })
    }

    /// The shading the preset comes with (Slicer's for its presets; none for PET).
    pub fn shading(self) -> Option<VolumeShading> {
        match self {
            Preset::CtAaa | Preset::CtBone | Preset::CtChestContrastEnhanced => Some(SLICER_CT_SHADING),
            Preset::MrAngio | Preset::MrDefault => Some(SLICER_MR_SHADING),
            Preset::PetHot | Preset::PetRainbow => None,
        }
    }

    /// The preset that suits a volume: by its modality (`modality`, a scene's, else the
    /// file's), else CT presets for data whose values reach below −500 (HU of air), else
    /// the percentile-based MR preset.
    pub fn for_modality(modality: Option<&str>, stats: &ValueStats) -> Preset {
        match modality.and_then(modality_code) {
            Some("CT") => Preset::CtAaa,
            Some("PT") | Some("NM") => Preset::PetHot,
            Some("MR") => Preset::MrDefault,
            _ if stats.min < -500.0 => Preset::CtAaa,
            _ => Preset::MrDefault,
        }
    }

    /// The transfer function; `unit_distance` (mm) is the opacity's unit distance, usually
    /// the smallest voxel spacing so that an opacity reads as "per voxel" (as Slicer sets
    /// it).
    pub fn transfer_function(self, stats: &ValueStats, unit_distance: f64) -> TransferFunction {
        self.shifted(stats, unit_distance, 0.0)
    }

    /// The transfer function moved by `shift` along the value axis (Slicer's "Shift"), in
    /// the data's units.
    pub fn shifted(self, stats: &ValueStats, unit_distance: f64, shift: f64) -> TransferFunction {
        let (lo, hi) = (stats.min, stats.max);
        // Points must increase and lie inside or at the data range's ends; clamp the
        // points into it and drop repeats so the function stays valid on any data.
        let clamp = |pts: Vec<[f64; 2]>| -> Vec<[f64; 2]> {
            monotone(pts.into_iter().map(|[v, a]| [(v + shift).clamp(lo, hi.max(lo)), a]).collect())
        };
        let clamp4 = |pts: Vec<[f64; 4]>| -> Vec<[f64; 4]> {
            let mut out: Vec<[f64; 4]> = Vec::new();
            for [v, r, g, b] in pts {
                let v = (v + shift).clamp(lo, hi.max(lo));
                if out.last().is_none_or(|l| v > l[0]) {
                    out.push([v, r, g, b]);
                }
            }
            out
        };
        // Slicer's shape placed on the data: Slicer's value s0 → the data's percentile q0,
        // s1 → q1 (linear between and beyond).
        let placed = |s0: f64, q0: f64, s1: f64, q1: f64| {
            let (a, b) = (stats.percentile(q0), stats.percentile(q1));
            let b = if b > a { b } else { hi.max(a + 1e-9) };
            move |s: f64| a + (s - s0) * (b - a) / (s1 - s0)
        };
        let (opacity, color) = match self {
            Preset::CtAaa => (
                clamp(vec![
                    [-3024.0, 0.0],
                    [143.556, 0.0],
                    [166.222, 0.686275],
                    [214.389, 0.696078],
                    [419.736, 0.833333],
                    [3071.0, 0.803922],
                ]),
                clamp4(vec![
                    [-3024.0, 0.0, 0.0, 0.0],
                    [143.556, 0.615686, 0.356863, 0.184314],
                    [166.222, 0.882353, 0.603922, 0.290196],
                    [214.389, 1.0, 1.0, 1.0],
                    [419.736, 1.0, 0.937033, 0.954531],
                    [3071.0, 0.827451, 0.658824, 1.0],
                ]),
            ),
            Preset::CtBone => (
                clamp(vec![[-3024.0, 0.0], [-16.4458, 0.0], [641.385, 0.715686], [3071.0, 0.705882]]),
                clamp4(vec![
                    [-3024.0, 0.0, 0.0, 0.0],
                    [-16.4458, 0.729412, 0.254902, 0.301961],
                    [641.385, 0.905882, 0.815686, 0.552941],
                    [3071.0, 1.0, 1.0, 1.0],
                ]),
            ),
            Preset::CtChestContrastEnhanced => (
                clamp(vec![[-3024.0, 0.0], [67.0106, 0.0], [251.105, 0.446429], [439.291, 0.625], [3071.0, 0.616071]]),
                clamp4(vec![
                    [-3024.0, 0.0, 0.0, 0.0],
                    [67.0106, 0.54902, 0.25098, 0.14902],
                    [251.105, 0.882353, 0.603922, 0.290196],
                    [439.291, 1.0, 0.937033, 0.954531],
                    [3071.0, 0.827451, 0.658824, 1.0],
                ]),
            ),
            Preset::MrAngio => {
                // Flow-bright vessels are the brightest percent or so of an angiogram:
                // Slicer's ramp (151 → 201) placed from the 99th to the 99.9th percentile,
                // so the background and its noise stay clear.
                let at = placed(151.354, 0.99, 200.873, 0.999);
                (
                    clamp(vec![
                        [lo - shift, 0.0],
                        [at(151.354), 0.0],
                        [at(158.279), 0.4375],
                        [at(190.112), 0.580357],
                        [at(200.873), 0.732143],
                        [hi - shift, 0.741071],
                    ]),
                    clamp4(vec![
                        [lo - shift, 0.0, 0.0, 0.0],
                        [at(151.354), 0.0, 0.0, 0.0],
                        [at(158.279), 0.74902, 0.376471, 0.0],
                        [at(190.112), 1.0, 0.866667, 0.733333],
                        [at(200.873), 0.937255, 0.937255, 0.937255],
                        [hi - shift, 1.0, 1.0, 1.0],
                    ]),
                )
            }
            Preset::MrDefault => {
                // Slicer's first visible value (40) at the 60th percentile, its 220 at the
                // 99.5th: the head's surface, as Slicer's MR-Default shows its sample MR.
                let at = placed(40.0, 0.60, 220.0, 0.995);
                (
                    clamp(vec![
                        [lo - shift, 0.0],
                        [at(20.0), 0.0],
                        [at(40.0), 0.15],
                        [at(120.0), 0.3],
                        [at(220.0), 0.375],
                        [at(1024.0), 0.5],
                    ]),
                    clamp4(vec![
                        [lo - shift, 0.0, 0.0, 0.0],
                        [at(20.0), 0.168627, 0.0, 0.0],
                        [at(40.0), 0.403922, 0.145098, 0.0784314],
                        [at(120.0), 0.780392, 0.607843, 0.380392],
                        [at(220.0), 0.847059, 0.835294, 0.788235],
                        [at(1024.0), 1.0, 1.0, 1.0],
                    ]),
                )
            }
            Preset::PetHot | Preset::PetRainbow => {
                // Uptake: transparent below the 90th percentile, colour up to the maximum.
                let a = stats.percentile(0.90);
                let m = |f: f64| a + f * (hi - a) - shift;
                let colours = if self == Preset::PetHot {
                    vec![
                        [lo - shift, 0.0, 0.0, 0.0],
                        [m(0.0), 0.3, 0.0, 0.0],
                        [m(0.35), 1.0, 0.2, 0.0],
                        [m(0.7), 1.0, 0.85, 0.1],
                        [m(1.0), 1.0, 1.0, 1.0],
                    ]
                } else {
                    vec![
                        [lo - shift, 0.0, 0.0, 0.5],
                        [m(0.0), 0.0, 0.0, 1.0],
                        [m(0.25), 0.0, 1.0, 1.0],
                        [m(0.5), 0.0, 1.0, 0.0],
                        [m(0.75), 1.0, 1.0, 0.0],
                        [m(1.0), 1.0, 0.0, 0.0],
                    ]
                };
                (clamp(vec![[lo - shift, 0.0], [m(0.0), 0.0], [m(0.3), 0.15], [m(1.0), 0.8]]), clamp4(colours))
            }
        };
        TransferFunction { scalar_opacity: opacity, color, scalar_opacity_unit_distance: unit_distance, gradient_opacity: Vec::new() }
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
        assert_eq!(Preset::for_modality(ct.modality.as_deref(), &s), Preset::CtAaa);
        let tf = Preset::CtAaa.transfer_function(&s, 1.0);
        assert_eq!(tf.opacity(0.0), 0.0, "soft tissue is transparent");
        assert!(tf.opacity(400.0) > 0.3, "contrast-filled vessels are visible");
    }
}
