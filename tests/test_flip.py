"""FLIP on Dr.Jit (pointillist.imaging.flip) against flip-evaluator, the reference implementation.

flip-evaluator (NVIDIA's package) stays the reference: every agreement test runs it on the same
pair. The contract: mean FLIP within 1e-3 and the maps within 1e-2 per pixel at the
99th percentile, on real renders of the project's scenes and on scikit-image's photographs. The
two implementations do the same float32 operations in the same order (only the transcendental
functions differ in their last bits), so the measured agreement is far tighter (maps within
about 1e-6 at the 99th percentile, 4e-5 at most; means within 1e-8): the drift bounds below
fail long before the contract would. Independent of both, the colour pipeline is checked
against colour-science on constant images (no features), where FLIP is the remapped HyAB
distance of the Hunt-adjusted CIELab colours.
"""

from __future__ import annotations

import math
from pathlib import Path

import colour
import drjit as dr
import flip_evaluator
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from pointillist.imaging import flip as flip_module
from pointillist.imaging.arrays import TensorXf
from pointillist.imaging.flip import (DEFAULT_PPD, FLIP_CONSTANTS, TONEMAPPERS, flip, hdr_exposure_range,
                                      pixels_per_degree, tonemapper_x_max)
from skimage import data

#: The contract.
MEAN_CONTRACT, P99_CONTRACT = 1e-3, 1e-2
#: Drift bounds, some 30x what is measured.
MEAN_DRIFT, P99_DRIFT, MAX_DRIFT = 1e-6, 5e-5, 1e-3


def reference_flip(image, reference, mode="HDR", **parameters):
    """flip-evaluator's (map, mean, parameters), the reference first as it takes them."""
    error_map, mean, used = flip_evaluator.evaluate(np.ascontiguousarray(reference, np.float32),
                                                    np.ascontiguousarray(image, np.float32), mode,
                                                    applyMagma=False, parameters=parameters)
    return np.asarray(error_map, np.float32)[..., 0], float(mean), used


def assert_agrees(result, expected_map, expected_mean, used=None, exposures_ulp=0, mean_drift=MEAN_DRIFT):
    ours = np.asarray(result.map)
    assert ours.shape == expected_map.shape and ours.dtype == np.float32
    difference = np.abs(ours.astype(np.float64) - expected_map)
    p99 = float(np.percentile(difference, 99))
    # the contract, on flip-evaluator's own (float32-summed) mean ...
    assert abs(result.mean - expected_mean) <= MEAN_CONTRACT and p99 <= P99_CONTRACT
    # ... and the drift bounds (flip-evaluator's map summed in float64, as ours is)
    assert abs(result.mean - expected_map.mean(dtype=np.float64)) <= mean_drift
    assert p99 <= P99_DRIFT and float(difference.max()) <= MAX_DRIFT, (p99, float(difference.max()))
    if used is not None and result.exposures is not None:  # the same exposures, to the bit (or ulp)
        expected = (np.float32(used["startExposure"]), np.float32(used["stopExposure"]))
        assert result.exposures[2] == used["numExposures"]
        for ours_end, end in zip(result.exposures[:2], expected):
            assert abs(np.float32(ours_end) - end) <= exposures_ulp * np.spacing(end), (result.exposures, used)


# ------------------------------------------------------------------------------ real renders
SCENES = ("edges", "cornell_phong", "whitted")
SCENE_DIR = Path(__file__).resolve().parent.parent / "scenes"


@pytest.fixture(scope="module")
def renders(mi):
    """Per scene: the 64-spp reference and the 1- and 4-spp renders (96 x 96, other seeds)."""
    images = {}
    for name in SCENES:
        scene = mi.load_file(str(SCENE_DIR / f"{name}.xml"), parallel=False, res="96")
        reference = np.asarray(mi.render(scene, spp=64, seed=1000))[..., :3]
        images[name] = (np.ascontiguousarray(reference, np.float32),
                        {spp: np.ascontiguousarray(np.asarray(mi.render(scene, spp=spp, seed=spp))[..., :3],
                                                   np.float32) for spp in (1, 4)})
        del scene
    return images


