"""Tests of imaging.dither (docs/conventions.md, "Dithering and halftoning") and the ``post --dither`` step.

The heart: the parallel error diffusion must equal, bit for bit, a straightforward sequential
float64 scan written here (``reference_diffuse``), for every kernel, raster and serpentine. The
reference uses the published error-diffusion tables written out below (``PUBLISHED``), never the
module's own ``KERNELS``, and multi-level thresholds computed here from the conventions' rule.
"""

from __future__ import annotations

import math
import subprocess
import sys
import zlib

import numpy as np
import pytest

import pointillist.imaging.dither as dither
import pointillist.imaging.dither._shared as shared
import pointillist.imaging.wavefront as wavefront
import pointillist.imaging.filters
from pointillist.imaging.dither import (KERNELS, TEMPLATE_4, bayer, blue_noise, blue_noise_mask, clustered_dot, diffuse,
                            dither_error, error_diffusion, floyd_steinberg, halftone, ordered, pattern)


# ----------------------------------------------------------------------------------------------
# the published error-diffusion tables, written out as printed (the current pixel is ``X`` in
# the middle column of the first row; entries left of and at X are 0; weights are / divisor)

X = 0
PUBLISHED = {
    # R. W. Floyd & L. Steinberg, "An adaptive algorithm for spatial greyscale", Proc. SID 17(2),
    # 75-77, 1976 (and docs/conventions.md).
    "floyd_steinberg": (16, [[0, X, 7],
                             [3, 5, 1]]),
    # J. F. Jarvis, C. N. Judice & W. H. Ninke, "A survey of techniques for the display of
    # continuous tone pictures on bilevel displays", Comput. Graph. Image Process. 5(1), 13-40, 1976.
    "jarvis_judice_ninke": (48, [[0, 0, X, 7, 5],
                                 [3, 5, 7, 5, 3],
                                 [1, 3, 5, 3, 1]]),
    # P. Stucki, "MECCA - a multiple-error correction computation algorithm for bi-level image
    # hardcopy reproduction", IBM Research Report RZ1060, 1981.
    "stucki": (42, [[0, 0, X, 8, 4],
                    [2, 4, 8, 4, 2],
                    [1, 2, 4, 2, 1]]),
    # D. Burkes, "Presentation of the Burkes error filter ...", CIS Graphics Support Forum, 1988
    # (as reprinted in L. Crocker et al., "DHALF.TXT", 1991).
    "burkes": (32, [[0, 0, X, 8, 4],
                    [2, 4, 8, 4, 2]]),
    # F. Sierra, three-row filter, CIS Graphics Support Forum, 1989 (DHALF.TXT: "Sierra").
    "sierra": (32, [[0, 0, X, 5, 3],
                    [2, 4, 5, 4, 2],
                    [0, 2, 3, 2, 0]]),
    # F. Sierra, "Filter Lite", 1990 (DHALF.TXT: "Sierra-2-4A").
    "sierra_lite": (4, [[0, X, 2],
                        [1, 1, 0]]),
    # B. Atkinson, Apple MacPaint / HyperCard, 1984: 1/8 to six neighbours (6/8 of the error).
    "atkinson": (8, [[0, 0, X, 1, 1],
                     [0, 1, 1, 1, 0],
                     [0, 0, 1, 0, 0]]),
}


def published_weights(name):
    """(dy, dx, weight) of a written-out table, for a left-to-right scan."""
    divisor, rows = PUBLISHED[name]
    centre = len(rows[0]) // 2
    return [(dy, dx - centre, n / divisor) for dy, row in enumerate(rows) for dx, n in enumerate(row) if n]


def independent_tables(levels, level=128.0, linear=False):
    """(thresholds, working values, output values) of the conventions' multi-level rule, from scratch.

    Output level k is k 255 / (levels - 1); in the working space (display, or linear light via the
    IEC 61966-2-1 sRGB decoding written out here) the threshold between levels k - 1 and k lies at
    the fraction level / 255 of the gap; 1-bit dithering thresholds at ``level`` itself.
    """
    shown = np.array([k * 255.0 / (levels - 1) for k in range(levels)])
    if linear:
        c = shown / 255.0
        work = 255.0 * np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        work[0], work[-1] = 0.0, 255.0
    else:
        work = shown.copy()
    if levels == 2:
        return np.array([level]), work, shown
    return np.array([work[k - 1] + (work[k] - work[k - 1]) * level / 255.0 for k in range(1, levels)]), work, shown


# ----------------------------------------------------------------------------------------------
# sequential references (float64, one pixel at a time, as in the textbook)


def prepare(image):
    """The documented input mapping: NaN -> 0, clip to 0..255, float32 -> float64."""
    image = np.asarray(image, dtype=np.float32)
    image = np.where(np.isnan(image), np.float32(0), image)
    return np.clip(image, 0, 255).astype(np.float64)


def quantise(v, thresholds, work, display):
    k = int(np.searchsorted(thresholds, v, side="right"))  # number of thresholds <= v
    return work[k], display[k]


