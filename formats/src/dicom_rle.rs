//! DICOM RLE Lossless (PS3.5 Annex G), decoded here for every sample size.
//!
//! Why not dicom-pixeldata's RLE decoder: it refuses 32-bit samples ("Could not decode
//! pixel data" on RT Dose grids, which pydicom reads). The format is small: each frame is one
//! fragment holding a 64-byte header (the number of segments and up to 15 offsets) and one
//! PackBits-coded segment per byte plane, most significant byte of each sample first, sample
//! planes (colour components) one after another.

use crate::error::{FormatError, Result};
use std::path::Path;

/// Decodes `fragments` (one per frame) into little-endian samples: per frame, for one
/// sample per pixel `rows × cols` samples of `bytes_per_sample` bytes; for several, each
/// component's plane after the other (planar layout).
pub fn decode(
    path: &Path,
    fragments: &[Vec<u8>],
    frames: usize,
    pixels: usize,
    samples: usize,
    bytes_per_sample: usize,
) -> Result<Vec<u8>> {
    if fragments.len() != frames {
        return Err(FormatError::invalid(
            path,
            format!("RLE pixel data holds {} fragments for {frames} frames (RLE stores each frame in one fragment)", fragments.len()),
        ));
    }
    let segments = samples * bytes_per_sample;
    let frame_bytes = pixels * segments;
    let mut out = vec![0u8; frame_bytes * frames];
    for (f, (frag, dst)) in fragments.iter().zip(out.chunks_exact_mut(frame_bytes)).enumerate() {
        if frag.len() < 64 {
            return Err(FormatError::invalid(path, format!("RLE frame {f} is {} bytes, shorter than its 64-byte header", frag.len())));
        }
        let word = |i: usize| u32::from_le_bytes(frag[4 * i..4 * i + 4].try_into().unwrap()) as usize;
        let n = word(0);
        if n != segments {
            return Err(FormatError::invalid(
                path,
                format!("RLE frame {f} has {n} segments, but {samples} sample(s) of {bytes_per_sample} byte(s) need {segments}"),
            ));
        }
        let offsets: Vec<usize> = (1..=n).map(word).collect();
        let mut plane = vec![0u8; pixels];
        for k in 0..n {
            let start = offsets[k];
            let end = if k + 1 < n { offsets[k + 1] } else { frag.len() };
            if start < 64 || start > end || end > frag.len() {
                return Err(FormatError::invalid(path, format!("RLE frame {f}: segment {k} lies outside the fragment ({start}..{end})")));
            }
            unpack_bits(&frag[start..end], &mut plane)
                .map_err(|got| FormatError::invalid(path, format!("RLE frame {f}: segment {k} decodes to {got} of {pixels} bytes")))?;
            // Segment k is byte (k mod b) of component k / b, most significant first.
            let (component, byte) = (k / bytes_per_sample, k % bytes_per_sample);
            let le_byte = bytes_per_sample - 1 - byte;
            let base = component * pixels * bytes_per_sample;
            for (p, &v) in plane.iter().enumerate() {
                dst[base + p * bytes_per_sample + le_byte] = v;
            }
        }
    }
    Ok(out)
}

/// PackBits: a header byte n, then n + 1 literal bytes (0 ≤ n ≤ 127), or one byte repeated
/// 1 − n times (−127 ≤ n ≤ −1); −128 is skipped. Fills `out` exactly; Err(bytes produced)
/// when the segment holds fewer. Extra bytes after a full plane are padding and ignored.
fn unpack_bits(seg: &[u8], out: &mut [u8]) -> std::result::Result<(), usize> {
    let (mut i, mut o) = (0, 0);
    while o < out.len() && i < seg.len() {
        let n = seg[i] as i8;
        i += 1;
        if n >= 0 {
            let len = n as usize + 1;
            let take = len.min(out.len() - o).min(seg.len() - i);
            out[o..o + take].copy_from_slice(&seg[i..i + take]);
            i += len;
            o += take;
        } else if n != -128 {
            let Some(&v) = seg.get(i) else { break };
            i += 1;
            let len = (1 - n as isize) as usize;
            let take = len.min(out.len() - o);
            out[o..o + take].fill(v);
            o += take;
        }
    }
    if o < out.len() {
        return Err(o);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Encodes planes the way the standard describes (literal and replicate runs), so the
    /// decoder is checked on runs of every kind, including ones that cross 128 bytes.
    fn pack_bits(plane: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        let mut i = 0;
        while i < plane.len() {
            let mut run = 1;
            while i + run < plane.len() && plane[i + run] == plane[i] && run < 128 {
                run += 1;
            }
            if run >= 2 {
                out.push((1 - run as isize) as i8 as u8);
                out.push(plane[i]);
                i += run;
            } else {
                let start = i;
                while i < plane.len() && i - start < 128 && (i + 1 >= plane.len() || plane[i + 1] != plane[i]) {
                    i += 1;
                }
                if i == start {
                    i += 1;
                }
                out.push((i - start - 1) as u8);
                out.extend_from_slice(&plane[start..i]);
            }
        }
        if out.len() % 2 == 1 {
            out.push(0x80); // a no-op pad to an even length, as encoders write
        }
        out
    }

    fn frame(values: &[u32], bytes: usize) -> Vec<u8> {
        let mut segs = Vec::new();
        for k in 0..bytes {
            let shift = 8 * (bytes - 1 - k);
            segs.push(pack_bits(&values.iter().map(|v| (v >> shift) as u8).collect::<Vec<_>>()));
        }
        let mut frag = vec![0u8; 64];
        frag[0..4].copy_from_slice(&(bytes as u32).to_le_bytes());
        let mut off = 64;
        for (k, s) in segs.iter().enumerate() {
            frag[4 + 4 * k..8 + 4 * k].copy_from_slice(&(off as u32).to_le_bytes());
            off += s.len();
        }
        for s in &segs {
            frag.extend_from_slice(s);
        }
        frag
    }

    #[test]
    fn thirty_two_bit_samples_decode_most_significant_plane_first() {
        let values: Vec<u32> = (0..300u32).map(|i| if i < 140 { 795_000 } else { 1_254_000 - i * 977 }).collect();
        let frames = [frame(&values, 4), frame(&values.iter().map(|v| v ^ 0xDEAD_BEEF).collect::<Vec<_>>(), 4)];
        let out = decode(Path::new("t.dcm"), &frames, 2, 300, 1, 4).unwrap();
        let got: Vec<u32> = out.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect();
        assert_eq!(&got[..300], &values[..]);
        assert!(got[300..].iter().zip(&values).all(|(g, v)| *g == v ^ 0xDEAD_BEEF));
    }

    #[test]
    fn a_short_segment_is_an_error_naming_the_frame() {
        let mut f = frame(&[1, 2, 3, 4], 2);
        f.truncate(f.len() - 3);
        let err = decode(Path::new("t.dcm"), &[f], 1, 4, 1, 2).unwrap_err().to_string();
        assert!(err.contains("RLE frame 0: segment 1 decodes to"), "{err}");
    }
}
