//! LZW tiles and strips the tiff crate cannot finish, decoded here.
//!
//! Every tiff 0.11 release (0.11.3 is the newest) decodes LZW through weezl 0.1 with
//! "yield on full buffer", and fails a valid, end-code-terminated chunk with "no lzw end
//! code found" when the output buffer fills just before the end code (image-tiff issue
//! #395; fixed upstream by weezl 0.2, not released). GDAL writes such chunks routinely: an
//! int16 or int32 DEM tiled with PREDICTOR=2, a byte raster's tiles. Such a chunk is read
//! here from its raw bytes, decoded with weezl in one call (to a vector, which has no
//! buffer to fill), and its predictor undone as libtiff undoes it (horizontal differencing,
//! TIFF 6.0 §14; floating point, Adobe's Technical Note 3). Chunks the crate decodes are
//! left to it.

use crate::error::{FormatError, Result};
use crate::geotiff::tiff_err;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;
use tiff::decoder::{ChunkType, Decoder, DecodingResult};
use tiff::tags::Tag;
use tiff::TiffError;

/// Whether `e` is the tiff crate's LZW failure this module works around.
pub(crate) fn is_lzw_end_error(e: &TiffError) -> bool {
    matches!(e, TiffError::IoError(io) if io.to_string().contains("no lzw end code found"))
}

/// Chunk `index` of the decoder's image decoded: by the tiff crate, or here where it fails
/// on an LZW chunk (see the module's comment). As the crate returns it: `dw` samples a row
/// for a strip, the tile's full width for a tile, the chunk's data rows.
pub(crate) fn read_chunk<R: Read + Seek>(path: &Path, d: &mut Decoder<R>, index: u32) -> Result<DecodingResult> {
    match d.read_chunk(index) {
        Ok(raw) => Ok(raw),
        Err(e) if is_lzw_end_error(&e) => decode_lzw_chunk(path, d, index),
        Err(e) => Err(tiff_err(path, e)),
    }
}

/// The decoder's whole `w` × `h` image of `spp` samples a pixel: by the tiff crate's
/// `read_image`, or, where that fails on an LZW chunk, chunk by chunk (see `read_chunk`).
pub(crate) fn read_image<R: Read + Seek>(path: &Path, d: &mut Decoder<R>, (w, h): (u32, u32), spp: usize) -> Result<DecodingResult> {
    match d.read_image() {
        Ok(raw) => return Ok(raw),
        Err(e) if is_lzw_end_error(&e) => {}
        Err(e) => return Err(tiff_err(path, e)),
    }
    let (cw, ch) = d.chunk_dimensions();
    if cw == 0 || ch == 0 {
        return Err(FormatError::invalid(path, "TIFF tiles or strips of size 0"));
    }
    let (across, down) = (w.div_ceil(cw), h.div_ceil(ch));
    let row = w as usize * spp;
    // Each chunk's rows copied to their place in the image (tiles at the right and bottom
    // edges stored whole or clipped, as the crate returns them).
    macro_rules! assemble {
        ($($variant:ident),*) => {{
            let mut image: Option<DecodingResult> = None;
            for ty in 0..down {
                for tx in 0..across {
                    let index = ty * across + tx;
                    let chunk = read_chunk(path, d, index)?;
                    let (dw, dh) = d.chunk_data_dimensions(index);
                    let (dw, dh) = (dw as usize * spp, dh as usize);
                    match (&mut image, chunk) {
                        $(
                            (slot, DecodingResult::$variant(c)) => {
                                if slot.is_none() {
                                    *slot = Some(DecodingResult::$variant(vec![Default::default(); row * h as usize]));
                                }
                                let Some(DecodingResult::$variant(out)) = slot else {
                                    return Err(FormatError::invalid(path, "chunks of different sample types"));
                                };
                                let stride = if c.len() >= cw as usize * spp * dh { cw as usize * spp } else { dw };
                                if c.len() < stride * (dh - 1) + dw {
                                    return Err(FormatError::invalid(path, format!("chunk {index} holds {} samples, fewer than its rows", c.len())));
                                }
                                let x0 = tx as usize * cw as usize * spp;
                                for r in 0..dh {
                                    let y = ty as usize * ch as usize + r;
                                    out[y * row + x0..y * row + x0 + dw].copy_from_slice(&c[r * stride..r * stride + dw]);
                                }
                            }
                        )*
                        _ => return Err(FormatError::unsupported(path, "sample type is not one of int8/16/32/64, uint8/16/32/64, float32/64")),
                    }
                }
            }
            image.ok_or_else(|| FormatError::invalid(path, "the image has no tiles or strips"))
        }};
    }
    assemble!(U8, I8, U16, I16, U32, I32, U64, I64, F32, F64)
}

