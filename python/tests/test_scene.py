"""Scenes built in Python and rendered from it, against the command line: a scene built
from arrays in memory renders bit for bit as the same scene written by `to_toml` and
rendered by `volterra render`; a loaded scene file renders as the CLI renders it; bad
arrays and keys raise clear errors; the camera moves as VTK's does; the GIL is released
while rendering and Ctrl-C cancels. Run by tests/python.sh with pytest."""

import _thread
import threading
import time

import numpy as np
import pytest

import volterra
from _support import cli, shared


def same_as_cli(scene, tmp_path, name):
    """Renders `scene` here and, written by to_toml, by the CLI: the EXR files' bytes."""
    toml = tmp_path / f"{name}.toml"
    scene.to_toml(toml)
    ours, theirs = tmp_path / f"{name}_py.exr", tmp_path / f"{name}_cli.exr"
    frame = scene.render()
    frame.save(ours)
    cli("render", toml, "-o", theirs)
    return frame, ours.read_bytes(), theirs.read_bytes()


def blob(shape=(40, 50, 60), dtype=np.int16):
    i, j, k = np.meshgrid(*(np.arange(n) for n in shape), indexing="ij")
    c = [n / 2 for n in shape]
    r2 = (i - c[0]) ** 2 + 0.6 * (j - c[1]) ** 2 + 1.4 * (k - c[2]) ** 2
    return (1200 * np.exp(-r2 / 150.0) - 100 * (k > c[2])).astype(dtype)


