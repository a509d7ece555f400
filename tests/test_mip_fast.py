"""Fast paths of the ``mip`` integrator: bit-for-bit equal to the plain ray march.

The axis-aligned column reduction and the brick skipping are optimisations only: every test
here renders the same rays with the fast path on and off (``fast_axis`` / ``skip_bricks``)
and demands identical float32 bits, and checks which path actually ran.
"""

from __future__ import annotations

import numpy as np
import pytest

from pointillist.imaging.volumes import Volume, shepp_logan_phantom

RNG = np.random.default_rng(80)  # module-level data only (drawn once at import); tests use the `rng` fixture

VOLUMES = {
    "random_float": RNG.random((5, 6, 7)).astype(np.float32),
    "phantom_int16": shepp_logan_phantom((12, 10, 16)),
    "odd_int16": RNG.integers(-1000, 1000, (7, 5, 9)).astype(np.int16),
    "pow2_int16": RNG.integers(-1000, 1000, (8, 32, 16)).astype(np.int16),
    "pow2_float": RNG.random((16, 8, 4)).astype(np.float32),
    "nan": np.where(RNG.random((6, 6, 8)) < 0.2, np.nan, RNG.random((6, 6, 8))).astype(np.float32),
}


def _pair(mi, volume, *, spacing=(1.0, 1.0, 1.0), **props):
    """(fast, plain) integrators holding the same volume."""
    out = []
    for fast in (True, False):
        integrator = mi.load_dict({"type": "mip", "fast_axis": fast, "skip_bricks": fast, **props})
        integrator.set_volume(Volume(volume, spacing))
        out.append(integrator)
    return out


def _project_both(mi, volume, props, spacing=(1.0, 1.0, 1.0), **view):
    from pointillist.mip import project_volume

    fast, plain = _pair(mi, volume, spacing=spacing, **props)
    a, _ = project_volume(Volume(volume, spacing), integrator=fast, **view)
    b, _ = project_volume(Volume(volume, spacing), integrator=plain, **view)
    assert plain.last_path == "march"
    return a, b, fast.last_path


def _same_bits(a, b):
    return a.shape == b.shape and np.array_equal(a.view(np.uint32), b.view(np.uint32))


@pytest.mark.parametrize("name", sorted(VOLUMES))
@pytest.mark.parametrize("view", ["axial", "coronal", "sagittal"])
@pytest.mark.parametrize("mode", ["mip", "minip", "average"])
def test_nearest_columns_equal_the_march_bit_for_bit(mi, name, view, mode):
    props = {"mode": mode, "interpolation": "nearest", "background": -3.0}
    for native, step in ((True, 0.5), (False, 1.0), (False, 0.3), (True, 2.5)):
        a, b, path = _project_both(mi, VOLUMES[name], dict(props, step=step), view=view, native=native,
                                   size=(23, 17))
        assert _same_bits(a, b), (native, step)
        # nearest mip/minip: a step clearly below one voxel samples every voxel of the column
        # (step 1.0 may skip one by float rounding: then it marches); average needs the same
        # number of samples in every voxel (step 0.5 of whole voxels: 2); 2.5 skips voxels
        if step == 0.5 or (step == 0.3 and mode != "average"):
            assert path == "columns", (native, step)
        if step == 2.5:
            assert path != "columns"


@pytest.mark.parametrize("name", sorted(VOLUMES))
@pytest.mark.parametrize("mode", ["mip", "minip", "average"])
def test_trilinear_columns_only_where_samples_hit_voxel_centres(mi, name, mode):
    props = {"mode": mode, "interpolation": "trilinear", "background": -3.0}
    for view in ("axial", "coronal", "sagittal"):
        for native, step in ((True, 0.5), (True, 0.3), (False, 0.5)):
            a, b, path = _project_both(mi, VOLUMES[name], dict(props, step=step), view=view,
                                       native=native, size=(23, 17))
            assert _same_bits(a, b), (view, native, step)
            # exact centres only with power-of-two sizes across the view (pixel centres are
            # then exact floats), native size, half-voxel steps, finite data, not average
            expected = ("columns" if name.startswith("pow2") and native and step == 0.5 and mode != "average"
                        else "bricks" if mode != "average" else "march")
            assert path == expected, (view, native, step)


