//! The 3-D viewport: the newest frame, navigation (orbit, pan, zoom, fly, walk), crop handles, and surface points and measurements picked from the frame's depth.

use super::*;

impl Viewer {
    /// The measurements taken (in the order taken), with each ellipse's statistics.
    pub fn measurements(&self) -> &[(Measurement, Option<RoiStats>)] {
        self.doc.as_ref().map_or(&[], |d| &d.measurements)
    }

    /// The newest distance measured on the slices, in millimetres.
    pub fn measured_mm(&self) -> Option<f64> {
        self.measurements().iter().rev().find(|(m, _)| m.kind == MeasurementKind::Distance).map(|(m, _)| m.value())
    }

    /// Drops every measurement.
    pub fn clear_measurements(&mut self) {
        if let Some(d) = &mut self.doc {
            d.measurements.clear();
        }
    }

    pub(super) fn viewport(&mut self, ui: &mut egui::Ui) {
        let (resp, painter) = ui.allocate_painter(ui.available_size(), Sense::click_and_drag());
        let rect = resp.rect;
        self.viewport_rect = Some(rect);
        painter.rect_filled(rect, 0.0, Color32::from_gray(18));
        let Some(_) = &self.doc else {
            painter.text(
                rect.center(),
                egui::Align2::CENTER_CENTER,
                "Open a file or scene (Ctrl+O), or drop one here",
                egui::FontId::proportional(18.0),
                Color32::GRAY,
            );
            return;
        };
        if let Some(s) = &self.shown {
            let uv = Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0));
            painter.image(s.texture.id(), rect, uv, Color32::WHITE);
            if self.show_steps {
                if let Some(t) = &s.steps {
                    painter.image(t.id(), rect, uv, Color32::from_white_alpha(200));
                }
            }
        }
        self.draw_surface_measurements(&painter, rect);
        if self.show_view_marks {
            let world = self.doc.as_ref().map_or(crate::view_marks::World::Plain, |d| view_world(&d.scene));
            crate::view_marks::draw(&painter, &self.camera, rect, world);
        }
        // Cross-hair of the slice views, projected.
        if let (Some(sl), true) = (&self.slices, self.show_slices && self.selected_volume().is_some()) {
            if let Some(p) = project(&self.camera, rect, sl.cross) {
                let c = Color32::from_rgb(255, 210, 0);
                painter.line_segment([p - Vec2::new(8.0, 0.0), p + Vec2::new(8.0, 0.0)], egui::Stroke::new(1.5, c));
                painter.line_segment([p - Vec2::new(0.0, 8.0), p + Vec2::new(0.0, 8.0)], egui::Stroke::new(1.5, c));
            }
        }
        if !self.crop_handles(&resp, &painter, rect) {
            self.navigate(ui, &resp, rect);
        }
    }

    /// Size of the 3-D view in physical pixels, as the last frame laid it out.
    pub(super) fn viewport_pixels(&self, ctx: &egui::Context) -> (usize, usize) {
        let ppp = ctx.pixels_per_point();
        self.viewport_rect
            .map(|r| ((r.width() * ppp).round().max(0.0) as usize, (r.height() * ppp).round().max(0.0) as usize))
            .unwrap_or((0, 0))
    }

    /// Where the 3-D view lies in the window (points).
    pub fn viewport_rect(&self) -> Option<Rect> {
        self.viewport_rect
    }

    /// Where the selected volume's crop box handle of face `face` (axis face / 2; min face
    /// when face % 2 = 0) is drawn in the window, if it has a crop box.
    pub fn crop_handle(&self, face: usize) -> Option<Pos2> {
        let (i, rect) = (self.selected_volume()?, self.viewport_rect?);
        let doc = self.doc.as_ref()?;
        let c = doc.scene.nodes()[i].crop?;
        crate::crop::handle_position(&c, face, doc.scene.world_transform(i), |p| project(&self.camera, rect, p))
    }

    /// The selected volume's crop box over the 3-D view, a handle on each face; a drag
    /// that starts on a handle moves that face (previews while it moves). True while
    /// such a drag goes on (the camera stays put).
    pub(super) fn crop_handles(&mut self, resp: &egui::Response, painter: &egui::Painter, rect: Rect) -> bool {
        let Some(i) = self.selected_volume() else { return false };
        let Some(doc) = &self.doc else { return false };
        let Some(mut c) = doc.scene.nodes()[i].crop else { return false };
        let to_world = doc.scene.world_transform(i);
        let cam = self.camera.clone();
        let project = |p: DVec3| project(&cam, rect, p);
        crate::crop::draw(painter, &c, to_world, project);
        if resp.drag_started_by(egui::PointerButton::Primary) {
            self.crop_drag =
                resp.ctx.input(|inp| inp.pointer.press_origin()).and_then(|pos| crate::crop::handle_at(&c, to_world, pos, project));
        }
        let Some(face) = self.crop_drag else { return false };
        if resp.dragged() && resp.drag_delta() != Vec2::ZERO {
            crate::crop::drag_face(&mut c, face, resp.drag_delta(), to_world, project);
            self.edit(true, |f| f.nodes[i].crop = Some(c));
        }
        if resp.drag_stopped() || !resp.dragged() {
            self.crop_drag = None;
            self.bump(false); // the full frame, now that the face is let go
        }
        true
    }

    pub(super) fn navigate(&mut self, ui: &mut egui::Ui, resp: &egui::Response, rect: Rect) {
        // Double-click (or Ctrl+click) on the volume: the slice views jump there (the depth where the
        // accumulated opacity passed 0.5 along that pixel's ray, from the full frame).
        let command = ui.input(|i| i.modifiers.command);
        if resp.double_clicked() || (resp.clicked() && command) {
            if let Some(pos) = resp.interact_pointer_pos() {
                self.jump_slices_to(rect, pos);
            }
        } else if resp.clicked() && self.tool != Tool::CrossHair {
            if let Some(pos) = resp.interact_pointer_pos() {
                self.place_surface_point(rect, pos);
            }
        }
        let mut moved = false;
        let d = resp.drag_delta();
        let (shift, scroll) = ui.input(|i| (i.modifiers.shift, i.smooth_scroll_delta.y));
        let h = rect.height().max(1.0) as f64;
        let primary = resp.dragged_by(egui::PointerButton::Primary);
        // As ParaView and pyvista: left rotates, middle (or Shift+left) pans, right zooms.
        let pan_drag = resp.dragged_by(egui::PointerButton::Middle) || (primary && shift && self.mode == NavMode::Orbit);
        if d != Vec2::ZERO {
            if resp.dragged_by(egui::PointerButton::Secondary) {
                navigate::zoom(&mut self.camera, (-2.0 * d.y as f64 / h).exp());
                moved = true;
            } else if pan_drag {
                navigate::pan(&mut self.camera, d.x as f64 / h, d.y as f64 / h);
                moved = true;
            } else if primary {
                match self.mode {
                    NavMode::Orbit => navigate::orbit(&mut self.camera, d.x as f64 * 180.0 / h, d.y as f64 * 180.0 / h),
                    NavMode::Fly | NavMode::Walk => navigate::look(&mut self.camera, d.x as f64 * 90.0 / h, -d.y as f64 * 90.0 / h),
                }
                moved = true;
            }
        }
        if resp.hovered() && scroll != 0.0 {
            navigate::zoom(&mut self.camera, (scroll as f64 / 300.0).exp());
            moved = true;
        }
        if self.mode != NavMode::Orbit && (resp.hovered() || resp.has_focus()) {
            let dt = ui.input(|i| i.stable_dt).min(0.1) as f64;
            let extent = self.doc.as_ref().and_then(|d| scene_extent(&d.scene)).unwrap_or(100.0);
            let speed = extent * 0.15 * dt * if shift { 5.0 } else { 1.0 };
            let key = |k| ui.input(|i| i.key_down(k));
            let f = (key(egui::Key::W) as i32 - key(egui::Key::S) as i32) as f64;
            let s = (key(egui::Key::D) as i32 - key(egui::Key::A) as i32) as f64;
            let r = if self.mode == NavMode::Fly { (key(egui::Key::E) as i32 - key(egui::Key::Q) as i32) as f64 } else { 0.0 };
            if f != 0.0 || s != 0.0 || r != 0.0 {
                navigate::travel(&mut self.camera, f * speed, s * speed, r * speed, self.mode == NavMode::Walk);
                if self.mode == NavMode::Walk {
                    self.settle_walk();
                }
                moved = true;
                ui.ctx().request_repaint();
            }
        }
        if moved {
            self.bump(true);
        }
    }

    /// Moves the slice views' cross-hair to the surface under window position `pos`.
    /// The world point on the surface under a window position in the 3-D view: along that
    /// pixel's ray at the full frame's depth (where the accumulated opacity passed 0.5, for
    /// volumes; the hit, for terrain and spheres). An error line where there is none.
    pub(super) fn surface_point(&self, rect: Rect, pos: Pos2) -> Result<DVec3, &'static str> {
        let Some((v, f)) = &self.last_full else { return Err("no full frame yet") };
        if *v != self.version {
            return Err("the full frame is still being drawn");
        }
        let x = ((pos.x - rect.left()) / rect.width() * f.width as f32).floor().max(0.0) as usize;
        let y = ((pos.y - rect.top()) / rect.height() * f.height as f32).floor().max(0.0) as usize;
        let (x, y) = (x.min(f.width - 1), y.min(f.height - 1));
        let depth = f.depth[y * f.width + x];
        if !depth.is_finite() {
            return Err("nothing opaque under the pointer");
        }
        let ray = self.camera.rays(f.width, f.height).ray(x as f64 + 0.5, y as f64 + 0.5);
        Ok(ray.origin + ray.dir * depth as f64)
    }

    pub(super) fn jump_slices_to(&mut self, rect: Rect, pos: Pos2) {
        match self.surface_point(rect, pos) {
            Ok(p) => {
                if let Some(s) = &mut self.slices {
                    let (lo, hi) = s.source.bounds();
                    s.cross = p.clamp(lo, hi);
                    s.dirty = true;
                }
            }
            Err(e) => self.message = Some(e.into()),
        }
    }

    /// A click on the 3-D view with a distance or angle tool places a point on the surface.
    pub(super) fn place_surface_point(&mut self, rect: Rect, pos: Pos2) {
        let Tool::Measure(kind) = self.tool else { return };
        if kind == MeasurementKind::Ellipse {
            self.message = Some("an elliptical ROI is drawn on a slice".into());
            return;
        }
        let p = match self.surface_point(rect, pos) {
            Ok(p) => p,
            Err(e) => {
                self.message = Some(e.into());
                return;
            }
        };
        if self.pending_on.is_some() {
            self.pending.clear();
            self.pending_on = None;
        }
        self.pending.push(p);
        if self.pending.len() == kind.points() {
            let Some(doc) = &mut self.doc else { return };
            let node = doc.scene.nodes().get(self.selected).map(|n| n.name.clone()).unwrap_or_default();
            let points = self.pending.drain(..).map(|p| p.to_array()).collect();
            doc.measurements.push((Measurement { kind, node, plane: None, points }, None));
        }
    }

    /// The measurements between surface points, and the one being placed, over the 3-D view.
    pub(super) fn draw_surface_measurements(&self, painter: &egui::Painter, rect: Rect) {
        let Some(doc) = &self.doc else { return };
        let screen = |q: DVec3| project(&self.camera, rect, q);
        let clip = painter.with_clip_rect(rect);
        for (m, _) in doc.measurements.iter().filter(|(m, _)| m.plane.is_none()) {
            if let Some(pts) = m.points.iter().map(|&q| screen(DVec3::from(q))).collect::<Option<Vec<Pos2>>>() {
                crate::measure::draw(&clip, m.kind, &pts, &crate::measure::describe_in(m, None, None, view_world(&doc.scene)));
            }
        }
        if let (Tool::Measure(kind), None) = (self.tool, self.pending_on) {
            if let Some(pts) = self.pending.iter().map(|&q| screen(q)).collect::<Option<Vec<Pos2>>>() {
                crate::measure::draw(&clip, kind, &pts, &[]);
            }
        }
    }

    pub(super) fn settle_walk(&mut self) {
        let Some(doc) = &self.doc else { return };
        let Some(i) = doc.scene.nodes().iter().position(|n| n.kind == NodeKind::Heightfield) else { return };
        let Ok(hf) = doc.scene.terrain_data(i) else { return };
        let m = doc.scene.world_transform(i);
        let eye = DVec3::from(self.camera.position);
        let local = m.inverse().transform_point3(DVec3::new(eye.x, eye.y, 0.0));
        if let Some(ground) = hf.surface_height(local.x, local.y) {
            let z = m.transform_point3(DVec3::new(local.x, local.y, ground)).z + self.eye_height;
            let lift = z - eye.z;
            self.camera.position[2] = z;
            self.camera.focal_point[2] += lift;
            self.bump(true);
        }
    }
}

