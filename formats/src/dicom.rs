//! DICOM volumes: a single file, a multi-frame file, or a directory holding one or more
//! series. Geometry comes from ImagePositionPatient / ImageOrientationPatient (slices are
//! sorted by their position along the slice normal, never by file name or InstanceNumber),
//! values from the decoded pixel data with BitsStored, PixelRepresentation and the
//! rescale applied as DICOM says. World space is converted from LPS to RAS+.

use crate::error::{ErrorKind, FormatError, Result};
use crate::memory::Limits;
use crate::volume::{spacing_of, Affine, Rescale, ScalarType, Volume, VoxelData};
use dicom_core::dictionary::{DataDictionary, DataDictionaryEntry, VirtualVr};
use dicom_core::{PrimitiveValue, VR};
use dicom_dictionary_std::{tags, uids, StandardDataDictionary};
use dicom_object::{InMemDicomObject, OpenFileOptions};
use dicom_pixeldata::PixelDecoder;
use rayon::prelude::*;
use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Default)]
pub struct DicomOptions {
    /// SeriesInstanceUID (or a unique prefix, or the 1-based number `info` lists) to read
    /// from a directory holding several series.
    pub series: Option<String>,
    /// Resample slices with non-uniform spacing (or gaps) to uniform spacing instead of
    /// refusing them.
    pub resample: bool,
}

/// One series found in a directory.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SeriesSummary {
    pub uid: String,
    pub description: String,
    pub modality: String,
    pub files: usize,
    pub rows: u32,
    pub columns: u32,
    /// Patient name, study description and study date where the files give them.
    pub patient: String,
    pub study: String,
    pub study_date: String,
}

/// What one file says about its image, read without decoding pixel data.
#[derive(Debug, Clone)]
struct ImageInfo {
    path: PathBuf,
    transfer_syntax: String,
    series_uid: String,
    series_description: String,
    modality: String,
    rows: u32,
    columns: u32,
    frames: u32,
    samples_per_pixel: u16,
    photometric: String,
    bits_allocated: u16,
    bits_stored: u16,
    signed: bool,
    rescale: Rescale,
    units: Option<String>,
    /// SUVbw per Bq/ml (`suv_bw_factor`), where the file gives what it needs.
    suv_bw: Option<(f64, String)>,
    orientation: Option<[f64; 6]>,
    pixel_spacing: Option<[f64; 2]>,
    slice_spacing: Option<f64>,
    /// One position per frame where the file gives them (ImagePositionPatient for a
    /// single frame; per-frame functional groups or GridFrameOffsetVector for multi-frame).
    frame_positions: Vec<[f64; 3]>,
    /// Per-frame rescale of enhanced multi-frame files, where it varies.
    frame_rescale: Vec<Rescale>,
    /// How the file was read where not as a plain Part 10 file (no meta header, say).
    read_note: Option<String>,
    /// Patient, study and series as dcm2niix users look for them (for `info`).
    attributes: Vec<(String, String)>,
}

type Obj = InMemDicomObject;

/// The value of `tag` as its dictionary VR reads it. dicom-rs hands elements stored with VR
/// UN (some exporters write position, orientation, spacing, Modality and DoseGridScaling so)
/// as raw bytes, which read as numbers give the bytes' codes; pydicom resolves them through
/// the DICOM dictionary, and so do we. UN values are in the data set's byte order.
fn value(obj: &Obj, tag: dicom_core::Tag) -> Option<Cow<'_, PrimitiveValue>> {
    let e = obj.get(tag)?;
    let p = e.value().primitive()?;
    if e.vr() != VR::UN {
        return Some(Cow::Borrowed(p));
    }
    let Some(VirtualVr::Exact(vr)) = StandardDataDictionary.by_tag(tag).map(|d| d.vr()) else {
        return Some(Cow::Borrowed(p));
    };
    let bytes = p.to_bytes();
    let big = BIG_ENDIAN_DATA_SET.with(|b| b.get());
    macro_rules! words {
        ($t:ty, $n:expr, $variant:ident) => {
            PrimitiveValue::$variant(
                bytes
                    .chunks_exact($n)
                    .map(|c| {
                        let a: [u8; $n] = c.try_into().unwrap();
                        if big {
                            <$t>::from_be_bytes(a)
                        } else {
                            <$t>::from_le_bytes(a)
                        }
                    })
                    .collect(),
            )
        };
    }
    Some(Cow::Owned(match vr {
        VR::AE
        | VR::AS
        | VR::CS
        | VR::DA
        | VR::DS
        | VR::DT
        | VR::IS
        | VR::LO
        | VR::LT
        | VR::PN
        | VR::SH
        | VR::ST
        | VR::TM
        | VR::UC
        | VR::UI
        | VR::UR
        | VR::UT => {
            let text = String::from_utf8_lossy(&bytes);
            PrimitiveValue::Strs(text.split('\\').map(|v| v.trim_matches(|c: char| c == '\0' || c == ' ').to_string()).collect())
        }
        VR::US => words!(u16, 2, U16),
        VR::SS => words!(i16, 2, I16),
        VR::UL => words!(u32, 4, U32),
        VR::SL => words!(i32, 4, I32),
        VR::FL => words!(f32, 4, F32),
        VR::FD => words!(f64, 8, F64),
        _ => return Some(Cow::Borrowed(p)),
    }))
}

