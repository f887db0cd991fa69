//! The transfer-function editor: piecewise-linear opacity drawn over the data's histogram
//! (log counts, as Slicer and ParaView show it), the colour map as a bar beneath with its
//! control points, presets, and numeric fields for the selected point.
//!
//! Mouse: drag a point to move it; double-click to add one (on the curve area: opacity,
//! on the bar: colour); right-click a point to remove it.

use egui::{Color32, Pos2, Rect, Sense, Stroke, Vec2};
use volterra::scene::presets::{Preset, ValueStats};
use volterra::scene::TransferFunction;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Selected {
    Opacity(usize),
    Color(usize),
}

#[derive(Default)]
pub struct TfEditor {
    pub selected: Option<Selected>,
    dragging: Option<Selected>,
    /// The preset the user chose last (taken by the caller, which saves it by name).
    pub chosen_preset: Option<Preset>,
}

const HANDLE_PX: f32 = 7.0;

/// A linear colour component as an 8-bit sRGB value (clamped to [0, 1], rounded).
pub(crate) fn srgb(c: f64) -> u8 {
    (volterra_formats::image::linear_to_srgb(c.clamp(0.0, 1.0) as f32) * 255.0).round() as u8
}

impl TfEditor {
    /// Shows the editor; returns true if `tf` changed.
    pub fn show(&mut self, ui: &mut egui::Ui, tf: &mut TransferFunction, stats: &ValueStats) -> bool {
        let mut changed = false;
        egui::ComboBox::from_label("Preset").selected_text("choose…").show_ui(ui, |ui| {
            for p in Preset::ALL {
                if ui.selectable_label(false, p.name()).clicked() {
                    *tf = p.transfer_function(stats, tf.scalar_opacity_unit_distance);
                    self.selected = None;
                    self.chosen_preset = Some(p);
                    changed = true;
                }
            }
        });
        let (lo, hi) = (stats.min, if stats.max > stats.min { stats.max } else { stats.min + 1.0 });
        let width = ui.available_width().max(120.0);
        let (resp, painter) = ui.allocate_painter(Vec2::new(width, 120.0), Sense::click_and_drag());
        let area = resp.rect;
        let (bar_resp, bar_painter) = ui.allocate_painter(Vec2::new(width, 22.0), Sense::click_and_drag());
        let bar = bar_resp.rect;
        let x_of = |v: f64| area.left() + ((v - lo) / (hi - lo)) as f32 * area.width();
        let v_of = |x: f32| lo + ((x - area.left()) / area.width()) as f64 * (hi - lo);
        let y_of = |a: f64| area.bottom() - a as f32 * area.height();
        let a_of = |y: f32| ((area.bottom() - y) / area.height()) as f64;

        // Histogram, log scale.
        painter.rect_filled(area, 2.0, ui.visuals().extreme_bg_color);
        let max_log = stats.histogram.iter().map(|&c| ((c + 1) as f32).ln()).fold(0.0, f32::max).max(1e-6);
        let bins = stats.histogram.len() as f32;
        for (b, &c) in stats.histogram.iter().enumerate() {
            if c == 0 {
                continue;
            }
            let h = ((c + 1) as f32).ln() / max_log * area.height();
            let x0 = area.left() + b as f32 / bins * area.width();
            let x1 = area.left() + (b + 1) as f32 / bins * area.width();
            painter.rect_filled(
                Rect::from_min_max(Pos2::new(x0, area.bottom() - h), Pos2::new(x1, area.bottom())),
                0.0,
                Color32::from_gray(70),
            );
        }
        // Opacity curve, extended flat to the range ends as the function clamps.
        let pts: Vec<Pos2> = std::iter::once(Pos2::new(area.left(), y_of(tf.opacity(lo))))
            .chain(tf.scalar_opacity.iter().map(|p| Pos2::new(x_of(p[0]).clamp(area.left(), area.right()), y_of(p[1]))))
            .chain(std::iter::once(Pos2::new(area.right(), y_of(tf.opacity(hi)))))
            .collect();
        painter.add(egui::Shape::line(pts, Stroke::new(1.5, Color32::WHITE)));
        for (i, p) in tf.scalar_opacity.iter().enumerate() {
            let c = tf.color(p[0]);
            let fill = Color32::from_rgb(srgb(c[0]), srgb(c[1]), srgb(c[2]));
            let pos = Pos2::new(x_of(p[0]), y_of(p[1]));
            let ring = if self.selected == Some(Selected::Opacity(i)) { Color32::YELLOW } else { Color32::WHITE };
            painter.circle(pos, 4.5, fill, Stroke::new(1.5, ring));
        }
        // Colour bar: the colour map, with the opacity shown against a dark ground.
        let steps = bar.width().max(1.0) as usize;
        for s in 0..steps {
            let v = lo + (s as f64 + 0.5) / steps as f64 * (hi - lo);
            let c = tf.color(v);
            let x = bar.left() + s as f32;
            bar_painter.rect_filled(
                Rect::from_min_max(Pos2::new(x, bar.top()), Pos2::new(x + 1.0, bar.bottom() - 6.0)),
                0.0,
                Color32::from_rgb(srgb(c[0]), srgb(c[1]), srgb(c[2])),
            );
        }
        for (i, p) in tf.color.iter().enumerate() {
            let x = x_of(p[0]);
            let ring = if self.selected == Some(Selected::Color(i)) { Color32::YELLOW } else { Color32::WHITE };
            let tip = Pos2::new(x, bar.bottom() - 7.0);
            bar_painter.add(egui::Shape::convex_polygon(
                vec![tip, Pos2::new(x - 4.0, bar.bottom()), Pos2::new(x + 4.0, bar.bottom())],
                Color32::from_rgb(srgb(p[1]), srgb(p[2]), srgb(p[3])),
                Stroke::new(1.0, ring),
            ));
        }

        // Interaction on the curve area.
        let nearest_opacity = |pos: Pos2, tf: &TransferFunction| {
            tf.scalar_opacity
                .iter()
                .enumerate()
                .map(|(i, p)| (i, Pos2::new(x_of(p[0]), y_of(p[1])).distance(pos)))
                .filter(|&(_, d)| d <= HANDLE_PX)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(i, _)| i)
        };
        let nearest_color = |pos: Pos2, tf: &TransferFunction| {
            tf.color
                .iter()
                .enumerate()
                .map(|(i, p)| (i, (x_of(p[0]) - pos.x).abs()))
                .filter(|&(_, d)| d <= HANDLE_PX)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(i, _)| i)
        };
        if let Some(pos) = resp.interact_pointer_pos() {
            if resp.drag_started() || resp.clicked() {
                self.dragging = nearest_opacity(pos, tf).map(Selected::Opacity);
                if self.dragging.is_some() {
                    self.selected = self.dragging;
                }
            }
            if resp.double_clicked() && nearest_opacity(pos, tf).is_none() {
                let v = v_of(pos.x).clamp(lo, hi);
                let a = a_of(pos.y).clamp(0.0, 1.0);
                let at = tf.scalar_opacity.iter().position(|p| p[0] > v).unwrap_or(tf.scalar_opacity.len());
                tf.scalar_opacity.insert(at, [v, a]);
                self.selected = Some(Selected::Opacity(at));
                changed = true;
            }
            if resp.secondary_clicked() {
                if let Some(i) = nearest_opacity(pos, tf).filter(|_| tf.scalar_opacity.len() > 1) {
                    tf.scalar_opacity.remove(i);
                    self.selected = None;
                    changed = true;
                }
            }
            if resp.dragged() {
                if let Some(Selected::Opacity(i)) = self.dragging {
                    changed |= move_point(&mut tf.scalar_opacity, i, v_of(pos.x), |p| p[1] = a_of(pos.y).clamp(0.0, 1.0));
                }
            }
        }
        if let Some(pos) = bar_resp.interact_pointer_pos() {
            if bar_resp.drag_started() || bar_resp.clicked() {
                self.dragging = nearest_color(pos, tf).map(Selected::Color);
                if self.dragging.is_some() {
                    self.selected = self.dragging;
                }
            }
            if bar_resp.double_clicked() && nearest_color(pos, tf).is_none() {
                let v = v_of(pos.x).clamp(lo, hi);
                let c = tf.color(v);
                let at = tf.color.iter().position(|p| p[0] > v).unwrap_or(tf.color.len());
                tf.color.insert(at, [v, c[0], c[1], c[2]]);
                self.selected = Some(Selected::Color(at));
                changed = true;
            }
            if bar_resp.secondary_clicked() {
                if let Some(i) = nearest_color(pos, tf).filter(|_| tf.color.len() > 1) {
                    tf.color.remove(i);
                    self.selected = None;
                    changed = true;
                }
            }
            if bar_resp.dragged() {
                if let Some(Selected::Color(i)) = self.dragging {
                    changed |= move_point(&mut tf.color, i, v_of(pos.x), |_| {});
                }
            }
        }
        if !ui.input(|i| i.pointer.any_down()) {
            self.dragging = None;
        }

        // The selected point, numerically.
        match self.selected {
            Some(Selected::Opacity(i)) if i < tf.scalar_opacity.len() => {
                ui.horizontal(|ui| {
                    ui.label("Opacity point: value");
                    let mut v = tf.scalar_opacity[i][0];
                    if ui.add(egui::DragValue::new(&mut v).speed((hi - lo) / 500.0)).changed() {
                        changed |= move_point(&mut tf.scalar_opacity, i, v, |_| {});
                    }
                    let lbl = ui.label("opacity");
                    changed |= ui
                        .add(egui::DragValue::new(&mut tf.scalar_opacity[i][1]).speed(0.005).range(0.0..=1.0))
                        .labelled_by(lbl.id)
                        .changed();
                });
            }
            Some(Selected::Color(i)) if i < tf.color.len() => {
                ui.horizontal(|ui| {
                    ui.label("Colour point: value");
                    let mut v = tf.color[i][0];
                    if ui.add(egui::DragValue::new(&mut v).speed((hi - lo) / 500.0)).changed() {
                        changed |= move_point(&mut tf.color, i, v, |_| {});
                    }
                    let p = tf.color[i];
                    let mut rgb = [p[1] as f32, p[2] as f32, p[3] as f32];
                    if ui.color_edit_button_rgb(&mut rgb).changed() {
                        tf.color[i] = [p[0], rgb[0] as f64, rgb[1] as f64, rgb[2] as f64];
                        changed = true;
                    }
                });
            }
            _ => {
                ui.label(egui::RichText::new("drag points · double-click adds · right-click removes").weak());
            }
        }
        ui.horizontal(|ui| {
            // Slicer's "Shift": drag to move the whole function along the value axis.
            let lbl = ui.label("Shift all points");
            let mut shift = 0.0;
            if ui.add(egui::DragValue::new(&mut shift).speed((hi - lo) / 500.0)).labelled_by(lbl.id).changed() && shift != 0.0 {
                tf.scalar_opacity.iter_mut().for_each(|p| p[0] += shift);
                tf.color.iter_mut().for_each(|p| p[0] += shift);
                changed = true;
            }
        });
        ui.horizontal(|ui| {
            let lbl = ui.label("Opacity unit distance (mm)");
            changed |= ui
                .add(egui::DragValue::new(&mut tf.scalar_opacity_unit_distance).speed(0.01).range(0.001..=1000.0))
                .labelled_by(lbl.id)
                .changed();
        });
        changed |= gradient_opacity(ui, tf, hi - lo);
        changed
    }
}