@pytest.mark.parametrize("scene", SCENES)
def test_hdr_flip_of_renders_is_flip_evaluators(renders, scene):
    reference, tests = renders[scene]
    for spp, image in tests.items():
        result = flip(image, reference)
        assert_agrees(result, *reference_flip(image, reference))
        assert result.exposures[2] >= 3       # real renders: several exposures, each compared
    # fewer samples, more error (both implementations)
    assert flip(tests[1], reference).mean > flip(tests[4], reference).mean


def test_ldr_flip_of_tone_mapped_renders_is_flip_evaluators(renders):
    from pointillist.imaging.tone import tonemap

    reference, tests = renders["cornell_phong"]
    display = [np.asarray(tonemap(a, "aces")) / 255.0 for a in (tests[1], reference)]  # sRGB-encoded in [0, 1]
    assert_agrees(flip(*display, dynamic_range="ldr"), *reference_flip(*display, "LDR"))


# ------------------------------------------------------------------------------- photographs
def _linear(photo):
    return colour.models.eotf_sRGB(photo / 255.0).astype(np.float32)


@pytest.fixture(scope="module")
def photos():
    rng = np.random.default_rng(32)
    chelsea = data.chelsea()[60:180, 150:310]           # 120 x 160, the cat's face
    coffee = data.coffee()[100:200, 200:330]            # 100 x 130
    return rng, {"chelsea": chelsea, "coffee": coffee}


def _distortions(rng, photo):
    """Noise, 16-level quantisation and a one-pixel shift of an sRGB photograph in [0, 1]."""
    x = photo / np.float32(255.0)
    return {"noise": np.clip(x + rng.normal(0, 0.04, x.shape), 0, 1).astype(np.float32),
            "quantised": (np.round(x * 15) / 15).astype(np.float32),
            "shifted": np.roll(x, 1, axis=1).astype(np.float32)}


def test_ldr_flip_of_photographs_is_flip_evaluators(photos):
    rng, images = photos
    for photo in images.values():
        reference = (photo / np.float32(255.0)).astype(np.float32)
        for distorted in _distortions(rng, photo).values():
            assert_agrees(flip(distorted, reference, dynamic_range="ldr"),
                          *reference_flip(distorted, reference, "LDR"))


def test_hdr_flip_of_photographs_is_flip_evaluators(photos):
    """Linear photographs with highlights 40x brighter: a range of several exposures."""
    rng, images = photos
    for photo in images.values():
        reference = _linear(photo) * 2
        reference[::7, ::5] *= 40
        test = np.clip(reference * rng.lognormal(0, 0.2, reference.shape), 0, None).astype(np.float32)
        result = flip(test, reference)
        assert_agrees(result, *reference_flip(test, reference), mean_drift=P99_DRIFT)  # a few pixels: see above
        assert result.exposures[2] >= 5


def test_grey_photograph_is_compared_as_rgb():
    camera = data.camera()[200:296, 180:300] / np.float32(255.0)
    noisy = np.clip(camera + np.random.default_rng(4).normal(0, 0.05, camera.shape), 0, 1).astype(np.float32)
    grey = flip(noisy, camera, dynamic_range="ldr")
    rgb = flip(np.repeat(noisy[..., None], 3, 2), np.repeat(camera[..., None], 3, 2), dynamic_range="ldr")
    np.testing.assert_array_equal(np.asarray(grey.map), np.asarray(rgb.map))
    np.testing.assert_array_equal(np.asarray(flip(noisy[..., None], camera[..., None], dynamic_range="ldr").map),
                                  np.asarray(grey.map))
    assert_agrees(grey, *reference_flip(np.repeat(noisy[..., None], 3, 2), np.repeat(camera[..., None], 3, 2),
                                        "LDR"))


# ----------------------------------------------------------------------------- the options
@pytest.fixture(scope="module")
def hdr_pair():
    rng = np.random.default_rng(7)
    reference = _linear(data.coffee()[150:214, 250:330]) * 3
    reference[20:30, 40:60] = 25.0                       # a highlight
    test = np.clip(reference + rng.normal(0, 0.1, reference.shape), 0, None).astype(np.float32)
    return test, reference


