//! `man` and `completions`: the manual pages and shell completions, made from the same
//! command definitions as `--help`.

use crate::args::Cli;
use anyhow::{Context, Result};
use std::path::Path;
use volterra_formats::{self as formats};

/// Writes volterra.1 and a page per command and subcommand (volterra-render.1,
/// volterra-bench-clinical.1, …) into `dir`, each written whole or not at all.
pub(crate) fn cmd_man(dir: &Path) -> Result<()> {
    fn pages(cmd: clap::Command, dir: &Path, written: &mut usize) -> Result<()> {
        for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set()).cloned() {
            pages(sub, dir, written)?;
        }
        let man = clap_mangen::Man::new(cmd);
        let mut roff = Vec::new();
        man.render(&mut roff)?;
        formats::atomic::write_bytes_atomically(&dir.join(man.get_filename()), &roff)?;
        *written += 1;
        Ok(())
    }
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    let mut cmd = <Cli as clap::CommandFactory>::command().disable_help_subcommand(true);
    // Built, the subcommands carry their full names (volterra-render) for their pages.
    cmd.build();
    let mut written = 0;
    pages(cmd, dir, &mut written)?;
    say!("wrote {written} manual pages into {} (man -l {}/volterra.1)", dir.display(), dir.display());
    Ok(())
}

/// The completion script for `shell` on stdout.
pub(crate) fn completions(shell: clap_complete::Shell) {
    clap_complete::generate(shell, &mut <Cli as clap::CommandFactory>::command(), "volterra", &mut std::io::stdout());
}
