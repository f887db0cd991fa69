//! The malformed-input suite: every reader gets truncated, mislabelled, self-contradicting and
//! hostile files, made here from the committed fixtures, and `volterra info` must answer each
//! with exactly one line — the exact text below, naming the file — and exit code 1.
//! Run with VOLTERRA_PRINT_MALFORMED=1 to print what each case gives now.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn fixture(rel: &str) -> Vec<u8> {
    std::fs::read(common::repo_path(&format!("tests/fixtures/{rel}"))).unwrap()
}

fn put_u16(b: &mut [u8], at: usize, v: u16) {
    b[at..at + 2].copy_from_slice(&v.to_le_bytes());
}
fn put_i16(b: &mut [u8], at: usize, v: i16) {
    b[at..at + 2].copy_from_slice(&v.to_le_bytes());
}
fn put_f32(b: &mut [u8], at: usize, v: f32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}
fn put_u32(b: &mut [u8], at: usize, v: u32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

/// A copy of `base` with one edit applied.
fn edited(base: &[u8], edit: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut b = base.to_vec();
    edit(&mut b);
    b
}

fn gunzip(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(data), &mut out).unwrap();
    out
}
fn gzip(data: &[u8]) -> Vec<u8> {
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    std::io::Write::write_all(&mut gz, data).unwrap();
    gz.finish().unwrap()
}

fn replace(data: &[u8], from: &str, to: &str) -> Vec<u8> {
    let at = data.windows(from.len()).position(|w| w == from.as_bytes()).unwrap_or_else(|| panic!("{from} not found"));
    [&data[..at], to.as_bytes(), &data[at + from.len()..]].concat()
}

