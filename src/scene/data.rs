//! A scene's data, read lazily: a node's file is read (and kept) only when a renderer asks
//! for it; a heightfield's GeoTIFF may be read row by row instead; a time series' steps
//! one at a time.

use super::*;

/// The heights of a heightfield node as a renderer takes them: the heightfield held, or
/// its GeoTIFF read row by row, by windows of tiles or strips, into the renderer's store.
#[derive(Clone)]
pub enum TerrainData {
    Held(Arc<Heightfield>),
    Rows(Arc<GeoTiffRows>),
}

impl TerrainData {
    /// Where the samples lie.
    pub fn georef(&self) -> GridGeoref {
        match self {
            TerrainData::Held(hf) => hf.georef(),
            TerrainData::Rows(rows) => rows.georef().clone(),
        }
    }

    /// What identifies these heights while they are held (for caches of work on them).
    pub fn address(&self) -> usize {
        match self {
            TerrainData::Held(hf) => Arc::as_ptr(hf) as usize,
            TerrainData::Rows(rows) => Arc::as_ptr(rows) as usize,
        }
    }

    /// What the reader noted of the raster (an overview read instead of the full raster,
    /// degrees converted to metres, …).
    pub fn notes(&self) -> &[String] {
        match self {
            TerrainData::Held(hf) => &hf.notes,
            TerrainData::Rows(rows) => &rows.notes,
        }
    }

    /// Why rows could not be read (a chunk of the GeoTIFF that failed to decode), if so.
    pub fn failure(&self) -> Option<String> {
        match self {
            TerrainData::Held(_) => None,
            TerrainData::Rows(rows) => rows.failure(),
        }
    }

    /// The bilinear surface height at (x, y) metres east and north of the south-west
    /// sample (see `Heightfield::surface_height`).
    pub fn surface_height(&self, x: f64, y: f64) -> Option<f64> {
        match self {
            TerrainData::Held(hf) => hf.surface_height(x, y),
            TerrainData::Rows(rows) => rows.surface_height(x, y),
        }
    }
}

/// A node's data, loaded on first use.
#[derive(Debug, Clone)]
pub enum NodeData {
    Volume(Arc<Volume>),
    Heightfield(Arc<Heightfield>),
    Particles(Arc<ParticleSet>),
}

impl From<Dataset> for NodeData {
    fn from(d: Dataset) -> NodeData {
        match d {
            Dataset::Volume(v) => NodeData::Volume(Arc::new(v)),
            Dataset::Heightfield(h) => NodeData::Heightfield(Arc::new(h)),
            Dataset::Particles(p) => {
                // Particles at positions that are not finite are left out (the reader's
                // note says how many); renderers need mass, h and density: fill the
                // documented defaults.
                let mut p = p.drawable();
                volterra_formats::sph::fill_defaults(&mut p);
                NodeData::Particles(Arc::new(p))
            }
        }
    }
}

impl NodeData {
    pub fn kind(&self) -> NodeKind {
        match self {
            NodeData::Volume(_) => NodeKind::Volume,
            NodeData::Heightfield(_) => NodeKind::Heightfield,
            NodeData::Particles(_) => NodeKind::Particles,
        }
    }
}

impl Scene {
    /// The node's data, read on first call and cached.
    pub fn data(&self, node: usize) -> Result<NodeData> {
        let cell = &self.data[node];
        cell.get_or_init(|| self.read_node(node).map_err(SharedError::new)).clone().map_err(anyhow::Error::new)
    }

    /// Step `k` of node `node`'s series, read now and not kept (a pass over a whole series
    /// holds one step at a time), as the renderers take it.
    pub fn step_data(&self, node: usize, k: usize) -> Result<NodeData> {
        let (path, opts) = self.load_plan_at(node, Some(k))?;
        Ok(NodeData::from(volterra_formats::load(&path, &opts)?))
    }

    /// The file node `node` reads (its series' step now, where it has one) and how.
    pub(super) fn load_plan(&self, node: usize) -> Result<(PathBuf, LoadOptions)> {
        self.load_plan_at(node, self.step(node))
    }

