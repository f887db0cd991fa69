//! Loading a scene: its file read, checked whole (parents, transforms, every node's
//! renderer and settings through the catalogue, measurements) before any data is read.

use super::*;

impl Scene {
    /// Reads, checks and resolves a scene file; no data file is read yet.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Scene> {
        let text = std::fs::read_to_string(path).map_err(|e| anyhow!("{}: cannot read scene file: {e}", path.display()))?;
        // Parse the text as written first, so errors point at its lines.
        check_node_keys(&text, path)?;
        let _: SceneFile = parse_toml(&text, path)?;
        let lines = SettingLines::of(&text);
        let file: SceneFile = if overrides.is_empty() {
            parse_toml(&text, path)?
        } else {
            let mut doc: toml::Table = parse_toml(&text, path)?;
            apply_overrides(&mut doc, overrides)?;
            doc.try_into().map_err(|e: toml::de::Error| anyhow!("{}: after --set: {}", path.display(), one_line(e.message())))?
        };
        let base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Scene::from_file_with_lines(file, base_dir, path.to_path_buf(), &lines, None, Vec::new())
    }

    /// A scene from parsed objects (errors name no lines).
    pub fn from_file(file: SceneFile, base_dir: PathBuf, source: PathBuf) -> Result<Scene> {
        Scene::from_file_with_lines(file, base_dir, source, &SettingLines::default(), None, Vec::new())
    }

    /// A scene whose nodes without a file hold data given in memory (`given`, by node
    /// name: arrays handed over from Python), checked as a scene file is.
    pub fn from_memory(file: SceneFile, base_dir: PathBuf, source: PathBuf, given: Vec<(String, NodeData)>) -> Result<Scene> {
        Scene::from_file_with_lines(file, base_dir, source, &SettingLines::default(), None, given)
    }

    fn from_file_with_lines(
        file: SceneFile,
        base_dir: PathBuf,
        source: PathBuf,
        lines: &SettingLines,
        known_series: Option<&HashMap<PathBuf, Option<Arc<TimeSeries>>>>,
        given: Vec<(String, NodeData)>,
    ) -> Result<Scene> {
        let src = source.display().to_string();
        for (name, data) in &given {
            let Some(n) = file.nodes.iter().find(|n| &n.name == name) else {
                bail!("{src}: data given for '{name}', a node the scene lacks")
            };
            if n.file.is_some() {
                bail!("{src}: node '{name}' names a file and is given data too");
            }
            if data.kind() != n.kind {
                bail!("{src}: node '{name}' is a {:?} node and is given {:?} data", n.kind, data.kind());
            }
        }
        file.camera.validate().map_err(|m| anyhow!("{src}: {m}"))?;
        if !(file.image.exposure.is_finite() && file.image.exposure.abs() <= 30.0) {
            bail!("{src}: image exposure {} must be a number of stops in -30..30", file.image.exposure);
        }
        if file.image.width == 0 || file.image.height == 0 || file.image.width > 16384 || file.image.height > 16384 {
            bail!("{src}: image size {}×{} must be between 1 and 16384", file.image.width, file.image.height);
        }
        let mut index: HashMap<&str, usize> = HashMap::new();
        for (i, n) in file.nodes.iter().enumerate() {
            if index.insert(n.name.as_str(), i).is_some() {
                bail!("{src}: two nodes are named '{}'", n.name);
            }
            if n.kind != NodeKind::Group && n.file.is_none() && !given.iter().any(|g| g.0 == n.name) {
                bail!("{src}: node '{}' ({:?}) needs a file", n.name, n.kind);
            }
            if let Some(f) = &n.file {
                let p = base_dir.join(f);
                if !p.exists() && !series::is_series_name(&p) {
                    bail!("{src}: node '{}': data file {} not found", n.name, p.display());
                }
            }
            if let Some(tf) = &n.transfer_function {
                tf.validate().map_err(|m| anyhow!("{src}: node '{}': {m}", n.name))?;
            }
            if n.kind != NodeKind::Volume && (n.preset.is_some() || n.modality.is_some() || n.preset_shift != 0.0) {
                bail!("{src}: node '{}': preset, preset_shift and modality apply to volume nodes only", n.name);
            }
            if let Some(p) = &n.preset {
                presets::Preset::from_name(p).map_err(|m| anyhow!("{src}: node '{}': {m}", n.name))?;
                if n.transfer_function.is_some() {
                    bail!("{src}: node '{}': give a transfer_function or a preset, not both", n.name);
                }
            }
            if n.opacity_scale != 1.0 && n.kind != NodeKind::Volume {
                bail!("{src}: node '{}': opacity_scale applies to volume nodes only", n.name);
            }
            if !(n.opacity_scale.is_finite() && (0.0..=1000.0).contains(&n.opacity_scale)) {
                bail!("{src}: node '{}': opacity_scale {} must be between 0 and 1000", n.name, n.opacity_scale);
            }
            if !n.preset_shift.is_finite() {
                bail!("{src}: node '{}': preset_shift must be finite", n.name);
            }
            if let Some(m) = &n.modality {
                if presets::modality_code(m).is_none() {
                    let known: Vec<String> = presets::MODALITIES
                        .iter()
                        .map(|(code, names)| if names.is_empty() { code.to_string() } else { format!("{code} ({})", names.join(", ")) })
                        .collect();
                    bail!("{src}: node '{}': unknown modality '{m}' (known: {})", n.name, known.join(", "));
                }
            }
            if let Some(s) = &n.shading {
                if n.kind != NodeKind::Volume {
                    bail!("{src}: node '{}': shading applies to volume nodes only", n.name);
                }
                s.validate().map_err(|m| anyhow!("{src}: node '{}': {m}", n.name))?;
            }
            if let Some(e) = n.extent {
                if n.kind != NodeKind::Heightfield {
                    bail!("{src}: node '{}': extent applies to heightfield nodes only", n.name);
                }
                if !e.iter().all(|v| v.is_finite()) || e[0] >= e[2] || e[1] >= e[3] {
                    bail!("{src}: node '{}': extent {e:?} must be [west, south, east, north], west < east, south < north", n.name);
                }
            }
            if n.kind != NodeKind::Heightfield && (n.texture.is_some() || n.texture_colormap.is_some() || n.texture_range.is_some()) {
                bail!("{src}: node '{}': texture, texture_colormap and texture_range apply to heightfield nodes only", n.name);
            }
            if n.texture.is_none() && (n.texture_colormap.is_some() || n.texture_range.is_some()) {
                bail!("{src}: node '{}': texture_colormap and texture_range colour a texture, and the node has none", n.name);
            }
            if let Some(c) = &n.texture_colormap {
                if crate::colormap::Colormap::from_name(c).is_none() {
                    let names: Vec<&str> = crate::colormap::Colormap::ALL.iter().map(|c| c.name()).collect();
                    bail!("{src}: node '{}': unknown texture_colormap '{c}' (known: {})", n.name, names.join(", "));
                }
            }
            if let Some([lo, hi]) = n.texture_range {
                if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                    bail!("{src}: node '{}': texture_range [{lo}, {hi}] must be two finite values, low < high", n.name);
                }
            }
            if let Some([lo, hi]) = n.elevation_range {
                if n.kind != NodeKind::Heightfield {
                    bail!("{src}: node '{}': elevation_range applies to heightfield nodes only", n.name);
                }
                if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                    bail!("{src}: node '{}': elevation_range [{lo}, {hi}] must be two finite values, low < high", n.name);
                }
            }
            if n.kind != NodeKind::Particles && (n.color_by.is_some() || n.color_range.is_some()) {
                bail!("{src}: node '{}': color_by and color_range apply to particle nodes only", n.name);
            }
            if n.scale_over != ScaleOver::Series && n.kind != NodeKind::Particles {
                bail!("{src}: node '{}': scale_over applies to particle nodes only", n.name);
            }
            if let Some([lo, hi]) = n.color_range {
                if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                    bail!("{src}: node '{}': color_range [{lo}, {hi}] must be two finite values, the first smaller", n.name);
                }
            }
            if n.kind != NodeKind::Volume && (n.crop.is_some() || !n.clip.is_empty()) {
                bail!("{src}: node '{}': crop and clip apply to volume nodes only", n.name);
            }
            if let Some(c) = &n.crop {
                c.validate().map_err(|m| anyhow!("{src}: node '{}': {m}", n.name))?;
            }
            for c in &n.clip {
                c.validate().map_err(|m| anyhow!("{src}: node '{}': {m}", n.name))?;
            }
        }
        // Each node's renderer and settings, checked before any data file is read.
        let mut renderers = Vec::with_capacity(file.nodes.len());
        for n in &file.nodes {
            let decl = catalog::resolve(n.kind, n.renderer.as_deref(), &n.settings)
                .map_err(|m| anyhow!("{src}:{}: node '{}': {m}", lines.at(&n.name, None), n.name))?;
            renderers.push(match decl {
                None => None,
                Some(d) => Some((
                    d,
                    (d.parse)(&n.settings)
                        .map_err(|e| anyhow!("{src}:{}: node '{}': {} {e}", lines.at(&n.name, Some(&e.key)), n.name, d.name))?,
                )),
            });
        }
        for (k, m) in file.measurements.iter().enumerate() {
            let node = index.get(m.node.as_str()).ok_or_else(|| anyhow!("{src}: measurement {}: no node named '{}'", k + 1, m.node))?;
            if m.plane.is_some() && file.nodes[*node].kind != NodeKind::Volume {
                bail!("{src}: measurement {}: node '{}' is not a volume (slices are a volume's)", k + 1, m.node);
            }
            m.validate().map_err(|e| anyhow!("{src}: measurement {}: {e}", k + 1))?;
        }
        if let Some(v) = &file.slices {
            for name in std::iter::once(&v.node).chain(v.overlay.as_ref().map(|o| &o.node)) {
                let node = index.get(name.as_str()).ok_or_else(|| anyhow!("{src}: slices: no node named '{name}'"))?;
                if file.nodes[*node].kind != NodeKind::Volume {
                    bail!("{src}: slices: node '{name}' is not a volume");
                }
            }
            v.validate().map_err(|e| anyhow!("{src}: slices: {e}"))?;
        }
        if let Some(w) = &file.walk {
            let node = index.get(w.node.as_str()).ok_or_else(|| anyhow!("{src}: walk: no node named '{}'", w.node))?;
            if file.nodes[*node].kind != NodeKind::Heightfield {
                bail!("{src}: walk: node '{}' is not a heightfield", w.node);
            }
            if !(w.eye_height.is_finite() && w.eye_height >= 0.0) {
                bail!("{src}: walk: eye_height {} must be a non-negative number of metres", w.eye_height);
            }
        }
        if let Some(o) = &file.orbit {
            o.validate().map_err(|m| anyhow!("{src}: {m}"))?;
            if !file.keyframes.is_empty() {
                bail!("{src}: give [[keyframe]]s or an [orbit], not both");
            }
        }
        for (k, key) in file.keyframes.iter().enumerate() {
            let cam = Camera { position: key.position, focal_point: key.focal_point, ..file.camera.clone() };
            cam.validate().map_err(|m| anyhow!("{src}: keyframe {}: {m}", k + 1))?;
        }
        // World transforms, parents first; a cycle is an error.
        let mut world: Vec<Option<DMat4>> = vec![None; file.nodes.len()];
        for i in 0..file.nodes.len() {
            let mut chain = vec![i];
            let mut cur = i;
            while let Some(p) = &file.nodes[cur].parent {
                let pi =
                    *index.get(p.as_str()).ok_or_else(|| anyhow!("{src}: node '{}': parent '{p}' does not exist", file.nodes[cur].name))?;
                if chain.contains(&pi) {
                    bail!("{src}: node '{}': parents form a cycle", file.nodes[i].name);
                }
                chain.push(pi);
                cur = pi;
            }
            let mut m = DMat4::IDENTITY;
            for &c in chain.iter().rev() {
                let local = file.nodes[c].transform.to_mat4().with_context(|| format!("{src}: node '{}'", file.nodes[c].name))?;
                m *= local;
            }
            world[i] = Some(m);
        }
        // Time series, found from their names (a directory listing, a collection's XML or
        // a NIfTI header): no data is read.
        let mut found = Vec::with_capacity(file.nodes.len());
        for n in &file.nodes {
            let s = match (&n.file, known_series) {
                (None, _) => None,
                (Some(f), Some(known)) if known.contains_key(f) => known[f].clone(),
                (Some(f), _) => series::discover(&base_dir.join(f)).map_err(|e| anyhow!("{src}: node '{}': {e}", n.name))?.map(Arc::new),
            };
            if s.is_some() && n.kind == NodeKind::Heightfield {
                bail!("{src}: node '{}': a heightfield cannot be a time series", n.name);
            }
            found.push(s);
        }
        let n = file.nodes.len();
        let scene = Scene {
            file,
            base_dir,
            source,
            world: world.into_iter().map(Option::unwrap).collect(),
            renderers,
            data: (0..n).map(|_| OnceLock::new()).collect(),
            textures: (0..n).map(|_| OnceLock::new()).collect(),
            height_rows: (0..n).map(|_| OnceLock::new()).collect(),
            stats: (0..n).map(|_| OnceLock::new()).collect(),
            series: found,
            time: None,
            limits: Limits::default(),
            view_windows: vec![None; n],
        };
        for (name, data) in given {
            let node = scene.node_index(&name).expect("checked above");
            scene.provide_data(node, data);
        }
        Ok(scene)
    }

    /// A scene from an edited copy of this one's description (same base directory and
    /// source), keeping the data already read for every node whose data-reading keys
    /// did not change: editing a transfer function or the camera reads nothing again.
    pub fn edited(&self, file: SceneFile) -> Result<Scene> {
        self.edited_with_data(file, Vec::new())
    }

    /// `edited`, with data `given` in memory for new nodes without a file (see
    /// `from_memory`); the nodes already holding data in memory keep it.
    pub fn edited_with_data(&self, file: SceneFile, mut given: Vec<(String, NodeData)>) -> Result<Scene> {
        // Series already found are not looked for again (the viewer edits often).
        let known: HashMap<PathBuf, Option<Arc<TimeSeries>>> =
            self.file.nodes.iter().zip(&self.series).filter_map(|(n, s)| Some((n.file.clone()?, s.clone()))).collect();
        for (j, o) in self.file.nodes.iter().enumerate() {
            let kept = file.nodes.iter().any(|n| n.name == o.name && n.kind == o.kind && n.file.is_none());
            if let (None, true, Some(Ok(data))) = (&o.file, kept, self.data[j].get()) {
                if !given.iter().any(|g| g.0 == o.name) {
                    given.push((o.name.clone(), data.clone()));
                }
            }
        }
        let mut next =
            Scene::from_file_with_lines(file, self.base_dir.clone(), self.source.clone(), &SettingLines::default(), Some(&known), given)?
                .with_limits(self.limits);
        next.time = self.time;
        for (i, n) in next.file.nodes.iter().enumerate() {
            let Some(j) = self.node_index(&n.name) else { continue };
            let o = &self.file.nodes[j];
            let same_data = (&o.kind, &o.file, &o.series, o.volume_index, o.resample, &o.png, &o.arrays, o.extent)
                == (&n.kind, &n.file, &n.series, n.volume_index, n.resample, &n.png, &n.arrays, n.extent);
            self.carry_over(
                j,
                &next,
                i,
                same_data,
                same_data && o.texture == n.texture && o.texture_colormap == n.texture_colormap && o.texture_range == n.texture_range,
            );
        }
        Ok(next)
    }
}
