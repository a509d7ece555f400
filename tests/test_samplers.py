"""Tests of the grid, jitter and poisson samplers (plugins/samplers/), and of what every pointillist sampler
shares with them (sobol and zsobol: tests/test_sobol.py)."""

from __future__ import annotations

import importlib
import math
import warnings

import numpy as np
import pytest


def _first_2d(mi, name, spp, pixels, seed=0, props=None):
    """The film-plane samples of ``pixels`` pixels: array (pixels, spp, 2)."""
    sampler = mi.load_dict({"type": name, "sample_count": spp, **(props or {})})
    sampler.seed(seed, pixels * spp)
    return np.asarray(sampler.next_2d()).T.reshape(pixels, spp, 2), sampler


def _rest(sampler, n=3):
    """The next ``n`` 2D requests (non-image dimensions) as (n, lanes, 2)."""
    return np.stack([np.asarray(sampler.next_2d()).T for _ in range(n)])


# --------------------------------------------------------------------------- layout
def test_grid_shape_nearest_rectangle(mi):
    from pointillist.plugins.samplers._base import grid_shape

    assert grid_shape(1) == (1, 1)
    assert grid_shape(16) == (4, 4)
    assert grid_shape(8) == (2, 4)
    assert grid_shape(12) == (3, 4)
    assert grid_shape(18) == (3, 6)
    assert grid_shape(7) == (1, 7)
    for n in range(1, 300):
        rows, cols = grid_shape(n)
        assert rows * cols == n and rows <= cols
    with pytest.raises(ValueError, match="sample_count"):
        grid_shape(0)


