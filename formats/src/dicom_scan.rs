//! A walk over a DICOM file's element headers that checks every declared length against the
//! bytes that are really there, before dicom-rs reads the file.
//!
//! Why: dicom-parser reserves and zero-fills each value at its declared length before reading
//! it, so one corrupt 4-byte length field claiming 4 GB costs 4 GB of memory in a 5 KB file
//! (found by fuzzing: `fuzz/regressions/dicom_file/`). Here values are skipped, not read, so
//! the walk costs a few reads per element; a length that overruns the file (or its enclosing
//! sequence or item) becomes a one-line error naming the element.

use crate::error::{FormatError, Result};
use crate::memory::Limits;
use dicom_core::dictionary::{DataDictionary, DataDictionaryEntry, VirtualVr};
use dicom_core::{Tag, VR};
use dicom_dictionary_std::{uids, StandardDataDictionary};
use std::fs::File;
use std::io::{BufReader, Read, Seek};
use std::path::Path;

const UNDEFINED: u32 = 0xFFFF_FFFF;
/// Explicit VR Big Endian: retired from the standard (dicom-rs marks its constant deprecated)
/// but still found in files.
pub(crate) const EXPLICIT_VR_BIG_ENDIAN: &str = "1.2.840.10008.1.2.2";
/// Deeper nesting than this is refused rather than walked (and rather than recursed into by
/// dicom-rs, whose stack it would exhaust).
const MAX_DEPTH: usize = 32;

/// What the walk reads from: the file itself, or the inflated stream of a deflated data set.
trait Source: Read {
    fn skip(&mut self, n: u64) -> std::io::Result<()>;
}

impl Source for BufReader<File> {
    fn skip(&mut self, n: u64) -> std::io::Result<()> {
        self.seek_relative(n as i64)
    }
}

