//! Reading a scene file's text: TOML errors as one line naming the file and line, unknown
//! keys with the nearest known one suggested, `--set` overrides, and where each setting
//! was written (for messages about it).

use super::*;

/// The line (1-based) of a byte offset in `text`.
pub(super) fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].bytes().filter(|&b| b == b'\n').count() + 1
}

pub(super) fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Parses TOML text into `T`, turning errors into one line that names the file and line;
/// an unknown key gets the nearest known one suggested (and in a node, the keys its kind
/// takes).
pub(super) fn parse_toml<T: serde::de::DeserializeOwned>(text: &str, path: &Path) -> Result<T> {
    toml::from_str(text).map_err(|e| {
        let line = e.span().map(|s| format!(" line {}", line_of(text, s.start))).unwrap_or_default();
        let message = one_line(e.message());
        let message = e.span().and_then(|s| unknown_key_message(text, s.start, &message)).unwrap_or(message);
        anyhow!("{}:{line}: {message}", path.display())
    })
}

/// The keys a node of each kind takes (besides those every node takes).
const NODE_KEYS: [&str; 8] = ["name", "kind", "file", "parent", "transform", "renderer", "visible", "settings"];
pub(super) fn node_kind_keys(kind: &str) -> &'static [&'static str] {
    match kind {
        "volume" => &[
            "series",
            "volume_index",
            "resample",
            "transfer_function",
            "preset",
            "preset_shift",
            "modality",
            "shading",
            "crop",
            "clip",
            "blend",
            "opacity_scale",
        ],
        "heightfield" => &["png", "extent", "texture", "texture_colormap", "texture_range", "elevation_range"],
        "particles" => &["arrays", "medium", "color_by", "color_range", "scale_over"],
        _ => &[],
    }
}

/// Every `[[node]]`'s keys against the keys its kind takes: a key another kind takes, or
/// none does, is refused with its line, the nearest key of the kind suggested, and the
/// kind's keys listed (serde would list every key of every kind, or accept a volume's
/// `preset` on a particle node to refuse it later without a line).
pub(super) fn check_node_keys(text: &str, path: &Path) -> Result<()> {
    let Ok(doc) = toml::from_str::<toml::Table>(text) else { return Ok(()) };
    let Some(nodes) = doc.get("node").and_then(|n| n.as_array()) else { return Ok(()) };
    // Where each [[node]] block starts in the text.
    let starts: Vec<usize> = text.match_indices("[[node]]").map(|(i, _)| i).collect();
    for (k, node) in nodes.iter().enumerate() {
        let Some(table) = node.as_table() else { continue };
        let kind = table.get("kind").and_then(|v| v.as_str()).unwrap_or("");
        let allowed: Vec<&str> = NODE_KEYS.iter().chain(node_kind_keys(kind)).copied().collect();
        for (key, value) in table {
            if allowed.contains(&key.as_str()) || (kind.is_empty() || !matches!(kind, "volume" | "heightfield" | "particles" | "group")) {
                continue;
            }
            // Scenes saved before these were skipped at their defaults carry them on every
            // node: harmless there.
            let default = match key.as_str() {
                "volume_index" => value.as_integer() == Some(0),
                "resample" => value.as_bool() == Some(false),
                "blend" => value.as_str() == Some("composite"),
                _ => false,
            };
            if default {
                continue;
            }
            let block = starts.get(k).map_or(0, |&s| s);
            let line = text[block..].lines().position(|l| l.trim_start().starts_with(key.as_str())).map(|n| line_of(text, block) + n);
            let at = line.map(|l| format!(" line {l}:")).unwrap_or_default();
            let nearest = allowed.iter().map(|k| (edit_distance(key, k), *k)).min().filter(|(d, _)| *d <= 2.max(key.len() / 3));
            let hint = nearest.map(|(_, k)| format!(" (did you mean `{k}`?)")).unwrap_or_default();
            let name = table.get("name").and_then(|v| v.as_str()).unwrap_or("?");
            bail!("{}:{at} node '{name}': unknown key `{key}`{hint}; a {kind} node takes: {}", path.display(), allowed.join(", "));
        }
    }
    Ok(())
}

/// Edits (insertions, deletions, substitutions) between two words.
pub(super) fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let here = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != *cb)).min(row[j] + 1).min(here + 1);
            prev = here;
        }
    }
    row[b.len()]
}

