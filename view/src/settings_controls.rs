//! The viewer's controls for renderer settings, built from the renderers' declarations:
//! every setting declared with a `viewer` control gets its widget, in declaration order.

use volterra::catalog::RendererDecl;
use volterra::settings::{self, SettingDecl, SettingType, Value, Widget};

/// A setting the user changed: its key, the new value, and whether a drag is still going
/// on (the viewer then draws a quick preview).
pub struct Change {
    pub key: &'static str,
    pub value: toml::Value,
    pub moving: bool,
}

/// Draws the controls `renderer` declares for a node whose settings are `table`.
pub fn show(ui: &mut egui::Ui, renderer: &RendererDecl, table: &toml::Table) -> Option<Change> {
    show_some(ui, renderer.settings.iter(), table)
}

/// Draws the controls of the settings `decls` (some of a renderer's) for `table`.
pub fn show_some<'a>(ui: &mut egui::Ui, decls: impl Iterator<Item = &'a SettingDecl>, table: &toml::Table) -> Option<Change> {
    let mut change = None;
    for d in decls {
        let Some(control) = d.viewer else { continue };
        let mut set = |value: Value, moving: bool| change = Some(Change { key: d.key, value: value.to_toml(), moving });
        match (d.ty, settings::current(d, table)) {
            (SettingType::Bool, Value::Bool(mut b)) => {
                if ui.checkbox(&mut b, control.label).changed() {
                    set(Value::Bool(b), false);
                }
            }
            (SettingType::Choice(choices), Value::Choice(current)) => {
                let mut pick = None;
                egui::ComboBox::from_label(control.label).selected_text(current).show_ui(ui, |ui| {
                    for c in choices {
                        if ui.selectable_label(current == c.name, c.name).on_hover_text(settings::summary(c.doc)).clicked() {
                            pick = Some(c.name);
                        }
                    }
                });
                if let Some(p) = pick.filter(|p| *p != current) {
                    set(Value::Choice(p), false);
                }
            }
            (ty, value) => {
                let integer = matches!(ty, SettingType::Integer);
                let mut x = value.as_f64().unwrap_or(0.0);
                // What a zero means ("auto"), shown instead of the number.
                let zero = d.zero.map(|z| z.split(':').next().unwrap_or(z).trim().to_string());
                ui.horizontal(|ui| {
                    let label = ui.label(control.label);
                    let r = match control.widget {
                        Widget::Slider { lo, hi, step } => {
                            let mut s = egui::Slider::new(&mut x, lo..=hi).step_by(step);
                            if integer {
                                s = s.integer();
                            }
                            if let Some(z) = zero {
                                s = s.custom_formatter(move |v, _| if v == 0.0 { z.clone() } else { format!("{v:.2}") });
                            }
                            ui.add(s)
                        }
                        Widget::Drag { lo, hi, speed } => {
                            let mut v = egui::DragValue::new(&mut x).speed(speed).range(lo..=hi);
                            if integer {
                                v = v.fixed_decimals(0);
                            }
                            ui.add(v)
                        }
                        Widget::ByType => ui.add(egui::DragValue::new(&mut x)),
                    }
                    .labelled_by(label.id)
                    .on_hover_text(d.summary());
                    if r.changed() {
                        let v = if integer { Value::Integer(x.round() as i64) } else { Value::Float(x) };
                        set(v, r.dragged());
                    }
                });
            }
        }
    }
    change
}
