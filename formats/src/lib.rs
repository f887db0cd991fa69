//! volterra-formats: readers and writers that turn files into plain data — [`Volume`],
//! [`Heightfield`], [`ParticleSet`], images — with metadata and units. Nothing here knows
//! about rendering.

// Matrix and grid code indexes several arrays by the same loop variable; iterators would hide that.
#![allow(clippy::needless_range_loop)]

pub mod atomic;
mod cog_write;
pub mod dicom;
mod dicom_jpeg12;
mod dicom_rle;
mod dicom_scan;
pub mod dicom_write;
pub mod error;
pub mod exr_io;
pub mod gdal_sidecar;
pub mod geojson;
pub mod geotiff;
pub mod geotiff_rows;
pub mod geotiff_write;
pub mod guard;
pub mod heightfield;
pub mod image;
pub mod kdtree;
pub mod memory;
pub mod metaimage;
pub mod nifti;
pub mod nrrd;
pub mod overview;
pub mod particles;
pub mod png_height;
pub mod projection;
pub mod raw;
pub mod rng;
pub mod series;
pub mod sph;
mod tiff_lzw;
pub mod volume;
pub mod vtk;
pub mod vtk_image;
pub mod vtk_legacy;
pub mod vtk_xml;

pub use error::{ErrorKind, FormatError, Result};
pub use memory::Limits;
pub use volume::{Affine, Rescale, ScalarType, Volume, VoxelData};

pub use exr_io::FloatImage;
pub use heightfield::{Crs, GridUnits, Heightfield, NodataMask};
pub use image::RgbImage;
pub use particles::{ParticleArrayNames, ParticleSet, PointArray};

mod load;
pub use load::*;

/// (min, max) of the finite values (None: there are none).
pub fn finite_range(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values.into_iter().filter(|x| x.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
    (lo <= hi).then_some((lo, hi))
}
