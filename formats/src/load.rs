//! One entry point that opens any supported file by what it is, not only by its name.

use crate::dicom::{self, DicomOptions};
use crate::error::{FormatError, Result};
use crate::memory::Limits;
use crate::nifti::{self, NiftiOptions};
use crate::png_height::{self, PngHeightOptions};
use crate::{geotiff, vtk, Heightfield, ParticleArrayNames, ParticleSet, Volume};
use std::path::Path;

/// What a file holds once read.
#[derive(Debug)]
pub enum Dataset {
    Volume(Volume),
    Heightfield(Heightfield),
    Particles(ParticleSet),
}

/// Every reader's options in one place; each reader looks only at its own, and all are
/// handed the same memory `limits`.
#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    pub nifti: NiftiOptions,
    pub dicom: DicomOptions,
    pub png: PngHeightOptions,
    pub geotiff: geotiff::GeoTiffOptions,
    pub particles: ParticleArrayNames,
    pub limits: Limits,
}

/// The kinds of file volterra reads, decided from the name and, where that is ambiguous,
/// the first bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileKind {
    Nifti,
    Dicom,
    DicomDir,
    GeoTiff,
    PngHeightmap,
    VtkLegacy,
    VtkXml,
    /// VTK XML ImageData (`.vti`).
    VtkImage,
    MetaImage,
    Nrrd,
}

pub fn detect(path: &Path) -> Result<FileKind> {
    if path.is_dir() {
        return Ok(FileKind::DicomDir);
    }
    if !path.exists() {
        return Err(FormatError::new(path, crate::ErrorKind::Io, "no such file"));
    }
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let kind = if name.ends_with(".nii") || name.ends_with(".nii.gz") || name.ends_with(".hdr") || name.ends_with(".hdr.gz") {
        FileKind::Nifti
    } else if name.ends_with(".tif") || name.ends_with(".tiff") {
        FileKind::GeoTiff
    } else if name.ends_with(".png") {
        FileKind::PngHeightmap
    } else if [".vtk", ".vtp", ".vtu", ".vti"].iter().any(|e| name.ends_with(e)) {
        vtk_kind(path, &name)?
    } else if name.ends_with(".mha") || name.ends_with(".mhd") {
        FileKind::MetaImage
    } else if name.ends_with(".nrrd") || name.ends_with(".nhdr") {
        FileKind::Nrrd
    } else if name.ends_with(".dcm") || dicom::looks_like_dicom(path) {
        FileKind::Dicom
    } else {
        return Err(FormatError::unsupported(
            path,
            "unknown file type (volterra reads .nii[.gz], .hdr/.img, DICOM files and directories, .mha/.mhd, .nrrd/.nhdr, .vti, .tif, .png, .vtk, .vtp, .vtu)",
        ));
    };
    Ok(kind)
}

/// Which VTK file a `.vtk`, `.vtp`, `.vtu` or `.vti` is, by its content (VTK's XML files
/// are often named `.vtk`): a legacy header, or the XML `VTKFile` element's type; by the
/// name where the content says neither.
fn vtk_kind(path: &Path, name: &str) -> Result<FileKind> {
    use std::io::Read;
    let mut head = Vec::new();
    std::fs::File::open(path).and_then(|f| f.take(1024).read_to_end(&mut head)).map_err(|e| FormatError::io(path, e))?;
    let text = String::from_utf8_lossy(&head);
    if text.starts_with("# vtk DataFile") {
        return Ok(FileKind::VtkLegacy);
    }
    if text.contains("<VTKFile") {
        return Ok(if text.contains("type=\"ImageData\"") { FileKind::VtkImage } else { FileKind::VtkXml });
    }
    Ok(if name.ends_with(".vtk") {
        FileKind::VtkLegacy
    } else if name.ends_with(".vti") {
        FileKind::VtkImage
    } else {
        FileKind::VtkXml
    })
}

pub fn load(path: &Path, opts: &LoadOptions) -> Result<Dataset> {
    Ok(match detect(path)? {
        FileKind::Nifti => Dataset::Volume(nifti::read_nifti(path, &opts.nifti, &opts.limits)?),
        FileKind::Dicom | FileKind::DicomDir => Dataset::Volume(dicom::read_dicom(path, &opts.dicom, &opts.limits)?),
        FileKind::GeoTiff => Dataset::Heightfield(geotiff::read_geotiff_with(path, &opts.geotiff, &opts.limits)?),
        FileKind::PngHeightmap => Dataset::Heightfield(png_height::read_png_heightmap(path, &opts.png, &opts.limits)?),
        FileKind::VtkLegacy => match crate::vtk_image::legacy_dataset(path)?.as_deref() {
            // Regular grids are volumes; point sets (POLYDATA, UNSTRUCTURED_GRID, the points of
            // a STRUCTURED_GRID) are particles.
            Some("STRUCTURED_POINTS" | "RECTILINEAR_GRID") => {
                Dataset::Volume(crate::vtk_image::read_structured_points(path, &opts.limits)?)
            }
            _ => Dataset::Particles(vtk::read_vtk_particles(path, &opts.particles, &opts.limits)?),
        },
        FileKind::VtkXml => Dataset::Particles(vtk::read_vtk_particles(path, &opts.particles, &opts.limits)?),
        FileKind::VtkImage => Dataset::Volume(crate::vtk_xml::read_vti(path, &opts.limits)?),
        FileKind::MetaImage => Dataset::Volume(crate::metaimage::read_metaimage(path, &opts.limits)?),
        FileKind::Nrrd => Dataset::Volume(crate::nrrd::read_nrrd(path, &opts.limits)?),
    })
}
