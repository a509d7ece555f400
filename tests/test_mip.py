"""The ``mip`` integrator and ``pointillist mip``: projections against numpy / scipy, geometry, stiff cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pointillist.imaging.volumes import Volume, shepp_logan_phantom

RNG = np.random.default_rng(8)  # module-level data only (drawn once at import); tests use the `rng` fixture


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


def test_sixteen_bit_volume_kept_exact_in_half_precision(rng, mi, project):
    vol = rng.integers(0, 4096, size=(6, 5, 4)).astype(np.uint16)  # 12-bit CT range
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
    ("spacing", "1,2", ValueError,
     "spacing: expected 3 positive numbers 'sx,sy,sz' separated by commas or spaces, got '1,2'"),
    ("spacing", "1,-2,1", ValueError, "spacing: expected 3 positive numbers"),
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

    scene = mi.load_file(str(SCENES / "mip.xml"), parallel=False, res=48)
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
    from pointillist.mip.views import sensor_dict, view_axes, view_frame

    axes = view_axes("axial")
    size, hw, hh = view_frame((6, 6, 6), axes, size=(16, 16))
    sensor = sensor_dict(mi, np.array([6.0, 6, 6]), axes, size, hw, hh, None)
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
                 "--window", "0,2000", "--no-labels", "-o", tmp_path / "c.png")
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
    from PIL import Image

    frames = [np.asarray(Image.open(tmp_path / f"t_{k:03d}.png").convert("RGB")).astype(float) for k in range(3)]
    assert all(frame.shape == (24, 24, 3) for frame in frames)
    # frame k is the view at azimuth 120 k: frame 0 is the plain oblique view, and the
    # off-centre blob moves between frames
    single = cli("mip", tmp_path / "v.npy", "--size", "24", "--elevation", "10", "--azimuth", "0",
                 "--colormap", "inferno", "-o", tmp_path / "single.png")
    assert single.returncode == 0, single.stderr
    np.testing.assert_array_equal(frames[0], np.asarray(Image.open(tmp_path / "single.png").convert("RGB")))
    assert np.abs(frames[1] - frames[0]).mean() > 1 and np.abs(frames[2] - frames[1]).mean() > 1
    gif = imageio.mimread(tmp_path / "t.gif")
    assert len(gif) == 3
    for frame, shown in zip(frames, gif):  # the GIF's palette may round colours a little
        assert np.abs(np.asarray(shown)[..., :3].astype(float) - frame).mean() < 3


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


# ---------------------------------------------------------------------------------------------
# Patient space: anatomical views whatever the voxel order
# ---------------------------------------------------------------------------------------------
def _write_all_orders(folder):
    """The same asymmetric object in seven voxel orders / formats; returns (object, paths)."""
    from medical_files import (asymmetric_object, write_dicom_coronal, write_enhanced, write_nifti,
                               write_nrrd_permuted)

    obj = asymmetric_object()
    paths = []
    for codes in ("RAS", "LAS", "LPI"):
        write_nifti(folder / f"{codes}.nii.gz", obj, codes)
        paths.append(folder / f"{codes}.nii.gz")
    write_nrrd_permuted(folder / "permuted.nrrd", obj)
    paths.append(folder / "permuted.nrrd")
    write_dicom_coronal(folder / "coronal_dicom", obj)
    paths.append(folder / "coronal_dicom")
    (folder / "enhanced").mkdir()
    write_enhanced(folder / "enhanced" / "mf.dcm", [obj])
    paths.append(folder / "enhanced")
    np.save(folder / "lps.npy", obj)  # no orientation: voxel axes taken as L, P, S
    paths.append(folder / "lps.npy")
    return obj, paths


@pytest.mark.parametrize("view", ["axial", "coronal", "sagittal"])
def test_same_object_in_any_voxel_order_gives_identical_views(mi, tmp_path, view):
    from medical_files import SPACING

    from pointillist.imaging.volumes import load_volume
    from pointillist.mip import project_volume

    obj, paths = _write_all_orders(tmp_path)
    expected = _native(view)(obj, np.max)  # the LPS-ordered object: radiological reference
    for path in paths:
        volume = load_volume(path, spacing=SPACING if path.suffix == ".npy" else None)
        image, integrator = project_volume(volume, view=view, native=True, interpolation="nearest")
        np.testing.assert_array_equal(image, expected, err_msg=str(path.name))
        assert integrator.last_path == "columns", path.name  # permuted into voxel axes: the fast path


def test_radiological_convention_puts_the_marker_where_viewers_do(mi, tmp_path):
    """The marker sits at the patient's right, anterior, superior (asymmetric_object)."""
    from medical_files import asymmetric_object, write_nifti

    from pointillist.imaging.volumes import load_volume
    from pointillist.mip import patient_view, project_volume

    write_nifti(tmp_path / "o.nii", asymmetric_object(), "LPI")
    volume = load_volume(tmp_path / "o.nii")
    for view, (row_half, col_half) in {"axial": ("top", "left"),     # anterior up, right on the left
                                       "coronal": ("top", "left"),   # superior up, right on the left
                                       "sagittal": ("top", "left"),  # superior up, anterior on the left
                                       }.items():
        image, _ = project_volume(volume, view=view, native=True, interpolation="nearest")
        row, col = np.unravel_index(np.argmax(image), image.shape)
        assert (row < image.shape[0] / 2) == (row_half == "top") and (col < image.shape[1] / 2), view
        labels = patient_view(view)["labels"]
        assert labels["left"] in ("R", "A") and labels["top"] in ("A", "S")
        mirrored, _ = project_volume(volume, view=view, native=True, interpolation="nearest", neurological=True)
        # neurological mirrors left and right; a sagittal image has no left-right axis (Slicer, ITK-SNAP)
        np.testing.assert_array_equal(mirrored, image if view == "sagittal" else image[:, ::-1])
    assert patient_view("axial", neurological=True)["labels"] == {"left": "L", "right": "R", "top": "A",
                                                                   "bottom": "P"}
    assert patient_view("sagittal")["labels"] == {"left": "A", "right": "P", "top": "S", "bottom": "I"}
    assert patient_view(None, 90.0, 0.0)["labels"]["top"] == "S"  # azimuth turns about the patient's S axis


