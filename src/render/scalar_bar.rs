//! The scalar bar drawn into PNG previews (and the viewer's picture) for every quantity a
//! frame shows through a colour map: the map as a vertical bar at the right edge, ticks at
//! round values with their labels, the quantity's name above. Several bars stand side by
//! side from the right. The EXR never gets one: it holds data, not a picture.
//!
//! Pictures smaller than [`MIN_WIDTH`] × [`MIN_HEIGHT`] get none (the bar would cover
//! the picture).

use super::text;
use crate::colormap::ColourScale;

pub const MIN_WIDTH: usize = 200;
pub const MIN_HEIGHT: usize = 150;

/// Round tick values in [lo, hi]: multiples of 1, 2 or 5 × 10^k, four to six of them.
pub fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) || !(hi - lo).is_finite() {
        return vec![lo];
    }
    let raw = (hi - lo) / 5.0;
    let decade = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * decade).find(|s| *s >= raw).unwrap_or(10.0 * decade);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    // The tolerance keeps a tick that rounding put a hair outside the range.
    (first..=last).map(|k| k as f64 * step).filter(|v| *v >= lo - 1e-9 * step && *v <= hi + 1e-9 * step).collect()
}

/// The labels of `ticks`, all with the digits their spacing needs (scientific notation
/// for very large or small values).
pub fn labels(ticks: &[f64]) -> Vec<String> {
    labels_like(ticks, ticks)
}

/// Labels of `values` with the digits the round ticks `like` need.
fn labels_like(values: &[f64], like: &[f64]) -> Vec<String> {
    let ticks = like;
    let step = if ticks.len() > 1 { (ticks[1] - ticks[0]).abs() } else { ticks[0].abs() };
    let big = ticks.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if big >= 1e5 || (big > 0.0 && big < 1e-3) {
        let digits = if step > 0.0 && big > 0.0 { ((big.log10().floor() - step.log10().floor()).max(0.0) as usize).min(6) } else { 0 };
        return values.iter().map(|v| format!("{v:.digits$e}")).collect();
    }
    let digits = if step > 0.0 { (-step.log10().floor()).clamp(0.0, 9.0) as usize } else { 0 };
    // Not "-0.0" for a value that rounds to zero.
    values
        .iter()
        .map(|v| format!("{:.digits$}", v))
        .map(|l| if l.trim_start_matches(['-', '0', '.']).is_empty() { l.trim_start_matches('-').to_string() } else { l })
        .collect()
}

/// Draws a bar for each scale into `rgba` (interleaved linear RGBA, w × h, row 0 at the
/// top), in white or black, whichever stands out from `background` (linear RGB).
pub fn draw(rgba: &mut [f32], w: usize, h: usize, scales: &[ColourScale], background: [f64; 3]) {
    if w < MIN_WIDTH || h < MIN_HEIGHT {
        return;
    }
    let luminance = 0.2126 * background[0] + 0.7152 * background[1] + 0.0722 * background[2];
    let ink = if luminance < 0.18 { [1.0f32; 3] } else { [0.0; 3] };
    let px = (h as f32 / 40.0).clamp(10.0, 24.0);
    let margin = px.round() as usize;
    let mut right = w.saturating_sub(margin);
    for scale in scales {
        let used = draw_one(rgba, w, h, scale, right, px, ink);
        right = right.saturating_sub(used + margin);
    }
}

