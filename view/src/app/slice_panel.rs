//! The slice panel: axial, coronal and sagittal views with a cross-hair, window/level presets, an overlay volume, and measurements on the slices.

use super::*;

impl Viewer {
    /// The cross-hair of the slice views (world RAS+ mm), once they are shown.
    pub fn slice_cross(&self) -> Option<DVec3> {
        self.slices.as_ref().map(|s| s.cross)
    }

    /// The colours a slice view shows (sRGB; `plane`: 0 axial, 1 coronal, 2 sagittal), with
    /// its size.
    pub fn slice_colours(&self, plane: usize) -> Option<(usize, usize, &[[u8; 3]])> {
        let s = self.slices.as_ref()?;
        let (img, _) = s.images.get(plane)?;
        Some((img.width, img.height, s.shown.get(plane)?.as_slice()))
    }

    /// Where slice view `plane` (0 axial, 1 coronal, 2 sagittal) was drawn, and the world
    /// point under a window position in it.
    pub fn slice_point(&self, plane: usize, pos: Pos2) -> Option<(Rect, DVec3)> {
        let s = self.slices.as_ref()?;
        let (r, (img, _)) = (s.rects.get(plane)?, s.images.get(plane)?);
        let u = (pos.x - r.left()) / r.width() * img.width as f32;
        let v = (pos.y - r.top()) / r.height() * img.height as f32;
        Some((*r, img.world_at(u as f64, v as f64)))
    }

    /// The slice views' window and level.
    pub fn window_level(&self) -> Option<(f64, f64)> {
        self.slices.as_ref().map(|s| (s.window, s.level))
    }