def test_trilinear_native_columns_equal_numpy_max_exactly(mi):
    vol = VOLUMES["pow2_int16"]
    from pointillist.mip import project_volume

    for view, axis in (("axial", 0), ("coronal", 1), ("sagittal", 2)):
        image, integrator = project_volume(vol, view=view, native=True, interpolation="trilinear")
        assert integrator.last_path == "columns"
        expected = vol.max(axis=axis).astype(np.float32)
        np.testing.assert_array_equal(image, expected if axis == 0 else expected[::-1])


def test_anisotropic_spacing_and_pose_keep_the_columns_exact(mi):
    vol = VOLUMES["phantom_int16"]
    a, b, path = _project_both(mi, vol, {"interpolation": "nearest"}, spacing=(0.7, 1.3, 2.0), view="coronal",
                               native=True)
    assert path == "columns" and _same_bits(a, b)
    a, b, path = _project_both(mi, vol, {"interpolation": "nearest"}, spacing=(0.7, 1.3, 2.0), view="axial",
                               size=(40, 31))
    assert path == "columns" and _same_bits(a, b)


@pytest.mark.parametrize("nx", [64, 16, 12, 10, 9])
def test_half_word_and_float_reductions_equal_numpy(rng, mi, nx):
    # nx even: packed float16 pairs, compared as 16-bit keys and (data without -0 or values below
    # 2^-17) as float32 words; rows of 32, 8, 6 and 5 words are read 8, 8, 2 and 1 word a lane
    # and load; 37 slices: chunks of 8, 4, 1 or no whole chunk (64) and the rest slices, 2-64 streams a kernel.
    # nx odd: one float16 gather a voxel
    from pointillist.plugins.integrators._mip_accel import (float_ordered, half_slices, reduce_columns,
                                                            reduce_half_words)

    vol = rng.integers(-2048, 2049, (37, 6, nx)).astype(np.float16)
    storage = mi.Float16(vol.ravel())
    assert float_ordered(vol.view(np.uint16))
    for axis, np_axis in ((0, 2), (1, 1), (2, 0)):
        for mode, reduce in (("mip", np.max), ("minip", np.min)):
            expected = reduce(vol, axis=np_axis).astype(np.float32)
            expected = expected.ravel()  # columns: (z, y), (z, x) or (y, x), last index fastest
            acc, seen = reduce_columns(storage, vol.shape, axis, mode, has_nan=False)
            np.testing.assert_array_equal(np.asarray(acc), expected)
            if nx % 2 == 0:
                words = mi.UInt32(vol.view(np.uint32).ravel()) + 0  # Dr.Jit's own (aligned) memory
                for floats in (False, True):
                    for group, stack in ((8, 8), (64, 8), (2, 4), (3, 1), (4, 64)):  # chunks of slices + rest
                        got = reduce_half_words(words, vol.shape, axis, mode, floats=floats, group=group,
                                                slices=half_slices(words, vol.shape, stack=stack))
                        np.testing.assert_array_equal(np.asarray(got), expected)
    with pytest.raises(ValueError, match="even"):
        reduce_half_words(mi.UInt32(np.zeros(4, np.uint32)), (1, 1, 9), 2, "mip")