/// Draws one bar with its right edge (labels included) at x = `right`; returns its width.
fn draw_one(rgba: &mut [f32], w: usize, h: usize, scale: &ColourScale, right: usize, px: f32, ink: [f32; 3]) -> usize {
    let [lo, hi] = scale.range;
    let bar_h = (0.45 * h as f32).round() as usize;
    let mut ticks = ticks(lo, hi);
    let digits_from = ticks.clone();
    // The range's ends get labels too (ParaView's range labels), where they keep clear of
    // the round ticks' labels.
    if hi > lo {
        for end in [lo, hi] {
            let clear = ticks.iter().all(|t| (t - end).abs() / (hi - lo) * bar_h as f64 > 1.2 * px as f64);
            if clear {
                ticks.push(end);
            }
        }
    }
    let labels = labels_like(&ticks, &digits_from);
    let masks: Vec<text::TextMask> = labels.iter().map(|l| text::render(l, px)).collect();
    let label_w = masks.iter().map(|m| m.width).max().unwrap_or(0);
    let (bar_w, gap, tick_len) = ((0.9 * px).round().max(6.0) as usize, (0.3 * px).round() as usize, (0.35 * px).round() as usize);
    let block = bar_w + tick_len + gap + label_w;
    if block + 2 > right {
        return 0;
    }
    let x0 = right - block;
    let title = text::render(&scale.title, px);
    let top = (h - bar_h) / 2 + title.height / 2;
    let bottom = top + bar_h;
    let mut canvas = Canvas { rgba, w, h };
    let mut put = |x: usize, y: usize, c: [f32; 3], a: f32| canvas.put(x, y, c, a);
    for y in top..bottom {
        let t = 1.0 - (y - top) as f64 / (bar_h - 1).max(1) as f64;
        let c = scale.colormap.at(t);
        for x in x0..x0 + bar_w {
            put(x, y, c, 1.0);
        }
    }
    // A one-pixel frame round the bar.
    for x in x0 - 1..=x0 + bar_w {
        put(x, top - 1, ink, 1.0);
        put(x, bottom, ink, 1.0);
    }
    for y in top - 1..=bottom {
        put(x0 - 1, y, ink, 1.0);
        put(x0 + bar_w, y, ink, 1.0);
    }
    let blit = |put: &mut dyn FnMut(usize, usize, [f32; 3], f32), m: &text::TextMask, x: usize, y: usize| {
        for j in 0..m.height {
            for i in 0..m.width {
                put(x + i, y + j, ink, m.alpha[j * m.width + i]);
            }
        }
    };
    for (v, m) in ticks.iter().zip(&masks) {
        let f = if hi > lo { (v - lo) / (hi - lo) } else { 0.5 };
        let y = bottom as f64 - 0.5 - f * (bar_h - 1) as f64;
        let y = y.round() as usize;
        for x in x0 + bar_w..x0 + bar_w + tick_len {
            put(x, y, ink, 1.0);
        }
        // Digits centred on the tick: their middle is about 0.36 em above the baseline.
        let baseline = y + (0.36 * px).round() as usize;
        blit(&mut put, m, x0 + bar_w + tick_len + gap, (baseline).saturating_sub(m.baseline));
    }
    // The name, right-aligned above the bar (cut from the left when too long).
    let tx = right.saturating_sub(title.width).max(right.saturating_sub(block.max(title.width)));
    blit(&mut put, &title, tx, top.saturating_sub(title.height + (0.4 * px) as usize));
    block.max(title.width.min(right))
}

struct Canvas<'a> {
    rgba: &'a mut [f32],
    w: usize,
    h: usize,
}

impl Canvas<'_> {
    /// Blends colour c with coverage a over pixel (x, y); outside the picture: nothing.
    fn put(&mut self, x: usize, y: usize, c: [f32; 3], a: f32) {
        if x < self.w && y < self.h && a > 0.0 {
            let i = 4 * (y * self.w + x);
            for k in 0..3 {
                self.rgba[i + k] += a * (c[k] - self.rgba[i + k]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_inside() {
        assert_eq!(labels(&ticks(0.0, 1.0)), ["0.0", "0.2", "0.4", "0.6", "0.8", "1.0"]);
        assert_eq!(labels(&ticks(-3.7, 12.2)), ["0", "5", "10"]);
        assert_eq!(labels(&ticks(-1000.0, 3000.0)), ["-1000", "0", "1000", "2000", "3000"]);
        assert_eq!(labels(&ticks(0.0013, 0.0021)), ["0.0014", "0.0016", "0.0018", "0.0020"]);
        assert_eq!(labels(&ticks(2.0e6, 9.0e6)), ["2e6", "4e6", "6e6", "8e6"]);
        assert_eq!(labels(&ticks(5.0, 5.0)), ["5"]);
        for (lo, hi) in [(0.1, 0.9), (-1e-7, 3e-7), (17.0, 17.5), (1e12, 1.1e12)] {
            let t = ticks(lo, hi);
            assert!((2..=6).contains(&t.len()), "{lo}..{hi}: {t:?}");
            assert!(t.iter().all(|v| *v >= lo - 1e-9 * (hi - lo) && *v <= hi + 1e-9 * (hi - lo)));
        }
    }
}
