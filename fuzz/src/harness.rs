//! What every fuzz target does with its input, shared with `tests/fuzz_regressions.rs`, which
//! replays the inputs that once crashed a reader (`fuzz/regressions/<target>/`) on stable Rust.
//!
//! The readers take paths (that is how users call them, and it is where a lying header meets
//! a real file length), so each input is written to a scratch file first. A reader may return
//! `Ok` or `Err`; what it must never do is panic, hang, abort on memory, hand back data whose
//! sizes disagree with its own header, or print an error that is not one line naming the file.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use volterra_formats::{self as formats, FormatError, Heightfield, ParticleSet, Volume};

/// The targets, as named in `fuzz/Cargo.toml` and under `fuzz/regressions/`.
pub const TARGETS: &[&str] = &[
    "dicom_file",
    "dicom_series",
    "nifti",
    "nifti_gz",
    "geotiff",
    "geotiff_sidecars",
    "png_height",
    "vtk_legacy",
    "vtk_xml",
    "vtk_image",
    "metaimage",
    "nrrd",
];

/// Bytes that split a `dicom_series` input into the files of one directory.
pub const SERIES_SPLIT: &[u8] = b"\n--volterra-next-file--\n";

/// The memory guard under fuzzing: far below libFuzzer's 2 GiB RSS limit, so an allocation
/// the guard does not see shows up as a crash instead of passing unnoticed.
pub const FUZZ_MEMORY_LIMIT: u64 = 256 << 20;

fn scratch_dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        // /dev/shm where there is one: a file written per input must not cost a disk write.
        let base = if Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
        let dir = base.join(format!("volterra-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("scratch directory");
        dir
    })
}

fn write(path: &Path, data: &[u8]) {
    std::fs::write(path, data).expect("scratch file");
}

/// Runs one input through the reader `target` names and checks what came back.
pub fn run(target: &str, data: &[u8]) {
    let limits = formats::Limits::max(FUZZ_MEMORY_LIMIT);
    let dir = scratch_dir().join(target);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    match target {
        "dicom_file" => {
            let path = dir.join("input.dcm");
            write(&path, data);
            check_volume(&path, formats::dicom::read_dicom(&path, &Default::default(), &limits));
        }
        "dicom_series" => {
            for (i, part) in split(data, SERIES_SPLIT).into_iter().take(8).enumerate() {
                write(&dir.join(format!("{i:02}.dcm")), part);
            }
            check_error(&dir, formats::dicom::list_series(&dir, &limits).map(|_| ()));
            check_volume(&dir, formats::dicom::read_dicom(&dir, &Default::default(), &limits));
        }
        "nifti" => {
            let path = dir.join("input.nii");
            write(&path, data);
            check_volume(&path, formats::nifti::read_nifti(&path, &Default::default(), &limits));
        }
        "nifti_gz" => {
            // The input is the uncompressed stream, so mutations reach the header; a broken
            // gzip stream itself is in the malformed-input suite.
            let path = dir.join("input.nii.gz");
            let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
            gz.write_all(data).expect("gzip");
            write(&path, &gz.finish().expect("gzip"));
            check_volume(&path, formats::nifti::read_nifti(&path, &Default::default(), &limits));
        }
        "geotiff" => {
            let path = dir.join("input.tif");
            write(&path, data);
            let whole = formats::geotiff::read_geotiff(&path, &limits);
            // The windowed reader too: the middle of the raster's bounds, where it has any.
            if let Ok(hf) = &whole {
                let (w, h) = ((hf.width as f64 - 1.0) * hf.cell_size_native[0], (hf.height as f64 - 1.0) * hf.cell_size_native[1]);
                let [x, y] = hf.origin;
                let extent = [x + 0.25 * w, y - 0.75 * h, x + 0.75 * w, y - 0.25 * h];
                if extent.iter().all(|v| v.is_finite()) {
                    let opts = formats::geotiff::GeoTiffOptions { extent: Some(extent), level: None };
                    check_heightfield(&path, formats::geotiff::read_geotiff_with(&path, &opts, &limits));
                    // A level fixed by the last byte (an overview, or one the file lacks).
                    let level = data.last().map(|b| (b % 4) as usize);
                    let opts = formats::geotiff::GeoTiffOptions { level, ..opts };
                    check_heightfield(&path, formats::geotiff::read_geotiff_with(&path, &opts, &limits));
                }
            }
            check_heightfield(&path, whole);
        }
        "geotiff_sidecars" => {
            // A raster and the files GDAL reads beside it: PAM (.aux.xml), world file, .prj.
            let path = dir.join("input.tif");
            let names = ["input.tif", "input.tif.aux.xml", "input.tfw", "input.prj"];
            for (part, name) in split(data, SERIES_SPLIT).into_iter().zip(names) {
                write(&dir.join(name), part);
            }
            if path.exists() {
                // An error may name the sidecar at fault (input.tfw) rather than the raster.
                check_heightfield(&dir.join("input"), formats::geotiff::read_geotiff(&path, &limits));
            }
        }
        "png_height" => {
            let path = dir.join("input.png");
            write(&path, data);
            // The last byte picks the encoding, so all three decoders get inputs.
            let encoding = match data.last().map(|b| b % 3) {
                Some(1) => formats::png_height::HeightEncoding::Terrarium,
                Some(2) => formats::png_height::HeightEncoding::Mapbox,
                _ => formats::png_height::HeightEncoding::Grey,
            };
            let opts = formats::png_height::PngHeightOptions { encoding, ..Default::default() };
            check_heightfield(&path, formats::png_height::read_png_heightmap(&path, &opts, &limits));
        }
        "vtk_legacy" => {
            let path = dir.join("input.vtk");
            write(&path, data);
            check_particles(&path, formats::vtk::read_vtk_particles(&path, &Default::default(), &limits));
        }
        "vtk_xml" => {
            // .vtp and .vtu go through the same reader; the first byte picks the name.
            let name = if data.first().is_some_and(|b| b & 1 == 1) { "input.vtu" } else { "input.vtp" };
            let path = dir.join(name);
            write(&path, data);
            check_particles(&path, formats::vtk::read_vtk_particles(&path, &Default::default(), &limits));
        }
        "vtk_image" => {
            // Legacy STRUCTURED_POINTS or XML ImageData, by what the input starts with.
            let name = if data.starts_with(b"# vtk") { "input.vtk" } else { "input.vti" };
            let path = dir.join(name);
            write(&path, data);
            let read = if name == "input.vtk" {
                formats::vtk_image::read_structured_points(&path, &limits)
            } else {
                formats::vtk_xml::read_vti(&path, &limits)
            };
            check_volume(&path, read);
        }
        "metaimage" => {
            let path = dir.join("input.mha");
            write(&path, data);
            check_volume(&path, formats::metaimage::read_metaimage(&path, &limits));
        }
        "nrrd" => {
            let path = dir.join("input.nrrd");
            write(&path, data);
            check_volume(&path, formats::nrrd::read_nrrd(&path, &limits));
        }
        other => panic!("unknown fuzz target {other}"),
    }
}

