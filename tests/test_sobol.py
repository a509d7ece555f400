"""The sobol and zsobol samplers (plugins/samplers/sobol.py, zsobol.py, _sobol.py, _sobol_matrices.py),
checked independently: generator matrices against scipy's Sobol' sequence, (0, m, 2)-nets by counting
points in elementary intervals, Owen scrambling's uniformity and nesting, zsobol's nets over blocks of
pixels, and where the error goes on scenes/edges.xml."""

from __future__ import annotations

import doctest
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parent.parent
EDGES = ROOT / "scenes" / "edges.xml"


# ------------------------------------------------------------------------------ helpers
def is_net(points: np.ndarray, m: int) -> bool:
    """Whether ``2^m`` points of [0, 1)^2 form a (0, m, 2)-net: every elementary interval of area 2^-m
    (``2^a x 2^(m-a)`` cells, a = 0..m) holds exactly one of them."""
    points = np.asarray(points, np.float64)
    if len(points) != 1 << m or not ((points >= 0) & (points < 1)).all():
        return False
    for a in range(m + 1):
        cell = np.floor(points[:, 0] * (1 << a)).astype(np.int64) * (1 << (m - a)) \
            + np.floor(points[:, 1] * (1 << (m - a))).astype(np.int64)
        if np.unique(cell).size != 1 << m:
            return False
    return True


def film_points(mi, name, spp, pixels, seed=0, props=None, film=None, requests=1):
    """The first ``requests`` 2D requests of ``pixels`` pixels: array (requests, pixels, spp, 2)."""
    sampler = mi.load_dict({"type": name, "sample_count": spp, **(props or {})})
    if film is not None and hasattr(sampler, "attach_film"):
        sampler.attach_film(film)
    sampler.seed(seed, pixels * spp)
    out = [np.asarray(sampler.next_2d()).T.reshape(pixels, spp, 2) for _ in range(requests)]
    return np.stack(out), sampler


def test_is_net_can_fail():
    grid = (np.stack(np.meshgrid(np.arange(4), np.arange(4)), -1).reshape(-1, 2) + 0.5) / 4
    assert not is_net(grid, 4)  # a 4 x 4 grid leaves 12 of the 16 rows of height 1/16 empty
    assert is_net(np.array([[0.1, 0.6], [0.6, 0.1]]), 1) and not is_net(np.array([[0.1, 0.1], [0.6, 0.2]]), 1)


# -------------------------------------------------------------------- generator matrices
def test_matrices_are_joe_kuo_and_agree_with_scipy():
    from scipy.stats import qmc

    from pointillist.plugins.samplers._sobol_matrices import (SOBOL_DIMENSIONS, joe_kuo_matrices,
                                                              scipy_direction_numbers, sobol_matrices, sobol_points)

    shipped = sobol_matrices()
    poly, vinit = scipy_direction_numbers()
    np.testing.assert_array_equal(shipped, joe_kuo_matrices(poly, vinit, SOBOL_DIMENSIONS))  # the file is the table
    # hand-worked: dimension 1 (x + 1, m_1 = 1): m_k = m_{k-1} ^ 2 m_{k-1} = 1, 3, 5, 15, 17
    assert [int(v) >> (31 - k) for k, v in enumerate(shipped[1, :5])] == [1, 3, 5, 15, 17]
    assert [int(v) for v in shipped[0, :3]] == [1 << 31, 1 << 30, 1 << 29]  # van der Corput
    # scipy's unscrambled sequence, Gray-code order: its point n is our point n ^ (n >> 1), every bit equal
    n = np.arange(2048)
    theirs = qmc.Sobol(SOBOL_DIMENSIONS, scramble=False, bits=32).random(2048)
    ours = sobol_points(n ^ (n >> 1), SOBOL_DIMENSIONS)
    np.testing.assert_array_equal(ours.astype(np.float64) / 2 ** 32, theirs)
    with pytest.raises(ValueError, match="dimensions: expected an integer in 1..2"):
        joe_kuo_matrices(poly[:2], vinit[:2], 3)
    with pytest.raises(ValueError, match="vinit: dimension 1: expected odd m_k"):
        joe_kuo_matrices(np.array([1, 3]), np.array([[1], [2]]), 2)