/// Chunk `index`, an LZW chunk, decoded from its raw bytes.
fn decode_lzw_chunk<R: Read + Seek>(path: &Path, d: &mut Decoder<R>, index: u32) -> Result<DecodingResult> {
    let err = |e: TiffError| tiff_err(path, e);
    let tiles = d.get_chunk_type() == ChunkType::Tile;
    let (offsets, counts) = if tiles { (Tag::TileOffsets, Tag::TileByteCounts) } else { (Tag::StripOffsets, Tag::StripByteCounts) };
    let offset = *d.get_tag_u64_vec(offsets).map_err(err)?.get(index as usize).ok_or_else(|| missing(path, index))?;
    let count = *d.get_tag_u64_vec(counts).map_err(err)?.get(index as usize).ok_or_else(|| missing(path, index))?;
    let spp = d.find_tag_unsigned::<u16>(Tag::SamplesPerPixel).map_err(err)?.unwrap_or(1) as usize;
    let bits = d.find_tag_unsigned_vec::<u16>(Tag::BitsPerSample).map_err(err)?.and_then(|b| b.first().copied()).unwrap_or(1);
    // One value per band (RGB files list three).
    let format = d.find_tag_unsigned_vec::<u16>(Tag::SampleFormat).map_err(err)?.and_then(|f| f.first().copied()).unwrap_or(1);
    let predictor = d.find_tag_unsigned::<u16>(Tag::Predictor).map_err(err)?.unwrap_or(1);
    let planar = d.find_tag_unsigned::<u16>(Tag::PlanarConfiguration).map_err(err)?.unwrap_or(1);
    let big_endian = d.byte_order() == tiff::tags::ByteOrder::BigEndian;
    if planar != 1 || !matches!(bits, 8 | 16 | 32 | 64) {
        return Err(FormatError::unsupported(path, format!("LZW chunk {index}: {bits}-bit samples, planar configuration {planar}")));
    }
    let bytes = bits as usize / 8;
    // Tiles are stored at their full width, strips at the image's; the data rows only.
    let (cw, _) = d.chunk_dimensions();
    let (dw, dh) = d.chunk_data_dimensions(index);
    let width = if tiles { cw } else { dw } as usize;
    let row_bytes = width * spp * bytes;
    let need = row_bytes * dh as usize;
    // The offsets were checked against the file's length when it was opened.
    let mut raw = vec![0u8; usize::try_from(count).map_err(|_| missing(path, index))?];
    let reader = d.inner();
    reader.seek(SeekFrom::Start(offset)).and_then(|_| reader.read_exact(&mut raw)).map_err(|e| FormatError::io(path, e))?;
    // Decoded into the chunk's bytes and no further: a stream that would decode to more
    // (LZW expands up to a few hundred times) allocates nothing beyond them.
    let mut out = vec![0u8; need];
    let mut decoder = weezl::decode::Decoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8);
    let (mut read, mut written) = (0, 0);
    while written < need {
        let r = decoder.decode_bytes(&raw[read..], &mut out[written..]);
        (read, written) = (read + r.consumed_in, written + r.consumed_out);
        match r.status {
            Ok(weezl::LzwStatus::Ok) if r.consumed_in + r.consumed_out > 0 => {}
            Ok(_) => break,
            Err(e) => return Err(FormatError::invalid(path, format!("LZW chunk {index}: {e}"))),
        }
    }
    if written < need {
        return Err(FormatError::invalid(path, format!("LZW chunk {index} holds {written} of its {need} bytes")));
    }
    let mut big_endian_values = big_endian;
    for row in out.chunks_exact_mut(row_bytes) {
        match predictor {
            1 => {}
            2 => undo_horizontal(row, spp, bytes, big_endian),
            3 => undo_floating_point(row, spp, bytes),
            other => return Err(FormatError::unsupported(path, format!("LZW chunk {index}: predictor {other}"))),
        }
    }
    if predictor == 3 {
        // Undone, each value's bytes are most significant first whatever the file's order.
        big_endian_values = true;
    }
    typed(path, &out, format, bytes, big_endian_values)
}

fn missing(path: &Path, index: u32) -> FormatError {
    FormatError::invalid(path, format!("no offset or byte count for chunk {index}"))
}

/// Horizontal differencing undone on one row: each sample plus the same band's sample
/// before it, modulo its integer size.
fn undo_horizontal(row: &mut [u8], spp: usize, bytes: usize, big_endian: bool) {
    let get = |b: &[u8]| -> u64 {
        let mut v = 0u64;
        for k in 0..bytes {
            let byte = if big_endian { b[k] } else { b[bytes - 1 - k] };
            v = (v << 8) | byte as u64;
        }
        v
    };
    let mask = if bytes == 8 { u64::MAX } else { (1u64 << (8 * bytes)) - 1 };
    for i in spp..row.len() / bytes {
        let prev = get(&row[(i - spp) * bytes..(i - spp + 1) * bytes]);
        let cur = get(&row[i * bytes..(i + 1) * bytes]);
        let sum = cur.wrapping_add(prev) & mask;
        for k in 0..bytes {
            let byte = (sum >> (8 * (bytes - 1 - k))) as u8;
            if big_endian {
                row[i * bytes + k] = byte;
            } else {
                row[i * bytes + bytes - 1 - k] = byte;
            }
        }
    }
}

