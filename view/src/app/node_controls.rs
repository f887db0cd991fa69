//! Each node kind's controls in the scene panel: a volume's transfer function, modality,
//! shading and crop; the terrain's sun; smoke's medium; the points' colours and style.

use super::*;

impl Viewer {
    pub(super) fn volume_controls(&mut self, ui: &mut egui::Ui, i: usize, renderer: &catalog::RendererDecl) {
        let Some(doc) = &self.doc else { return };
        let n = doc.scene.nodes()[i].clone();
        let stats = doc.stats.get(i).cloned().flatten();
        let volume = doc.scene.volume(i).ok();
        // The transfer function drawn: the node's points, else its preset's on its data.
        let drawn_tf = n.transfer_function.clone().or_else(|| doc.scene.transfer_function(i).ok());
        let modality_preset = (n.transfer_function.is_none() && n.preset.is_none()).then(|| doc.scene.preset(i).ok()).flatten();
        let drawn_shading = doc.scene.shading(i);
        let mut mip = n.blend == BlendMode::Mip;
        if ui.checkbox(&mut mip, "Maximum intensity projection").changed() {
            self.edit(false, |f| f.nodes[i].blend = if mip { BlendMode::Mip } else { BlendMode::Composite });
        }
        ui.add_enabled_ui(!mip, |ui| {
            ui.horizontal(|ui| {
                // Fades one volume of a fused pair (its extinction scaled; saved as opacity_scale).
                let mut scale = n.opacity_scale;
                let lbl = ui.label("Opacity scale");
                let r = ui.add(egui::Slider::new(&mut scale, 0.0..=10.0).logarithmic(true)).labelled_by(lbl.id);
                if r.changed() {
                    self.edit(r.dragged(), |f| f.nodes[i].opacity_scale = scale);
                }
            });
        });
        self.setting_controls(ui, i, renderer, &n.settings);
        ui.checkbox(&mut self.show_slices, "Slice views");
        ui.separator();
        ui.label(egui::RichText::new("Transfer function").strong());
        let Some(stats) = stats else { return };
        if let Some(p) = &n.preset {
            ui.label(format!("Preset {p} (saved by name; editing a point makes it points)"));
        } else if let Some(p) = modality_preset {
            ui.label(format!("Preset {} (the modality's)", p.name()));
        }
        let Some(mut tf) = drawn_tf else {
            if ui.button("Add a transfer function").clicked() {
                if let Some(v) = volume {
                    let modality = n.modality.as_deref().or(v.modality.as_deref());
                    let p = volterra::scene::presets::Preset::for_modality(modality, &stats);
                    self.edit(false, |f| f.nodes[i].preset = Some(p.name().to_string()));
                }
            }
            return;
        };
        if self.tf_editor.show(ui, &mut tf, &stats) {
            if let Some(p) = self.tf_editor.chosen_preset.take() {
                // A preset chosen is saved as such (its name), with Slicer's shading
                // unless the node has its own.
                self.edit(false, |f| {
                    f.nodes[i].transfer_function = None;
                    f.nodes[i].preset = Some(p.name().to_string());
                    f.nodes[i].preset_shift = 0.0;
                });
            } else if tf.validate().is_ok() {
                // Points moved by hand replace the preset; the shading it gave is kept.
                let moving = ui.input(|inp| inp.pointer.any_down());
                self.edit(moving, |f| {
                    f.nodes[i].transfer_function = Some(tf);
                    if f.nodes[i].preset.take().is_some() {
                        f.nodes[i].shading = drawn_shading;
                        f.nodes[i].preset_shift = 0.0;
                    }
                });
            }
        }
        ui.separator();
        self.modality_control(ui, i, n.modality.as_deref());
        self.shading_controls(ui, i, drawn_shading.unwrap_or_default(), mip);
        ui.separator();
        if let Some(v) = volume {
            if let Some(e) = crate::crop::controls(ui, n.crop, &n.clip, crate::crop::volume_box(&v)) {
                self.edit(e.moving, |f| {
                    f.nodes[i].crop = e.crop;
                    f.nodes[i].clip = e.clip;
                });
            }
        }
    }

