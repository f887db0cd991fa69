//! The documentation a newcomer follows: every relative link in README.md and docs/*.md
//! leads to a file that exists, and every `#anchor` to a heading of that file (GitHub's
//! rule: lower case, spaces to hyphens, punctuation dropped).

mod common;

use common::repo_path;
use std::path::{Path, PathBuf};

/// GitHub's anchor for a heading.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            '-' | '_' => Some(c),
            c if c.is_alphanumeric() => Some(c),
            _ => None,
        })
        .collect()
}

/// The targets of the Markdown links `[text](target)` and images `![alt](target)` in `text`.
fn links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        match after.find(')') {
            Some(j) => {
                out.push(after[..j].to_string());
                rest = &after[j..];
            }
            None => break,
        }
    }
    out
}

fn headings(path: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut in_code = false;
    let mut found = Vec::new();
    for line in text.lines() {
        if line.starts_with("```") {
            in_code = !in_code;
        } else if !in_code && line.starts_with('#') {
            found.push(anchor(line.trim_start_matches('#')));
        }
    }
    found
}

#[test]
fn every_link_in_the_readme_and_docs_leads_somewhere() {
    let mut pages: Vec<PathBuf> = vec![repo_path("README.md"), repo_path("ARCHITECTURE.md")];
    pages.extend(
        std::fs::read_dir(repo_path("docs")).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "md")),
    );
    let mut checked = 0;
    let mut broken = Vec::new();
    for page in &pages {
        let text = std::fs::read_to_string(page).unwrap();
        for target in links(&text) {
            if target.contains("://") || target.starts_with("mailto:") || target.contains(' ') {
                continue;
            }
            let (file, frag) = target.split_once('#').map_or((target.as_str(), None), |(f, a)| (f, Some(a)));
            let dest = if file.is_empty() { page.clone() } else { page.parent().unwrap().join(file) };
            checked += 1;
            if !dest.exists() {
                broken.push(format!("{}: {target} (no such file)", page.display()));
            } else if let Some(frag) = frag.filter(|_| dest.extension().is_some_and(|e| e == "md")) {
                if !headings(&dest).iter().any(|h| h == frag) {
                    broken.push(format!("{}: {target} (no such heading)", page.display()));
                }
            }
        }
    }
    assert!(checked >= 30, "only {checked} links found: the link finder is broken");
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn anchors_follow_github() {
    assert_eq!(anchor(" DEM products (`volterra dem`)"), "dem-products-volterra-dem");
    assert_eq!(anchor(" Shear-warp (volumes)"), "shear-warp-volumes");
    assert_eq!(links("see [a](x.md#b) and ![i](img.png)"), ["x.md#b", "img.png"]);
}
