//! The scene graph and the scene file (TOML; documented in docs/scene-format.md).
//!
//! A scene is parsed once into plain objects ([`SceneFile`]), checked, and then holds its
//! data lazily: a node's file is read (and cached) only when a renderer asks for it, so a
//! render loads exactly the nodes it draws.
//!
//! Here: `Scene` itself and what it holds; `load` reading and checking a scene, `file` the
//! scene file's plain objects, `parse` reading its text (one-line errors, `--set`
//! overrides), `data` the nodes' data read lazily, `time` the scene at one time, `views`
//! its cameras and what they see, `classification` a volume node's preset, transfer
//! function, cropping and shading.

pub mod animation;
pub mod auto;
pub mod camera;
mod classification;
pub mod crop;
mod data;
pub mod drape;
mod file;
mod load;
pub mod measurement;
mod parse;
pub mod presets;
mod time;
pub mod transfer;
pub mod view_window;
mod views;

pub use camera::{Camera, Ray, RayGenerator};
pub use crop::{ClipPlane, CropBox, HalfSpace};
pub use data::{NodeData, TerrainData};
pub use file::*;
pub use measurement::{Measurement, MeasurementKind, SliceOverlay, SlicePlane, SliceViews};
pub use parse::apply_overrides;
use parse::*;
pub use transfer::{TransferFunction, VolumeShading};

use crate::catalog::{self, NodeSettings, RendererDecl};
use crate::shared_error::SharedError;
use anyhow::{anyhow, bail, Context, Result};
use glam::{DMat4, DVec3};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use volterra_formats::geotiff::HeldBytes;
use volterra_formats::geotiff_rows::GeoTiffRows;
use volterra_formats::heightfield::GridGeoref;
use volterra_formats::png_height::PngHeightOptions;
use volterra_formats::series::{self, TimeSeries};
use volterra_formats::{Dataset, Heightfield, Limits, LoadOptions, ParticleArrayNames, ParticleSet, Volume};

pub struct Scene {
    pub file: SceneFile,
    /// Directory the scene's relative paths start from.
    pub base_dir: PathBuf,
    /// Scene file path, for messages.
    pub source: PathBuf,
    world: Vec<DMat4>,
    /// Each node's renderer and its checked settings (None for groups).
    renderers: Vec<Option<(&'static RendererDecl, NodeSettings)>>,
    data: Vec<OnceLock<Result<NodeData, SharedError>>>,
    textures: Vec<OnceLock<Result<Arc<drape::Drape>, SharedError>>>,
    /// A heightfield node's GeoTIFF opened to be read row by row (see `terrain_data`).
    height_rows: Vec<OnceLock<Result<Arc<GeoTiffRows>, SharedError>>>,
    /// A volume node's value statistics, for its preset (computed on first use).
    stats: Vec<OnceLock<Arc<presets::ValueStats>>>,
    /// Each node's time series, where its `file` names one (found at load, no data read).
    series: Vec<Option<Arc<TimeSeries>>>,
    /// The animation time drawn (None: a still; series nodes draw their first step, a 4-D
    /// NIfTI its `volume_index`).
    time: Option<f64>,
    /// The memory limits handed to every reader of the scene's data and to every renderer's
    /// preparation (`--max-memory`).
    limits: Limits,
    /// Heightfield nodes read only where the renders' cameras see them (`with_views`).
    view_windows: Vec<Option<Arc<view_window::ViewWindow>>>,
}

impl Scene {
    /// The scene with `limits` for everything it reads and prepares from now on.
    pub fn with_limits(mut self, limits: Limits) -> Scene {
        self.limits = limits;
        self
    }

    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    pub fn nodes(&self) -> &[NodeDesc] {
        &self.file.nodes
    }

    /// The renderer that draws the node (None for groups).
    pub fn renderer(&self, node: usize) -> Option<&'static RendererDecl> {
        self.renderers[node].as_ref().map(|r| r.0)
    }

    /// The node's settings, checked and typed at load (None for groups).
    pub fn node_settings(&self, node: usize) -> Option<&NodeSettings> {
        self.renderers[node].as_ref().map(|r| &r.1)
    }

    /// Node-local → world transform (parents applied). A heightfield read in a view window
    /// (`with_views`) has its window's south-west sample at the origin: the window's
    /// placement in the node's frame comes first.
    pub fn world_transform(&self, node: usize) -> DMat4 {
        match &self.view_windows[node] {
            Some(w) => self.world[node] * w.placement(),
            None => self.world[node],
        }
    }

    pub fn node_index(&self, name: &str) -> Option<usize> {
        self.file.nodes.iter().position(|n| n.name == name)
    }

    /// World-space bounding box of a node's data as its renderer reads it (a heightfield's
    /// GeoTIFF by rows, not held: `terrain_data`), reading it on first use; None where
    /// nothing finite is there.
    pub fn bounds(&self, node: usize) -> Result<Option<(DVec3, DVec3)>> {
        let m = self.world_transform(node);
        match self.file.nodes[node].kind {
            NodeKind::Heightfield => Ok(auto::terrain_bounds(&self.terrain_data(node)?, m)),
            _ => Ok(auto::data_bounds(&self.data(node)?, m)),
        }
    }
}