def reference_diffuse(image, weights, *, serpentine=False, tables=None, level=128.0):
    """Sequential error diffusion of a (H, W) float64 image; weights (dy, dx, w) for a L->R scan."""
    H, W = image.shape
    if tables is None:
        tables = (np.array([level]), np.array([0.0, 255.0]), np.array([0.0, 255.0]))
    buf = image.astype(np.float64).copy()
    out = np.zeros((H, W), dtype=np.float32)
    for y in range(H):
        d = -1 if (serpentine and y % 2) else 1
        for X in (range(W) if d == 1 else range(W - 1, -1, -1)):
            v = buf[y, X]
            q, shown = quantise(v, *tables)
            out[y, X] = shown
            e = v - q
            for dy, dx, w in weights:
                ty, tx = y + dy, X + d * dx
                if 0 <= ty < H and 0 <= tx < W:  # error leaving the image is dropped
                    buf[ty, tx] += e * w
    return out


def reference_simple(image, level=128.0):
    """The conventions' simple error diffusion: 100 % of the error to the next pixel of the serpentine scan."""
    H, W = image.shape
    out = np.zeros((H, W), dtype=np.float32)
    carried = 0.0
    for y in range(H):
        for X in (range(W) if y % 2 == 0 else range(W - 1, -1, -1)):
            v = image[y, X] + carried
            out[y, X] = 255.0 if v >= level else 0.0
            carried = v - out[y, X]
    return out


def weights_of(name):
    return published_weights(name)


def random_image(rng, shape, spread=False):
    image = rng.random(shape) * 255
    if spread:  # out-of-range values, exact integers and the threshold itself
        image = rng.choice([-40.0, 0.0, 127.0, 128.0, 255.0, 300.0], size=shape) * (rng.random(shape) < 0.2) \
            + image * (rng.random(shape) >= 0.2)
    return image.astype(np.float32)


SIZES = [(1, 1), (1, 13), (13, 1), (2, 2), (7, 5), (19, 33)]


# ----------------------------------------------------------------------------------------------
# bit-exactness of the parallel schedule


@pytest.mark.parametrize("name", list(KERNELS))
@pytest.mark.parametrize("serpentine", [False, True])
def test_diffuse_matches_sequential_reference(name, serpentine):
    rng = np.random.default_rng(zlib.crc32(f"{name}:{serpentine}".encode()))
    for shape in SIZES + [(41, 70)]:
        image = random_image(rng, shape, spread=shape[0] > 5)
        expected = reference_diffuse(prepare(image), weights_of(name), serpentine=serpentine)
        got = np.asarray(diffuse(image, name, serpentine=serpentine))
        assert got.dtype == np.float32 and got.shape == shape
        assert np.array_equal(got, expected), f"{name} serpentine={serpentine} {shape}: " \
                                              f"{int((got != expected).sum())} pixels differ"


def test_floyd_steinberg_large_image_matches_reference():
    rng = np.random.default_rng(7)
    image = (rng.random((96, 160)) * 255).astype(np.float32)
    expected = reference_diffuse(prepare(image), weights_of("floyd_steinberg"))
    assert np.array_equal(np.asarray(floyd_steinberg(image)), expected)


@pytest.mark.parametrize("lanes", [1, 2, 4, 8])
def test_result_does_not_depend_on_packet_width(monkeypatch, lanes):
    rng = np.random.default_rng(lanes)
    image = (rng.random((37, 29)) * 255).astype(np.float32)
    monkeypatch.setattr(wavefront, "verified_lanes", lambda: lanes)
    for name in ("floyd_steinberg", "jarvis_judice_ninke"):
        expected = reference_diffuse(prepare(image), weights_of(name))
        assert np.array_equal(np.asarray(diffuse(image, name)), expected)


BLOCKED_SIZES = [(1, 8), (2, 16), (15, 8), (17, 24), (33, 64), (40, 40)]


@pytest.mark.parametrize("name", list(KERNELS))
def test_blocked_schedule_matches_sequential_reference(name):
    # widths that are whole blocks of 8 take the blocked schedule (packets of 8 columns per lane)
    rng = np.random.default_rng(zlib.crc32(f"blocked:{name}".encode()))
    for shape in BLOCKED_SIZES:
        image = random_image(rng, shape, spread=shape[0] > 5)
        expected = reference_diffuse(prepare(image), weights_of(name))
        assert wavefront.blocked(shape[1], 1, False, False, wavefront.verified_lanes()) == \
            (wavefront.verified_lanes() > 1)
        got = np.asarray(diffuse(image, name))
        assert np.array_equal(got, expected), f"{name} {shape}: {int((got != expected).sum())} pixels differ"
        eight = np.clip(image, 0, 255).astype(np.uint8)
        got8 = np.asarray(diffuse(eight, name))
        assert got8.dtype == np.uint8
        assert np.array_equal(got8, reference_diffuse(prepare(eight), weights_of(name)).astype(np.uint8))


@pytest.mark.parametrize("lanes", [2, 4, 8])
def test_blocked_schedule_does_not_depend_on_packet_width(monkeypatch, lanes):
    rng = np.random.default_rng(100 + lanes)
    image = (rng.random((3 * lanes + 5, 48)) * 255).astype(np.float32)
    monkeypatch.setattr(wavefront, "verified_lanes", lambda: lanes)
    for name in ("floyd_steinberg", "jarvis_judice_ninke", "atkinson"):
        expected = reference_diffuse(prepare(image), weights_of(name))
        assert np.array_equal(np.asarray(diffuse(image, name)), expected)


