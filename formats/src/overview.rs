//! Overviews computed as GDAL computes them (`gdaladdo`, the COG driver): each level from
//! the next larger one (GDAL cascades its convolution resamplers), by a separable
//! convolution — every row filtered along x, then the filtered rows along y — whose taps
//! span the kernel's radius scaled by the reduction. A sample that is NoData (or whose
//! cell's alpha is 0) gives no weight; a filtered sample with no weight left, or, for a
//! kernel with negative lobes (cubic), whose valid taps do not run unbroken over half its
//! span, is NoData in turn. The values are summed in f64 and stored as f32 (bytes rounded
//! half up and clamped), as GDAL's overview code does: a COG's overviews written here equal
//! `gdal_translate -of COG`'s cell for cell (tests/users_findings.rs).
//!
//! Rows stream through: a level holds only the filtered rows its kernel spans.

use std::collections::VecDeque;

/// How an overview's samples are taken from the larger level (GDAL's `RESAMPLING`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Resampling {
    /// Keys' cubic convolution, a = −0.5 (GDAL's default for COG overviews).
    Cubic,
    /// The tent filter.
    Bilinear,
}

impl Resampling {
    /// The name GDAL's `RESAMPLING` option takes (any case).
    pub fn parse(name: &str) -> Option<Resampling> {
        match name.to_ascii_uppercase().as_str() {
            "CUBIC" => Some(Resampling::Cubic),
            "BILINEAR" => Some(Resampling::Bilinear),
            _ => None,
        }
    }

    /// The kernel's radius at a reduction of 1, in samples.
    fn radius(self) -> f64 {
        match self {
            Resampling::Cubic => 2.0,
            Resampling::Bilinear => 1.0,
        }
    }

    /// The kernel's weight at `x` samples from the centre (GDAL's GWKCubic / GWKBilinear).
    fn weight(self, x: f64) -> f64 {
        let a = x.abs();
        match self {
            Resampling::Cubic if a <= 1.0 => x * x * (1.5 * a - 2.5) + 1.0,
            Resampling::Cubic if a <= 2.0 => x * x * (-0.5 * a + 2.5) - 4.0 * a + 2.0,
            Resampling::Bilinear if a <= 1.0 => 1.0 - a,
            _ => 0.0,
        }
    }

    /// Whether the kernel has negative lobes (then a sample needs an unbroken run of
    /// valid taps over half its span: a lone valid tap under a negative lobe would
    /// otherwise be amplified without bound).
    fn has_negative_lobes(self) -> bool {
        self == Resampling::Cubic
    }
}

/// The taps of one output sample along one axis: its first input sample and the weights
/// from there on.
#[derive(Debug, Clone)]
struct Taps {
    first: usize,
    weights: Vec<f64>,
}

/// The taps of each of `n_out` samples over `n_in` (GDAL's: centred on (i + ½)·n_in/n_out,
/// the radius widened by the reduction, clipped at the edges).
fn taps(n_in: usize, n_out: usize, r: Resampling) -> Vec<Taps> {
    let ratio = n_in as f64 / n_out as f64;
    let scale = if ratio > 1.0 { 1.0 / ratio } else { 1.0 };
    let radius = r.radius() / scale;
    (0..n_out)
        .map(|i| {
            let centre = (i as f64 + 0.5) * ratio;
            let first = (centre - radius + 0.5).floor().max(0.0) as usize;
            let stop = ((centre + radius + 0.5) as usize).min(n_in);
            let weights = (first..stop.max(first)).map(|j| r.weight(scale * (j as f64 - centre + 0.5))).collect();
            Taps { first, weights }
        })
        .collect()
}

/// One filtered sample: the weighted mean of the valid samples under `taps`, `sample(k)`
/// giving the k-th tap's value and its mask (0: NoData; else a factor of its weight, as
/// GDAL weighs a sample by its mask band's value: an alpha of 128 counts half of 255);
/// None where it is NoData.
#[inline]
fn convolve(taps: &Taps, negative_lobes: bool, mut sample: impl FnMut(usize) -> (f64, f64)) -> Option<f64> {
    let (mut sum, mut weight) = (0.0f64, 0.0f64);
    let (mut run, mut longest) = (0usize, 0usize);
    for (k, w) in taps.weights.iter().enumerate() {
        let (v, mask) = sample(k);
        if mask != 0.0 {
            let w = w * mask;
            sum += v * w;
            weight += w;
            run += 1;
            longest = longest.max(run);
        } else {
            run = 0;
        }
    }
    let broken = negative_lobes && longest < taps.weights.len() / 2;
    (weight > 0.0 && !broken).then(|| sum / weight)
}

/// One overview level computed from the rows of the next larger, streamed in order.
pub struct Downsampler {
    resampling: Resampling,
    /// Samples a cell (3 or 4 for RGB(A) bytes, interleaved).
    spp: usize,
    x_taps: Vec<Taps>,
    y_taps: Vec<Taps>,
    /// Input rows filtered along x (values and validity, `spp` samples a cell), the first
    /// being input row `held_from`.
    held: VecDeque<(Vec<f64>, Vec<bool>)>,
    held_from: usize,
    rows_in: usize,
    next_out: usize,
}

impl Downsampler {
    /// A level of `out` = [width, height] cells from one of `input`.
    pub fn new(input: [usize; 2], out: [usize; 2], spp: usize, resampling: Resampling) -> Downsampler {
        Downsampler {
            resampling,
            spp,
            x_taps: taps(input[0], out[0], resampling),
            y_taps: taps(input[1], out[1], resampling),
            held: VecDeque::new(),
            held_from: 0,
            rows_in: 0,
            next_out: 0,
        }
    }