def test_second_dimension_is_the_pascal_transform(mi):
    """zsobol computes Sobol' dimension 1 as brev(pascal_transform(i)) (Pascal's triangle mod 2): the
    shipped matrix's points for every 16-bit index; the argument is left as it was (an in-place XOR
    once turned zsobol's x into its y)."""
    from pointillist.plugins.samplers._sobol import laine_karras, pascal_transform
    from pointillist.plugins.samplers._sobol_matrices import sobol_points

    import drjit as dr

    index = mi.UInt32(np.arange(1 << 16, dtype=np.uint32))
    np.testing.assert_array_equal(np.asarray(dr.brev(pascal_transform(index))),
                                  sobol_points(np.arange(1 << 16), 2)[:, 1])
    laine_karras(index, mi.UInt32(7))
    np.testing.assert_array_equal(np.asarray(index), np.arange(1 << 16))


def test_unscrambled_samplers_are_scipys_sequence(mi):
    """randomization="none": sobol's sample i is scipy's point i in every dimension the integrator asks
    for (2D, 1D, 2D, ... requests); zsobol's samples of one pixel are the same set of 2^m points."""
    from scipy.stats import qmc

    spp = 64
    sampler = mi.load_dict({"type": "sobol", "sample_count": spp, "randomization": "none"})
    sampler.seed(5, 2 * spp)  # two pixels: unscrambled, both the same
    columns = []
    for request in (2, 1, 2, 1, 1, 2):
        value = sampler.next_2d() if request == 2 else sampler.next_1d()
        columns += list(np.atleast_2d(np.asarray(value)))
    ours = np.stack(columns, 1).reshape(2, spp, -1)
    n = np.arange(spp)
    natural = np.empty((spp, 9))
    natural[n ^ (n >> 1)] = qmc.Sobol(9, scramble=False, bits=32).random(spp)
    expected = np.floor(natural * 2 ** 24) / 2 ** 24  # the samplers keep a float32's 24 bits
    np.testing.assert_array_equal(ours[0], expected)
    np.testing.assert_array_equal(ours[1], expected)
    for spp in (1, 2, 4, 16, 32):
        pts, _ = film_points(mi, "zsobol", spp, 1, props={"randomization": "none"})
        first = qmc.Sobol(2, scramble=False, bits=32).random(spp)
        assert sorted(map(tuple, pts[0, 0])) == sorted(map(tuple, np.floor(first * 2 ** 24) / 2 ** 24))


# ----------------------------------------------------------------------------- nets
@pytest.mark.parametrize("spp", [1, 2, 16, 256])
def test_sobol_every_power_of_two_prefix_is_a_net(mi, spp):
    """The film position (dimensions 0, 1) of a pixel's first 2^k samples is a (0, k, 2)-net, in every
    pixel, for any seed: the scrambled sequence is a (0, 2)-sequence."""
    m = spp.bit_length() - 1
    for seed in (0, 9):
        pts, _ = film_points(mi, "sobol", spp, 40, seed=seed)
        for pixel in pts[0]:
            assert all(is_net(pixel[:1 << k], k) for k in range(m + 1))
        assert np.unique(pts[0, :, 0, 0]).size == 40  # a different scrambling in every pixel


