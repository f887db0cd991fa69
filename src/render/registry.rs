//! The renderers, each declared once by its own module ([`RendererDecl`]: name, the node
//! kind it draws, whether it is a brute-force reference, its settings), and the typed
//! settings a node holds once its scene is loaded ([`NodeSettings`]). Everything that
//! names a renderer or a setting — the scene loader, `render_node`, the viewer, the
//! benches, the settings tables in docs/scene-format.md — reads it from here.

use super::settings::{SettingDecl, SettingError};
use super::{points, reference_volume, shear_warp, smoke, terrain};
use crate::scene::{NodeDesc, NodeKind};

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
}

/// A node's settings, checked and typed, tagged by the renderer that draws it.
#[derive(Debug, Clone, PartialEq)]
pub enum NodeSettings {
    Reference(reference_volume::Settings),
    ShearWarp(shear_warp::Settings),
    Terrain(terrain::Settings),
    TerrainReference(terrain::ReferenceSettings),
    Smoke(smoke::Settings),
    Points(points::Settings),
}

/// Every renderer. For each node kind the first listed is the one a node that names no
/// renderer gets.
pub const RENDERERS: &[RendererDecl] =
    &[shear_warp::RENDERER, reference_volume::RENDERER, terrain::RENDERER, terrain::REFERENCE_RENDERER, points::RENDERER, smoke::RENDERER];

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

/// The renderer that draws `node` (the one it names, or its kind's default); None for
/// groups. Errors name what is wrong, not the node (the caller adds it).
pub fn resolve(node: &NodeDesc) -> Result<Option<&'static RendererDecl>, String> {
    if node.kind == NodeKind::Group {
        if node.renderer.is_some() || !node.settings.is_empty() {
            return Err("a group is not drawn: it takes no renderer or settings".into());
        }
        return Ok(None);
    }
    let decl = match &node.renderer {
        Some(name) => find(name).ok_or_else(|| {
            let names: Vec<&str> = RENDERERS.iter().map(|r| r.name).collect();
            format!("unknown renderer '{name}' (known: {})", names.join(", "))
        })?,
        None => default_for(node.kind).ok_or_else(|| format!("no renderer draws {:?} nodes", node.kind))?,
    };
    if decl.kind != node.kind {
        return Err(format!("renderer '{}' draws {:?} nodes, not {:?}", decl.name, decl.kind, node.kind));
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
            if let super::settings::SettingType::Choice(choices) = d.ty {
                let each: Vec<String> = choices.iter().map(|c| format!("`{}`: {}", c.name, super::settings::summary(c.doc))).collect();
                meaning += &format!(" {}", each.join(" "));
            }
            let default = match (d.default)() {
                super::settings::Value::Choice(c) => format!("`{c}`"),
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