# An oblique placement with non-unit, unequal spacing and a flipped axis.
ODD_AFFINE = np.array(
    [
        [0.0, -0.75, 0.25, 12.5],
        [0.5, 0.0, 0.0, -30.0],
        [0.0, 0.125, 1.5, 7.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


@pytest.mark.parametrize("renderer", ["shear-warp", "reference", "gpu-raycast"])
def test_volume_from_arrays_renders_as_the_cli_from_files(tmp_path, renderer):
    scene = volterra.Scene(width=96, height=80, background=(0.1, 0.1, 0.2))
    scene.add_volume(blob(), ODD_AFFINE, preset="CT-AAA", shading=True, renderer=renderer)
    scene.camera.azimuth(40)
    scene.camera.elevation(25)
    frame, ours, theirs = same_as_cli(scene, tmp_path, "vol")
    assert ours == theirs
    assert frame.rgba.shape == (80, 96, 4) and frame.rgba.dtype == np.float32
    # Something was drawn, and the depth is finite exactly where it was.
    assert (frame.rgba[..., 3] > 0.5).sum() > 100
    assert np.isfinite(frame.depth).sum() > 100


def test_parallel_mip_of_the_aneurism_read_in_python_renders_as_the_cli(tmp_path):
    ct = volterra.read(shared("volumes/aneurism/aneurism.nii.gz"))
    scene = volterra.Scene(width=128, height=128)
    scene.add_volume(ct, blend="mip")
    scene.camera.parallel_projection = True
    scene.camera.reset()
    _, ours, theirs = same_as_cli(scene, tmp_path, "mip")
    assert ours == theirs


def test_terrain_from_an_array_renders_as_the_cli_from_its_geotiff(tmp_path):
    y, x = np.mgrid[0:60, 0:80]
    z = (100 + 30 * np.sin(x / 9.0) * np.cos(y / 7.0)).astype(np.float32)
    z[5:8, 10:12] = np.nan  # NoData
    scene = volterra.Scene(width=120, height=90, background=(0.55, 0.7, 0.9))
    scene.add_heightfield(z, (500000.0, 10.0, 0.0, 4100000.0, 0.0, -10.0), epsg=32633)
    scene.add_light("directional", direction=(1, 1, -1))
    frame, ours, theirs = same_as_cli(scene, tmp_path, "dem")
    assert ours == theirs
    assert frame.stats["renderer"] == "terrain"


@pytest.mark.parametrize("renderer", ["points", "smoke"])
def test_particles_from_arrays_render_as_the_cli_from_vtp(tmp_path, renderer):
    rng = np.random.default_rng(7)
    pos = rng.normal(scale=[1.0, 0.5, 2.0], size=(3000, 3))
    scene = volterra.Scene(width=96, height=96)
    if renderer == "points":
        scene.add_particles(pos, {"h": np.full(3000, 0.15), "temp": pos[:, 2]}, renderer="points", color_by="temp")
    else:
        scene.add_particles(pos, {"h": np.full(3000, 0.3)}, renderer="smoke", medium={"albedo": 0.9, "g": 0.3})
        scene.add_light(direction=(-1, 0.6, -0.5), intensity=3.0)
    _, ours, theirs = same_as_cli(scene, tmp_path, renderer)
    assert ours == theirs


def test_a_scene_file_loaded_renders_as_the_cli_renders_it(tmp_path):
    cli("samples", tmp_path)
    scene = volterra.Scene.load(tmp_path / "angio.toml", set=["image.width=64", "image.height=48"])
    frame = scene.render()
    frame.save(tmp_path / "py.exr")
    frame.save(tmp_path / "py.png")
    cli("render", tmp_path / "angio.toml", "-o", tmp_path / "cli.exr", "--png", tmp_path / "cli.png",
        "--set", "image.width=64", "--set", "image.height=48")
    assert (tmp_path / "py.exr").read_bytes() == (tmp_path / "cli.exr").read_bytes()
    assert (tmp_path / "py.png").read_bytes() == (tmp_path / "cli.png").read_bytes()
    assert frame._repr_png_() == (tmp_path / "cli.png").read_bytes()
    # to_toml of a loaded scene names its data relative to where it is written.
    (tmp_path / "sub").mkdir()
    scene.to_toml(tmp_path / "sub" / "again.toml")
    cli("render", tmp_path / "sub" / "again.toml", "-o", tmp_path / "again.exr")
    assert (tmp_path / "again.exr").read_bytes() == (tmp_path / "cli.exr").read_bytes()


def test_frame_arrays_hold_what_the_exr_holds():
    scene = volterra.Scene(width=32, height=24, background=(0.2, 0.3, 0.4))
    scene.add_volume(blob((20, 20, 20)), np.diag([2.0, 2.0, 2.0, 1.0]))
    frame = scene.render()
    rgba, rgb = frame.rgba, frame.rgb
    np.testing.assert_array_equal(rgb, rgba[..., :3] + (1 - rgba[..., 3:]) * np.float32([0.2, 0.3, 0.4]))
    stats = frame.stats
    assert stats["renderer"] == "shear-warp" and stats["nodes"][0]["node"] == "volume"
    assert stats["counters"]["samples"] > 0


def test_layouts_of_one_array_render_the_same():
    data = blob((30, 32, 34))
    frames = []
    for variant in (data, np.asfortranarray(data), np.ascontiguousarray(data), np.ascontiguousarray(data[:, :, ::-1])[:, :, ::-1]):
        scene = volterra.Scene(width=48, height=48)
        scene.add_volume(variant, np.diag([1.0, 1.5, 2.0, 1.0]))
        frames.append(scene.render().rgba)
    for f in frames[1:]:
        np.testing.assert_array_equal(f, frames[0])
    # A strided view (every other voxel) renders as its contiguous copy.
    a, b = volterra.Scene(width=40, height=40), volterra.Scene(width=40, height=40)
    a.add_volume(data[::2, ::2, ::2])
    b.add_volume(np.array(data[::2, ::2, ::2], order="F"))
    np.testing.assert_array_equal(a.render().rgba, b.render().rgba)


def test_from_nibabel_renders_as_the_file_read_by_volterra():
    nib = pytest.importorskip("nibabel")
    path = shared("volumes/mr/nibabel_anatomical.nii")
    ours, theirs = volterra.read(path), volterra.from_nibabel(nib.load(path))
    np.testing.assert_array_equal(theirs.array, ours.array)
    np.testing.assert_array_equal(theirs.affine, ours.affine)
    frames = []
    for v in (ours, theirs):
        scene = volterra.Scene(width=48, height=48)
        scene.add_volume(v, preset="MR-Default")
        frames.append(scene.render().rgba)
    np.testing.assert_array_equal(frames[0], frames[1])


BAD_VOLUMES = [
    (np.zeros((4, 4, 4), dtype=np.complex64), TypeError, "complex64"),
    (np.zeros((4, 4, 4), dtype=bool), TypeError, "bool"),
    (np.zeros((4, 4, 4), dtype=np.int64), TypeError, "int64"),
    (np.zeros((4, 4, 0), dtype=np.uint8), ValueError, "empty"),
    (np.zeros((4, 4), dtype=np.uint8), ValueError, "3 dimensions"),
    (np.zeros((2, 4, 4, 4), dtype=np.uint8), ValueError, "3 dimensions"),
]


@pytest.mark.parametrize("array, error, words", BAD_VOLUMES)
def test_bad_volume_arrays_raise_clear_errors(array, error, words):
    with pytest.raises(error, match=words):
        volterra.Scene().add_volume(array)


@pytest.mark.parametrize(
    "affine, words",
    [
        (np.diag([1.0, np.nan, 1.0, 1.0]), "NaN"),
        (np.diag([1.0, 0.0, 1.0, 1.0]), "singular"),
        (np.eye(3), "4×4"),
        (np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1.0]]), "last row"),
    ],
)
def test_bad_affines_raise_clear_errors(affine, words):
    with pytest.raises(ValueError, match=words):
        volterra.Scene().add_volume(np.zeros((4, 4, 4), np.uint8), affine)