@pytest.mark.parametrize("levels", [3, 256])
def test_blocked_schedule_levels_and_linear_light(levels):
    rng = np.random.default_rng(levels + 7)
    image = random_image(rng, (21, 32), spread=True)
    expected = reference_diffuse(prepare(image), weights_of("stucki"), tables=independent_tables(levels))
    assert np.array_equal(np.asarray(diffuse(image, "stucki", levels=levels)), expected)
    linear = np.asarray(floyd_steinberg(image, levels=levels, linear=True))
    from drjit.llvm import Float

    decoded = np.asarray(shared._srgb_decode_255(Float(prepare(image).astype(np.float32).ravel()))).reshape(image.shape)
    expected = reference_diffuse(decoded.astype(np.float64), weights_of("floyd_steinberg"),
                                 tables=independent_tables(levels, linear=True))
    assert np.array_equal(linear, expected)


def test_blocked_schedule_reads_non_finite_and_unaligned_input():
    # NaN -> 0 and the clip happen as the blocked loop reads float input; uint8 bytes that do not
    # start on a 16-byte boundary (no packet load) are widened first: same levels either way
    image = np.full((18, 32), 100.0, np.float32)
    image[3, 5], image[7, 9], image[11, 30] = np.nan, np.inf, -np.inf
    expected = reference_diffuse(prepare(image), weights_of("floyd_steinberg"))
    assert np.array_equal(np.asarray(floyd_steinberg(image)), expected)
    rng = np.random.default_rng(4)
    storage = rng.integers(0, 256, 18 * 32 + 1, dtype=np.uint8)
    shifted = storage[1:].reshape(18, 32)
    assert shifted.ctypes.data % 16 != 0 or storage.ctypes.data % 16 != 0
    for bytes_ in (shifted, np.ascontiguousarray(shifted)):
        assert np.array_equal(np.asarray(floyd_steinberg(bytes_)),
                              reference_diffuse(prepare(shifted), weights_of("floyd_steinberg")).astype(np.uint8))


def test_blocked_and_column_schedules_agree_on_real_and_noisy_images():
    # the old one-column schedule (blocks=False) and the blocked one, bit for bit, on scikit-image's
    # camera (512 x 512, 8-bit) and on a noisy gradient, 8-bit and float, Floyd-Steinberg and Stucki
    from drjit.llvm.ad import Float, UInt8
    from skimage import data

    camera = data.camera()
    rng = np.random.default_rng(12)
    noisy = np.clip(np.linspace(0, 255, 256)[None, :] + rng.normal(0, 30, (96, 256)), 0, 255)
    tables = shared._quantiser(2, 128.0, False)
    for image in (camera, noisy.astype(np.uint8), noisy.astype(np.float32)):
        height, width = image.shape
        flat = UInt8(image.reshape(-1)) if image.dtype == np.uint8 else Float(image.reshape(-1))
        for name in ("floyd_steinberg", "stucki"):
            kernel = tuple((dy, dx, n / KERNELS[name].divisor) for dy, dx, n in KERNELS[name].weights)
            runs = [wavefront.diffuse_wavefront(flat, height, width, 1, kernel, False, tables,
                                                eight_bit=image.dtype == np.uint8, blocks=blocks).numpy()
                    for blocks in (True, False)]
            assert np.array_equal(*runs), name
    with pytest.raises(ValueError, match="blocks: the blocked schedule needs"):
        wavefront.diffuse_wavefront(Float(np.zeros(7 * 9, np.float32)), 7, 9, 1, kernel, False, tables, blocks=True)


def test_overestimated_packet_width_is_caught_and_halved(monkeypatch):
    # The lane count comes from CPU flags; if it exceeds Dr.Jit's real SIMD packet, the one-time
    # check against the one-lane schedule must catch it and fall back to a width that is exact.
    monkeypatch.setattr(wavefront, "packet_width", lambda: 64)
    monkeypatch.delenv("POINTILLIST_DITHER_LANES", raising=False)
    wavefront.verified_lanes.cache_clear()
    try:
        with pytest.warns(RuntimeWarning, match="narrower than the 64 lanes"):
            lanes = wavefront.verified_lanes()
        assert 1 <= lanes < 64
        rng = np.random.default_rng(5)
        image = (rng.random((2 * lanes + 5, 23)) * 255).astype(np.float32)
        expected = reference_diffuse(prepare(image), weights_of("floyd_steinberg"))
        assert np.array_equal(np.asarray(diffuse(image, "floyd_steinberg")), expected)
    finally:
        wavefront.verified_lanes.cache_clear()


def test_error_diffusion_matches_reference():
    rng = np.random.default_rng(11)
    for shape in SIZES + [(30, 17)]:
        image = random_image(rng, shape, spread=True)
        assert np.array_equal(np.asarray(error_diffusion(image)), reference_simple(prepare(image)))