    /// The modality of data whose file does not say it (NIfTI): it picks the preset.
    pub(super) fn modality_control(&mut self, ui: &mut egui::Ui, i: usize, modality: Option<&str>) {
        let mut chosen = modality.map(str::to_string);
        egui::ComboBox::from_label("Modality").selected_text(modality.unwrap_or("from the file")).show_ui(ui, |ui| {
            ui.selectable_value(&mut chosen, None, "from the file");
            for m in volterra::scene::presets::MODALITIES.iter().map(|(code, _)| *code) {
                ui.selectable_value(&mut chosen, Some(m.to_string()), m);
            }
        });
        if chosen.as_deref() != modality {
            self.edit(false, |f| f.nodes[i].modality = chosen);
        }
    }

    /// Gradient shading of a volume node, with vtkVolumeProperty's coefficients (MIP is
    /// never shaded). Turning it off keeps the coefficients, as `shade = false`.
    pub(super) fn shading_controls(&mut self, ui: &mut egui::Ui, i: usize, mut shading: VolumeShading, mip: bool) {
        ui.add_enabled_ui(!mip, |ui| {
            let mut changed = ui
                .checkbox(&mut shading.shade, "Shading")
                .on_hover_text("Gradient shading as VTK's ShadeOn, lit by the scene's lights or a headlight")
                .changed();
            let mut moving = false;
            if shading.shade {
                let VolumeShading { ambient, diffuse, specular, specular_power, .. } = &mut shading;
                for (label, value, hi) in [
                    ("Ambient", ambient, 1.0),
                    ("Diffuse", diffuse, 1.0),
                    ("Specular", specular, 1.0),
                    ("Specular power", specular_power, 128.0),
                ] {
                    ui.horizontal(|ui| {
                        let lbl = ui.label(label);
                        let r = ui.add(egui::Slider::new(value, 0.0..=hi)).labelled_by(lbl.id);
                        changed |= r.changed();
                        moving |= r.dragged();
                    });
                }
            }
            if changed {
                self.edit(moving, |f| f.nodes[i].shading = Some(shading));
            }
        });
    }

    pub(super) fn terrain_controls(&mut self, ui: &mut egui::Ui, i: usize, renderer: &catalog::RendererDecl) {
        let Some(doc) = &self.doc else { return };
        let n = doc.scene.nodes()[i].clone();
        let lights = doc.scene.file.lights.clone();
        self.setting_controls(ui, i, renderer, &n.settings);
        let mut exaggeration = n.transform.scale.map(|s| s[2]).unwrap_or(1.0);
        ui.horizontal(|ui| {
            let lbl = ui.label("Vertical exaggeration");
            let r = ui.add(egui::Slider::new(&mut exaggeration, 0.1..=10.0).logarithmic(true)).labelled_by(lbl.id);
            if r.changed() {
                self.edit(r.dragged(), |f| {
                    let s = f.nodes[i].transform.scale.get_or_insert([1.0; 3]);
                    s[2] = exaggeration;
                });
            }
        });
        self.sun_controls(ui, &lights);
        ui.checkbox(&mut self.show_steps, "Step-count heat map");
        if self.mode == NavMode::Walk {
            ui.horizontal(|ui| {
                let lbl = ui.label("Eye height (m)");
                if ui.add(egui::DragValue::new(&mut self.eye_height).speed(0.1).range(0.0..=10000.0)).labelled_by(lbl.id).changed() {
                    self.settle_walk();
                }
            });
        }
        ui.label(egui::RichText::new("Fly/Walk: drag to look, W A S D to move, Q/E down/up (fly), Shift faster").weak());
    }

    /// Sun azimuth (degrees clockwise from north, where the light comes from) and
    /// elevation above the horizon, editing the first directional light.
    pub(super) fn sun_controls(&mut self, ui: &mut egui::Ui, lights: &[volterra::scene::Light]) {
        let Some(li) = lights.iter().position(|l| l.kind == volterra::scene::LightKind::Directional) else { return };
        let d = DVec3::from(lights[li].direction.unwrap_or([0.0, 0.0, -1.0])).normalize();
        let from = -d;
        let mut azimuth = from.x.atan2(from.y).to_degrees().rem_euclid(360.0);
        let mut elevation = from.z.clamp(-1.0, 1.0).asin().to_degrees();
        let mut changed = None;
        ui.horizontal(|ui| {
            let lbl = ui.label("Sun azimuth");
            let r = ui.add(egui::Slider::new(&mut azimuth, 0.0..=360.0).suffix("°")).labelled_by(lbl.id);
            if r.changed() {
                changed = Some(r.dragged());
            }
        });
        ui.horizontal(|ui| {
            let lbl = ui.label("Sun elevation");
            let r = ui.add(egui::Slider::new(&mut elevation, 1.0..=90.0).suffix("°")).labelled_by(lbl.id);
            if r.changed() {
                changed = Some(r.dragged());
            }
        });
        if let Some(moving) = changed {
            let (a, e) = (azimuth.to_radians(), elevation.to_radians());
            let from = DVec3::new(a.sin() * e.cos(), a.cos() * e.cos(), e.sin());
            self.edit(moving, |f| f.lights[li].direction = Some((-from).to_array()));
        }
    }