@pytest.mark.parametrize("tonemapper", ["reinhard", "hable", "aces"])
def test_tone_mappers_are_flip_evaluators(hdr_pair, tonemapper):
    test, reference = hdr_pair
    result = flip(test, reference, tonemapper=tonemapper.upper() if tonemapper == "hable" else tonemapper)
    assert_agrees(result, *reference_flip(test, reference, tonemapper=tonemapper))


def test_explicit_exposures_and_count_are_flip_evaluators(hdr_pair):
    test, reference = hdr_pair
    for start, stop, count in ((-2.0, 3.0, None), (-1.5, 4.5, 4), (0.5, 0.5, None)):
        parameters = {"startExposure": start, "stopExposure": stop}
        if count is not None:
            parameters["numExposures"] = count
        result = flip(test, reference, start_exposure=start, stop_exposure=stop, num_exposures=count)
        assert_agrees(result, *reference_flip(test, reference, **parameters))
    # only one end given: the other is computed, as flip-evaluator does
    result = flip(test, reference, start_exposure=-4.0)
    assert_agrees(result, *reference_flip(test, reference, startExposure=-4.0))
    # one exposure: the start alone (flip-evaluator divides by zero there); the largest over several is larger
    single = flip(test, reference, start_exposure=1.0, stop_exposure=3.0, num_exposures=1)
    assert single.exposures == (1.0, 3.0, 1)
    same = flip(test, reference, start_exposure=1.0, stop_exposure=1.0)
    np.testing.assert_array_equal(np.asarray(single.map), np.asarray(same.map))
    several = flip(test, reference, start_exposure=1.0, stop_exposure=3.0)
    assert np.all(np.asarray(several.map) >= np.asarray(single.map)) and several.mean > single.mean


@pytest.mark.parametrize("ppd", [20.0, 45.0, 120.0])
def test_pixels_per_degree_changes_the_filters_as_in_flip_evaluator(hdr_pair, ppd):
    test, reference = hdr_pair
    radius = math.ceil(3 * math.sqrt(0.04 / (2 * math.pi ** 2)) * ppd)   # the widest CSF Gaussian, 3 sigma
    assert flip_module._filters(ppd)["radius"] == radius
    assert flip_module._filters(ppd)["feature_radius"] == math.ceil(3 * 0.5 * 0.082 * ppd)
    assert_agrees(flip(test, reference, ppd=ppd), *reference_flip(test, reference, ppd=ppd))


def test_viewing_conditions():
    assert DEFAULT_PPD == pytest.approx(0.7 * 3840 / 0.7 * math.pi / 180, rel=1e-6)
    assert pixels_per_degree(0.5, 1920, 0.6) == pytest.approx(0.5 * 1920 / 0.6 * math.pi / 180, rel=1e-6)
    _, _, used = reference_flip(np.zeros((2, 2, 3)), np.ones((2, 2, 3)), vc=[0.5, 1920.0, 0.6])
    assert pixels_per_degree(0.5, 1920, 0.6) == used["ppd"]
    default = flip_module._filters(DEFAULT_PPD)
    assert default["radius"] == 10 and default["feature_radius"] == 9
    for bad in (0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="^distance: expected a (finite )?number"):
            pixels_per_degree(bad)
    with pytest.raises(TypeError, match="^distance: expected a number, got str '1'$"):
        pixels_per_degree("1")


def test_srgb_option_is_flip_evaluators(hdr_pair):
    test, reference = hdr_pair
    display = [np.clip(a / 4, 0, 1) for a in (test, reference)]
    # LDR of linear input (flip-evaluator's inputsRGB=False)
    ours = flip(*display, dynamic_range="ldr", srgb=False)
    m, mean, _ = flip_evaluator.evaluate(display[1], display[0], "LDR", inputsRGB=False, applyMagma=False)
    assert_agrees(ours, np.asarray(m)[..., 0], float(mean))
    # HDR of sRGB-encoded input: decoded first, exposures from the decoded reference (its C++ API); the
    # two sRGB decodings (float32 powers) may differ in the last bit, and so may the exposures
    ours = flip(*display, srgb=True)
    m, mean, used = flip_evaluator.nbflip.evaluate(display[1], display[0], True, True, False, True, {})
    assert_agrees(ours, np.asarray(m)[..., 0], float(mean), used, exposures_ulp=2)


