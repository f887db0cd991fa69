//! The catalogue of renderers: each one declared once (`RendererDecl`: its name, the node
//! kind it draws, whether it is a brute-force reference, its settings, in one file per
//! renderer beside this one), and the typed settings a node holds once its scene is loaded
//! ([`NodeSettings`]). It sits below both the scene and the renderers: the scene loader
//! checks a node's settings against it, each renderer (`render::<name>`) reads its own
//! `Settings` from it, and the viewer, the benches and the settings tables of
//! docs/scene-format.md list what it holds. It knows nothing of either, so imports run one
//! way: render → scene → catalog.

pub mod gpu_volume;
pub mod points;
pub mod reference_volume;
pub mod shear_warp;
pub mod smoke;
pub mod terrain;

use crate::settings::{SettingDecl, SettingError};
use serde::{Deserialize, Serialize};

/// What a scene node holds, and so which renderers can draw it.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum NodeKind {
    Group,
    Volume,
    Heightfield,
    Particles,
}

/// One renderer.
pub struct RendererDecl {
    pub name: &'static str,
    pub kind: NodeKind,
    /// What it is, in a sentence or two (for `volterra renderers` and the docs).
    pub doc: &'static str,
    /// The brute-force reference its kind's other renderers are measured against.
    pub reference: bool,
    pub settings: &'static [SettingDecl],
    /// A node's settings table to the renderer's typed settings.
    pub parse: fn(&toml::Table) -> Result<NodeSettings, SettingError>,
    /// For a heightfield renderer that reads a GeoTIFF row by row into memory of its own
    /// (the GPU's): the bytes it holds for a level of so many samples, by which the scene
    /// chooses the level that fits the memory limit. None: it draws the heightfield read whole.
    pub heights_held: Option<fn(u64) -> u64>,
}

/// A node's settings, checked and typed, tagged by the renderer that draws it.
#[derive(Debug, Clone, PartialEq)]
pub enum NodeSettings {
    Reference(reference_volume::Settings),
    ShearWarp(shear_warp::Settings),
    GpuRaycast(gpu_volume::Settings),
    Terrain(terrain::Settings),
    TerrainReference(terrain::ReferenceSettings),
    Smoke(smoke::Settings),
    Points(points::Settings),
}

/// Every renderer. For each node kind the first listed is the one a node that names no
/// renderer gets.
pub const RENDERERS: &[RendererDecl] = &[
    shear_warp::RENDERER,
    reference_volume::RENDERER,
    gpu_volume::RENDERER,
    terrain::RENDERER,
    terrain::REFERENCE_RENDERER,
    points::RENDERER,
    smoke::RENDERER,
];

pub fn find(name: &str) -> Option<&'static RendererDecl> {
    RENDERERS.iter().find(|r| r.name == name)
}

/// The renderer a node of `kind` that names none gets.
pub fn default_for(kind: NodeKind) -> Option<&'static RendererDecl> {
    RENDERERS.iter().find(|r| r.kind == kind)
}

/// The fast renderer for `kind` (the first that is not a reference): what a scene made
/// for a data file, and the viewer, use.
pub fn fast_for(kind: NodeKind) -> Option<&'static RendererDecl> {
    RENDERERS.iter().find(|r| r.kind == kind && !r.reference)
}

/// The brute-force reference for `kind`, if it has one in-process.
pub fn reference_for(kind: NodeKind) -> Option<&'static RendererDecl> {
    RENDERERS.iter().find(|r| r.kind == kind && r.reference)
}

/// The renderers that draw `kind`.
pub fn for_kind(kind: NodeKind) -> impl Iterator<Item = &'static RendererDecl> {
    RENDERERS.iter().filter(move |r| r.kind == kind)
}

/// The renderer that draws a node of `kind` naming `renderer` (or its kind's default), with
/// `settings` as its settings table; None for groups. Errors name what is wrong, not the
/// node (the caller adds it).
pub fn resolve(kind: NodeKind, renderer: Option<&str>, settings: &toml::Table) -> Result<Option<&'static RendererDecl>, String> {
    if kind == NodeKind::Group {
        if renderer.is_some() || !settings.is_empty() {
            return Err("a group is not drawn: it takes no renderer or settings".into());
        }
        return Ok(None);
    }
    let decl = match renderer {
        Some(name) => find(name).ok_or_else(|| {
            let names: Vec<&str> = RENDERERS.iter().map(|r| r.name).collect();
            format!("unknown renderer '{name}' (known: {})", names.join(", "))
        })?,
        None => default_for(kind).ok_or_else(|| format!("no renderer draws {kind:?} nodes"))?,
    };
    if decl.kind != kind {
        return Err(format!("renderer '{}' draws {:?} nodes, not {kind:?}", decl.name, decl.kind));
    }
    Ok(Some(decl))
}

