//! Plain images: 8-bit RGB textures in, PNG previews (sRGB, clamped) out, and the PNG
//! decoding shared with PNG heightmaps.

use crate::atomic::write_bytes_atomically;
use crate::error::{FormatError, Result};
use crate::memory::Limits;
use std::path::Path;

/// An 8-bit RGB image, row-major, row 0 at the top.
#[derive(Debug, Clone)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
}

/// A decoded PNG: samples widened to u16 (8-bit values kept as 0..255), channels as stored
/// (1 grey, 2 grey+alpha, 3 RGB, 4 RGBA; palettes expanded to RGB(A)).
pub struct PngSamples {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub bit_depth: u8,
    pub samples: Vec<u16>,
    /// The file stores palette indices (expanded here to the palette's RGB(A) colours).
    pub palette: bool,
}

/// A PNG's width and height, from its header alone.
pub fn png_size(path: &Path) -> Result<(usize, usize)> {
    let file = std::fs::File::open(path).map_err(|e| FormatError::io(path, e))?;
    let reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .map_err(|e| FormatError::invalid(path, format!("invalid PNG: {e}")))?;
    Ok((reader.info().width as usize, reader.info().height as usize))
}

/// Decodes a PNG's samples. `built_per_pixel`: the bytes a pixel the caller builds from
/// the samples while it holds them (a heightmap's elevations, a texture's RGB), counted
/// against the limit with the decoder's buffer and the samples (each pixel's bytes held at
/// once: the buffer and the samples while converting, then the samples and what is built).
pub fn decode_png(path: &Path, limits: &Limits, built_per_pixel: u64) -> Result<PngSamples> {
    let file = std::fs::File::open(path).map_err(|e| FormatError::io(path, e))?;
    let mut dec = png::Decoder::new(std::io::BufReader::new(file));
    dec.set_transformations(png::Transformations::EXPAND);
    let mut reader = dec.read_info().map_err(|e| FormatError::invalid(path, format!("invalid PNG: {e}")))?;
    let (w, h) = (reader.info().width as u64, reader.info().height as u64);
    let palette = reader.info().color_type == png::ColorType::Indexed;
    let (ct, depth) = reader.output_color_type();
    let channels = ct.samples();
    let bytes_per = if depth == png::BitDepth::Sixteen { 2 } else { 1 };
    let (decoded, samples) = (channels as u64 * bytes_per, channels as u64 * 2);
    limits.check(path, "PNG image", &[w, h, samples + decoded.max(built_per_pixel)])?;
    let size = (w * h * decoded) as usize;
    let mut buf = vec![0u8; size.max(reader.output_buffer_size())];
    let frame = reader.next_frame(&mut buf).map_err(|e| FormatError::invalid(path, format!("PNG data is corrupt or truncated: {e}")))?;
    let buf = &buf[..frame.buffer_size()];
    let samples: Vec<u16> = if bytes_per == 2 {
        buf.chunks_exact(2).map(|c| u16::from_be_bytes([c[0], c[1]])).collect()
    } else {
        buf.iter().map(|&b| b as u16).collect()
    };
    Ok(PngSamples { width: w as usize, height: h as usize, channels, bit_depth: if bytes_per == 2 { 16 } else { 8 }, samples, palette })
}

/// Reads a colour texture (PNG) as 8-bit RGB; grey is replicated, alpha dropped,
/// 16-bit reduced to 8.
pub fn read_rgb_png(path: &Path, limits: &Limits) -> Result<RgbImage> {
    let p = decode_png(path, limits, 3)?;
    let to8 = |v: u16| if p.bit_depth == 16 { (v >> 8) as u8 } else { v as u8 };
    let mut data = Vec::with_capacity(p.width * p.height * 3);
    for px in p.samples.chunks_exact(p.channels) {
        match p.channels {
            1 | 2 => data.extend_from_slice(&[to8(px[0]); 3]),
            _ => data.extend_from_slice(&[to8(px[0]), to8(px[1]), to8(px[2])]),
        }
    }
    Ok(RgbImage { width: p.width, height: p.height, data })
}

/// Linear → sRGB transfer function.
pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Writes an 8-bit RGBA PNG preview from linear RGBA floats (sRGB-encoded colour, values
/// clamped to [0, 1], NaN shown as 0). Written atomically.
pub fn write_png_preview(path: &Path, width: usize, height: usize, rgba: &[f32]) -> Result<()> {
    let bytes = png_preview_bytes(width, height, rgba).map_err(|m| FormatError::invalid(path, m))?;
    write_bytes_atomically(path, &bytes)
}

/// The PNG file `write_png_preview` writes, in memory (a notebook shows it inline).
pub fn png_preview_bytes(width: usize, height: usize, rgba: &[f32]) -> std::result::Result<Vec<u8>, String> {
    if rgba.len() != width * height * 4 {
        return Err("preview buffer size does not match the image size".into());
    }
    let q = |v: f32| (if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) } * 255.0 + 0.5) as u8;
    let bytes: Vec<u8> =
        rgba.chunks_exact(4).flat_map(|p| [q(linear_to_srgb(p[0])), q(linear_to_srgb(p[1])), q(linear_to_srgb(p[2])), q(p[3])]).collect();
    png_rgba8_bytes(width, height, &bytes)
}

/// Writes 8-bit RGBA bytes as a PNG, atomically.
pub fn write_png_rgba8(path: &Path, width: usize, height: usize, bytes: &[u8]) -> Result<()> {
    let out = png_rgba8_bytes(width, height, bytes).map_err(|m| FormatError::invalid(path, m))?;
    write_bytes_atomically(path, &out)
}

/// 8-bit RGBA bytes encoded as a PNG file in memory.
fn png_rgba8_bytes(width: usize, height: usize, bytes: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        let mut w = enc.write_header().map_err(|e| format!("cannot write PNG: {e}"))?;
        w.write_image_data(bytes).map_err(|e| format!("cannot write PNG: {e}"))?;
    }
    Ok(out)
}

/// Writes a 16-bit greyscale PNG (used for heightmap samples), atomically.
pub fn write_png_grey16(path: &Path, width: usize, height: usize, values: &[u16]) -> Result<()> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        let mut w = enc.write_header().map_err(|e| FormatError::invalid(path, format!("cannot write PNG: {e}")))?;
        w.write_image_data(&bytes).map_err(|e| FormatError::invalid(path, format!("cannot write PNG: {e}")))?;
    }
    write_bytes_atomically(path, &out)
}

/// Writes 8-bit RGB bytes as a PNG, atomically.
pub fn write_png_rgb8(path: &Path, img: &RgbImage) -> Result<()> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, img.width as u32, img.height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().map_err(|e| FormatError::invalid(path, format!("cannot write PNG: {e}")))?;
        w.write_image_data(&img.data).map_err(|e| FormatError::invalid(path, format!("cannot write PNG: {e}")))?;
    }
    write_bytes_atomically(path, &out)
}
