//! The scalar bar in PNG previews: the colour map drawn exactly (each row the map's colour
//! at its place between the range's ends, top = high), labels and title inked in a colour
//! that stands out from the background, nothing drawn into pictures too small for one or
//! into the EXR's channels, and one bar per distinct scale when frames are composited.

use volterra::colormap::{Colormap, ColourScale};
use volterra::render::{scalar_bar, Frame};

fn frame(w: usize, h: usize) -> Frame {
    let mut f = Frame::empty(w, h);
    f.scales.push(ColourScale { title: "temperature".into(), colormap: Colormap::Viridis, range: [250.0, 400.0] });
    f
}

/// The pixels of `rgba` (interleaved) that differ from `bg`, as (x, y, colour).
fn changed(rgba: &[f32], w: usize, bg: [f32; 3]) -> Vec<(usize, usize, [f32; 3])> {
    rgba.chunks(4)
        .enumerate()
        .filter(|(_, p)| (0..3).any(|k| (p[k] - bg[k]).abs() > 1e-6))
        .map(|(i, p)| (i % w, i / w, [p[0], p[1], p[2]]))
        .collect()
}

#[test]
fn the_bar_is_the_colour_map_from_the_low_end_at_the_bottom_to_the_high_end_at_the_top() {
    let (w, h) = (480, 320);
    let bg = [0.02f32, 0.02, 0.03];
    let rgba = frame(w, h).preview_rgba(bg.map(|c| c as f64), 0.0);
    let px = changed(&rgba, w, bg);
    // The bar: the pixels whose colour is neither the background nor the (white) ink,
    // nor a blend of the two (text edges are grey: equal channels).
    let is_grey = |c: [f32; 3]| (c[0] - c[1]).abs() < 0.02 && (c[1] - c[2]).abs() < 0.03;
    let bar: Vec<_> = px.iter().filter(|p| !is_grey(p.2)).collect();
    let (x0, x1) = (bar.iter().map(|p| p.0).min().unwrap(), bar.iter().map(|p| p.0).max().unwrap());
    let (y0, y1) = (bar.iter().map(|p| p.1).min().unwrap(), bar.iter().map(|p| p.1).max().unwrap());
    assert_eq!(bar.len(), (x1 - x0 + 1) * (y1 - y0 + 1), "the bar is a filled rectangle");
    assert!(x1 > w * 3 / 4 && x1 < w - 8, "at the right edge, inside the picture: x {x0}..{x1}");
    let bar_h = y1 - y0 + 1;
    assert!((bar_h as f64 - 0.45 * h as f64).abs() <= 1.0, "{bar_h} rows");
    for p in &bar {
        let t = 1.0 - (p.1 - y0) as f64 / (bar_h - 1) as f64;
        let want = Colormap::Viridis.at(t);
        assert!((0..3).all(|k| (p.2[k] - want[k]).abs() < 1e-6), "row {}: {:?} vs {want:?}", p.1, p.2);
    }
    // White ink right of the bar (ticks and labels) and above it (the title), none left of it.
    let ink: Vec<_> = px.iter().filter(|p| is_grey(p.2)).collect();
    let labels = ink.iter().filter(|p| p.0 > x1 + 1 && p.2[0] > 0.5).count();
    assert!(labels > 60, "{labels} label pixels");
    assert!(ink.iter().filter(|p| p.1 + 2 < y0 && p.2[0] > 0.5).count() > 40, "title");
    assert!(ink.iter().all(|p| p.0 + 1 >= x0 - 60), "nothing far left of the bar but the title");
    // On a light background the ink is black.
    let light = frame(w, h).preview_rgba([0.9; 3], 0.0);
    let dark_ink = changed(&light, w, [0.9; 3]).iter().filter(|p| p.2.iter().all(|c| *c < 0.05)).count();
    assert!(dark_ink > 200, "{dark_ink} black pixels");
}

#[test]
fn small_pictures_the_exr_and_frames_without_scales_get_no_bar() {
    let bg = [0.1f32; 3];
    let small = frame(scalar_bar::MIN_WIDTH - 1, 300);
    assert!(changed(&small.preview_rgba([0.1; 3], 0.0), small.width, bg).is_empty());
    let plain = Frame::empty(400, 300);
    assert!(changed(&plain.preview_rgba([0.1; 3], 0.0), 400, bg).is_empty());
    let f = frame(400, 300);
    let exr = f.to_image([0.1; 3]);
    assert!(exr.channel("R").unwrap().iter().all(|v| *v == 0.1), "the EXR holds data, not a picture");
}

#[test]
fn composited_frames_keep_one_bar_per_distinct_scale() {
    let a = frame(400, 300);
    let mut b = frame(400, 300);
    let c = {
        let mut c = Frame::empty(400, 300);
        c.scales.push(ColourScale { title: "density".into(), colormap: Colormap::Magma, range: [0.0, 2.0] });
        c
    };
    b.stats.renderer = "points".into();
    let all = Frame::composite(400, 300, &[a, b, c]);
    assert_eq!(all.scales.len(), 2);
    let bg = [0.0f32; 3];
    let rgba = all.preview_rgba([0.0; 3], 0.0);
    // Two bars: magma's top colour and viridis's, side by side.
    let top =
        |m: Colormap| changed(&rgba, 400, bg).iter().filter(|p| (0..3).all(|k| (p.2[k] - m.at(1.0)[k]).abs() < 1e-6)).map(|p| p.0).min();
    let (v, m) = (top(Colormap::Viridis).unwrap(), top(Colormap::Magma).unwrap());
    assert!(m + 30 < v, "the second bar stands left of the first: {m} vs {v}");
}
