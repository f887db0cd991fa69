//! `volterra compare`: error metrics between two EXR images, per channel and overall.

use serde::Serialize;
use volterra_formats::FloatImage;

#[derive(Debug, Clone, Serialize)]
pub struct ChannelStats {
    pub channel: String,
    pub rmse: f64,
    pub psnr_db: f64,
    pub max_abs: f64,
    /// RMSE divided by the RMS of the reference (B) channel.
    pub relative_rmse: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    pub width: usize,
    pub height: usize,
    pub channels: Vec<ChannelStats>,
    pub overall: ChannelStats,
    /// Pixels with alpha > 0 in one image and alpha == 0 in the other (needs an A channel).
    pub coverage_mismatch: usize,
}

fn stats(name: &str, a: &[f32], b: &[f32]) -> ChannelStats {
    let n = a.len().max(1) as f64;
    let mut se = 0.0;
    let mut max_abs: f64 = 0.0;
    let mut ref_sq = 0.0;
    let mut peak: f64 = 0.0;
    for (&x, &y) in a.iter().zip(b) {
        let (x, y) = (x as f64, y as f64);
        let d = x - y;
        se += d * d;
        max_abs = max_abs.max(d.abs());
        ref_sq += y * y;
        peak = peak.max(y.abs());
    }
    let rmse = (se / n).sqrt();
    // PSNR against the reference's peak (1 for images in [0, 1]).
    let peak = if peak > 0.0 { peak.max(1.0) } else { 1.0 };
    let psnr_db = if rmse > 0.0 { 20.0 * (peak / rmse).log10() } else { f64::INFINITY };
    let rms_ref = (ref_sq / n).sqrt();
    let relative_rmse = if rms_ref > 0.0 {
        rmse / rms_ref
    } else if rmse == 0.0 {
        0.0
    } else {
        f64::INFINITY
    };
    ChannelStats { channel: name.to_string(), rmse, psnr_db, max_abs, relative_rmse }
}

/// Compares the channels the two images share (A against B, B the reference). Depth-like
/// channels (Z) with infinities are compared where both are finite.
pub fn compare(a: &FloatImage, b: &FloatImage) -> anyhow::Result<Comparison> {
    if (a.width, a.height) != (b.width, b.height) {
        anyhow::bail!("sizes differ: {}×{} vs {}×{}", a.width, a.height, b.width, b.height);
    }
    let mut channels = Vec::new();
    let mut all_a = Vec::new();
    let mut all_b = Vec::new();
    for (name, va) in &a.channels {
        let Some(vb) = b.channel(name) else { continue };
        let (fa, fb): (Vec<f32>, Vec<f32>) =
            va.iter().zip(vb).filter(|(x, y)| x.is_finite() && y.is_finite()).map(|(x, y)| (*x, *y)).unzip();
        if ["R", "G", "B", "A"].contains(&name.as_str()) {
            all_a.extend_from_slice(&fa);
            all_b.extend_from_slice(&fb);
        }
        channels.push(stats(name, &fa, &fb));
    }
    if channels.is_empty() {
        anyhow::bail!("the images share no channel");
    }
    let overall = if all_a.is_empty() { channels[0].clone() } else { stats("RGBA", &all_a, &all_b) };
    let coverage_mismatch = match (a.channel("A"), b.channel("A")) {
        (Some(x), Some(y)) => x.iter().zip(y).filter(|(p, q)| (**p > 0.0) != (**q > 0.0)).count(),
        _ => 0,
    };
    Ok(Comparison { width: a.width, height: a.height, channels, overall, coverage_mismatch })
}

/// Relative RMSE of premultiplied RGBA pixels, `b` the reference (its RMS is the scale).
pub fn rgba_rel_rmse(a: &[[f32; 4]], b: &[[f32; 4]]) -> f64 {
    let (mut se, mut rs) = (0.0, 0.0);
    for (p, q) in a.iter().zip(b) {
        for k in 0..4 {
            se += ((p[k] - q[k]) as f64).powi(2);
            rs += (q[k] as f64).powi(2);
        }
    }
    (se / rs.max(1e-300)).sqrt()
}

/// PSNR in dB of premultiplied RGBA pixels against `b`, with peak 1 (colours and opacity
/// are in [0, 1]).
pub fn rgba_psnr(a: &[[f32; 4]], b: &[[f32; 4]]) -> f64 {
    let se: f64 = a.iter().zip(b).map(|(p, q)| (0..4).map(|k| ((p[k] - q[k]) as f64).powi(2)).sum::<f64>()).sum();
    let mse = se / (4 * a.len().max(1)) as f64;
    -10.0 * mse.max(1e-30).log10()
}

/// An image's R, G, B, A channels as pixels (missing channels read as 0).
pub fn rgba_pixels(img: &FloatImage) -> Vec<[f32; 4]> {
    let n = img.width * img.height;
    let zero = vec![0.0; n];
    let ch: Vec<&[f32]> = ["R", "G", "B", "A"].iter().map(|c| img.channel(c).unwrap_or(&zero)).collect();
    (0..n).map(|i| [ch[0][i], ch[1][i], ch[2][i], ch[3][i]]).collect()
}
