"""The ``adaptive`` integrator: corner refinement, weighting, sample counts, stiff cases.

Most tests look through an orthographic camera at an emitting rectangle, so the
radiance of every ray is known exactly (no noise) and results can be worked out by
hand or rendered independently by Mitsuba on a finer film.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from pathlib import Path

import numpy as np
import pytest

from pointillist.imaging.io import read_exr, to_8bit

ROOT = Path(__file__).resolve().parent.parent
EDGE_X = 0.1234  # world x of the vertical edge: film x = (EDGE_X + 1) / 2 * W


def _camera(mi, width, height, scale=1.0, sampler=None):
    T = mi.ScalarTransform4f
    return {"type": "orthographic",
            "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]) @ T().scale([scale, scale, 1]),
            "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}},
            "sampler": sampler or {"type": "independent", "sample_count": 4}}


def _edge_scene(mi, integrator, width=5, height=3, left=0.0, right=1.0, x0=EDGE_X, sampler=None):
    """Radiance ``right`` for world x > x0, ``left`` elsewhere (a vertical edge)."""
    T = mi.ScalarTransform4f
    scene = {"type": "scene", "integrator": integrator, "sensor": _camera(mi, width, height, sampler=sampler),
             "bright": {"type": "rectangle", "to_world": T().translate([x0 + 1, 0, 0]).scale([1, 2, 1]),
                        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": right}}}}
    if left:
        scene["dim"] = {"type": "rectangle", "to_world": T().translate([x0 - 1, 0, 0]).scale([1, 2, 1]),
                        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": left}}}
    return mi.load_dict(scene)


#: Texel values of the 2 x 2 bilinear emitter texture (different per channel).
TEXELS = np.array([[[0.10, 0.20, 0.05], [0.60, 0.30, 0.40]],
                   [[0.30, 0.70, 0.25], [0.90, 0.50, 0.80]]], dtype=np.float32)


def _gradient_scene(mi, integrator, size, scale=0.5, sampler=None):
    """A bilinear texture seen between its texel centres: it varies in every square."""
    emitter = {"type": "area", "radiance": {"type": "bitmap", "bitmap": mi.Bitmap(TEXELS), "raw": True,
                                            "filter_type": "bilinear", "wrap_mode": "clamp"}}
    return mi.load_dict({"type": "scene", "integrator": integrator,
                         "sensor": _camera(mi, size, size, scale, sampler),
                         "light": {"type": "rectangle", "emitter": emitter}})


def _adaptive(nested="path", **options):
    return dict({"type": "adaptive", "nested": {"type": nested}}, **options)


def _render(mi, scene, seed=0):
    image = np.asarray(mi.render(scene, seed=seed))
    return image[..., :3], image[..., -1]


def _lattice(mi, size, depth):
    """Mitsuba's own render of the uniform (size 2^depth + 1)^2 lattice of the pixel
    corners of a ``size`` x ``size`` film over [-0.5, 0.5]^2: a finer film whose pixel
    centres are the lattice points, one unjittered stratified sample per pixel."""
    cells = size << depth
    scene = _gradient_scene(mi, {"type": "path"}, cells + 1, scale=0.5 * (cells + 1) / cells,
                            sampler={"type": "stratified", "sample_count": 1, "jitter": False})
    return np.asarray(mi.render(scene))[..., :3]


def _blocks(lattice, size, depth, weights):
    step = 1 << depth
    out = np.zeros((size, size, 3))
    for y in range(size):
        for x in range(size):
            block = lattice[y * step:(y + 1) * step + 1, x * step:(x + 1) * step + 1]
            out[y, x] = np.tensordot(weights, block, axes=([0, 1], [0, 1])) / weights.sum()
    return out


def _trapezoid(n):
    w = np.ones(n)
    w[0] = w[-1] = 0.5
    return np.outer(w, w)


# -- the course's method ---------------------------------------------------------------

def test_flat_scene_takes_exactly_the_corner_samples(mi):
    scene = mi.load_dict({"type": "scene", "integrator": _adaptive(threshold=0.0, max_depth=4),
                          "sensor": _camera(mi, 7, 5),
                          "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.3, 0.5, 0.7]}}})
    image, count = _render(mi, scene)
    np.testing.assert_allclose(image, np.broadcast_to([0.3, 0.5, 0.7], image.shape), rtol=1e-6)
    assert (count == 4).all()
    assert scene.integrator().stats["rays"] == [8 * 6]  # (W + 1) (H + 1), one batch


@pytest.mark.parametrize("depth", [1, 3])
def test_vertical_edge_refines_only_edge_pixels_to_max_depth(mi, depth):
    scene = _edge_scene(mi, _adaptive(threshold=20.0, max_depth=depth))
    image, count = _render(mi, scene)
    f = (EDGE_X + 1) / 2 * 5 - 2  # edge position inside pixel column 2
    h = 0.5 ** depth
    a = math.floor(f / h) * h  # the finest refined column of squares [a, a + h]
    expected = np.zeros((3, 5))
    expected[:, 3:] = 1.0
    expected[:, 2] = 1.0 - a - h / 2  # area weighting: half of the straddling column is lit
    np.testing.assert_allclose(image[..., 0], expected, atol=1e-6)
    samples = np.full((3, 5), 4.0)
    samples[:, 2] = 4 + 4 * (2 ** depth - 1) + depth  # per level L: 4 * 2^L + 1 new points
    np.testing.assert_array_equal(count, samples)
    # One batch per level; shared points traced once: level L traces 3 pixel rows of a
    # column of 2^L squares, (3 * 2^L) * 5 points minus (3 * 2^L - 1) shared midpoints.
    rays = scene.integrator().stats["rays"]
    assert rays == [6 * 4] + [4 * 3 * 2 ** L + 1 for L in range(depth)]


def test_vertical_edge_equal_weighting_is_the_plain_mean(mi):
    depth = 3
    image, count = _render(mi, _edge_scene(mi, _adaptive(threshold=20.0, max_depth=depth, weighting="equal")))
    # Enumerate the samples of an edge pixel by hand: x positions of its distinct points.
    f = (EDGE_X + 1) / 2 * 5 - 2
    xs = [0.0, 0.0, 1.0, 1.0]
    for level in range(depth):
        h = 0.5 ** level
        a = math.floor(f / h) * h
        rows = 2 ** level
        xs += [a + h / 2] * (2 * rows + 1) + [a] * rows + [a + h] * rows
    assert count[0, 2] == len(xs) == 35
    np.testing.assert_allclose(image[:, 2, 0], np.mean(np.array(xs) > f), atol=1e-6)
    np.testing.assert_allclose(image[:, 2, 0], 18 / 35, atol=1e-6)  # vs 0.1875 with area weights


@pytest.mark.parametrize("weighting, threshold, min_depth", [("area", 0.0, 0), ("equal", 0.0, 0),
                                                              ("area", math.inf, 2), ("equal", math.inf, 2)])
def test_threshold_zero_is_the_uniform_grid(mi, weighting, threshold, min_depth):
    # min_depth = max_depth splits everything whatever the threshold: the same grid.
    size, depth = 4, 2
    scene = _gradient_scene(mi, _adaptive(threshold=threshold, max_depth=depth, min_depth=min_depth,
                                          weighting=weighting), size)
    image, count = _render(mi, scene)
    assert (count == (2 ** depth + 1) ** 2).all()
    n = 2 ** depth + 1
    weights = _trapezoid(n) if weighting == "area" else np.ones((n, n))
    expected = _blocks(_lattice(mi, size, depth), size, depth, weights)
    np.testing.assert_allclose(image, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("options", [dict(threshold=math.inf, max_depth=3), dict(threshold=1e30, max_depth=3),
                                     dict(threshold=0.0, max_depth=0)])
def test_infinite_threshold_or_depth_zero_is_corner_averaging(mi, options):
    size = 4
    scene = _gradient_scene(mi, _adaptive(**options), size)
    image, count = _render(mi, scene)
    assert (count == 4).all() and scene.integrator().stats["rays"] == [(size + 1) ** 2]
    expected = _blocks(_lattice(mi, size, 0), size, 0, np.ones((2, 2)))
    np.testing.assert_allclose(image, expected, rtol=1e-5, atol=1e-6)


def test_threshold_is_on_the_display_scale_after_exposure(mi):
    # 0.001 vs 0.002: sRGB display 3.3 vs 6.6 (range 3.3 <= 20): no refinement ...
    scene = _edge_scene(mi, _adaptive(threshold=20.0, max_depth=2), left=0.001, right=0.002)
    assert (_render(mi, scene)[1] == 4).all()
    # ... at +6 stops (x 64): 72 vs 100, range 28 > 20: the edge column is refined.
    scene = _edge_scene(mi, _adaptive(threshold=20.0, max_depth=2, exposure=6.0), left=0.001, right=0.002)
    count = _render(mi, scene)[1]
    assert (count[:, 2] > 4).all() and (np.delete(count, 2, axis=1) == 4).all()
    # Linear display: 0.255 vs 0.51 and x 2: 0.51 vs 1.02 -> 130 vs 255 clipped.
    scene = _edge_scene(mi, _adaptive(threshold=120.0, max_depth=1, srgb=False, exposure=1.0),
                        left=0.255, right=0.51)
    assert (_render(mi, scene)[1][:, 2] == 9).all()


def test_display_mapping_matches_the_png_writer(mi):
    import drjit as dr

    from pointillist.plugins.integrators.adaptive import srgb_display

    values = np.array([0.0, 1e-4, 0.0031308, 0.01, 0.2, 0.5, 0.999, 1.0, 3.0, -1.0], dtype=np.float32)
    ours = np.asarray(srgb_display(mi.Float(values)))
    np.testing.assert_array_equal(np.round(ours).astype(np.uint8), to_8bit(values[None, :], srgb=True)[0])
    linear = np.asarray(srgb_display(mi.Float(values), exposure=-1.0, srgb=False))
    np.testing.assert_allclose(linear, np.clip(values / 2, 0, 1) * 255, rtol=1e-6)
    assert dr.allclose(srgb_display(0.5, exposure=1.0), 255.0)


# -- with real integrators ---------------------------------------------------------------

def _default_scene(mi, integrator, res=16):
    # parallel=False as pointillist loads scenes (Mitsuba's parallel loader once failed here in CI with
    # "failed to instantiate shape plugin of type sphere: basic_string::_M_create")
    return mi.load_file(str(ROOT / "scenes" / "default.xml"), parallel=False, res=str(res), integrator=integrator,
                        spp="4")


def test_determinism_for_a_fixed_seed(mi):
    scene = _default_scene(mi, "path")
    integrator = mi.load_dict(_adaptive(threshold=10.0, max_depth=2))
    first = np.asarray(mi.render(scene, integrator=integrator, seed=3))
    again = np.asarray(mi.render(scene, integrator=integrator, seed=3))
    other = np.asarray(mi.render(scene, integrator=integrator, seed=4))
    np.testing.assert_array_equal(first, again)
    assert np.abs(first[..., :3] - other[..., :3]).max() > 1e-3  # path noise differs


@pytest.mark.parametrize("nested", ["path", "direct", "whitted"])
def test_works_with_nested_integrators(mi, nested):
    from pointillist import plugins

    assert nested in ("path", "direct") or nested in plugins.registered()  # ours must be registered
    scene = _default_scene(mi, "path", res=20)
    integrator = mi.load_dict(_adaptive(nested, threshold=20.0, max_depth=2))
    image = np.asarray(mi.render(scene, integrator=integrator, seed=1))
    count = image[..., -1]
    reference = np.asarray(mi.render(scene, integrator=mi.load_dict({"type": nested}), spp=64, seed=9))
    assert image.shape == (20, 20, 4) and np.isfinite(image).all()
    assert count.min() == 4 and count.max() > 4 and count.max() <= 25
    # Same scene, same nested integrator: the image means agree (noise and edges aside).
    np.testing.assert_allclose(image[..., :3].mean(axis=(0, 1)), reference.mean(axis=(0, 1)), rtol=0.08)


def test_sample_count_layer_and_heat_map_from_the_cli(cli, mi, tmp_path):
    xml = tmp_path / "edge.xml"
    xml.write_text(f"""<scene version="3.0.0">
    <integrator type="adaptive"><float name="threshold" value="20"/><integer name="max_depth" value="2"/>
        <integrator type="path"/></integrator>
    <sensor type="orthographic">
        <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
        <film type="hdrfilm"><integer name="width" value="5"/><integer name="height" value="3"/>
            <rfilter type="gaussian"/></film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><scale x="1" y="2"/><translate x="{EDGE_X + 1}"/></transform>
        <emitter type="area"><rgb name="radiance" value="1"/></emitter>
    </shape>
