"""pointillist.core.checks: the shared argument checks (TypeError for a wrong type, ValueError for a bad
value, the argument named), and the float32 rule for reals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pointillist.core import checks
from pointillist.core.checks import FLOAT32_MAX, boolean, choice, float32_finite, integer, real, seed, uint32


def test_float32_max_is_float32s_largest_finite_value():
    assert FLOAT32_MAX == 2.0**128 - 2.0**104 == float(np.finfo(np.float32).max)
    assert checks.UINT32_MAX == 4294967295


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_real_accepts_exactly_what_float32_holds(x):
    """A finite float64 passes exactly when its float32 rounding is finite too (the kernels' view)."""
    with np.errstate(over="ignore"):
        holds = bool(np.isfinite(np.float32(x)))
    if holds:
        assert real(x, "x") == x
    else:
        with pytest.raises(ValueError, match=r"^x: expected a number float32 can hold \(\|x\| <= 3.40282e\+38\)"):
            real(x, "x")


def test_real_edges_of_the_float32_range():
    assert real(FLOAT32_MAX, "a") == FLOAT32_MAX
    assert real(-FLOAT32_MAX, "a") == -FLOAT32_MAX
    # above FLOAT32_MAX but rounding down to it (less than half an ulp above): float32 holds it
    half_ulp = 2.0**103
    assert real(FLOAT32_MAX + half_ulp / 2, "a") == FLOAT32_MAX + half_ulp / 2
    for bad in (FLOAT32_MAX + half_ulp, 4e38, -4e38, 1e300, 10**400):
        with pytest.raises(ValueError, match="float32 can hold"):
            real(bad, "a")
    for bad in (math.nan, math.inf, -math.inf, np.float64("nan")):
        with pytest.raises(ValueError, match="^a: expected a finite number"):
            real(bad, "a")
    assert real(math.inf, "white", allow_inf=True) == math.inf


def test_real_bounds_hold_after_the_float32_cast():
    """1e-50 > 0 in float64 but is 0 in float32: refused as "> 0"; the message says why."""
    assert real(1e-45, "g", low=0, low_open=True) == 1e-45   # float32's smallest subnormal: > 0
    with pytest.raises(ValueError, match=r"^g: expected a number > 0, got 1e-50 \(0 in float32"):
        real(1e-50, "g", low=0, low_open=True)
    with pytest.raises(ValueError, match=r"^g: expected a number > 0, got 0$"):
        real(0, "g", low=0, low_open=True)
    assert real(0, "s", low=0) == 0.0
    with pytest.raises(ValueError, match=r"^s: expected a number >= 0, got -1$"):
        real(-1, "s", low=0)
    with pytest.raises(ValueError, match=r"^r: expected a number <= 255, got 255.5$"):
        real(255.5, "r", high=255)
    with pytest.raises(ValueError, match=r"^r: expected a number < 1, got 1$"):
        real(1.0, "r", high=1, high_open=True)
    # 1 + 1e-9 is above the bound 1 in float64 (refused whatever float32 says)
    with pytest.raises(ValueError, match=r"<= 1, got 1$"):
        real(1 + 1e-9, "r", high=1)


@pytest.mark.parametrize("bad", [True, np.bool_(False), "1", None, 1j, [1.0], np.array([1.0]), b"1"])
def test_real_refuses_other_types_with_a_type_error(bad):
    with pytest.raises(TypeError, match=r"^v: expected a number, got "):
        real(bad, "v")


def test_real_takes_numpy_scalars_and_returns_a_python_float():
    for value in (np.float32(0.5), np.float64(0.5), np.int8(3), np.uint64(7), 7):
        out = real(value, "v")
        assert type(out) is float and out == float(value)


def test_float32_finite_names_the_argument_and_the_quantity():
    assert float32_finite(1e38, "a", "the scale") == 1e38
    assert float32_finite(-FLOAT32_MAX, "a", "the scale") == -FLOAT32_MAX
    for bad in (1e39, -1e39, math.inf, math.nan):
        with pytest.raises(ValueError, match=r"^a: the scale is .*, beyond float32"):
            float32_finite(bad, "a", "the scale")


@given(st.integers(min_value=-2**70, max_value=2**70), st.integers(-5, 5), st.integers(-5, 5))
def test_integer_bounds(value, low, high):
    if low <= value <= high:
        assert integer(value, "n", low=low, high=high) == value
    else:
        with pytest.raises(ValueError, match=rf"^n: expected an integer in {low}\.\.{high}, got {value}$"):
            integer(value, "n", low=low, high=high)


def test_integer_types_and_one_sided_bounds():
    assert integer(np.int64(5), "n") == 5 and type(integer(np.int64(5), "n")) is int
    for bad in (2.0, True, "3", None, np.float32(1)):
        with pytest.raises(TypeError, match="^n: expected an integer, got "):
            integer(bad, "n")
    with pytest.raises(ValueError, match="^n: expected an integer >= 1, got 0$"):
        integer(0, "n", low=1)
    with pytest.raises(ValueError, match="^n: expected an integer <= 9, got 10$"):
        integer(10, "n", high=9)


def test_integers_type_then_length_then_bounds():
    assert checks.integers((480, np.int64(640)), "size", 2, low=1) == (480, 640)
    assert checks.integers(np.array([3, 4, 5]), "shape") == (3, 4, 5)
    assert checks.integers([], "shape") == ()
    for bad in ("64", 64, None, {1, 2}, b"ab"):  # not a sequence: TypeError, the argument named
        with pytest.raises(TypeError, match="^size: expected a sequence of integers, got "):
            checks.integers(bad, "size", 2)
    with pytest.raises(TypeError, match="^size: expected an integer, got float 2.5$"):
        checks.integers((2.5, 3), "size", 2)
    with pytest.raises(TypeError, match="^size: expected an integer, got bool True$"):
        checks.integers((True, 3), "size", 2)
    with pytest.raises(ValueError, match=r"^size: expected 2 integers, got 3: \(1, 2, 3\)$"):
        checks.integers((1, 2, 3), "size", 2)
    with pytest.raises(ValueError, match="^size: expected an integer >= 1, got 0$"):
        checks.integers((0, 3), "size", 2, low=1)


def test_boolean():
    assert boolean(True, "b") is True and boolean(np.bool_(False), "b") is False
    for bad in (1, 0, "true", None, 1.0):
        with pytest.raises(TypeError, match="^b: expected True or False, got "):
            boolean(bad, "b")


def test_choice_type_then_value():
    assert choice("wrap", "border", ("zero", "wrap")) == "wrap"
    assert choice(np.int64(8), "connectivity", (4, 8)) == 8 and type(choice(np.int64(8), "c", (4, 8))) is int
    with pytest.raises(ValueError, match=r"^border: expected one of 'zero', 'wrap', got 'Wrap'$"):
        choice("Wrap", "border", ("zero", "wrap"))
    with pytest.raises(TypeError, match=r"^border: expected one of 'zero', 'wrap', got int 3$"):
        choice(3, "border", ("zero", "wrap"))
    with pytest.raises(TypeError, match="got bool True"):   # True == 1, but it is not a count
        choice(True, "connectivity", (1, 4, 8))
    with pytest.raises(ValueError, match="got 6"):
        choice(6, "connectivity", (4, 8))


def test_uint32_and_seed():
    assert uint32(0, "spp") == 0 and uint32(2**32 - 1, "spp") == 2**32 - 1
    for bad in (-1, 2**32):
        with pytest.raises(ValueError, match=r"^spp: expected an integer in 0\.\.4294967295"):
            uint32(bad, "spp")
    assert seed(12) == 12
    with pytest.raises(ValueError, match="^seed: "):
        seed(-1)
    with pytest.raises(TypeError, match="^seed: "):
        seed(1.5)


def test_docstring_examples_run():
    import doctest

    result = doctest.testmod(checks, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 20 and result.failed == 0
