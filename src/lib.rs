//! volterra: medical and scientific visualization. The file readers and writers live in
//! the `volterra-formats` crate; this crate holds the scene graph, the renderers and the
//! command-line tool.

// Matrix and grid code indexes several arrays by the same loop variable; iterators would hide that.
#![allow(clippy::needless_range_loop)]

pub mod compare;
pub mod info;

pub use volterra_formats as formats;
pub mod bench;
pub mod bench_shear_warp;
pub mod bench_smoke;
pub mod bench_terrain;
pub mod progress;
pub mod render;
pub mod samples;
pub mod scene;
pub mod shared_error;
pub mod view;