/// VTK's gradient opacity: a factor on the opacity per unit distance by the gradient's
/// magnitude (value units per mm), piecewise linear. Switched on it starts at 1 everywhere
/// (the picture unchanged, as Slicer's default); lowering the factor at small gradients
/// fades homogeneous regions and keeps edges. `range`: the data's value span, for the
/// drag speed and the second point's place (the span over 20 mm).
fn gradient_opacity(ui: &mut egui::Ui, tf: &mut TransferFunction, range: f64) -> bool {
    let mut changed = false;
    let mut on = !tf.gradient_opacity.is_empty();
    if ui.checkbox(&mut on, "Gradient opacity").changed() {
        tf.gradient_opacity = if on { vec![[0.0, 1.0], [range / 20.0, 1.0]] } else { Vec::new() };
        changed = true;
    }
    let mut remove = None;
    let n = tf.gradient_opacity.len();
    for i in 0..n {
        ui.horizontal(|ui| {
            let lbl = ui.label(format!("gradient {}", i + 1));
            let mut g = tf.gradient_opacity[i][0];
            if ui.add(egui::DragValue::new(&mut g).speed(range / 2000.0).range(0.0..=f64::MAX).suffix(" /mm")).labelled_by(lbl.id).changed()
            {
                changed |= move_point(&mut tf.gradient_opacity, i, g, |_| {});
            }
            if n > 1 && ui.small_button("remove").on_hover_text("remove this gradient point").clicked() {
                remove = Some(i);
            }
        });
        // On a line of its own: the panel keeps its width.
        changed |= ui.add(egui::Slider::new(&mut tf.gradient_opacity[i][1], 0.0..=1.0).text(format!("factor {}", i + 1))).changed();
    }
    if let Some(i) = remove {
        tf.gradient_opacity.remove(i);
        changed = true;
    }
    if on && ui.button("Add a gradient point").clicked() {
        let last = *tf.gradient_opacity.last().unwrap_or(&[0.0, 1.0]);
        tf.gradient_opacity.push([last[0] + range / 20.0, last[1]]);
        changed = true;
    }
    changed
}

/// Moves point `i` to value `v`, kept between its neighbours so the values still increase;
/// `rest` edits the other fields. Returns true (the function changed).
fn move_point<const N: usize>(pts: &mut [[f64; N]], i: usize, v: f64, rest: impl FnOnce(&mut [f64; N])) -> bool {
    let lo = if i > 0 { pts[i - 1][0] } else { f64::NEG_INFINITY };
    let hi = if i + 1 < pts.len() { pts[i + 1][0] } else { f64::INFINITY };
    if v.is_finite() {
        pts[i][0] = v.clamp(lo, hi);
    }
    rest(&mut pts[i]);
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moved_points_stay_between_their_neighbours() {
        let mut pts = vec![[0.0, 0.0], [10.0, 0.5], [20.0, 1.0]];
        move_point(&mut pts, 1, 25.0, |p| p[1] = 0.7);
        assert_eq!(pts[1], [20.0, 0.7]);
        move_point(&mut pts, 0, -5.0, |_| {});
        assert_eq!(pts[0][0], -5.0);
    }
}