fn split<'a>(data: &'a [u8], sep: &[u8]) -> Vec<&'a [u8]> {
    let mut parts = Vec::new();
    let mut rest = data;
    while let Some(at) = rest.windows(sep.len()).position(|w| w == sep) {
        parts.push(&rest[..at]);
        rest = &rest[at + sep.len()..];
    }
    parts.push(rest);
    parts
}

/// An error must be one line that names the file it is about.
fn check_error<T>(path: &Path, result: Result<T, FormatError>) -> Option<T> {
    match result {
        Ok(v) => Some(v),
        Err(e) => {
            let text = e.to_string();
            assert!(!text.contains('\n'), "error is not one line: {text:?}");
            assert!(!e.message.trim().is_empty(), "empty error message for {}", path.display());
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            assert!(text.contains(&name), "error does not name {name}: {text:?}");
            None
        }
    }
}

fn check_volume(path: &Path, result: Result<Volume, FormatError>) {
    let Some(v) = check_error(path, result) else { return };
    let n = v.dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).expect("dims overflow");
    assert!(n > 0, "empty volume {:?}", v.dims);
    assert_eq!(v.data.len(), n, "voxel count disagrees with dims {:?}", v.dims);
    assert!(v.spacing.iter().all(|s| s.is_finite() && *s > 0.0), "spacing {:?}", v.spacing);
    assert!(v.affine.iter().flatten().all(|x| x.is_finite()), "affine {:?}", v.affine);
    assert!(v.rescale.slope.is_finite() && v.rescale.intercept.is_finite(), "rescale {:?}", v.rescale);
    assert!(v.volume_index < v.volume_count.max(1));
}

fn check_heightfield(path: &Path, result: Result<Heightfield, FormatError>) {
    let Some(h) = check_error(path, result) else { return };
    let n = h.width.checked_mul(h.height).expect("size overflow");
    assert!(n > 0, "empty heightfield {}x{}", h.width, h.height);
    assert_eq!(h.elevations.len(), n);
    assert!(h.nodata.is_empty() || h.nodata.len() == n, "NoData mask length {}", h.nodata.len());
    assert!(h.cell_size.iter().all(|s| s.is_finite() && *s > 0.0), "cell size {:?}", h.cell_size);
    assert!(h.origin.iter().all(|o| o.is_finite()), "origin {:?}", h.origin);
    for (i, e) in h.elevations.iter().enumerate() {
        assert!(e.is_finite() || h.nodata.get(i), "non-finite elevation {e} not flagged NoData");
    }
}

fn check_particles(path: &Path, result: Result<ParticleSet, FormatError>) {
    let Some(p) = check_error(path, result) else { return };
    let n = p.len();
    for (name, len) in [
        ("mass", p.mass.as_ref().map(Vec::len)),
        ("density", p.density.as_ref().map(Vec::len)),
        ("h", p.smoothing_length.as_ref().map(Vec::len)),
    ] {
        if let Some(len) = len {
            assert_eq!(len, n, "{name} array length");
        }
    }
    for a in &p.arrays {
        assert_eq!(a.values.len(), a.components * n, "array {} length", a.name);
    }
}
