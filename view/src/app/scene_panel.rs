//! The scene panel: each node's metadata, renderer and settings, with each node kind's own controls (volumes: transfer function, shading, crop; terrain: sun; smoke; points).

use super::*;

impl Viewer {
    pub(super) fn scene_panel(&mut self, ui: &mut egui::Ui) {
        let Some(doc) = &self.doc else { return };
        let scene = doc.scene.clone();
        ui.heading("Scene");
        ui.label(egui::RichText::new(scene.source.display().to_string()).small());
        for (i, n) in scene.nodes().iter().enumerate() {
            let label = format!("{} ({:?})", n.name, n.kind).to_lowercase();
            if ui.selectable_label(self.selected == i, label).clicked() {
                self.selected = i;
                self.tf_editor = TfEditor::default();
            }
        }
        ui.separator();
        let i = self.selected;
        let Some(n) = scene.nodes().get(i).cloned() else { return };
        ui.heading(&n.name);
        // Metadata, as `volterra info` prints it.
        if n.kind != NodeKind::Group {
            match node_json(&scene, i) {
                Ok(json) => metadata_grid(ui, json),
                Err(e) => {
                    ui.colored_label(Color32::from_rgb(230, 90, 80), format!("{e:#}"));
                }
            }
        }
        let mut visible = n.visible;
        if ui.checkbox(&mut visible, "Visible").changed() {
            self.edit(false, |f| f.nodes[i].visible = visible);
        }
        // Renderer choice among those that draw this kind.
        let Some(current) = scene.renderer(i) else { return };
        let mut chosen = None;
        egui::ComboBox::from_label("Renderer").selected_text(current.name).show_ui(ui, |ui| {
            for r in catalog::for_kind(n.kind) {
                if ui.selectable_label(current.name == r.name, r.name).on_hover_text(volterra::settings::summary(r.doc)).clicked() {
                    chosen = Some(r.name);
                }
            }
        });
        if let Some(r) = chosen.filter(|r| *r != current.name) {
            self.edit(false, |f| {
                f.nodes[i].renderer = Some(r.to_string());
                // Each renderer has its own settings: those of the previous one go.
                f.nodes[i].settings = toml::Table::new();
            });
        }
        match n.kind {
            NodeKind::Volume => self.volume_controls(ui, i, current),
            NodeKind::Heightfield => self.terrain_controls(ui, i, current),
            NodeKind::Particles if current.name == volterra::render::points::RENDERER.name => self.points_controls(ui, i, current),
            NodeKind::Particles => self.smoke_controls(ui, i, current),
            NodeKind::Group => {}
        }
    }

    /// The controls the node's renderer declares for its settings.
    pub(super) fn setting_controls(&mut self, ui: &mut egui::Ui, i: usize, renderer: &catalog::RendererDecl, settings: &toml::Table) {
        if let Some(c) = crate::settings_controls::show(ui, renderer, settings) {
            self.edit(c.moving, |f| {
                f.nodes[i].settings.insert(c.key.to_string(), c.value);
            });
        }
    }
}

/// What `volterra info` prints of a node's data, as its renderer reads it (a heightfield's
/// GeoTIFF by rows, not held).
pub(super) fn node_json(scene: &Scene, i: usize) -> Result<serde_json::Value> {
    if scene.nodes()[i].kind == NodeKind::Heightfield {
        if let TerrainData::Rows(rows) = scene.terrain_data(i)? {
            return Ok(volterra::info::grid_json(&volterra::info::GridSummary::of_rows(&rows)));
        }
    }
    Ok(match scene.data(i)? {
        NodeData::Volume(v) => {
            // The modality in effect: the node's where it sets one (a NIfTI says none).
            let mut json = volterra::info::volume_json(&v);
            if let Some(m) = scene.nodes()[i].modality.as_deref() {
                let code = volterra::scene::presets::modality_code(m).unwrap_or(m);
                let file = v.modality.as_deref().map(|f| format!("the file says {f}")).unwrap_or_else(|| "the file says none".into());
                json["modality"] = serde_json::json!(format!("{code} (the node's; {file})"));
            }
            json
        }
        NodeData::Heightfield(h) => volterra::info::heightfield_json(&h),
        NodeData::Particles(p) => volterra::info::particles_json(&p, &scene.nodes()[i].arrays.clone().unwrap_or_default()),
    })
}

pub(super) fn metadata_grid(ui: &mut egui::Ui, json: serde_json::Value) {
    // What the file says about itself (codes, patient, series, compression, corners): whole,
    // under a header that starts closed so the panel keeps its layout.
    let details: Vec<(String, serde_json::Value)> = match &json {
        serde_json::Value::Object(map) => {
            ["attributes", "corners", "corners_lonlat"].iter().filter_map(|k| map.get(*k).map(|v| (k.to_string(), v.clone()))).collect()
        }
        _ => Vec::new(),
    };
    egui::Grid::new("metadata").num_columns(2).striped(true).show(ui, |ui| {
        if let serde_json::Value::Object(map) = json {
            for (k, v) in map {
                if ["notes", "affine", "attributes", "corners", "corners_lonlat", "orientation", "geotransform"].contains(&k.as_str()) {
                    continue;
                }
                ui.label(k);
                let text = match &v {
                    serde_json::Value::String(s) => s.clone(),
                    serde_json::Value::Null => "—".into(),
                    serde_json::Value::Array(a) if a.iter().all(|x| x.is_number()) => a
                        .iter()
                        .map(|x| {
                            if x.is_f64() {
                                format!("{:.6}", x.as_f64().unwrap()).trim_end_matches('0').trim_end_matches('.').to_string()
                            } else {
                                x.to_string()
                            }
                        })
                        .collect::<Vec<_>>()
                        .join(" × "),
                    other => {
                        let t = other.to_string();
                        if t.len() > 60 {
                            format!("{}…", &t[..t.char_indices().nth(60).map(|c| c.0).unwrap_or(t.len())])
                        } else {
                            t
                        }
                    }
                };
                ui.label(text);
                ui.end_row();
            }
        }
    });
    for (k, v) in details {
        let serde_json::Value::Object(o) = v else { continue };
        egui::CollapsingHeader::new(format!("file {k}")).default_open(false).show(ui, |ui| {
            egui::Grid::new(format!("metadata-{k}")).num_columns(2).striped(true).show(ui, |ui| {
                for (name, value) in o {
                    ui.label(name);
                    ui.label(value.as_str().map(str::to_string).unwrap_or_else(|| value.to_string()));
                    ui.end_row();
                }
            });
        });
    }
}
