//! `volterra bench formats`: load speed against the reference readers, measured side by
//! side in one run on the same files (medians of several runs; these machines are noisy).

use super::median;
use super::report::{Report, Table};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::time::Instant;
use volterra_formats::{dicom, nifti, Volume, VoxelData};

pub struct FormatsBench {
    pub env: super::BenchEnv,
    pub runs: usize,
    pub json: bool,
}

/// A 512-slice CT-like series (256×256, i16) and a 256³ i16 gzipped NIfTI, made from the
/// angiography phantom with CT-like noise (σ ≈ 12 HU) so they compress like real scans
/// (about 2.5:1) rather than like a clean phantom (50:1).
fn prepare(dir: &Path) -> Result<(PathBuf, PathBuf)> {
    let series = dir.join("series512");
    let nii = dir.join("volume256.nii.gz");
    if series.join("IMG00511.dcm").exists() && nii.exists() && dir.join("v2").exists() {
        return Ok((series, nii));
    }
    std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
    let phantom = volterra::samples::angio_phantom(256);
    let n = 256;
    let noise: Vec<i16> = {
        let mut rng = volterra::samples::SplitMix64(99);
        (0..n * n * n).map(|_| ((rng.next_f64() + rng.next_f64() + rng.next_f64() - 1.5) * 24.0) as i16).collect()
    };
    let hu = |i: usize| (phantom.data.stored(i) * 6.0 - 1000.0) as i16 + noise[i];
    let mut slices = Vec::with_capacity(n * n * 512);
    for k in 0..512 {
        let src = k / 2;
        slices.extend((0..n * n).map(|p| hu(src * n * n + p)));
    }
    let affine = [[-0.6, 0.0, 0.0, 76.5], [0.0, -0.6, 0.0, 76.5], [0.0, 0.0, 0.3, -76.5], [0.0, 0.0, 0.0, 1.0]];
    let mut vol = Volume { modality: Some("CT".into()), ..Volume::new([n, n, 512], affine, VoxelData::I16(slices)) };
    eprintln!("writing 512 DICOM files into {}", series.display());
    volterra_formats::dicom_write::write_series(&series, &vol, "1.2.826.0.1.3680043.10.1234.512", Some(42))?;
    vol.dims = [n, n, 256];
    vol.data = VoxelData::I16((0..n * n * n).map(hu).collect());
    nifti::write_nifti(&nii, &vol)?;
    std::fs::write(dir.join("v2"), b"noisy inputs")?;
    Ok((series, nii))
}

fn time_runs(runs: usize, f: impl Fn() -> Result<()>) -> Result<Vec<f64>> {
    (0..runs)
        .map(|_| {
            let t = Instant::now();
            f()?;
            Ok(t.elapsed().as_secs_f64())
        })
        .collect()
}

/// The columns of the bench's one table.
const COLUMNS: &[&str] = &["input", "volterra s", "reference s", "reference", "ratio"];
pub const TABLES: &[&[&str]] = &[COLUMNS];

/// Times volterra and the reference readers on one DICOM series and one gzipped NIfTI.
fn compare_pair(
    b: &FormatsBench,
    label: &str,
    series: &Path,
    nii: &Path,
    table: &mut Table,
    json: &mut Vec<serde_json::Value>,
) -> Result<()> {
    let opts = dicom::DicomOptions::default();
    let mut ours_dicom = time_runs(b.runs, || dicom::read_dicom(series, &opts, &b.env.limits).map(|_| ()).map_err(Into::into))?;
    let mut ours_nifti = time_runs(b.runs, || nifti::read_nifti(nii, &Default::default(), &b.env.limits).map(|_| ()).map_err(Into::into))?;
    let py = std::process::Command::new(&b.env.python)
        .arg(b.env.scripts.join("bench_readers.py"))
        .arg(series)
        .arg(nii)
        .arg(b.runs.to_string())
        .output();
    let theirs: Option<serde_json::Value> = match py {
        Ok(o) if o.status.success() => serde_json::from_slice(&o.stdout).ok(),
        Ok(o) => {
            eprintln!("reference timing failed: {}", crate::child::last_line(&o.stderr));
            None
        }
        Err(e) => {
            eprintln!("reference timing skipped: cannot run {}: {e} (run `python3 tests/setup_venv.py`)", b.env.python.display());
            None
        }
    };
    let count = std::fs::read_dir(series).map(|d| d.count()).unwrap_or(0);
    let rows = [
        (format!("{label}: DICOM series, {count} files"), &mut ours_dicom, "pydicom"),
        (format!("{label}: {}", nii.file_name().unwrap_or_default().to_string_lossy()), &mut ours_nifti, "nibabel"),
    ];
    for (name, ours, key) in rows {
        let m = median(ours);
        let theirs_s = theirs.as_ref().and_then(|t| t[key].as_array()).map(|v| {
            let mut r: Vec<f64> = v.iter().filter_map(|x| x.as_f64()).collect();
            median(&mut r)
        });
        let version = theirs.as_ref().and_then(|t| t["versions"][key].as_str());
        json.push(serde_json::json!({"input": name, "volterra_s": m, "reference": key, "reference_s": theirs_s,
            "reference_version": version}));
        match theirs_s {
            Some(rm) => {
                let version = version.map(|v| format!(" {v}")).unwrap_or_default();
                table.row(vec![name, format!("{m:.3}"), format!("{rm:.3}"), format!("{key}{version}"), format!("{:.2}×", rm / m)]);
            }
            None => table.row(vec![name, format!("{m:.3}"), "-".into(), key.into(), "-".into()]),
        }
    }
    if let Some(v) = theirs.as_ref().map(|t| t["versions"].clone()) {
        eprintln!("reference versions: {v}");
    }
    Ok(())
}

pub fn run(b: &FormatsBench) -> Result<()> {
    if b.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let (series, nii) = prepare(&b.env.work_dir)?;
    let mut report = Report::new("formats", TABLES);
    report.line(format!(
        "Load time in seconds, median of {} runs, {} threads; ratio = reference / volterra.",
        b.runs,
        rayon::current_num_threads()
    ));
    let (mut table, mut json) = (Table::new(COLUMNS), Vec::new());
    compare_pair(b, "synthetic 512×256² i16", &series, &nii, &mut table, &mut json)?;
    // The real aneurism scan in ../shared/data, where present.
    let shared = b.env.scripts.join("../../../shared/data/volumes/aneurism");
    if shared.join("dicom_ct").is_dir() {
        compare_pair(b, "aneurism 256³", &shared.join("dicom_ct"), &shared.join("aneurism.nii.gz"), &mut table, &mut json)?;
    }
    report.table(table);
    if b.json {
        println!("{}", serde_json::to_string_pretty(&json)?);
    }
    report.finish(b.json, b.env.markdown.as_deref())
}