thread_local! {
    /// Whether the data set being read is big endian (for UN values): set by `image_info`.
    static BIG_ENDIAN_DATA_SET: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

fn floats(obj: &Obj, tag: dicom_core::Tag) -> Option<Vec<f64>> {
    value(obj, tag).and_then(|v| v.to_multi_float64().ok()).filter(|v| v.iter().all(|x| x.is_finite()))
}
fn float(obj: &Obj, tag: dicom_core::Tag) -> Option<f64> {
    floats(obj, tag).and_then(|v| v.first().copied())
}
/// A numeric element that must be valid where present: None when absent or empty, an error
/// naming the element when it holds something that is not finite numbers (a NaN slope or
/// spacing must not be ignored silently).
fn checked_floats(path: &Path, obj: &Obj, tag: dicom_core::Tag, name: &str) -> Result<Option<Vec<f64>>> {
    let Some(e) = value(obj, tag) else { return Ok(None) };
    let raw = e.to_str().trim_matches(|c: char| c == '\0' || c.is_whitespace()).to_string();
    if raw.is_empty() && e.to_multi_float64().map(|v| v.is_empty()).unwrap_or(true) {
        return Ok(None);
    }
    match e.to_multi_float64() {
        Ok(v) if !v.is_empty() && v.iter().all(|x| x.is_finite()) => Ok(Some(v)),
        _ => Err(FormatError::invalid(path, format!("{name} '{raw}' is not a finite number"))),
    }
}

/// RescaleSlope/Intercept of `obj` (identity where absent). A slope of 0 would map every
/// pixel to the intercept: refused, like a non-finite one.
fn rescale_of(path: &Path, obj: &Obj) -> Result<Rescale> {
    let slope = checked_floats(path, obj, tags::RESCALE_SLOPE, "RescaleSlope")?.map(|v| v[0]);
    let intercept = checked_floats(path, obj, tags::RESCALE_INTERCEPT, "RescaleIntercept")?.map(|v| v[0]);
    if slope == Some(0.0) {
        return Err(FormatError::invalid(path, "RescaleSlope is 0: every pixel would map to the intercept"));
    }
    Ok(Rescale { slope: slope.unwrap_or(1.0), intercept: intercept.unwrap_or(0.0) })
}

fn int(obj: &Obj, tag: dicom_core::Tag) -> Option<i64> {
    value(obj, tag).and_then(|v| v.to_int::<i64>().ok())
}
fn text(obj: &Obj, tag: dicom_core::Tag) -> Option<String> {
    value(obj, tag).map(|v| v.to_str().trim_matches(|c: char| c == '\0' || c.is_whitespace()).to_string())
}
fn item(obj: &Obj, seq: dicom_core::Tag) -> Option<&Obj> {
    obj.get(seq).and_then(|e| e.items()).and_then(|items| items.first())
}
fn items(obj: &Obj, seq: dicom_core::Tag) -> &[Obj] {
    obj.get(seq).and_then(|e| e.items()).unwrap_or(&[])
}

/// Opens a DICOM file; the note says how it was read where it was not as a plain Part 10 file.
fn open(path: &Path, metadata_only: bool, limits: &Limits) -> Result<(dicom_object::DefaultDicomObject, Option<String>)> {
    if let Some(how) = crate::dicom_scan::check_lengths(path, limits)? {
        return reparse(path, &how).map(|f| (f, Some(how.note)));
    }
    let opts = OpenFileOptions::new();
    let opts = if metadata_only { opts.read_until(tags::PIXEL_DATA) } else { opts };
    crate::guard::third_party(path, "the DICOM parser", || {
        opts.open_file(path).map_err(|e| FormatError::invalid(path, format!("not a readable DICOM file: {}", first_line(&e.to_string()))))
    })
    .map(|f| (f, None))
}

/// A data set dicom-rs does not read as the file stands (see [`crate::dicom_scan::Reparse`]):
/// ACR-NEMA files and bare data sets (no preamble, no "DICM", no file meta group), or an
/// implicit VR data set behind a meta group naming explicit VR. dicom-rs reads only Part 10
/// files as they declare themselves, so the data set is read alone in the syntax the walk
/// found and given a file meta group naming the pixel data's syntax (pydicom's
/// `dcmread(force=True)` reads the same files).
fn reparse(path: &Path, how: &crate::dicom_scan::Reparse) -> Result<dicom_object::DefaultDicomObject> {
    use dicom_encoding::transfer_syntax::TransferSyntaxIndex;
    use dicom_transfer_syntax_registry::TransferSyntaxRegistry;
    use std::io::{Seek, SeekFrom};
    let ts = TransferSyntaxRegistry.get(how.parse_syntax).expect("the walk names only native transfer syntaxes");
    crate::guard::third_party(path, "the DICOM parser", || {
        let mut f = std::fs::File::open(path).map_err(|e| FormatError::io(path, e))?;
        f.seek(SeekFrom::Start(how.start)).map_err(|e| FormatError::io(path, e))?;
        let obj = InMemDicomObject::read_dataset_with_ts(std::io::BufReader::new(f), ts)
            .map_err(|e| FormatError::invalid(path, format!("the data set does not parse: {}", first_line(&e.to_string()))))?;
        let meta = dicom_object::meta::FileMetaTableBuilder::new()
            .transfer_syntax(how.pixel_syntax.as_str())
            .media_storage_sop_class_uid("1.2.840.10008.5.1.4.1.1.7")
            .media_storage_sop_instance_uid("2.25.0");
        obj.with_meta(meta).map_err(|e| FormatError::invalid(path, format!("no usable file meta: {}", first_line(&e.to_string()))))
    })
}

fn first_line(s: &str) -> &str {
    s.lines().next().unwrap_or(s)
}

fn units_for(obj: &Obj, modality: &str) -> Option<String> {
    match modality {
        "CT" => match text(obj, tags::RESCALE_TYPE).as_deref() {
            None | Some("") | Some("HU") => Some("HU".into()),
            Some(other) => Some(other.into()),
        },
        // PS3.3 C.8.9.1.1.3: BQML is activity concentration; GML, CM2ML and CM2 are the
        // standardised uptake values by body weight, body surface area and lean body mass.
        "PT" | "NM" => text(obj, tags::UNITS).filter(|u| !u.is_empty()).map(|u| match u.as_str() {
            "BQML" => "Bq/ml".to_string(),
            "GML" => "SUVbw g/ml".to_string(),
            "CM2ML" => "SUVbsa cm²/ml".to_string(),
            _ => u,
        }),
        "RTDOSE" => text(obj, tags::DOSE_UNITS).map(|u| if u == "GY" { "Gy".into() } else { u }),
        _ => text(obj, tags::RESCALE_TYPE).filter(|u| !u.is_empty() && u != "US"),
    }
}

/// Seconds since midnight of a DICOM time (HHMMSS.FFFFFF, or HH:MM:SS of old files).
fn seconds_of_day(tm: &str) -> Option<f64> {
    let t: String = tm.trim().chars().filter(|c| *c != ':').collect();
    let (hms, frac) = t.split_once('.').unwrap_or((&t, ""));
    if hms.len() < 2 || hms.len() % 2 != 0 || !hms.chars().all(|c| c.is_ascii_digit()) {
        return None;
    }
    let part = |k: usize| hms.get(2 * k..2 * k + 2).map_or(Some(0.0), |p| p.parse::<f64>().ok());
    let fraction = if frac.is_empty() { 0.0 } else { format!("0.{frac}").parse::<f64>().ok()? };
    Some(part(0)? * 3600.0 + part(1)? * 60.0 + part(2)? + fraction)
}

/// The body-weight SUV factor of a PET in Bq/ml (PS3.3 C.8.9.1, the QIBA/Vendor-neutral
/// rule): SUVbw = value · weight [g] / dose at the reference time [Bq], where the dose is
/// the injected RadionuclideTotalDose decayed with RadionuclideHalfLife from
/// RadiopharmaceuticalStartTime to SeriesTime when the images are decay-corrected to the
/// scan's START, undecayed when corrected to the injection (ADMIN). None where a value is
/// missing or not positive, or the correction is another; with a note saying what it used.
fn suv_bw_factor(obj: &Obj) -> Option<(f64, String)> {
    let weight_kg = float(obj, tags::PATIENT_WEIGHT).filter(|w| *w > 0.0)?;
    let item = obj.get(tags::RADIOPHARMACEUTICAL_INFORMATION_SEQUENCE)?.items()?.first()?;
    let dose = float(item, tags::RADIONUCLIDE_TOTAL_DOSE).filter(|d| *d > 0.0)?;
    let half_life = float(item, tags::RADIONUCLIDE_HALF_LIFE).filter(|h| *h > 0.0)?;
    let correction = text(obj, tags::DECAY_CORRECTION).unwrap_or_default();
    let (decay, elapsed) = match correction.as_str() {
        "ADMIN" => (1.0, 0.0),
        "START" => {
            let start = seconds_of_day(&text(item, tags::RADIOPHARMACEUTICAL_START_TIME)?)?;
            let series = seconds_of_day(&text(obj, tags::SERIES_TIME)?)?;
            // A scan after midnight of an injection before it.
            let elapsed = if series >= start { series - start } else { series + 86400.0 - start };
            ((-std::f64::consts::LN_2 * elapsed / half_life).exp(), elapsed)
        }
        _ => return None,
    };
    let factor = weight_kg * 1000.0 / (dose * decay);
    let how = format!(
        "SUVbw = Bq/ml x {factor:.6e} (weight {weight_kg} kg, dose {:.1} MBq decayed over {:.1} min, half-life {:.1} min, corrected to {correction})",
        dose / 1e6,
        elapsed / 60.0,
        half_life / 60.0
    );
    Some((factor, how))
}

fn image_info(path: &Path, file: &dicom_object::DefaultDicomObject, read_note: Option<String>) -> Result<ImageInfo> {
    let obj: &Obj = file;
    BIG_ENDIAN_DATA_SET.with(|b| b.set(file.meta().transfer_syntax().trim_end_matches('\0') == crate::dicom_scan::EXPLICIT_VR_BIG_ENDIAN));
    let need = |tag, name: &str| int(obj, tag).ok_or_else(|| FormatError::invalid(path, format!("missing or malformed {name}")));
    // A data set that carries no image (an RT plan or structure set, a report) has neither
    // Rows nor Columns (the pixel data, read later, is not in `obj`): said so.
    if obj.element(tags::ROWS).is_err() && obj.element(tags::COLUMNS).is_err() {
        let modality = text(obj, tags::MODALITY).unwrap_or_default();
        let what = if modality.is_empty() { String::new() } else { format!(" (modality {modality})") };
        return Err(FormatError::unsupported(path, format!("the data set holds no image: it has no Rows, Columns or pixel data{what}")));
    }
    let rows = need(tags::ROWS, "Rows")?;
    let columns = need(tags::COLUMNS, "Columns")?;
    if rows < 1 || columns < 1 || rows > 65535 || columns > 65535 {
        return Err(FormatError::invalid(path, format!("image size {columns}x{rows} is not valid")));
    }
    let frames = int(obj, tags::NUMBER_OF_FRAMES).unwrap_or(1);
    if frames < 1 || frames > i32::MAX as i64 {
        return Err(FormatError::invalid(path, format!("NumberOfFrames {frames} is not valid")));
    }
    let bits_allocated = need(tags::BITS_ALLOCATED, "BitsAllocated")? as u16;
    let bits_stored = int(obj, tags::BITS_STORED).unwrap_or(bits_allocated as i64) as u16;
    if ![8, 16, 32].contains(&bits_allocated) || bits_stored == 0 || bits_stored > bits_allocated {
        return Err(FormatError::unsupported(
            path,
            format!("BitsAllocated {bits_allocated} / BitsStored {bits_stored} is not a scalar layout volterra reads (8, 16 or 32 bits)"),
        ));
    }
    let modality = text(obj, tags::MODALITY).unwrap_or_default();
    let mut rescale = rescale_of(path, obj)?;
    if modality == "RTDOSE" {
        // Dose values are stored × DoseGridScaling (Gy per unit); it plays the slope's role.
        if let Some(s) = float(obj, tags::DOSE_GRID_SCALING).filter(|s| *s != 0.0) {
            rescale.slope = s;
        }
    }

    let shared = item(obj, tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE);
    let per_frame = items(obj, tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE);
    let from_groups = |tag_seq, tag| -> Option<Vec<f64>> {
        let from = |o: &Obj| item(o, tag_seq).and_then(|i| floats(i, tag));
        per_frame.first().and_then(from).or_else(|| shared.and_then(from))
    };
    let orientation = floats(obj, tags::IMAGE_ORIENTATION_PATIENT)
        .or_else(|| from_groups(tags::PLANE_ORIENTATION_SEQUENCE, tags::IMAGE_ORIENTATION_PATIENT))
        .filter(|v| v.len() == 6)
        .map(|v| [v[0], v[1], v[2], v[3], v[4], v[5]]);
    let pixel_spacing = checked_floats(path, obj, tags::PIXEL_SPACING, "PixelSpacing")?
        .or_else(|| from_groups(tags::PIXEL_MEASURES_SEQUENCE, tags::PIXEL_SPACING))
        .filter(|v| v.len() == 2)
        .map(|v| [v[0], v[1]]);
    if let Some(ps) = pixel_spacing {
        if ps.iter().any(|&s| s <= 0.0) {
            return Err(FormatError::invalid(path, format!("PixelSpacing {ps:?} is not positive")));
        }
    }
    let slice_spacing = float(obj, tags::SPACING_BETWEEN_SLICES)
        .or_else(|| from_groups(tags::PIXEL_MEASURES_SEQUENCE, tags::SPACING_BETWEEN_SLICES).and_then(|v| v.first().copied()))
        .or_else(|| float(obj, tags::SLICE_THICKNESS))
        .or_else(|| from_groups(tags::PIXEL_MEASURES_SEQUENCE, tags::SLICE_THICKNESS).and_then(|v| v.first().copied()))
        .filter(|s| *s > 0.0);

    let ipp = floats(obj, tags::IMAGE_POSITION_PATIENT).filter(|v| v.len() == 3).map(|v| [v[0], v[1], v[2]]);
    let mut frame_positions = Vec::new();
    let mut frame_rescale = Vec::new();
    if frames > 1 && !per_frame.is_empty() {
        for f in per_frame {
            if let Some(p) = item(f, tags::PLANE_POSITION_SEQUENCE).and_then(|i| floats(i, tags::IMAGE_POSITION_PATIENT)) {
                if p.len() == 3 {
                    frame_positions.push([p[0], p[1], p[2]]);
                }
            }
            if let Some(t) = item(f, tags::PIXEL_VALUE_TRANSFORMATION_SEQUENCE) {
                frame_rescale.push(rescale_of(path, t)?);
            }
        }
        if frame_positions.len() != frames as usize {
            frame_positions.clear();
        }
        if frame_rescale.len() != frames as usize {
            frame_rescale.clear();
        }
        if frame_rescale.is_empty() {
            if let Some(t) = shared.and_then(|s| item(s, tags::PIXEL_VALUE_TRANSFORMATION_SEQUENCE)) {
                rescale = rescale_of(path, t)?;
            }
        }
    } else if frames > 1 {
        // RT Dose and similar: frame k lies at IPP + offset[k] along the slice normal.
        if let (Some(p0), Some(o), Some(offsets)) = (ipp, orientation, floats(obj, tags::GRID_FRAME_OFFSET_VECTOR)) {
            if offsets.len() == frames as usize {
                let n = cross([o[0], o[1], o[2]], [o[3], o[4], o[5]]);
                frame_positions = offsets.iter().map(|&d| [p0[0] + d * n[0], p0[1] + d * n[1], p0[2] + d * n[2]]).collect();
            }
        }
    } else if let Some(p) = ipp {
        frame_positions.push(p);
    }

    let units = units_for(obj, &modality);
    Ok(ImageInfo {
        path: path.to_path_buf(),
        transfer_syntax: file.meta().transfer_syntax().trim_end_matches('\0').to_string(),
        series_uid: text(obj, tags::SERIES_INSTANCE_UID).unwrap_or_default(),
        series_description: text(obj, tags::SERIES_DESCRIPTION).unwrap_or_default(),
        suv_bw: (units.as_deref() == Some("Bq/ml")).then(|| suv_bw_factor(obj)).flatten(),
        units,
        modality,
        rows: rows as u32,
        columns: columns as u32,
        frames: frames as u32,
        samples_per_pixel: int(obj, tags::SAMPLES_PER_PIXEL).unwrap_or(1) as u16,
        photometric: text(obj, tags::PHOTOMETRIC_INTERPRETATION).unwrap_or_default(),
        bits_allocated,
        bits_stored,
        signed: int(obj, tags::PIXEL_REPRESENTATION).unwrap_or(0) == 1,
        rescale,
        orientation,
        pixel_spacing,
        slice_spacing,
        frame_positions,
        frame_rescale,
        read_note,
        attributes: describe(obj, file.meta().transfer_syntax().trim_end_matches('\0')),
    })
}

/// Patient, study, series, date and encoding, each where the file has it.
fn describe(obj: &Obj, syntax: &str) -> Vec<(String, String)> {
    use dicom_encoding::transfer_syntax::TransferSyntaxIndex;
    use dicom_transfer_syntax_registry::TransferSyntaxRegistry;
    let mut a = Vec::new();
    let mut put = |name: &str, v: Option<String>| {
        if let Some(v) = v.filter(|v| !v.is_empty()) {
            a.push((name.to_string(), v));
        }
    };
    let date = |d: Option<String>| {
        d.map(|d| if d.len() == 8 && d.bytes().all(|b| b.is_ascii_digit()) { format!("{}-{}-{}", &d[..4], &d[4..6], &d[6..]) } else { d })
    };
    put("patient", text(obj, tags::PATIENT_NAME).map(|n| n.replace('^', " ").trim().to_string()));
    put("patient ID", text(obj, tags::PATIENT_ID));
    put("study", text(obj, tags::STUDY_DESCRIPTION));
    put("study date", date(text(obj, tags::STUDY_DATE)));
    put("series number", text(obj, tags::SERIES_NUMBER));
    put("series", text(obj, tags::SERIES_DESCRIPTION));
    put("series date", date(text(obj, tags::SERIES_DATE).or_else(|| text(obj, tags::ACQUISITION_DATE))));
    put("manufacturer", text(obj, tags::MANUFACTURER));
    put("photometric", text(obj, tags::PHOTOMETRIC_INTERPRETATION));
    let ts_name = TransferSyntaxRegistry.get(syntax).map(|t| t.name().to_string());
    put(
        "transfer syntax",
        Some(match ts_name {
            Some(n) => format!("{n} ({syntax})"),
            None => syntax.to_string(),
        }),
    );
    a
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Refuses transfer syntaxes that dicom-pixeldata cannot decode with our features.
fn check_transfer_syntax(info: &ImageInfo) -> Result<()> {
    use dicom_encoding::transfer_syntax::TransferSyntaxIndex;
    use dicom_transfer_syntax_registry::TransferSyntaxRegistry;
    let uid = info.transfer_syntax.as_str();
    match TransferSyntaxRegistry.get(uid) {
        Some(ts) if ts.can_decode_all() => Ok(()),
        Some(ts) => Err(FormatError::unsupported(&info.path, format!("unsupported transfer syntax {} ({uid})", ts.name()))),
        None => Err(FormatError::unsupported(&info.path, format!("unsupported transfer syntax {uid} (unknown)"))),
    }
}

/// Decodes one file's pixel data into `frames × rows × cols` samples of the stored type,
/// as little-endian bytes, with BitsStored masking / sign extension applied.
fn decode_frames(info: &ImageInfo, limits: &Limits) -> Result<Vec<u8>> {
    let (file, _) = open(&info.path, false, limits)?;
    let pixels = info.rows as usize * info.columns as usize * info.frames as usize;
    let bytes_per = info.bits_allocated as usize / 8;
    let pixel_fragments = file.get(tags::PIXEL_DATA).and_then(|e| e.value().fragments());
    let rgb_jpeg = if info.photometric == "RGB" && info.samples_per_pixel == 3 && bytes_per == 1 {
        pixel_fragments.and_then(|f| rgb_jpeg_frames(&info.path, f, info.frames as usize, &info.transfer_syntax).transpose())
    } else {
        None
    };
    let jpeg12 = info.transfer_syntax == uids::JPEG_EXTENDED12_BIT && info.bits_stored > 8 && info.samples_per_pixel == 1;
    let (data, spp, planar) = if let Some(rgb) = rgb_jpeg {
        (rgb?, 3, false)
    } else if let Some(fragments) = pixel_fragments.filter(|_| jpeg12 && bytes_per == 2) {
        // 12-bit lossy JPEG: libjpeg-turbo 3 (dicom-pixeldata's jpeg-decoder is 8-bit only).
        let (rows, columns) = (info.rows as usize, info.columns as usize);
        limits.check(&info.path, "the decoded JPEG frames", &[info.frames as u64, rows as u64, columns as u64, 4])?;
        let data = crate::guard::third_party(&info.path, "the 12-bit JPEG decoder", || {
            crate::dicom_jpeg12::decode_frames(&info.path, fragments, info.frames as usize, rows, columns)
        })?;
        (data, 1, false)
    } else if info.transfer_syntax == uids::RLE_LOSSLESS {
        let fragments = pixel_fragments.ok_or_else(|| FormatError::invalid(&info.path, "RLE pixel data is not encapsulated"))?;
        let spp = info.samples_per_pixel as usize;
        let frame_px = info.rows as usize * info.columns as usize;
        let data = crate::dicom_rle::decode(&info.path, fragments, info.frames as usize, frame_px, spp, bytes_per)?;
        (data, spp, true)
    } else {
        let decoded = crate::guard::third_party(&info.path, "the pixel data decoder", || {
            file.decode_pixel_data().map_err(|e| {
                // jpeg-decoder (behind dicom-pixeldata) has no 12-bit DCT: say so instead of a
                // generic decode failure.
                if info.transfer_syntax == uids::JPEG_EXTENDED12_BIT && info.bits_stored > 8 {
                    FormatError::unsupported(
                        &info.path,
                        format!(
                            "unsupported: JPEG Extended at {} bits with {} samples a pixel (12-bit JPEG is read for one sample a pixel)",
                            info.bits_stored, info.samples_per_pixel
                        ),
                    )
                } else {
                    FormatError::invalid(&info.path, format!("cannot decode pixel data: {}", first_line(&e.to_string())))
                }
            })
        })?;
        let mut data = decoded.data().to_vec();
        if info.transfer_syntax == crate::dicom_scan::EXPLICIT_VR_BIG_ENDIAN {
            let word = file.get(tags::PIXEL_DATA).and_then(|e| e.value().primitive()).map(word_size).unwrap_or(1);
            big_endian_samples_to_le(&mut data, word, bytes_per);
        }
        let planar = decoded.planar_configuration() == dicom_pixeldata::PlanarConfiguration::PixelFirst;
        (data, decoded.samples_per_pixel() as usize, planar)
    };
    // Native YBR_FULL_422 keeps one Cb and one Cr per two pixels: Y0 Y1 Cb Cr.
    let ybr_422 = pixel_fragments.is_none() && info.photometric == "YBR_FULL_422" && spp == 3 && bytes_per == 1;
    let want = if ybr_422 { pixels * 2 } else { pixels * bytes_per * spp };
    if data.len() < want {
        return Err(FormatError::invalid(
            &info.path,
            format!("pixel data holds {} bytes, but {}x{}x{} frames need {want}", data.len(), info.columns, info.rows, info.frames),
        ));
    }
    let mut out = if spp == 1 {
        let mut data = data;
        data.truncate(want);
        data
    } else if spp == 3 && bytes_per == 1 && pixel_fragments.is_none() && info.photometric.starts_with("YBR_FULL") {
        // Native YBR_FULL: Y is the BT.601 luminance already (PS3.3 C.7.6.3.1.2, full range),
        // so it is kept as stored; treating Y, Cb, Cr as R, G, B (as before) mixed in chroma.
        let frame_px = info.rows as usize * info.columns as usize;
        (0..pixels)
            .map(|p| {
                if ybr_422 {
                    data[4 * (p / 2) + p % 2]
                } else if planar {
                    data[(p / frame_px) * frame_px * 3 + p % frame_px]
                } else {
                    data[3 * p]
                }
            })
            .collect()
    } else if spp == 3 && bytes_per == 1 {
        // Colour to luminance (ITU-R BT.601), so colour images still load as scalar volumes.
        let frame_px = info.rows as usize * info.columns as usize;
        (0..pixels)
            .map(|p| {
                let (r, g, b) = if planar {
                    let f = p / frame_px;
                    let q = p % frame_px;
                    let base = f * frame_px * 3;
                    (data[base + q], data[base + frame_px + q], data[base + 2 * frame_px + q])
                } else {
                    (data[3 * p], data[3 * p + 1], data[3 * p + 2])
                };
                (0.299 * r as f64 + 0.587 * g as f64 + 0.114 * b as f64).round() as u8
            })
            .collect()
    } else {
        return Err(FormatError::unsupported(
            &info.path,
            format!("{spp} samples per pixel at {} bits is not a scalar image", info.bits_allocated),
        ));
    };
    // BitsStored: keep the low bits; sign-extend them for signed data.
    let bs = info.bits_stored as u32;
    if bs < info.bits_allocated as u32 && spp == 1 {
        match bytes_per {
            1 => out.iter_mut().for_each(|b| *b = mask_bits(*b as u32, bs, info.signed) as u8),
            2 => out.chunks_exact_mut(2).for_each(|c| {
                let v = u16::from_le_bytes([c[0], c[1]]) as u32;
                c.copy_from_slice(&(mask_bits(v, bs, info.signed) as u16).to_le_bytes());
            }),
            _ => out.chunks_exact_mut(4).for_each(|c| {
                let v = u32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                c.copy_from_slice(&mask_bits(v, bs, info.signed).to_le_bytes());
            }),
        }
    }
    Ok(out)
}

/// JPEG frames whose components DICOM calls RGB but whose stream says nothing of its colour
/// (no JFIF or Adobe marker, component ids other than 1,2,3 or 'R','G','B'): jpeg-decoder,
/// behind dicom-pixeldata, then assumes YCbCr and converts colours that are not (pydicom's
/// SC_jpeg_no_color_transform.dcm came out up to 77 grey levels off). Decoded here with the
/// transform DICOM states; None for every other stream, which dicom-pixeldata decodes.
fn rgb_jpeg_frames(path: &Path, fragments: &[Vec<u8>], frames: usize, syntax: &str) -> Result<Option<Vec<u8>>> {
    if !matches!(syntax, uids::JPEG_BASELINE8_BIT | uids::JPEG_EXTENDED12_BIT) || fragments.is_empty() {
        return Ok(None);
    }
    let streams: Vec<Vec<u8>> = if frames == 1 {
        vec![fragments.concat()]
    } else if fragments.len() == frames {
        fragments.to_vec()
    } else {
        return Ok(None);
    };
    if !streams.iter().all(|s| jpeg_colour_is_unstated(s)) {
        return Ok(None);
    }
    let mut out = Vec::new();
    for (k, s) in streams.iter().enumerate() {
        let mut d = jpeg_decoder::Decoder::new(s.as_slice());
        d.set_color_transform(jpeg_decoder::ColorTransform::RGB);
        let px = crate::guard::third_party(path, "the JPEG decoder", || {
            d.decode().map_err(|e| FormatError::invalid(path, format!("cannot decode JPEG frame {k}: {e}")))
        })?;
        out.extend_from_slice(&px);
    }
    Ok(Some(out))
}

/// No JFIF (APP0) or whole Adobe (APP14) marker before the scan, and three components whose ids
/// do not name their colour space.
fn jpeg_colour_is_unstated(s: &[u8]) -> bool {
    let mut i = 2;
    while i + 4 <= s.len() && s[i] == 0xFF {
        let marker = s[i + 1];
        let len = u16::from_be_bytes([s[i + 2], s[i + 3]]) as usize;
        match marker {
            0xE0 if s.get(i + 4..i + 9) == Some(b"JFIF\0") => return false,
            // An Adobe marker states the transform only when whole (14 bytes); a short one
            // (pydicom's SC_rgb_jpeg.dcm) states nothing.
            0xEE if s.get(i + 4..i + 9) == Some(b"Adobe") && len >= 14 => return false,
            0xC0..=0xC3 => {
                let Some(sof) = s.get(i + 4..i + 4 + len.saturating_sub(2)) else { return false };
                if sof.len() < 15 || sof[5] != 3 {
                    return false;
                }
                let ids = (sof[6], sof[9], sof[12]);
                return !matches!(ids, (1, 2, 3) | (1, 34, 35) | (82, 71, 66) | (114, 103, 98));
            }
            0xDA => return false,
            _ => {}
        }
        i += 2 + len;
    }
    false
}
/// The size of the words dicom-rs converted a native value to host order by: its VR's
/// (OB/UN bytes, OW 16-bit words, OL/OF 32-bit, OD 64-bit).
fn word_size(p: &PrimitiveValue) -> usize {
    match p {
        PrimitiveValue::U16(_) | PrimitiveValue::I16(_) => 2,
        PrimitiveValue::U32(_) | PrimitiveValue::I32(_) | PrimitiveValue::F32(_) => 4,
        PrimitiveValue::U64(_) | PrimitiveValue::I64(_) | PrimitiveValue::F64(_) => 8,
        _ => 1,
    }
}

/// Explicit VR Big Endian pixel data, as dicom-rs hands it: each `word`-byte word of the
/// file (the VR's: OW 16-bit) already in host (little-endian) order. That is right for
/// samples as large as the words, and for smaller ones (8-bit samples in OW words are packed
/// low byte first, as pydicom reads them). Samples larger than the words are big-endian
/// in the file across words: 32-bit doses in OW came out with their two 16-bit halves
/// swapped (an RT Dose read 23 … 4292 Gy where pydicom reads 0.795 … 1.254), so the words
/// are put back as the file has them and each sample reversed.
fn big_endian_samples_to_le(data: &mut [u8], word: usize, sample: usize) {
    if sample <= word || cfg!(target_endian = "big") {
        return;
    }
    if word > 1 {
        data.chunks_exact_mut(word).for_each(|w| w.reverse());
    }
    data.chunks_exact_mut(sample).for_each(|w| w.reverse());
}

fn mask_bits(v: u32, bits: u32, signed: bool) -> u32 {
    let m = (1u32 << bits) - 1;
    let low = v & m;
    if signed && low & (1 << (bits - 1)) != 0 {
        low | !m
    } else {
        low
    }
}

fn scalar_type(info: &ImageInfo) -> ScalarType {
    match (info.bits_allocated, info.signed && info.samples_per_pixel == 1) {
        (8, false) => ScalarType::U8,
        (8, true) => ScalarType::I8,
        (16, false) => ScalarType::U16,
        (16, true) => ScalarType::I16,
        (32, false) => ScalarType::U32,
        _ => ScalarType::I32,
    }
}

/// Is `path` a DICOM file? (the "DICM" magic at 128, or a bare data set starting with an
/// element of a low group, as ACR-NEMA files do).
pub fn looks_like_dicom(path: &Path) -> bool {
    use std::io::Read;
    let mut buf = [0u8; 132];
    let Ok(mut f) = std::fs::File::open(path) else { return false };
    let n = f.read(&mut buf).unwrap_or(0);
    (n >= 132 && &buf[128..132] == b"DICM") || crate::dicom_scan::bare_syntax_of(&buf[..n]).is_some()
}

/// Lists the DICOM files under `dir` (recursively), skipping others.
fn dicom_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for entry in walkdir::WalkDir::new(dir).follow_links(true).sort_by_file_name() {
        let entry = entry.map_err(|e| FormatError::new(dir, ErrorKind::Io, e.to_string()))?;
        if entry.file_type().is_file() && looks_like_dicom(entry.path()) {
            files.push(entry.into_path());
        }
    }
    if files.is_empty() {
        return Err(FormatError::invalid(dir, "directory holds no DICOM files"));
    }
    Ok(files)
}

fn scan(dir: &Path, limits: &Limits) -> Result<BTreeMap<String, Vec<ImageInfo>>> {
    let files = dicom_files(dir)?;
    let infos: Vec<Result<ImageInfo>> = files
        .par_iter()
        .map(|p| {
            let (f, note) = open(p, true, limits)?;
            image_info(p, &f, note)
        })
        .collect();
    let mut series: BTreeMap<String, Vec<ImageInfo>> = BTreeMap::new();
    let mut first_err = None;
    for r in infos {
        match r {
            Ok(i) => series.entry(i.series_uid.clone()).or_default().push(i),
            // Non-image objects (reports, presentation states) in a study folder are skipped.
            Err(e) => first_err = first_err.or(Some(e)),
        }
    }
    if series.is_empty() {
        return Err(first_err.unwrap_or_else(|| FormatError::invalid(dir, "directory holds no DICOM images")));
    }
    Ok(series)
}

fn attribute(attributes: &[(String, String)], name: &str) -> String {
    attributes.iter().find(|(k, _)| k == name).map(|(_, v)| v.clone()).unwrap_or_default()
}

/// The series in a directory, for `info` and for choosing one.
pub fn list_series(dir: &Path, limits: &Limits) -> Result<Vec<SeriesSummary>> {
    Ok(scan(dir, limits)?.into_iter().map(|(uid, v)| summary(uid, &v)).collect())
}

fn summary(uid: String, v: &[ImageInfo]) -> SeriesSummary {
    SeriesSummary {
        uid,
        description: v[0].series_description.clone(),
        modality: v[0].modality.clone(),
        files: v.len(),
        rows: v[0].rows,
        columns: v[0].columns,
        patient: attribute(&v[0].attributes, "patient"),
        study: attribute(&v[0].attributes, "study"),
        study_date: attribute(&v[0].attributes, "study date"),
    }
}

/// Series as people pick them, on one line: by number, description, modality and size
/// first, the UID last (`1: 'AX T1' MR, 20 files of 512×512 (UID 1.2.840…)`).
pub fn series_listing(list: &[SeriesSummary]) -> String {
    list.iter()
        .enumerate()
        .map(|(n, s)| {
            format!("{}: '{}' {}, {} files of {}×{} (UID {})", n + 1, s.description, s.modality, s.files, s.columns, s.rows, s.uid)
        })
        .collect::<Vec<_>>()
        .join("; ")
}

pub fn read_dicom(path: &Path, opts: &DicomOptions, limits: &Limits) -> Result<Volume> {
    if path.is_dir() {
        read_series_dir(path, opts, limits)
    } else {
        let (f, note) = open(path, true, limits)?;
        let info = image_info(path, &f, note)?;
        assemble(path, vec![info], opts, limits)
    }
}

fn read_series_dir(dir: &Path, opts: &DicomOptions, limits: &Limits) -> Result<Volume> {
    let mut series = scan(dir, limits)?;
    let uid = if series.len() == 1 {
        series.keys().next().unwrap().clone()
    } else {
        let listing = series_listing(&series.iter().map(|(uid, v)| summary(uid.clone(), v)).collect::<Vec<_>>());
        match &opts.series {
            None => {
                return Err(FormatError::new(
                    dir,
                    ErrorKind::Ambiguous,
                    format!("directory holds {} series, choose one with --series: {listing}", series.len()),
                ))
            }
            Some(want) => {
                // An exact UID first, then the number `info` lists, then a unique prefix.
                let by_number = want.parse::<usize>().ok().and_then(|n| series.keys().nth(n.wrapping_sub(1)).cloned());
                let prefixed: Vec<&String> = series.keys().filter(|u| u.starts_with(want.as_str())).collect();
                if series.contains_key(want) {
                    want.clone()
                } else if let Some(u) = by_number {
                    u
                } else if let [one] = prefixed.as_slice() {
                    (*one).clone()
                } else {
                    return Err(FormatError::new(
                        dir,
                        ErrorKind::Ambiguous,
                        format!("--series {want} matches none or several of: {listing}"),
                    ));
                }
            }
        }
    };
    let infos = series.remove(&uid).unwrap();
    assemble(dir, infos, opts, limits)
}

/// A frame in the final volume: which file and frame it comes from, and where it lies.
struct FrameRef {
    file: usize,
    frame: usize,
    position: Option<[f64; 3]>,
}

fn assemble(src: &Path, infos: Vec<ImageInfo>, opts: &DicomOptions, limits: &Limits) -> Result<Volume> {
    let first = &infos[0];
    for info in &infos {
        check_transfer_syntax(info)?;
    }
    // A series must agree with itself on everything that shapes the volume.
    let name = |i: &ImageInfo| i.path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    for info in &infos[1..] {
        let (a, b) = (name(info), name(first));
        let contradiction = if (info.rows, info.columns) != (first.rows, first.columns) {
            Some(format!("{a} has {}x{} pixels, {b} {}x{}", info.columns, info.rows, first.columns, first.rows))
        } else if (info.bits_allocated, info.signed, info.samples_per_pixel)
            != (first.bits_allocated, first.signed, first.samples_per_pixel)
        {
            Some(format!("{a} and {b} store pixels differently (bits, sign or samples per pixel)"))
        } else if !orientation_close(info.orientation, first.orientation) {
            Some(format!("{a} has orientation {}, {b} {}", show_orientation(info.orientation), show_orientation(first.orientation)))
        } else if info.pixel_spacing.zip(first.pixel_spacing).is_some_and(|(a, b)| (a[0] - b[0]).abs() > 1e-4 || (a[1] - b[1]).abs() > 1e-4)
        {
            Some(format!("{a} and {b} have different PixelSpacing"))
        } else {
            None
        };
        if let Some(c) = contradiction {
            return Err(FormatError::invalid(src, format!("series contradicts itself: {c}")));
        }
    }
    // The whole volume against the memory guard before anything is sized by the frame count
    // (a lying NumberOfFrames of 2^31 would otherwise allocate the frame list first).
    let total_frames: u64 = infos.iter().map(|i| i.frames as u64).sum();
    limits.check(
        src,
        "DICOM volume",
        &[first.columns as u64, first.rows as u64, total_frames, (first.bits_allocated as u64).div_ceil(8)],
    )?;
    if infos.len() > 1 && infos.iter().any(|i| i.frames > 1) {
        return Err(FormatError::unsupported(src, "a series of several multi-frame files is not supported"));
    }

    let mut notes = Vec::new();
    let orientation = first.orientation.unwrap_or_else(|| {
        notes.push("no ImageOrientationPatient: axial orientation assumed".to_string());
        [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    });
    let row_dir = [orientation[0], orientation[1], orientation[2]];
    let col_dir = [orientation[3], orientation[4], orientation[5]];
    let normal = cross(row_dir, col_dir);
    let nn = dot(normal, normal).sqrt();
    if !(0.5..1.5).contains(&nn) {
        return Err(FormatError::invalid(&first.path, format!("ImageOrientationPatient {orientation:?} is not two unit vectors")));
    }
    let normal = [normal[0] / nn, normal[1] / nn, normal[2] / nn];

    let mut frames: Vec<FrameRef> = Vec::new();
    for (fi, info) in infos.iter().enumerate() {
        for k in 0..info.frames as usize {
            frames.push(FrameRef { file: fi, frame: k, position: info.frame_positions.get(k).copied() });
        }
    }
    let positioned = frames.iter().all(|f| f.position.is_some());
    if frames.len() > 1 && !positioned {
        if infos.len() > 1 {
            return Err(FormatError::invalid(src, "some slices have no ImagePositionPatient, so they cannot be ordered"));
        }
        notes.push("frames have no positions: stacked in file order".to_string());
    }
    let along = |f: &FrameRef| f.position.map(|p| dot(p, normal)).unwrap_or(f.frame as f64);
    if positioned {
        frames.sort_by(|a, b| along(a).total_cmp(&along(b)));
    }

    let [row_spacing, col_spacing] = first.pixel_spacing.unwrap_or_else(|| {
        notes.push("no PixelSpacing: 1 mm assumed".to_string());
        [1.0, 1.0]
    });
    let n = frames.len();
    let origin = frames[0].position.unwrap_or([0.0; 3]);
    // The slice step vector: from the positions when there are several, else the normal
    // times SpacingBetweenSlices / SliceThickness (or 1 mm).
    let mut slice_vec = {
        let s = first.slice_spacing.unwrap_or(1.0);
        [normal[0] * s, normal[1] * s, normal[2] * s]
    };
    let mut resample_to: Option<(f64, Vec<f64>)> = None;
    if n > 1 && positioned {
        let d: Vec<f64> = frames.iter().map(along).collect();
        let gaps: Vec<f64> = d.windows(2).map(|w| w[1] - w[0]).collect();
        let mut sorted = gaps.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        if let Some(i) = gaps.iter().position(|&g| g.abs() < 1e-4) {
            let f = &frames[i + 1];
            return Err(FormatError::invalid(
                &infos[f.file].path,
                format!("two slices share position {:.4} mm along the normal (duplicates, or several volumes in one series)", d[i]),
            ));
        }
        let tol = (0.01 * median).max(1e-3);
        let uniform = gaps.iter().all(|g| (g - median).abs() <= tol);
        if !uniform {
            let (i, g) = gaps.iter().enumerate().max_by(|a, b| (a.1 - median).abs().total_cmp(&(b.1 - median).abs())).unwrap();
            let what = if *g > 1.5 * median {
                let missing = (g / median).round() as i64 - 1;
                format!(
                    "{missing} slice(s) missing between {:.3} and {:.3} mm along the normal (gap {g:.3} mm, usual {median:.3} mm)",
                    d[i],
                    d[i + 1]
                )
            } else {
                format!(
                    "non-uniform slice spacing: gap {g:.3} mm between {:.3} and {:.3} mm along the normal, usual {median:.3} mm",
                    d[i],
                    d[i + 1]
                )
            };
            if !opts.resample {
                return Err(FormatError::invalid(src, format!("{what}; pass --resample to resample to uniform spacing")));
            }
            // Every gap off the usual one, as a range, and the spacing chosen.
            let off: Vec<f64> = gaps.iter().copied().filter(|g| (g - median).abs() > tol).collect();
            let (lo, hi) = off.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &g| (lo.min(g), hi.max(g)));
            let range = if off.len() == 1 {
                format!("1 gap off the usual ({lo:.3} mm)")
            } else {
                format!("{} gaps off the usual, {lo:.3} to {hi:.3} mm", off.len())
            };
            notes.push(format!(
                "{what}; {range}; resampled to uniform {median:.4} mm spacing (the median gap) over {:.3} to {:.3} mm",
                d[0],
                d[d.len() - 1]
            ));
            resample_to = Some((median, d.clone()));
        }
        let last = frames[n - 1].position.unwrap();
        let span = sub(last, origin);
        let steps = match &resample_to {
            Some((s, d)) => (d[n - 1] - d[0]) / s,
            None => (n - 1) as f64,
        };
        slice_vec = [span[0] / steps, span[1] / steps, span[2] / steps];
        let tilt = 1.0 - dot(slice_vec, normal).abs() / dot(slice_vec, slice_vec).sqrt();
        if tilt > 1e-4 {
            notes.push("slices are offset in-plane (gantry tilt): the affine is sheared to keep their true positions".to_string());
        }
    }

    // Affine in LPS, then to RAS by negating x and y.
    let mut affine: Affine = [[0.0; 4]; 4];
    for r in 0..3 {
        affine[r][0] = row_dir[r] * col_spacing;
        affine[r][1] = col_dir[r] * row_spacing;
        affine[r][2] = slice_vec[r];
        affine[r][3] = origin[r];
    }
    affine[3][3] = 1.0;
    for row in affine.iter_mut().take(2) {
        for v in row.iter_mut() {
            *v = -*v;
        }
    }

    let ty = scalar_type(first);
    let (rows, cols) = (first.rows as usize, first.columns as usize);
    let plane = rows * cols;
    let frame_bytes = plane * ty.size();
    // One rescale for all slices keeps the stored type; differing ones force real values,
    // which each file's frames are turned into as they are decoded (so the stored-type
    // volume is never held beside the real-valued one).
    let slice_rescale: Vec<Rescale> =
        frames.iter().map(|f| infos[f.file].frame_rescale.get(f.frame).copied().unwrap_or(infos[f.file].rescale)).collect();
    let per_slice = slice_rescale.iter().any(|r| r != &slice_rescale[0]);
    let mut rescale = slice_rescale[0];
    let out_ty = if per_slice { ScalarType::F32 } else { ty };
    let what = if per_slice { "real-valued volume (the rescale differs between slices)" } else { "DICOM volume" };
    let volume = limits.check(src, what, &[cols as u64, rows as u64, n as u64, out_ty.size() as u64])? as u64;
    // Each thread decoding a file holds its data set (dicom-rs reads a file whole, pixel
    // data included), the decoded frames and their copy — and for compressed pixel data
    // the decoder's own buffers, measured at up to twice the frames more (JPEG Lossless
    // decodes to 16-bit samples, then to bytes): counted with the volume.
    let threads = rayon::current_num_threads().min(infos.len()).max(1) as u64;
    let per_file = infos
        .iter()
        .map(|i| {
            let on_disk = std::fs::metadata(&i.path).map(|m| m.len()).unwrap_or(0);
            let decoded =
                i.rows as u64 * i.columns as u64 * i.frames as u64 * i.samples_per_pixel as u64 * (i.bits_allocated as u64).div_ceil(8);
            let native = [uids::IMPLICIT_VR_LITTLE_ENDIAN, uids::EXPLICIT_VR_LITTLE_ENDIAN, crate::dicom_scan::EXPLICIT_VR_BIG_ENDIAN];
            let copies = if native.contains(&i.transfer_syntax.as_str()) { 2 } else { 4 };
            // OpenJPEG's working state, whatever the image's size (measured 1.3 MiB for a
            // 64 × 64 frame).
            let jpeg2000 =
                i.transfer_syntax.starts_with("1.2.840.10008.1.2.4.9") || i.transfer_syntax.starts_with("1.2.840.10008.1.2.4.20");
            let workspace = if jpeg2000 { 2 << 20 } else { 0 };
            on_disk.saturating_add(decoded.saturating_mul(copies)).saturating_add(workspace)
        })
        .max()
        .unwrap_or(0);
    limits.check(src, &format!("{what} with the files being decoded"), &[volume.saturating_add(threads.saturating_mul(per_file))])?;
    let mut data = VoxelData::zeroed(out_ty, plane * n);
    let out_frame_bytes = plane * out_ty.size();

    // Decode files in parallel; each file's frames are copied to their sorted slots as soon
    // as it is decoded and its buffer freed, so the series needs the volume plus one decoded
    // file per thread (it held a copy of every file until all were decoded: twice the volume).
    let mut slot_of: Vec<Vec<(usize, usize)>> = vec![Vec::new(); infos.len()];
    for (slot, f) in frames.iter().enumerate() {
        slot_of[f.file].push((f.frame, slot));
    }
    let slots = std::sync::Mutex::new(data.as_bytes_mut());
    infos.par_iter().enumerate().try_for_each(|(fi, info)| -> Result<()> {
        let file_bytes = decode_frames(info, limits)?;
        let frame = |k: usize| &file_bytes[k * frame_bytes..(k + 1) * frame_bytes];
        // Real values in native order, converted before the lock is taken.
        let real: Vec<Vec<f32>> = if per_slice {
            slot_of[fi]
                .iter()
                .map(|&(k, slot)| {
                    let stored = VoxelData::from_bytes(ty, frame(k), false);
                    (0..plane).map(|i| slice_rescale[slot].apply(stored.stored(i)) as f32).collect()
                })
                .collect()
        } else {
            Vec::new()
        };
        let mut bytes = slots.lock().unwrap_or_else(|e| e.into_inner());
        for (j, &(k, slot)) in slot_of[fi].iter().enumerate() {
            let to = &mut bytes[slot * out_frame_bytes..(slot + 1) * out_frame_bytes];
            match real.get(j) {
                Some(values) => to.copy_from_slice(bytemuck::cast_slice(values)),
                None => to.copy_from_slice(frame(k)),
            }
        }
        Ok(())
    })?;
    if per_slice {
        rescale = Rescale::IDENTITY;
        notes.push("rescale differs between slices: real-world values stored as f32".to_string());
    } else {
        // decode_frames yields little-endian samples.
        data.fix_byte_order(false);
    }
    let mut depth = n;
    if let Some((spacing, d)) = resample_to {
        limits.check(src, "resampled volume", &[(cols * rows) as u64, ((d[n - 1] - d[0]) / spacing) as u64 + 1, 4])?;
        let (vals, k) = resample_uniform(&data, rescale, rows * cols, &d, spacing);
        data = VoxelData::F32(vals);
        rescale = Rescale::IDENTITY;
        depth = k;
    }
    if first.samples_per_pixel == 3 {
        notes.push("colour image converted to luminance (BT.601)".to_string());
    }
    if let Some(n) = &first.read_note {
        notes.push(n.clone());
    }
    if let Some((_, how)) = &first.suv_bw {
        notes.push(how.clone());
    }
    if first.photometric == "MONOCHROME1" {
        notes.push("MONOCHROME1: low values display bright; values kept as stored".to_string());
    }
    notes.insert(0, format!("DICOM {} file(s), {} slice(s), transfer syntax {}", infos.len(), n, first.transfer_syntax));
    let spacing = spacing_of(&affine);
    if affine.iter().flatten().any(|v| !v.is_finite()) || spacing.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(FormatError::invalid(src, format!("positions and orientations give no valid geometry (voxel spacing {spacing:?})")));
    }
    Ok(Volume {
        dims: [cols, rows, depth],
        spacing,
        affine,
        data,
        rescale,
        modality: Some(first.modality.clone()).filter(|m| !m.is_empty()),
        units: first.units.clone(),
        suv_bw: first.suv_bw.as_ref().map(|(f, _)| *f),
        volume_count: 1,
        volume_index: 0,
        notes,
        attributes: first.attributes.clone(),
    })
}