def test_float_word_order_needs_no_negative_zero_and_no_tiny_values(mi):
    # every pair of finite halves outside {-0, |x| < 2^-17} compares as float32 words like the keys;
    # -0 and the tiny values are exactly what float_ordered refuses (they compare equal to 0 there)
    from pointillist.plugins.integrators._mip_accel import float_ordered, reduce_half_words

    bits = np.arange(1 << 16, dtype=np.uint32).astype(np.uint16)
    finite = bits[np.isfinite(bits.view(np.float16))]
    safe = finite[((finite & 0x7F80) != 0) | (finite == 0)]
    assert float_ordered(safe) and not float_ordered(np.array([0x8000], np.uint16))
    assert not float_ordered(np.array([0x0001], np.uint16)) and not float_ordered(np.array([0x807F], np.uint16))
    assert float_ordered(np.array([0x0080, 0x8080, 0x0000, 0x7BFF, 0xFBFF], np.uint16))
    rng = np.random.default_rng(9)
    vol = rng.choice(safe, size=(40, 3, 2048)).view(np.float16)  # every safe half, shuffled
    words = mi.UInt32(vol.view(np.uint32).ravel()) + 0
    for axis, np_axis in ((0, 2), (1, 1), (2, 0)):
        for mode, reduce in (("mip", np.max), ("minip", np.min)):
            expected = reduce(vol.astype(np.float32), axis=np_axis).ravel()
            keys = np.asarray(reduce_half_words(words, vol.shape, axis, mode, floats=False))
            floats = np.asarray(reduce_half_words(words, vol.shape, axis, mode, floats=True))
            assert np.array_equal(keys.view(np.uint32), expected.view(np.uint32))
            assert np.array_equal(floats.view(np.uint32), expected.view(np.uint32))


def test_integrator_compares_words_as_floats_only_where_exact(mi):
    # int16 CT (integers less an integer offset): float-order words; float16 data holding -0 or
    # values below 2^-17: integer keys; both equal the march bit for bit, on all three axes
    ct = VOLUMES["pow2_int16"]
    tiny = RNG.integers(-50, 50, (8, 6, 8)).astype(np.float16)
    tiny[1, 2, 3], tiny[4, 0, 0], tiny[5, 5, 5] = -0.0, np.float16(2.0**-20), np.float16(-(2.0**-22))
    tiny[:, :, 6] = np.float16(2.0**-24)  # a whole column of subnormals: its maximum is one of them
    for volume, ordered in ((ct, True), (tiny, False)):
        for view in ("axial", "coronal", "sagittal"):
            for mode in ("mip", "minip"):
                props = {"mode": mode, "interpolation": "nearest", "precision": "half"}
                a, b, path = _project_both(mi, volume, props, view=view, native=True)
                assert path == "columns" and _same_bits(a, b), (view, mode)
        fast, _ = _pair(mi, volume, interpolation="nearest", precision="half")
        assert fast.stored.float_ordered() is ordered


@pytest.mark.parametrize("shape", [(8, 6, 10), (5, 7, 4), (3, 2, 2), (16, 16, 16)])
@pytest.mark.parametrize("kind", ["int16", "float16", "tiny"])
def test_word_lookups_equal_the_texture_bit_for_bit(mi, rng, shape, kind):
    # HalfSampler (32-bit word gathers) against the texture's own eval: points inside, outside and on
    # faces, voxel centres and half-way points; integers, float16 data, and float16 data with
    # subnormals and -0 (the general half conversion); trilinear and nearest
    from pointillist.imaging.volumes import volume_texture
    from pointillist.plugins.integrators._mip_accel import HalfSampler, float_ordered

    data = {"int16": lambda: rng.integers(-2000, 2000, shape).astype(np.int16),
            "float16": lambda: (rng.standard_normal(shape) * 100).astype(np.float16),
            "tiny": lambda: (rng.standard_normal(shape) * 1e-5).astype(np.float16)}[kind]()
    if kind == "tiny":
        data.reshape(-1)[:3] = np.float16(-0.0)
    res = np.array(shape[::-1], np.float64)
    grid = [(np.arange(-1, 2 * int(r) + 2) / (2 * r)).astype(np.float32) for r in res]  # centres, faces, halves
    for filter_mode in ("linear", "nearest"):
        tex = volume_texture(Volume(data), filter=filter_mode, precision="half")
        storage = tex.texture.tensor().array.numpy()
        sampler = HalfSampler(mi.UInt32(storage.view(np.uint32)), shape[::-1], nearest=filter_mode == "nearest",
                              normal_only=float_ordered(storage.view(np.uint16)))
        points = [rng.uniform(-0.2, 1.2, (3, 5000)).astype(np.float32),
                  np.stack([g.ravel() for g in np.meshgrid(*grid, indexing="ij")])]
        for p in points:
            point = mi.Point3f(*(mi.Float(np.ascontiguousarray(c)) for c in p))
            expected = np.asarray(tex.texture.eval(point)[0])
            got = np.asarray(sampler(point))
            assert np.array_equal(got.view(np.uint32), expected.view(np.uint32)), filter_mode
    assert float_ordered(np.asarray(data, np.float16).view(np.uint16)) == (kind != "tiny")


