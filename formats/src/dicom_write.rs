//! A minimal DICOM series writer: one single-frame CT Image Storage file per slice,
//! Explicit VR Little Endian, 16-bit, with the geometry of the volume's affine (RAS+
//! converted back to LPS) and its rescale. volterra uses it to make test series and
//! benchmark inputs of any size; it is not a general DICOM exporter.

use crate::error::{FormatError, Result};
use crate::volume::{Volume, VoxelData};
use dicom_core::{DataElement, PrimitiveValue, VR};
use dicom_dictionary_std::tags;
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
use std::path::Path;

fn ds(values: &[f64]) -> PrimitiveValue {
    PrimitiveValue::from(values.iter().map(|v| format!("{v}")).collect::<Vec<_>>().join("\\"))
}

/// Writes `vol` (u16 or i16) as `dir/IMG#####.dcm`, one file per k slice. `shuffle`
/// permutes the file names so readers must sort by position.
pub fn write_series(dir: &Path, vol: &Volume, series_uid: &str, shuffle: Option<u64>) -> Result<()> {
    let (signed, bytes): (bool, Vec<u8>) = match &vol.data {
        VoxelData::U16(_) => (false, vol.data.to_le_bytes()),
        VoxelData::I16(_) => (true, vol.data.to_le_bytes()),
        _ => return Err(FormatError::unsupported(dir, "the series writer takes 16-bit volumes")),
    };
    std::fs::create_dir_all(dir).map_err(|e| FormatError::io(dir, e))?;
    let [nx, ny, nz] = vol.dims;
    let a = &vol.affine;
    // RAS → LPS: negate x and y rows.
    let col = |c: usize| [-a[0][c], -a[1][c], a[2][c]];
    let (ci, cj, ck) = (col(0), col(1), col(2));
    let (si, sj) = (vol.spacing[0], vol.spacing[1]);
    let iop = [ci[0] / si, ci[1] / si, ci[2] / si, cj[0] / sj, cj[1] / sj, cj[2] / sj];
    let origin = [-a[0][3], -a[1][3], a[2][3]];
    let mut names: Vec<usize> = (0..nz).collect();
    if let Some(seed) = shuffle {
        let mut rng = crate::rng::SplitMix64(seed);
        for i in (1..nz).rev() {
            names.swap(i, rng.below(i + 1));
        }
    }
    let plane = nx * ny * 2;
    for k in 0..nz {
        let ipp = [origin[0] + k as f64 * ck[0], origin[1] + k as f64 * ck[1], origin[2] + k as f64 * ck[2]];
        let sop_uid = format!("{series_uid}.{}", k + 1);
        let mut obj = InMemDicomObject::new_empty();
        let mut put = |tag, vr, v: PrimitiveValue| {
            obj.put(DataElement::new(tag, vr, v));
        };
        put(tags::SOP_CLASS_UID, VR::UI, PrimitiveValue::from("1.2.840.10008.5.1.4.1.1.2"));
        put(tags::SOP_INSTANCE_UID, VR::UI, PrimitiveValue::from(sop_uid.as_str()));
        put(tags::MODALITY, VR::CS, PrimitiveValue::from(vol.modality.clone().unwrap_or_else(|| "CT".into()).as_str()));
        put(tags::STUDY_INSTANCE_UID, VR::UI, PrimitiveValue::from(format!("{series_uid}.0").as_str()));
        put(tags::SERIES_INSTANCE_UID, VR::UI, PrimitiveValue::from(series_uid));
        put(tags::INSTANCE_NUMBER, VR::IS, PrimitiveValue::from(format!("{}", k + 1).as_str()));
        put(tags::IMAGE_POSITION_PATIENT, VR::DS, ds(&ipp));
        put(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, ds(&iop));
        put(tags::PIXEL_SPACING, VR::DS, ds(&[sj, si]));
        put(tags::SLICE_THICKNESS, VR::DS, ds(&[vol.spacing[2]]));
        put(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16));
        put(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, PrimitiveValue::from("MONOCHROME2"));
        put(tags::ROWS, VR::US, PrimitiveValue::from(ny as u16));
        put(tags::COLUMNS, VR::US, PrimitiveValue::from(nx as u16));
        put(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(16u16));
        put(tags::BITS_STORED, VR::US, PrimitiveValue::from(16u16));
        put(tags::HIGH_BIT, VR::US, PrimitiveValue::from(15u16));
        put(tags::PIXEL_REPRESENTATION, VR::US, PrimitiveValue::from(signed as u16));
        put(tags::RESCALE_SLOPE, VR::DS, ds(&[vol.rescale.slope]));
        put(tags::RESCALE_INTERCEPT, VR::DS, ds(&[vol.rescale.intercept]));
        put(tags::PIXEL_DATA, VR::OW, PrimitiveValue::from(bytes[k * plane..(k + 1) * plane].to_vec()));
        let meta = FileMetaTableBuilder::new()
            .transfer_syntax("1.2.840.10008.1.2.1")
            .media_storage_sop_class_uid("1.2.840.10008.5.1.4.1.1.2")
            .media_storage_sop_instance_uid(sop_uid.as_str());
        let file = obj.with_meta(meta).map_err(|e| FormatError::invalid(dir, format!("cannot build DICOM meta: {e}")))?;
        let path = dir.join(format!("IMG{:05}.dcm", names[k]));
        // Encoded in memory, then written under a temporary name and renamed (crate::atomic).
        let mut bytes = Vec::new();
        file.write_all(&mut bytes).map_err(|e| FormatError::invalid(&path, format!("cannot write DICOM: {e}")))?;
        crate::atomic::write_bytes_atomically(&path, &bytes)?;
    }
    Ok(())
}