def test_nibabel_anatomical_and_its_dicom_export_agree(mi, tmp_path):
    import os

    import nibabel
    from medical_files import write_dicom_axial
    from nibabel.testing import data_path

    from pointillist.imaging.volumes import load_volume
    from pointillist.mip import project_volume

    path = os.path.join(data_path, "anatomical.nii")
    canonical = nibabel.as_closest_canonical(nibabel.load(path))  # RAS, by nibabel
    ras = np.asarray(canonical.dataobj)
    obj = np.ascontiguousarray(ras[::-1, ::-1, :].transpose(2, 1, 0)).astype(np.int16)  # LPS order
    n = np.array(ras.shape)
    corner = canonical.affine @ [n[0] - 1, n[1] - 1, 0, 1]  # RAS of LPS voxel (0, 0, 0)
    spacing = tuple(float(s) for s in canonical.header.get_zooms()[:3])
    write_dicom_axial(tmp_path / "export", obj, spacing=spacing, origin=(-corner[0], -corner[1], corner[2]))
    nifti, dicom = load_volume(path), load_volume(tmp_path / "export")
    centre = np.array([*(np.array(nifti.shape_xyz) - 1) / 2, 1.0])
    np.testing.assert_allclose(nifti.affine @ centre, dicom.affine @ centre)
    for view in ("axial", "coronal", "sagittal"):
        a, _ = project_volume(nifti, view=view, native=True, interpolation="nearest")
        b, _ = project_volume(dicom, view=view, native=True, interpolation="nearest")
        np.testing.assert_array_equal(a, b, err_msg=view)
        np.testing.assert_array_equal(a, _native(view)(obj, np.max), err_msg=view)