@pytest.mark.parametrize("interpolation", ["trilinear", "nearest"])
def test_marches_with_word_lookups_equal_texture_marches(mi, interpolation):
    # the plain march and the brick march read half storage through word gathers; forced back to
    # the texture's own lookup they give the same bits (phantom and noise, oblique, mip and minip)
    from pointillist.mip import project_volume

    noisy = shepp_logan_phantom(24) + RNG.normal(0, 20, (24, 24, 24)).round().astype(np.int16)
    for volume in (shepp_logan_phantom((20, 18, 22)), noisy):
        for mode in ("mip", "minip", "average"):
            images = []
            for texture in (False, True):
                integrator = mi.load_dict({"type": "mip", "interpolation": interpolation, "mode": mode,
                                           "skip_bricks": mode != "average"})
                integrator.set_volume(Volume(volume))
                if texture:
                    integrator.stored.word_gathers = False
                    assert type(integrator.stored.lookup()).__name__ == "function"
                else:
                    assert type(integrator.stored.lookup()).__name__ == "HalfSampler"
                image, _ = project_volume(volume, integrator=integrator, view=None, azimuth=30.0, elevation=20.0,
                                          size=(40, 36))
                images.append(image)
            assert _same_bits(*images), mode


@pytest.mark.parametrize("shape", [(20, 17, 22), (8, 8, 8), (9, 16, 10), (1, 3, 2), (33, 5, 18)])
def test_brick_grid_from_words_equals_the_numpy_grid(mi, rng, shape):
    # the Dr.Jit brick grid over the stored halves: the same per-brick maxima and minima (dilated by
    # one voxel, clipped at the faces, partial bricks at the far faces) as brick_grid of the data
    from pointillist.imaging.volumes import volume_texture
    from pointillist.plugins.integrators._mip_accel import brick_grid, brick_grid_words, float_ordered

    data = rng.integers(-3000, 3000, shape).astype(np.int16)
    data[0, 0, 0], data[-1, -1, -1] = 32000, -32000  # extremes on the corners (outside half's exact range)
    for volume in (data, shepp_logan_phantom(shape)):
        tex = volume_texture(Volume(volume), precision="half")
        storage = tex.texture.tensor().array.numpy()
        for brick in (8, 4):
            upper, lower = brick_grid_words(mi.UInt32(storage.view(np.uint32)), shape, brick=brick,
                                            normal_only=float_ordered(storage.view(np.uint16)))
            if tex.exact:
                expected = brick_grid(volume, brick=brick, offset=tex.offset)
            else:
                expected = brick_grid(storage.reshape(shape), brick=brick)
            assert np.array_equal(upper, expected[0]) and np.array_equal(lower, expected[1])
    with pytest.raises(ValueError, match="even x size"):
        brick_grid_words(mi.UInt32(np.zeros(8, np.uint32)), (2, 2, 3))


@pytest.mark.parametrize("size", [(23, 17), (16, 16), (5, 3), (1, 1)])
def test_tiled_ray_order_gives_the_same_image(mi, monkeypatch, size):
    # project() casts its rays in 4 x 4 pixel blocks (partial blocks at the far edges pad with lanes
    # that are not written); rows of pixels give the same image, oblique and axis-aligned
    import pointillist.plugins.integrators.mip as mip_module
    from pointillist.mip import project_volume

    volume = VOLUMES["phantom_int16"]
    for view in (dict(view=None, azimuth=30.0, elevation=20.0), dict(view="coronal")):
        images = []
        for tile in (mip_module.TILE, 1):
            monkeypatch.setattr(mip_module, "TILE", tile)
            images.append(project_volume(volume, size=size, **view)[0])
        assert _same_bits(*images), view