@pytest.mark.parametrize("levels", [3, 4, 7, 256])
def test_levels_match_reference(levels):
    rng = np.random.default_rng(levels)
    image = random_image(rng, (23, 31), spread=True)
    tables = independent_tables(levels)
    for name in ("floyd_steinberg", "stucki"):
        expected = reference_diffuse(prepare(image), weights_of(name), tables=tables)
        got = np.asarray(diffuse(image, name, levels=levels))
        assert np.array_equal(got, expected)
        allowed = np.float32(np.arange(levels) * 255.0 / (levels - 1))
        assert np.isin(got, allowed).all()


def test_levels_256_keeps_integer_images():
    image = np.arange(256, dtype=np.float32).reshape(16, 16)
    assert np.array_equal(np.asarray(floyd_steinberg(image, levels=256)), image)


def test_linear_light_matches_reference_on_decoded_input():
    from pointillist.imaging.colour import srgb_decode

    rng = np.random.default_rng(5)
    image = random_image(rng, (17, 23))
    from drjit.llvm import Float

    decoded = np.asarray(shared._srgb_decode_255(Float(prepare(image).astype(np.float32).ravel()))).reshape(image.shape)
    np.testing.assert_allclose(decoded, np.asarray(srgb_decode(prepare(image) / 255.0)) * 255.0, rtol=1e-5, atol=1e-4)
    for levels in (2, 5):
        tables = independent_tables(levels, linear=True)
        expected = reference_diffuse(decoded.astype(np.float64), weights_of("floyd_steinberg"), tables=tables)
        assert np.array_equal(np.asarray(floyd_steinberg(image, levels=levels, linear=True)), expected)


def test_linear_light_preserves_mean_linear_light():
    from pointillist.imaging.colour import srgb_decode

    image = np.full((64, 64), 128.0, dtype=np.float32)  # 21.6 % linear light
    display = np.asarray(floyd_steinberg(image)).mean() / 255
    linear = np.asarray(floyd_steinberg(image, linear=True)).mean() / 255
    target = float(np.asarray(srgb_decode(np.array([[128 / 255.0]])))[0, 0])
    assert abs(display - 128 / 255) < 0.01
    assert abs(linear - target) < 0.01


def test_colour_is_per_channel():
    rng = np.random.default_rng(2)
    image = (rng.random((21, 18, 3)) * 255).astype(np.float32)
    got = np.asarray(floyd_steinberg(image))
    for c in range(3):
        assert np.array_equal(got[..., c], np.asarray(floyd_steinberg(np.ascontiguousarray(image[..., c]))))
    got = np.asarray(error_diffusion(image))
    for c in range(3):
        assert np.array_equal(got[..., c], reference_simple(prepare(image[..., c])))


# ----------------------------------------------------------------------------------------------
# hand-worked cases from the conventions' definitions


def test_threshold_is_the_filters_function():
    assert dither.threshold is pointillist.imaging.filters.threshold
    assert np.asarray(dither.threshold(np.array([[127.99, 128.0]]))).tolist() == [[0.0, 255.0]]


def test_floyd_steinberg_by_hand():
    # (0,0) 100 -> 0, error 100: right 143.75, below 131.25, below-right 106.25.
    # (0,1) 143.75 -> 255, error -111.25: below-left += -20.859375, below += -34.765625.
    # (1,0) 110.390625 -> 0, error 110.390625: right += 48.2958984375.
    # (1,1) 100 + 6.25 - 34.765625 + 48.2958984375 = 119.78... -> 0.
    assert np.asarray(floyd_steinberg(np.full((2, 2), 100.0))).tolist() == [[0.0, 255.0], [0.0, 0.0]]
    # Serpentine: row 1 runs right to left. (1,1) gets 100 + 6.25 - 34.765625 = 71.48 -> 0, error
    # 71.484375 goes 7/16 left: (1,0) = 100 + 31.25 - 20.859375 + 31.2744140625 = 141.67 -> 255.
    assert np.asarray(floyd_steinberg(np.full((2, 2), 100.0), serpentine=True)).tolist() == [[0.0, 255.0],
                                                                                             [255.0, 0.0]]
    # The threshold rule: exactly 128 goes up.
    assert np.asarray(floyd_steinberg(np.array([[128.0, 0.0]]))).tolist() == [[255.0, 0.0]]


def test_error_diffusion_by_hand():
    # 100 -> 0 (e 100); 200 -> 255 (e -55); next is the pixel below (serpentine): 45 -> 0 (e 45);
    # then 145 -> 255.
    assert np.asarray(error_diffusion(np.full((2, 2), 100.0))).tolist() == [[0.0, 255.0], [255.0, 0.0]]


def test_kernels_are_the_published_tables():
    assert set(KERNELS) == set(PUBLISHED)  # a new kernel needs its published table here
    for name, kernel in KERNELS.items():
        got = sorted((dy, dx, n / kernel.divisor) for dy, dx, n in kernel.weights)
        assert got == sorted(published_weights(name)), name


