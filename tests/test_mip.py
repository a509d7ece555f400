"""The ``mip`` integrator and ``pointillist mip``: projections against numpy / scipy, geometry, stiff cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pointillist.imaging.volumes import Volume, shepp_logan_phantom

RNG = np.random.default_rng(8)


@pytest.fixture(scope="module")
def project(mi):
    from pointillist.mip import project_volume

    def run(volume, **kwargs):
        image, integrator = project_volume(volume, **kwargs)
        return image

    return run


def _native(axis_view):
    """numpy reference for the named native views (see pointillist mip's documented orientation)."""
    return {"axial": lambda v, f: f(v, axis=0),
            "coronal": lambda v, f: f(v, axis=1)[::-1],
            "sagittal": lambda v, f: f(v, axis=2)[::-1]}[axis_view]


VOL = RNG.random((5, 6, 7)).astype(np.float32)  # (Z, Y, X): nx=7, ny=6, nz=5


# ---------------------------------------------------------------------------------------------
# Axis-aligned views against numpy
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("view", ["axial", "coronal", "sagittal"])
@pytest.mark.parametrize("mode,reduce", [("mip", np.max), ("minip", np.min)])
def test_nearest_native_view_equals_numpy_exactly(project, view, mode, reduce):
    image = project(Volume(VOL, (0.7, 1.3, 2.0)), view=view, native=True, interpolation="nearest", mode=mode)
    expected = _native(view)(VOL, reduce)
    assert image.shape == expected.shape
    np.testing.assert_array_equal(image, expected)


@pytest.mark.parametrize("view", ["axial", "coronal", "sagittal"])
def test_nearest_average_equals_numpy_mean(project, view):
    image = project(VOL, view=view, native=True, interpolation="nearest", mode="average")
    np.testing.assert_allclose(image, _native(view)(VOL, np.mean), rtol=1e-5)


@pytest.mark.parametrize("view", ["axial", "coronal", "sagittal"])
def test_trilinear_native_view_matches_numpy_max(project, view):
    # Rays through voxel-column centres: trilinear values along the ray interpolate the column
    # linearly, and half-voxel samples include the centres, so the max is the column max
    # up to float rounding of the sample positions.
    image = project(VOL, view=view, native=True, interpolation="trilinear")
    np.testing.assert_allclose(image, _native(view)(VOL, np.max), atol=2e-3)
    image = project(VOL, view=view, native=True, interpolation="trilinear", mode="minip")
    np.testing.assert_allclose(image, _native(view)(VOL, np.min), atol=2e-3)


def test_sixteen_bit_volume_kept_exact_in_half_precision(mi, project):
    vol = RNG.integers(0, 4096, size=(6, 5, 4)).astype(np.uint16)  # 12-bit CT range
    vol[0, 0, 0], vol[1, 1, 1] = 0, 4095
    integrator = mi.load_dict({"type": "mip", "interpolation": "nearest"})
    integrator.set_volume(vol)
    info = integrator.texture_info()
    assert info["precision"] == "half" and info["exact"] and info["nbytes"] == vol.size * 2
    image = project(vol, view="axial", native=True, interpolation="nearest")
    np.testing.assert_array_equal(image, vol.max(axis=0).astype(np.float32))
    wide = vol.astype(np.int32) * 16  # 0..65520 does not fit float16 exactly: auto keeps float32
    integrator.set_volume(wide)
    assert integrator.texture_info()["precision"] == "single"


# ---------------------------------------------------------------------------------------------
# Oblique views against an independent scipy ray caster
# ---------------------------------------------------------------------------------------------
def _blob(shape=(20, 24, 28)):
    z, y, x = np.meshgrid(*[np.linspace(-1, 1, n) for n in shape], indexing="ij")
    return (np.exp(-((x - 0.3) ** 2 / 0.1 + (y + 0.2) ** 2 / 0.2 + z ** 2 / 0.05))
            + 0.5 * np.exp(-((x + 0.4) ** 2 + (y - 0.3) ** 2 + (z + 0.3) ** 2) / 0.03)).astype(np.float32)


def _scipy_mip(volume, spacing, azimuth, elevation, size):
    """Reference: scipy map_coordinates (order 1, clamped) at a fine step along every ray."""
    from scipy.ndimage import map_coordinates

    from pointillist.mip import view_axes, view_frame

    vol = Volume(volume, spacing)
    right, up, forward = view_axes(None, azimuth, elevation)
    (w, h), half_w, half_h = view_frame(vol.extent, (right, up, forward), size=size)
    cols = ((np.arange(w) + 0.5) / w * 2 - 1) * half_w
    rows = (1 - (np.arange(h) + 0.5) / h * 2) * half_h
    radius = np.linalg.norm(vol.extent) / 2
    ts = np.arange(-radius, radius, 0.05 * min(spacing))
    pr, pc, pt = np.meshgrid(rows, cols, ts, indexing="ij")
    points = (pc[..., None] * right + pr[..., None] * up + pt[..., None] * forward)  # (h, w, t, 3)
    extent = np.array(vol.extent)
    inside = np.all(np.abs(points) <= extent / 2 + 1e-9, axis=-1)
    index = points / np.array(spacing) + np.array(vol.shape_xyz) / 2 - 0.5  # voxel index (x, y, z)
    samples = map_coordinates(volume, [index[..., 2].ravel(), index[..., 1].ravel(), index[..., 0].ravel()],
                              order=1, mode="nearest").reshape(inside.shape)
    samples = np.where(inside, samples, -np.inf)
    image = samples.max(axis=-1)
    return np.where(np.isfinite(image), image, volume.min())


@pytest.mark.parametrize("azimuth,elevation,spacing", [(30.0, 20.0, (1.0, 1.0, 1.0)),
                                                       (-115.0, -40.0, (0.8, 1.0, 1.5))])
def test_oblique_trilinear_mip_matches_scipy_ray_caster(project, azimuth, elevation, spacing):
    vol = _blob()
    image = project(Volume(vol, spacing), view=None, azimuth=azimuth, elevation=elevation, size=(40, 32))
    reference = _scipy_mip(vol, spacing, azimuth, elevation, (40, 32))
    assert image.shape == (32, 40)
    np.testing.assert_allclose(image, reference, atol=0.02)  # half-voxel vs 1/20-voxel steps
    assert np.abs(image - reference).mean() < 3e-3


# ---------------------------------------------------------------------------------------------
# Geometry: single bright voxel, 180-degree mirror, anisotropic spacing, pose
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("view,pixel", [("axial", (2, 5)), ("coronal", (5 - 3, 5)), ("sagittal", (5 - 3, 2))])
def test_bright_voxel_lands_on_its_pixel_in_named_views(project, view, pixel):
    vol = np.zeros((6, 7, 8), np.float32)  # nz=6
    vol[3, 2, 5] = 1.0  # z=3, y=2, x=5
    image = project(vol, view=view, native=True, interpolation="nearest")
    assert np.argwhere(image == 1.0).tolist() == [list(pixel)]


@pytest.mark.parametrize("azimuth,elevation", [(0.0, 0.0), (37.0, 25.0), (200.0, -60.0), (90.0, 89.0)])
def test_bright_voxel_projects_where_the_camera_says(project, azimuth, elevation):
    from pointillist.mip import view_axes, view_frame

    vol = np.zeros((9, 9, 9), np.float32)
    vol[6, 2, 5] = 1.0
    right, up, forward = view_axes(None, azimuth, elevation)
    (w, h), half_w, half_h = view_frame((9, 9, 9), (right, up, forward), size=(48, 48))
    centre = np.array([5, 2, 6]) + 0.5 - 4.5  # voxel centre in the centred box
    col = (centre @ right + half_w) / (2 * half_w) * w
    row = (half_h - centre @ up) / (2 * half_h) * h
    image = project(vol, view=None, azimuth=azimuth, elevation=elevation, size=(w, h))
    r, c = np.unravel_index(np.argmax(image), image.shape)
    assert image[r, c] > 0.5
    assert abs(r + 0.5 - row) <= 1.0 and abs(c + 0.5 - col) <= 1.0


def test_rotating_the_view_by_180_degrees_mirrors_the_image(project):
    vol = _blob()
    a = project(vol, view=None, azimuth=30.0, elevation=0.0, size=(36, 30))
    b = project(vol, view=None, azimuth=210.0, elevation=0.0, size=(36, 30))
    np.testing.assert_allclose(b, a[:, ::-1], atol=0.02)
    assert not np.allclose(a, a[:, ::-1], atol=0.02)  # the image is not symmetric by itself


def test_anisotropic_spacing_scales_the_projection(project):
    vol = np.ones((8, 8, 8), np.float32)
    image = project(Volume(vol, (1.0, 1.0, 3.0)), view="coronal", size=(60, 60), background=0.0)
    cols = np.flatnonzero(image.max(axis=0) > 0.5)
    rows = np.flatnonzero(image.max(axis=1) > 0.5)
    assert len(rows) == 60  # the box is 8 x 8 x 24: full height ...
    assert abs(len(cols) - 20) <= 1  # ... and a third of the width
    native = project(Volume(vol, (1.0, 1.0, 3.0)), view="coronal", native=True)
    assert native.shape == (8, 8)  # native size counts voxels, not millimetres


def test_to_world_pose_moves_the_volume(mi):
    vol = np.zeros((4, 4, 4), np.float32)
    vol[:, :, 3] = 1.0  # the +x face layer is bright
    integrator = mi.load_dict({"type": "mip", "interpolation": "nearest", "background": -1.0,
                               "to_world": mi.ScalarTransform4f().rotate([0, 0, 1], 90)})
    integrator.set_volume(vol)
    # after a 90-degree turn about z the bright layer faces +y: a ray along x at y=1.5 sees it
    o = mi.Point3f([-10.0, -10.0], [1.5, -1.5], [0.0, 0.0])
    value, valid = integrator.project_rays(mi.Ray3f(o, mi.Vector3f(1, 0, 0)))
    assert np.asarray(value).tolist() == [1.0, 0.0]


# ---------------------------------------------------------------------------------------------
# Stiff cases
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("mode", ["mip", "minip", "average"])
@pytest.mark.parametrize("value", [0.0, 7.25, -1024.0])
def test_constant_volume_projects_to_its_value(project, mode, value):
    vol = np.full((5, 4, 6), value, np.float32)
    image = project(vol, view=None, azimuth=33.0, elevation=12.0, size=(24, 24), mode=mode, background=99.0,
                    interpolation="nearest")
    hit = image != 99.0
    assert hit.sum() > 100
    np.testing.assert_array_equal(image[hit], value)
    # trilinear weights sum to 1 only up to float32 rounding: a few ulp
    image = project(vol, view=None, azimuth=33.0, elevation=12.0, size=(24, 24), mode=mode, background=99.0)
    np.testing.assert_array_equal(image != 99.0, hit)
    np.testing.assert_allclose(image[hit], value, rtol=4 * 2.0**-23, atol=0)


def test_one_voxel_volume(project):
    image = project(np.array([[[3.5]]], np.float32), view=None, azimuth=45.0, elevation=30.0,
                    size=(16, 16), background=0.0, interpolation="nearest")
    assert set(np.unique(image).tolist()) == {0.0, 3.5}
    image = project(np.array([[[3.5]]], np.float32), view=None, azimuth=45.0, elevation=30.0,
                    size=(16, 16), background=0.0)
    np.testing.assert_allclose(image[image != 0], 3.5, rtol=1e-6)
    native = project(np.array([[[3.5]]], np.float32), view="axial", native=True)
    assert native.tolist() == [[3.5]]


def test_nan_voxels_are_skipped_like_nanmax(project):
    vol = VOL.copy()
    vol[2, 3, :] = np.nan
    vol[:, 0, 0] = np.nan  # one column is all NaN -> background
    image = project(vol, view="axial", native=True, interpolation="nearest", background=-5.0)
    with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
        expected = np.nanmax(vol, axis=0)
    expected[0, 0] = -5.0
    np.testing.assert_array_equal(image, expected)
    mean = project(vol, view="axial", native=True, interpolation="nearest", mode="average", background=-5.0)
    with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
        expected = np.nanmean(vol, axis=0)
    expected[0, 0] = -5.0
    np.testing.assert_allclose(mean, expected, rtol=1e-5)


def test_all_nan_and_empty_volume_give_background(project):
    image = project(np.full((3, 3, 3), np.nan, np.float32), view="axial", native=True)
    np.testing.assert_array_equal(image, 0.0)  # no finite voxel: background defaults to 0


def test_rays_missing_the_volume_give_the_background(mi):
    integrator = mi.load_dict({"type": "mip", "background": -7.0})
    integrator.set_volume(np.ones((4, 4, 4), np.float32))
    o = mi.Point3f([-10.0, 0.0, 0.0], [5.0, 0.0, 3.0], [0.0, 10.0, -10.0])  # box is [-2, 2]^3
    d = mi.Vector3f([1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 1.0])
    value, valid = integrator.project_rays(mi.Ray3f(o, d))
    assert np.asarray(value).tolist() == [-7.0, -7.0, -7.0]  # above, beside, and behind the camera
    assert not np.asarray(valid).any()


def test_rays_grazing_faces_and_edges_count_as_inside(mi):
    vol = np.zeros((4, 4, 4), np.float32)
    vol[:, 0, 0] = 1.0  # the edge column x=0, y=0
    vol[:, 3, 2] = 2.0  # a column on the y=+2 face
    integrator = mi.load_dict({"type": "mip", "interpolation": "nearest", "background": -1.0})
    integrator.set_volume(vol)
    # box [-2, 2]^3; rays along z exactly on an edge, on a face, and just outside
    o = mi.Point3f([-2.0, 0.75, 0.5, -2.0001], [-2.0, 2.0, 2.0, -2.0], [-5.0, -5.0, -5.0, -5.0])
    value, valid = integrator.project_rays(mi.Ray3f(o, mi.Vector3f(0, 0, 1)))
    assert np.asarray(value).tolist() == [1.0, 2.0, 2.0, -1.0]


def test_camera_inside_the_volume_marches_from_the_camera(mi):
    vol = np.zeros((8, 4, 4), np.float32)
    vol[:2] = 5.0  # bright slab at the -z end
    integrator = mi.load_dict({"type": "mip", "interpolation": "nearest"})
    integrator.set_volume(vol)
    o = mi.Point3f(0.0, 0.0, 0.0)  # the box centre
    forward, _ = integrator.project_rays(mi.Ray3f(o, mi.Vector3f(0, 0, 1)))
    backward, _ = integrator.project_rays(mi.Ray3f(o, mi.Vector3f(0, 0, -1)))
    assert np.asarray(forward).tolist() == [0.0] and np.asarray(backward).tolist() == [5.0]


@pytest.mark.parametrize("mode,expected", [("mip", 4.0), ("minip", 1.0), ("average", 2.5)])
def test_step_larger_than_the_volume(mi, mode, expected):
    vol = np.array([1.0, 2.0, 3.0, 4.0], np.float32).reshape(4, 1, 1)  # a ramp along z
    integrator = mi.load_dict({"type": "mip", "mode": mode, "step": 100.0})
    integrator.set_volume(vol)
    value, _ = integrator.project_rays(mi.Ray3f(mi.Point3f(0, 0, -10), mi.Vector3f(0, 0, 1)))
    # mip/minip sample only the entry and exit points (clamped voxel values 1 and 4);
    # average samples the midpoint, between voxels 1 and 2 (values 2 and 3)
    assert np.asarray(value).tolist() == [expected]


def test_bad_parameters_raise(mi):
    with pytest.raises(Exception, match="mode"):
        mi.load_dict({"type": "mip", "mode": "max"})
    with pytest.raises(Exception, match="step"):
        mi.load_dict({"type": "mip", "step": 0.0})
    with pytest.raises(Exception, match="window"):
        mi.load_dict({"type": "mip", "window": "40"})
    with pytest.raises(Exception, match="colormap"):
        mi.load_dict({"type": "mip", "colormap": "no-such-map"})
    with pytest.raises(Exception, match="fast_axis: expected a boolean"):  # "false" is not False
        mi.load_dict({"type": "mip", "fast_axis": "false"})
    with pytest.raises(Exception, match="precision: expected one of auto, half, single"):
        mi.load_dict({"type": "mip", "precision": "double"})


@pytest.mark.parametrize("key,value,error,message", [
    ("window", 5, TypeError, "window: expected a string, got int"),
    ("colormap", 3, TypeError, "colormap: expected a string, got int"),
    ("background", "dark", TypeError, "background: expected a number, got str"),
    ("background", math.nan, ValueError, "background: expected a finite number, got nan"),
    ("spacing", "1,2", ValueError, "spacing: expected three positive numbers 'sx,sy,sz', got '1,2'"),
    ("spacing", "1,-2,1", ValueError, "spacing: expected three positive numbers"),
    ("spacing", 2.0, TypeError, "spacing: expected a string, got float"),
    ("filename", 3, TypeError, "filename: expected a string, got int"),
    ("to_world", "abc", TypeError, "to_world: expected a transform or a 4x4 matrix, got str"),
    ("to_world", 5.0, ValueError, r"to_world: expected a finite 4x4 transform, got shape \(\)"),
])
def test_bad_properties_name_the_property(mi, key, value, error, message):
    from pointillist.plugins.integrators.mip import MIPIntegrator

    props = mi.Properties("mip")
    props[key] = value
    with pytest.raises(error, match=message):
        MIPIntegrator(props)
    with pytest.raises(RuntimeError, match=message):  # through Mitsuba's loader
        mi.load_dict({"type": "mip", key: value})


def test_good_properties_are_read(mi):
    integrator = mi.load_dict({"type": "mip", "window": "40,400", "colormap": "grey", "background": -5,
                               "spacing": "1, 2 3"})
    assert integrator.background == -5.0 and isinstance(integrator.background, float)
    integrator.set_volume(np.zeros((2, 3, 4), np.float32))
    assert tuple(integrator.volume.spacing) == (1.0, 2.0, 3.0)
    integrator = mi.load_dict({"type": "mip"})
    with pytest.raises(RuntimeError, match="no volume"):
        integrator.project_rays(mi.Ray3f(mi.Point3f(0, 0, 0), mi.Vector3f(0, 0, 1)))


# ---------------------------------------------------------------------------------------------
# Window, colormap, scene file, surfaces ignored
# ---------------------------------------------------------------------------------------------
def test_window_and_colormap(mi):
    import matplotlib

    from pointillist.imaging.window import apply_window, colormap_lut, parse_window

    assert parse_window("40,400") == (40.0, 400.0) and parse_window("bone") == (400.0, 1800.0)
    values = mi.Float([-1000.0, -160.0, 40.0, 240.0, 3000.0, float("nan")])
    grey = np.asarray(apply_window(values, 40.0, 400.0)[0])
    np.testing.assert_allclose(grey, [0.0, 0.0, 0.5, 1.0, 1.0, 0.0], atol=1e-7)  # clip; NaN -> 0
    lut = colormap_lut("viridis")
    rgb = np.stack([np.asarray(c) for c in apply_window(mi.Float([-160.0, 40.0, 240.0]), 40.0, 400.0, lut)], -1)
    np.testing.assert_allclose(rgb, matplotlib.colormaps["viridis"]([0.0, 0.5, 1.0])[:, :3], atol=2e-3)


def test_scene_file_renders_and_matches_project(mi):
    from conftest import SCENES

    scene = mi.load_file(str(SCENES / "mip.xml"), res=48)
    integrator = scene.integrator()
    assert integrator.volume.data.shape == (64, 64, 64)
    assert integrator.texture_info()["precision"] == "half"  # integer HU in float32 -> exact half
    raw = np.asarray(integrator.project(scene))
    assert raw.min() >= -1000 and raw.max() <= 1200 and raw.max() > 700  # skull seen
    image = np.asarray(mi.render(scene))
    from pointillist.imaging.window import apply_window

    expected = np.asarray(apply_window(mi.Float(raw.ravel()), 400.0, 1800.0)[0]).reshape(raw.shape)
    np.testing.assert_allclose(image[..., 0], expected, atol=1e-6)


def test_surfaces_and_emitters_are_not_traced(mi):
    vol = _blob((6, 6, 6))
    from pointillist.mip import _sensor_dict, view_axes, view_frame

    axes = view_axes("axial")
    size, hw, hh = view_frame((6, 6, 6), axes, size=(16, 16))
    sensor = _sensor_dict(mi, np.array([6.0, 6, 6]), axes, size, hw, hh, None)
    empty = mi.load_dict({"type": "scene", "sensor": sensor})
    cluttered = mi.load_dict({"type": "scene", "sensor": sensor,
                              "wall": {"type": "sphere", "center": [0, 0, -5], "radius": 1.5},
                              "light": {"type": "point", "position": [0, 0, -8]}})
    integrator = mi.load_dict({"type": "mip"})
    integrator.set_volume(vol)
    np.testing.assert_array_equal(np.asarray(integrator.project(cluttered)), np.asarray(integrator.project(empty)))


# ---------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------
def test_cli_exr_holds_raw_values_and_png_is_windowed(cli, tmp_path):
    from PIL import Image

    from pointillist.imaging.io import read_exr

    vol = np.round(shepp_logan_phantom((12, 16, 20)).astype(np.float32))
    np.save(tmp_path / "v.npy", vol.astype(np.int16))
    result = cli("mip", tmp_path / "v.npy", "--view", "coronal", "--native-size", "--interpolation", "nearest",
                 "-o", tmp_path / "c.exr")
    assert result.returncode == 0, result.stderr
    exr = read_exr(tmp_path / "c.exr")
    np.testing.assert_array_equal(exr.image, vol.max(axis=1)[::-1])
    assert exr.metadata["mode"] == "mip"
    result = cli("mip", tmp_path / "v.npy", "--view", "coronal", "--native-size", "--interpolation", "nearest",
                 "--window", "0,2000", "-o", tmp_path / "c.png")
    assert result.returncode == 0, result.stderr
    png = np.asarray(Image.open(tmp_path / "c.png").convert("RGB")).astype(float)
    expected = np.clip((vol.max(axis=1)[::-1] + 1000) / 2000, 0, 1) * 255
    np.testing.assert_allclose(png[..., 0], expected, atol=0.51)


def test_cli_turntable_writes_frames_and_gif(cli, tmp_path):
    np.save(tmp_path / "v.npy", _blob((8, 8, 8)))
    result = cli("mip", tmp_path / "v.npy", "--turntable", "3", "--size", "24", "--elevation", "10",
                 "--azimuth", "0", "--colormap", "inferno", "-o", tmp_path / "t.png")
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in tmp_path.glob("t*")) == ["t.gif", "t_000.png", "t_001.png", "t_002.png"]
    import imageio.v2 as imageio

    assert len(imageio.mimread(tmp_path / "t.gif")) == 3


@pytest.mark.parametrize("args,message", [
    (["missing.npy", "-o", "{tmp}/x.png"], "no such file"),
    (["{tmp}/v.npy", "-o", "{tmp}/x.jpg"], ".png or .exr"),
    (["{tmp}/v.npy", "-o", "{tmp}/x.png", "--azimuth", "30", "--native-size"], "axis-aligned"),
    (["{tmp}/v.npy", "-o", "{tmp}/x.png", "--window", "a,b"], "window"),
    (["{tmp}/v.npy", "-o", "{tmp}/v.npy"], ".png or .exr"),
    (["{tmp}/bad.npy", "-o", "{tmp}/x.png"], "not a readable .npy"),
])
def test_cli_bad_input_one_line_exit_2(cli, tmp_path, args, message):
    np.save(tmp_path / "v.npy", np.zeros((2, 2, 2), np.float32))
    (tmp_path / "bad.npy").write_bytes(b"not numpy")
    result = cli("mip", *[a.format(tmp=tmp_path) for a in args])
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], result.stderr