@pytest.mark.parametrize("spp", [4, 16, 64])
def test_zsobol_pixel_samples_are_nets_and_prefixes_of_powers_of_four(mi, spp):
    m = spp.bit_length() - 1
    pts, _ = film_points(mi, "zsobol", spp, 64, seed=3)
    for pixel in pts[0]:
        assert is_net(pixel, m)
        assert all(is_net(pixel[:4 ** j], 2 * j) for j in range(m // 2 + 1))
    # 8 spp (an odd power of two: the last Morton digit is a single bit) is still a net per pixel
    pts, _ = film_points(mi, "zsobol", 8, 64, seed=3)
    assert all(is_net(pixel, 3) for pixel in pts[0])


@pytest.mark.parametrize("spp", [1, 2, 4])
def test_zsobol_blocks_of_pixels_form_nets(mi, spp):
    """The issue's check: at 1 spp an aligned 2^k x 2^k block of pixels holds a (0, 2k, 2)-net (and at
    spp samples a (0, 2k + log2 spp, 2)-net), in every request (dimension pair), here on a 32 x 16
    film with a crop window of 16 x 8 at (8, 4) as well (the film's own pixel coordinates)."""
    film = film_of(mi, 32, 16)
    log2 = spp.bit_length() - 1
    pts, _ = film_points(mi, "zsobol", spp, 32 * 16, seed=4, film=film, requests=3)
    grid = pts.reshape(3, 16, 32, spp, 2)  # (request, y, x, sample, 2)
    for request in range(3):
        for k in range(0, 5):
            size = 1 << k
            for by in range(0, 16, size):
                for bx in range(0, 32, size):
                    block = grid[request, by:by + size, bx:bx + size].reshape(-1, 2)
                    assert is_net(block, 2 * k + log2), (request, k, by, bx)
    # a sampler over a crop window gives each pixel its samples on the whole film
    crop = film_of(mi, 32, 16, crop=(8, 4, 16, 8))
    cropped, _ = film_points(mi, "zsobol", spp, 16 * 8, seed=4, film=crop, requests=3)
    np.testing.assert_array_equal(cropped.reshape(3, 8, 16, spp, 2), grid[:, 4:12, 8:24])


def _mi():
    import pointillist

    mi = pointillist.setup("llvm_ad_rgb")
    return (mi,)


def film_of(mi, width, height, crop=None, border=False):
    props = {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}}
    if crop is not None:
        props.update(crop_offset_x=crop[0], crop_offset_y=crop[1], crop_width=crop[2], crop_height=crop[3])
    if border:
        props.update(sample_border=True, rfilter={"type": "gaussian"})
    return mi.load_dict(props)


def test_zsobol_film_layout(mi):
    from pointillist.plugins.samplers.zsobol import film_layout

    assert film_layout(film_of(mi, 32, 16), 512) == (32, 0, 0, 32)
    assert film_layout(film_of(mi, 32, 16, crop=(8, 4, 16, 8)), 128) == (16, 8, 4, 32)
    bordered = film_of(mi, 10, 6, border=True)  # the Gaussian's 2-pixel border is sampled too
    assert film_layout(bordered, 14 * 10) == (14, 0, 0, 14)
    assert film_layout(film_of(mi, 32, 16), 100) == (10, 0, 0, 10)  # another wavefront: a square guess
    assert film_layout(None, 1) == (1, 0, 0, 1) and film_layout(None, 12) == (4, 0, 0, 4)
    # scenes loaded through pointillist hand zsobol its film; plain Mitsuba loading does not
    from pointillist.compare.methods import METHODS, load_configured_scene

    scene = load_configured_scene(EDGES, METHODS["zsobol"], 4, {"res": "8"})
    assert "film=attached" in str(scene.sensors()[0].sampler())
    plain = mi.load_file(str(EDGES), parallel=False, sampler="zsobol", res="8")
    assert "film=unknown" in str(plain.sensors()[0].sampler())


def test_zsobol_without_the_film_warns_for_a_non_square_wavefront(mi):
    sampler = mi.load_dict({"type": "zsobol", "sample_count": 1})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sampler.seed(0, 64)  # 8 x 8 assumed quietly
    with pytest.warns(RuntimeWarning, match="film's width is unknown.*rows of 8"):
        sampler.seed(0, 48)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sampler.seed(0, 48)  # once per sampler


def test_zsobol_rounds_to_powers_of_two_and_refuses_indices_beyond_32_bits(mi):
    with pytest.warns(RuntimeWarning, match="sample_count 5 is not a power of two; using 8"):
        sampler = mi.load_dict({"type": "zsobol", "sample_count": 5})
    assert sampler.sample_count() == 8
    with pytest.warns(RuntimeWarning, match="using 16"):
        sampler.set_sample_count(9)
    assert sampler.sample_count() == 16
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert mi.load_dict({"type": "sobol", "sample_count": 5}).sample_count() == 5  # sobol takes any count
    # a 4 x 4 crop of a 1000 x 1000 film: the Morton grid covers the whole film, 1024^2 (20 bits)
    film = film_of(mi, 1000, 1000, crop=(500, 500, 4, 4))
    for spp, fits in ((1 << 12, True), (1 << 13, False)):
        sampler = mi.load_dict({"type": "zsobol", "sample_count": spp})
        sampler.attach_film(film)
        if fits:
            sampler.seed(0, 16 * spp)
        else:
            with pytest.raises(ValueError, match=r"^zsobol sampler: a film of side 1000 \(rounded up to 1024\) at "
                                                 r"8192 spp needs 33-bit Morton indices; at most 32"):
                sampler.seed(0, 16 * spp)
    # pointillist refuses the render before any work (a UsageError: exit status 2 and one line); inside
    # mi.render the error comes wrapped in Mitsuba's
    from pointillist.core.errors import UsageError
    from pointillist.scene import attach_films, timed_render

    scene = mi.load_dict({"type": "scene", "integrator": {"type": "direct"}, "sensor": {"type": "perspective",
                          "sampler": {"type": "zsobol", "sample_count": 2},
                          "film": {"type": "hdrfilm", "width": 1 << 17, "height": 1}}})
    attach_films(scene)
    with pytest.raises(UsageError, match=r"^zsobol sampler: a film of side 131072 .* needs 35-bit"):
        timed_render(scene)
    with pytest.raises(RuntimeError) as raised:
        mi.render(scene)
    assert "zsobol sampler: a film of side 131072" in str(raised.value.__cause__)


# ------------------------------------------------------------------- Owen scrambling
def test_owen_scrambling_is_uniform_across_pixels_and_seeds(mi):
    """Each sample, with the other ones fixed, is uniformly distributed over the pixel: chi-square of
    (x, y) over 8 x 8 cells and Kolmogorov-Smirnov per coordinate, over 16384 pixels (sobol: a scrambling
    per pixel) and over 400 seeds at one pixel (zsobol: a scrambling per seed and dimension)."""
    from scipy import stats

    pts, sampler = film_points(mi, "sobol", 4, 16384, seed=1, requests=2)
    for request in range(2):
        for sample in range(4):
            xy = pts[request, :, sample]
            hist = np.histogram2d(xy[:, 0], xy[:, 1], bins=8, range=[[0, 1], [0, 1]])[0]
            assert stats.chisquare(hist.ravel()).pvalue > 1e-3
            assert min(stats.kstest(xy[:, c], "uniform").pvalue for c in (0, 1)) > 1e-3
    values = []
    sampler = mi.load_dict({"type": "zsobol", "sample_count": 4})
    for seed in range(400):
        sampler.seed(seed, 16 * 4)
        values.append(np.asarray(sampler.next_2d()).T.reshape(16, 4, 2)[5])
    values = np.array(values)  # (seed, sample, 2) at pixel 5
    for sample in range(4):
        hist = np.histogram2d(values[:, sample, 0], values[:, sample, 1], bins=4, range=[[0, 1], [0, 1]])[0]
        assert stats.chisquare(hist.ravel()).pvalue > 1e-3
        assert min(stats.kstest(values[:, sample, c], "uniform").pvalue for c in (0, 1)) > 1e-3


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(0, 2 ** 32 - 1), st.integers(0, 31), st.integers(0, 2 ** 32 - 1))
def test_owen_scramble_is_nested(value, seed, depth, noise):
    """Owen scrambling maps every elementary interval onto one of the same size: two values that share
    their top ``depth`` bits still do after scrambling, and it is a bijection (distinct values stay
    distinct)."""
    mi = _mi()[0]
    from pointillist.plugins.samplers._sobol import owen_scramble

    other = value ^ (noise & ((1 << (32 - depth)) - 1))  # the same top `depth` bits
    a, b = (int(owen_scramble(mi.UInt32(v), mi.UInt32(seed))[0]) for v in (value, other))
    assert a >> (32 - depth) == b >> (32 - depth) if depth else True
    assert (a == b) == (value == other)


