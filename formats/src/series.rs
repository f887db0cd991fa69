//! Time series: one data set per timestep, named as simulation and scanner output names
//! them — a ParaView collection (`.pvd`: one `<DataSet timestep=… file=…/>` per step), a
//! numbered pattern (`frames/plume_####.vtp`: every file — or DICOM folder — whose name
//! has digits where the `#`s are), or a 4-D NIfTI (its volumes are the timesteps). Finding
//! the steps reads no data: the collection's XML, a directory listing or a NIfTI header.
//! Each step is then read on its own, when it is drawn.

use crate::error::{FormatError, Result};
use quick_xml::events::Event;
use std::path::{Path, PathBuf};

/// The most steps a series may have (a NIfTI header's count is checked against it).
pub const MAX_STEPS: usize = 1_000_000;

/// One timestep: its time and where its data is.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeStep {
    /// The step's time: the collection's `timestep`, the pattern's number, or
    /// k · pixdim[4] for volume k of a 4-D NIfTI (in `TimeSeries::time_unit`).
    pub time: f64,
    pub file: PathBuf,
    /// The volume of a 4-D NIfTI this step is (None: the whole file).
    pub volume_index: Option<usize>,
}

/// The steps of a time series, in increasing time.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeSeries {
    /// What the series was named by (the pattern, the collection or the 4-D file).
    pub source: PathBuf,
    /// How the steps were found: "ParaView collection", "numbered files", "4-D NIfTI".
    pub kind: &'static str,
    /// The unit of the times, where the source says one ("s", "ms", "µs" for NIfTI).
    pub time_unit: Option<&'static str>,
    pub steps: Vec<TimeStep>,
}

impl TimeSeries {
    /// The index of the step drawn at time `t`: the last one at or before it (the first
    /// before the series starts), so a step holds until the next one begins.
    pub fn step_at(&self, t: f64) -> usize {
        self.steps.partition_point(|s| s.time <= t).saturating_sub(1)
    }
    pub fn times(&self) -> Vec<f64> {
        self.steps.iter().map(|s| s.time).collect()
    }
}

/// True when `path` names a series by its form alone (a `.pvd`, or `#`s in its file name):
/// such a path need not exist as a file.
pub fn is_series_name(path: &Path) -> bool {
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    name.ends_with(".pvd") || name.contains('#')
}

/// The series `path` names, or None when it names one data set (a 3-D NIfTI, a single
/// `.vtp`, a DICOM folder, …). Errors name the file and what is wrong: a pattern that
/// matches nothing, a collection without steps, two steps at one time.
pub fn discover(path: &Path) -> Result<Option<TimeSeries>> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let lower = name.to_ascii_lowercase();
    if name.contains('#') {
        return numbered(path, &name).map(Some);
    }
    if lower.ends_with(".pvd") {
        return collection(path).map(Some);
    }
    if (lower.ends_with(".nii") || lower.ends_with(".nii.gz")) && path.is_file() {
        // A header that cannot be read makes no series; reading the data says what is wrong
        // with it (a scene loads without reading its data, and fails only when drawn).
        let Ok(h) = crate::nifti::read_nifti_header(path) else { return Ok(None) };
        // A lying header must not make a list of a billion steps: the count is checked.
        let count = (4..=h.dim[0].clamp(0, 7) as usize).try_fold(1i64, |n, i| n.checked_mul(h.dim[i].max(1)));
        let Some(count) = count else { return Err(FormatError::invalid(path, "volume count overflows")) };
        if count > MAX_STEPS as i64 {
            return Err(FormatError::unsupported(path, format!("{count} volumes; a time series has at most {MAX_STEPS} steps")));
        }
        if count > 1 {
            let dt = if h.pixdim[4].is_finite() && h.pixdim[4] > 0.0 { h.pixdim[4] } else { 1.0 };
            let unit = match h.xyzt_units & 0x38 {
                8 => Some("s"),
                16 => Some("ms"),
                24 => Some("µs"),
                _ => None,
            };
            let steps =
                (0..count as usize).map(|k| TimeStep { time: k as f64 * dt, file: path.to_path_buf(), volume_index: Some(k) }).collect();
            return Ok(Some(TimeSeries { source: path.to_path_buf(), kind: "4-D NIfTI", time_unit: unit, steps }));
        }
    }
    Ok(None)
}

