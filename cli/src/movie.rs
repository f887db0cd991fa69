//! `volterra movie FRAMES -o OUT.mp4|OUT.gif`: rendered PNG frames into a movie through
//! the system's ffmpeg (a Debian package), which encodes better than any crate: H.264 in
//! MP4 (yuv420p, the form every player takes; odd sizes padded by a pixel) or a GIF with
//! a palette made from the frames. The PNGs are piped to ffmpeg in order, so any file
//! names work; the movie is written under a temporary name and renamed when complete.

use anyhow::{anyhow, bail, Context, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// `*` and `?` matching in one file name.
fn glob_match(pattern: &[u8], name: &[u8]) -> bool {
    match (pattern.first(), name.first()) {
        (None, None) => true,
        (Some(b'*'), _) => glob_match(&pattern[1..], name) || (!name.is_empty() && glob_match(pattern, &name[1..])),
        (Some(b'?'), Some(_)) => glob_match(&pattern[1..], &name[1..]),
        (Some(p), Some(n)) if p == n => glob_match(&pattern[1..], &name[1..]),
        _ => false,
    }
}

/// A name's sort key: runs of digits compared as numbers (f_9 before f_10).
fn natural_key(name: &str) -> Vec<(String, u128)> {
    let mut key = vec![];
    let mut text = String::new();
    let mut chars = name.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            let mut digits = c.to_string();
            while let Some(d) = chars.peek().filter(|d| d.is_ascii_digit()) {
                digits.push(*d);
                chars.next();
            }
            key.push((std::mem::take(&mut text), digits.parse().unwrap_or(u128::MAX)));
        } else {
            text.push(c);
        }
    }
    key.push((text, 0));
    key
}

/// The frames `pattern` names: a glob in the file name (`out/f_*.png`) or a numbered
/// pattern (`out/f_####.png`), in order.
pub fn frames(pattern: &Path) -> Result<Vec<PathBuf>> {
    let name = pattern.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    if name.contains('#') {
        let s = volterra_formats::series::discover(pattern)?.ok_or_else(|| anyhow!("{}: not a numbered pattern", pattern.display()))?;
        return Ok(s.steps.into_iter().map(|s| s.file).collect());
    }
    let dir = pattern.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot list the frames' folder", dir.display()))?
        .filter_map(|e| e.ok())
        .filter(|e| glob_match(name.as_bytes(), e.file_name().to_string_lossy().as_bytes()))
        .map(|e| e.path())
        .filter(|p| p.is_file())
        .collect();
    if found.is_empty() {
        bail!("{}: no file matches", pattern.display());
    }
    found.sort_by_cached_key(|p| natural_key(&p.file_name().unwrap_or_default().to_string_lossy()));
    Ok(found)
}

/// The frames missing from a numbered run (`f_0003.png` then `f_0007.png`), said in one
/// line; None where the numbers follow each other (or the names carry none).
pub fn numbering_gaps(frames: &[PathBuf]) -> Option<String> {
    let number = |p: &PathBuf| -> Option<u64> {
        let stem = p.file_stem()?.to_string_lossy().into_owned();
        let digits: String = stem.chars().rev().skip_while(|c| !c.is_ascii_digit()).take_while(|c| c.is_ascii_digit()).collect();
        digits.chars().rev().collect::<String>().parse().ok()
    };
    let numbers: Vec<u64> = frames.iter().map(number).collect::<Option<_>>()?;
    let mut gaps = Vec::new();
    let mut missing = 0;
    for w in numbers.windows(2) {
        if w[1] > w[0] + 1 {
            missing += w[1] - w[0] - 1;
            gaps.push(if w[1] == w[0] + 2 { format!("{}", w[0] + 1) } else { format!("{}–{}", w[0] + 1, w[1] - 1) });
        }
    }
    (missing > 0)
        .then(|| format!("{missing} frame{} missing from the numbering: {}", if missing == 1 { " is" } else { "s are" }, gaps.join(", ")))
}