def test_owen_scramble_permutes_each_level(mi):
    """Applied to all 2^10 values of the top 10 bits, the scramble is a permutation of them."""
    from pointillist.plugins.samplers._sobol import owen_scramble

    top = mi.UInt32(np.arange(1024, dtype=np.uint32) << 22)
    for seed in (0, 1, 0xDEADBEEF):
        scrambled = np.asarray(owen_scramble(top, mi.UInt32(seed))) >> 22
        assert sorted(scrambled.tolist()) == list(range(1024))


def test_zsobol_digit_permutations_are_uniform_and_independent_between_siblings(mi):
    """Over 23040 keys (seed and dimension), the permutation of a quadtree node's children is each of the 24
    equally often, and two sibling nodes' permutations are independent (chi-square over the 576 pairs; a
    hash of a single multiplication fails this with p = 0)."""
    from scipy import stats

    from pointillist.plugins.samplers._sobol import DIGIT_PERMUTATIONS, packed_permutations, zsobol_index

    number = {p: i for i, p in enumerate(DIGIT_PERMUTATIONS)}
    keys = mi.UInt32(np.random.default_rng(1).integers(0, 2 ** 32, 23040, dtype=np.uint64).astype(np.uint32))
    table = mi.UInt32(packed_permutations())
    chosen = []
    for node in (0, 1):  # two siblings under the root: Morton indices 4 node + d, two digits
        digits = [np.asarray(zsobol_index(mi.UInt32(np.full(23040, 4 * node + d, np.uint32)), keys, 2, False, table))
                  & 3 for d in range(4)]
        chosen.append(np.array([number[tuple(p)] for p in np.stack(digits, 1)]))
    assert stats.chisquare(np.bincount(chosen[0], minlength=24)).pvalue > 1e-3
    assert stats.chisquare(np.bincount(chosen[0] * 24 + chosen[1], minlength=576)).pvalue > 1e-3


