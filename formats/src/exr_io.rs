//! OpenEXR images: any number of named 32-bit float channels (R, G, B, A, Z, step counts…),
//! written losslessly (ZIP) and atomically; read back for `compare`.

use crate::atomic::write_bytes_atomically;
use crate::error::{FormatError, Result};
use crate::memory::Limits;
use std::path::Path;

/// A float image with named channels, row-major, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct FloatImage {
    pub width: usize,
    pub height: usize,
    /// (name, width·height samples) in the order given; EXR stores them sorted by name.
    pub channels: Vec<(String, Vec<f32>)>,
}

impl FloatImage {
    pub fn new(width: usize, height: usize) -> FloatImage {
        FloatImage { width, height, channels: Vec::new() }
    }
    pub fn channel(&self, name: &str) -> Option<&[f32]> {
        self.channels.iter().find(|(n, _)| n == name).map(|(_, v)| v.as_slice())
    }
    pub fn add_channel(&mut self, name: &str, values: Vec<f32>) {
        assert_eq!(values.len(), self.width * self.height, "channel {name} has the wrong size");
        self.channels.retain(|(n, _)| n != name);
        self.channels.push((name.to_string(), values));
    }
}

pub fn write_exr(path: &Path, img: &FloatImage) -> Result<()> {
    use exr::prelude::*;
    if img.channels.is_empty() {
        return Err(FormatError::invalid(path, "image has no channels to write"));
    }
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> =
        img.channels.iter().map(|(name, v)| AnyChannel::new(name.as_str(), FlatSamples::F32(v.clone()))).collect();
    let layer = Layer::new((img.width, img.height), LayerAttributes::named("volterra"), Encoding::SMALL_LOSSLESS, AnyChannels::sort(list));
    let image = Image::from_layer(layer);
    let mut buf = std::io::Cursor::new(Vec::new());
    image.write().to_buffered(&mut buf).map_err(|e| FormatError::invalid(path, format!("cannot encode EXR: {e}")))?;
    write_bytes_atomically(path, buf.get_ref())
}

pub fn read_exr(path: &Path, limits: &Limits) -> Result<FloatImage> {
    use exr::prelude::*;
    let meta =
        exr::meta::MetaData::read_from_file(path, false).map_err(|e| FormatError::invalid(path, format!("not a readable EXR: {e}")))?;
    let header = meta.headers.first().ok_or_else(|| FormatError::invalid(path, "EXR has no layer"))?;
    let size = header.layer_size;
    limits.check(path, "EXR image", &[size.0 as u64, size.1 as u64, header.channels.list.len() as u64, 4])?;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| FormatError::invalid(path, format!("not a readable EXR: {e}")))?;
    let layer = image.layer_data;
    let (w, h) = (layer.size.0, layer.size.1);
    let channels = layer
        .channel_data
        .list
        .into_iter()
        .map(|c| {
            let v: Vec<f32> = match c.sample_data {
                FlatSamples::F32(v) => v,
                FlatSamples::F16(v) => v.into_iter().map(|x| x.to_f32()).collect(),
                FlatSamples::U32(v) => v.into_iter().map(|x| x as f32).collect(),
            };
            (c.name.to_string(), v)
        })
        .collect();
    Ok(FloatImage { width: w, height: h, channels })
}
