//! Puts the commit the binary was built from into `volterra --version` (VOLTERRA_COMMIT):
//! the abbreviated hash of HEAD and its date, or "unknown commit" outside a git checkout
//! (a source tarball, a vendored copy).

use std::path::Path;
use std::process::Command;

fn main() {
    let git = |args: &[&str]| {
        Command::new("git")
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .and_then(|o| String::from_utf8(o.stdout).ok())
            .map(|s| s.trim().to_string())
            .filter(|s| !s.is_empty())
    };
    let commit = git(&["rev-parse", "--short=12", "HEAD"]);
    let date = git(&["show", "-s", "--format=%cs", "HEAD"]);
    let text = match (commit, date) {
        (Some(c), Some(d)) => format!("commit {c}, {d}"),
        (Some(c), None) => format!("commit {c}"),
        _ => "unknown commit".to_string(),
    };
    println!("cargo:rustc-env=VOLTERRA_COMMIT={text}");
    // Rebuilt when HEAD moves: a checkout changes .git/HEAD, a commit the branch's ref (or
    // packed-refs, where git packed it).
    if let Some(git_dir) = git(&["rev-parse", "--git-dir"]) {
        let git_dir = Path::new(&git_dir);
        let branch = git(&["symbolic-ref", "-q", "HEAD"]);
        // Only files that exist: cargo reruns the script every build for one that does not.
        for f in [Some("HEAD"), Some("packed-refs"), branch.as_deref()].into_iter().flatten() {
            if git_dir.join(f).is_file() {
                println!("cargo:rerun-if-changed={}", git_dir.join(f).display());
            }
        }
    }
    println!("cargo:rerun-if-changed=build.rs");
}