/// The window position of a world point, if in front of the camera.
pub(super) fn project(cam: &Camera, rect: Rect, p: DVec3) -> Option<Pos2> {
    let g = cam.rays(rect.width().max(1.0) as usize, rect.height().max(1.0) as usize);
    let (eye, right, up) = g.basis();
    let (hw, hh) = g.half_extent();
    let d = p - eye;
    let (x, y) = if g.is_parallel() {
        (d.dot(right), d.dot(up))
    } else {
        let z = d.dot(g.forward());
        if z <= 0.0 {
            return None;
        }
        (d.dot(right) / z, d.dot(up) / z)
    };
    let sx = 0.5 * (x / hw + 1.0);
    let sy = 0.5 * (1.0 - y / hh);
    Some(Pos2::new(rect.left() + sx as f32 * rect.width(), rect.top() + sy as f32 * rect.height()))
}

/// sRGB pixels of a frame over its background.
pub(super) fn frame_image(frame: &Frame, bg: [f64; 3], exposure: f64) -> egui::ColorImage {
    let rgba = frame.preview_rgba(bg, exposure);
    let to8 = |v: f32| (volterra_formats::image::linear_to_srgb(v.clamp(0.0, 1.0)) * 255.0).round() as u8;
    let pixels = rgba.chunks_exact(4).map(|p| Color32::from_rgb(to8(p[0]), to8(p[1]), to8(p[2]))).collect();
    egui::ColorImage::new([frame.width, frame.height], pixels)
}

/// Terrain traversal steps per pixel as a heat map (black → red → yellow at the maximum).
pub(super) fn steps_image(frame: &Frame, steps: &[f32]) -> egui::ColorImage {
    let max = steps.iter().cloned().fold(1.0f32, f32::max);
    let pixels = steps
        .iter()
        .map(|&s| {
            let t = (s / max).clamp(0.0, 1.0);
            let r = (t * 2.0).min(1.0);
            let g = (t * 2.0 - 1.0).max(0.0);
            Color32::from_rgb((r * 255.0) as u8, (g * 255.0) as u8, 0)
        })
        .collect();
    egui::ColorImage::new([frame.width, frame.height], pixels)
}
