//! The library's layers, checked on its source: every `crate::` path a module names points
//! to a layer below its own (ARCHITECTURE.md draws the same picture), and no renderer names
//! another. A new import that runs upward, or a renderer that reaches into another, fails here.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The library's top-level modules, lowest first; a module may name only those on lower
/// rows (and itself). The exported setting macros belong to `settings`.
const LAYERS: &[&[&str]] = &[
    &["settings", "shared_error", "geometry", "compare", "dem", "info", "samples"],
    &["colormap", "gpu"],
    &["catalog"],
    &["scene"],
    &["render"],
];

/// The renderers under src/render/: none may name another.
const RENDERERS: &[&str] = &["shear_warp", "reference_volume", "terrain", "smoke", "points", "gpu_volume"];

/// The module a `crate::` path's first name belongs to.
fn module_of(name: &str) -> &str {
    match name {
        "declare_settings" | "setting_choice" => "settings",
        m => m,
    }
}

fn rank(module: &str) -> Option<usize> {
    LAYERS.iter().position(|row| row.contains(&module_of(module)))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The code of a file without its comments (line comments and doc comments; the library
/// writes no block comments), so a path named in prose is not an import.
fn code_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().map(|(i, l)| (i + 1, l.split("//").next().unwrap_or(""))).filter(|(_, l)| !l.trim().is_empty())
}

/// Each `crate::name` a line names.
fn crate_paths(line: &str) -> Vec<String> {
    line.match_indices("crate::")
        .filter(|(i, _)| !line[..*i].ends_with('$')) // `$crate::` in a macro is the caller's crate
        .map(|(i, m)| line[i + m.len()..].chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect())
        .collect()
}

#[test]
fn imports_run_downward_only() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut upward = Vec::new();
    let mut seen = BTreeSet::new();
    for file in &files {
        let rel = file.strip_prefix(&src).unwrap();
        let own = rel.components().next().unwrap().as_os_str().to_str().unwrap().trim_end_matches(".rs").to_string();
        if own == "lib" {
            continue;
        }
        let own_rank = rank(&own).unwrap_or_else(|| panic!("src/{}: module '{own}' is in no layer of this test", rel.display()));
        let text = std::fs::read_to_string(file).unwrap();
        for (line_no, line) in code_lines(&text) {
            for target in crate_paths(line) {
                seen.insert(target.clone());
                let Some(target_rank) = rank(&target) else {
                    upward.push(format!("src/{}:{line_no}: crate::{target} is in no layer of this test", rel.display()));
                    continue;
                };
                if module_of(&target) != own && target_rank >= own_rank {
                    upward.push(format!(
                        "src/{}:{line_no}: {own} (layer {own_rank}) names crate::{target} (layer {target_rank})",
                        rel.display()
                    ));
                }
            }
        }
    }
    assert!(upward.is_empty(), "imports that do not run downward:\n{}", upward.join("\n"));
    // The check saw the layers it is about (a parser that found nothing would pass).
    for m in ["catalog", "settings", "colormap", "scene", "geometry", "gpu"] {
        assert!(seen.contains(m), "no file names crate::{m}: the scan is broken");
    }
}

#[test]
fn no_renderer_reaches_into_another() {
    let render = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/render");
    let mut reaches = Vec::new();
    for &r in RENDERERS {
        let mut files = Vec::new();
        if render.join(r).is_dir() {
            rust_files(&render.join(r), &mut files);
        } else {
            files.push(render.join(format!("{r}.rs")));
        }
        assert!(files.iter().all(|f| f.exists()), "renderer {r} not found under src/render");
        for file in &files {
            let text = std::fs::read_to_string(file).unwrap();
            for (line_no, line) in code_lines(&text) {
                for &other in RENDERERS.iter().filter(|&&o| o != r) {
                    let named = [format!("render::{other}"), format!("super::{other}"), format!("catalog::{other}")];
                    // A renderer reads its own declaration from the catalogue, not another's.
                    if named.iter().any(|n| line.contains(&format!("{n}::")) || line.contains(&format!("{n};"))) {
                        reaches.push(format!("{}:{line_no}: {r} names {other}", file.display()));
                    }
                }
            }
        }
    }
    assert!(reaches.is_empty(), "renderers that reach into another:\n{}", reaches.join("\n"));
}

#[test]
fn the_scan_sees_an_upward_import() {
    // The parser the tests above rely on, on lines that would break the layers.
    assert_eq!(crate_paths("use crate::render::registry::{self, NodeSettings};"), vec!["render"]);
    assert_eq!(crate_paths("    let _ = crate::render::terrain::gpu::gpu(); // crate::scene"), vec!["render", "scene"]);
    assert!(crate_paths("$crate::settings::SettingDecl").is_empty());
    let lines: Vec<_> = code_lines("/// crate::render in prose\nlet x = 1; // crate::render\n").collect();
    assert_eq!(lines, vec![(2, "let x = 1; ")]);
    assert!(rank("render") > rank("scene") && rank("scene") > rank("catalog") && rank("catalog") > rank("settings"));
}