# ----------------------------------------------------------------- blue-noise error
def low_share(error: np.ndarray) -> float:
    from pointillist.imaging.spectrum import low_frequency_energy

    return low_frequency_energy(error) / float((error ** 2).mean())


def test_zsobol_error_is_blue_noise_where_neighbours_integrate_alike(mi):
    """Analytic integrands, the same in every pixel, at 1 spp on 128 x 128 pixels (four seeds): the
    error image of zsobol keeps at most half of white noise's share of its energy below a quarter of
    Nyquist; random and sobol (independent pixels) keep white noise's, pi / 64."""
    white = math.pi / 64
    integrands = {  # (function of the sample's (x, y), its integral over the pixel)
        "step": (lambda p: (p[..., 0] < 0.3).astype(float), 0.3),
        "smooth": (lambda p: p[..., 0] * p[..., 1], 0.25),
        "disk": (lambda p: (np.hypot(p[..., 0] - 0.5, p[..., 1] - 0.5) < 0.4).astype(float), math.pi * 0.16),
    }
    for name in ("independent", "sobol", "zsobol"):
        for label, (f, integral) in integrands.items():
            shares = []
            for seed in range(4):
                pts, _ = film_points(mi, name, 1, 128 * 128, seed=seed, film=film_of(mi, 128, 128))
                shares.append(low_share(f(pts[0, :, 0]).reshape(128, 128) - integral))
            share = float(np.mean(shares))
            if name == "zsobol":
                assert share <= 0.5 * white, (label, share)
            else:
                assert share == pytest.approx(white, rel=0.15), (name, label, share)


def _edges_errors(mi, name, spp, seeds, res=64):
    """Luminance error images of scenes/edges.xml against a 4096-spp stratified reference."""
    from pointillist.compare.methods import METHODS, load_configured_scene
    from pointillist.imaging.metrics import luminance_error

    global _REFERENCE
    if _REFERENCE is None:
        scene = load_configured_scene(EDGES, METHODS["stratified"], 4096, {"res": str(res)})
        _REFERENCE = np.asarray(mi.render(scene, seed=1_000_003))
        del scene
    scene = load_configured_scene(EDGES, METHODS[name], spp, {"res": str(res)})
    out = [luminance_error(np.asarray(mi.render(scene, seed=seed)), _REFERENCE) for seed in seeds]
    del scene
    return out


_REFERENCE = None


@pytest.mark.slow  # ~10 s: 112 renders of edges.xml at 64 x 64
def test_edges_convergence_and_error_distribution(mi):
    """The issue's must-hold, deterministic (fixed seeds, means over eight): on scenes/edges.xml sobol and
    zsobol converge at least as fast as jitter (MSE slope over 1..64 spp), zsobol's MSE stays within 10 %
    of sobol's at 1 and 4 spp, and at 4 spp zsobol's error holds at most half of random's energy below a
    quarter of Nyquist. (At 1 spp it does not on this scene: benchmarks/RESULTS.md, "sobol and zsobol".)"""
    from pointillist.compare.tables import fit_slope
    from pointillist.imaging.spectrum import low_frequency_energy

    seeds = range(8)  # (with 4, zsobol's MSE at 4 spp came out 0.93x sobol's: noise, 0.97x with 8)
    spps = (1, 4, 16, 64)
    mse = {(name, spp): np.mean([float((e ** 2).mean()) for e in _edges_errors(mi, name, spp, seeds)])
           for name in ("jitter", "sobol", "zsobol") for spp in spps}
    slope = {name: fit_slope(spps, [mse[name, spp] for spp in spps]) for name in ("jitter", "sobol", "zsobol")}
    assert slope["sobol"] <= slope["jitter"] and slope["zsobol"] <= slope["jitter"], slope
    assert slope["jitter"] < -1.2  # a stratified rate, not random's -1
    for spp in (1, 4):
        assert abs(mse["zsobol", spp] / mse["sobol", spp] - 1) <= 0.10, (spp, mse)
    low = {name: np.mean([low_frequency_energy(e) for e in _edges_errors(mi, name, 4, seeds)])
           for name in ("independent", "zsobol")}
    assert low["zsobol"] <= 0.5 * low["independent"], low