def test_axial_fold_on_new_slices_and_shapes(mi, rng):
    # repeated axial folds (the kernels are reused): new data of the same shape, another shape, mip
    # and minip, keys and floats all give numpy's maxima and minima
    from pointillist.plugins.integrators._mip_accel import half_slices, reduce_half_words

    for shape in ((40, 6, 16), (40, 6, 16), (9, 4, 8), (40, 6, 16)):
        vol = rng.integers(-2048, 2049, shape).astype(np.float16)
        words = mi.UInt32(vol.view(np.uint32).ravel()) + 0
        slices = half_slices(words, shape)
        for mode, reduce in (("mip", np.max), ("minip", np.min)):
            for floats in (False, True):
                got = reduce_half_words(words, shape, 2, mode, floats=floats, slices=slices, group=8)
                assert np.array_equal(np.asarray(got), reduce(vol, axis=0).astype(np.float32).ravel())


def _decode_keys(keys: np.ndarray) -> np.ndarray:
    """An independent numpy decoder of 16-bit keys (the oracle of the Dr.Jit one): a key with the top
    bit set is a non-negative half with that bit flipped, else a negative one with every bit flipped."""
    keys = keys.astype(np.uint32)
    bits = np.where(keys & 0x8000, keys ^ 0x8000, ~keys & 0xFFFF).astype(np.uint16)
    return bits.view(np.float16).astype(np.float32)


def test_half_keys_order_every_finite_float16(mi):
    from pointillist.plugins.integrators._mip_accel import _half_key, _key_to_float

    bits = np.arange(1 << 16, dtype=np.uint32).astype(np.uint16)
    values = bits.view(np.float16)
    bits = bits[np.isfinite(values)]
    pairs = np.stack([bits, bits[::-1]], axis=1).ravel().view(np.uint32)  # (a, b) in one word
    lo, hi = (np.asarray(k) for k in _half_key(mi.UInt32(pairs)))
    finite = bits.view(np.float16).astype(np.float64)
    order = np.lexsort((~np.signbit(finite), finite))  # by value, -0 before +0 (IEEE maximum)
    sorted_values = bits.view(np.float16)[order].astype(np.float64)
    keys = lo[order]
    # keys rise with the value (strictly, except -0 < +0 which are equal values)
    assert np.all(np.diff(keys.astype(np.int64)) > 0)
    assert np.all(np.diff(sorted_values) >= 0)
    np.testing.assert_array_equal(_decode_keys(lo), bits.view(np.float16).astype(np.float32))
    np.testing.assert_array_equal(_decode_keys(hi), bits[::-1].view(np.float16).astype(np.float32))
    for keys, source in ((lo, bits), (hi, bits[::-1])):  # the Dr.Jit decoder, subnormals and -0 included
        decoded = np.asarray(_key_to_float(mi.UInt32(keys)))
        assert np.array_equal(decoded.view(np.uint32), source.view(np.float16).astype(np.float32).view(np.uint32))


def test_views_that_are_not_axis_aligned_columns_fall_back_to_the_march(mi):
    vol = VOLUMES["phantom_int16"]
    fast, plain = _pair(mi, vol, interpolation="nearest", skip_bricks=False)
    fast.skip_bricks = False
    from pointillist.mip import project_volume

    a, _ = project_volume(vol, integrator=fast, view=None, azimuth=30.0, elevation=0.0, size=(16, 16))
    assert fast.last_path == "march"
    a, _ = project_volume(vol, integrator=fast, view="axial", size=(16, 16), perspective=40.0)
    assert fast.last_path == "march"
    b, _ = project_volume(vol, integrator=plain, view="axial", size=(16, 16), perspective=40.0)
    assert _same_bits(a, b)
    # a camera inside the box does not see whole columns
    o = mi.Point3f([0.5, -1.5], [0.5, 0.5], [0.0, 0.0])
    ray = mi.Ray3f(o, mi.Vector3f(0, 0, 1))
    a, _ = fast.project_rays(ray)
    assert fast.last_path == "march"
    b, _ = plain.project_rays(ray)
    assert _same_bits(np.asarray(a), np.asarray(b))