# --------------------------------------------------------------------- exposures, constants
def test_exposure_range_is_flip_evaluators():
    rng = np.random.default_rng(11)
    cases = [rng.random((9, 11, 3), dtype=np.float32) * 5,                 # odd count: the middle value
             rng.random((8, 8, 3), dtype=np.float32) ** 4,                   # even count: the upper middle
             np.where(rng.random((8, 8, 1)) < 0.6, 0, 3).astype(np.float32) * np.ones(3, np.float32),  # mostly black
             np.full((4, 4, 3), 0.5, np.float32)]                            # constant: start = stop
    for reference in cases:
        _, _, used = reference_flip(reference * 0.9, reference)
        assert hdr_exposure_range(reference) == (np.float32(used["startExposure"]), np.float32(used["stopExposure"]))
    # mostly black: the median is float32's epsilon, the stop log2(x_max / eps)
    start, stop = hdr_exposure_range(cases[2])
    assert stop == pytest.approx(math.log2(tonemapper_x_max() / np.finfo(np.float32).eps), abs=1e-5)
    # a black reference has no range (flip-evaluator exits the process; flip raises)
    assert hdr_exposure_range(np.zeros((3, 3, 3)))[0] == math.inf
    with pytest.raises(ValueError, match="exposure range is empty .*pass start_exposure and stop_exposure"):
        flip(np.ones((3, 3, 3)), np.zeros((3, 3, 3)))
    with pytest.raises(ValueError, match="exposure range is empty"):
        flip(np.ones((3, 3, 3)), np.full((3, 3, 3), 1e-7))
    assert flip(np.ones((3, 3, 3)), np.zeros((3, 3, 3)), start_exposure=0.0, stop_exposure=0.0).mean > 0


def test_tone_mapper_x_max_is_where_the_curve_reaches_085():
    for name, (c0, c1, c2, c3, c4, c5) in TONEMAPPERS.items():
        x = tonemapper_x_max(name)
        assert (c0 * x * x + c1 * x + c2) / (c3 * x * x + c4 * x + c5) == pytest.approx(0.85, rel=1e-5)
    # ACES: Narkowicz's fit at 0.6 x (the pre-exposure the coefficients cancel)
    x = 0.6 * tonemapper_x_max("aces")
    assert x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14) == pytest.approx(0.85, rel=1e-5)


# ---------------------------------------------------------------- an independent colour check
D65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]


def _hunt_lab(srgb):
    """colour-science: sRGB -> XYZ -> CIELab (D65), then the Hunt adjustment a, b x 0.01 L."""
    L, a, b = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(np.asarray(srgb, float), apply_cctf_decoding=True), D65)
    return np.array([L, 0.01 * L * a, 0.01 * L * b])


def _hyab(p, q):
    return abs(p[0] - q[0]) + math.hypot(p[1] - q[1], p[2] - q[2])


@pytest.mark.parametrize("pair", [((0.2, 0.3, 0.4), (0.25, 0.3, 0.4)), ((0, 0, 0), (1, 1, 1)),
                                  ((0.5, 0.5, 0.5), (0.5, 0.2, 0.5)), ((1, 0, 0), (0, 0, 1)),
                                  ((0.8, 0.7, 0.1), (0.8, 0.7, 0.1))])
def test_constant_images_give_the_remapped_hunt_hyab_distance(pair):
    """No edges or points in constant images: FLIP is the colour error alone, everywhere (Andersson et al.
    2020, eq. 5-6: HyAB^qc, mapped linearly to [0, pt] below pc cmax and to [pt, 1] above)."""
    qc, pc, pt = FLIP_CONSTANTS["qc"], FLIP_CONSTANTS["pc"], FLIP_CONSTANTS["pt"]
    cmax = _hyab(_hunt_lab((0, 1, 0)), _hunt_lab((0, 0, 1))) ** qc
    d = _hyab(_hunt_lab(pair[1]), _hunt_lab(pair[0])) ** qc
    expected = pt * d / (pc * cmax) if d < pc * cmax else pt + (d - pc * cmax) / (cmax - pc * cmax) * (1 - pt)
    reference, test = (np.full((6, 9, 3), c, np.float32) for c in pair)
    result = np.asarray(flip(test, reference, dynamic_range="ldr").map)
    np.testing.assert_allclose(result, expected, atol=1e-4)


