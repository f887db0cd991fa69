//! An interrupted `volterra render` (SIGINT, SIGTERM) leaves no partial output, no temporary
//! file, and an older output file intact.
#![cfg(unix)]

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn volterra() -> Command {
    Command::new(common::volterra_bin())
}

fn signal(pid: u32, sig: &str) {
    let ok = Command::new("kill").args(["-s", sig, &pid.to_string()]).status().unwrap().success();
    assert!(ok, "kill -s {sig} {pid}");
}

fn entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

#[test]
fn an_interrupted_render_leaves_no_partial_file_and_the_old_one_intact() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    assert!(volterra().args(["samples", d.to_str().unwrap()]).status().unwrap().success());
    let scene = d.join("angio.toml");
    let out_dir = d.join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let exr = out_dir.join("angio.exr");
    let png = out_dir.join("angio.png");
    std::fs::write(&exr, b"the older render").unwrap();
    std::fs::write(&png, b"the older preview").unwrap();
    let before = entries(&out_dir);

    // 1. SIGINT while rendering: a reference render at step 0.02 voxel takes far longer than
    //    the second we wait.
    let mut child = volterra()
        .args(["render", scene.to_str().unwrap(), "-o", exr.to_str().unwrap(), "--png", png.to_str().unwrap()])
        .args(["--set", "node.phantom.settings.step=0.02"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    signal(child.id(), "INT");
    let status = child.wait().unwrap();
    let mut err = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    assert_eq!(status.code(), Some(130), "{err}");
    assert!(err.lines().last().unwrap().starts_with("error: interrupted by SIGINT"), "{err}");
    assert_eq!(entries(&out_dir), before);
    assert_eq!(std::fs::read(&exr).unwrap(), b"the older render");

    // 2. SIGTERM while the output's temporary file exists (held open by the test hook).
    let mut child = volterra()
        .args(["render", scene.to_str().unwrap(), "-o", exr.to_str().unwrap()])
        .args(["--set", "image.width=32", "--set", "image.height=32", "--set", "node.phantom.settings.step=1.0"])
        .env("VOLTERRA_TEST_HOLD_TEMP_MS", "30000")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let temp_seen = loop {
        if entries(&out_dir).iter().any(|n| n.ends_with(".tmp")) {
            break true;
        }
        if start.elapsed() > Duration::from_secs(60) || child.try_wait().unwrap().is_some() {
            break false;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    signal(child.id(), "TERM");
    let status = child.wait().unwrap();
    let mut err = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    assert!(temp_seen, "the render never started writing: {err}");
    assert_eq!(status.code(), Some(143), "{err}");
    assert!(err.contains("interrupted by SIGTERM, 1 unfinished output(s) removed"), "{err}");
    assert_eq!(entries(&out_dir), before, "a temporary file was left behind");
    assert_eq!(std::fs::read(&exr).unwrap(), b"the older render");
    assert_eq!(std::fs::read(&png).unwrap(), b"the older preview");
}