impl<R: Read> Source for flate2::read::DeflateDecoder<R> {
    fn skip(&mut self, n: u64) -> std::io::Result<()> {
        let got = std::io::copy(&mut self.take(n), &mut std::io::sink())?;
        if got < n {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        Ok(())
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Encoding {
    ExplicitLe,
    ImplicitLe,
    ExplicitBe,
}

struct Walk<'a, S: Source> {
    path: &'a Path,
    src: S,
    pos: u64,
    enc: Encoding,
}

/// The transfer syntax of a data set that starts at byte 0 without the Part 10 header
/// (ACR-NEMA files, and DICOM data sets written without preamble and file meta group): None
/// unless the first bytes are an element of a low, even group, as such files begin. Explicit
/// VR where a valid VR follows the tag (byte order from the group number), else implicit VR
/// little endian, as pydicom's `force=True` decides.
pub fn bare_syntax_of(head: &[u8]) -> Option<&'static str> {
    if head.len() < 8 || (head.len() >= 132 && &head[128..132] == b"DICM") || &head[..4] == b"DICM" {
        return None;
    }
    let plausible = |g: u16| g & 1 == 0 && (0x0002..=0x0088).contains(&g);
    let (le, be) = (u16::from_le_bytes([head[0], head[1]]), u16::from_be_bytes([head[0], head[1]]));
    let explicit = names_a_vr([head[4], head[5]]);
    if explicit && plausible(le) {
        Some(uids::EXPLICIT_VR_LITTLE_ENDIAN)
    } else if explicit && plausible(be) {
        Some(EXPLICIT_VR_BIG_ENDIAN)
    } else if plausible(le) {
        Some(uids::IMPLICIT_VR_LITTLE_ENDIAN)
    } else {
        None
    }
}

/// Are the two bytes after an element's tag a VR (explicit VR), not the start of a length?
fn names_a_vr(b: [u8; 2]) -> bool {
    b[0].is_ascii_uppercase() && b[1].is_ascii_uppercase() && VR::from_binary(b).is_some()
}

/// How a native transfer syntax encodes its elements (encapsulated ones: explicit LE).
fn encoding_of(syntax: &str) -> Encoding {
    match syntax {
        uids::IMPLICIT_VR_LITTLE_ENDIAN => Encoding::ImplicitLe,
        EXPLICIT_VR_BIG_ENDIAN => Encoding::ExplicitBe,
        _ => Encoding::ExplicitLe,
    }
}

/// A file dicom-rs cannot read as it stands, and how to read its data set instead.
#[derive(Debug, Clone)]
pub struct Reparse {
    /// Where the data set starts.
    pub start: u64,
    /// The transfer syntax its elements are encoded in.
    pub parse_syntax: &'static str,
    /// The transfer syntax its pixel data is in (the meta group's, where there is one).
    pub pixel_syntax: String,
    /// Said in the volume's notes.
    pub note: String,
}

/// Checks `path`'s element lengths (and that it has the DICM magic and a transfer syntax, or
/// is a bare data set). Returns how to read a data set that dicom-rs would not read as the
/// file stands: a bare data set (see [`bare_syntax_of`]), or one encoded in implicit VR
/// although the meta group names an explicit VR syntax (as pydicom does, with a warning);
/// None for a Part 10 file read as it says.
pub fn check_lengths(path: &Path, limits: &Limits) -> Result<Option<Reparse>> {
    let file = File::open(path).map_err(|e| FormatError::io(path, e))?;
    let len = file.metadata().map_err(|e| FormatError::io(path, e))?.len();
    let mut r = BufReader::new(file);
    let mut head = [0u8; 132];
    let n = read_up_to(&mut r, &mut head).map_err(|e| FormatError::io(path, e))?;
    let start = if n >= 132 && &head[128..132] == b"DICM" {
        132
    } else if n >= 4 && &head[..4] == b"DICM" {
        4
    } else if let Some(syntax) = bare_syntax_of(&head[..n]) {
        r.seek(std::io::SeekFrom::Start(0)).map_err(|e| FormatError::io(path, e))?;
        let enc = encoding_of(syntax);
        Walk { path, src: r, pos: 0, enc }.dataset(len, false, 0)?;
        let name = match enc {
            Encoding::ImplicitLe => "implicit VR little endian",
            Encoding::ExplicitLe => "explicit VR little endian",
            Encoding::ExplicitBe => "explicit VR big endian",
        };
        return Ok(Some(Reparse {
            start: 0,
            parse_syntax: syntax,
            pixel_syntax: syntax.to_string(),
            note: format!("no DICOM file meta header (ACR-NEMA or a bare data set): read as {name}"),
        }));
    } else {
        return Err(FormatError::invalid(path, "not a DICOM file: no DICM magic at byte 128 (or 0), and no data set at byte 0"));
    };
    r.seek(std::io::SeekFrom::Start(start)).map_err(|e| FormatError::io(path, e))?;
    let mut meta = Walk { path, src: r, pos: start, enc: Encoding::ExplicitLe };
    let syntax = meta.file_meta(len)?;
    if syntax.is_empty() {
        return Err(FormatError::invalid(path, "the file meta group has no TransferSyntaxUID (0002,0010)"));
    }
    let enc = encoding_of(&syntax);
    if syntax == uids::DEFLATED_EXPLICIT_VR_LITTLE_ENDIAN {
        // Deflated: count the inflated bytes first (bounded by the memory limit, which is
        // what dicom-rs would hold them in), then walk the inflated stream.
        let dataset_start = meta.pos;
        let inflated = inflated_len(path, dataset_start, limits)?;
        let mut f = File::open(path).map_err(|e| FormatError::io(path, e))?;
        f.seek(std::io::SeekFrom::Start(dataset_start)).map_err(|e| FormatError::io(path, e))?;
        let src = flate2::read::DeflateDecoder::new(BufReader::new(f));
        let mut w = Walk { path, src, pos: 0, enc };
        return w.dataset(inflated, false, 0).map(|_| None);
    }
    meta.enc = enc;
    if enc == Encoding::ExplicitLe {
        // The first element's VR field: letters in explicit VR, a length's bytes in implicit.
        let start = meta.pos;
        let mut first = [0u8; 6];
        let n = read_up_to(&mut meta.src, &mut first).map_err(|e| FormatError::io(path, e))?;
        meta.src.seek(std::io::SeekFrom::Start(start)).map_err(|e| FormatError::io(path, e))?;
        if n == 6 && !names_a_vr([first[4], first[5]]) {
            meta.enc = Encoding::ImplicitLe;
            meta.dataset(len, false, 0)?;
            return Ok(Some(Reparse {
                start,
                parse_syntax: uids::IMPLICIT_VR_LITTLE_ENDIAN,
                pixel_syntax: syntax,
                note: "the data set is encoded in implicit VR although the file meta group names an explicit VR transfer syntax: read as implicit VR".into(),
            }));
        }
    }
    meta.dataset(len, false, 0).map(|_| None)
}

fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..])? {
            0 => break,
            n => got += n,
        }
    }
    Ok(got)
}

