//! volterra: medical and scientific visualization. The file readers and writers live in
//! the `volterra-formats` crate; this crate holds the scene graph, the renderers and the
//! command-line tool.

pub mod compare;
pub mod info;

pub use volterra_formats as formats;
pub mod scene;
pub mod render;
pub mod samples;
