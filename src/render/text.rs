//! Text for pictures (the scalar bar's labels): strings set in Hack, the monospaced font
//! egui ships (through `epaint_default_fonts`, already in the build for the viewer; MIT /
//! Bitstream Vera licence), outlines read by skrifa and filled here. No system font is
//! looked for, so a PNG preview looks the same on every machine.
//!
//! Filling: the non-zero winding rule on `SUBROWS` sub-scanlines per pixel row, each
//! span's horizontal coverage exact (fractional at its ends): an anti-aliased mask.

use skrifa::instance::{LocationRef, Size};
use skrifa::outline::{DrawSettings, OutlinePen};
use skrifa::{FontRef, MetadataProvider};
use std::sync::OnceLock;

/// Sub-scanlines per pixel row (vertical anti-aliasing; horizontal coverage is exact).
const SUBROWS: usize = 8;
/// Segments each curve is flattened into (glyphs at label sizes have small curves).
const CURVE_STEPS: usize = 8;

/// A string's coverage: `alpha[y * width + x]` in [0, 1]; the baseline at row `baseline`.
#[derive(Debug, Clone)]
pub struct TextMask {
    pub width: usize,
    pub height: usize,
    pub baseline: usize,
    pub alpha: Vec<f32>,
}

fn font() -> &'static FontRef<'static> {
    static FONT: OnceLock<FontRef<'static>> = OnceLock::new();
    FONT.get_or_init(|| FontRef::new(epaint_default_fonts::HACK_REGULAR).expect("the built-in Hack font parses"))
}

/// Outline edges in pixels, y down, with the pen's current point.
#[derive(Default)]
struct Edges {
    lines: Vec<([f32; 2], [f32; 2])>,
    start: [f32; 2],
    at: [f32; 2],
    origin: [f32; 2],
}

impl Edges {
    fn point(&self, x: f32, y: f32) -> [f32; 2] {
        [self.origin[0] + x, self.origin[1] - y]
    }
    fn push(&mut self, p: [f32; 2]) {
        if p != self.at {
            self.lines.push((self.at, p));
        }
        self.at = p;
    }
}

impl OutlinePen for Edges {
    fn move_to(&mut self, x: f32, y: f32) {
        self.close();
        let p = self.point(x, y);
        (self.start, self.at) = (p, p);
    }
    fn line_to(&mut self, x: f32, y: f32) {
        let p = self.point(x, y);
        self.push(p);
    }
    fn quad_to(&mut self, cx: f32, cy: f32, x: f32, y: f32) {
        let (a, c, b) = (self.at, self.point(cx, cy), self.point(x, y));
        for k in 1..=CURVE_STEPS {
            let t = k as f32 / CURVE_STEPS as f32;
            let u = 1.0 - t;
            self.push([0, 1].map(|i| u * u * a[i] + 2.0 * u * t * c[i] + t * t * b[i]));
        }
    }
    fn curve_to(&mut self, c0x: f32, c0y: f32, c1x: f32, c1y: f32, x: f32, y: f32) {
        let (a, c0, c1, b) = (self.at, self.point(c0x, c0y), self.point(c1x, c1y), self.point(x, y));
        for k in 1..=CURVE_STEPS {
            let t = k as f32 / CURVE_STEPS as f32;
            let u = 1.0 - t;
            self.push([0, 1].map(|i| u * u * u * a[i] + 3.0 * u * u * t * c0[i] + 3.0 * u * t * t * c1[i] + t * t * t * b[i]));
        }
    }
    fn close(&mut self) {
        let s = self.start;
        self.push(s);
    }
}

/// The width in pixels of `text` set at `px` pixels per em.
pub fn width(text: &str, px: f32) -> f32 {
    let f = font();
    let (map, metrics) = (f.charmap(), f.glyph_metrics(Size::new(px), LocationRef::default()));
    text.chars().map(|c| map.map(c).and_then(|g| metrics.advance_width(g)).unwrap_or(0.0)).sum()
}

/// `text` set at `px` pixels per em, as a coverage mask (characters the font lacks are
/// left out).
pub fn render(text: &str, px: f32) -> TextMask {
    let f = font();
    let size = Size::new(px);
    let m = skrifa::metrics::Metrics::new(f, size, LocationRef::default());
    let (map, metrics, outlines) = (f.charmap(), f.glyph_metrics(size, LocationRef::default()), f.outline_glyphs());
    let baseline = m.ascent.ceil().max(1.0);
    let height = (baseline - m.descent).ceil().max(1.0) as usize;
    let mut edges = Edges::default();
    let mut x = 0.0;
    for c in text.chars() {
        let Some(g) = map.map(c) else { continue };
        if let Some(outline) = outlines.get(g) {
            edges.origin = [x, baseline];
            // A glyph that fails to draw is left out, as one the font lacks.
            let _ = outline.draw(DrawSettings::unhinted(size, LocationRef::default()), &mut edges);
            edges.close();
        }
        x += metrics.advance_width(g).unwrap_or(0.0);
    }
    let width = x.ceil().max(1.0) as usize;
    TextMask { width, height, baseline: baseline as usize, alpha: fill(&edges.lines, width, height) }
}

