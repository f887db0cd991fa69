//! How a volume node's values are classified and cut: its preset, transfer function,
//! cropping and shading.

use super::*;

impl Scene {
    /// The preset that classifies volume node `node` when it gives no transfer function:
    /// the one it names, else the one for its modality (the node's `modality`, else the
    /// file's). Reads the data (for its modality and values) only when none is named.
    pub fn preset(&self, node: usize) -> Result<presets::Preset> {
        let n = &self.file.nodes[node];
        if let Some(p) = &n.preset {
            return presets::Preset::from_name(p).map_err(|m| anyhow!("node '{}': {m}", n.name));
        }
        let NodeData::Volume(v) = self.data(node)? else { bail!("node '{}' is not a volume", n.name) };
        let modality = n.modality.as_deref().or(v.modality.as_deref());
        Ok(presets::Preset::for_modality(modality, &*self.value_stats(node)?))
    }

    /// The transfer function that classifies volume node `node`: its own, else its preset's
    /// (see `preset`) placed on its data (the smallest voxel spacing as unit distance, as
    /// Slicer sets it), moved by `preset_shift`.
    pub fn transfer_function(&self, node: usize) -> Result<TransferFunction> {
        let n = &self.file.nodes[node];
        if let Some(tf) = &n.transfer_function {
            return Ok(tf.clone());
        }
        let preset = self.preset(node)?;
        let NodeData::Volume(v) = self.data(node)? else { bail!("node '{}' is not a volume", n.name) };
        let unit = v.spacing.iter().cloned().fold(f64::INFINITY, f64::min);
        Ok(preset.shifted(&*self.value_stats(node)?, unit, n.preset_shift))
    }

    /// The transfer function volume node `node` is drawn with: `transfer_function`'s,
    /// its extinction scaled by the node's `opacity_scale`.
    pub fn classification(&self, node: usize) -> Result<TransferFunction> {
        let mut tf = self.transfer_function(node)?;
        let s = self.file.nodes[node].opacity_scale;
        if s != 1.0 {
            // s = 0: an unreachable unit distance, every segment's opacity 0.
            tf.scalar_opacity_unit_distance = if s > 0.0 { tf.scalar_opacity_unit_distance / s } else { f64::MAX };
        }
        Ok(tf)
    }

    /// The region volume node `node` keeps (its crop box and clipping planes) as
    /// half-spaces in its own coordinates; empty: all of it.
    pub fn crop_region(&self, node: usize) -> Vec<HalfSpace> {
        let n = &self.file.nodes[node];
        crop::region(n.crop.as_ref(), &n.clip)
    }

    /// The shading of volume node `node`: its own `[node.shading]`, else the shading of its
    /// preset (named, or its modality's when it gives no transfer function; a transfer
    /// function given as points comes with none).
    pub fn shading(&self, node: usize) -> Option<VolumeShading> {
        let n = &self.file.nodes[node];
        if n.shading.is_some() || n.transfer_function.is_some() {
            return n.shading;
        }
        self.preset(node).ok().and_then(presets::Preset::shading)
    }
}