def test_bad_heightfields_particles_and_keys_raise_clear_errors():
    s = volterra.Scene()
    z = np.zeros((10, 10), np.float32)
    with pytest.raises(ValueError, match="geotransform"):
        s.add_heightfield(z)
    with pytest.raises(ValueError, match="north up"):
        s.add_heightfield(z, (0, 1, 0, 0, 0, 1))
    with pytest.raises(ValueError, match="rotated"):
        s.add_heightfield(z, (0, 1, 0.1, 0, 0, -1))
    with pytest.raises(ValueError, match="infinite"):
        s.add_heightfield(np.full((3, 3), np.inf), (0, 1, 0, 0, 0, -1))
    with pytest.raises(TypeError, match="not elevations"):
        s.add_heightfield(z.astype(np.complex64), (0, 1, 0, 0, 0, -1))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        s.add_particles(np.zeros((5, 2)))
    with pytest.raises(ValueError, match="array 'h'"):
        s.add_particles(np.zeros((5, 3)), {"h": np.zeros(4)})
    # A node key the scene format lacks, a preset it does not know, a setting out of range:
    # refused at the call, the scene left as it was.
    with pytest.raises(ValueError, match="unknown field `colour_by`"):
        s.add_particles(np.zeros((5, 3)), colour_by="h")
    with pytest.raises(volterra.SceneError, match="unknown preset 'CT-AAAA'"):
        s.add_volume(np.zeros((4, 4, 4), np.uint8), preset="CT-AAAA")
    with pytest.raises(volterra.SceneError, match="supersampling"):
        s.add_volume(np.zeros((4, 4, 4), np.uint8), renderer="shear-warp", settings={"supersampling": -1})
    assert s.nodes == []
    with pytest.raises(ValueError, match="in memory"):
        s.add_volume(np.ones((4, 4, 4), np.uint8)) and s.to_toml()


def test_the_camera_moves_as_vtks():
    s = volterra.Scene()
    s.add_volume(blob((20, 20, 20)))
    cam = s.camera
    start = np.array(cam.position)
    focal = np.array(cam.focal_point)
    cam.azimuth(90)
    moved = np.array(cam.position)
    # About view-up (z) through the focal point: z and the distance kept, a quarter turn.
    assert moved[2] == pytest.approx(start[2])
    assert np.linalg.norm(moved - focal) == pytest.approx(np.linalg.norm(start - focal))
    assert np.dot(moved - focal, start - focal) == pytest.approx(0, abs=1e-9)
    cam.azimuth(270)
    np.testing.assert_allclose(cam.position, start, atol=1e-9)
    cam.elevation(30)
    d = np.array(cam.position) - focal
    assert np.degrees(np.arcsin(d[2] / np.linalg.norm(d))) == pytest.approx(30)
    assert np.dot(cam.view_up, d) == pytest.approx(0, abs=1e-9)
    angle = cam.view_angle
    cam.zoom(2)
    assert np.tan(np.radians(cam.view_angle / 2)) == pytest.approx(np.tan(np.radians(angle / 2)) / 2)
    before = np.linalg.norm(np.array(cam.position) - focal)
    cam.dolly(4)
    assert np.linalg.norm(np.array(cam.position) - focal) == pytest.approx(before / 4)
    cam.reset()
    np.testing.assert_allclose(cam.focal_point, focal)
    # A camera looking along its own view-up is refused, and the scene keeps the old one.
    with pytest.raises(volterra.SceneError):
        cam.view_up = np.subtract(cam.focal_point, cam.position).tolist()
    np.testing.assert_allclose(cam.focal_point, focal)