def test_render_with_several_samples_per_pixel_uses_the_columns(mi):
    from pointillist.mip.views import sensor_dict, view_axes, view_frame

    vol = VOLUMES["odd_int16"]
    axes = view_axes("coronal")
    volume = Volume(vol)
    size, hw, hh = view_frame(volume.extent, axes, size=(20, 12))
    sensor = sensor_dict(mi, np.asarray(volume.extent), axes, size, hw, hh, None)
    sensor["sampler"]["sample_count"] = 4
    scene = mi.load_dict({"type": "scene", "sensor": sensor})
    fast, plain = _pair(mi, vol, interpolation="nearest", window="0,1000")
    a = np.asarray(fast.render(scene, seed=3))
    assert fast.last_path == "columns"
    b = np.asarray(plain.render(scene, seed=3))
    assert _same_bits(a, b)


# ---------------------------------------------------------------------------------------------
# Brick skipping (oblique views)
# ---------------------------------------------------------------------------------------------
BRICK_VOLUMES = {
    "random": RNG.random((11, 13, 10)).astype(np.float32),
    "phantom": shepp_logan_phantom((36, 40, 44)),
    "nan": np.where(RNG.random((18, 12, 20)) < 0.2, np.nan, RNG.random((18, 12, 20))).astype(np.float32),
    "constant": np.full((9, 17, 12), -1100, np.int16),
}


@pytest.mark.parametrize("name", sorted(BRICK_VOLUMES))
@pytest.mark.parametrize("mode", ["mip", "minip"])
@pytest.mark.parametrize("interpolation", ["nearest", "trilinear"])
def test_brick_skipping_equals_the_march_bit_for_bit(mi, name, mode, interpolation):
    from pointillist.mip import project_volume

    vol = BRICK_VOLUMES[name]
    props = {"mode": mode, "interpolation": interpolation, "background": -5.0, "fast_axis": False}
    fast, plain = (mi.load_dict({"type": "mip", "skip_bricks": s, **props}) for s in (True, False))
    for integrator in (fast, plain):
        integrator.set_volume(Volume(vol, (0.8, 1.0, 1.3)))
    for view in (dict(azimuth=30.0, elevation=20.0), dict(azimuth=-115.0, elevation=-40.0),
                 dict(azimuth=90.0, elevation=0.0), dict(azimuth=10.0, elevation=5.0, perspective=50.0)):
        a, _ = project_volume(vol, integrator=fast, view=None, size=(36, 28), **view)
        assert fast.last_path == "bricks"
        b, _ = project_volume(vol, integrator=plain, view=None, size=(36, 28), **view)
        assert plain.last_path == "march"
        assert _same_bits(a, b), view


def test_brick_skipping_with_a_camera_inside_and_rays_that_miss(mi):
    vol = BRICK_VOLUMES["phantom"]
    fast, plain = (mi.load_dict({"type": "mip", "skip_bricks": s, "background": -7.0}) for s in (True, False))
    pose = mi.ScalarTransform4f().translate([1.0, -2.0, 0.5]) @ mi.ScalarTransform4f().rotate([1, 1, 0], 35)
    for integrator in (fast, plain):
        integrator.set_volume(vol, to_world=pose)
    rng = np.random.default_rng(3)
    o = mi.Point3f(*(rng.random((3, 500)) * 60 - 30).astype(np.float32))  # box is 44 x 40 x 36
    d = rng.normal(size=(3, 500)).astype(np.float32)
    ray = mi.Ray3f(o, mi.Vector3f(*(d / np.linalg.norm(d, axis=0))))
    a, va = fast.project_rays(ray)
    b, vb = plain.project_rays(ray)
    assert _same_bits(np.asarray(a), np.asarray(b))
    assert np.array_equal(np.asarray(va), np.asarray(vb)) and 0 < np.asarray(va).sum() < 500