    /// The file node `node` reads at step `step` of its series (None: no series) and how.
    pub(super) fn load_plan_at(&self, node: usize, step: Option<usize>) -> Result<(PathBuf, LoadOptions)> {
        let n = &self.file.nodes[node];
        let mut path = self.base_dir.join(n.file.as_ref().ok_or_else(|| anyhow!("node '{}' has no file", n.name))?);
        let mut opts = LoadOptions { limits: self.limits, ..LoadOptions::default() };
        opts.dicom.series = n.series.clone();
        opts.dicom.resample = n.resample;
        opts.nifti.volume_index = n.volume_index;
        if let (Some(s), Some(k)) = (&self.series[node], step) {
            let step = s.steps.get(k).ok_or_else(|| anyhow!("node '{}': its series has {} steps, not {}", n.name, s.steps.len(), k + 1))?;
            path = step.file.clone();
            opts.nifti.volume_index = step.volume_index.unwrap_or(n.volume_index);
        }
        if let Some(p) = &n.png {
            opts.png = p.clone();
        }
        if let Some(extent) = n.extent {
            if volterra_formats::detect(&path)? != volterra_formats::FileKind::GeoTiff {
                bail!("{}: node '{}': extent needs a georeferenced raster (a GeoTIFF)", path.display(), n.name);
            }
            opts.geotiff.extent = Some(extent);
        }
        if let Some(w) = &self.view_windows[node] {
            opts.geotiff.extent = Some(w.extent);
            opts.geotiff.level = Some(w.level);
        }
        if let Some(a) = &n.arrays {
            opts.particles = a.clone();
        }
        Ok((path, opts))
    }

    pub(super) fn read_node(&self, node: usize) -> Result<NodeData> {
        let n = &self.file.nodes[node];
        let (path, opts) = self.load_plan(node)?;
        let d = match volterra_formats::load(&path, &opts) {
            // A folder of several series: the node's own key chooses, not a CLI flag.
            Err(e) if e.kind == volterra_formats::ErrorKind::Ambiguous && path.is_dir() => {
                let list = volterra_formats::dicom::list_series(&path, &self.limits)?;
                let which = if n.series.is_some() { "matches none or several of them" } else { "names none of them" };
                bail!(
                    "{}: node '{}': the folder holds {} series and the node's series = … {which}; give series = N (the number) or its UID: {}",
                    path.display(),
                    n.name,
                    list.len(),
                    volterra_formats::dicom::series_listing(&list)
                );
            }
            r => r?,
        };
        let data = NodeData::from(d);
        if data.kind() != n.kind {
            bail!("{}: node '{}' is a {:?} node but the file holds other data", path.display(), n.name, n.kind);
        }
        Ok(data)
    }

    /// The heights of heightfield node `node` as its renderer takes them. The GPU
    /// ray-caster copies them into textures of its own: for it a GeoTIFF is opened to be
    /// read row by row (at the finest level whose window fits the memory limit at the
    /// textures' bytes a sample), so the heights are held once, there, not twice. Held
    /// otherwise: for other renderers, other files, and where the heightfield is held
    /// already (read for another use).
    pub fn terrain_data(&self, node: usize) -> Result<TerrainData> {
        if let Some(Ok(NodeData::Heightfield(hf))) = self.data[node].get() {
            return Ok(TerrainData::Held(hf.clone()));
        }
        let n = &self.file.nodes[node];
        if n.kind != NodeKind::Heightfield {
            bail!("node '{}' is not a heightfield", n.name);
        }
        let (path, opts) = self.load_plan(node)?;
        let Some(held_by_renderer) = self.renderer(node).and_then(|r| r.heights_held) else {
            return self.heightfield(node).map(TerrainData::Held);
        };
        if volterra_formats::detect(&path)? != volterra_formats::FileKind::GeoTiff {
            return self.heightfield(node).map(TerrainData::Held);
        }
        let rows = self.height_rows[node]
            .get_or_init(|| {
                GeoTiffRows::open_holding(&path, &opts.geotiff, &self.limits, &held_by_renderer)
                    .map(Arc::new)
                    .map_err(|e| SharedError::new(e.into()))
            })
            .clone()
            .map_err(anyhow::Error::new)?;
        Ok(TerrainData::Rows(rows))
    }