/// The floating-point predictor undone on one row: bytes summed with the byte `spp` before
/// them, then each value gathered from the row's byte planes (most significant plane
/// first), most significant byte first.
fn undo_floating_point(row: &mut [u8], spp: usize, bytes: usize) {
    for i in spp..row.len() {
        row[i] = row[i].wrapping_add(row[i - spp]);
    }
    let planes = row.to_vec();
    let values = row.len() / bytes;
    for v in 0..values {
        for k in 0..bytes {
            row[v * bytes + k] = planes[k * values + v];
        }
    }
}

/// The samples as the tiff crate types them.
fn typed(path: &Path, data: &[u8], format: u16, bytes: usize, big_endian: bool) -> Result<DecodingResult> {
    fn each<const N: usize, T>(data: &[u8], big_endian: bool, from: impl Fn([u8; N]) -> T, from_le: impl Fn([u8; N]) -> T) -> Vec<T> {
        data.chunks_exact(N).map(|c| if big_endian { from(c.try_into().unwrap()) } else { from_le(c.try_into().unwrap()) }).collect()
    }
    Ok(match (format, bytes) {
        (1, 1) => DecodingResult::U8(data.to_vec()),
        (2, 1) => DecodingResult::I8(data.iter().map(|&b| b as i8).collect()),
        (1, 2) => DecodingResult::U16(each(data, big_endian, u16::from_be_bytes, u16::from_le_bytes)),
        (2, 2) => DecodingResult::I16(each(data, big_endian, i16::from_be_bytes, i16::from_le_bytes)),
        (1, 4) => DecodingResult::U32(each(data, big_endian, u32::from_be_bytes, u32::from_le_bytes)),
        (2, 4) => DecodingResult::I32(each(data, big_endian, i32::from_be_bytes, i32::from_le_bytes)),
        (3, 4) => DecodingResult::F32(each(data, big_endian, f32::from_be_bytes, f32::from_le_bytes)),
        (3, 8) => DecodingResult::F64(each(data, big_endian, f64::from_be_bytes, f64::from_le_bytes)),
        (1, 8) => DecodingResult::U64(each(data, big_endian, u64::from_be_bytes, u64::from_le_bytes)),
        (2, 8) => DecodingResult::I64(each(data, big_endian, i64::from_be_bytes, i64::from_le_bytes)),
        _ => return Err(FormatError::unsupported(path, format!("sample format {format} of {bytes} bytes"))),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn horizontal_differencing_is_undone_per_band_modulo_the_sample_size() {
        // Two bands of little-endian u16: deltas wrap around 65536.
        let samples: [u16; 6] = [65535, 10, 2, 5, 65534, 1];
        let mut row: Vec<u8> = samples.iter().flat_map(|s| s.to_le_bytes()).collect();
        undo_horizontal(&mut row, 2, 2, false);
        let got: Vec<u16> = row.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
        assert_eq!(got, [65535, 10, 1, 15, 65535, 16]);
        // The same, big-endian.
        let mut row: Vec<u8> = samples.iter().flat_map(|s| s.to_be_bytes()).collect();
        undo_horizontal(&mut row, 2, 2, true);
        let got: Vec<u16> = row.chunks_exact(2).map(|c| u16::from_be_bytes([c[0], c[1]])).collect();
        assert_eq!(got, [65535, 10, 1, 15, 65535, 16]);
    }

    #[test]
    fn the_floating_point_predictor_is_undone_as_adobe_s_note_encodes_it() {
        // Encode as Technical Note 3 does: planes most significant first, then byte
        // differences along the row.
        let values = [1.5f32, -2.25, 1e-3, 6.0e7, f32::MIN_POSITIVE];
        let be: Vec<[u8; 4]> = values.iter().map(|v| v.to_be_bytes()).collect();
        let mut row: Vec<u8> = (0..4).flat_map(|k| be.iter().map(move |b| b[k])).collect();
        for i in (1..row.len()).rev() {
            row[i] = row[i].wrapping_sub(row[i - 1]);
        }
        undo_floating_point(&mut row, 1, 4);
        let got: Vec<f32> = row.chunks_exact(4).map(|c| f32::from_be_bytes(c.try_into().unwrap())).collect();
        assert_eq!(got, values);
    }
}