@pytest.mark.parametrize("levels", [3, 4, 5])
def test_multilevel_thresholds_by_hand(levels):
    # levels=3: outputs 0, 127.5, 255; thresholds at 128/255 of each gap: 64.0 and 191.5.
    # A value just below / at a threshold goes down / up (">=" goes up), no error diffusion on
    # a 1 x 1 image.
    thresholds, _, shown = independent_tables(levels)
    if levels == 3:
        assert thresholds.tolist() == [64.0, 191.5] and shown.tolist() == [0.0, 127.5, 255.0]
    for k, t in enumerate(thresholds):
        below = np.asarray(floyd_steinberg(np.array([[np.nextafter(np.float32(t), -np.inf)]]), levels=levels))
        assert below.tolist() == [[np.float32(shown[k])]], (levels, k, t)
        if float(np.float32(t)) == t:  # the threshold itself is representable: it goes up
            assert np.asarray(floyd_steinberg(np.array([[t]], np.float32), levels=levels)).tolist() \
                == [[np.float32(shown[k + 1])]]


def test_kernels_sum_and_atkinson_drops_a_quarter():
    for name, kernel in KERNELS.items():
        total = sum(n for _, _, n in kernel.weights)
        assert total == (6 if name == "atkinson" else kernel.divisor), name
        assert all(dy > 0 or dx > 0 for dy, dx, _ in kernel.weights), name  # only forward


def test_ordered_by_hand():
    # I = 128: p = floor(128 / 255 * 17) = 8: white where the template number <= 8.
    got = np.asarray(ordered(np.full((4, 4), 128.0)))
    assert np.array_equal(got, np.where(TEMPLATE_4 <= 8, 255.0, 0.0))
    # Tiled: (y, x) uses TEMPLATE_4[y % 4, x % 4]; I = 16: p = 1, only the 1s.
    got = np.asarray(ordered(np.full((5, 6), 16.0)))
    assert np.array_equal(np.argwhere(got == 255).tolist(), [[0, 0], [0, 4], [4, 0], [4, 4]])