/// serde's "unknown field `x`, expected one of …" made useful: the nearest known key
/// suggested, and inside a `[[node]]` only the keys that node's kind takes listed.
pub(super) fn unknown_key_message(text: &str, at: usize, message: &str) -> Option<String> {
    let key = message.strip_prefix("unknown field `")?.split('`').next()?.to_string();
    let expected: Vec<String> = message.split("expected one of ").nth(1)?.split(", ").map(|k| k.trim_matches('`').to_string()).collect();
    // The [[node]] the key is in, if any: its kind, read from its lines.
    let before = &text[..at.min(text.len())];
    let header = before.rfind("\n[")?;
    let in_node = before[header..].trim_start().starts_with("[[node]]");
    let (listed, what): (Vec<String>, String) = if in_node {
        let block_end = text[header + 1..].find("\n[").map_or(text.len(), |e| header + 1 + e);
        let kind = text[header..block_end]
            .lines()
            .find_map(|l| l.trim().strip_prefix("kind").map(|r| r.trim_start_matches([' ', '=']).trim().trim_matches('"').to_string()))
            .unwrap_or_default();
        let keys: Vec<String> = NODE_KEYS.iter().chain(node_kind_keys(&kind)).map(|k| k.to_string()).collect();
        let what = if kind.is_empty() { "a node takes".to_string() } else { format!("a {kind} node takes") };
        (keys, what)
    } else {
        (expected, "known keys".to_string())
    };
    let nearest = listed.iter().map(|k| (edit_distance(&key, k), k)).min()?;
    let hint = if nearest.0 <= 2.max(key.len() / 3) { format!(" (did you mean `{}`?)", nearest.1) } else { String::new() };
    Some(format!("unknown key `{key}`{hint}; {what}: {}", listed.join(", ")))
}

/// Applies `key=value` overrides to a parsed TOML document. Keys are dotted paths;
/// `node.NAME.rest` addresses the node whose name is NAME. Values are TOML (strings may
/// be given bare).
pub fn apply_overrides(doc: &mut toml::Table, sets: &[String]) -> Result<()> {
    for set in sets {
        let (key, raw) = set.split_once('=').ok_or_else(|| anyhow!("--set {set}: expected key=value"))?;
        let value: toml::Value = match toml::from_str::<toml::Table>(&format!("v = {raw}")) {
            Ok(mut t) => t.remove("v").unwrap(),
            Err(_) => toml::Value::String(raw.to_string()),
        };
        let parts: Vec<&str> = key.split('.').collect();
        let mut table: &mut toml::Table = doc;
        let mut rest = &parts[..];
        if parts.first() == Some(&"node") && parts.len() >= 3 {
            let nodes =
                table.get_mut("node").and_then(|n| n.as_array_mut()).ok_or_else(|| anyhow!("--set {key}: the scene has no nodes"))?;
            let node = nodes
                .iter_mut()
                .find(|n| n.get("name").and_then(|v| v.as_str()) == Some(parts[1]))
                .ok_or_else(|| anyhow!("--set {key}: no node named '{}'", parts[1]))?;
            table = node.as_table_mut().unwrap();
            rest = &parts[2..];
        }
        for p in &rest[..rest.len() - 1] {
            let entry = table.entry(p.to_string()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
            table = entry.as_table_mut().ok_or_else(|| anyhow!("--set {key}: '{p}' is not a table"))?;
        }
        table.insert(rest[rest.len() - 1].to_string(), value);
    }
    Ok(())
}

/// Where a scene file's text sets each node's renderer and settings, for errors that
/// name the line. Empty for scenes built in code.
#[derive(Default)]
pub(super) struct SettingLines {
    /// Per node name: the line of the node's `renderer` (or of its name) and of each setting.
    nodes: HashMap<String, (usize, HashMap<String, usize>)>,
}

impl SettingLines {
    pub(super) fn of(text: &str) -> SettingLines {
        #[derive(Deserialize)]
        struct Node {
            name: toml::Spanned<String>,
            renderer: Option<toml::Spanned<toml::Value>>,
            #[serde(default)]
            settings: HashMap<String, toml::Spanned<toml::Value>>,
        }
        #[derive(Deserialize)]
        struct Doc {
            #[serde(default)]
            node: Vec<Node>,
        }
        let Ok(doc) = toml::from_str::<Doc>(text) else { return SettingLines::default() };
        let nodes = doc
            .node
            .into_iter()
            .map(|n| {
                let at = n.renderer.as_ref().map(|r| r.span().start).unwrap_or(n.name.span().start);
                let keys = n.settings.iter().map(|(k, v)| (k.clone(), line_of(text, v.span().start))).collect();
                (n.name.into_inner(), (line_of(text, at), keys))
            })
            .collect();
        SettingLines { nodes }
    }

    /// " line N" for the node's setting `key` (or its renderer), or " (from --set)" for a
    /// setting the file does not hold; empty when the scene has no text.
    pub(super) fn at(&self, node: &str, key: Option<&str>) -> String {
        if self.nodes.is_empty() {
            return String::new();
        }
        match (self.nodes.get(node), key) {
            (Some((_, keys)), Some(k)) => keys.get(k).map(|l| format!(" line {l}")).unwrap_or_else(|| " (from --set)".into()),
            (Some((line, _)), None) => format!(" line {line}"),
            (None, _) => " (from --set)".into(),
        }
    }
}