    pub fn volume(&self, node: usize) -> Result<Arc<Volume>> {
        match self.data(node)? {
            NodeData::Volume(v) => Ok(v),
            _ => bail!("node '{}' is not a volume", self.file.nodes[node].name),
        }
    }

    pub fn heightfield(&self, node: usize) -> Result<Arc<Heightfield>> {
        match self.data(node)? {
            NodeData::Heightfield(h) => Ok(h),
            _ => bail!("node '{}' is not a heightfield", self.file.nodes[node].name),
        }
    }

    pub fn particles(&self, node: usize) -> Result<Arc<ParticleSet>> {
        match self.data(node)? {
            NodeData::Particles(p) => Ok(p),
            _ => bail!("node '{}' is not a particle set", self.file.nodes[node].name),
        }
    }

    /// The node's draped image, if it names one or was given one (`provide_texture`).
    pub fn texture(&self, node: usize) -> Result<Option<Arc<drape::Drape>>> {
        let desc = &self.file.nodes[node];
        let Some(t) = &desc.texture else {
            return Ok(self.textures[node].get().and_then(|r| r.as_ref().ok()).cloned());
        };
        let path = self.base_dir.join(t);
        let band = (desc.texture_colormap.is_some() || desc.texture_range.is_some()).then(|| drape::BandColours {
            colormap: desc
                .texture_colormap
                .as_deref()
                .and_then(crate::colormap::Colormap::from_name)
                .unwrap_or(crate::colormap::Colormap::Grey),
            range: desc.texture_range,
        });
        let r = self.textures[node]
            .get_or_init(|| drape::Drape::load(&path, band, &self.limits).map(Arc::new).map_err(SharedError::new))
            .clone();
        r.map(Some).map_err(anyhow::Error::new)
    }

    /// A volume node's value statistics (read and counted once).
    pub fn value_stats(&self, node: usize) -> Result<Arc<presets::ValueStats>> {
        if let Some(s) = self.stats[node].get() {
            return Ok(s.clone());
        }
        let NodeData::Volume(v) = self.data(node)? else { bail!("node '{}' is not a volume", self.file.nodes[node].name) };
        Ok(self.stats[node].get_or_init(|| Arc::new(presets::ValueStats::of(&v))).clone())
    }

    /// Gives a node data already read (a viewer that opened a data file read it to build
    /// the scene). Does nothing if the node's data is already there.
    pub fn provide_data(&self, node: usize, data: NodeData) {
        let _ = self.data[node].set(Ok(data));
    }

    /// Gives a heightfield node that names no texture a drape held in memory (an image
    /// from Python); it is kept across edits as a texture read from a file is.
    pub fn provide_texture(&self, node: usize, drape: Arc<drape::Drape>) -> Result<()> {
        let desc = &self.file.nodes[node];
        if desc.kind != NodeKind::Heightfield || desc.texture.is_some() {
            bail!("node '{}': a drape in memory is for a heightfield node that names no texture", desc.name);
        }
        self.textures[node].set(Ok(drape)).map_err(|_| anyhow!("node '{}' has a drape already", desc.name))
    }

    /// The data read so far, node by node (for caches that keep work per data set).
    pub fn loaded_data(&self) -> impl Iterator<Item = NodeData> + '_ {
        self.data.iter().filter_map(|c| c.get().and_then(|r| r.as_ref().ok()).cloned())
    }

    /// The addresses of the GeoTIFFs opened to be read row by row (`terrain_data`), for the
    /// same caches.
    pub fn opened_height_rows(&self) -> impl Iterator<Item = usize> + '_ {
        self.height_rows.iter().filter_map(|c| c.get().and_then(|r| r.as_ref().ok()).map(|r| Arc::as_ptr(r) as usize))
    }

    /// True if the node's data has been read (for tests of lazy loading).
    pub fn is_loaded(&self, node: usize) -> bool {
        self.data[node].get().is_some()
    }

    /// True if the node's data has been read, or its GeoTIFF opened to be read by rows.
    pub fn is_opened(&self, node: usize) -> bool {
        self.is_loaded(node) || self.height_rows[node].get().is_some()
    }
}