    pub(super) fn smoke_controls(&mut self, ui: &mut egui::Ui, i: usize, renderer: &catalog::RendererDecl) {
        let Some(doc) = &self.doc else { return };
        let n = doc.scene.nodes()[i].clone();
        let lights = doc.scene.file.lights.clone();
        if let Some(mut m) = n.medium.clone() {
            let mut changed = None;
            ui.horizontal(|ui| {
                let lbl = ui.label("Albedo");
                let r = ui.add(egui::Slider::new(&mut m.albedo, 0.0..=1.0)).labelled_by(lbl.id);
                if r.changed() {
                    changed = Some(r.dragged());
                }
            });
            ui.horizontal(|ui| {
                // Automatic: optical depth 2 through the densest column, in any units.
                let mut auto = m.c_ext.is_none();
                if ui.checkbox(&mut auto, "Automatic C_ext").changed() {
                    m.c_ext = if auto { None } else { Some(10.0) };
                    changed = Some(false);
                }
                if let Some(c) = m.c_ext.as_mut() {
                    let lbl = ui.label("C_ext (m²/kg)");
                    let r = ui.add(egui::Slider::new(c, 0.01..=1000.0).logarithmic(true)).labelled_by(lbl.id);
                    if r.changed() {
                        changed = Some(r.dragged());
                    }
                }
            });
            ui.horizontal(|ui| {
                let lbl = ui.label("g (Henyey–Greenstein)");
                let r = ui.add(egui::Slider::new(&mut m.g, -0.95..=0.95)).labelled_by(lbl.id);
                if r.changed() {
                    changed = Some(r.dragged());
                }
            });
            if let Some(moving) = changed {
                self.edit(moving, |f| f.nodes[i].medium = Some(m));
            }
        }
        self.setting_controls(ui, i, renderer, &n.settings);
        self.sun_controls(ui, &lights);
        ui.label(egui::RichText::new("Traced photons are cached on disk: moving the camera reuses them.").weak());
    }

    /// The points renderer's controls: what colours the particles (any of their point
    /// arrays), then the declared settings; opacity only for splats (spheres refuse it).
    pub(super) fn points_controls(&mut self, ui: &mut egui::Ui, i: usize, renderer: &catalog::RendererDecl) {
        let Some(doc) = &self.doc else { return };
        let n = doc.scene.nodes()[i].clone();
        if let Ok(NodeData::Particles(p)) = doc.scene.data(i) {
            let mut names: Vec<String> =
                [("density", p.density.is_some()), ("mass", p.mass.is_some()), ("h", p.smoothing_length.is_some())]
                    .iter()
                    .filter(|(_, present)| *present)
                    .map(|(n, _)| n.to_string())
                    .collect();
            names.extend(p.arrays.iter().map(|a| a.name.clone()));
            let current = n.color_by.clone().unwrap_or_else(|| if p.density.is_some() { "density".into() } else { "(one colour)".into() });
            let mut pick = None;
            egui::ComboBox::from_label("Colour by").selected_text(&current).show_ui(ui, |ui| {
                for name in &names {
                    if ui.selectable_label(*name == current, name).clicked() {
                        pick = Some(name.clone());
                    }
                }
            });
            if let Some(name) = pick.filter(|p| *p != current) {
                // A range given for another array would not fit this one.
                self.edit(false, |f| {
                    f.nodes[i].color_by = Some(name);
                    f.nodes[i].color_range = None;
                });
            }
        }
        let splats = n.settings.get("style").and_then(|v| v.as_str()) == Some(volterra::render::points::PointStyle::Splats.name());
        let decls = renderer.settings.iter().filter(|d| splats || d.key != "opacity");
        if let Some(c) = crate::settings_controls::show_some(ui, decls, &n.settings) {
            self.edit(c.moving, |f| {
                let settings = &mut f.nodes[i].settings;
                settings.insert(c.key.to_string(), c.value);
                if settings.get("style").and_then(|v| v.as_str()) != Some("splats") {
                    settings.remove("opacity");
                }
            });
        }
    }
}