fn inflated_len(path: &Path, start: u64, limits: &Limits) -> Result<u64> {
    let mut f = File::open(path).map_err(|e| FormatError::io(path, e))?;
    f.seek(std::io::SeekFrom::Start(start)).map_err(|e| FormatError::io(path, e))?;
    let limit = limits.bytes();
    let d = flate2::read::DeflateDecoder::new(BufReader::new(f));
    let n = std::io::copy(&mut d.take(limit + 1), &mut std::io::sink())
        .map_err(|e| FormatError::invalid(path, format!("deflated data set is corrupt: {e}")))?;
    if n > limit {
        limits.check(path, "inflated data set", &[n])?;
    }
    Ok(n)
}

/// Explicit VR: which value representations have a 4-byte length (all but the 21 with a
/// 2-byte one, PS3.5 7.1.2). Unknown VR bytes are read as UN, as dicom-rs does.
fn has_long_length(vr: VR) -> bool {
    use VR::*;
    !matches!(vr, AE | AS | AT | CS | DA | DS | DT | FL | FD | IS | LO | LT | PN | SH | SL | SS | ST | TM | UI | UL | US)
}

impl<S: Source> Walk<'_, S> {
    fn read<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        let mut b = [0u8; N];
        self.src
            .read_exact(&mut b)
            .map_err(|_| FormatError::invalid(self.path, format!("file is truncated in {what} at byte {}", self.pos)))?;
        self.pos += N as u64;
        Ok(b)
    }
    fn read_u16(&mut self, what: &str) -> Result<u16> {
        let b = self.read::<2>(what)?;
        Ok(if self.enc == Encoding::ExplicitBe { u16::from_be_bytes(b) } else { u16::from_le_bytes(b) })
    }
    fn read_u32(&mut self, what: &str) -> Result<u32> {
        let b = self.read::<4>(what)?;
        Ok(if self.enc == Encoding::ExplicitBe { u32::from_be_bytes(b) } else { u32::from_le_bytes(b) })
    }
    fn skip(&mut self, n: u64, tag: Tag) -> Result<()> {
        self.src
            .skip(n)
            .map_err(|_| FormatError::invalid(self.path, format!("file is truncated in the value of element {}", show(tag))))?;
        self.pos += n;
        Ok(())
    }
}

impl Walk<'_, BufReader<File>> {
    /// The file meta group (always explicit VR little endian); returns the transfer syntax.
    fn file_meta(&mut self, file_len: u64) -> Result<String> {
        let mut syntax = String::new();
        // Where (0002,0000) FileMetaInformationGroupLength says the group ends. dicom-rs
        // reads the meta group to there whatever the elements' groups (a fuzzed file had
        // (0003,0012) inside it), so the data set starts there for us too: stopping at the
        // first other group instead began the deflate stream 60 bytes early, inflated
        // nothing, and let a 2.5 GB element length through to dicom-rs.
        let mut declared_end: Option<u64> = None;
        loop {
            if declared_end.is_some_and(|end| self.pos >= end) {
                return Ok(syntax);
            }
            // Peek at the group: without a group length, the meta group ends where group
            // 0002 does.
            let mut g = [0u8; 2];
            if read_up_to(&mut self.src, &mut g).map_err(|e| FormatError::io(self.path, e))? < 2 {
                return Ok(syntax);
            }
            let group = u16::from_le_bytes(g);
            if group != 0x0002 && declared_end.is_none() {
                // Step back over the peeked group: the data set starts there.
                self.src.seek_relative(-2).map_err(|e| FormatError::io(self.path, e))?;
                return Ok(syntax);
            }
            self.pos += 2;
            let e = u16::from_le_bytes(self.read::<2>("the file meta group")?);
            let tag = Tag(group, e);
            let vr = self.read::<2>("the file meta group")?;
            let len = if has_long_length(VR::from_binary(vr).unwrap_or(VR::UN)) {
                self.read::<2>("the file meta group")?;
                u32::from_le_bytes(self.read::<4>("the file meta group")?) as u64
            } else {
                u16::from_le_bytes(self.read::<2>("the file meta group")?) as u64
            };
            self.fits(tag, len, file_len)?;
            if group == 0x0002 && e == 0x0000 && len == 4 && declared_end.is_none() {
                let value = u32::from_le_bytes(self.read::<4>("the file meta group")?) as u64;
                declared_end = Some(self.pos + value);
            } else if group == 0x0002 && e == 0x0010 && len <= 256 {
                let mut v = vec![0u8; len as usize];
                self.src.read_exact(&mut v).map_err(|e| FormatError::io(self.path, e))?;
                self.pos += len;
                syntax = String::from_utf8_lossy(&v).trim_end_matches(['\0', ' ']).to_string();
            } else {
                self.skip(len, tag)?;
            }
        }
    }
}