    /// Takes the next input row (its samples, and each one's mask: 0 NoData, else the
    /// factor of its weight, 1 for plain valid samples) and hands `emit(row, values,
    /// valid)` every output row it completes, in order.
    pub fn push(&mut self, values: &[f64], mask: &[f64], mut emit: impl FnMut(usize, &[f64], &[bool])) {
        let (spp, neg) = (self.spp, self.resampling.has_negative_lobes());
        let n_out = self.x_taps.len() * spp;
        let (mut fv, mut fm) = (vec![0.0; n_out], vec![false; n_out]);
        for (x, t) in self.x_taps.iter().enumerate() {
            for s in 0..spp {
                let at = |k: usize| (t.first + k) * spp + s;
                let v = convolve(t, neg, |k| (values[at(k)], mask[at(k)]));
                fv[x * spp + s] = v.unwrap_or(0.0);
                fm[x * spp + s] = v.is_some();
            }
        }
        self.held.push_back((fv, fm));
        self.rows_in += 1;
        let (mut ov, mut om) = (vec![0.0; n_out], vec![false; n_out]);
        while let Some(t) = self.y_taps.get(self.next_out) {
            if self.rows_in < t.first + t.weights.len() {
                break;
            }
            let base = t.first - self.held_from;
            for i in 0..n_out {
                let v = convolve(t, neg, |k| {
                    let (rv, rm) = &self.held[base + k];
                    (rv[i], if rm[i] { 1.0 } else { 0.0 })
                });
                ov[i] = v.unwrap_or(0.0);
                om[i] = v.is_some();
            }
            emit(self.next_out, &ov, &om);
            self.next_out += 1;
            // Rows no later output row reaches are let go.
            let keep_from = self.y_taps.get(self.next_out).map_or(self.rows_in, |t| t.first);
            while self.held_from < keep_from && !self.held.is_empty() {
                self.held.pop_front();
                self.held_from += 1;
            }
        }
    }
}

/// The overview sizes GDAL's COG driver makes (`OVERVIEWS=AUTO`): halvings (rounded
/// down, at least 1) of the full raster until one fits in a single block each way.
pub fn cog_levels([w, h]: [usize; 2], block: usize) -> Vec<[usize; 2]> {
    let mut levels = Vec::new();
    let mut k = 0;
    while (w >> k) > block || (h >> k) > block {
        k += 1;
        levels.push([(w >> k).max(1), (h >> k).max(1)]);
    }
    levels
}

#[cfg(test)]
mod tests {
    use super::*;

    fn downsample(input: &[f64], valid: &[f64], [w, h]: [usize; 2], out: [usize; 2], r: Resampling) -> Vec<Option<f64>> {
        let mut d = Downsampler::new([w, h], out, 1, r);
        let mut result = vec![None; out[0] * out[1]];
        for y in 0..h {
            d.push(&input[y * w..(y + 1) * w], &valid[y * w..(y + 1) * w], |row, v, m| {
                for x in 0..out[0] {
                    result[row * out[0] + x] = m[x].then_some(v[x]);
                }
            });
        }
        result
    }

    #[test]
    fn a_plane_is_kept_and_every_row_is_emitted() {
        // Cubic and tent weights, normalised, reproduce a linear function away from edges
        // (halving: the taps lie symmetrically about each centre).
        let (w, h) = (40, 22);
        let plane: Vec<f64> = (0..w * h).map(|i| 3.0 * (i % w) as f64 - 2.0 * (i / w) as f64 + 7.0).collect();
        for r in [Resampling::Cubic, Resampling::Bilinear] {
            let out = downsample(&plane, &vec![1.0; w * h], [w, h], [20, 11], r);
            let (rx, ry) = (w as f64 / 20.0, h as f64 / 11.0);
            for y in 3..8 {
                for x in 3..17 {
                    let (cx, cy) = ((x as f64 + 0.5) * rx - 0.5, (y as f64 + 0.5) * ry - 0.5);
                    let want = 3.0 * cx - 2.0 * cy + 7.0;
                    let got = out[y * 20 + x].expect("valid");
                    assert!((got - want).abs() < 1e-9, "{r:?} ({x},{y}): {got} vs {want}");
                }
            }
            assert!(out.iter().all(|v| v.is_some()), "every output row emitted");
        }
    }

    #[test]
    fn a_lone_valid_sample_under_a_cubic_kernel_is_nodata() {
        // Only one valid sample in the taps of the first output: with a cubic kernel its
        // taps hold no unbroken run of half their span; the tent filter takes it.
        let (w, h) = (16, 16);
        let input = vec![5.0; w * h];
        let mut valid = vec![0.0; w * h];
        valid[0] = 1.0;
        let cubic = downsample(&input, &valid, [w, h], [8, 8], Resampling::Cubic);
        assert_eq!(cubic[0], None);
        let tent = downsample(&input, &valid, [w, h], [8, 8], Resampling::Bilinear);
        assert_eq!(tent[0], Some(5.0));
        assert!(cubic.iter().chain(&tent).skip(1).all(|v| v.is_none() || *v == Some(5.0)));
    }

    #[test]
    fn cog_levels_halve_until_a_block_holds_the_level() {
        assert_eq!(cog_levels([1500, 1100], 512), vec![[750, 550], [375, 275]]);
        assert_eq!(cog_levels([1025, 513], 512), vec![[512, 256]]);
        assert_eq!(cog_levels([512, 512], 512), Vec::<[usize; 2]>::new());
        assert_eq!(cog_levels([36000, 3], 512)[6], [281, 1]);
    }
}