def test_grid_points_exact(mi):
    for spp, (rows, cols) in ((16, (4, 4)), (8, (2, 4)), (1, (1, 1))):
        pts, _ = _first_2d(mi, "grid", spp, pixels=5, seed=3)
        s = np.arange(spp)
        expected = np.stack([(s % cols + 0.5) / cols, (s // cols + 0.5) / rows], 1)
        for pixel in range(5):  # the same pattern in every pixel, for any seed
            np.testing.assert_allclose(pts[pixel], expected, atol=1e-7)


def test_grid_warns_for_counts_without_a_near_square_grid(mi):
    with pytest.warns(RuntimeWarning, match="1 x 7"):
        mi.load_dict({"type": "grid", "sample_count": 7})
    with pytest.warns(RuntimeWarning, match="1 x 5"):
        mi.load_dict({"type": "jitter", "sample_count": 5})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mi.load_dict({"type": "jitter", "sample_count": 8})  # 2 x 4: accepted quietly
        mi.load_dict({"type": "grid", "sample_count": 64})


def test_jitter_one_point_per_cell(mi):
    for spp, (rows, cols) in ((16, (4, 4)), (8, (2, 4)), (64, (8, 8))):
        pts, _ = _first_2d(mi, "jitter", spp, pixels=200, seed=1)
        assert ((pts >= 0) & (pts < 1)).all()
        col = np.floor(pts[..., 0] * cols).astype(int)
        row = np.floor(pts[..., 1] * rows).astype(int)
        cell = row * cols + col
        # sample s sits in cell s, so every cell of every pixel holds exactly one sample
        assert (cell == np.arange(spp)[None, :]).all()
        # the offset inside the cell is uniform: mean 0.5, variance 1/12
        offset = np.stack([pts[..., 0] * cols - col, pts[..., 1] * rows - row], -1)
        assert abs(offset.mean() - 0.5) < 0.01
        assert abs(offset.var() - 1 / 12) < 0.005


def test_jitter_with_one_sample_is_uniform(mi):
    pts, _ = _first_2d(mi, "jitter", 1, pixels=20000, seed=2)
    hist, _, _ = np.histogram2d(pts[:, 0, 0], pts[:, 0, 1], bins=4, range=[[0, 1], [0, 1]])
    expected = 20000 / 16
    assert ((hist - expected) ** 2 / expected).sum() < 45  # chi2, 15 dof, p ~ 1e-4


# -------------------------------------------------------------------------- poisson
@pytest.mark.parametrize("spp", [2, 16, 64, 100])
def test_poisson_min_distance_and_count(mi, spp):
    from pointillist.plugins.samplers.poisson import hexagonal_radius, poisson_disk_points, toroidal_min_distance

    points, radius = poisson_disk_points(spp)
    assert points.shape == (spp, 2) and points.dtype == np.float32
    assert ((points >= 0) & (points < 1)).all()
    # a real Poisson-disk packing: at least 0.65 of the densest (hexagonal) radius
    assert 0.65 * hexagonal_radius(spp) <= radius <= hexagonal_radius(spp)
    assert toroidal_min_distance(points) >= radius * (1 - 1e-6)

    sampled, sampler = _first_2d(mi, "poisson", spp, pixels=50, seed=4)
    assert math.isclose(sampler.radius, radius)
    for pixel in sampled:  # the per-pixel toroidal shift keeps the distance inside each pixel
        assert len(pixel) == spp
        assert ((pixel >= 0) & (pixel < 1)).all()
        assert toroidal_min_distance(pixel) >= radius * (1 - 1e-5)
    shifts = (sampled[:, 0, :] - points[0]) % 1.0
    assert np.unique(np.round(shifts, 5), axis=0).shape[0] == 50  # a different shift per pixel


def test_toroidal_min_distance_against_scipy(mi):
    from scipy.spatial import cKDTree

    from pointillist.plugins.samplers.poisson import toroidal_min_distance

    rng = np.random.default_rng(5)
    pts = rng.random((300, 2))
    dist, _ = cKDTree(pts, boxsize=1.0).query(pts, k=2)
    assert math.isclose(toroidal_min_distance(pts), dist[:, 1].min(), rel_tol=1e-12)
    assert toroidal_min_distance(pts[:1]) == math.inf


def test_poisson_edge_counts(mi):
    from pointillist.plugins.samplers.poisson import MAX_POINTS, poisson_disk_points, toroidal_min_distance

    one, radius = poisson_disk_points(1)
    assert one.shape == (1, 2) and radius == math.inf
    # one sample: the per-pixel shift makes it uniform over the pixel
    pts, _ = _first_2d(mi, "poisson", 1, pixels=20000, seed=0)
    hist, _, _ = np.histogram2d(pts[:, 0, 0], pts[:, 0, 1], bins=4, range=[[0, 1], [0, 1]])
    assert ((hist - 1250) ** 2 / 1250).sum() < 45
    # the radius comes from the count, so it is never too large for it; absurd counts are refused
    with pytest.raises(ValueError, match="sample_count"):
        poisson_disk_points(MAX_POINTS + 1)
    with pytest.raises(ValueError, match="sample_count"):
        poisson_disk_points(0)
    # deterministic: the same count always gives the same set, and the shipped sets are
    # exactly what the generator returns
    from pointillist.plugins.samplers.poisson import SHIPPED_COUNTS, generate_poisson_disk_points, hexagonal_radius

    for n in (4, 16, 64, 25):
        generated = generate_poisson_disk_points(n)
        np.testing.assert_array_equal(generated[0], poisson_disk_points(n)[0])
        assert generated[1] == poisson_disk_points(n)[1]
    for n in SHIPPED_COUNTS[1:]:
        points, radius = poisson_disk_points(n)
        assert points.shape == (n, 2) and radius >= 0.65 * hexagonal_radius(n)
        assert toroidal_min_distance(points) >= radius * (1 - 1e-6)
    # a count that is not shipped is generated and keeps the property
    points, radius = poisson_disk_points(37)
    assert points.shape == (37, 2) and toroidal_min_distance(points) >= radius * (1 - 1e-6)


def test_set_sample_count_reconfigures(mi):
    sampler = mi.load_dict({"type": "poisson", "sample_count": 4})
    sampler.set_sample_count(32)
    assert sampler.sample_count() == 32 and len(sampler.points) == 32
    grid = mi.load_dict({"type": "grid", "sample_count": 4})
    grid.set_sample_count(12)
    assert (grid.rows, grid.cols) == (3, 4)
    with pytest.raises(ValueError, match="sample_count"):
        grid.set_sample_count(0)


# ------------------------------------------------------- determinism and other dimensions
@pytest.mark.filterwarnings("ignore:zsobol sampler")  # no film here: rows of a power of two assumed
@pytest.mark.parametrize("name", ["grid", "jitter", "poisson", "sobol", "zsobol"])
def test_determinism_and_seeds(mi, name):
    a, sa = _first_2d(mi, name, 16, pixels=8, seed=7)
    b, sb = _first_2d(mi, name, 16, pixels=8, seed=7)
    c, sc = _first_2d(mi, name, 16, pixels=8, seed=8)
    ra, rb, rc = _rest(sa), _rest(sb), _rest(sc)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ra, rb)
    assert not np.allclose(ra, rc)  # other dimensions change with the seed
    if name == "grid":
        np.testing.assert_array_equal(a, c)  # the grid itself is deterministic
    else:
        assert not np.allclose(a, c)
    # the "seed" property offsets the render seed
    d, sd = _first_2d(mi, name, 16, pixels=8, seed=0, props={"seed": 7})
    np.testing.assert_array_equal(d, a)
    np.testing.assert_array_equal(_rest(sd), ra)


@pytest.mark.parametrize("name", ["grid", "jitter", "poisson", "sobol"])
def test_pixel_sample_reproducible_on_its_own(mi, name):
    """(pixel, sample) gives the same numbers whatever the wavefront size (zsobol: whatever the crop
    window, tests/test_sobol.py)."""
    small, s_small = _first_2d(mi, name, 4, pixels=3, seed=11)
    large, s_large = _first_2d(mi, name, 4, pixels=10, seed=11)
    np.testing.assert_array_equal(small, large[:3])
    np.testing.assert_array_equal(_rest(s_small), _rest(s_large)[:, :12])


@pytest.mark.filterwarnings("ignore:zsobol sampler")
@pytest.mark.parametrize("name", ["grid", "jitter", "poisson", "sobol", "zsobol"])
def test_other_dimensions_uniform_and_decorrelated(mi, name):
    pts, sampler = _first_2d(mi, name, 16, pixels=2000, seed=5)
    one = np.asarray(sampler.next_1d())
    rest = _rest(sampler, 4)  # (4, lanes, 2)
    values = np.concatenate([one[None], rest.reshape(4, -1, 2).transpose(0, 2, 1).reshape(8, -1)])
    assert np.abs(values.mean(1) - 0.5).max() < 0.01
    assert np.abs(values.var(1) - 1 / 12).max() < 0.003
    film = pts.reshape(-1, 2).T
    corr = np.corrcoef(np.concatenate([film, values]))
    np.fill_diagonal(corr, 0)
    assert np.abs(corr).max() < 0.03


def test_clone_and_fork(mi):
    sampler = mi.load_dict({"type": "jitter", "sample_count": 4, "seed": 3})
    sampler.seed(1, 8)
    sampler.next_2d()
    twin = sampler.clone()
    np.testing.assert_array_equal(np.asarray(twin.next_2d()), np.asarray(sampler.next_2d()))
    fresh = sampler.fork()
    assert fresh.sample_count() == 4 and "seed=3" in str(fresh)


def test_bad_sample_count(mi):
    with pytest.raises(Exception, match="sample_count"):
        mi.load_dict({"type": "jitter", "sample_count": 0})


_BAD_PROPERTIES = [
    ("sample_count", "abc", TypeError, "sample_count: expected an integer, got str"),
    ("sample_count", 2.5, TypeError, "sample_count: expected an integer, got float"),
    ("sample_count", -1, ValueError, "sample_count: expected an integer in 1..16777216, got -1"),
    ("sample_count", 0, ValueError, "sample_count: expected an integer in 1..16777216, got 0"),
    ("seed", "7", TypeError, "seed: expected an integer, got str"),
    ("seed", 1.5, TypeError, "seed: expected an integer, got float"),
]
_BAD_RANDOMIZATION = [  # sobol and zsobol only
    ("randomization", "fast", ValueError, "randomization: expected one of owen, none, got 'fast'"),
    ("randomization", 3, TypeError, "randomization: expected a string, got int"),
]


_ALL_SAMPLERS = ("grid", "jitter", "poisson", "sobol", "zsobol")


@pytest.mark.parametrize("name,key,value,error,message",
                         [(n, *case) for n in _ALL_SAMPLERS for case in _BAD_PROPERTIES]
                         + [(n, *case) for n in ("sobol", "zsobol") for case in _BAD_RANDOMIZATION])
def test_bad_properties_name_the_property(mi, name, key, value, error, message):
    # read through the shared property readers (plugins/properties.py) before Mitsuba coerces them
    cls = importlib.import_module(f"pointillist.plugins.samplers.{name}").PLUGIN_CLASS
    props = mi.Properties(name)
    props[key] = value
    with pytest.raises(error, match=message):
        cls(props)
    with pytest.raises(RuntimeError, match=message):  # through Mitsuba's loader
        mi.load_dict({"type": name, key: value})


def test_set_sample_count_checks_its_argument(mi):
    for name in ("sobol", "zsobol", "grid"):
        sampler = mi.load_dict({"type": name, "sample_count": 4})
        for bad in (0, -3, 2.0, "8", True):
            with pytest.raises(ValueError, match="sample_count: expected an integer in 1.."):
                sampler.set_sample_count(bad)
    sampler.set_sample_count(np.int64(9))
    assert sampler.sample_count() == 9 and (sampler.rows, sampler.cols) == (3, 3)


# ------------------------------------------------------------------- in scenes
def _box(mi, sampler, spp, integrator="path", res=24):
    scene = mi.cornell_box()
    scene["sensor"]["sampler"] = {"type": sampler, "sample_count": spp}
    scene["sensor"]["film"]["width"] = scene["sensor"]["film"]["height"] = res
    scene["integrator"] = {"type": integrator}
    return mi.load_dict(scene)


@pytest.mark.parametrize("integrator", ["path", "direct", "whitted"])
def test_unbiased_in_renders(mi, integrator):
    """Image means match Mitsuba's independent sampler at many samples.

    Tolerance 3%: one 64 spp render of this 24x24 Cornell box has about 1.8% noise
    in its mean with random sampling, and the deterministic grid is off by up to 2%
    (it aliases the small bright light); a sampler that reused dimensions inside the
    path loop or put samples outside their pixel is off by far more.
    """
    from pointillist import plugins

    assert integrator in ("path", "direct") or integrator in plugins.registered()  # ours must be registered
    reference = np.asarray(mi.render(_box(mi, "independent", 1024, integrator), seed=99))
    for name in ("grid", "jitter", "poisson", "sobol", "zsobol"):
        scene = _box(mi, name, 64, integrator)
        image = np.mean([np.asarray(mi.render(scene, seed=s)) for s in (1, 2)], axis=0)
        assert np.isfinite(image).all()
        assert abs(image.mean() / reference.mean() - 1) < 0.03, name
        # local agreement: means of 4x4 pixel blocks
        blocks = lambda x: x.reshape(6, 4, 6, 4, 3).mean((1, 3))  # noqa: E731
        assert np.abs(blocks(image) - blocks(reference)).mean() < 0.05 * reference.mean(), name


def test_xml_configuration(mi):
    xml = """<scene version="3.0.0">
        <integrator type="direct"/>
        <sensor type="perspective">
            <sampler type="poisson"><integer name="sample_count" value="16"/>
                <integer name="seed" value="5"/></sampler>
            <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
        </sensor>
        <shape type="sphere"><transform name="to_world"><translate z="4"/></transform></shape>
        <emitter type="constant"/>
    </scene>"""
    scene = mi.load_string(xml)
    sampler = scene.sensors()[0].sampler()
    assert sampler.sample_count() == 16 and "PoissonSampler" in str(sampler) and "seed=5" in str(sampler)
    image = np.asarray(mi.render(scene))
    # constant emitter, black sphere in the middle: corners see the sky exactly
    np.testing.assert_allclose(image[0, 0], 1.0, rtol=1e-3)


def test_edges_scene_renders_with_each_sampler(mi):
    from pathlib import Path

    scene_path = Path(__file__).resolve().parent.parent / "scenes" / "edges.xml"
    means = {}
    for name in ("grid", "jitter", "poisson", "sobol", "zsobol", "independent"):
        scene = mi.load_file(str(scene_path), parallel=False, sampler=name, spp="16", res="32")
        means[name] = float(np.asarray(mi.render(scene)).mean())
    assert all(abs(m / means["independent"] - 1) < 0.05 for m in means.values()), means
