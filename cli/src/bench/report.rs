//! What a benchmark prints, built once: lines of prose and tables, printed as aligned text
//! on stdout, and with `--markdown FILE` written as Markdown into FILE's section for that
//! benchmark, with the command, machine, date and commit it ran on. docs/benchmarks.md is
//! those sections: regenerating a section is running its command again; no figure in it is
//! typed by hand. Each benchmark declares the columns of its tables (`TABLES`), which the
//! test below holds the page to.

use anyhow::{anyhow, Result};
use std::path::{Path, PathBuf};

/// One table: its columns, as the benchmark declares them, and its rows.
pub struct Table {
    columns: &'static [&'static str],
    rows: Vec<Vec<String>>,
}

impl Table {
    pub fn new(columns: &'static [&'static str]) -> Table {
        Table { columns, rows: Vec::new() }
    }

    /// A row: one cell per column.
    pub fn row(&mut self, cells: Vec<String>) {
        assert_eq!(cells.len(), self.columns.len(), "a row of {:?} has {} cells", self.columns, cells.len());
        self.rows.push(cells);
    }

    /// Aligned text: the first column to the left, the figures to the right.
    fn text(&self) -> String {
        let width = |c: usize| self.rows.iter().map(|r| r[c].chars().count()).chain([self.columns[c].chars().count()]).max().unwrap_or(0);
        let widths: Vec<usize> = (0..self.columns.len()).map(width).collect();
        let line = |cells: Vec<&str>| {
            let padded: Vec<String> = cells
                .iter()
                .enumerate()
                .map(|(c, s)| if c == 0 { format!("{s:<w$}", w = widths[c]) } else { format!("{s:>w$}", w = widths[c]) })
                .collect();
            padded.join("  ").trim_end().to_string() + "\n"
        };
        let mut out = line(self.columns.to_vec());
        for r in &self.rows {
            out += &line(r.iter().map(String::as_str).collect());
        }
        out
    }

    fn markdown(&self) -> String {
        let escape = |s: &str| s.replace('|', "\\|");
        let mut out = format!("| {} |\n", self.columns.iter().map(|c| escape(c)).collect::<Vec<_>>().join(" | "));
        out += &format!("|{}\n", self.columns.iter().enumerate().map(|(c, _)| if c == 0 { "---|" } else { "---:|" }).collect::<String>());
        for r in &self.rows {
            out += &format!("| {} |\n", r.iter().map(|c| escape(c)).collect::<Vec<_>>().join(" | "));
        }
        out
    }
}

enum Part {
    Line(String),
    Table(Table),
    /// A plot the benchmark wrote (shown in the Markdown where it exists).
    Image(PathBuf),
}

/// A benchmark's report, in the order it is printed.
pub struct Report {
    /// The `volterra bench` subcommand (its section's name in the page).
    bench: &'static str,
    /// The columns of every table the benchmark writes (its `TABLES`).
    declared: &'static [&'static [&'static str]],
    parts: Vec<Part>,
}

impl Report {
    pub fn new(bench: &'static str, declared: &'static [&'static [&'static str]]) -> Report {
        Report { bench, declared, parts: Vec::new() }
    }

    /// A line of prose: what was measured, units, ratios.
    pub fn line(&mut self, text: impl Into<String>) {
        self.parts.push(Part::Line(text.into()));
    }

    pub fn table(&mut self, table: Table) {
        // What the page is checked against (`declared_tables`) is what is written.
        assert!(self.declared.contains(&table.columns), "bench {}: table {:?} is not in its TABLES", self.bench, table.columns);
        self.parts.push(Part::Table(table));
    }

    pub fn image(&mut self, path: &Path) {
        self.parts.push(Part::Image(path.to_path_buf()));
    }

    /// Prints the report on stdout (unless `quiet_stdout`, where the benchmark printed JSON
    /// instead), and writes its section into `markdown`.
    pub fn finish(self, quiet_stdout: bool, markdown: Option<&Path>) -> Result<()> {
        if !quiet_stdout {
            for p in &self.parts {
                match p {
                    Part::Line(l) => println!("{l}"),
                    Part::Table(t) => print!("{}", t.text()),
                    Part::Image(_) => {}
                }
            }
        }
        if let Some(page) = markdown {
            write_section(page, self.bench, &self.section(page))?;
            say!("bench {}: its section of {} written", self.bench, page.display());
        }
        Ok(())
    }

