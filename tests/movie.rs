//! `volterra movie`: PNG frames into MP4 and GIF through the system's ffmpeg, checked by
//! decoding the movies again with ffmpeg and ffprobe (frame count, size, rate) and
//! comparing decoded frames with the PNGs they came from.

mod common;

use std::path::Path;
use std::process::Command;

fn have(tool: &str) -> bool {
    Command::new(tool).arg("-version").output().is_ok_and(|o| o.status.success())
}

/// Frame k: a dark background with a bright square that moves right by 4 pixels a frame.
fn frame(k: usize, w: usize, h: usize) -> Vec<u8> {
    let mut data = Vec::with_capacity(w * h * 3);
    for y in 0..h {
        for x in 0..w {
            let inside = (4 * k..4 * k + 16).contains(&x) && (10..26).contains(&y);
            data.extend_from_slice(if inside { &[240, 200, 40] } else { &[20, 30, 60] });
        }
    }
    data
}

/// Frame `n` of `movie`, decoded to RGB bytes by ffmpeg.
fn decoded(movie: &Path, n: usize) -> Vec<u8> {
    let out = Command::new("ffmpeg")
        .args(["-v", "error", "-i"])
        .arg(movie)
        .args(["-vf", &format!("select=eq(n\\,{n})"), "-frames:v", "1", "-f", "rawvideo", "-pix_fmt", "rgb24", "-"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    out.stdout
}

fn probe(movie: &Path) -> String {
    let out = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-count_frames",
            "-show_entries",
            "stream=codec_name,width,height,nb_read_frames,r_frame_rate",
            "-of",
            "compact",
        ])
        .arg(movie)
        .output()
        .unwrap();
    String::from_utf8_lossy(&out.stdout).trim().to_string()
}

#[test]
fn frames_become_an_mp4_and_a_gif_that_decode_to_the_same_pictures() {
    if !(have("ffmpeg") && have("ffprobe")) {
        let why = "ffmpeg is not installed: run tests/setup-system.sh";
        assert!(!common::under_ci(), "{why}");
        eprintln!("skipped: {why}");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // An odd size: H.264 in yuv420p needs even sides, so the MP4 is padded by a pixel.
    let (w, h, n) = (61, 45, 12);
    for k in 0..n {
        let img = volterra_formats::RgbImage { width: w, height: h, data: frame(k, w, h) };
        volterra_formats::image::write_png_rgb8(&dir.path().join(format!("f_{k:04}.png")), &img).unwrap();
    }
    let bin = common::volterra_bin();
    let mp4 = dir.path().join("plume.mp4");
    let gif = dir.path().join("plume.gif");
    let glob = dir.path().join("f_*.png");
    let numbered = dir.path().join("f_####.png");
    for (frames, out) in [(&glob, &mp4), (&numbered, &gif)] {
        let r = Command::new(&bin).args(["movie", frames.to_str().unwrap(), "-o", out.to_str().unwrap(), "--fps", "12"]).output().unwrap();
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    assert_eq!(probe(&mp4), "stream|codec_name=h264|width=62|height=46|r_frame_rate=12/1|nb_read_frames=12");
    assert!(probe(&gif).starts_with("stream|codec_name=gif|width=61|height=45|"), "{}", probe(&gif));
    assert!(probe(&gif).ends_with("nb_read_frames=12"), "{}", probe(&gif));
    for k in [0, 5, 11] {
        let want = frame(k, w, h);
        // The GIF's palette holds both colours exactly.
        assert_eq!(decoded(&gif, k), want, "GIF frame {k}");
        // The MP4 (lossy, chroma at half resolution): PSNR over the picture, padding cut.
        let got = decoded(&mp4, k);
        let mut se = 0.0;
        for y in 0..h {
            for x in 0..w * 3 {
                let d = got[y * 62 * 3 + x] as f64 - want[y * w * 3 + x] as f64;
                se += d * d;
            }
        }
        let psnr = 10.0 * (255.0f64.powi(2) / (se / (w * h * 3) as f64)).log10();
        assert!(psnr > 30.0, "MP4 frame {k}: PSNR {psnr:.1} dB");
    }
    // Mistakes: one line, nothing written.
    let bad = dir.path().join("bad.mp4");
    std::fs::write(dir.path().join("f_0012.png"), b"not a png").unwrap();
    let r = Command::new(&bin).args(["movie", glob.to_str().unwrap(), "-o", bad.to_str().unwrap()]).output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("f_0012.png") && err.contains("invalid PNG"), "{err}");
    assert!(!bad.exists());
    let leftovers: Vec<_> =
        std::fs::read_dir(dir.path()).unwrap().filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().ends_with(".tmp")).collect();
    assert!(leftovers.is_empty());
}
