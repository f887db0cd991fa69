//! volterra-formats: readers and writers that turn files into plain data — [`Volume`],
//! [`Heightfield`], [`ParticleSet`], images — with metadata and units. Nothing here knows
//! about rendering.

pub mod atomic;
pub mod dicom;
pub mod error;
pub mod exr_io;
pub mod memory;
pub mod geotiff;
pub mod heightfield;
pub mod image;
pub mod nifti;
pub mod particles;
pub mod png_height;
pub mod vtk;
pub mod vtk_xml;
pub mod volume;

pub use error::{ErrorKind, FormatError, Result};
pub use volume::{Affine, Rescale, ScalarType, Volume, VoxelData};

pub use heightfield::{Crs, Heightfield};
pub use particles::{ParticleArrayNames, ParticleSet, PointArray};
pub use exr_io::FloatImage;
pub use image::RgbImage;

mod load;
pub use load::*;