fn show_orientation(o: Option<[f64; 6]>) -> String {
    match o {
        Some(v) => format!("[{}]", v.iter().map(|x| format!("{x:.4}")).collect::<Vec<_>>().join(", ")),
        None => "none".to_string(),
    }
}

fn orientation_close(a: Option<[f64; 6]>, b: Option<[f64; 6]>) -> bool {
    match (a, b) {
        (Some(a), Some(b)) => a.iter().zip(b.iter()).all(|(x, y)| (x - y).abs() < 1e-4),
        (None, None) => true,
        _ => false,
    }
}

/// Linear interpolation of slices at positions `d` (sorted, mm along the normal) onto a
/// uniform grid starting at d[0] with the given spacing. Returns real-world values.
fn resample_uniform(data: &VoxelData, rescale: Rescale, plane: usize, d: &[f64], spacing: f64) -> (Vec<f32>, usize) {
    let total = d[d.len() - 1] - d[0];
    let k = (total / spacing + 1e-6).floor() as usize + 1;
    let mut out = vec![0f32; plane * k];
    let mut lo = 0;
    for z in 0..k {
        let t = d[0] + z as f64 * spacing;
        while lo + 2 < d.len() && d[lo + 1] < t {
            lo += 1;
        }
        let w = ((t - d[lo]) / (d[lo + 1] - d[lo])).clamp(0.0, 1.0);
        for p in 0..plane {
            let a = rescale.apply(data.stored(lo * plane + p));
            let b = rescale.apply(data.stored((lo + 1) * plane + p));
            out[z * plane + p] = (a + w * (b - a)) as f32;
        }
    }
    (out, k)
}

#[cfg(test)]
mod units_tests {
    use super::*;
    use dicom_core::{DataElement, PrimitiveValue, VR};

    fn with_units(u: &str) -> Obj {
        let mut o = Obj::new_empty();
        o.put(DataElement::new(tags::UNITS, VR::CS, PrimitiveValue::from(u)));
        o
    }

    #[test]
    fn pet_units_are_named_as_people_read_them() {
        assert_eq!(units_for(&with_units("BQML"), "PT").as_deref(), Some("Bq/ml"));
        assert_eq!(units_for(&with_units("GML"), "PT").as_deref(), Some("SUVbw g/ml"));
        assert_eq!(units_for(&with_units("CNTS"), "NM").as_deref(), Some("CNTS"));
        assert_eq!(units_for(&Obj::new_empty(), "CT").as_deref(), Some("HU"));
    }
}