/// `table` reduced to what `to` should keep when a node drawn by `from` is redrawn by it:
/// the settings both declare that are part of the picture, not quality knobs.
pub fn carry_over(from: &RendererDecl, to: &RendererDecl, table: &toml::Table) -> toml::Table {
    let keeps = |key: &str| {
        let decl = |r: &RendererDecl| r.settings.iter().find(|d| d.key == key).copied();
        matches!((decl(from), decl(to)), (Some(a), Some(b)) if !a.quality && !b.quality)
    };
    table.iter().filter(|(k, _)| keeps(k)).map(|(k, v)| (k.clone(), v.clone())).collect()
}

/// The settings tables of docs/scene-format.md, one per renderer (checked by a test).
pub fn markdown() -> String {
    let mut out = String::new();
    for r in RENDERERS {
        out += &format!("### `{}`: draws `{}` nodes\n\n{}\n\n", r.name, format!("{:?}", r.kind).to_lowercase(), r.doc);
        if r.settings.is_empty() {
            out += "No settings.\n\n";
            continue;
        }
        out += "| setting | type | default | allowed | meaning |\n|---|---|---|---|---|\n";
        for d in r.settings {
            let unit = if d.unit.is_empty() { String::new() } else { format!(" {}", d.unit) };
            let allowed: Vec<String> =
                [d.range.map(|b| format!("{b}{unit}")), d.zero.map(|z| format!("0 = {z}"))].into_iter().flatten().collect();
            let allowed = allowed.join("; ");
            let mut meaning = d.summary();
            if let crate::settings::SettingType::Choice(choices) = d.ty {
                let each: Vec<String> = choices.iter().map(|c| format!("`{}`: {}", c.name, crate::settings::summary(c.doc))).collect();
                meaning += &format!(" {}", each.join(" "));
            }
            let default = match (d.default)() {
                crate::settings::Value::Choice(c) => format!("`{c}`"),
                v => format!("{v}"),
            };
            out += &format!(
                "| `{}` | {} | {default} | {allowed} | {} |\n",
                d.key,
                d.ty.describe().replace('|', "\\|"),
                meaning.replace('|', "\\|")
            );
        }
        out += "\n";
    }
    out
}

/// What `markdown` tables, as JSON (`volterra renderers --json`): one object per renderer,
/// each setting with its type, default, unit, allowed range, what 0 means and its doc.
pub fn json() -> serde_json::Value {
    use crate::settings::{SettingType, Value};
    let value = |v: Value| match v {
        Value::Float(x) => serde_json::json!(x),
        Value::Integer(i) => serde_json::json!(i),
        Value::Bool(b) => serde_json::json!(b),
        Value::Choice(c) => serde_json::json!(c),
    };
    let renderers: Vec<serde_json::Value> = RENDERERS
        .iter()
        .map(|r| {
            let settings: Vec<serde_json::Value> = r
                .settings
                .iter()
                .map(|d| {
                    let (ty, choices) = match d.ty {
                        SettingType::Float => ("number", vec![]),
                        SettingType::Integer => ("integer", vec![]),
                        SettingType::Bool => ("boolean", vec![]),
                        SettingType::Choice(c) => {
                            ("choice", c.iter().map(|c| serde_json::json!({"name": c.name, "doc": c.doc.trim()})).collect())
                        }
                    };
                    serde_json::json!({
                        "key": d.key,
                        "type": ty,
                        "choices": choices,
                        "default": value((d.default)()),
                        "unit": d.unit,
                        "range": d.range.map(|b| b.to_string()),
                        "zero": d.zero,
                        "quality": d.quality,
                        "doc": d.doc.trim(),
                    })
                })
                .collect();
            serde_json::json!({
                "name": r.name,
                "kind": format!("{:?}", r.kind).to_lowercase(),
                "reference": r.reference,
                "default_for_kind": default_for(r.kind).is_some_and(|d| d.name == r.name),
                "doc": r.doc,
                "settings": settings,
            })
        })
        .collect();
    serde_json::Value::Array(renderers)
}
