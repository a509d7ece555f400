"""imaging.filters against docs/conventions.md, hand-worked cases, scipy.ndimage and OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import scipy.ndimage as ndi

import pointillist.imaging  # noqa: F401  (libLLVM first)
from pointillist.imaging import filters as F

SHAPES = [(1, 1), (2, 2), (5, 5), (7, 10), (6, 4, 3)]
#: our padded border modes -> scipy.ndimage mode, OpenCV border type (None: OpenCV has none for filter2D)
MODES = {"clamp": ("nearest", cv2.BORDER_REPLICATE), "reflect": ("reflect", cv2.BORDER_REFLECT),
         "mirror": ("mirror", cv2.BORDER_REFLECT_101), "wrap": ("wrap", None),
         "constant": ("constant", cv2.BORDER_CONSTANT)}


def image(rng, shape, scale=255.0):
    return (rng.random(shape) * scale).astype(np.float32)


def kernel_for(image_array, kernel):
    return kernel if image_array.ndim == 2 else kernel[..., None]


def out(x):
    return np.asarray(x)


# --- kernels and hand-worked cases ------------------------------------------------------------
def test_kernel_constants_follow_the_spec():
    assert F.SOBEL_X.tolist() == [[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]]
    assert F.SOBEL_Y.tolist() == [[1, 2, 1], [0, 0, 0], [-1, -2, -1]]
    assert F.PREWITT_X.tolist() == [[1, 0, -1]] * 3
    assert F.PREWITT_Y.tolist() == [[1, 1, 1], [0, 0, 0], [-1, -1, -1]]
    assert F.GAUSSIAN_3.tolist() == [[1, 3, 1], [3, 9, 3], [1, 3, 1]]
    assert F.LOW_PASS.tolist() == [[1] * 3] * 3
    assert F.HIGH_PASS.tolist() == [[-1, -1, -1], [-1, 8, -1], [-1, -1, -1]]
    assert F.HIGH_PASS.sum() == 0 and F.LAPLACIAN.sum() == 0


def test_gaussian_on_a_5x5_image_by_hand():
    img = np.array([[0, 0, 0, 0, 0],
                    [0, 10, 10, 10, 0],
                    [0, 10, 20, 10, 0],
                    [0, 10, 10, 10, 0],
                    [0, 0, 0, 0, 0]], dtype=np.float32)
    # centre: 9*20 + 3*(4*10) + 1*(4*10) = 180 + 120 + 40 = 340
    # (1,1): row 0 and column 0 are 0; 9*10 + 3*10 (right) + 3*10 (below) + 1*20 (diagonal) = 170
    # (1,2): row 0 is 0; row 1: 3*10 + 9*10 + 3*10 = 150; row 2: 1*10 + 3*20 + 1*10 = 80 -> 230
    expected = np.array([[0, 0, 0, 0, 0],
                         [0, 170, 230, 170, 0],
                         [0, 230, 340, 230, 0],
                         [0, 170, 230, 170, 0],
                         [0, 0, 0, 0, 0]], dtype=np.float32)
    np.testing.assert_array_equal(out(F.correlate(img, F.GAUSSIAN_3)), expected)
    np.testing.assert_array_equal(out(F.correlate(img, "gaussian", border="crop")), expected[1:4, 1:4])
    kept = out(F.correlate(img + 1, F.GAUSSIAN_3, border="keep"))
    np.testing.assert_array_equal(kept[0], np.ones(5))
    np.testing.assert_array_equal(kept[2, 2], 340 + 25)
    # normalised over the computed 3x3 only: (v - 170) * 255 / 170, ring stays 0
    norm = out(F.correlate(img, F.GAUSSIAN_3, normalize=True))
    np.testing.assert_allclose(norm[1:4, 1:4], (expected[1:4, 1:4] - 170) * 255 / 170, rtol=1e-6)
    assert norm[0].max() == 0 and norm[:, 0].max() == 0


def test_correlation_is_not_convolution():
    img = np.zeros((3, 3), np.float32)
    img[1, 2] = 1  # bright pixel right of the centre: correlation picks the kernel's right column
    assert out(F.correlate(img, F.SOBEL_X))[1, 1] == 2.0
    assert out(F.correlate(img, [[1, 2, 3]], border="crop")).tolist() == [[0.0], [3.0], [0.0]]


def test_negative_results_made_positive_by_absolute_value():
    img = np.array([[0, 0, 0, 0], [0, 10, 0, 0], [0, 0, 0, 0]], np.float32)
    raw = out(F.correlate(img, F.SOBEL_X))          # (1,2): -2*10 = -20 ; (1,1): 0
    assert raw[1, 2] == -20 and raw[1, 1] == 0
    norm = out(F.correlate(img, F.SOBEL_X, normalize=True))
    assert norm[1, 2] == 255 and norm[1, 1] == 0


# --- against scipy.ndimage and OpenCV ---------------------------------------------------------
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("border", list(MODES))
def test_padded_borders_match_scipy(rng, shape, border):
    img = image(rng, shape)
    for kernel in (F.GAUSSIAN_3, F.SOBEL_Y, rng.standard_normal((5, 3)).astype(np.float32),
                   rng.standard_normal((1, 7)).astype(np.float32)):
        expected = ndi.correlate(img.astype(np.float64), kernel_for(img, kernel).astype(np.float64),
                                 mode=MODES[border][0])
        got = out(F.correlate(img, kernel, border=border))
        np.testing.assert_allclose(got, expected, atol=2e-4 * max(1.0, np.abs(expected).max()))


@pytest.mark.parametrize("border", [b for b, (_, cv) in MODES.items() if cv is not None])
def test_padded_borders_match_opencv_filter2d(rng, border):
    img = image(rng, (9, 12, 3))
    kernel = rng.standard_normal((3, 5)).astype(np.float32)
    expected = cv2.filter2D(img, -1, kernel, borderType=MODES[border][1])
    np.testing.assert_allclose(out(F.correlate(img, kernel, border=border)), expected, atol=2e-3)


@pytest.mark.parametrize("shape", SHAPES)
def test_zero_keep_crop_interior_matches_scipy(rng, shape):
    img = image(rng, shape)
    kernel = F.HIGH_PASS
    ref = ndi.correlate(img, kernel_for(img, kernel), mode="nearest")
    interior = (slice(1, -1), slice(1, -1))
    zero = out(F.correlate(img, kernel))
    keep = out(F.correlate(img, kernel, border="keep"))
    np.testing.assert_allclose(zero[interior], ref[interior], atol=1e-3)
    ring = np.ones(shape[:2], bool)
    ring[interior] = False
    assert np.all(zero[ring] == 0)
    np.testing.assert_array_equal(keep[ring], img[ring])
    if shape[0] >= 3 and shape[1] >= 3:
        np.testing.assert_allclose(out(F.correlate(img, kernel, border="crop")), ref[interior], atol=1e-3)
    else:
        with pytest.raises(ValueError, match="crop"):
            F.correlate(img, kernel, border="crop")


def test_sobel_matches_opencv_and_components(rng):
    img = image(rng, (11, 13))
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    gy = -cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)  # the conventions' y is up
    mag, ox, oy = F.gradient(img, "sobel", border="clamp")
    np.testing.assert_array_equal(out(F.sobel(img, border="clamp")), out(mag))   # one magnitude, two ways
    np.testing.assert_allclose(out(ox), gx, atol=1e-3)
    np.testing.assert_allclose(out(oy), gy, atol=1e-3)
    np.testing.assert_allclose(out(mag), np.hypot(gx, gy), rtol=1e-5, atol=1e-3)
    zero = out(F.sobel(img))
    np.testing.assert_allclose(zero[1:-1, 1:-1], np.hypot(gx, gy)[1:-1, 1:-1], rtol=1e-5, atol=1e-3)
    assert zero[0].max() == 0 and zero[-1].max() == 0


def test_prewitt_and_laplacian_match_references(rng):
    img = image(rng, (8, 9, 3))
    px = ndi.correlate(img, F.PREWITT_X[..., None], mode="reflect")
    py = ndi.correlate(img, F.PREWITT_Y[..., None], mode="reflect")
    np.testing.assert_allclose(out(F.prewitt(img, border="reflect")), np.hypot(px, py), rtol=1e-5, atol=1e-3)
    lap = cv2.Laplacian(img, cv2.CV_32F, ksize=1, borderType=cv2.BORDER_REFLECT_101)
    np.testing.assert_allclose(out(F.laplacian(img, border="mirror")), lap, atol=1e-3)


@pytest.mark.parametrize("shape", [(1, 1), (2, 2), (6, 7), (9, 8, 3)])
@pytest.mark.parametrize("border", list(MODES))
def test_median_matches_scipy(rng, shape, border):
    img = image(rng, shape)
    for size in (3, 5):
        window = (size, size) if img.ndim == 2 else (size, size, 1)
        expected = ndi.median_filter(img, size=window, mode=MODES[border][0])
        np.testing.assert_array_equal(out(F.median(img, size, border=border)), expected)


def test_median_matches_opencv_and_7x7(rng):
    img = image(rng, (20, 23))
    for size in (3, 5):
        np.testing.assert_array_equal(out(F.median(img, size)), cv2.medianBlur(img, size))
    np.testing.assert_array_equal(out(F.median(img, 7, border="reflect")),
                                  ndi.median_filter(img, size=7, mode="reflect"))
    np.testing.assert_array_equal(out(F.median(img, 1)), img)
    zero = out(F.median(img, 3, border="zero"))
    assert zero[0].max() == 0
    np.testing.assert_array_equal(zero[1:-1, 1:-1], cv2.medianBlur(img, 3)[1:-1, 1:-1])


def test_median_removes_salt_noise_by_hand():
    img = np.full((5, 5), 10.0, np.float32)
    img[2, 2] = 255
    img[0, 4] = 0
    got = out(F.median(img))
    assert got[2, 2] == 10 and got[0, 4] == 10  # clamp border: window has 6 tens of 9 entries at the corner


# --- edges, zero crossings and normalisation ---------------------------------------------------
@pytest.mark.parametrize("value", [0.0, 255.0, 77.0])
def test_constant_images(value):
    img = np.full((6, 5, 3), value, np.float32)
    for border in ("zero", "clamp", "reflect", "wrap"):
        assert np.all(out(F.sobel(img, border=border)) == 0)
        assert np.all(out(F.prewitt(img, border=border)) == 0)
        assert np.all(out(F.laplacian(img, border=border)) == 0)
        assert np.all(out(F.correlate(img, F.SOBEL_X, border=border, normalize=True)) == 0)
    assert np.all(out(F.zero_crossings(F.laplacian(img))) == 0)
    assert np.all(out(F.normalize(img)) == 0)
    np.testing.assert_array_equal(out(F.median(img, 5)), img)


def test_zero_crossings_by_hand():
    lap = np.array([[1, -1, 0, 0],
                    [0, 0, 0, 2],
                    [0, 0, -3, 0],
                    [5, 0, 0, 0]], np.float32)
    eight = out(F.zero_crossings(lap))
    assert eight.tolist() == [[255, 0, 0, 0], [0, 0, 0, 255], [0, 0, 0, 0], [0, 0, 0, 0]]
    four = out(F.zero_crossings(lap, connectivity=4))   # (1,3) touches -3 only diagonally
    assert four.tolist() == [[255, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]]
    # no wrap-around: a negative value at the end of the previous row is not a neighbour
    row = np.array([[0, 0, -1], [1, 0, 0]], np.float32)
    assert out(F.zero_crossings(row))[1, 0] == 0


def test_zero_crossings_of_a_step_edge_are_on_the_edge():
    img = np.zeros((7, 8), np.float32)
    img[:, 4:] = 100
    edges = out(F.zero_crossings(F.laplacian(img)))
    # laplacian: +100 at x=3 (dark side), -100 at x=4; the crossing pixel is x=3 on the inner rows
    assert np.all(edges[1:-1, 3] == 255)
    assert edges.sum() == 255 * 5


def test_normalize_definition_and_edges():
    x = np.array([[-2.0, 1.0], [3.0, 5.0]], np.float32)
    np.testing.assert_allclose(out(F.normalize(x)), (np.abs(x) - 1) * 255 / 4)
    np.testing.assert_allclose(out(F.normalize(x, absolute=False)), (x + 2) * 255 / 7, rtol=1e-6)
    special = np.array([[np.nan, np.inf], [-np.inf, 10.0], [20.0, 30.0]], np.float32)
    got = out(F.normalize(special))
    assert np.isnan(got[0, 0]) and got[0, 1] == 255 and got[1, 0] == 255
    np.testing.assert_allclose(got[1:, :].ravel()[1:], [0, 127.5, 255])
    huge = np.array([[0.0, 3e38], [1e38, -3e38]], np.float32)
    np.testing.assert_allclose(out(F.normalize(huge)), [[0, 255], [85, 255]], rtol=1e-5)
    assert out(F.normalize(np.array([[5.0]]))).tolist() == [[0.0]]
    black = out(F.normalize(np.zeros((3, 3))))
    assert np.all(black == 0)


def test_one_pixel_and_tiny_images():
    one = np.array([[42.0]], np.float32)
    assert out(F.correlate(one, F.GAUSSIAN_3)).tolist() == [[0.0]]
    assert out(F.correlate(one, F.GAUSSIAN_3, border="clamp")).tolist() == [[42.0 * 25]]
    assert out(F.correlate(one, F.GAUSSIAN_3, normalize=True)).tolist() == [[0.0]]
    assert out(F.sobel(one)).tolist() == [[0.0]]
    assert out(F.median(one, 7)).tolist() == [[42.0]]
    assert out(F.zero_crossings(one)).tolist() == [[0.0]]


def test_nan_propagates_only_through_nonzero_weights():
    img = np.ones((5, 5), np.float32)
    img[2, 1] = np.nan
    got = out(F.correlate(img, F.SOBEL_Y))   # SOBEL_Y has zeros in its middle row
    assert np.isfinite(got[2, 2]) and np.isnan(got[1, 2]) and np.isnan(got[3, 1])


def test_threshold_spec():
    got = out(F.threshold(np.array([[127.9, 128.0, np.nan, 300.0]]), 128))
    assert got.tolist() == [[0.0, 255.0, 0.0, 255.0]]


# --- bad arguments --------------------------------------------------------------------------
@pytest.mark.parametrize("kernel", [np.ones((2, 3)), np.ones((3, 4)), np.zeros((0, 3)), [], "sobel_z",
                                    [[1, np.nan, 1]]])
def test_bad_kernels(kernel):
    with pytest.raises(ValueError, match="kernel"):
        F.correlate(np.ones((4, 4)), kernel)


def test_bad_arguments():
    img = np.ones((4, 4))
    with pytest.raises(ValueError, match="border"):
        F.correlate(img, F.SOBEL_X, border="replicate")
    with pytest.raises(ValueError, match="border"):
        F.median(img, 3, border=None)
    for size in (0, -3, 4):
        with pytest.raises(ValueError, match="size"):
            F.median(img, size)
    with pytest.raises(TypeError, match="size"):
        F.median(img, 3.0)
    with pytest.raises(ValueError, match="connectivity"):
        F.zero_crossings(img, connectivity=6)
    with pytest.raises(ValueError, match="level"):
        F.threshold(img, float("nan"))
    with pytest.raises(ValueError, match="image"):
        F.sobel(np.ones((2, 2, 2, 2)))


# --- post steps ---------------------------------------------------------------------------------
def test_post_steps_registered_and_run(rng, tmp_path, cli):
    from PIL import Image

    from pointillist.steps import parse_steps

    pipeline = parse_steps("sobel;normalize;threshold:level=128;median:5;correlate:gaussian,border=reflect;"
                           "laplacian;zero_crossings;prewitt;resize:3,2,bicubic")
    img = image(rng, (6, 7))
    current = img
    for spec, kwargs in pipeline:
        current = spec.function(current, **kwargs)
    assert out(current).shape == (2, 3)
    source = tmp_path / "in.png"
    from pointillist.imaging.io import write_png
    step = np.tile(np.where(np.arange(16) < 8, 40.0, 200.0).astype(np.float32), (12, 1))   # one vertical edge
    write_png(source, step, srgb=False, max_value=255.0)
    result = cli("post", source, "-o", tmp_path / "edges.png", "--steps", "sobel;normalize;threshold:level=128")
    assert result.returncode == 0, result.stderr
    ramp = np.asarray(Image.open(source).convert("L")).astype(np.float32)
    # normalize after a zero-border step leaves that step's uncomputed ring out
    expected = out(F.threshold(F.normalize(F.sobel(ramp), ring=1), 128))
    written = np.asarray(Image.open(tmp_path / "edges.png").convert("L")).astype(np.float32)
    np.testing.assert_array_equal(written, expected)
    assert (written[1:-1, 7:9] == 255).all() and (written[:, :6] == 0).all() and (written[:, 10:] == 0).all()
    assert (written[[0, -1]] == 0).all()  # the ring stays 0: not an edge of the image
    bad = cli("post", source, "-o", tmp_path / "bad.png", "--steps", "correlate:sobel_z")
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1


def test_normalize_leaves_the_uncomputed_ring_out():
    """``normalize`` alone counted the zero border ring, so ``normalize(correlate(...))``
    differed from ``correlate(..., normalize=True)`` (193..255 against 0..255 on a positive image);
    with ``ring`` the two agree, and ``post`` passes the ring of the window step before."""
    from pointillist.post import apply_steps

    img = (np.random.default_rng(17).random((5, 5)) * 200 + 50).astype(np.float32)  # positive: ring 0 = the min
    for kernel, border in (("gaussian", "zero"), ("sobel_x", "zero"), ("laplacian", "keep")):
        fused = out(F.correlate(img, kernel, border=border, normalize=True))
        apart = out(F.normalize(F.correlate(img, kernel, border=border), ring=1))
        np.testing.assert_array_equal(apart, fused)
        assert fused[1:4, 1:4].min() == 0 and fused[1:4, 1:4].max() == 255
    gauss = out(F.correlate(img, F.GAUSSIAN_3))
    inner = np.abs(gauss[1:4, 1:4])
    expected = (inner - inner.min()) * 255 / (inner.max() - inner.min())
    np.testing.assert_allclose(out(F.normalize(gauss, ring=1))[1:4, 1:4], expected, rtol=1e-6)
    assert out(F.normalize(gauss))[1:4, 1:4].min() > 150      # the whole image: the ring's 0 is the min
    steps = apply_steps(img, "correlate:gaussian;normalize")
    np.testing.assert_array_equal(out(steps.image), out(F.correlate(img, "gaussian", normalize=True)))
    assert steps.done == ["correlate:kernel=gaussian", "normalize:ring=1"]
    assert out(apply_steps(img, "correlate:gaussian,border=reflect;normalize").image).min() == 0
    for bad in (-1, (1,)):
        with pytest.raises(ValueError, match="^ring: "):
            F.normalize(img, ring=bad)
    for bad in (1.5, True, "1"):  # not an integer: a TypeError (the argument contract)
        with pytest.raises(TypeError, match="^ring: expected an integer"):
            F.normalize(img, ring=bad)


def test_the_signs_the_conventions_state_against_scipy_opencv_and_scikit_image():
    """SOBEL_Y and PREWITT_Y are positive upwards, PREWITT_X positive leftwards (the conventions
    page and the docstrings say so): the opposite of scipy's, OpenCV's and scikit-image's."""
    import cv2
    import scipy.ndimage as ndi
    import skimage.filters as skf

    from pointillist.imaging.filters import correlate

    right = np.tile(np.arange(7, dtype=np.float32) * 3, (7, 1))   # intensity grows to the right
    down = right.T.copy()                                          # ... and downwards
    inner = (slice(1, -1), slice(1, -1))
    ours = {name: np.asarray(correlate(image, name))[inner]
            for name, image in (("sobel_x", right), ("prewitt_x", right), ("sobel_y", down), ("prewitt_y", down))}
    np.testing.assert_allclose(ours["sobel_x"], ndi.sobel(right, axis=1)[inner])
    np.testing.assert_allclose(ours["sobel_x"], cv2.Sobel(right, cv2.CV_32F, 1, 0)[inner])
    np.testing.assert_allclose(ours["sobel_y"], -ndi.sobel(down, axis=0)[inner])
    np.testing.assert_allclose(ours["sobel_y"], -cv2.Sobel(down, cv2.CV_32F, 0, 1)[inner])
    np.testing.assert_allclose(ours["prewitt_x"], -ndi.prewitt(right, axis=1)[inner])
    np.testing.assert_allclose(ours["prewitt_x"], -3 * skf.prewitt_v(right)[inner], rtol=1e-6)
    np.testing.assert_allclose(ours["prewitt_y"], -ndi.prewitt(down, axis=0)[inner])
    assert ours["sobel_y"].min() < 0 and ours["prewitt_x"].max() < 0   # the signs are not zero by accident


def test_gradient_is_one_return_type_and_refuses_unknown_operators(rng):
    """sobel and prewitt return the magnitude only; gradient returns (magnitude, gx, gy) by name."""
    img = image(rng, (7, 9))
    g = F.gradient(img, "prewitt")
    assert isinstance(g, F.Gradient) and all(type(part).__name__ == "TensorXf" for part in g)
    np.testing.assert_array_equal(out(g.magnitude), out(F.prewitt(img)))
    np.testing.assert_allclose(out(g.gx)[1:-1, 1:-1], out(F.correlate(img, "prewitt_x"))[1:-1, 1:-1], rtol=1e-6)
    with pytest.raises(ValueError, match="operator: expected one of 'sobel', 'prewitt', got 'canny'"):
        F.gradient(img, "canny")
    with pytest.raises(TypeError):
        F.sobel(img, components=True)