/// The files (or folders) whose names match `name`'s run of `#`s with digits: at least as
/// many digits as `#`s (zero-padded to that width; wider numbers as they are). The times
/// are the numbers.
fn numbered(path: &Path, name: &str) -> Result<TimeSeries> {
    let first = name.find('#').unwrap();
    let run = name[first..].find(|c| c != '#').map_or(name.len() - first, |n| n);
    let (prefix, suffix) = (&name[..first], &name[first + run..]);
    if suffix.contains('#') {
        return Err(FormatError::invalid(path, "a numbered pattern has one run of '#'s (e.g. plume_####.vtp)"));
    }
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let entries = std::fs::read_dir(dir).map_err(|e| FormatError::io(dir, e))?;
    let mut steps: Vec<(u64, TimeStep)> = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| FormatError::io(dir, e))?;
        let file_name = entry.file_name().to_string_lossy().into_owned();
        let Some(digits) = file_name.strip_prefix(prefix).and_then(|r| r.strip_suffix(suffix)) else { continue };
        let padded_ok = digits.len() == run || (digits.len() > run && !digits.starts_with('0'));
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || !padded_ok {
            continue;
        }
        let Ok(number) = digits.parse::<u64>() else { continue };
        steps.push((number, TimeStep { time: number as f64, file: dir.join(&file_name), volume_index: None }));
    }
    if steps.is_empty() {
        return Err(FormatError::invalid(path, format!("no file in {} matches the pattern (digits where the '#'s are)", dir.display())));
    }
    steps.sort_by_key(|s| s.0);
    Ok(TimeSeries { source: path.to_path_buf(), kind: "numbered files", time_unit: None, steps: steps.into_iter().map(|s| s.1).collect() })
}

