//! The wrong-data bugs of issue 15, each reproduced on the files that showed it: pydicom's
//! own test files (read in place from the reference venv), fixtures, and the CLI.

mod common;

use common::{repo_path, under_ci};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use volterra_formats::{dicom, LoadOptions};

fn volterra(args: &[&str]) -> std::process::Output {
    Command::new(common::volterra_bin()).args(args).output().unwrap()
}

/// pydicom's test files in the reference venv (tests/setup_venv.py installs it). Under CI a
/// missing venv is a failure; locally the test is skipped with a printed reason.
fn pydicom_file(name: &str) -> Option<PathBuf> {
    let lib = repo_path("tests/reference/.venv/lib");
    let found = std::fs::read_dir(&lib)
        .ok()
        .and_then(|d| d.flatten().map(|e| e.path().join("site-packages/pydicom/data/test_files").join(name)).find(|p| p.exists()));
    if found.is_none() {
        if under_ci() {
            panic!("pydicom's {name} not found under {} (CI=true: run tests/setup_venv.py first)", lib.display());
        }
        eprintln!("SKIPPED: pydicom's {name} not found under {} (run python3 tests/setup_venv.py)", lib.display());
    }
    found
}

fn real_range(v: &volterra_formats::Volume) -> (f64, f64) {
    let n = v.data.len();
    let vals: Vec<f64> = (0..n).map(|i| v.value(i)).collect();
    (vals.iter().cloned().fold(f64::INFINITY, f64::min), vals.iter().cloned().fold(f64::NEG_INFINITY, f64::max))
}