def test_brick_bounds_hold_every_sample(mi):
    # the bounds are the dilated brick max / min (nearest) widened by 2^-16 of the magnitude
    # (trilinear); check against a brute-force dilated max and against real trilinear lookups
    from pointillist.plugins.integrators._mip_accel import BRICK

    vol = BRICK_VOLUMES["phantom"].astype(np.float32) * 0.37  # non-integer: single precision
    integrator = mi.load_dict({"type": "mip"})
    integrator.set_volume(vol)
    upper, lower, grid = integrator.bricks.bounds()
    upper, lower = np.asarray(upper).reshape(grid), np.asarray(lower).reshape(grid)
    bz, by, bx = 2, 3, 1
    window = vol[bz * BRICK - 1:(bz + 1) * BRICK + 1, by * BRICK - 1:(by + 1) * BRICK + 1,
                 bx * BRICK - 1:(bx + 1) * BRICK + 1]
    assert window.max() < upper[bz, by, bx] <= window.max() + abs(window).max() * 2.0**-15
    rng = np.random.default_rng(5)
    nz, ny, nx = vol.shape
    points = rng.random((3, 20000))  # points inside every brick's box, texture coordinates
    cell = np.minimum((points * np.array([[nx], [ny], [nz]]) / BRICK).astype(int), np.array(grid)[::-1, None] - 1)
    values = np.asarray(integrator.stored.texture.texture.eval(mi.Point3f(*points.astype(np.float32)))[0])
    assert np.all(values <= upper[cell[2], cell[1], cell[0]])
    assert np.all(values >= lower[cell[2], cell[1], cell[0]])


def test_average_never_skips(mi):
    integrator = mi.load_dict({"type": "mip", "mode": "average"})
    integrator.set_volume(BRICK_VOLUMES["random"])
    integrator.project_rays(mi.Ray3f(mi.Point3f(0.1, 0.2, -20), mi.Vector3f(0.1, 0, 1)))
    assert integrator.last_path == "march"


@pytest.mark.parametrize("value,dtype,precision", [(-1100, np.int16, "single"), (40, np.int16, "single"),
                                                   (-1100, np.int16, "half"), (0.37, np.float32, "auto"),
                                                   (-3e4, np.float32, "auto")])
def test_flat_brick_samples_repeat_the_texture_arithmetic(mi, value, dtype, precision):
    # a constant volume's trilinear lookups are not all exactly the constant (rounded weights):
    # the flat-brick shortcut must reproduce each lookup's bits, not the constant
    vol = np.full((9, 10, 12), value, dtype)
    integrator = mi.load_dict({"type": "mip", "precision": precision})
    integrator.set_volume(vol)
    integrator.bricks.bounds()
    c = np.asarray(integrator.bricks.flat)
    assert np.all(c == c[0]) and c[0] == np.float32(value) - np.float32(integrator.stored.texture.offset)
    points = mi.Point3f(*np.random.default_rng(9).random((3, 50000)).astype(np.float32) * 1.2 - 0.1)
    texture = np.asarray(integrator.stored.texture.texture.eval(points)[0])
    flat = np.asarray(integrator.bricks.flat_sample(mi.Float(float(c[0])), points))
    assert np.array_equal(flat.view(np.uint32), texture.view(np.uint32))
    if c[0] != 0:  # (half precision stores value - offset = 0 here: exact)
        assert np.count_nonzero(texture != np.float32(c[0])) > 100  # the rounding is really there


@pytest.mark.parametrize("brick", [2, 4, 8])
def test_brick_grid_equals_brute_force_dilated_extremes(rng, mi, brick):
    from pointillist.plugins.integrators._mip_accel import brick_grid

    vol = rng.random((17, 9, 24)).astype(np.float32)
    vol[rng.random(vol.shape) < 0.1] = np.nan
    vol[:3, :3, :3] = np.nan  # a brick of NaN only (brick 2)
    upper, lower = brick_grid(vol, brick=brick, offset=0.25, slab=7)  # slabs that split bricks
    for index in np.ndindex(upper.shape):
        window = vol[tuple(slice(max(0, b * brick - 1), (b + 1) * brick + 1) for b in index)]
        finite = window[~np.isnan(window)]
        assert upper[index] == (np.float64(finite.max()) - 0.25 if finite.size else -np.inf)
        assert lower[index] == (np.float64(finite.min()) - 0.25 if finite.size else np.inf)