/// A ParaView collection: `<VTKFile type="Collection"><Collection><DataSet timestep="…"
/// file="…"/>…`, files relative to the collection. A step split into several parts (the
/// `part` attribute) is refused: its parts would have to be merged.
fn collection(path: &Path) -> Result<TimeSeries> {
    let text = std::fs::read(path).map_err(|e| FormatError::io(path, e))?;
    let dir = path.parent().unwrap_or(Path::new(""));
    let mut reader = quick_xml::Reader::from_reader(&text[..]);
    let mut buf = Vec::new();
    let mut steps: Vec<TimeStep> = Vec::new();
    let mut is_collection = false;
    let bad = |e: quick_xml::Error| FormatError::invalid(path, format!("malformed ParaView collection: {e}"));
    loop {
        buf.clear();
        let ev = reader.read_event_into(&mut buf).map_err(bad)?;
        let e = match &ev {
            Event::Start(e) | Event::Empty(e) => e.clone(),
            Event::Eof => break,
            _ => continue,
        };
        let attr = |key: &str| -> Option<String> {
            e.attributes()
                .flatten()
                .find(|a| a.key.as_ref() == key.as_bytes())
                .and_then(|a| a.unescape_value().ok())
                .map(|v| v.into_owned())
        };
        match e.name().as_ref() {
            b"VTKFile" => {
                let ty = attr("type").unwrap_or_default();
                if ty != "Collection" {
                    return Err(FormatError::invalid(path, format!("a .pvd is a VTKFile of type Collection, this one is '{ty}'")));
                }
                is_collection = true;
            }
            b"DataSet" => {
                let file = attr("file").ok_or_else(|| FormatError::invalid(path, "a DataSet without a file attribute"))?;
                let time = match attr("timestep") {
                    None => steps.len() as f64,
                    Some(t) => t
                        .trim()
                        .parse::<f64>()
                        .ok()
                        .filter(|t| t.is_finite())
                        .ok_or_else(|| FormatError::invalid(path, format!("timestep '{t}' of {file} is not a number")))?,
                };
                if let Some(part) = attr("part").filter(|p| p.trim() != "0") {
                    return Err(FormatError::unsupported(
                        path,
                        format!("timestep {time} has several parts (part {part} of {file}); merge them into one file per timestep"),
                    ));
                }
                steps.push(TimeStep { time, file: dir.join(file), volume_index: None });
            }
            _ => {}
        }
    }
    if !is_collection {
        return Err(FormatError::invalid(path, "not a ParaView collection (no VTKFile element)"));
    }
    if steps.is_empty() {
        return Err(FormatError::invalid(path, "the collection lists no DataSet"));
    }
    steps.sort_by(|a, b| a.time.total_cmp(&b.time));
    if let Some(w) = steps.windows(2).find(|w| w[0].time == w[1].time) {
        return Err(FormatError::invalid(
            path,
            format!("two data sets at timestep {} ({} and {})", w[0].time, w[0].file.display(), w[1].file.display()),
        ));
    }
    if let Some(s) = steps.iter().find(|s| !s.file.exists()) {
        return Err(FormatError::invalid(path, format!("timestep {}: {} not found", s.time, s.file.display())));
    }
    Ok(TimeSeries { source: path.to_path_buf(), kind: "ParaView collection", time_unit: None, steps })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbered_files_are_found_in_number_order_with_their_padding() {
        let d = tempfile::tempdir().unwrap();
        for n in ["plume_0002.vtp", "plume_0010.vtp", "plume_0001.vtp", "plume_12345.vtp", "plume_002.vtp", "plume_0003.vtk", "other.vtp"] {
            std::fs::write(d.path().join(n), b"").unwrap();
        }
        let s = discover(&d.path().join("plume_####.vtp")).unwrap().unwrap();
        assert_eq!(s.times(), vec![1.0, 2.0, 10.0, 12345.0]);
        assert!(s.steps[0].file.ends_with("plume_0001.vtp"));
        assert_eq!(s.step_at(0.0), 0);
        assert_eq!(s.step_at(9.9), 1);
        assert_eq!(s.step_at(10.0), 2);
        assert_eq!(s.step_at(1e9), 3);
        let e = discover(&d.path().join("none_####.vtp")).unwrap_err().to_string();
        assert!(e.contains("none_####.vtp") && e.contains("matches"), "{e}");
    }

    #[test]
    fn a_collection_lists_its_steps_by_time_and_refuses_parts() {
        let d = tempfile::tempdir().unwrap();
        for n in ["a.vtp", "b.vtp"] {
            std::fs::write(d.path().join(n), b"").unwrap();
        }
        let pvd = d.path().join("run.pvd");
        std::fs::write(
            &pvd,
            r#"<?xml version="1.0"?><VTKFile type="Collection" version="0.1"><Collection>
            <DataSet timestep="0.5" group="" part="0" file="b.vtp"/>
            <DataSet timestep="0.25" group="" part="0" file="a.vtp"/></Collection></VTKFile>"#,
        )
        .unwrap();
        let s = discover(&pvd).unwrap().unwrap();
        assert_eq!(s.times(), vec![0.25, 0.5]);
        assert_eq!(s.steps[0].file, d.path().join("a.vtp"));
        std::fs::write(
            &pvd,
            r#"<VTKFile type="Collection"><Collection><DataSet timestep="0" part="1" file="a.vtp"/></Collection></VTKFile>"#,
        )
        .unwrap();
        assert!(discover(&pvd).unwrap_err().to_string().contains("several parts"));
        std::fs::write(&pvd, r#"<VTKFile type="Collection"><Collection><DataSet timestep="0" file="gone.vtp"/></Collection></VTKFile>"#)
            .unwrap();
        assert!(discover(&pvd).unwrap_err().to_string().contains("gone.vtp not found"));
    }
}