impl<S: Source> Walk<'_, S> {
    fn fits(&self, tag: Tag, len: u64, end: u64) -> Result<()> {
        let remain = end.saturating_sub(self.pos);
        if len > remain {
            return Err(FormatError::invalid(
                self.path,
                format!("element {} declares {len} bytes but only {remain} remain (truncated file or corrupt length)", show(tag)),
            ));
        }
        Ok(())
    }

    /// Walks the elements up to `end`, the byte where the enclosing file, sequence or item
    /// ends; when `delimited` (an undefined-length item) up to its item delimiter instead,
    /// which must come before `end`.
    fn dataset(&mut self, end: u64, delimited: bool, depth: usize) -> Result<()> {
        if depth > MAX_DEPTH {
            return Err(FormatError::invalid(self.path, format!("sequences are nested deeper than {MAX_DEPTH} levels")));
        }
        loop {
            if self.pos >= end {
                if delimited {
                    return Err(FormatError::invalid(self.path, "file is truncated: an item has no delimiter"));
                }
                return Ok(());
            }
            let g = self.read_u16("an element header")?;
            let e = self.read_u16("an element header")?;
            let tag = Tag(g, e);
            if g == 0xFFFE {
                let len = self.read_u32("an item header")?;
                if e == 0xE00D && delimited {
                    return Ok(());
                }
                // A stray item or delimiter: skip what it declares.
                if len != UNDEFINED {
                    self.fits(tag, len as u64, end)?;
                    self.skip(len as u64, tag)?;
                }
                continue;
            }
            let (vr, len) = match self.enc {
                Encoding::ImplicitLe => {
                    let len = self.read_u32("an element header")?;
                    // The VR dicom-rs decodes the value as: the dictionary's (UN for
                    // unknown tags; US for the US-or-SS ones, the same width).
                    let vr = match StandardDataDictionary.by_tag(tag).map(|d| d.vr()) {
                        Some(VirtualVr::Exact(vr)) => vr,
                        Some(VirtualVr::Xs) => VR::US,
                        _ => VR::UN,
                    };
                    (vr, len)
                }
                _ => {
                    let vr = VR::from_binary(self.read::<2>("an element header")?).unwrap_or(VR::UN);
                    let len = if has_long_length(vr) {
                        self.read::<2>("an element header")?;
                        self.read_u32("an element header")?
                    } else {
                        self.read_u16("an element header")? as u32
                    };
                    (vr, len)
                }
            };
            if len == UNDEFINED {
                // Undefined length: encapsulated pixel data (opaque fragments) at the pixel
                // data tag, a sequence of data sets anywhere else (as dicom-rs reads it).
                self.items(tag, end, tag != Tag(0x7FE0, 0x0010), depth)?;
                continue;
            }
            let len = len as u64;
            self.fits(tag, len, end)?;
            if let Some(size) = binary_value_size(vr).filter(|size| !len.is_multiple_of(*size)) {
                // dicom-rs reads len / size whole values and goes on from there, short of
                // the value's end: every later header is read out of step, and a fuzzed
                // 7.5 KB file then made it reserve 3.5 GB for a garbage length.
                return Err(FormatError::invalid(
                    self.path,
                    format!(
                        "element {} ({vr:?}) declares {len} bytes, not a whole number of its {size}-byte values (corrupt length)",
                        show(tag)
                    ),
                ));
            }
            if vr == VR::SQ {
                let seq_end = self.pos + len;
                self.defined_items(tag, seq_end, depth)?;
            } else {
                self.skip(len, tag)?;
            }
        }
    }

    /// The items of an undefined-length element up to its sequence delimiter: data sets
    /// (`nested`) or pixel-data fragments.
    fn items(&mut self, tag: Tag, end: u64, nested: bool, depth: usize) -> Result<()> {
        loop {
            if self.pos >= end {
                return Err(FormatError::invalid(self.path, format!("file is truncated: element {} has no sequence delimiter", show(tag))));
            }
            let g = self.read_u16("an item header")?;
            let e = self.read_u16("an item header")?;
            let len = self.read_u32("an item header")?;
            match (g, e) {
                (0xFFFE, 0xE0DD) => return Ok(()),
                (0xFFFE, 0xE000) if len == UNDEFINED => {
                    if !nested {
                        return Err(FormatError::invalid(self.path, format!("a fragment of element {} has no defined length", show(tag))));
                    }
                    self.dataset(end, true, depth + 1)?;
                }
                (0xFFFE, 0xE000) => {
                    self.fits(Tag(g, e), len as u64, end)?;
                    if nested {
                        let item_end = self.pos + len as u64;
                        self.dataset(item_end, false, depth + 1)?;
                    } else {
                        self.skip(len as u64, tag)?;
                    }
                }
                _ => {
                    return Err(FormatError::invalid(
                        self.path,
                        format!("element {} holds {} where an item was expected", show(tag), show(Tag(g, e))),
                    ))
                }
            }
        }
    }

    /// The items of a defined-length sequence ending at `seq_end`.
    fn defined_items(&mut self, tag: Tag, seq_end: u64, depth: usize) -> Result<()> {
        while self.pos < seq_end {
            let g = self.read_u16("an item header")?;
            let e = self.read_u16("an item header")?;
            let len = self.read_u32("an item header")?;
            if (g, e) != (0xFFFE, 0xE000) {
                return Err(FormatError::invalid(
                    self.path,
                    format!("sequence {} holds {} where an item was expected", show(tag), show(Tag(g, e))),
                ));
            }
            if len == UNDEFINED {
                self.dataset(seq_end, true, depth + 1)?;
            } else {
                self.fits(Tag(g, e), len as u64, seq_end)?;
                let item_end = self.pos + len as u64;
                self.dataset(item_end, false, depth + 1)?;
            }
        }
        Ok(())
    }
}