def test_ordered_matches_integer_formula_and_opencv():
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (37, 45)).astype(np.uint8)
    for template in (TEMPLATE_4, bayer(8), blue_noise_mask()):
        n = template.shape[0]
        tiled = np.tile(template, (-(-37 // n), -(-45 // n)))[:37, :45]
        p = np.minimum(image.astype(np.int64) * (n * n + 1) // 255, n * n)  # exact integer floor
        expected = np.where(p >= tiled, 255.0, 0.0)
        got = np.asarray(ordered(image, template))
        assert np.array_equal(got, expected)
        # OpenCV: compare p against the pre-tiled threshold map.
        assert np.array_equal(cv2.compare(p.astype(np.float32), tiled.astype(np.float32), cv2.CMP_GE) > 0, got > 0)


def test_pattern_by_hand():
    # 2x2 template [[1,3],[4,2]] (n^2 + 1 = 5 levels). Block mean 127.5: p = floor(0.5 * 5) = 2.
    image = np.array([[0.0, 255.0, 255.0, 255.0], [0.0, 255.0, 255.0, 255.0]])
    got = np.asarray(pattern(image, bayer(2))).astype(int).tolist()
    assert got == [[255, 0, 255, 255], [0, 255, 255, 255]]
    # A block cut by the edge averages what it has: one column of 200 -> p = floor(200/255*5) = 3.
    got = np.asarray(pattern(np.full((2, 1), 200.0), bayer(2))).astype(int).tolist()
    assert got == [[255], [0]]


def test_halftone_by_hand_and_growth_sequence():
    # I = 128, n = 2: p = floor(128 / 255 * 5) = 2; clustered_dot(2) = [[3, 4], [2, 1]].
    assert np.asarray(halftone(np.array([[128.0]]), 2)).astype(int).tolist() == [[0, 0], [255, 255]]
    for n in (1, 2, 3, 4, 5):
        levels = n * n + 1
        values = np.array([[min(255.0, math.ceil(255 * p / levels))] for p in range(levels)], dtype=np.float32)
        out = np.asarray(halftone(values.T, n)) > 0  # shape (n, levels * n)
        patterns = [out[:, p * n:(p + 1) * n] for p in range(levels)]
        for p in range(levels):
            assert patterns[p].sum() == p, (n, p)  # n^2 + 1 distinct levels
            if p:
                assert np.all(patterns[p] >= patterns[p - 1])  # growth: on stays on


def test_clustered_dot_grows_from_the_centre():
    t = clustered_dot(5)
    assert t[2, 2] == 1 and sorted(t.ravel()) == list(range(1, 26))
    assert {t[0, 0], t[0, 4], t[4, 0], t[4, 4]} == {22, 23, 24, 25}


def test_bayer_recursion_and_template_4():
    assert np.array_equal(bayer(4), TEMPLATE_4)
    assert bayer(1).tolist() == [[1]]
    for n in (1, 2, 4, 8, 16, 32):
        m = bayer(n)
        assert sorted(m.ravel()) == list(range(1, n * n + 1))
        if n > 1:
            h = bayer(n // 2) - 1
            expected = np.block([[4 * h, 4 * h + 2], [4 * h + 3, 4 * h + 1]]) + 1
            assert np.array_equal(m, expected)
    with pytest.raises(ValueError, match="power of two"):
        bayer(6)


def test_blue_noise_mask_is_blue():
    mask = blue_noise_mask()
    assert mask.shape == (64, 64) and sorted(mask.ravel()) == list(range(1, 4097))
    # Half-tone of 50 %: little low-frequency power, much high-frequency power.
    spectrum = np.fft.fftshift(np.abs(np.fft.fft2((mask <= 2048) - 0.5)) ** 2)
    yy, xx = np.mgrid[-32:32, -32:32]
    radius = np.hypot(yy, xx)
    low, high = spectrum[(radius > 0) & (radius < 6)].mean(), spectrum[radius > 20].mean()
    assert low < 0.1 * high
    white = (np.random.default_rng(0).random((64, 64)) < 0.5) - 0.5
    white_spectrum = np.fft.fftshift(np.abs(np.fft.fft2(white)) ** 2)
    assert low < 0.2 * white_spectrum[(radius > 0) & (radius < 6)].mean()
    assert np.array_equal(dither.void_and_cluster(8, seed=3), dither.void_and_cluster(8, seed=3))


def test_dither_error_by_hand():
    error = dither_error([[100.0, 100.0]], [[0.0, 255.0]])
    assert error.total == 55.0 and error.average == 27.5
    with pytest.raises(ValueError, match="shape"):
        dither_error(np.zeros((2, 2)), np.zeros((2, 3)))


# ----------------------------------------------------------------------------------------------
# properties


ALL_METHODS = [
    ("error_diffusion", lambda im: error_diffusion(im)),
    *[(name, lambda im, name=name: diffuse(im, name)) for name in KERNELS],
    ("floyd_steinberg_serpentine", lambda im: floyd_steinberg(im, serpentine=True)),
    ("ordered", lambda im: ordered(im)),
    ("bayer8", lambda im: ordered(im, bayer(8))),
    ("blue_noise", lambda im: blue_noise(im)),
    ("pattern", lambda im: pattern(im)),
]


@pytest.mark.parametrize("name,method", ALL_METHODS)
def test_outputs_are_levels_and_constants_stay(name, method):
    rng = np.random.default_rng(9)
    image = rng.random((24, 40)).astype(np.float32) * 255
    out = np.asarray(method(image))
    assert out.shape == image.shape and np.isin(out, [0.0, 255.0]).all()
    for value in (0.0, 255.0):
        assert np.all(np.asarray(method(np.full((9, 14), value))) == value)


@pytest.mark.parametrize("name", list(KERNELS) + ["error_diffusion"])
def test_mean_tracks_input_mean(name):
    y, x = np.mgrid[0:64, 0:96]
    image = (127.5 + 120 * np.sin(x / 9.0) * np.cos(y / 13.0)).astype(np.float32)
    out = np.asarray(error_diffusion(image) if name == "error_diffusion" else diffuse(image, name))
    # Atkinson drops 1/4 of every error, but on this symmetric pattern the losses of the dark
    # and bright parts nearly cancel (measured: -0.76 grey levels).
    assert abs(out.mean() - image.mean()) < 2.0
    def blocks(a):
        return a.reshape(8, 8, 12, 8).mean(axis=(1, 3))
    assert np.abs(blocks(out) - blocks(image)).mean() < (13 if name == "atkinson" else 8)


def test_agrees_with_pillow_on_real_and_grey_images():
    Image = pytest.importorskip("PIL.Image")
    data = pytest.importorskip("skimage.data")
    # Pillow's convert('1') is a Floyd-Steinberg in integer arithmetic (error / 16 truncated,
    # value clipped to 0..255, threshold > 128): not bit-comparable, but on a real photograph
    # (scikit-image's 512 x 512 "camera") the local grey of both halftones must agree.
    camera = data.camera()
    ours = np.asarray(floyd_steinberg(camera)).astype(np.float64)
    theirs = np.asarray(Image.fromarray(camera).convert("1"), dtype=np.float64) * 255
    def blocks(a):
        return a.reshape(64, 8, 64, 8).mean(axis=(1, 3))
    assert np.abs(blocks(ours) - blocks(theirs)).mean() < 5  # measured 3.6
    assert np.abs(blocks(ours) - blocks(camera)).mean() < 4  # measured 3.0 (Pillow: 2.9)
    assert abs(ours.mean() - theirs.mean()) < 1.0
    for grey in (32, 77, 200):
        image = np.full((64, 64), grey, dtype=np.uint8)
        ours = np.asarray(floyd_steinberg(image)).astype(np.float64)
        theirs = np.asarray(Image.fromarray(image).convert("1"), dtype=np.float64) * 255
        assert abs(ours.mean() - grey) < 1.5 and abs(ours.mean() - theirs.mean()) < 1.5
        assert (ours == theirs).mean() > 0.6  # measured 0.63-0.80: the same pattern mostly


# ----------------------------------------------------------------------------------------------
# stiff and extreme cases


def test_out_of_range_nan_and_infinite_values():
    image = np.array([[np.nan, -50.0, 300.0, np.inf, -np.inf, 1e30]], dtype=np.float32)
    clipped = np.array([[0.0, 0.0, 255.0, 255.0, 0.0, 255.0]])
    for method in (floyd_steinberg, error_diffusion, lambda im: diffuse(im, "stucki", serpentine=True)):
        out = np.asarray(method(image))
        assert np.array_equal(out, np.asarray(method(clipped)))
        assert np.isfinite(out).all()
    assert np.array_equal(np.asarray(ordered(image)), np.asarray(ordered(clipped)))
    assert np.array_equal(np.asarray(halftone(image, 2)), np.asarray(halftone(clipped, 2)))


def test_one_by_one_templates_and_images():
    image = np.array([[0.0, 127.0, 128.0, 255.0]])
    # n = 1: p = min(floor(2 I / 255), 1); white where p >= 1, i.e. I >= 127.5.
    for method in (lambda im: ordered(im, [[1]]), lambda im: pattern(im, [[1]]), lambda im: halftone(im, 1)):
        assert np.asarray(method(image)).tolist() == [[0.0, 0.0, 255.0, 255.0]]
    for value, expected in ((127.0, 0.0), (128.0, 255.0)):
        assert np.asarray(floyd_steinberg(np.array([[value]]))).tolist() == [[expected]]
        assert np.asarray(error_diffusion(np.array([[value]]))).tolist() == [[expected]]


def test_huge_image_memory_stays_linear(tmp_path):
    # 4096 x 4096 float32 input is 64 MiB; the output as much; the error buffer a few rows.
    code = (
        "import resource, numpy as np, drjit as dr\n"
        "import pointillist.imaging.dither as d\n"
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "image = np.full((4096, 4096), 100.0, np.float32)\n"
        "out = d.floyd_steinberg(image); dr.eval(out); dr.sync_thread()\n"
        "assert abs(float(np.asarray(out).mean()) - 100.0) < 0.5\n"
        "print((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) // 1024)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    grown_mib = int(result.stdout.split()[-1])
    assert grown_mib < 5 * 64, grown_mib  # input + output + temporaries, not a float64 copy per pass


def test_bad_arguments():
    image = np.zeros((4, 4))
    with pytest.raises(ValueError, match="kernel"):
        diffuse(image, "nope")
    with pytest.raises(ValueError, match="levels"):
        floyd_steinberg(image, levels=1)
    with pytest.raises(ValueError, match="levels"):
        floyd_steinberg(image, levels=257)
    with pytest.raises(ValueError, match="level"):
        floyd_steinberg(image, level=float("nan"))
    with pytest.raises(TypeError, match="serpentine"):
        floyd_steinberg(image, serpentine="yes")
    with pytest.raises(ValueError, match="permutation"):
        ordered(image, [[1, 1], [2, 3]])
    with pytest.raises(ValueError, match="square"):
        ordered(image, [[1, 2]])
    with pytest.raises(ValueError, match="n:"):
        halftone(image, 0)
    with pytest.raises(ValueError, match="image"):
        floyd_steinberg(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="image"):
        floyd_steinberg(np.zeros(5))


# ----------------------------------------------------------------------------------------------
# the post step


def test_post_step_functions():
    from pointillist.steps import parse_steps

    (spec, kwargs), = parse_steps("dither:floyd_steinberg,levels=4,serpentine=true")
    rng = np.random.default_rng(4)
    image = (rng.random((12, 10)) * 255).astype(np.float32)
    got = np.asarray(spec.function(image, **kwargs))
    assert np.array_equal(got, np.asarray(floyd_steinberg(image, levels=4, serpentine=True)))
    report = spec.report(image, got)
    expected = float(got.astype(np.float64).sum() - image.astype(np.float64).sum())
    assert report["dither error total"] == pytest.approx(expected)
    (spec, kwargs), = parse_steps("dither:bayer,n=8")
    assert np.array_equal(np.asarray(spec.function(image, **kwargs)), np.asarray(ordered(image, bayer(8))))
    (spec, kwargs), = parse_steps("dither:halftone,n=3")
    big = spec.function(image, **kwargs)
    assert tuple(big.shape) == (36, 30)
    average = spec.report(image, big)["dither error average"]
    assert average == pytest.approx(np.asarray(big).mean() - image.mean(), abs=1e-3)
    with pytest.raises(ValueError, match="method"):
        spec.function(image, method="nope")
    with pytest.raises(ValueError, match="options"):
        spec.function(image, method="halftone", levels=3)


def test_dither_entry_dispatches_by_method():
    rng = np.random.default_rng(9)
    image = (rng.random((13, 11, 3)) * 255).astype(np.float32)
    same = [
        (dither.dither(image), floyd_steinberg(image)),
        (dither.dither(image, "stucki", levels=3, serpentine=True),
         diffuse(image, "stucki", levels=3, serpentine=True)),
        (dither.dither(image, "error_diffusion", level=100), error_diffusion(image, 100)),
        (dither.dither(image, "threshold", level=90), dither.threshold(image, 90)),
        (dither.dither(image, "ordered"), ordered(image, TEMPLATE_4)),
        (dither.dither(image, "bayer", n=8, levels=4), ordered(image, bayer(8), levels=4)),
        (dither.dither(image, "pattern", n=2), dither.pattern(image, bayer(2))),
        (dither.dither(image, "blue_noise", linear=True), blue_noise(image, linear=True)),
        (dither.dither(image, "halftone", n=2), dither.halftone(image, 2)),
    ]
    for got, expected in same:
        assert np.array_equal(np.asarray(got), np.asarray(expected))
    assert set(dither.DITHER_METHODS) == {"threshold", "error_diffusion", *KERNELS, "ordered", "bayer", "blue_noise",
                                          "pattern", "halftone"}
    assert dither.dither_options("atkinson") == ("level", "levels", "serpentine", "linear")
    with pytest.raises(ValueError, match="^method: expected one of threshold, error_diffusion, floyd_steinberg"):
        dither.dither(image, "nope")
    with pytest.raises(ValueError, match=r"^levels: not an option of dither method 'halftone' \(its options: n\)$"):
        dither.dither(image, "halftone", levels=3)
    with pytest.raises(ValueError, match=r"^levels: expected an integer in 2\.\.256, got 1$"):
        dither.dither(image, "ordered", levels=1)


def test_post_cli_dither_and_report(cli, tmp_path):
    Image = pytest.importorskip("PIL.Image")
    source = tmp_path / "grey.png"
    y, x = np.mgrid[0:32, 0:48]
    Image.fromarray((x * 5).astype(np.uint8)).save(source)
    out = tmp_path / "fs.png"
    result = cli("post", source, "-o", out, "--dither", "floyd_steinberg:levels=2", "--report")
    assert result.returncode == 0, result.stderr
    assert "dither error total" in result.stdout and "dither error average" in result.stdout
    written = np.asarray(Image.open(out))
    expected = np.asarray(floyd_steinberg((x * 5).astype(np.float32)))
    assert np.array_equal(written.astype(np.float32), expected)
    bad = cli("post", source, "-o", tmp_path / "x.png", "--dither", "nope")
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1


def test_divmod_helper_is_exact():
    from drjit.llvm import UInt32

    from pointillist.imaging.arrays import divmod_u32

    a = np.concatenate([np.arange(0, 50000), np.arange(2**32 - 50000, 2**32)]).astype(np.uint32)
    for divisor in (1, 3, 7, 255, 2048, 2049, 65537, 12345679):
        q, r = divmod_u32(UInt32(a), divisor)
        assert np.array_equal(np.asarray(q), a // divisor) and np.array_equal(np.asarray(r), a % divisor)
    # and the non-power-of-two template path of ordered dithering
    image = np.random.default_rng(1).integers(0, 256, (11, 13)).astype(np.float32)
    template = clustered_dot(3)
    p = np.minimum(image.astype(np.int64) * 10 // 255, 9)
    expected = np.where(p >= np.tile(template, (4, 5))[:11, :13], 255.0, 0.0)
    assert np.array_equal(np.asarray(ordered(image, template)), expected)


# ----------------------------------------------------------------------------------------------
# 8-bit in, 8-bit out


@pytest.mark.parametrize("method", sorted(dither.DITHER_METHODS))
@pytest.mark.parametrize("shape", [(13, 17), (9, 11, 3)])
def test_every_method_uint8_in_uint8_out(method, shape):
    """uint8 (numpy or TensorXu8) in: uint8 out, equal to the float32 result of the same values
    rounded as the 8-bit writers round it; float in: float32 out."""
    import drjit.llvm
    from drjit.llvm.ad import TensorXu8

    from pointillist.imaging.io import to_8bit

    rng = np.random.default_rng(sum(shape) + len(method))
    image = rng.integers(0, 256, shape).astype(np.uint8)
    options = dither.dither_options(method)
    variants = [{}] + ([{"levels": 3}, {"levels": 5}] if "levels" in options else []) \
        + ([{"linear": True}] if "linear" in options else [])
    for kwargs in variants:
        as_float = np.asarray(dither.dither(image.astype(np.float32), method, **kwargs))
        assert as_float.dtype == np.float32
        for source in (image, TensorXu8(image), drjit.llvm.TensorXu8(image)):     # numpy, AD and plain tensors
            result = dither.dither(source, method, **kwargs)
            assert isinstance(result, TensorXu8), (method, kwargs)
            got = np.asarray(result)
            assert got.dtype == np.uint8
            np.testing.assert_array_equal(got, to_8bit(as_float, srgb=False, max_value=255.0), err_msg=method)
    if method == "floyd_steinberg":  # levels=3: 127.5 is a tie, written as 128 (half to even)
        assert set(np.unique(np.asarray(dither.dither(image, method, levels=3)))) <= {0, 128, 255}


def test_uint8_dither_result_written_as_png_and_reported(tmp_path):
    """A uint8 dither result flows into the PNG writer and the dither error (as_tensor widens it)."""
    from PIL import Image

    from pointillist.imaging.io import write_png

    image = np.random.default_rng(5).integers(0, 256, (24, 32)).astype(np.uint8)
    result = floyd_steinberg(image)
    write_png(tmp_path / "fs.png", result, srgb=False, max_value=255.0)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "fs.png")), np.asarray(result))
    expected = dither_error(image.astype(np.float32), np.asarray(floyd_steinberg(image.astype(np.float32))))
    assert dither_error(image, result) == expected
