#!/usr/bin/env python3
"""Builds the seed corpus of every fuzz target (standard library only).

usage: make_seeds.py OUT_DIR [SHARED_DATA_DIR]

Seeds are the project's own fixtures and samples, the small files of ../shared/data (read in
place, copied only into the throw-away seed directory, never into the repository), a few
tiny PNGs written here, and for `dicom_series` whole fixture series joined into one input
with the separator the harness splits on (fuzz/src/harness.rs: SERIES_SPLIT).
"""
import gzip
import shutil
import struct
import sys
import zlib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SERIES_SPLIT = b"\n--volterra-next-file--\n"
MAX_SEED = 1 << 20  # libFuzzer runs with -max_len 1 MiB; larger files would be cut anyway


def png(width, height, colour_type, bit_depth, pixels: bytes) -> bytes:
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    channels = {0: 1, 2: 3, 4: 2, 6: 4}[colour_type]
    row = width * channels * bit_depth // 8
    raw = b"".join(b"\0" + pixels[y * row:(y + 1) * row] for y in range(height))
    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def plain_tiff(width=4, height=3) -> bytes:
    """A little-endian TIFF of int16 samples in one strip, no georeferencing tags."""
    pixels = struct.pack(f"<{width * height}h", *range(width * height))
    tags = [(256, 3, width), (257, 3, height), (258, 3, 16), (259, 3, 1), (262, 3, 1), (273, 4, 8),
            (277, 3, 1), (278, 3, height), (279, 4, len(pixels)), (339, 3, 2)]
    ifd_at = 8 + len(pixels)
    ifd = struct.pack("<H", len(tags)) + b"".join(
        struct.pack("<HHI", tag, kind, 1) + (struct.pack("<HH", value, 0) if kind == 3 else struct.pack("<I", value))
        for tag, kind, value in tags) + struct.pack("<I", 0)
    return b"II*\0" + struct.pack("<I", ifd_at) + pixels + ifd


def small_files(directory: Path, suffixes):
    if not directory.is_dir():
        return []
    return sorted(p for p in directory.rglob("*") if p.is_file() and p.stat().st_size <= MAX_SEED
                  and any(p.name.lower().endswith(s) for s in suffixes))