# ------------------------------------------------------------------------------- the edges
def test_identical_images_give_zero_everywhere(hdr_pair):
    _, reference = hdr_pair
    for mode in ("hdr", "ldr"):
        result = flip(reference, reference, dynamic_range=mode)
        assert result.mean == 0 and not np.asarray(result.map).any()


@pytest.mark.parametrize("shape", [(1, 1, 3), (1, 17, 3), (13, 1, 3), (2, 3, 3)])
def test_tiny_images_are_flip_evaluators(shape):
    """Every filter tap reads the nearest edge pixel, so a pixel or a strip is a well-defined image."""
    rng = np.random.default_rng(sum(shape))
    reference = rng.random(shape, dtype=np.float32) * 2
    test = rng.random(shape, dtype=np.float32) * 2
    assert_agrees(flip(test, reference), *reference_flip(test, reference))
    assert_agrees(flip(test / 2, reference / 2, dynamic_range="ldr"), *reference_flip(test / 2, reference / 2, "LDR"))


def test_huge_values_are_flip_evaluators():
    """1e30 overflows float32 in the tone mapper (inf / inf) and becomes 0 in both, without NaN."""
    reference = np.full((8, 8, 3), 0.3, np.float32)
    reference[2, 3] = 4.0
    test = reference.copy()
    test[5, 5] = 1e30
    test[1, 1] = 3e38
    result = flip(test, reference)
    assert np.all(np.isfinite(np.asarray(result.map)))
    assert_agrees(result, *reference_flip(test, reference), mean_drift=P99_DRIFT)  # a few pixels: see above


def test_refuses_bad_input():
    good = np.ones((4, 5, 3), np.float32)
    cases = [
        (dict(image=np.ones((4, 6, 3))), "^image: expected the reference's shape \\(4, 5\\), got \\(4, 6\\)$"),
        (dict(image=np.ones((4, 5, 4))), "^image: expected 1 or 3 channels, got 4$"),
        (dict(reference=np.ones(5)), "^reference: expected an image of shape"),
        (dict(image=np.zeros((0, 5, 3))), "^image: expected a non-empty image"),
        (dict(image=np.full((4, 5, 3), np.nan)), "^image: expected finite values"),
        (dict(reference=np.full((4, 5, 3), np.inf)), "^reference: expected finite values"),
        (dict(image=-good), "^image: expected linear values >= 0 for HDR-FLIP"),
        (dict(dynamic_range="sdr"), "^dynamic_range: expected 'hdr' or 'ldr', got 'sdr'$"),
        (dict(tonemapper="filmic"), "^tonemapper: expected one of 'reinhard', 'aces', 'hable', got 'filmic'$"),
        (dict(ppd=0.0), "^ppd: expected a number > 0, got 0$"),
        (dict(ppd=math.nan), "^ppd: expected a finite number"),
        (dict(start_exposure=math.inf), "^start_exposure: expected a finite number"),
        (dict(num_exposures=0), "^num_exposures: expected an integer >= 1, got 0$"),
        (dict(start_exposure=3.0, stop_exposure=1.0), "^start_exposure: HDR-FLIP's exposure range is empty"),
    ]
    for change, message in cases:
        arguments = dict(image=good, reference=good, **{k: v for k, v in change.items()
                                                         if k not in ("image", "reference")})
        arguments.update({k: v for k, v in change.items() if k in ("image", "reference")})
        with pytest.raises(ValueError, match=message):
            flip(arguments.pop("image"), arguments.pop("reference"), **arguments)
    with pytest.raises(TypeError, match="^srgb: expected True or False, got str 'yes'$"):
        flip(good, good, srgb="yes")
    with pytest.raises(TypeError, match="^stop_exposure: expected a number, got str '2'$"):
        flip(good, good, stop_exposure="2")
    with pytest.raises(TypeError, match="^num_exposures: expected an integer, got float 2.5$"):
        flip(good, good, num_exposures=2.5)
    with pytest.raises(TypeError, match="^image: expected an array-like image|^image: expected a numeric array"):
        flip(object(), good)
    # LDR accepts negative and above-one values: clamped after sRGB decoding, as flip-evaluator does
    out_of_range = good * np.float32(1.5) - np.float32(0.75)
    assert_agrees(flip(out_of_range, good / 2, dynamic_range="ldr"),
                  *reference_flip(out_of_range, good / 2, "LDR"))