    /// The Markdown between the section's markers.
    fn section(&self, page: &Path) -> String {
        let mut out = format!("## bench {}\n\n`{}`\n\n{}\n\n", self.bench, command_line(), machine_line());
        for p in &self.parts {
            match p {
                Part::Line(l) => out += &format!("{}\n\n", l.trim()),
                Part::Table(t) => out += &format!("{}\n", t.markdown()),
                Part::Image(path) if path.is_file() => {
                    let shown = relative_to(path, page.parent().unwrap_or(Path::new(".")));
                    out += &format!("![{} plot]({})\n\n", self.bench, shown.display());
                }
                Part::Image(_) => {}
            }
        }
        out
    }
}

/// The command as run, with the program named `volterra`.
fn command_line() -> String {
    let args: Vec<String> = std::env::args().skip(1).map(|a| if a.contains(' ') { format!("'{a}'") } else { a }).collect();
    format!("volterra {}", args.join(" "))
}

/// The machine, date and build a section's figures come from.
fn machine_line() -> String {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let cpu = cpuinfo.lines().find_map(|l| l.strip_prefix("model name")).map(|l| l.trim_start_matches([' ', '\t', ':']).to_string());
    let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap_or_default();
    let kib = meminfo.lines().find_map(|l| l.strip_prefix("MemTotal:")).and_then(|l| l.split_whitespace().next()?.parse::<f64>().ok());
    let memory = kib.map(|k| format!(", {:.0} GiB memory", k / (1u64 << 20) as f64));
    // "commit abc1234 (2026-12-06)", as `--version` says it.
    let commit = option_env!("VOLTERRA_COMMIT").unwrap_or("unknown commit");
    // The dev profile is optimised (opt-level 2, dependencies 3) but keeps debug assertions.
    let build = if cfg!(debug_assertions) { "dev build (optimised, debug assertions on)" } else { "release build" };
    format!(
        "Ran on {}, {} threads{}, on {}; built from {commit}, {build}.",
        cpu.as_deref().unwrap_or("an unknown CPU"),
        rayon::current_num_threads(),
        memory.unwrap_or_default(),
        today(),
    )
}

/// Today's date (UTC), from the system clock.
fn today() -> String {
    let days = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs() / 86_400).unwrap_or(0) as i64;
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}

/// `path` as seen from `dir` (both made absolute), for a link in the page.
fn relative_to(path: &Path, dir: &Path) -> PathBuf {
    let abs = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    let (path, dir) = (abs(path), abs(dir));
    let common = path.components().zip(dir.components()).take_while(|(a, b)| a == b).count();
    let ups = dir.components().count() - common;
    std::iter::repeat_n(std::ffi::OsStr::new(".."), ups).chain(path.components().skip(common).map(|c| c.as_os_str())).collect()
}

fn markers(bench: &str) -> (String, String) {
    (
        format!("<!-- bench {bench}: begin (written by its command below with --markdown; do not edit) -->"),
        format!("<!-- bench {bench}: end -->"),
    )
}

/// Puts `body` between `bench`'s markers in `page` (after the last section where it has
/// none; a new page if there is none), written to a temporary file and renamed.
fn write_section(page: &Path, bench: &str, body: &str) -> Result<()> {
    let text = match std::fs::read_to_string(page) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => "# Benchmarks\n".to_string(),
        Err(e) => return Err(anyhow!("{}: cannot read: {e}", page.display())),
    };
    let (begin, end) = markers(bench);
    let block = format!("{begin}\n{body}{end}\n");
    let text = match (text.find(&begin), text.find(&end)) {
        (Some(b), Some(e)) if e > b => format!("{}{block}{}", &text[..b], &text[e + end.len()..].trim_start_matches('\n')),
        (None, None) => format!("{}\n{block}", text.trim_end_matches('\n').to_string() + "\n"),
        _ => return Err(anyhow!("{}: the markers of bench {bench} are broken (one without the other)", page.display())),
    };
    let tmp = page.with_extension("md.tmp");
    std::fs::write(&tmp, text).map_err(|e| anyhow!("{}: cannot write: {e}", tmp.display()))?;
    std::fs::rename(&tmp, page).map_err(|e| anyhow!("{}: cannot write: {e}", page.display()))?;
    Ok(())
}

