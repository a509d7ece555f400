"""Tests of the one-pass ordered-dithering path of imaging.dither.

1-bit ordered dithering compares each value with a per-entry intensity threshold
(``intensity_thresholds``) instead of computing p per pixel; uint8 input is read as bytes; the
template index uses shifts and masks for powers of two and a float reciprocal otherwise. These
tests hold each path to the conventions' rule evaluated exactly (integers or exact float64 products),
at the edges of the domain, and check that a call is one kernel launch with no recompilation.
"""

from __future__ import annotations

import drjit as dr
import numpy as np
import pytest
from drjit.llvm import UInt32

from pointillist.imaging.arrays import as_tensor, divmod_u32
from pointillist.imaging.colour import srgb_decode
from pointillist.imaging.io import to_8bit
from pointillist.imaging.dither import (TEMPLATE_4, bayer, blue_noise, blue_noise_mask, clustered_dot,
                                        intensity_thresholds, ordered)

TEMPLATES = {"template_4": TEMPLATE_4, "bayer_8": bayer(8), "blue_noise_64": blue_noise_mask(),
             "clustered_3": clustered_dot(3), "clustered_5": clustered_dot(5), "one": np.array([[1]])}


def tiled(template, height, width):
    n = template.shape[0]
    return np.tile(template, (-(-height // n), -(-width // n)))[:height, :width]


def spec_rule(image, template):
    """The rule: p = min(floor(I (n^2+1) / 255), n^2) with I clipped to 0..255 (NaN -> 0); white if p >= T.

    Evaluated exactly: for T <= n^2, p >= T  <=>  I (n^2+1) >= 255 T, and the product of a float32
    and an integer below 2^29 is exact in float64.
    """
    image = np.asarray(image, dtype=np.float32)
    values = np.clip(np.where(np.isnan(image), 0, image), 0, 255).astype(np.float64)
    n = template.shape[0]
    if values.ndim == 3:
        t = tiled(template, *values.shape[:2])[:, :, None]
    else:
        t = tiled(template, *values.shape)
    return np.where(values * (n * n + 1) >= 255.0 * t, 255.0, 0.0)


@pytest.mark.parametrize("name", list(TEMPLATES))
def test_intensity_thresholds_are_the_smallest_float32_meeting_the_rule(name):
    template = TEMPLATES[name]
    n = template.shape[0]
    thresholds = intensity_thresholds(template)
    assert thresholds.dtype == np.float32 and thresholds.shape == template.shape
    target = 255.0 * template
    assert np.all(thresholds.astype(np.float64) * (n * n + 1) >= target)
    below = np.nextafter(thresholds, np.float32(-np.inf)).astype(np.float64)
    assert np.all(below * (n * n + 1) < target)
    # For 8-bit values this is OpenCV's integer map ceil(255 T / (n^2 + 1)) (integer arithmetic).
    integer_map = -(-255 * template // (n * n + 1))
    codes = np.arange(256)[:, None]
    assert np.array_equal(codes >= thresholds.ravel()[None, :], codes >= integer_map.ravel()[None, :])
    assert np.all((thresholds > 0) & (thresholds < 255))


@pytest.mark.slow  # ~15 s: every value at every position of a 64 x 64 mask
@pytest.mark.parametrize("name", list(TEMPLATES))
def test_every_8bit_value_at_every_template_position(name):
    template = TEMPLATES[name]
    n = template.shape[0]
    # Rows: the 256 codes repeated so that each code meets every template entry.
    width = n * n
    image = np.repeat(np.arange(256, dtype=np.uint8), n)[:, None].repeat(width, axis=1)
    image = image.reshape(-1, width)  # (256 n, n^2): row r has code r // n, template row r % n
    expected = spec_rule(image, template)
    assert np.array_equal(np.asarray(ordered(image, template)), expected)  # uint8 path
    assert np.array_equal(np.asarray(ordered(image.astype(np.float32), template)), expected)  # float path


@pytest.mark.parametrize("name", ["template_4", "blue_noise_64", "clustered_3"])
def test_real_values_near_every_threshold_follow_the_exact_rule(name):
    template = TEMPLATES[name]
    n = template.shape[0]
    rng = np.random.default_rng(17)
    height, width = 3 * n + 1, 2 * n + 3
    t = tiled(template, height, width).astype(np.float64)
    exact = (255.0 * t / (n * n + 1)).astype(np.float32)
    # Values at, one ulp around, and randomly near the real threshold of their own pixel.
    choices = np.stack([exact, np.nextafter(exact, np.float32(0)), np.nextafter(exact, np.float32(300)),
                        exact + rng.normal(0, 0.01, exact.shape).astype(np.float32),
                        rng.uniform(-20, 275, exact.shape).astype(np.float32)])
    pick = rng.integers(0, len(choices), exact.shape)
    image = np.take_along_axis(choices, pick[None], 0)[0]
    assert np.array_equal(np.asarray(ordered(image, template)), spec_rule(image, template))


def test_edges_nan_infinite_out_of_range_constants():
    image = np.array([[np.nan, -np.inf, np.inf, -1e30, 1e30, -0.0, 255.0, 256.0]], dtype=np.float32)
    expected = spec_rule(np.array([[0, 0, 255, 0, 255, 0, 255, 255]], dtype=np.float32), TEMPLATE_4)
    assert np.array_equal(np.asarray(ordered(image)), expected)
    assert np.array_equal(expected[0], [0, 0, 255, 0, 255, 0, 255, 255])
    for value in (0, 255):  # constants stay, whatever the template
        for template in TEMPLATES.values():
            for array in (np.full((5, 7), value, np.uint8), np.full((5, 7), value, np.float32)):
                assert np.all(np.asarray(ordered(array, template)) == value)
    # one pixel: template entry (0, 0)
    assert np.asarray(ordered(np.array([[15]], np.uint8))).tolist() == [[255.0]]  # 15 * 17 >= 255 * 1
    assert np.asarray(ordered(np.array([[14]], np.uint8))).tolist() == [[0.0]]


@pytest.mark.parametrize("shape", [(13, 7, 3), (6, 2048 + 5), (1, 1, 4), (9, 1), (1, 11), (4, 6, 2)])
def test_shapes_channels_and_odd_widths(shape):
    rng = np.random.default_rng(sum(shape))
    image = rng.integers(0, 256, shape).astype(np.uint8)
    for template in (TEMPLATE_4, clustered_dot(3), blue_noise_mask()):
        expected = spec_rule(image, template)
        assert np.array_equal(np.asarray(ordered(image, template)), expected)
        assert np.array_equal(np.asarray(ordered(image.astype(np.float32), template)), expected)


def test_uint8_views_and_non_contiguous_input():
    rng = np.random.default_rng(5)
    base = rng.integers(0, 256, (20, 30, 3)).astype(np.uint8)
    for view in (base[::2, 1::3], base[:, :, 1], base.transpose(1, 0, 2)[3:, :5]):
        assert np.array_equal(np.asarray(ordered(view)), spec_rule(view, TEMPLATE_4))
    with pytest.raises(ValueError, match="image"):
        ordered(np.zeros((0, 4), np.uint8))
    with pytest.raises(ValueError, match="image"):
        ordered(np.zeros((2, 2, 2, 2), np.uint8))


def test_levels_above_two_follow_the_generalised_rule():
    rng = np.random.default_rng(8)
    image = rng.integers(0, 256, (19, 23))
    for levels in (3, 4, 256):
        for template in (TEMPLATE_4, clustered_dot(3)):
            n = template.shape[0]
            t = tiled(template, *image.shape)
            scaled = image * (levels - 1)
            base = np.minimum(scaled // 255, levels - 2)
            rest = scaled - base * 255
            p = np.minimum(rest * (n * n + 1) // 255, n * n)
            expected = ((base + (p >= t)) * 255.0 / (levels - 1)).astype(np.float32)
            got = np.asarray(ordered(image.astype(np.float32), template, levels=levels))
            np.testing.assert_allclose(got, expected, rtol=0, atol=1e-4)
            # uint8 in, uint8 out: the float32 levels rounded as the 8-bit writers round them
            eight = np.asarray(ordered(image.astype(np.uint8), template, levels=levels))
            assert eight.dtype == np.uint8
            np.testing.assert_array_equal(eight, to_8bit(got, srgb=False, max_value=255.0))
    # levels = 256 leaves 8-bit input unchanged
    assert np.array_equal(np.asarray(ordered(image.astype(np.uint8), levels=256)), image)


def test_linear_light_uint8_equals_float():
    rng = np.random.default_rng(2)
    image = rng.integers(0, 256, (12, 10)).astype(np.uint8)
    decoded = np.asarray(srgb_decode(image.astype(np.float32) / 255.0)) * 255.0
    expected = np.asarray(ordered(decoded))
    assert np.array_equal(np.asarray(ordered(image, linear=True)), expected)
    assert np.array_equal(np.asarray(ordered(image.astype(np.float32), linear=True)), expected)
    assert np.array_equal(np.asarray(blue_noise(image, linear=True)), np.asarray(blue_noise(decoded)))


def test_float32_divmod_is_exact_below_2_to_24():
    top = 1 << 24
    a = np.concatenate([np.arange(0, 40000), np.arange(top - 40000, top)]).astype(np.uint32)
    for divisor in (2, 3, 7, 255, 2047, 2049, 4095, 65537, 12345679, top - 1):
        q, r = divmod_u32(UInt32(a), divisor, top)
        assert np.array_equal(np.asarray(q), a // divisor), divisor
        assert np.array_equal(np.asarray(r), a % divisor), divisor


def test_one_kernel_per_call_and_no_recompilation_across_sizes(aligned):
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for shape in ((40, 64), (41, 77), (40, 64, 3)):
            image = np.random.default_rng(0).integers(0, 256, shape).astype(np.uint8)
            tensor = as_tensor(image.astype(np.float32))
            dr.eval(tensor)
            for fn in (lambda: ordered(tensor), lambda: blue_noise(tensor), lambda: ordered(image)):
                dr.eval(fn())
                dr.kernel_history()  # warm: constants and tables are cached after the first call
                dr.eval(fn())
                launches = [e for e in dr.kernel_history() if e["type"] == dr.KernelType.JIT]
                assert len(launches) == 1
        # Same structure, other sizes: the same kernel (cache hit), sizes are not baked in.
        dr.kernel_history()
        dr.eval(ordered(aligned(np.zeros((33, 96), np.float32))))
        compiled = {e["hash"] for e in dr.kernel_history() if e["type"] == dr.KernelType.JIT}
        for shape in ((35, 96), (17, 160), (5, 1000)):
            image = np.random.default_rng(1).integers(0, 256, shape).astype(np.float32)
            dr.eval(ordered(aligned(image)))
        launches = [e for e in dr.kernel_history() if e["type"] == dr.KernelType.JIT]
        # kernel hashes, not cache_hit (which also counts kernels loaded from ~/.drjit)
        assert len(launches) == 3 and {e["hash"] for e in launches} <= compiled
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


# ----------------------------------------------------------------------------------------------
# error diffusion reads its input in the loop (uint8 as bytes, float32 clipped on the fly)


@pytest.mark.parametrize("shape", [(1, 1), (7, 1), (1, 9), (23, 37), (11, 17, 3)])
def test_diffusion_uint8_input_equals_float_input(shape):
    from pointillist.imaging.dither import KERNELS, diffuse, error_diffusion, floyd_steinberg

    image = np.random.default_rng(len(shape) * 100 + shape[0]).integers(0, 256, shape).astype(np.uint8)
    as_float = image.astype(np.float32)
    for name in KERNELS:
        assert np.array_equal(np.asarray(diffuse(image, name)), np.asarray(diffuse(as_float, name))), name
    assert np.array_equal(np.asarray(floyd_steinberg(image, serpentine=True)),
                          np.asarray(floyd_steinberg(as_float, serpentine=True)))
    assert np.array_equal(np.asarray(floyd_steinberg(image, levels=4)), np.asarray(floyd_steinberg(as_float, levels=4)))
    assert np.array_equal(np.asarray(error_diffusion(image)), np.asarray(error_diffusion(as_float)))
    # a non-contiguous uint8 view
    view = image[::-1, ::2]
    assert np.array_equal(np.asarray(floyd_steinberg(view)), np.asarray(floyd_steinberg(view.astype(np.float32))))


def test_diffusion_is_one_kernel_launch():
    from pointillist.imaging.dither import floyd_steinberg

    image = np.random.default_rng(4).uniform(-10, 300, (20, 30)).astype(np.float32)
    tensor = as_tensor(image)
    dr.eval(tensor)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        # float32: one launch (clipped in the loop); uint8: the bytes widened in one pass first (a
        # byte gather per step is scalarised), then the diffusion writing bytes
        for source, widen in ((tensor, 0), (image.clip(0, 255).astype(np.uint8), 1)):
            dr.eval(floyd_steinberg(source))
            dr.kernel_history()
            dr.eval(floyd_steinberg(source))
            launches = [e for e in dr.kernel_history() if e["type"] == dr.KernelType.JIT]
            assert len(launches) == 1 + widen
            assert sum(e["size"] == image.size for e in launches) == widen  # the widening pass: one lane a pixel
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


# ----------------------------------------------------------------------------------------------
# halftone: the same one-comparison rule per output cell


def halftone_reference(image, template):
    """Every pixel becomes its n x n pattern: cell (ty, tx) white where I (n^2+1) >= 255 T (exact)."""
    n = template.shape[0]
    big = np.repeat(np.repeat(np.asarray(image), n, axis=0), n, axis=1)
    return spec_rule(big, template)


@pytest.mark.parametrize("n,shape", [(1, (3, 4)), (2, (5, 3)), (3, (4, 7, 3)), (4, (2, 2)), (5, (3, 1, 2))])
def test_halftone_follows_the_exact_rule(n, shape):
    from pointillist.imaging.dither import halftone

    rng = np.random.default_rng(n)
    image = rng.uniform(-30, 290, shape).astype(np.float32)
    image.flat[0], image.flat[-1] = np.nan, np.inf
    template = clustered_dot(n)
    assert np.array_equal(np.asarray(halftone(image, n)), halftone_reference(image, template))
    if n in (2, 4):
        assert np.array_equal(np.asarray(halftone(image, n, template=bayer(n))), halftone_reference(image, bayer(n)))


def test_halftone_output_beyond_2_to_24_values():
    from pointillist.imaging.dither import halftone

    # 690 x 690 pixels, n = 6: 4140^2 = 17.1 M output values (> 2^24: the float64 index path).
    image = np.random.default_rng(6).integers(0, 256, (690, 690)).astype(np.uint8)
    out = np.asarray(halftone(image, 6)) > 0
    n, template = 6, clustered_dot(6)
    cells = np.tile(255 * template.astype(np.int32), (690, 690))
    codes = np.repeat(np.repeat(image.astype(np.int32) * (n * n + 1), n, axis=0), n, axis=1)
    assert np.array_equal(out, codes >= cells)


# ----------------------------------------------------------------------------------------------
# pattern: one mean per n x n block (edge blocks average what they have), then the same rule


def block_means(image, n):
    values = np.asarray(image, dtype=np.float32)
    values = np.clip(np.where(np.isnan(values), 0, values), 0, 255).astype(np.float64)
    h, w = values.shape[:2]
    out = np.empty_like(values)
    for by in range(0, h, n):  # a loop over blocks in the reference only
        for bx in range(0, w, n):
            block = values[by:by + n, bx:bx + n]
            out[by:by + n, bx:bx + n] = block.mean(axis=(0, 1))
    return out.astype(np.float32)


@pytest.mark.parametrize("n,shape", [(1, (3, 5)), (2, (5, 7)), (4, (9, 6, 3)), (3, (1, 8)), (8, (4, 4))])
def test_pattern_uses_block_means_and_the_exact_rule(n, shape):
    from pointillist.imaging.dither import pattern

    rng = np.random.default_rng(n * 7)
    image = rng.uniform(-20, 280, shape).astype(np.float32)
    image.flat[1] = np.nan
    template = bayer(n) if n in (1, 2, 4, 8) else clustered_dot(n)
    got = np.asarray(pattern(image, template))
    expected = spec_rule(block_means(image, n), template)
    assert np.array_equal(got, expected)
    # levels > 2 on block-constant integer images (integer means): the generalised rule
    coarse = rng.integers(0, 256, (-(-shape[0] // n), -(-shape[1] // n)) + shape[2:])
    blocky = np.kron(coarse, np.ones((n, n) + (1,) * (len(shape) - 2)))[:shape[0], :shape[1]].astype(np.uint8)
    assert np.array_equal(np.asarray(pattern(blocky, template, levels=3)),
                          np.asarray(ordered(blocky, template, levels=3)))


def test_float32_single_product_divmod_is_exact_below_2_to_22():
    top = 1 << 22
    a = np.arange(0, top, dtype=np.uint32)  # every dividend the path accepts
    for divisor in (3, 5, 7, 255, 2047, 2049, 4093, 65535, top - 1):
        q, r = divmod_u32(UInt32(a), divisor, top)
        assert np.array_equal(np.asarray(q), a // divisor), divisor
        assert np.array_equal(np.asarray(r), a % divisor), divisor


def test_uint8_pre_tiled_map_equals_the_table_path(monkeypatch):
    """1-bit uint8 ordered dithering compares the bytes with a cached pre-tiled byte map; it equals
    the per-pixel table route (taken above the size limit) and the conventions' rule, for every shape."""
    import pointillist.imaging.dither.templates as dither_module

    rng = np.random.default_rng(11)
    for shape in ((37, 45), (16, 64, 3), (5, 7, 1), (64, 70)):
        image = rng.integers(0, 256, shape).astype(np.uint8)
        for template in (TEMPLATE_4, bayer(8), blue_noise_mask(), clustered_dot(3)):
            mapped = np.asarray(ordered(image, template))
            assert mapped.dtype == np.uint8
            assert np.array_equal(mapped, np.asarray(ordered(image.astype(np.float32), template)))
            monkeypatch.setattr(dither_module, "_TILED_MAP_BYTES", 0)
            assert np.array_equal(np.asarray(ordered(image, template)), mapped)
            monkeypatch.undo()