</scene>""")
    out = tmp_path / "edge.exr"
    proc = cli("render", xml, "-o", out, "--png")
    assert proc.returncode == 0, proc.stderr
    image, meta, layers = read_exr(out)
    assert image.shape == (3, 5, 3) and meta["integrator"] == "adaptive"
    np.testing.assert_array_equal(layers["sample_count"], [[4, 4, 4 + 4 * 3 + 2, 4, 4]] * 3)
    np.testing.assert_allclose(image[:, 3:], 1.0)  # box-filtered whatever the film's rfilter
    heat = tmp_path / "edge.sample_count.png"
    assert heat.stat().st_size > 1000


# -- stiff and extreme cases ---------------------------------------------------------------

def test_one_pixel_image(mi):
    scene = _edge_scene(mi, _adaptive(threshold=20.0, max_depth=3), width=1, height=1)
    image, count = _render(mi, scene)
    f = (EDGE_X + 1) / 2  # the edge inside the only pixel
    h = 1 / 8
    a = math.floor(f / h) * h
    np.testing.assert_allclose(image[0, 0], 1 - a - h / 2, atol=1e-6)
    assert count[0, 0] == 35 and scene.integrator().stats["rays"][0] == 4


@pytest.fixture(scope="module")
def broken(mi):
    """A nested integrator returning NaN for x < -0.6, +inf for -0.6 <= x < -0.1, 1 elsewhere."""
    import drjit as dr

    class Broken(mi.SamplingIntegrator):
        def sample(self, scene, sampler, ray, medium=None, active=True):
            x = ray.o.x
            value = dr.select(x < -0.6, dr.nan, dr.select(x < -0.1, dr.inf, 1.0))
            return mi.Color3f(value), mi.Bool(True), []

        def aov_names(self):
            return []

        def to_string(self):
            return "Broken[]"

    mi.register_integrator("adaptive_test_broken", lambda props: Broken(props))
    return "adaptive_test_broken"


@pytest.mark.parametrize("weighting", ["area", "equal"])
def test_nan_and_inf_samples_are_dropped_but_counted(mi, broken, weighting):
    scene = _edge_scene(mi, _adaptive(broken, threshold=20.0, max_depth=2, weighting=weighting), width=8, height=2)
    image, count = _render(mi, scene)
    assert np.isfinite(image).all()
    # Pixels 0 (NaN), 1 (NaN and inf corners) and 2 (inf) have no valid sample: 0.
    # Pixel 3 (x in [-0.25, 0]): left corners inf, right corners 1: the range over the
    # valid ones is 0 (no refinement) and the pixel is their mean.
    np.testing.assert_array_equal(image[:, :3], 0.0)
    np.testing.assert_array_equal(image[:, 3:], 1.0)
    np.testing.assert_array_equal(count, 4.0)


def test_huge_radiance_clips_on_the_display_scale(mi):
    # 10 vs 1e30: both white on the display: no refinement; the average keeps the HDR values.
    image, count = _render(mi, _edge_scene(mi, _adaptive(threshold=20.0, max_depth=3), left=10.0, right=1e30))
    assert (count == 4).all()
    np.testing.assert_allclose(image[0, 2, 0], (10.0 * 2 + 1e30 * 2) / 4, rtol=1e-5)


# -- variance criterion --------------------------------------------------------------------

def test_variance_criterion_stops_flat_pixels_and_refines_edges(mi):
    # Stratified 4 x 4: 12 strata of the edge pixel lie left of the edge (x < 0.75), some
    # of the 4 others right of it, so its samples always vary.
    options = dict(criterion="variance", max_error=0.02, max_sample_factor=8)
    spp = 16
    scene = _edge_scene(mi, _adaptive(**options), width=5, height=3, left=0.2, right=1.0,
                        sampler={"type": "stratified", "sample_count": spp})
    image, count = _render(mi, scene)
    flat = np.delete(count, 2, axis=1)
    assert (flat == spp).all()  # zero variance: one round of spp samples
    # Luminance std ~0.3 about a mean ~0.35: the interval stays wider than 2% to the cap.
    np.testing.assert_array_equal(count[:, 2], 8 * spp)
    np.testing.assert_allclose(np.delete(image[..., 0], 2, axis=1), [[0.2, 0.2, 1, 1]] * 3, rtol=1e-6)
    f = (EDGE_X + 1) / 2 * 5 - 2
    truth = 0.2 * f + 1.0 * (1 - f)
    assert np.abs(image[:, 2, 0] - truth).max() < 0.1  # 128 samples: standard error ~0.03
    assert scene.integrator().stats["rounds"] >= 2


def _variance_rule_count(values, spp, max_error, p_value, factor):
    """The conventions' stopping rule replayed in float64: rounds of the same ``spp`` luminance values
    (a grid sampler puts every round's samples at the same cell centres) until
    ``z sqrt(var / n) <= max_error |mean|`` (z = the normal quantile of 1 - p/2, var with n - 1)
    or ``factor * spp`` samples."""
    z = NormalDist().inv_cdf(1 - p_value / 2)
    n = 0
    while True:
        n += spp
        samples = np.tile(values, n // spp)
        if z * math.sqrt(samples.var(ddof=1) / n) <= max_error * abs(samples.mean()) or n + spp > factor * spp:
            return n


@pytest.mark.parametrize("p_value, max_error, factor, expected", [
    # The edge pixel's 16 grid samples: 12 at 0.2, 4 at 1.0 (mean 0.4, sd 0.3464 sqrt(n/(n-1))),
    # so the rule stops at the first n = 16 k with n - 1 >= (z 0.8660 / max_error)^2 =: T.
    (0.05, 0.10010, 64, 304),  # z = 1.960, T = 287.5: the n - 1 matters (with n: 288)
    (0.2, 0.11357, 64, 112),   # z = 1.282, T = 95.5 (with n: 96)
    (0.01, 0.2, 64, 128),      # z = 2.576, T = 124.4
    (0.05, 0.05, 20, 320),     # T = 1152: the cap of 20 x 16 samples comes first
])
def test_variance_criterion_sample_count_follows_the_rule(mi, p_value, max_error, factor, expected):
    spp = 16
    scene = _edge_scene(mi, _adaptive(criterion="variance", max_error=max_error, p_value=p_value,
                                      max_sample_factor=factor),
                        width=5, height=3, left=0.2, right=1.0, sampler={"type": "grid", "sample_count": spp})
    image, count = _render(mi, scene)
    # The grid's 4 x 4 cell centres of pixel 2 sit at x = 0.125 .. 0.875; the edge at 0.81: 12 left.
    values = np.array([0.2] * 12 + [1.0] * 4)
    assert _variance_rule_count(values, spp, max_error, p_value, factor) == expected
    np.testing.assert_array_equal(count[:, 2], [expected] * 3)
    np.testing.assert_array_equal(np.delete(count, 2, axis=1), spp)  # flat pixels: zero variance
    np.testing.assert_allclose(image[:, 2, 0], 0.4, rtol=1e-6)


def test_variance_criterion_black_pixels_stop(mi):
    scene = _edge_scene(mi, _adaptive(criterion="variance", max_sample_factor=4), width=4, height=2, x0=5.0)
    image, count = _render(mi, scene)
    assert (image == 0).all() and (count == 4).all()


# -- parameters ---------------------------------------------------------------------------------

@pytest.mark.parametrize("options, error, message", [
    (dict(criterion="median"), ValueError, "criterion: expected one of range, variance"),
    (dict(weighting="gauss"), ValueError, "weighting: expected one of area, equal"),
    (dict(threshold=-1.0), ValueError, "threshold: expected a number >= 0"),
    (dict(threshold=math.nan), ValueError, "threshold: expected a finite number"),
    (dict(threshold="20"), TypeError, "threshold: expected a number"),
    (dict(max_depth=-1), ValueError, "max_depth: expected an integer in 0..12"),
    (dict(max_depth=13), ValueError, "max_depth: expected an integer in 0..12"),
    (dict(max_depth=2.5), TypeError, "max_depth: expected an integer"),
    (dict(max_depth=2, min_depth=3), ValueError, "min_depth: expected at most max_depth = 2, got 3"),
    (dict(max_error=0.0), ValueError, "max_error: expected a number > 0"),
    (dict(p_value=1.0), ValueError, "p_value: expected a number in (0, 1)"),
    (dict(max_sample_factor=0), ValueError, "max_sample_factor: expected an integer in 1.."),
    (dict(exposure=math.inf), ValueError, "exposure: expected a finite number"),
    (dict(srgb=1), TypeError, "srgb: expected a boolean"),
])
def test_bad_parameters(mi, options, error, message):
    from pointillist.plugins.integrators.adaptive import AdaptiveIntegrator

    props = mi.Properties("adaptive")
    for name, value in options.items():
        props[name] = value
    props["nested"] = mi.load_dict({"type": "path"})
    pattern = message.replace("(", r"\(").replace(")", r"\)")
    with pytest.raises(error, match=pattern):
        AdaptiveIntegrator(props)
    with pytest.raises(RuntimeError, match=pattern):  # through Mitsuba's loader
        mi.load_dict(_adaptive(**options))


def test_nested_integrator_required_once(mi):
    with pytest.raises(RuntimeError, match="exactly one nested integrator, got 0"):
        mi.load_dict({"type": "adaptive"})
    with pytest.raises(RuntimeError, match="exactly one nested integrator, got 2"):
        mi.load_dict({"type": "adaptive", "a": {"type": "path"}, "b": {"type": "direct"}})
    with pytest.raises(RuntimeError, match="cannot be another adaptive"):
        mi.load_dict({"type": "adaptive", "a": _adaptive()})


def test_aov_names_and_description(mi):
    integrator = mi.load_dict(_adaptive("path", threshold=5.0))
    assert integrator.aov_names() == ["sample_count"]
    assert "threshold=5" in integrator.to_string() and "criterion=range" in integrator.to_string()


# -- pointillist compare ---------------------------------------------------------------------

def test_compare_sweeps_adaptive_thresholds_around_the_scene_integrator(mi, tmp_path):
    from pointillist.compare import render_one
    from pointillist.compare.methods import METHODS, load_configured_scene

    method = METHODS["adaptive"]
    assert method.kind == "integrator" and method.parameter == "threshold" and len(method.values) >= 3
    scene = load_configured_scene(ROOT / "scenes" / "edges.xml", method, 8.0, {"res": "12"})
    integrator = scene.integrator()
    assert integrator.threshold == 8.0 and "DirectIntegrator" in integrator.to_string()
    record = render_one(str(ROOT / "scenes" / "edges.xml"), "adaptive", 8.0, 0, {"res": "12"}, str(tmp_path))
    image, meta, layers = read_exr(tmp_path / "renders" / record.exr)
    assert record.spp == pytest.approx(layers["sample_count"].mean()) and record.spp > 4


# -- scheduling (speed work): lattice start, shared points, no recompilation -----------------

@pytest.mark.parametrize("min_depth, rays, edge_count", [(0, [24, 13, 25, 49], 35), (1, [77, 25, 49], 35),
                                                         (2, [273, 49], 42)])
def test_min_depth_lattice_batch_and_shared_points(mi, min_depth, rays, edge_count):
    # min_depth m: one batch of the (5 * 2^m + 1) x (3 * 2^m + 1) lattice, then only the
    # edge column: level L traces its 3 * 2^L squares' 5 points minus the
    # 3 * 2^L - 1 midpoints shared with the square below (counted by hand).
    scene = _edge_scene(mi, _adaptive(threshold=20.0, max_depth=3, min_depth=min_depth))
    image, count = _render(mi, scene)
    assert scene.integrator().stats["rays"] == rays
    f = (EDGE_X + 1) / 2 * 5 - 2
    a = math.floor(f * 8) / 8  # same finest column as with min_depth 0: same image
    expected = np.zeros((3, 5))
    expected[:, 3:] = 1.0
    expected[:, 2] = 1.0 - a - 1 / 16
    np.testing.assert_allclose(image[..., 0], expected, atol=1e-6)
    flat = (2 ** min_depth + 1) ** 2
    np.testing.assert_array_equal(np.delete(count, 2, axis=1), flat)
    np.testing.assert_array_equal(count[:, 2], edge_count)


def test_min_depth_equal_weighting_counts_each_lattice_point_once(mi):
    # min_depth 1, equal weights: a flat pixel is the plain mean of its 9 lattice points.
    scene = _gradient_scene(mi, _adaptive(threshold=math.inf, max_depth=1, min_depth=1, weighting="equal"), 4)
    image, count = _render(mi, scene)
    assert (count == 9).all()
    np.testing.assert_allclose(image, _blocks(_lattice(mi, 4, 1), 4, 1, np.ones((3, 3))), rtol=1e-5, atol=1e-6)


def test_no_kernel_recompiles_between_thresholds_seeds_and_sizes(mi):
    # Thresholds, seeds and the number of squares per level differ between these renders;
    # every kernel of the later ones must be one the first render already compiled (no
    # per-call scalar or per-level size baked into a kernel as a literal).
    import drjit as dr

    scene = _default_scene(mi, "path", res=24)

    def hashes(threshold, seed, min_depth):
        integrator = mi.load_dict(_adaptive("direct", threshold=threshold, max_depth=3, min_depth=min_depth))
        dr.kernel_history()
        image = mi.render(scene, integrator=integrator, seed=seed)
        dr.eval(image)
        history = dr.kernel_history()
        return {k["hash"] for k in history if k["type"] == dr.KernelType.JIT}, integrator.stats["rays"]

    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        first, rays_a = hashes(30.0, 1, 1)
        later, rays_b = hashes(3.0, 2, 1)
        assert rays_a[1:] != rays_b[1:] and len(rays_b) == 3  # other square counts, same levels
        assert later <= first, f"{len(later - first)} kernels recompiled"
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)


def test_divmod_without_division_is_exact(mi):
    import drjit as dr

    from pointillist.imaging.arrays import divmod_u32

    rng = np.random.default_rng(5)
    x = np.concatenate([rng.integers(0, 2 ** 32, 20000, dtype=np.uint64), [0, 2 ** 32 - 1, 2 ** 31]]).astype(np.uint32)
    for d in (1, 3, 257, 4097, 65537, 2 ** 20 + 1, 2 ** 31 - 1):
        x_d = np.concatenate([x, (np.arange(1, 200, dtype=np.uint64) * d - 1).astype(np.uint32)[:199]])
        q, r = divmod_u32(mi.UInt32(x_d), d)
        np.testing.assert_array_equal(np.asarray(q), x_d // np.uint32(d))
        np.testing.assert_array_equal(np.asarray(r), x_d % np.uint32(d))
    assert dr.width(q) == len(x_d)


@pytest.mark.parametrize("sampler", ["grid", "independent"])
def test_range_nested_random_numbers_do_not_follow_the_image_plane_pattern(mi, sampler):
    """The range criterion places its rays itself; the scene's sampler only feeds the
    nested integrator. A pattern sampler's first 2D request is its image-plane pattern
    (``grid`` with one sample: always (0.5, 0.5)); the adaptive integrator must consume
    it as the film position so that the nested integrator's light samples stay uniform.
    A diffuse plane under a large area light seen by ``direct``: always sampling the
    light's centre overestimates the image by about 5%."""
    T = mi.ScalarTransform4f
    sensor = _camera(mi, 16, 16, sampler={"type": sampler, "sample_count": 1})
    sensor["to_world"] = T().look_at(origin=[0, 0, 0.5], target=[0, 0, 0], up=[0, 1, 0]) @ T().scale([0.8, 0.8, 1])
    scene = mi.load_dict({
        "type": "scene", "integrator": _adaptive("direct", threshold=math.inf), "sensor": sensor,
        "plane": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 1.0}}},
        "light": {"type": "rectangle", "to_world": T().translate([0, 0, 1]).rotate([1, 0, 0], 180).scale(2.0),
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}},
    })
    image = np.mean([_render(mi, scene, seed=s)[0] for s in range(8)], axis=0)
    # the camera sits between the plane and the light (facing down) and sees x, y in [-0.8, 0.8]
    reference = np.asarray(mi.render(scene, integrator=mi.load_dict({"type": "direct"}), spp=256, seed=1))[..., :3]
    assert reference.mean() > 0.1
    np.testing.assert_allclose(image.mean(), reference.mean(), rtol=0.02)