def test_drjit_tensors_and_numpy_give_the_same_map(hdr_pair):
    test, reference = hdr_pair
    from_numpy = flip(test, reference)
    from_drjit = flip(TensorXf(test) * 1.0, TensorXf(reference))     # a lazy tensor too
    np.testing.assert_array_equal(np.asarray(from_numpy.map), np.asarray(from_drjit.map))
    assert isinstance(from_numpy.map, TensorXf) and from_numpy.map.shape == test.shape[:2]


def test_batches_of_exposures_give_the_same_map(hdr_pair, monkeypatch):
    """Exposures are evaluated in batches that bound the memory: any split gives the same map."""
    test, reference = hdr_pair
    whole = flip(test, reference, start_exposure=-3.0, stop_exposure=4.0)
    assert whole.exposures[2] == 7
    frame = flip_module._Frame(*reference.shape[:2], 10)
    monkeypatch.setattr(flip_module, "_BATCH_LANES", 3 * frame.P)        # batches of 3, 3 and 1 exposures
    split = flip(test, reference, start_exposure=-3.0, stop_exposure=4.0)
    np.testing.assert_array_equal(np.asarray(whole.map), np.asarray(split.map))


def test_kernels_do_not_depend_on_the_image_size_or_the_exposures():
    """Sizes, exposure scales and batch counts are opaque or data: after a first call, another size
    and other exposures launch only kernels already compiled in this process."""
    rng = np.random.default_rng(3)
    pairs = [(rng.random((h, w, 3), dtype=np.float32) * 3, rng.random((h, w, 3), dtype=np.float32) * 3)
             for h, w in ((20, 30), (41, 17))]
    flip(*pairs[0])
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        flip(*pairs[1], start_exposure=-1.0, stop_exposure=2.5)
        kernels = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert len(kernels) >= 3 and all(k["cache_hit"] for k in kernels)


# ------------------------------------------------------------------------------- properties
SETTINGS = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _pairs(high):
    shapes = st.tuples(st.integers(1, 7), st.integers(1, 7), st.just(3))
    return shapes.flatmap(lambda shape: st.tuples(*(hnp.arrays(np.float32, shape, elements=st.floats(
        0, high, width=32)) for _ in range(2))))


@SETTINGS
@given(pair=_pairs(1.0))
def test_ldr_flip_property_symmetric_bounded_and_flip_evaluators(pair):
    a, b = pair
    forward, backward = flip(a, b, dynamic_range="ldr"), flip(b, a, dynamic_range="ldr")
    m = np.asarray(forward.map)
    assert m.shape == a.shape[:2] and np.all((m >= 0) & (m <= 1))
    np.testing.assert_array_equal(m, np.asarray(backward.map))      # LDR-FLIP is symmetric
    # an image of a few pixels has a mean of a few pixels: its drift bound is the per-pixel one (found:
    # black against grey 0.4375, one pixel, 3.0e-6 apart: the sRGB decoding's float32 power)
    assert_agrees(forward, *reference_flip(a, b, "LDR"), mean_drift=P99_DRIFT)


@SETTINGS
@given(pair=_pairs(50.0))
def test_hdr_flip_property_bounded_and_flip_evaluators(pair):
    test, reference = pair
    if reference.max() < 1e-3:          # no exposure range (flip-evaluator would exit)
        reference = reference + np.float32(0.5)
    result = flip(test, reference)
    m = np.asarray(result.map)
    assert np.all((m >= 0) & (m <= 1))
    if np.array_equal(test, reference):
        assert result.mean == 0
    assert_agrees(result, *reference_flip(test, reference), mean_drift=P99_DRIFT)  # a few pixels: see above