    pub(super) fn slice_panel(&mut self, ui: &mut egui::Ui) {
        let Some(i) = self.selected_volume() else { return };
        let Some(doc) = &self.doc else { return };
        let Ok(volume) = doc.scene.volume(i) else { return };
        let stats = doc.stats[i].clone();
        // (Re)build the source when another volume (or its placement) is selected.
        let world = doc.scene.world_transform(i);
        let rebuild = self.slices.as_ref().is_none_or(|s| s.node != i || !Arc::ptr_eq(&s.source.volume, &volume));
        if rebuild {
            let source = SliceSource::new(volume.clone(), world);
            let (window, level) = stats
                .as_ref()
                .map(|s| {
                    let (a, b) = (s.percentile(0.005), s.percentile(0.999));
                    let (a, b) = if b > a { (a, b) } else { (s.min, s.max.max(s.min + 1.0)) };
                    (b - a, 0.5 * (a + b))
                })
                .unwrap_or((1.0, 0.5));
            let restore = self.restore_slices.take().filter(|r| r.node == doc.scene.nodes()[i].name);
            let (window, level, cross) = match &restore {
                Some(r) => (r.window, r.level, DVec3::from(r.cross)),
                None => (window, level, source.centre()),
            };
            let overlay = restore.and_then(|r| r.overlay).and_then(|o| {
                let j = doc.scene.nodes().iter().position(|n| n.name == o.node)?;
                Some(OverlayState {
                    node: j,
                    source: SliceSource::new(doc.scene.volume(j).ok()?, doc.scene.world_transform(j)),
                    window: o.window,
                    level: o.level,
                    colormap: volterra::colormap::Colormap::from_name(&o.colormap)?,
                    opacity: o.opacity,
                })
            });
            self.slices = Some(SliceState {
                node: i,
                cross,
                source,
                window,
                level,
                images: vec![],
                shown: vec![],
                overlay,
                rects: vec![],
                dirty: true,
            });
        }
        // The CT presets apply to values in Hounsfield units: a CT (the node's modality, else
        // the file's) or values the file says are HU.
        let node = &doc.scene.nodes()[i];
        let ct = node.modality.as_deref().or(volume.modality.as_deref()).is_some_and(|m| m.eq_ignore_ascii_case("CT"))
            || volume.units.as_deref() == Some("HU");
        let s = self.slices.as_mut().unwrap();
        ui.horizontal(|ui| {
            let current = crate::slices::CT_WINDOWS.iter().find(|(_, w, l)| *w == s.window && *l == s.level).map_or("Custom", |p| p.0);
            ui.add_enabled_ui(ct, |ui| {
                egui::ComboBox::from_label("W/L preset")
                    .selected_text(current)
                    .show_ui(ui, |ui| {
                        for &(name, w, l) in crate::slices::CT_WINDOWS {
                            if ui.selectable_label(current == name, format!("{name} (W {w} / L {l})")).clicked() {
                                (s.window, s.level, s.dirty) = (w, l, true);
                            }
                        }
                    })
                    .response
                    .on_disabled_hover_text("CT window presets need values in Hounsfield units (a CT, or set the node's modality to CT)");
            });
        });
        s.dirty |= window_level_controls(ui, ("Window", "Level"), &mut s.window, &mut s.level);
        // Fusion: another volume node over these slices, through a colour map.
        let others: Vec<(usize, String)> = doc
            .scene
            .nodes()
            .iter()
            .enumerate()
            .filter(|(j, n)| *j != i && n.kind == NodeKind::Volume)
            .map(|(j, n)| (j, n.name.clone()))
            .collect();
        if !others.is_empty() {
            let current =
                s.overlay.as_ref().and_then(|o| others.iter().find(|(j, _)| *j == o.node)).map_or("None".to_string(), |(_, n)| n.clone());
            let mut pick: Option<Option<usize>> = None;
            egui::ComboBox::from_label("Overlay").selected_text(&current).show_ui(ui, |ui| {
                if ui.selectable_label(s.overlay.is_none(), "None").clicked() {
                    pick = Some(None);
                }
                for (j, name) in &others {
                    if ui.selectable_label(current == *name, name).clicked() {
                        pick = Some(Some(*j));
                    }
                }
            });
            match pick {
                Some(None) => {
                    s.overlay = None;
                    s.dirty = true;
                }
                Some(Some(j)) => {
                    if let Ok(v) = doc.scene.volume(j) {
                        // The window from the overlay's own values (0.5 % to 99.9 %).
                        let (lo, hi) =
                            doc.scene.value_stats(j).map(|st| (st.percentile(0.005), st.percentile(0.999))).unwrap_or((0.0, 1.0));
                        let (lo, hi) = if hi > lo { (lo, hi) } else { (lo, lo + 1.0) };
                        s.overlay = Some(OverlayState {
                            node: j,
                            source: SliceSource::new(v, doc.scene.world_transform(j)),
                            window: hi - lo,
                            level: 0.5 * (lo + hi),
                            colormap: volterra::colormap::Colormap::Hot,
                            opacity: 0.5,
                        });
                        s.dirty = true;
                    }
                }
                None => {}
            }
        }
        if let Some(o) = s.overlay.as_mut() {
            use volterra::colormap::Colormap;
            egui::ComboBox::from_label("Overlay colours").selected_text(o.colormap.name()).show_ui(ui, |ui| {
                for &c in Colormap::ALL {
                    if ui.selectable_label(o.colormap == c, c.name()).clicked() && o.colormap != c {
                        o.colormap = c;
                        s.dirty = true;
                    }
                }
            });
            ui.horizontal(|ui| {
                let lbl = ui.label("Overlay opacity");
                s.dirty |= ui.add(egui::Slider::new(&mut o.opacity, 0.0..=1.0)).labelled_by(lbl.id).changed();
            });
            s.dirty |= window_level_controls(ui, ("Overlay window", "level"), &mut o.window, &mut o.level);
            // The scalar bar: the map from the window's bottom to its top, with the values.
            let (rect, _) = ui.allocate_exact_size(Vec2::new(ui.available_width().min(240.0), 12.0), Sense::hover());
            let painter = ui.painter_at(rect);
            let steps = 64;
            for k in 0..steps {
                let c = o.colormap.at((k as f64 + 0.5) / steps as f64).map(f64::from);
                let x0 = rect.left() + rect.width() * k as f32 / steps as f32;
                let x1 = rect.left() + rect.width() * (k + 1) as f32 / steps as f32;
                painter.rect_filled(
                    Rect::from_min_max(Pos2::new(x0, rect.top()), Pos2::new(x1, rect.bottom())),
                    0.0,
                    Color32::from_rgb(srgb(c[0]), srgb(c[1]), srgb(c[2])),
                );
            }
            ui.horizontal(|ui| {
                ui.label(format!("{:.4}", o.level - 0.5 * o.window));
                ui.add_space((rect.width() - 120.0).max(0.0));
                ui.label(format!("{:.4}", o.level + 0.5 * o.window));
            });
        }
        if s.dirty {
            let overlay = s.overlay.as_ref().map(|o| Overlay {
                source: &o.source,
                window: o.window,
                level: o.level,
                colormap: o.colormap,
                opacity: o.opacity,
            });
            s.shown.clear();
            s.images = Plane::ALL
                .iter()
                .map(|&p| {
                    let img = s.source.slice(p, s.cross, s.window, s.level);
                    let rgb = crate::slices::fused(&img, overlay.as_ref());
                    let flat: Vec<u8> = rgb.iter().flatten().copied().collect();
                    let tex = ui.ctx().load_texture(
                        format!("slice-{}", p.label()),
                        egui::ColorImage::from_rgb([img.width, img.height], &flat),
                        egui::TextureOptions::LINEAR,
                    );
                    s.shown.push(rgb);
                    (img, tex)
                })
                .collect();
            s.dirty = false;
        }
        let width = ui.available_width();
        let mut new_cross = None;
        let mut taken = None;
        let node_name = doc.scene.nodes()[i].name.clone();
        // The values' units: the file's, else HU for a CT (as the W/L presets take them).
        let units = volume.units.clone().or_else(|| ct.then(|| "HU".to_string()));
        s.rects.clear();
        for (k, plane) in Plane::ALL.iter().enumerate() {
            let (img, tex) = &s.images[k];
            ui.label(format!(
                "{} ({:.1} mm)",
                plane.label(),
                match plane {
                    Plane::Axial => s.cross.z,
                    Plane::Coronal => s.cross.y,
                    Plane::Sagittal => s.cross.x,
                }
            ));
            let aspect = img.height as f32 / img.width as f32;
            let size = Vec2::new(width, (width * aspect).min(width * 1.5));
            let (resp, painter) = ui.allocate_painter(size, Sense::click_and_drag());
            let r = resp.rect;
            s.rects.push(r);
            painter.image(tex.id(), r, Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)), Color32::WHITE);
            let on_screen = |p: DVec3| {
                let (u, v) = img.pixel_of(p);
                Pos2::new(r.left() + (u as f32 / img.width as f32) * r.width(), r.top() + (v as f32 / img.height as f32) * r.height())
            };
            // Cross-hair.
            let p = on_screen(s.cross);
            let stroke = egui::Stroke::new(1.0, Color32::from_rgb(255, 210, 0));
            painter.line_segment([Pos2::new(r.left(), p.y), Pos2::new(r.right(), p.y)], stroke);
            painter.line_segment([Pos2::new(p.x, r.top()), Pos2::new(p.x, r.bottom())], stroke);
            let [l, rt, t, b] = plane.edge_labels();
            let font = egui::FontId::proportional(13.0);
            let c = Color32::from_rgb(120, 220, 255);
            painter.text(Pos2::new(r.left() + 4.0, r.center().y), egui::Align2::LEFT_CENTER, l, font.clone(), c);
            painter.text(Pos2::new(r.right() - 4.0, r.center().y), egui::Align2::RIGHT_CENTER, rt, font.clone(), c);
            painter.text(Pos2::new(r.center().x, r.top() + 2.0), egui::Align2::CENTER_TOP, t, font.clone(), c);
            painter.text(Pos2::new(r.center().x, r.bottom() - 2.0), egui::Align2::CENTER_BOTTOM, b, font, c);
            // The measurements on this slice (this volume, this plane, this slice position:
            // within half a slice pixel of the cross-hair along the normal).
            let axis = plane.scene_plane().normal_axis();
            let on_this_slice = |p: &[f64; 3]| (p[axis] - s.cross[axis]).abs() <= 0.5 * s.source.slice_pixel(*plane);
            let clip = painter.with_clip_rect(r);
            for (m, stats) in &doc.measurements {
                if m.node == node_name && m.plane == Some(plane.scene_plane()) && on_this_slice(&m.points[0]) {
                    let pts: Vec<Pos2> = m.points.iter().map(|&q| on_screen(DVec3::from(q))).collect();
                    let lines = crate::measure::describe(m, stats.as_ref(), units.as_deref(), volume.suv_bw);
                    crate::measure::draw(&clip, m.kind, &pts, &lines);
                }
            }
            if let (Tool::Measure(kind), true) = (self.tool, self.pending_on == Some(k) && !self.pending.is_empty()) {
                let pts: Vec<Pos2> = self.pending.iter().map(|&q| on_screen(q)).collect();
                crate::measure::draw(&clip, kind, &pts, &[]);
            }
            if let Some(pos) = resp.interact_pointer_pos().filter(|_| resp.clicked() || (resp.dragged() && self.tool == Tool::CrossHair)) {
                let u = (pos.x - r.left()) / r.width() * img.width as f32;
                let v = (pos.y - r.top()) / r.height() * img.height as f32;
                let world = img.world_at(u as f64, v as f64);
                match self.tool {
                    Tool::CrossHair => new_cross = Some(world),
                    Tool::Measure(kind) => {
                        // A click on another slice starts over there.
                        if self.pending_on != Some(k) {
                            self.pending.clear();
                            self.pending_on = Some(k);
                        }
                        self.pending.push(world);
                        if self.pending.len() == kind.points() {
                            let points = self.pending.drain(..).map(|p| p.to_array()).collect();
                            taken = Some(Measurement { kind, node: node_name.clone(), plane: Some(plane.scene_plane()), points });
                        }
                    }
                }
            }
        }
        if let Some(c) = new_cross {
            let (lo, hi) = s.source.bounds();
            s.cross = c.clamp(lo, hi);
            s.dirty = true;
        }
        let Some(doc) = &mut self.doc else { return };
        if let Some(m) = taken {
            let stats = measurement_stats(&doc.scene, &m);
            doc.measurements.push((m, stats));
        }
    }
}

/// `dir/name.view.toml` beside the opened file.
/// A window and a level as drag values labelled `labels` (the window kept positive, both
/// moving by a hundredth of the window); true when either changed.
pub(super) fn window_level_controls(ui: &mut egui::Ui, labels: (&str, &str), window: &mut f64, level: &mut f64) -> bool {
    ui.horizontal(|ui| {
        let speed = window.abs() * 0.01 + 1e-6;
        let lbl = ui.label(labels.0);
        let w = ui.add(egui::DragValue::new(window).speed(speed).range(1e-9..=f64::MAX)).labelled_by(lbl.id).changed();
        let lbl = ui.label(labels.1);
        let l = ui.add(egui::DragValue::new(level).speed(speed)).labelled_by(lbl.id).changed();
        w | l
    })
    .inner
}