def test_oblique_nifti_renders_the_object_upright(mi, tmp_path):
    """A vertical rod (along the patient's S axis) sampled on a voxel grid tilted 25 degrees about
    the left-right axis: sagittal and coronal views show it vertical, in patient space."""
    import nibabel

    from pointillist.imaging.volumes import load_volume
    from pointillist.mip import project_volume

    n, step, angle = 40, 1.0, np.radians(25.0)
    rotation = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]])
    ras = np.eye(4)
    ras[:3, :3] = rotation * step
    ras[:3, 3] = -rotation @ np.full(3, (n - 1) / 2 * step)  # grid centred on the origin
    i, j, k = np.meshgrid(*(np.arange(n),) * 3, indexing="ij")
    points = np.einsum("ab,bijk->aijk", ras[:3, :3], np.stack([i, j, k])) + ras[:3, 3, None, None, None]
    rod = (np.hypot(points[0] - 3.0, points[1] + 4.0) <= 2.0) & (np.abs(points[2]) <= 12.0)  # x=3 (R), y=-4 (P)
    nibabel.save(nibabel.Nifti1Image(np.where(rod, 1000, 0).astype(np.int16), ras), str(tmp_path / "rod.nii"))
    volume = load_volume(tmp_path / "rod.nii")
    for view in ("sagittal", "coronal"):
        image, integrator = project_volume(volume, view=view, size=(64, 64), interpolation="trilinear")
        assert integrator.last_path != "columns"  # oblique in voxel space: marched
        rows = np.flatnonzero(image.max(axis=1) > 500)
        assert len(rows) >= 20, view  # ~24 mm of rod at ~1 pixel per mm
        slope = np.polyfit(rows, _centroids(image[rows]), 1)[0]
        assert abs(slope) < 0.02, (view, slope)  # upright: the same column from top to bottom
    # without the patient pose (voxel axes as L, P, S) the rod leans in the sagittal view
    from pointillist.imaging.volumes import Volume

    bare = Volume(volume.data, volume.spacing)
    image, _ = project_volume(bare, view="sagittal", size=(64, 64))
    rows = np.flatnonzero(image.max(axis=1) > 500)
    assert abs(np.polyfit(rows, _centroids(image[rows]), 1)[0]) > 0.3  # leans by tan(25 deg) = 0.47


def _centroids(rows):
    """Column centroid of the bright part (> half the maximum) of each image row."""
    weights = np.where(rows > rows.max() / 2, rows, 0.0)
    return (weights * np.arange(rows.shape[1])).sum(axis=1) / weights.sum(axis=1)


def test_oblique_native_size_uses_in_plane_spacing(mi):
    import os

    import nibabel
    from nibabel.testing import data_path

    from pointillist.imaging.volumes import load_volume
    from pointillist.mip import project_volume

    path = os.path.join(data_path, "example4d.nii.gz")
    volume = load_volume(path, frame=0)
    sx, sy, sz = volume.spacing  # 2, 2, 2.2: j and k tilted ~9 degrees about x
    image, integrator = project_volume(volume, view="axial", native=True, interpolation="nearest")
    nx, ny, nz = volume.shape_xyz
    depth = ny * sy * np.cos(np.radians(9.3)) + nz * sz * np.sin(np.radians(9.3))  # A-P span of the tilted box
    assert image.shape[1] == nx and abs(image.shape[0] - depth / sy) <= 2
    assert integrator.last_path != "columns"
    raw = np.asarray(nibabel.load(path).dataobj)[..., 0]
    assert np.nanmax(image) == raw.max()  # nearest lookups: the brightest voxel survives the projection


def test_pydicom_ct_small_axial_view_is_the_stored_slice(mi, tmp_path):
    """Radiology viewers show an axial slice with IOP (1,0,0,0,1,0) as stored: so does the axial view."""
    import shutil

    import pydicom
    from pydicom.data import get_testdata_file

    from pointillist.imaging.volumes import load_volume
    from pointillist.mip import project_volume

    (tmp_path / "ct").mkdir()
    shutil.copy(get_testdata_file("CT_small.dcm"), tmp_path / "ct")
    ds = pydicom.dcmread(get_testdata_file("CT_small.dcm"))
    image, _ = project_volume(load_volume(tmp_path / "ct"), view="axial", native=True, interpolation="nearest")
    np.testing.assert_array_equal(image, ds.pixel_array * float(ds.RescaleSlope) + float(ds.RescaleIntercept))