def test_render_frames_of_an_orbit_are_the_cli_frames(tmp_path):
    s = volterra.Scene(width=40, height=40)
    s.add_volume(blob((16, 18, 20)), np.diag([1.0, 1.0, 1.5, 1.0]))
    s.set_orbit(360, frames=4)
    frames = list(s.render_frames())
    assert len(frames) == 4
    s.to_toml(tmp_path / "orbit.toml")
    cli("render", tmp_path / "orbit.toml", "-o", tmp_path / "f.exr", "--frames")
    for k, f in enumerate(frames):
        f.save(tmp_path / f"p_{k}.exr")
        assert (tmp_path / f"p_{k}.exr").read_bytes() == (tmp_path / f"f_{k:04}.exr").read_bytes()
    assert not np.array_equal(frames[0].rgba, frames[1].rgba)


def big_scene():
    """A render that takes seconds: the reference ray caster at 512² over 96³."""
    s = volterra.Scene(width=512, height=512)
    s.add_volume(blob((96, 96, 96)), renderer="reference", shading=True, preset="CT-AAA")
    return s


def test_the_gil_is_released_while_rendering():
    s = big_scene()
    turns, done = [0], threading.Event()

    def count():
        while not done.is_set():
            turns[0] += 1

    t = threading.Thread(target=count)
    t.start()
    start = time.perf_counter()
    s.render()
    seconds = time.perf_counter() - start
    done.set()
    t.join()
    # Held, the GIL would let the loop turn only at switch intervals around the call.
    assert seconds > 0.2 and turns[0] > 10000, (seconds, turns[0])


def test_ctrl_c_cancels_a_render():
    s = big_scene()
    start = time.perf_counter()
    s.render()
    full = time.perf_counter() - start
    timer = threading.Timer(0.1 * full, _thread.interrupt_main)
    timer.start()
    start = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        s.render()
    cancelled = time.perf_counter() - start
    timer.join()
    assert cancelled < 0.6 * full, (cancelled, full)
    # The scene renders again afterwards.
    assert s.render().width == 512


def test_terrain_draped_with_an_array_renders_as_the_cli_from_its_png(tmp_path):
    y, x = np.mgrid[0:60, 0:80]
    z = (100 + 30 * np.sin(x / 9.0) * np.cos(y / 7.0)).astype(np.float32)
    rgb = np.zeros((30, 40, 3), np.uint8)
    rgb[..., 0] = np.linspace(0, 255, 40).astype(np.uint8)[None, :]
    rgb[..., 2] = np.linspace(255, 0, 30).astype(np.uint8)[:, None]
    transform = (500000.0, 10.0, 0.0, 4100000.0, 0.0, -10.0)
    scene = volterra.Scene(width=120, height=90, background=(0.55, 0.7, 0.9))
    scene.add_heightfield(z, transform, epsg=32633, drape=rgb)
    scene.add_light("directional", direction=(1, 1, -1))
    draped, ours, theirs = same_as_cli(scene, tmp_path, "draped")
    assert ours == theirs
    # The drape is what colours the terrain: without it the picture is another.
    plain = volterra.Scene(width=120, height=90, background=(0.55, 0.7, 0.9))
    plain.add_heightfield(z, transform, epsg=32633)
    plain.add_light("directional", direction=(1, 1, -1))
    assert np.abs(plain.render().rgba - draped.rgba).max() > 0.2
    with pytest.raises(TypeError, match="uint8"):
        plain.add_heightfield(z, transform, drape=rgb / 255.0)
    with pytest.raises(ValueError, match=r"\(rows, columns, 3\)"):
        plain.add_heightfield(z, transform, drape=rgb[..., 0])
    with pytest.raises(ValueError, match="not both"):
        plain.add_heightfield(z, transform, drape=rgb, texture="photo.png")


def test_render_frames_of_a_time_series_are_the_cli_frames(tmp_path):
    cli("samples", tmp_path)
    size = ["image.width=48", "image.height=40"]
    scene = volterra.Scene.load(tmp_path / "smoke_series.toml", set=size)
    frames = list(scene.render_frames(3))
    cli("render", tmp_path / "smoke_series.toml", "-o", tmp_path / "s.exr", "--frames", "3", *(f"--set={s}" for s in size))
    for k, f in enumerate(frames):
        f.save(tmp_path / f"p_{k}.exr")
        assert (tmp_path / f"p_{k}.exr").read_bytes() == (tmp_path / f"s_{k:04}.exr").read_bytes()
    # The steps differ: the plume moves.
    assert not np.array_equal(frames[0].rgba, frames[2].rgba)