/// The coverage of the region the closed edges bound (non-zero winding) in a w × h grid.
pub fn fill(lines: &[([f32; 2], [f32; 2])], w: usize, h: usize) -> Vec<f32> {
    let mut alpha = vec![0.0f32; w * h];
    let mut crossings: Vec<(f32, i32)> = Vec::new();
    for row in 0..h {
        for sub in 0..SUBROWS {
            let y = row as f32 + (sub as f32 + 0.5) / SUBROWS as f32;
            crossings.clear();
            for &(a, b) in lines {
                // Half-open in y, so a vertex shared by two edges counts once.
                let (lo, hi, dir) = if a[1] < b[1] { (a, b, 1) } else { (b, a, -1) };
                if lo[1] <= y && y < hi[1] {
                    crossings.push((lo[0] + (y - lo[1]) / (hi[1] - lo[1]) * (hi[0] - lo[0]), dir));
                }
            }
            crossings.sort_by(|p, q| p.0.total_cmp(&q.0));
            let mut winding = 0;
            for k in 0..crossings.len() {
                winding += crossings[k].1;
                if winding != 0 && k + 1 < crossings.len() {
                    span(&mut alpha[row * w..(row + 1) * w], crossings[k].0, crossings[k + 1].0, 1.0 / SUBROWS as f32);
                }
            }
        }
    }
    for a in &mut alpha {
        *a = a.min(1.0);
    }
    alpha
}

/// Adds `weight` times the covered part of each pixel of `row` between x0 and x1.
fn span(row: &mut [f32], x0: f32, x1: f32, weight: f32) {
    let (x0, x1) = (x0.clamp(0.0, row.len() as f32), x1.clamp(0.0, row.len() as f32));
    if x1 <= x0 {
        return;
    }
    let (first, last) = (x0.floor() as usize, (x1.ceil() as usize).min(row.len()));
    for (i, px) in row.iter_mut().enumerate().take(last).skip(first) {
        let covered = (x1.min(i as f32 + 1.0) - x0.max(i as f32)).max(0.0);
        *px += weight * covered;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A filled polygon's coverage adds up to its area (shoelace), so the filler neither
    /// drops nor doubles spans; a hole wound the other way is left empty.
    #[test]
    fn coverage_adds_up_to_the_area() {
        let poly = |pts: &[[f32; 2]]| -> Vec<([f32; 2], [f32; 2])> { (0..pts.len()).map(|i| (pts[i], pts[(i + 1) % pts.len()])).collect() };
        let tri = poly(&[[1.3, 2.1], [17.6, 5.4], [6.2, 14.9]]);
        let area = 0.5 * ((17.6 - 1.3) * (14.9 - 2.1) - (6.2 - 1.3) * (5.4 - 2.1f32)).abs();
        let sum: f32 = fill(&tri, 20, 16).iter().sum();
        assert!((sum - area).abs() < 0.01 * area, "{sum} vs {area}");
        let mut ring = poly(&[[2.0, 2.0], [18.0, 2.0], [18.0, 14.0], [2.0, 14.0]]);
        ring.extend(poly(&[[6.0, 6.0], [6.0, 10.0], [14.0, 10.0], [14.0, 6.0]]));
        let a = fill(&ring, 20, 16);
        assert!((a.iter().sum::<f32>() - (16.0 * 12.0 - 8.0 * 4.0)).abs() < 1e-3);
        assert_eq!(a[8 * 20 + 10], 0.0, "the hole is empty");
        assert_eq!(a[3 * 20 + 3], 1.0);
    }

    /// Digits come out inked, within the advance, about a cap height tall.
    #[test]
    fn digits_are_inked() {
        let m = render("0.25", 20.0);
        assert!((m.width as f32 - width("0.25", 20.0)).abs() <= 1.0);
        let ink: f32 = m.alpha.iter().sum();
        assert!(ink > 40.0 && ink < 0.6 * (m.width * m.height) as f32, "{ink}");
        let rows: Vec<usize> = (0..m.height).filter(|&y| (0..m.width).any(|x| m.alpha[y * m.width + x] > 0.5)).collect();
        let tall = rows.last().unwrap() - rows[0] + 1;
        assert!((12..=17).contains(&tall), "digits {tall} px tall at 20 px");
        assert!(*rows.last().unwrap() < m.baseline + 1, "digits sit on the baseline");
    }
}