def test_cli_labels_exr_patient_axes_frames_and_warnings(cli, tmp_path):
    import os

    from nibabel.testing import data_path
    from PIL import Image

    from pointillist.imaging.io import read_exr

    np.save(tmp_path / "v.npy", _blob((16, 48, 40)))
    common = ["--view", "axial", "--native-size", "--interpolation", "nearest", "--window", "0,2"]
    assert cli("mip", tmp_path / "v.npy", *common, "-o", tmp_path / "l.png").returncode == 0
    assert cli("mip", tmp_path / "v.npy", *common, "--no-labels", "-o", tmp_path / "n.png").returncode == 0
    labelled = np.asarray(Image.open(tmp_path / "l.png").convert("RGB")).astype(int)
    plain = np.asarray(Image.open(tmp_path / "n.png").convert("RGB")).astype(int)
    changed = np.argwhere(np.any(labelled != plain, axis=2))
    values = labelled[changed[:, 0], changed[:, 1]]
    assert (values >= 200).all(axis=1).any() and (values <= 40).all(axis=1).any()  # white letters, black outline
    height, width = plain.shape[:2]
    near_middle = ((np.abs(changed[:, 0] - height / 2) < height / 4) | (np.abs(changed[:, 1] - width / 2) < width / 4))
    assert near_middle.all()  # letters only at the middle of the edges
    result = cli("mip", tmp_path / "v.npy", "--view", "sagittal", "--neurological", "-o", tmp_path / "s.exr",
                 "--size", "32")
    assert result.returncode == 0, result.stderr
    meta = read_exr(tmp_path / "s.exr").metadata
    assert meta["patient_frame"] == "LPS" and meta["display"] == "neurological"
    # a sagittal view has no left-right axis: neurological leaves it as radiological (it mirrored it)
    assert (meta["image_left"], meta["image_right"], meta["image_top"], meta["image_bottom"]) == ("A", "P", "S", "I")
    assert meta["view_forward"] == "-1,0,0" and meta["view_right"] == "0,1,0"
    four_d = os.path.join(data_path, "example4d.nii.gz")
    result = cli("mip", four_d, "-o", tmp_path / "f.png", "--size", "16")
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "2 frames" in result.stderr and "--frame" in result.stderr
    result = cli("mip", four_d, "--frame", "1", "-o", tmp_path / "f.png", "--size", "16")
    assert result.returncode == 0, result.stderr
    import nrrd

    nrrd.write(str(tmp_path / "s.nrrd"), np.zeros((2, 3, 4), np.int16),
               {"space": "scanner-xyz", "space directions": np.eye(3)}, index_order="C")
    result = cli("mip", tmp_path / "s.nrrd", "-o", tmp_path / "w.png", "--size", "16")
    assert result.returncode == 0
    assert result.stderr.strip().splitlines() == [
        f"pointillist mip: warning: volume: {tmp_path / 's.nrrd'}: NRRD space 'scanner-xyz' has no anatomical "
        "axes; taken as LPS"]


def test_integrator_reads_a_frame_and_poses_in_patient_space(mi):
    import os

    import nibabel
    from nibabel.testing import data_path

    path = os.path.join(data_path, "example4d.nii.gz")
    integrator = mi.load_dict({"type": "mip", "filename": path, "frame": 1})
    np.testing.assert_array_equal(integrator.volume.data, np.asarray(nibabel.load(path).dataobj)[..., 1].T)
    with pytest.raises(Exception, match="4-D with 2 frames"):
        mi.load_dict({"type": "mip", "filename": path})
    unposed = mi.load_dict({"type": "mip", "filename": path, "frame": 1, "patient_space": False})
    posed_box = np.asarray(integrator.stored.orientation[:3, :3]) @ np.asarray(integrator.volume.extent)
    assert not np.allclose(posed_box, unposed.volume.extent)  # the posed box is turned (LAS, oblique)
    np.testing.assert_array_equal(unposed.stored.orientation, np.eye(4))