/// The RT Dose grid pydicom reads as 0.795 … 1.254 Gy in every encoding it ships: implicit
/// little endian (the reference), explicit big endian (the two 16-bit halves of each 32-bit
/// word were swapped: 23.07 … 4292.35), RLE (refused: "Could not decode pixel data"), and
/// their one-frame variants. Values equal voxel for voxel, spacing 10 mm from the elements
/// the RLE file stores with VR UN.
#[test]
fn rt_dose_reads_the_same_in_every_encoding() {
    let Some(reference) = pydicom_file("rtdose.dcm") else { return };
    let want = dicom::read_dicom(&reference, &Default::default(), &Default::default()).unwrap();
    assert_eq!(want.dims, [10, 10, 15]);
    let (lo, hi) = real_range(&want);
    assert!((lo - 0.795).abs() < 1e-9 && (hi - 1.254).abs() < 1e-9, "{lo} … {hi}");
    for name in ["rtdose_expb.dcm", "rtdose_rle.dcm"] {
        let p = pydicom_file(name).unwrap();
        let got = dicom::read_dicom(&p, &Default::default(), &Default::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(got.dims, want.dims, "{name}");
        assert_eq!(got.units, want.units, "{name}");
        assert_eq!(got.modality.as_deref(), Some("RTDOSE"), "{name}");
        for i in 0..want.data.len() {
            assert_eq!(got.value(i), want.value(i), "{name}: voxel {i}");
        }
        assert_eq!(got.spacing, [10.0, 10.0, want.spacing[2]], "{name}");
        for r in 0..4 {
            for c in 0..4 {
                assert!((got.affine[r][c] - want.affine[r][c]).abs() < 1e-9, "{name}: affine[{r}][{c}]");
            }
        }
    }
    for name in ["rtdose_expb_1frame.dcm", "rtdose_rle_1frame.dcm", "rtdose_1frame.dcm"] {
        let p = pydicom_file(name).unwrap();
        let got = dicom::read_dicom(&p, &Default::default(), &Default::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(got.dims, [10, 10, 1], "{name}");
        for i in 0..100 {
            assert_eq!(got.value(i), want.value(i), "{name}: voxel {i}");
        }
    }
}

/// `convert` carried the swapped big-endian values into NIfTI: the NIfTI written from the
/// big-endian file reads back as the implicit-VR one does.
#[test]
fn converting_a_big_endian_dose_writes_the_right_values() {
    let (Some(be), Some(le)) = (pydicom_file("rtdose_expb.dcm"), pydicom_file("rtdose.dcm")) else { return };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("dose.nii");
    let r = volterra(&["convert", be.to_str().unwrap(), out.to_str().unwrap()]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let got = volterra_formats::nifti::read_nifti(&out, &Default::default(), &Default::default()).unwrap();
    let want = dicom::read_dicom(&le, &Default::default(), &Default::default()).unwrap();
    for i in 0..want.data.len() {
        // NIfTI stores scl_slope as f32: DoseGridScaling 1e-6 becomes 1e-6 to 7 digits.
        assert!((got.value(i) - want.value(i)).abs() < 1e-6 * want.value(i).abs(), "voxel {i}: {} vs {}", got.value(i), want.value(i));
    }
}

/// Every 8/16-bit big-endian layout pydicom ships reads as its little-endian twin.
#[test]
fn big_endian_files_read_as_their_little_endian_twins() {
    for (be, le) in [
        ("MR_small_bigendian.dcm", "MR_small.dcm"),
        ("MR_small_expb.dcm", "MR_small.dcm"),
        ("SC_rgb_small_odd_big_endian.dcm", "SC_rgb_small_odd.dcm"),
    ] {
        let (Some(be), Some(le)) = (pydicom_file(be), pydicom_file(le)) else { return };
        let a = dicom::read_dicom(&be, &Default::default(), &Default::default()).unwrap_or_else(|e| panic!("{}: {e}", be.display()));
        let b = dicom::read_dicom(&le, &Default::default(), &Default::default()).unwrap();
        assert_eq!(a.dims, b.dims);
        assert!((0..b.data.len()).all(|i| a.value(i) == b.value(i)), "{} differs from {}", be.display(), le.display());
    }
}

/// Files with no preamble and no file meta group (ACR-NEMA style): read as pydicom's
/// `force=True` reads them, with a note. pydicom's own such files are RT plans (no image:
/// refused with one line); the images are MR_small in three encodings with the preamble and
/// the meta group cut off, which must read as the Part 10 file does.
#[test]
fn files_without_file_meta_are_read_with_a_note() {
    let Some(with_meta) = pydicom_file("MR_small.dcm") else { return };
    let want = dicom::read_dicom(&with_meta, &Default::default(), &Default::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for name in ["MR_small.dcm", "MR_small_implicit.dcm", "MR_small_bigendian.dcm"] {
        let bytes = std::fs::read(pydicom_file(name).unwrap()).unwrap();
        assert_eq!(&bytes[128..132], b"DICM");
        // (0002,0000) UL, 4 bytes: the meta group's length after this element.
        let group_len = u32::from_le_bytes(bytes[140..144].try_into().unwrap()) as usize;
        let bare = dir.path().join(format!("bare_{name}"));
        std::fs::write(&bare, &bytes[144 + group_len..]).unwrap();
        let got = volterra_formats::load(&bare, &LoadOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        let volterra_formats::Dataset::Volume(v) = got else { panic!("{name}: not a volume") };
        assert!(v.notes.iter().any(|n| n.contains("no DICOM file meta header")), "{name}: {:?}", v.notes);
        assert_eq!(v.dims, want.dims, "{name}");
        assert_eq!(v.affine, want.affine, "{name}");
        assert!((0..want.data.len()).all(|i| v.value(i) == want.value(i)), "{name}: values differ from MR_small.dcm");
    }
    for name in ["ExplVR_LitEndNoMeta.dcm", "ExplVR_BigEndNoMeta.dcm", "no_meta.dcm"] {
        let p = pydicom_file(name).unwrap();
        let err = dicom::read_dicom(&p, &Default::default(), &Default::default()).unwrap_err().to_string();
        assert!(err.contains(name) && !err.contains('\n'), "{err}");
    }
    // Bytes that are no data set are still refused, with one line.
    let junk = dir.path().join("junk.dcm");
    std::fs::write(&junk, [0x08u8, 0x00, 0x10, 0x00, 0xFF, 0xFF, 0xFF, 0x7F, 1, 2, 3]).unwrap();
    let err = dicom::read_dicom(&junk, &Default::default(), &Default::default()).unwrap_err().to_string();
    assert!(err.contains("junk.dcm") && !err.contains('\n'), "{err}");
}

/// A 17×21×3×20 fMRI-like 4-D NIfTI converted whole (it became 17×21×3), or one volume
/// when --volume says so.
#[test]
fn converting_a_4d_nifti_keeps_every_volume() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("fmri.nii.gz");
    let mut vols = Vec::new();
    for t in 0..20usize {
        let data: Vec<i16> = (0..17 * 21 * 3).map(|i| (i as i16).wrapping_mul(7).wrapping_add(t as i16 * 100)).collect();
        let affine = [[-3.0, 0.0, 0.0, 24.0], [0.0, 3.0, 0.0, -30.0], [0.0, 0.0, 4.0, -6.0], [0.0, 0.0, 0.0, 1.0]];
        let rescale = volterra_formats::Rescale { slope: 0.5, intercept: 10.0 };
        vols.push(volterra_formats::Volume {
            volume_count: 20,
            volume_index: t,
            ..common::volume([17, 21, 3], affine, volterra_formats::VoxelData::I16(data), rescale)
        });
    }
    volterra_formats::nifti::write_nifti_volumes(&src, &vols, &[20], 2.5, 8).unwrap();
    let out = dir.path().join("out.nii");
    let r = volterra(&["convert", src.to_str().unwrap(), out.to_str().unwrap()]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let h = volterra_formats::nifti::read_nifti_header(&out).unwrap();
    assert_eq!(&h.dim[..5], &[4, 17, 21, 3, 20]);
    assert_eq!(h.pixdim[4], 2.5);
    let all = volterra_formats::nifti::read_nifti_volumes(&out, &Default::default()).unwrap();
    assert_eq!(all.volumes.len(), 20);
    for (a, b) in all.volumes.iter().zip(&vols) {
        assert_eq!(a.data, b.data);
        assert_eq!(a.rescale, b.rescale);
    }
    // One volume, when asked for.
    let one = dir.path().join("one.nii");
    let r = volterra(&["convert", src.to_str().unwrap(), one.to_str().unwrap(), "--volume", "7"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let v = volterra_formats::nifti::read_nifti(&one, &Default::default(), &Default::default()).unwrap();
    assert_eq!(v.dims, [17, 21, 3]);
    assert_eq!(v.volume_count, 1);
    assert_eq!(v.data, vols[7].data);
}

/// `render -o out.png` wrote EXR bytes into a file named .png: the format follows the
/// extension, and an unknown one is refused naming those supported.
#[test]
fn render_output_format_follows_the_extension() {
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("samples");
    assert!(volterra(&["samples", samples.to_str().unwrap()]).status.success());
    let scene = samples.join("angio.toml");
    let png = dir.path().join("out.png");
    let exr = dir.path().join("out.exr");
    for (out, magic) in [(&png, &b"\x89PNG"[..]), (&exr, &b"\x76\x2f\x31\x01"[..])] {
        let r = volterra(&[
            "render",
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--set",
            "image.width=32",
            "--set",
            "image.height=32",
        ]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let bytes = std::fs::read(out).unwrap();
        assert_eq!(&bytes[..4], magic, "{}", out.display());
    }
    let bad = dir.path().join("out.jpg");
    let r = volterra(&["render", scene.to_str().unwrap(), "-o", bad.to_str().unwrap()]);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("out.jpg") && err.contains(".exr") && err.contains(".png"), "{err}");
    assert!(!bad.exists());
    // An output directory that does not exist is named before any work.
    let missing = dir.path().join("no/such/dir/out.exr");
    let r = volterra(&["render", scene.to_str().unwrap(), "-o", missing.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1));
    assert!(err.contains("output directory") && err.contains("does not exist") && err.lines().count() == 1, "{err}");
    let r = volterra(&[
        "convert",
        repo_path("tests/fixtures/nifti/scaled.nii").to_str().unwrap(),
        missing.with_extension("nii").to_str().unwrap(),
    ]);
    assert!(String::from_utf8_lossy(&r.stderr).contains("does not exist"));
}

/// `volterra info --json FILE | head -1` panicked ("failed printing to stdout: Broken
/// pipe", exit 101, a backtrace): a closed pipe ends the program quietly.
#[test]
fn a_closed_pipe_ends_info_quietly() {
    let p = repo_path("tests/fixtures/nifti/scaled.nii");
    for _ in 0..3 {
        let mut child = Command::new(common::volterra_bin())
            .args(["info", "--json", p.to_str().unwrap()])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take()); // the reader is gone before anything is written
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("panicked") && !err.contains("Broken pipe"), "{err}");
        assert_ne!(out.status.code(), Some(101), "{err}");
    }
}

/// A gzip stream named `.nii` is read by its bytes (it was refused as a bad header).
#[test]
fn a_gzip_stream_named_nii_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let plain = repo_path("tests/fixtures/nifti/scaled.nii");
    let gz = dir.path().join("really_gzipped.nii");
    let mut enc = flate2::write::GzEncoder::new(std::fs::File::create(&gz).unwrap(), flate2::Compression::fast());
    std::io::Write::write_all(&mut enc, &std::fs::read(&plain).unwrap()).unwrap();
    enc.finish().unwrap();
    let a = volterra_formats::nifti::read_nifti(&gz, &Default::default(), &Default::default()).unwrap();
    let b = volterra_formats::nifti::read_nifti(&plain, &Default::default(), &Default::default()).unwrap();
    assert_eq!((a.dims, a.affine, &a.data), (b.dims, b.affine, &b.data));
}

/// `error: XDG_RUNTIME_DIR is invalid or not set` was printed on every GPU render (Mesa's
/// device-select layer asking libwayland for a display): a render without a runtime
/// directory prints only its own lines.
#[test]
fn a_gpu_render_without_a_runtime_directory_prints_no_wayland_error() {
    if common::gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("samples");
    assert!(volterra(&["samples", samples.to_str().unwrap()]).status.success());
    let out = dir.path().join("t.exr");
    let r = Command::new(common::volterra_bin())
        .args(["render", samples.join("terrain.toml").to_str().unwrap(), "-o", out.to_str().unwrap()])
        .args(["--set", "image.width=64", "--set", "image.height=48"])
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("NODEVICE_SELECT")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{err}");
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
}

/// `--max-memory` covered only the input: a CT four times smaller than the limit was
/// accepted and the render peaked far above it. The budget bounds the whole command: a
/// limit below what reading + preparation + frames need is refused before the work, naming
/// what it needs; a sufficient one is kept (the peak the binary counts stays under it).
#[test]
fn max_memory_bounds_the_whole_render() {
    let dir = tempfile::tempdir().unwrap();
    let (nx, ny, nz) = (256usize, 256usize, 160usize);
    // A CT-like int16 volume: air, a body ellipse, bone ring, a vessel, noise.
    let mut data = vec![0i16; nx * ny * nz];
    let mut seed = 12345u32;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
                let (u, v) = ((x as f64 - 128.0) / 100.0, (y as f64 - 128.0) / 80.0);
                let r = (u * u + v * v).sqrt();
                let mut hu = if r < 1.0 { 40.0 } else { -1000.0 };
                if (0.85..0.95).contains(&r) {
                    hu = 900.0;
                }
                if ((x as f64 - 150.0).powi(2) + (y as f64 - 120.0).powi(2)).sqrt() < 6.0 {
                    hu = 350.0;
                }
                data[(z * ny + y) * nx + x] = (hu + ((seed >> 16) % 40) as f64 - 20.0 + 1024.0) as i16;
            }
        }
    }
    let affine = [[0.7, 0.0, 0.0, -90.0], [0.0, 0.7, 0.0, -90.0], [0.0, 0.0, 1.25, -100.0], [0.0, 0.0, 0.0, 1.0]];
    let rescale = volterra_formats::Rescale { slope: 1.0, intercept: -1024.0 };
    let vol = common::volume([nx, ny, nz], affine, volterra_formats::VoxelData::I16(data), rescale);
    volterra_formats::nifti::write_nifti(&dir.path().join("ct.nii"), &vol).unwrap();
    let scene = dir.path().join("ct.toml");
    std::fs::write(
        &scene,
        r#"[image]
width = 256
height = 256

[camera]
position = [300.0, 250.0, 120.0]
focal_point = [0.0, 0.0, 0.0]
view_up = [0.0, 0.0, 1.0]
parallel_projection = true
parallel_scale = 110.0

[[node]]
name = "ct"
kind = "volume"
file = "ct.nii"
renderer = "shear-warp"

# The intermediate image counts against the limit too (20 bytes per pixel): at ratio 2,
# 11 MiB for this view; the automatic ratio (4.65 here) would need 60 MiB.
[node.settings]
supersampling = 2.0

[node.transfer_function]
scalar_opacity = [[-1000.0, 0.0], [100.0, 0.0], [300.0, 0.2], [1000.0, 0.8]]
color = [[-1000.0, 0.3, 0.1, 0.1], [300.0, 0.9, 0.3, 0.2], [1000.0, 1.0, 1.0, 0.9]]
"#,
    )
    .unwrap();
    let stored = (nx * ny * nz * 2) as f64;
    let out = dir.path().join("ct.exr");
    let render_with = |limit: &str, sets: &[&str]| {
        Command::new(common::volterra_bin())
            .args(["--max-memory", limit, "render", scene.to_str().unwrap(), "-o", out.to_str().unwrap()])
            .args(sets.iter().flat_map(|s| ["--set", s]))
            .output()
            .unwrap()
    };
    let render = |limit: &str| render_with(limit, &[]);
    // 1.5× the stored volume: enough for reading it, not for reading and preparing it.
    let tight = format!("{}", (1.5 * stored) as u64);
    let r = render(&tight);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("memory limit") && err.contains("needs"), "the refusal names what the work needs: {err}");
    assert_eq!(err.lines().count(), 1, "one line: {err}");
    assert!(!out.exists(), "no output from refused work");
    // Enough: it renders, and the peak the binary counted stays within the limit.
    let r = render("200M");
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{err}");
    let peak_line = err.lines().find(|l| l.starts_with("memory: peak")).unwrap_or_else(|| panic!("no peak reported: {err}"));
    assert!(!peak_line.contains("over the limit"), "{peak_line}");
    assert!(out.exists());
    // Within 2.5× the stored volume and 12 MiB more (issue 17's target: the volume, one u16
    // copy of its slices along the viewing axis, the min-max map at 8 bits; no quantised
    // copy of the whole volume beside them; and the intermediate image): measured 56.8 MiB
    // for this 20 MiB CT (62.6 with a 16-bit map). A quantised copy kept as well needed
    // about 4×.
    std::fs::remove_file(&out).unwrap();
    let enough = format!("{}", (2.5 * stored) as u64 + (12 << 20));
    let r = render(&enough);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{err}");
    eprintln!("{}", err.lines().find(|l| l.starts_with("memory: peak")).unwrap_or(""));
    assert!(out.exists());
    // The automatic ratio's intermediate image (60 MiB here) does not fit beside the
    // prepared volume: refused before it is allocated, naming it, and no output.
    std::fs::remove_file(&out).unwrap();
    let r = render_with(&enough, &["node.ct.settings.supersampling=0"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("the intermediate image") && err.contains("memory limit"), "{err}");
    assert!(!out.exists(), "no output from refused work");
}

/// `info` prints values as people read them and what gdalinfo and dcm2niix users look for.
#[test]
fn info_prints_what_gdalinfo_and_dcm2niix_users_look_for() {
    let text = |p: &std::path::Path| {
        let r = volterra(&["info", p.to_str().unwrap()]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        String::from_utf8(r.stdout).unwrap()
    };
    // GeoTIFF (written by tifffile: tiepoint 500000, 5200000, cells 30 × 20 m, 45 × 37).
    let t = text(&repo_path("tests/fixtures/geotiff/i32_deflate_pred2.tif"));
    for want in [
        "data type   int32",
        "compression Deflate, predictor 2",
        "upper left  (  500000.000, 5200000.000) (123d 0' 0.00\"W, 46d57'12.71\"N)",
        "lower right (  501350.000, 5199260.000)",
        "bounds      west 500000.000, south 5199260.000, east 501350.000, north 5200000.000",
        "transform   500000.000, 30, 0, 5200000.000, 0, -20",
        "(value -9999)",
    ] {
        assert!(t.contains(want), "missing {want:?} in:\n{t}");
    }
    assert!(!t.contains("Some("), "{t}");
    // NIfTI: codes and the orientation string (nibabel's aff2axcodes of this affine: LAS).
    let t = text(&repo_path("tests/fixtures/nifti/scaled.nii"));
    for want in ["orientation L", "sform_code", "qform_code"] {
        assert!(t.contains(want), "missing {want:?} in:\n{t}");
    }
    // DICOM: series, modality and transfer syntax by name.
    let t = text(&repo_path("tests/fixtures/dicom/oblique"));
    for want in ["transfer syntax", "modality    CT"] {
        assert!(t.contains(want), "missing {want:?} in:\n{t}");
    }
    // No float noise from f32 values.
    assert!(!t.lines().any(|l| l.starts_with("range") && l.contains("00000")), "{t}");
}
