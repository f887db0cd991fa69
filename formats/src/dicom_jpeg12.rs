//! 12-bit lossy JPEG (DICOM's JPEG Extended, 1.2.840.10008.1.2.4.51, as older CT archives
//! hold it), decoded by libjpeg-turbo 3's `tj3Decompress12`: jpeg-decoder, behind
//! dicom-pixeldata, has no 12-bit DCT, and Debian bookworm's libturbojpeg (2.1) no 12-bit
//! API, so turbojpeg-sys builds the libjpeg-turbo it bundles.

use crate::error::{FormatError, Result};
use std::path::Path;
use turbojpeg_sys as tj;

/// A TurboJPEG decompressor, destroyed when dropped.
struct Decompressor(tj::tjhandle);

impl Decompressor {
    fn new(path: &Path) -> Result<Decompressor> {
        // SAFETY: tj3Init has no preconditions; a null handle is its failure.
        let h = unsafe { tj::tj3Init(tj::TJINIT_TJINIT_DECOMPRESS as std::ffi::c_int) };
        if h.is_null() {
            return Err(FormatError::invalid(path, "cannot start the 12-bit JPEG decoder (libjpeg-turbo)"));
        }
        let d = Decompressor(h);
        // A stream of thousands of progressive scans takes minutes and memory for a few
        // pixels (libjpeg-turbo's own fuzzers stop at 500); the size is checked against the
        // data set's before anything is decoded.
        // SAFETY: the handle is live.
        unsafe { tj::tj3Set(d.0, tj::TJPARAM_TJPARAM_SCANLIMIT as std::ffi::c_int, 500) };
        Ok(d)
    }

    /// The decoder's last error, one line.
    fn error(&self) -> String {
        // SAFETY: the handle is live; the string is the handle's own, copied at once.
        let s = unsafe { std::ffi::CStr::from_ptr(tj::tj3GetErrorStr(self.0)) };
        s.to_string_lossy().lines().next().unwrap_or_default().to_string()
    }

    fn get(&self, param: tj::TJPARAM) -> i32 {
        // SAFETY: the handle is live.
        unsafe { tj::tj3Get(self.0, param as std::ffi::c_int) }
    }
}

impl Drop for Decompressor {
    fn drop(&mut self) {
        // SAFETY: the handle came from tj3Init and is destroyed once.
        unsafe { tj::tj3Destroy(self.0) }
    }
}

/// Decodes the frames of a 12-bit JPEG Extended pixel data element (`fragments`, the
/// offset table left out) of one sample a pixel into `rows × columns` samples a frame, as
/// little-endian u16 bytes. One fragment a frame, or a single frame in several fragments.
pub fn decode_frames(path: &Path, fragments: &[Vec<u8>], frames: usize, rows: usize, columns: usize) -> Result<Vec<u8>> {
    let streams: Vec<std::borrow::Cow<[u8]>> = if frames == 1 {
        vec![fragments.concat().into()]
    } else if fragments.len() == frames {
        fragments.iter().map(|f| f.as_slice().into()).collect()
    } else {
        return Err(FormatError::unsupported(
            path,
            format!("{} JPEG fragments for {frames} frames: frames split over several fragments are not read", fragments.len()),
        ));
    };
    let d = Decompressor::new(path)?;
    let mut out = Vec::with_capacity(frames * rows * columns * 2);
    let mut frame = vec![0i16; rows * columns];
    for (k, s) in streams.iter().enumerate() {
        let bad = |what: String| FormatError::invalid(path, format!("12-bit JPEG frame {k}: {what}"));
        // SAFETY: the handle is live and the stream's pointer and length are its own.
        if unsafe { tj::tj3DecompressHeader(d.0, s.as_ptr(), s.len() as _) } != 0 {
            return Err(bad(d.error()));
        }
        let (w, h, precision) =
            (d.get(tj::TJPARAM_TJPARAM_JPEGWIDTH), d.get(tj::TJPARAM_TJPARAM_JPEGHEIGHT), d.get(tj::TJPARAM_TJPARAM_PRECISION));
        if (w as usize, h as usize) != (columns, rows) {
            return Err(bad(format!("{w}×{h} samples where the data set says {columns}×{rows}")));
        }
        if precision != 12 {
            return Err(bad(format!("{precision}-bit samples in a 12-bit transfer syntax")));
        }
        // SAFETY: `frame` holds w × h samples of one component (TJPF_GRAY), pitch 0 meaning
        // packed rows; the decoder writes no more.
        let rc = unsafe { tj::tj3Decompress12(d.0, s.as_ptr(), s.len() as _, frame.as_mut_ptr(), 0, tj::TJPF_TJPF_GRAY) };
        if rc != 0 {
            return Err(bad(d.error()));
        }
        out.extend(frame.iter().flat_map(|v| (*v as u16).to_le_bytes()));
    }
    Ok(out)
}