def test_frame_task_loads_the_chosen_frame(mi):
    import os

    from nibabel.testing import data_path

    from pointillist.imaging.volumes import load_volume
    from pointillist.mip import mip_frame_task, project_volume

    path = os.path.join(data_path, "example4d.nii.gz")
    options = {"size": (24, 24), "interpolation": "nearest", "neurological": True}
    result = mip_frame_task({"volume": path, "spacing": None, "load": {"frame": 1}, "view": {"view": "coronal"},
                             "options": options})
    expected, _ = project_volume(load_volume(path, frame=1), view="coronal", **options)
    np.testing.assert_array_equal(result["image"], expected)


@pytest.mark.parametrize("text", ["1,2,3", "1 2 3", "1, 2 ,3", " 0.5\t0.5, 2 ", "1,,2", "1,2", "1,2,3,4", "0,1,1",
                                  "nan,1,1", "1e39,1,1", "a,b,c", ""])
def test_the_spacing_text_is_read_alike_by_the_integrator_and_the_command(mi, text, tmp_path):
    """One rule for a spacing written as text: the ``mip`` integrator's ``spacing`` property and
    ``pointillist mip --spacing`` accept the same texts, as the same numbers."""
    import argparse

    from pointillist.commands.mip import _spacing
    from pointillist.plugins.integrators.mip import MIPIntegrator  # noqa: F401 - registers the plugin

    volume = tmp_path / "v.npy"
    np.save(volume, np.arange(8, dtype=np.float32).reshape(2, 2, 2))
    try:
        command = _spacing(text)
    except argparse.ArgumentTypeError:
        command = None
    try:
        integrator = mi.load_dict({"type": "mip", "filename": str(volume), "spacing": text})
    except (ValueError, TypeError, RuntimeError):
        integrator = None
    assert (command is None) == (integrator is None), (command, integrator)
    if command is not None:
        assert command == (1.0, 2.0, 3.0) if "3" in text and "4" not in text else command == (0.5, 0.5, 2.0)


def test_a_tiled_render_of_a_mip_scene_equals_the_whole_render(cli, tmp_path):
    """Tiles are crop windows of the film: the mip integrator's rays must map [0, 1]^2 onto the crop
    window, as Mitsuba's sensors do (they divided by the whole film's size: 632 of 4096 pixels of
    scenes/mip.xml at 64x64 came out of the wrong rays in 2x2 tiles)."""
    from pointillist.imaging.io import read_exr

    whole, tiled = tmp_path / "whole.exr", tmp_path / "tiled.exr"
    for out, extra in ((whole, []), (tiled, ["--tiles", "2x3"])):
        done = cli("render", "scenes/mip.xml", "-D", "res=40", "-o", out, *extra)
        assert done.returncode == 0, done.stderr
    a, b = read_exr(whole).image, read_exr(tiled).image
    assert a.std() > 0.05                                     # the phantom is there
    # the same rays up to float32 rounding of their sample positions (a tile's own mapping onto its
    # window): within 1e-4 of the display value (1.9e-5 measured), where the wrong mapping was off by 0.9
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-4)


def test_a_turntable_without_a_view_orbits_upright_from_the_coronal_view(cli, tmp_path):
    """`--turntable N` alone: frame 0 is the coronal view and frame N/4 the view from the patient's
    left (azimuth 90, the sagittal direction), upright; with `--view axial` it spins in the image plane."""
    from PIL import Image

    def png(path):
        return np.asarray(Image.open(path).convert("L")).astype(float)

    volume = "scenes/phantom64.vol"
    done = cli("mip", volume, "--turntable", "4", "--size", "32", "--no-labels", "-o", tmp_path / "t.png")
    assert done.returncode == 0, done.stderr
    assert not (tmp_path / "t.png").exists() and (tmp_path / "t_003.png").exists()
    for name, args in (("coronal", ["--view", "coronal"]), ("side", ["--azimuth", "90", "--elevation", "0"])):
        single = cli("mip", volume, "--size", "32", "--no-labels", *args, "-o", tmp_path / f"{name}.png")
        assert single.returncode == 0, single.stderr
    np.testing.assert_array_equal(png(tmp_path / "t_000.png"), png(tmp_path / "coronal.png"))
    np.testing.assert_array_equal(png(tmp_path / "t_001.png"), png(tmp_path / "side.png"))