/// Encodes the frames into `output` at `fps` frames per second.
pub fn run(pattern: &Path, output: &Path, fps: f64) -> Result<()> {
    if !(fps.is_finite() && fps > 0.0 && fps <= 1000.0) {
        bail!("--fps {fps} must lie in (0, 1000]");
    }
    let lower = output.to_string_lossy().to_ascii_lowercase();
    let (format, codec): (&str, Vec<&str>) = if lower.ends_with(".mp4") {
        (
            "mp4",
            vec!["-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "18", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-movflags", "+faststart"],
        )
    } else if lower.ends_with(".gif") {
        ("gif", vec!["-vf", "split[a][b];[a]palettegen=stats_mode=full[p];[b][p]paletteuse", "-loop", "0"])
    } else {
        bail!("{}: unsupported movie format (movie writes .mp4 or .gif)", output.display());
    };
    if let Some(dir) = output.parent().filter(|d| !d.as_os_str().is_empty() && !d.is_dir()) {
        bail!("{}: the output directory {} does not exist", output.display(), dir.display());
    }
    let frames = frames(pattern)?;
    if let Some(gap) = numbering_gaps(&frames) {
        eprintln!("warning: {gap}: the movie skips them (render them, with --frames and --resume, to fill the gap)");
    }
    if let Some(p) = frames.iter().find(|p| !p.to_string_lossy().to_ascii_lowercase().ends_with(".png")) {
        bail!("{}: movie takes PNG frames (render them with --png or -o f.png)", p.display());
    }
    // Every frame the first one's size: ffmpeg would otherwise stop at the first odd one.
    let size = volterra_formats::image::png_size(&frames[0])?;
    for f in &frames[1..] {
        let s = volterra_formats::image::png_size(f)?;
        if s != size {
            bail!("{}: {}×{} pixels, but {} is {}×{}", f.display(), s.0, s.1, frames[0].display(), size.0, size.1);
        }
    }
    let bar = crate::progress::bar(frames.len() as u64, "frames encoded");
    volterra_formats::atomic::write_via_temp_path(output, |tmp| {
        let mut child = Command::new("ffmpeg")
            .args(["-hide_banner", "-loglevel", "error", "-y", "-f", "image2pipe", "-c:v", "png", "-framerate"])
            .arg(format!("{fps}"))
            .args(["-i", "-"])
            .args(&codec)
            .args(["-f", format])
            .arg(tmp)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| {
                let why = match e.kind() {
                    std::io::ErrorKind::NotFound => "ffmpeg not found: install it (Debian: ffmpeg)".to_string(),
                    _ => format!("ffmpeg: {e}"),
                };
                volterra_formats::FormatError::unsupported(output, why)
            })?;
        let mut stdin = child.stdin.take().unwrap();
        let fed = frames.iter().try_for_each(|f| {
            let bytes = std::fs::read(f).map_err(|e| volterra_formats::FormatError::io(f, e))?;
            stdin.write_all(&bytes).map_err(|e| volterra_formats::FormatError::io(output, e))?;
            bar.inc(1);
            Ok::<_, volterra_formats::FormatError>(())
        });
        drop(stdin);
        let out = child.wait_with_output().map_err(|e| volterra_formats::FormatError::io(output, e))?;
        if !out.status.success() {
            let why = crate::child::first_line(&out.stderr);
            return Err(volterra_formats::FormatError::invalid(output, format!("ffmpeg failed: {why}")));
        }
        fed
    })?;
    bar.finish_and_clear();
    say!("wrote {} ({} frames, {}×{}, {fps} fps)", output.display(), frames.len(), size.0, size.1);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_in_the_numbering_are_named() {
        let names = |n: &[u32]| n.iter().map(|k| PathBuf::from(format!("out/f_{k:04}.png"))).collect::<Vec<_>>();
        assert_eq!(numbering_gaps(&names(&[0, 1, 2, 3])), None);
        assert_eq!(numbering_gaps(&names(&[0, 1, 3, 7, 8])).unwrap(), "4 frames are missing from the numbering: 2, 4–6");
        assert_eq!(numbering_gaps(&names(&[5, 7])).unwrap(), "1 frame is missing from the numbering: 6");
        assert_eq!(numbering_gaps(&[PathBuf::from("a.png"), PathBuf::from("b.png")]), None);
    }

    #[test]
    fn globs_match_file_names_and_numbers_sort_as_numbers() {
        assert!(glob_match(b"f_*.png", b"f_0001.png"));
        assert!(glob_match(b"f_?.png", b"f_1.png") && !glob_match(b"f_?.png", b"f_12.png"));
        assert!(!glob_match(b"f_*.png", b"f_1.exr"));
        let mut names = vec!["f_10.png", "f_9.png", "f_100.png"];
        names.sort_by_cached_key(|n| natural_key(n));
        assert_eq!(names, vec!["f_9.png", "f_10.png", "f_100.png"]);
    }
}