/// Classic little-endian TIFF: the byte offset of the first IFD entry with `tag`.
fn tiff_entry(b: &[u8], tag: u16) -> usize {
    let ifd = u32::from_le_bytes(b[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes(b[ifd..ifd + 2].try_into().unwrap()) as usize;
    (0..n).map(|i| ifd + 2 + 12 * i).find(|&e| u16::from_le_bytes(b[e..e + 2].try_into().unwrap()) == tag).expect("tag")
}

/// A DICOM fixture with some elements changed, through dicom-rs (an independent writer).
fn dicom_edit(rel: &str, edit: impl FnOnce(&mut dicom_object::DefaultDicomObject)) -> Vec<u8> {
    let mut obj = dicom_object::open_file(common::repo_path(&format!("tests/fixtures/{rel}"))).unwrap();
    edit(&mut obj);
    let mut out = Vec::new();
    obj.write_all(&mut out).unwrap();
    out
}

fn put_str(obj: &mut dicom_object::DefaultDicomObject, tag: dicom_core::Tag, vr: dicom_core::VR, v: &str) {
    obj.put(dicom_object::mem::InMemElement::new(tag, vr, dicom_core::PrimitiveValue::from(v)));
}
fn put_us(obj: &mut dicom_object::DefaultDicomObject, tag: dicom_core::Tag, v: u16) {
    obj.put(dicom_object::mem::InMemElement::new(tag, dicom_core::VR::US, dicom_core::PrimitiveValue::from(v)));
}

struct Suite {
    dir: PathBuf,
    cases: Vec<(String, PathBuf)>,
}

impl Suite {
    /// Writes `data` as `name`; EXPECTED holds what `volterra info` must say of it.
    fn file(&mut self, name: &str, data: &[u8]) {
        let path = self.dir.join(name);
        std::fs::write(&path, data).unwrap();
        self.cases.push((name.to_string(), path));
    }
    /// A directory of files (a DICOM series).
    fn series(&mut self, name: &str, files: Vec<(String, Vec<u8>)>) {
        let dir = self.dir.join(name);
        std::fs::create_dir(&dir).unwrap();
        for (f, data) in files {
            std::fs::write(dir.join(f), data).unwrap();
        }
        self.cases.push((name.to_string(), dir));
    }
}

fn nifti_cases(s: &mut Suite) {
    // i16_nifti1.nii: 348-byte header, 4 extension bytes, then voxels.
    let base = fixture("nifti/i16_nifti1.nii");
    s.file("empty.nii", &[]);
    s.file("sizeof_only.nii", &base[..4]);
    s.file("cut_in_header.nii", &base[..200]);
    s.file("header_only.nii", &base[..348]);
    s.file("no_voxels.nii", &base[..352]);
    s.file("half_voxels.nii", &base[..352 + (base.len() - 352) / 2]);
    s.file("wrong_magic.nii", &edited(&base, |b| b[344..348].copy_from_slice(b"xyz\0")));
    s.file("dim_zero.nii", &edited(&base, |b| put_i16(b, 42, 0)));
    s.file("unknown_datatype.nii", &edited(&base, |b| put_i16(b, 70, 1234)));
    s.file("bitpix_mismatch.nii", &edited(&base, |b| put_i16(b, 72, 32)));
    s.file("vox_offset_in_header.nii", &edited(&base, |b| put_f32(b, 108, 100.0)));
    // Spacing: pixdim[i] at 76 + 4 i. qform_only.nii takes its geometry from pixdim.
    let q = fixture("nifti/qform_only.nii");
    s.file("negative_pixdim.nii", &edited(&q, |b| put_f32(b, 80, -2.0)));
    s.file("zero_pixdim.nii", &edited(&q, |b| put_f32(b, 84, 0.0)));
    s.file("nan_pixdim.nii", &edited(&q, |b| put_f32(b, 88, f32::NAN)));
    // The sform (srow_x at 280) with a zero column: no voxel size at all.
    let mut b = base.clone();
    for k in 0..3 {
        put_f32(&mut b, 280 + 4 * k, 0.0);
        put_f32(&mut b, 296 + 4 * k, 0.0);
        put_f32(&mut b, 312 + 4 * k, 0.0);
    }
    s.file("singular_sform.nii", &b);
    // NIfTI-2 (540-byte header, dims as i64 at 16).
    let n2 = gunzip(&fixture("nifti/f32_nifti2_be.nii.gz"));
    let le = i32::from_le_bytes(n2[0..4].try_into().unwrap()) == 540;
    let i64_bytes = |v: i64| if le { v.to_le_bytes() } else { v.to_be_bytes() };
    s.file("dim_2pow31.nii", &edited(&n2, |b| b[24..32].copy_from_slice(&i64_bytes(1 << 31))));
    let mut b = n2.clone();
    for k in 0..3 {
        b[24 + 8 * k..32 + 8 * k].copy_from_slice(&i64_bytes(1 << 40));
    }
    s.file("dims_overflow.nii", &b);
    // gzip: the stream cut short, and a corrupt deflate block.
    let gz = fixture("nifti/i16_nifti2_be.nii.gz");
    s.file("cut_gzip.nii.gz", &gz[..gz.len() / 2]);
    let mut b = gzip(&base);
    let mid = b.len() / 2;
    for x in &mut b[mid..mid + 16] {
        *x ^= 0x5A;
    }
    s.file("corrupt_gzip.nii.gz", &b);
}

fn dicom_cases(s: &mut Suite) {
    use dicom_dictionary_std::tags;
    let base = fixture("dicom/oblique/z5.dcm");
    let n = base.len();
    s.file("cut_in_preamble.dcm", &base[..64]);
    s.file("magic_only.dcm", &base[..132]);
    s.file("cut_in_meta.dcm", &base[..180]);
    s.file("cut_in_dataset.dcm", &base[..n / 2]);
    s.file("cut_in_pixels.dcm", &base[..n - 10]);
    s.file("wrong_magic.dcm", &edited(&base, |b| b[128..132].copy_from_slice(b"DICX")));
    s.file("rows_zero.dcm", &dicom_edit("dicom/oblique/z5.dcm", |o| put_us(o, tags::ROWS, 0)));
    s.file(
        "huge_frames.dcm",
        &dicom_edit("dicom/oblique/z5.dcm", |o| {
            put_us(o, tags::ROWS, 65535);
            put_us(o, tags::COLUMNS, 65535);
            put_str(o, tags::NUMBER_OF_FRAMES, dicom_core::VR::IS, "2147483647");
        }),
    );
    s.file("short_pixel_data.dcm", &dicom_edit("dicom/oblique/z5.dcm", |o| put_us(o, tags::ROWS, 40)));
    for (name, v) in [("spacing_zero.dcm", "0\\0.5"), ("spacing_negative.dcm", "-1\\1"), ("spacing_nan.dcm", "NaN\\1")] {
        s.file(name, &dicom_edit("dicom/oblique/z5.dcm", |o| put_str(o, tags::PIXEL_SPACING, dicom_core::VR::DS, v)));
    }
    s.file("slope_zero.dcm", &dicom_edit("dicom/oblique/z5.dcm", |o| put_str(o, tags::RESCALE_SLOPE, dicom_core::VR::DS, "0")));
    s.file("slope_nan.dcm", &dicom_edit("dicom/oblique/z5.dcm", |o| put_str(o, tags::RESCALE_SLOPE, dicom_core::VR::DS, "NaN")));
    // Series that contradict themselves.
    let names = ["z5", "z6", "z7", "z8", "z9"];
    let series = |edit_last: &dyn Fn(&mut dicom_object::DefaultDicomObject)| -> Vec<(String, Vec<u8>)> {
        names
            .iter()
            .enumerate()
            .map(|(i, z)| {
                let rel = format!("dicom/oblique/{z}.dcm");
                let data = if i == names.len() - 1 { dicom_edit(&rel, |o| edit_last(o)) } else { fixture(&rel) };
                (format!("{z}.dcm"), data)
            })
            .collect()
    };
    s.series(
        "mixed_sizes",
        series(&|o| {
            put_us(o, tags::ROWS, 2);
        }),
    );
    s.series("mixed_orientations", series(&|o| put_str(o, tags::IMAGE_ORIENTATION_PATIENT, dicom_core::VR::DS, "0\\1\\0\\0\\0\\-1")));
}

fn geotiff_cases(s: &mut Suite) {
    let base = fixture("geotiff/i16_none_strips.tif");
    s.file("header_only.tif", &base[..8]);
    s.file("cut_half.tif", &base[..base.len() / 2]);
    s.file("wrong_magic.tif", &edited(&base, |b| b[..4].copy_from_slice(b"XX*\0")));
    let mut b = base.clone();
    let e = tiff_entry(&b, 34735);
    put_u16(&mut b, e, 65000); // GeoKeyDirectory renamed to an unknown private tag
    s.file("no_geokeys.tif", &b);
    let mut b = base.clone();
    let e = tiff_entry(&b, 273);
    put_u32(&mut b, e + 8, 1 << 30); // StripOffsets far beyond the end
    s.file("strip_beyond_end.tif", &b);
    let tiles = fixture("geotiff/f32_deflate_pred3_tiles.tif");
    let mut b = tiles.clone();
    let e = tiff_entry(&b, 324);
    let count = u32::from_le_bytes(b[e + 4..e + 8].try_into().unwrap());
    if count == 1 {
        put_u32(&mut b, e + 8, 1 << 30);
    } else {
        let at = u32::from_le_bytes(b[e + 8..e + 12].try_into().unwrap()) as usize;
        put_u32(&mut b, at, 1 << 30);
    }
    s.file("tile_beyond_end.tif", &b);
    let mut b = base.clone();
    let e = tiff_entry(&b, 256);
    put_u32(&mut b, e + 8, 0);
    s.file("width_zero.tif", &b);
    let mut b = base.clone();
    let (w, h) = (tiff_entry(&b, 256), tiff_entry(&b, 257));
    put_u32(&mut b, w + 8, 1 << 31);
    put_u32(&mut b, h + 8, 1 << 31);
    s.file("huge.tif", &b);
    // A geographic raster whose origin lies beyond the pole (ModelTransformation: 16
    // doubles, the y origin is the 8th): metres per degree would come out negative.
    let mut b = fixture("geotiff/f32_transform_point_geographic.tif");
    let e = tiff_entry(&b, 34264);
    let at = u32::from_le_bytes(b[e + 8..e + 12].try_into().unwrap()) as usize + 7 * 8;
    b[at..at + 8].copy_from_slice(&(-179.5f64).to_le_bytes());
    s.file("latitude_beyond_pole.tif", &b);
    // ModelPixelScale: three doubles at the entry's offset.
    for (name, v) in [("scale_zero.tif", 0.0), ("scale_negative.tif", -30.0), ("scale_nan.tif", f64::NAN)] {
        let mut b = base.clone();
        let e = tiff_entry(&b, 33550);
        let at = u32::from_le_bytes(b[e + 8..e + 12].try_into().unwrap()) as usize;
        b[at..at + 8].copy_from_slice(&v.to_le_bytes());
        s.file(name, &b);
    }
}

fn png_cases(s: &mut Suite) {
    // A 16-bit grey heightmap written by our own PNG writer.
    let png = s.dir.join("base_heightmap.png.src");
    let grey: Vec<u16> = (0..64 * 48).map(|i| (i * 13 % 65536) as u16).collect();
    volterra_formats::image::write_png_grey16(&png, 64, 48, &grey).unwrap();
    let base = std::fs::read(&png).unwrap();
    s.file("cut_signature.png", &base[..4]);
    s.file("cut_half.png", &base[..base.len() / 2]);
    s.file("wrong_magic.png", &edited(&base, |b| b[1..4].copy_from_slice(b"JPG")));
    // IHDR width at byte 16, its CRC at 29: fix the CRC so only the value is wrong.
    let ihdr = |w: u32, h: u32| {
        let mut b = base.clone();
        b[16..20].copy_from_slice(&w.to_be_bytes());
        b[20..24].copy_from_slice(&h.to_be_bytes());
        let crc = crc32(&b[12..29]);
        b[29..33].copy_from_slice(&crc.to_be_bytes());
        b
    };
    s.file("width_zero.png", &ihdr(0, 512));
    s.file("huge.png", &ihdr(0x7FFF_FFFF, 0x7FFF_FFFF));
}

fn crc32(data: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in data {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

fn vtk_cases(s: &mut Suite) {
    let ascii = fixture("vtk/legacy_ascii_42.vtk");
    s.file("more_points_ascii.vtk", &replace(&ascii, "POINTS 50 float", "POINTS 5000 float"));
    s.file("huge_points.vtk", &replace(&ascii, "POINTS 50 float", "POINTS 4294967296 float"));
    s.file("cut_half.vtk", &ascii[..ascii.len() / 2]);
    s.file("wrong_magic.vtk", &replace(&ascii, "# vtk DataFile", "# xyz DataFile"));
    let binary = fixture("vtk/legacy_binary_42.vtk");
    s.file("more_points_binary.vtk", &replace(&binary, "POINTS 50 float", "POINTS 5000 float"));
    let xml = fixture("vtk/xml_ascii.vtp");
    s.file("more_points.vtp", &replace(&xml, "NumberOfPoints=\"50\"", "NumberOfPoints=\"5000\""));
    s.file("huge_points.vtp", &replace(&xml, "NumberOfPoints=\"50\"", "NumberOfPoints=\"4294967296\""));
    s.file("cut_half.vtp", &xml[..xml.len() / 2]);
    s.file("wrong_root.vtp", &replace(&xml, "<VTKFile", "<VTKFool"));
    let appended = fixture("vtk/xml_appended_raw.vtp");
    s.file("cut_appended.vtp", &appended[..appended.len() - 100]);
}

/// The text-header volume formats (MetaImage, NRRD, VTK image data): lying sizes, cut
/// data, what they hold that is not a scalar volume.
fn volume_format_cases(s: &mut Suite) {
    let vox: Vec<u8> = (-12i16..12).flat_map(|v| v.to_le_bytes()).collect();
    let mha = |head: &str, data: &[u8]| {
        [format!("ObjectType = Image\nNDims = 3\n{head}ElementDataFile = LOCAL\n").into_bytes(), data.to_vec()].concat()
    };
    s.file("short_data.mha", &mha("DimSize = 4 3 2\nElementType = MET_SHORT\n", &vox[..30]));
    s.file("huge_dims.mha", &mha("DimSize = 100000 100000 100000\nElementType = MET_SHORT\n", &vox));
    s.file("two_channels.mha", &mha("DimSize = 4 3 2\nElementNumberOfChannels = 2\nElementType = MET_SHORT\n", &vox));
    s.file("long_type.mha", &mha("DimSize = 4 3 2\nElementType = MET_LONG_LONG\n", &vox));
    s.file("bad_zlib.mha", &mha("DimSize = 4 3 2\nCompressedData = True\nElementType = MET_SHORT\n", &vox));
    s.file("missing_raw.mhd", b"ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementType = MET_SHORT\nElementDataFile = gone.raw\n");
    s.file("no_datafile.mha", b"ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementType = MET_SHORT\n");
    let nrrd = |head: &str, data: &[u8]| [format!("NRRD0004\ntype: short\n{head}endian: little\n\n").into_bytes(), data.to_vec()].concat();
    s.file("short_data.nrrd", &nrrd("dimension: 3\nsizes: 4 3 2\nencoding: raw\n", &vox[..30]));
    s.file("huge_sizes.nrrd", &nrrd("dimension: 3\nsizes: 100000 100000 100000\nencoding: raw\n", &vox));
    s.file("vector_kind.nrrd", &nrrd("dimension: 3\nsizes: 2 3 4\nkinds: vector domain domain\nencoding: raw\n", &vox));
    s.file("bzip2.nrrd", &nrrd("dimension: 3\nsizes: 4 3 2\nencoding: bzip2\n", &vox));
    s.file("cut_gzip.nrrd", &nrrd("dimension: 3\nsizes: 4 3 2\nencoding: gzip\n", &gzip(&vox)[..20]));
    s.file("missing_raw.nhdr", b"NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 2\nendian: little\nencoding: raw\ndata file: gone.raw\n");
    let sp = |dims: &str, data: &[u8]| {
        [format!("# vtk DataFile Version 3.0\nt\nBINARY\nDATASET STRUCTURED_POINTS\nDIMENSIONS {dims}\nPOINT_DATA 24\nSCALARS s short\nLOOKUP_TABLE default\n").into_bytes(), data.to_vec()].concat()
    };
    s.file("short_scalars.vtk", &sp("4 3 2", &vox[..30]));
    s.file("wrong_count.vtk", &sp("4 3 3", &vox));
    s.file("rectilinear.vtk", b"# vtk DataFile Version 3.0\nt\nASCII\nDATASET RECTILINEAR_GRID\nDIMENSIONS 2 1 1\n");
    let vti = |extent: &str, values: &str| {
        format!(
            "<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\">\n<ImageData WholeExtent=\"{extent}\" Origin=\"0 0 0\" Spacing=\"1 1 1\">\n\
             <Piece Extent=\"{extent}\"><PointData Scalars=\"s\"><DataArray type=\"Float32\" Name=\"s\" format=\"ascii\">{values}</DataArray></PointData></Piece></ImageData></VTKFile>\n"
        )
    };
    s.file("few_values.vti", vti("0 1 0 1 0 0", "0 1 2").as_bytes());
    s.file("huge_extent.vti", vti("0 99999 0 99999 0 99999", "0").as_bytes());
    s.file("no_scalars.vti", vti("0 1 0 1 0 0", "0 1 2 3").replace("Scalars=\"s\"", "Scalars=\"t\"").as_bytes());
}

fn run_info(path: &Path) -> (Option<i32>, String) {
    let out = Command::new(common::volterra_bin()).args(["--max-memory", "1G", "info"]).arg(path).output().unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn every_malformed_input_gets_its_one_line_error_and_exit_1() {
    let tmp = tempfile::tempdir().unwrap();
    let mut s = Suite { dir: tmp.path().to_path_buf(), cases: Vec::new() };
    nifti_cases(&mut s);
    dicom_cases(&mut s);
    geotiff_cases(&mut s);
    png_cases(&mut s);
    vtk_cases(&mut s);
    volume_format_cases(&mut s);
    let print = std::env::var_os("VOLTERRA_PRINT_MALFORMED").is_some();
    let mut failures = Vec::new();
    for (name, path) in &s.cases {
        let (code, stderr) = run_info(path);
        if print {
            println!("    (\"{name}\", {:?}),", stderr.trim_end().replace(&format!("error: {}: ", path.display()), ""));
        }
        let Some(&(_, want)) = EXPECTED.iter().find(|(n, _)| n == name) else {
            failures.push(format!("{name}: no expected error in EXPECTED"));
            continue;
        };
        let want_line = format!("error: {}: {want}", path.display());
        if code != Some(1) || stderr.trim_end() != want_line || stderr.lines().count() != 1 {
            failures.push(format!("{name}: exit {code:?}\n  got:  {}\n  want: {want_line}", stderr.trim_end()));
        }
    }
    assert_eq!(s.cases.len(), EXPECTED.len(), "a case was added or removed without its expected error");
    assert!(failures.is_empty(), "{} of {} cases differ:\n{}", failures.len(), s.cases.len(), failures.join("\n"));
}
/// Each case and the exact error `volterra info` must print after "error: PATH: ".
const EXPECTED: &[(&str, &str)] = &[
    ("empty.nii", "file is truncated in the header"),
    ("sizeof_only.nii", "file is truncated in the header"),
    ("cut_in_header.nii", "file is truncated in the header"),
    ("header_only.nii", "file is truncated: voxel data holds 0 of 120 bytes"),
    ("no_voxels.nii", "file is truncated: voxel data holds 0 of 120 bytes"),
    ("half_voxels.nii", "file is truncated: voxel data holds 60 of 120 bytes"),
    ("wrong_magic.nii", "NIfTI-1 magic is neither \"n+1\" nor \"ni1\" (an Analyze 7.5 file?)"),
    ("dim_zero.nii", "dim[1] = 0 is not positive"),
    ("unknown_datatype.nii", "unsupported NIfTI datatype 1234 (unknown)"),
    ("bitpix_mismatch.nii", "bitpix 32 does not match datatype 4 (i16)"),
    ("vox_offset_in_header.nii", "vox_offset 100 lies inside the header"),
    ("negative_pixdim.nii", "pixdim[1] = -2 is not a positive voxel size (the qform needs it)"),
    ("zero_pixdim.nii", "pixdim[2] = 0 is not a positive voxel size (the qform needs it)"),
    ("nan_pixdim.nii", "pixdim[3] = NaN is not finite"),
    ("singular_sform.nii", "the sform affine is singular (a zero voxel spacing)"),
    ("dim_2pow31.nii", "volume needs 96.0 GiB but the memory limit is 1.0 GiB (set --max-memory to raise it)"),
    ("dims_overflow.nii", "volume: size overflows ([1099511627776, 1099511627776, 1099511627776, 4])"),
    ("cut_gzip.nii.gz", "file is truncated in the header"),
    ("corrupt_gzip.nii.gz", "gzip stream is corrupt: corrupt deflate stream"),
    ("cut_in_preamble.dcm", "not a DICOM file: no DICM magic at byte 128 (or 0), and no data set at byte 0"),
    ("magic_only.dcm", "the file meta group has no TransferSyntaxUID (0002,0010)"),
    ("cut_in_meta.dcm", "element (0002,0002) declares 26 bytes but only 14 remain (truncated file or corrupt length)"),
    ("cut_in_dataset.dcm", "element (0008,103E) declares 12 bytes but only 8 remain (truncated file or corrupt length)"),
    ("cut_in_pixels.dcm", "element (7FE0,0010) declares 84 bytes but only 74 remain (truncated file or corrupt length)"),
    ("wrong_magic.dcm", "not a DICOM file: no DICM magic at byte 128 (or 0), and no data set at byte 0"),
    ("rows_zero.dcm", "image size 7x0 is not valid"),
    ("huge_frames.dcm", "DICOM volume needs 16776704.0 TiB but the memory limit is 1.0 GiB (set --max-memory to raise it)"),
    ("short_pixel_data.dcm", "pixel data holds 84 bytes, but 7x40x1 frames need 560"),
    ("spacing_zero.dcm", "PixelSpacing [0.0, 0.5] is not positive"),
    ("spacing_negative.dcm", "PixelSpacing [-1.0, 1.0] is not positive"),
    ("spacing_nan.dcm", "PixelSpacing 'NaN\\1' is not a finite number"),
    ("slope_zero.dcm", "RescaleSlope is 0: every pixel would map to the intercept"),
    ("slope_nan.dcm", "RescaleSlope 'NaN' is not a finite number"),
    ("mixed_sizes", "series contradicts itself: z9.dcm has 7x2 pixels, z5.dcm 7x6"),
    ("mixed_orientations", "series contradicts itself: z9.dcm has orientation [0.0000, 1.0000, 0.0000, 0.0000, 0.0000, -1.0000], z5.dcm [0.9553, 0.2955, 0.0000, -0.2891, 0.9345, 0.2076]"),
    ("header_only.tif", "TIFF is truncated or unreadable: failed to fill whole buffer"),
    ("cut_half.tif", "strip 0 lies beyond the end of the file (offset 432, 3330 bytes; the file has 1881)"),
    ("wrong_magic.tif", "invalid TIFF: format error: TIFF signature not found"),
    ("no_geokeys.tif", "has a pixel scale or transformation but no GeoKeys: its CRS (degrees or metres) is unknown"),
    ("strip_beyond_end.tif", "strip 0 lies beyond the end of the file (offset 1073741824, 3330 bytes; the file has 3762)"),
    ("tile_beyond_end.tif", "tile 0 lies beyond the end of the file (offset 1073741824, 1981 bytes; the file has 7530)"),
    ("width_zero.tif", "invalid TIFF: format error: invalid dimensions: 0x37"),
    ("huge.tif", "invalid TIFF: format error: inconsistent sizes encountered"),
    ("latitude_beyond_pole.tif", "geographic raster centred at latitude -179.536°, outside ±90°"),
    ("scale_zero.tif", "pixel scale (0, 20) must be finite and positive (north-up)"),
    ("scale_negative.tif", "pixel scale (-30, 20) must be finite and positive (north-up)"),
    ("scale_nan.tif", "pixel scale (NaN, 20) must be finite and positive (north-up)"),
    ("cut_signature.png", "invalid PNG: unexpected end of file"),
    ("cut_half.png", "PNG data is corrupt or truncated: unexpected end of file"),
    ("wrong_magic.png", "invalid PNG: Invalid PNG signature."),
    ("width_zero.png", "invalid PNG: Invalid image dimensions"),
    ("huge.png", "invalid PNG: limits are exceeded"),
    ("more_points_ascii.vtk", "POINTS declares 5000 points but only 150 coordinates follow (15000 needed)"),
    ("huge_points.vtk", "POINTS needs 96.0 GiB but the memory limit is 1.0 GiB (set --max-memory to raise it)"),
    ("cut_half.vtk", "FIELD array 'h' declares 50 values but only 26 follow"),
    ("wrong_magic.vtk", "not a legacy VTK file (no '# vtk DataFile' header)"),
    ("more_points_binary.vtk", "POINTS declares 5000 points (60000 bytes of float) but only 2759 bytes follow"),
    ("more_points.vtp", "array 'Points' holds 150 values, but 5000 points × 3 components need 15000"),
    ("huge_points.vtp", "array 'Points' needs 48.0 GiB but the memory limit is 1.0 GiB (set --max-memory to raise it)"),
    ("cut_half.vtp", "file is truncated: no closing </VTKFile>"),
    ("wrong_root.vtp", "not a VTK XML file (no VTKFile element)"),
    ("cut_appended.vtp", "file is truncated: no closing </VTKFile>"),
    ("short_data.mha", "file is truncated: it holds 30 bytes of voxel data, the header declares 48"),
    ("huge_dims.mha", "volume needs 1819.0 TiB but the memory limit is 1.0 GiB (set --max-memory to raise it)"),
    ("two_channels.mha", "ElementNumberOfChannels 2: a volume holds one value per voxel"),
    ("long_type.mha", "ElementType MET_LONG_LONG: not a scalar type volumes keep"),
    ("bad_zlib.mha", "voxel data does not decompress: corrupt deflate stream"),
    ("missing_raw.mhd", "data file gone.raw: no such file"),
    ("no_datafile.mha", "header has no ElementDataFile (or is longer than 1 MiB)"),
    ("short_data.nrrd", "file is truncated: it holds 30 bytes of voxel data, the header declares 48"),
    ("huge_sizes.nrrd", "volume needs 1819.0 TiB but the memory limit is 1.0 GiB (set --max-memory to raise it)"),
    ("vector_kind.nrrd", "kinds 'vector domain domain': a non-spatial axis (vector, colour, time, list) is not a scalar volume"),
    ("bzip2.nrrd", "encoding 'bzip2' (raw, gzip and ascii are read)"),
    ("cut_gzip.nrrd", "voxel data does not decompress: incomplete deflate stream"),
    ("missing_raw.nhdr", "data file gone.raw: no such file"),
    ("short_scalars.vtk", "file is truncated: 24 short values need 48 bytes, 30 remain"),
    ("wrong_count.vtk", "POINT_DATA 24 does not match DIMENSIONS [4, 3, 3] (36 points)"),
    ("rectilinear.vtk", "a RECTILINEAR_GRID's spacing varies along its axes: not a regular volume"),
    ("few_values.vti", "array 's' holds 3 values; the extent has 4 points"),
    ("huge_extent.vti", "array 's' needs 3638.0 TiB but the memory limit is 1.0 GiB (set --max-memory to raise it)"),
    ("no_scalars.vti", "PointData names Scalars 't', which it does not hold"),
];

/// Non-UTF-8 file names are read like any other, and named (lossily) in errors.
#[cfg(unix)]
#[test]
fn non_utf8_file_names_are_read_and_named() {
    use std::ffi::OsStr;
    use std::os::unix::ffi::OsStrExt;
    let tmp = tempfile::tempdir().unwrap();
    let good = tmp.path().join(OsStr::from_bytes(b"good\xff\xfe.nii"));
    std::fs::write(&good, fixture("nifti/i16_nifti1.nii")).unwrap();
    let out = Command::new(common::volterra_bin()).arg("info").arg(&good).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let bad = tmp.path().join(OsStr::from_bytes(b"bad\xff.nii"));
    std::fs::write(&bad, b"not a header").unwrap();
    let (code, stderr) = run_info(&bad);
    assert_eq!(code, Some(1));
    assert_eq!(stderr.trim_end(), format!("error: {}: not a NIfTI file (sizeof_hdr is neither 348 nor 540)", bad.display()));
    assert!(stderr.contains("bad\u{FFFD}.nii"), "{stderr}");
}

/// Scene files: an unknown key is named with its line, a missing data file with the path tried.
#[test]
fn scene_errors_name_the_key_line_and_the_path_tried() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = |body: &str| {
        let p = tmp.path().join("scene.toml");
        std::fs::write(&p, body).unwrap();
        let out = Command::new(common::volterra_bin()).arg("render").arg(&p).arg("-o").arg(tmp.path().join("out.exr")).output().unwrap();
        assert_eq!(out.status.code(), Some(1));
        assert!(!tmp.path().join("out.exr").exists());
        let err = String::from_utf8_lossy(&out.stderr).trim_end().to_string();
        assert_eq!(err.lines().count(), 1, "{err}");
        err.replace(&format!("{}: ", p.display()), "SCENE: ")
    };
    let head = "[image]\nwidth = 8\nheight = 8\n[camera]\nposition = [0.0, 100.0, 0.0]\nfocal_point = [0.0, 0.0, 0.0]\nview_up = [0.0, 0.0, 1.0]\n";
    let err = scene(&format!("{head}[[node]]\nname = \"v\"\nkind = \"volume\"\nfile = \"v.nii\"\nrendrer = \"reference\"\n"));
    assert!(
        err.starts_with(
            "error: SCENE: line 12: node 'v': unknown key `rendrer` (did you mean `renderer`?); a volume node takes: name, kind,"
        ),
        "{err}"
    );
    assert!(err.contains("opacity_scale") && !err.contains("texture"), "only a volume node's keys: {err}");
    let err = scene(&format!("{head}[[node]]\nname = \"p\"\nkind = \"particles\"\nfile = \"p.vtp\"\npreset = \"CT-AAA\"\n"));
    assert!(err.contains("line 12: node 'p': unknown key `preset`; a particles node takes: name,") && err.contains("color_by"), "{err}");
    // Outside nodes: the nearest key of that table.
    let err = scene(&head.replace("view_up", "veiw_up"));
    assert!(err.contains("unknown key `veiw_up` (did you mean `view_up`?)"), "{err}");
    let err = scene(&format!("{head}[[node]]\nname = \"v\"\nkind = \"volume\"\nfile = \"absent.nii\"\nrenderer = \"reference\"\n"));
    assert_eq!(err, format!("error: SCENE: node 'v': data file {} not found", tmp.path().join("absent.nii").display()));
}