/// Every benchmark's tables, by the name of its section: what the page is checked against.
#[cfg(test)]
fn declared_tables() -> Vec<(&'static str, &'static [&'static [&'static str]])> {
    use super::*;
    vec![
        ("formats", formats::TABLES),
        ("shear-warp", shear_warp::TABLES),
        ("clinical", clinical::TABLES),
        ("gpu-volume", gpu_volume::TABLES),
        ("terrain", terrain::TABLES),
        ("points", points::TABLES),
        ("frames", frames::TABLES),
        ("smoke", smoke::TABLES),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sections of a page: each bench's name and the header rows of its tables.
    fn page_sections(text: &str) -> Vec<(String, Vec<Vec<String>>)> {
        let mut out = Vec::new();
        for (i, _) in text.match_indices("<!-- bench ") {
            let name = text[i + 11..].split(':').next().unwrap().to_string();
            if !text[i..].starts_with(&format!("<!-- bench {name}: begin")) {
                continue;
            }
            let body = &text[i..i + text[i..].find(&markers(&name).1).expect("section end")];
            let lines: Vec<&str> = body.lines().collect();
            let headers = lines
                .windows(2)
                .filter(|w| w[0].starts_with('|') && w[1].starts_with("|---"))
                .map(|w| w[0].trim_matches('|').split(" | ").map(|c| c.trim().replace("\\|", "|")).collect())
                .collect();
            out.push((name, headers));
        }
        out
    }

    #[test]
    fn the_benchmarks_page_has_a_section_per_bench_with_the_columns_it_writes() {
        let page = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/benchmarks.md");
        let text = std::fs::read_to_string(&page).unwrap();
        let sections = page_sections(&text);
        let declared = declared_tables();
        for (name, tables) in &declared {
            let Some((_, headers)) = sections.iter().find(|(n, _)| n == name) else {
                panic!("docs/benchmarks.md has no section for `volterra bench {name}`")
            };
            assert!(!headers.is_empty(), "bench {name}: its section holds no table");
            for h in headers {
                assert!(
                    tables.iter().any(|t| t.iter().map(|c| c.to_string()).collect::<Vec<_>>() == *h),
                    "bench {name}: the page's table {h:?} is none the bench writes now ({tables:?}): rerun its command"
                );
            }
        }
        for (name, _) in &sections {
            assert!(declared.iter().any(|(n, _)| n == name), "docs/benchmarks.md: section for unknown bench {name}");
        }
    }

    #[test]
    fn a_section_is_replaced_in_place_and_a_new_one_appended() {
        let dir = tempfile::tempdir().unwrap();
        let page = dir.path().join("b.md");
        std::fs::write(&page, "# Benchmarks\n\nintro\n").unwrap();
        write_section(&page, "formats", "one\n").unwrap();
        write_section(&page, "terrain", "two\n").unwrap();
        write_section(&page, "formats", "three\n").unwrap();
        let text = std::fs::read_to_string(&page).unwrap();
        assert!(text.starts_with("# Benchmarks\n\nintro\n"));
        assert!(text.contains("three") && text.contains("two") && !text.contains("one"));
        assert!(text.find("three").unwrap() < text.find("two").unwrap(), "replaced in place: {text}");
        assert!(!dir.path().join("b.md.tmp").exists());
        let mut t = Table::new(&["config", "ms"]);
        t.row(vec!["a|b".into(), "1".into()]);
        let sections = page_sections(&format!("{}\n{}{}\n", markers("x").0, t.markdown(), markers("x").1));
        assert_eq!(sections, vec![("x".to_string(), vec![vec!["config".to_string(), "ms".to_string()]])]);
        assert_eq!(t.text(), "config  ms\na|b      1\n");
        assert_eq!(today().len(), 10);
    }
}
