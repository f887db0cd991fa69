//! The README's gallery (docs/images) is what `volterra demo --gallery` makes today: each
//! picture is made again and compared with the committed one, so a picture cannot drift
//! from the code. After a change that alters a picture on purpose, regenerate them with
//! `cargo run --release -- demo --gallery docs/images` and commit the result.

mod common;

use common::repo_path;
use std::process::Command;
use volterra_formats::image::{decode_png, PngSamples};

/// Mean absolute difference per sample (grey levels) and the share of pixels where some
/// channel differs by more than 16 levels.
fn difference(a: &PngSamples, b: &PngSamples) -> (f64, f64) {
    let c = a.channels;
    let (mut sum, mut far) = (0u64, 0usize);
    for (p, q) in a.samples.chunks(c).zip(b.samples.chunks(c)) {
        let d: Vec<u32> = p.iter().zip(q).map(|(&x, &y)| (x as i32 - y as i32).unsigned_abs()).collect();
        sum += d.iter().map(|&v| v as u64).sum::<u64>();
        far += usize::from(d.iter().any(|&v| v > 16));
    }
    let n = (a.width * a.height) as f64;
    (sum as f64 / (c as f64 * n), far as f64 / n)
}

#[test]
fn the_gallery_pictures_are_what_the_demo_makes_today() {
    // Two of them (the terrain and the points) draw on the GPU: lavapipe where there is none.
    if common::gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(common::volterra_bin()).args(["-q", "demo", "--gallery"]).arg(dir.path()).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let committed = repo_path("docs/images");
    let mut made: Vec<String> =
        std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    made.sort();
    assert_eq!(made.len(), 6, "six pictures and nothing else (the samples' temporary directory is gone): {made:?}");
    for name in &made {
        let load = |p: &std::path::Path| decode_png(p, &Default::default(), 0).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        let (new, old) = (load(&dir.path().join(name)), load(&committed.join(name)));
        assert_eq!((new.width, new.height, new.channels), (old.width, old.height, old.channels), "{name}: size or channels changed");
        let (mean, far) = difference(&new, &old);
        // Rounding and a GPU driver's own rasterisation move a few pixels by a level or
        // two; a changed colour map, light or camera moves most of them further.
        assert!(mean <= 1.0 && far <= 0.005, "{name} drifted from docs/images: mean |Δ| {mean:.3} levels, {:.2} % of pixels off by more than 16 (regenerate: demo --gallery docs/images)", 100.0 * far);
    }
    // The README shows every picture.
    let readme = std::fs::read_to_string(repo_path("README.md")).unwrap();
    for name in &made {
        assert!(readme.contains(&format!("docs/images/{name}")), "README.md does not show {name}");
    }
}