def main():
    out = Path(sys.argv[1])
    shared = Path(sys.argv[2]) if len(sys.argv) > 2 else None
    have_shared = shared is not None and shared.is_dir()
    fixtures = ROOT / "tests" / "fixtures"
    seeds = {t: [] for t in ["dicom_file", "dicom_series", "nifti", "nifti_gz", "geotiff", "geotiff_sidecars", "png_height",
                             "vtk_legacy", "vtk_xml", "vtk_image", "metaimage", "nrrd"]}

    dicoms = small_files(fixtures / "dicom", [".dcm"])
    if have_shared:
        dicoms += small_files(shared / "volumes" / "dicom_real" / "pydicom", [".dcm"])
    seeds["dicom_file"] = [(p.name, p.read_bytes()) for p in dicoms]
    for series in sorted(d for d in (fixtures / "dicom").iterdir() if d.is_dir()):
        files = sorted(series.glob("*.dcm"))
        seeds["dicom_series"].append((series.name, SERIES_SPLIT.join(f.read_bytes() for f in files)))
    if have_shared:
        py = shared / "volumes" / "dicom_real" / "pydicom"
        pair = [py / "CT_small.dcm", py / "MR_small.dcm"]
        if all(p.exists() for p in pair):
            seeds["dicom_series"].append(("two_series_real", SERIES_SPLIT.join(p.read_bytes() for p in pair)))

    niftis = [p for p in small_files(fixtures / "nifti", [".nii", ".nii.gz"])]
    if have_shared:
        niftis += small_files(shared / "volumes", [".nii", ".nii.gz"])
    for p in niftis:
        data = p.read_bytes()
        if p.name.endswith(".gz"):
            data = gzip.decompress(data)
            if len(data) > MAX_SEED:
                continue
        seeds["nifti"].append((p.name.removesuffix(".gz"), data))
        seeds["nifti_gz"].append((p.name.removesuffix(".gz"), data))

    tiffs = small_files(fixtures / "geotiff", [".tif"]) + small_files(ROOT / "samples", [".tif"])
    if have_shared:
        tiffs += small_files(shared / "terrain", [".tif", ".tiff"])
    seeds["geotiff"] = [(p.name, p.read_bytes()) for p in tiffs]

    # A plain TIFF and the sidecars GDAL reads beside it (the harness splits the parts):
    # PAM with a WKT1 CRS, geotransform and NoData; a world file; a .prj in WKT2.
    utm = ('PROJCS["WGS 84 / UTM zone 10N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],'
           'UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],UNIT["metre",1],AUTHORITY["EPSG","32610"]]')
    pam = ('<PAMDataset>\n  <SRS>' + utm.replace('"', "&quot;") + '</SRS>\n  <GeoTransform> 500000, 30, 0, 4200000, 0, -30</GeoTransform>\n'
           '  <PAMRasterBand band="1"><NoDataValue>-32768</NoDataValue></PAMRasterBand>\n</PAMDataset>\n').encode()
    wkt2 = b'GEOGCRS["WGS 84",DATUM["World Geodetic System 1984",ELLIPSOID["WGS 84",6378137,298.257223563]],CS[ellipsoidal,2],ID["EPSG",4326]]'
    world = b"30.0\n0.0\n0.0\n-30.0\n500015.0\n4199985.0\n"
    seeds["geotiff_sidecars"] = [
        ("pam.bin", SERIES_SPLIT.join([plain_tiff(), pam, b"", b""])),
        ("world_prj.bin", SERIES_SPLIT.join([plain_tiff(), b"<PAMDataset/>", world, wkt2])),
        ("world_only.bin", SERIES_SPLIT.join([plain_tiff(), b"<PAMDataset></PAMDataset>", world, utm.encode()])),
    ] + [(p.name + ".bin", SERIES_SPLIT.join([p.read_bytes(), pam, world, wkt2])) for p in tiffs[:3]]

    # Grey 8/16-bit, grey+alpha, RGB and RGBA; the harness picks the encoding from the last byte.
    seeds["png_height"] = [
        ("grey8.png", png(4, 3, 0, 8, bytes(range(12)))),
        ("grey16.png", png(5, 4, 0, 16, b"".join(struct.pack(">H", 1000 * i) for i in range(20)))),
        ("grey_alpha.png", png(3, 2, 4, 8, bytes(range(12)))),
        ("rgb.png", png(3, 3, 2, 8, bytes(range(27)))),
        ("rgba.png", png(2, 2, 6, 8, bytes(range(16)))),
    ] + [(p.name, p.read_bytes()) for p in small_files(ROOT / "samples", [".png"])]

    seeds["vtk_legacy"] = [(p.name, p.read_bytes()) for p in small_files(fixtures / "vtk", [".vtk"])]
    seeds["vtk_xml"] = [(p.name, p.read_bytes()) for p in small_files(fixtures / "vtk", [".vtp", ".vtu"])]
    if have_shared:
        seeds["vtk_legacy"] += [(p.name, p.read_bytes()) for p in small_files(shared, [".vtk"])]
        seeds["vtk_xml"] += [(p.name, p.read_bytes()) for p in small_files(shared, [".vtp", ".vtu"])]

    # Volumes in the text-header formats: small ones written here (every encoding the readers
    # take), and the real files in ../shared/data that are small enough.
    vox = struct.pack("<24h", *range(-12, 12))  # 4 x 3 x 2 int16
    seeds["metaimage"] = [
        ("raw.mha", b"ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementSpacing = 0.5 1 2\nOffset = 1 2 3\n"
                    b"TransformMatrix = 0 1 0 -1 0 0 0 0 1\nElementType = MET_SHORT\nElementDataFile = LOCAL\n" + vox),
        ("zlib.mha", b"ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nCompressedData = True\nBinaryDataByteOrderMSB = True\n"
                     b"ElementType = MET_SHORT\nElementDataFile = LOCAL\n" + zlib.compress(struct.pack(">24h", *range(24)))),
        ("float2d.mha", b"ObjectType = Image\nNDims = 2\nDimSize = 3 2\nElementType = MET_FLOAT\nElementDataFile = LOCAL\n"
                        + struct.pack("<6f", *[0.5 * i for i in range(6)])),
    ]
    seeds["nrrd"] = [
        ("raw.nrrd", b"NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 2\nspace: left-posterior-superior\n"
                     b"space directions: (0.5,0,0) (0,1,0) (0,0.2,2)\nspace origin: (1,2,3)\nendian: little\nencoding: raw\n\n" + vox),
        ("gzip.nrrd", b"NRRD0005\ntype: uint16\ndimension: 3\nsizes: 4 3 2\nspacings: 1 1 2\nendian: big\nencoding: gzip\n\n"
                      + gzip.compress(struct.pack(">24H", *range(24)))),
        ("ascii.nrrd", b"NRRD0004\ntype: float\ndimension: 2\nsizes: 3 2\nencoding: ascii\n\n0 1.5 2\n3 4 -5\n"),
    ]
    seeds["vtk_image"] = [
        ("points.vtk", b"# vtk DataFile Version 3.0\nseed\nBINARY\nDATASET STRUCTURED_POINTS\nDIMENSIONS 4 3 2\n"
                       b"ORIGIN 0 0 0\nSPACING 1 1 1\nPOINT_DATA 24\nSCALARS s short 1\nLOOKUP_TABLE default\n"
                       + struct.pack(">24h", *range(24)) + b"\n"),
        ("ascii.vtk", b"# vtk DataFile Version 3.0\nseed\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 2 2 1\n"
                      b"SPACING 1 1 1\nORIGIN 0 0 0\nPOINT_DATA 4\nVECTORS v float\n0 0 0 1 1 1 2 2 2 3 3 3\n"
                      b"SCALARS s float\nLOOKUP_TABLE default\n0 1 2 3\n"),
        ("inline.vti", b'<?xml version="1.0"?>\n<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian">\n'
                       b'<ImageData WholeExtent="0 1 0 1 0 0" Origin="0 0 0" Spacing="1 1 1" Direction="0 1 0 1 0 0 0 0 1">\n'
                       b'<Piece Extent="0 1 0 1 0 0"><PointData Scalars="s"><DataArray type="Float32" Name="s" format="ascii">'
                       b"0 1 2 3</DataArray></PointData></Piece></ImageData></VTKFile>\n"),
    ]
    if have_shared:
        seeds["metaimage"] += [(p.name, p.read_bytes()) for p in small_files(shared / "volumes", [".mha"])]
        seeds["vtk_image"] += [(p.name, p.read_bytes()) for p in small_files(shared / "volumes", [".vti"])]

    for target, files in seeds.items():
        d = out / target
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        for i, (name, data) in enumerate(files):
            (d / f"{i:03d}_{name}").write_bytes(data)
        print(f"{target}: {len(files)} seeds")


if __name__ == "__main__":
    main()