# ------------------------------------------------------------------ as Mitsuba samplers
@pytest.mark.parametrize("name", ["sobol", "zsobol"])
def test_clone_fork_and_state(mi, name):
    sampler = mi.load_dict({"type": name, "sample_count": 4, "seed": 3})
    if name == "zsobol":
        sampler.attach_film(film_of(mi, 4, 2))
    sampler.seed(1, 8 * 4)
    sampler.next_2d()
    twin = sampler.clone()
    np.testing.assert_array_equal(np.asarray(twin.next_2d()), np.asarray(sampler.next_2d()))
    np.testing.assert_array_equal(np.asarray(twin.next_1d()), np.asarray(sampler.next_1d()))
    fresh = sampler.fork()
    assert fresh.sample_count() == 4 and "seed=3" in str(fresh) and "randomization=owen" in str(fresh)
    if name == "zsobol":
        assert "film=attached" in str(fresh)
    # advance(): dimension 0 again, with another scrambling
    first, _ = film_points(mi, name, 4, 8, seed=1, props={"seed": 3}, film=film_of(mi, 4, 2))
    sampler.advance()
    again = np.asarray(sampler.next_2d()).T.reshape(8, 4, 2)
    assert not np.allclose(again, first[0]) and all(is_net(p, 2) for p in again)


@pytest.mark.parametrize("name", ["sobol", "zsobol"])
def test_a_new_seed_recompiles_nothing(mi, name):
    import drjit as dr

    sampler = mi.load_dict({"type": name, "sample_count": 4})
    sampler.seed(0, 64)
    dr.eval(sampler.next_2d(), sampler.next_1d())
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        sampler.seed(1, 64)
        dr.eval(sampler.next_2d(), sampler.next_1d())
        first = {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}
        for seed in (2, 3, 12345):
            sampler.seed(seed, 64)
            dr.eval(sampler.next_2d(), sampler.next_1d())
        later = {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert first and later <= first  # the same kernels: the seed is opaque


def test_sobol_dimensions_beyond_the_shipped_ones(mi):
    """Dimension 256 on reuses the matrices with a shuffled index: every coordinate stays stratified
    (16 samples in the 16 intervals of 1/16), dimensions 256-257 are a net again like 0-1 (the only
    pair of Sobol' dimensions that is a (0, 2)-sequence), and they are not a copy of dimensions 0-1."""
    sampler = mi.load_dict({"type": "sobol", "sample_count": 16})
    sampler.seed(0, 16 * 30)
    values = [np.asarray(sampler.next_2d()).T.reshape(30, 16, 2) for _ in range(140)]  # dimensions 0..279
    strata = np.floor(np.stack(values) * 16).astype(int)  # (request, pixel, sample, 2)
    assert all(sorted(strata[r, p, :, c]) == list(range(16)) for r in range(140) for p in range(30) for c in (0, 1))
    for request in (0, 128):
        assert all(is_net(pixel, 4) for pixel in values[request]), request
    assert not all(is_net(pixel, 4) for pixel in values[127])  # dimensions 254-255: t > 0
    first, later = values[0].reshape(-1, 2), values[128].reshape(-1, 2)  # dimensions 0-1 and 256-257
    assert abs(np.corrcoef(first[:, 0], later[:, 0])[0, 1]) < 0.1
    top = lambda v: (v >= 0.5).astype(int)  # noqa: E731  Owen-scrambled copies of one index share their top bit
    assert 0.3 < np.mean(top(first[:, 0]) == top(later[:, 0])) < 0.7


def test_docstring_examples_run(mi):
    from pointillist.plugins.samplers import _sobol, _sobol_matrices, zsobol

    results = [doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE)
               for module in (_sobol, _sobol_matrices, zsobol)]
    assert all(r.failed == 0 for r in results) and sum(r.attempted for r in results) >= 8