/// The byte width of each value of a binary VR, which dicom-rs decodes value by value.
fn binary_value_size(vr: VR) -> Option<u64> {
    use VR::*;
    match vr {
        US | SS | OW => Some(2),
        UL | SL | FL | OF | OL | AT => Some(4),
        FD | OD | SV | UV | OV => Some(8),
        _ => None,
    }
}

fn show(tag: Tag) -> String {
    format!("({:04X},{:04X})", tag.0, tag.1)
}

#[cfg(test)]
mod tests {
    /// A meta group holding an element of another group within its declared length (as a
    /// fuzzer made it): the deflated data set starts where the group length says, as
    /// dicom-rs reads it, and its lying pixel-data length is refused before dicom-rs would
    /// reserve 4 GB for it.
    #[test]
    fn the_data_set_starts_where_the_meta_group_length_says() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/regressions/dicom_file/meta_foreign_group_deflated.dcm");
        let err = super::check_lengths(&path, &Default::default()).expect_err("the lying length must be refused").to_string();
        assert!(err.contains("element (7FE0,0010) declares 4294967280 bytes but only 84 remain"), "{err}");
    }

    /// An implicit VR data set holding (0000,0000), a UL, with 50 bytes (as a fuzzer made
    /// it): refused, as dicom-rs would read 12 values, go on 2 bytes short of the next
    /// header, and reserve gigabytes for the garbage lengths it then reads.
    #[test]
    fn a_binary_value_that_is_not_whole_values_is_refused() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../fuzz/regressions/dicom_file/group_length_not_whole_values_implicit.dcm");
        let err = super::check_lengths(&path, &Default::default()).expect_err("the odd length must be refused").to_string();
        assert!(err.contains("element (0000,0000) (UL) declares 50 bytes, not a whole number of its 4-byte values"), "{err}");
    }
}
