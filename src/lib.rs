//! volterra: medical and scientific visualization. The file readers and writers live in
//! the `volterra-formats` crate; this crate holds the scene graph, the renderers and image
//! comparison. The viewer (`volterra-view`) and the command line with its benchmarks
//! (`volterra-cli`) are crates of their own, so the library needs no UI or CLI crates.
//! ARCHITECTURE.md is the map.

// Matrix and grid code indexes several arrays by the same loop variable; iterators would hide that.
#![allow(clippy::needless_range_loop)]

pub mod catalog;
pub mod colormap;
pub mod compare;
pub mod dem;
pub mod geometry;
pub mod gpu;
pub mod info;

pub use volterra_formats as formats;
pub mod render;
pub mod samples;
pub mod scene;
pub mod settings;
pub mod shared_error;
