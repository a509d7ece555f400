"""Argument checks every layer shares: one rule for each kind of value.

Each function checks one argument and returns it as a plain Python value. The rule is the one
the plugins' property readers follow: a value of the wrong type raises ``TypeError``, a value
of the right type outside its domain raises ``ValueError``, and both messages start with the
argument's name and say what was expected (the command line prints them as one line).

Reals are checked for the computation they feed. Dr.Jit kernels compute in float32, so a number
that Python holds (float64) is accepted only when float32 holds it too: finite after the cast
(``|x| <= 3.4028235e38``, :data:`FLOAT32_MAX`) and inside the bounds after the cast as well, so
that ``1e-50`` is not "> 0" (float32 rounds it to 0). A quantity derived from checked arguments
(a slope, a reciprocal, a scale) can still overflow float32; :func:`float32_finite` checks it
and names the argument it comes from.

====================  ===================================================================
Function              Accepts
====================  ===================================================================
``real``              int or float (numpy scalars too, not bool) that float32 holds, in bounds
``real_array``        an array of such reals (a kernel, a table)
``float32_finite``    a float derived from checked arguments: finite in float32
``integer``           int (numpy integers too, not bool), in bounds
``integers``          a sequence of such ints (a shape, a size), of a given length
``boolean``           bool (numpy bool too)
``choice``            one of a fixed set of values (of the same type)
``uint32``            int in 0..2^32-1 (Mitsuba's and Dr.Jit's 32-bit counters)
``seed``              a :func:`uint32` named ``seed``
``numbers_text``      several reals written in one string: ``"1,2,3"``, ``"1 2 3"``, ``"1, 2, 3"``
``spacing``           a volume's voxel spacing written as text: three positive numbers
``exr_attribute``     an EXR header attribute: a name not OpenEXR's own, an int, float or str
``round_to_float32``  not a check: a real rounded to the nearest float32 (inf beyond its range)
====================  ===================================================================

Examples
--------
>>> from pointillist.core import checks
>>> checks.real(2.5, "gamma", low=0, low_open=True)
2.5
>>> checks.real(4e38, "hue")
Traceback (most recent call last):
...
ValueError: hue: expected a number float32 can hold (|x| <= 3.40282e+38), got 4e+38
>>> checks.real(1e-50, "gamma", low=0, low_open=True)
Traceback (most recent call last):
...
ValueError: gamma: expected a number > 0, got 1e-50 (0 in float32, the precision of the computation)
>>> checks.integer("3", "levels")
Traceback (most recent call last):
...
TypeError: levels: expected an integer, got str '3'
"""

from __future__ import annotations

import math
import numbers
import struct
import sys
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy is imported only by the checks of arrays: a command's -h or a plain render loads none
    import numpy as np

__all__ = ["FLOAT32_MAX", "UINT32_MAX", "real", "real_array", "float32_finite", "integer", "integers", "boolean",
           "choice", "uint32", "seed", "available_memory", "memory", "EXR_RESERVED", "EXR_INT_RANGE", "exr_attribute",
           "numbers_text", "spacing", "round_to_float32"]

#: The largest finite float32 (``numpy.finfo(numpy.float32).max``, 2^128 - 2^104).
FLOAT32_MAX = math.ldexp(2.0 - 2.0**-23, 127)

#: The largest value of a 32-bit unsigned counter (sample counts, seeds).
UINT32_MAX = 2**32 - 1


def _got(value: Any) -> str:
    """The type and value of a refused argument, shortly."""
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 60 else text[:57] + '...'}"


class _Never:
    """A type nothing is an instance of."""


def _numpy_type(name: str) -> type:
    """numpy's type ``name`` (``bool_``, ``ndarray``) when numpy is loaded, else :class:`_Never`: a
    value cannot be a numpy object unless numpy was imported, so the checks need not import it."""
    numpy = sys.modules.get("numpy")
    return getattr(numpy, name) if numpy is not None else _Never


def _is_bool(value: Any) -> bool:
    """A Python or numpy bool."""
    return isinstance(value, (bool, _numpy_type("bool_")))


def round_to_float32(value: float) -> float:
    """``value`` rounded to the nearest float32 (inf beyond its range), as a Python float; the
    float32 cast of numpy and of Dr.Jit's kernels, without numpy."""
    try:
        return struct.unpack("<f", struct.pack("<f", float(value)))[0]
    except OverflowError:  # rounds beyond float32's largest (or an int beyond float64)
        return math.inf if value > 0 else -math.inf


def real(value: Any, name: str, *, low: float | None = None, high: float | None = None,
         low_open: bool = False, high_open: bool = False, allow_inf: bool = False, float32: bool = True) -> float:
    """A real argument as a float that float32 holds, within ``[low, high]``.

    Parameters
    ----------
    value : int or float
        The argument (numpy integer and floating scalars are accepted; bool is not a number here).
    name : str
        Its name, the start of every message.
    low, high : float, optional
        Bounds (inclusive; exclusive with ``low_open`` / ``high_open``), checked on the value and
        on its float32 rounding.
    allow_inf : bool
        Accept +-inf (when the operation gives infinity a meaning, e.g. an infinite white point).
    float32 : bool
        Apply the float32 rule (default). ``False`` only for a value that never reaches float32
        itself, where the caller checks what does (e.g. a gamma whose kernel sees 1 / gamma).

    Returns
    -------
    float
        ``float(value)`` (not rounded: the caller may compute in float64 first).

    Raises
    ------
    TypeError
        If ``value`` is not a real number.
    ValueError
        If it is NaN, infinite (unless ``allow_inf``), beyond float32's range or outside the bounds.

    Examples
    --------
    >>> from pointillist.core.checks import real
    >>> real(3, "level")
    3.0
    >>> real(float("nan"), "level")
    Traceback (most recent call last):
    ...
    ValueError: level: expected a finite number, got nan
    """
    if _is_bool(value) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: expected a number, got {_got(value)}")
    try:
        number = float(value)
    except OverflowError:  # an int beyond float64
        raise ValueError(f"{name}: expected a number float32 can hold (|x| <= {FLOAT32_MAX:g}), got {value}") \
            from None
    if math.isnan(number) or (math.isinf(number) and not allow_inf):
        raise ValueError(f"{name}: expected a finite number, got {number:g}")
    rounded = round_to_float32(number) if float32 else number
    if math.isfinite(number) and not math.isfinite(rounded):
        raise ValueError(f"{name}: expected a number float32 can hold (|x| <= {FLOAT32_MAX:g}), got {number:g}")
    for bound, is_low, is_open in ((low, True, low_open), (high, False, high_open)):
        if bound is None:
            continue
        for candidate in (number, rounded):
            outside = (candidate < bound or (is_open and candidate == bound)) if is_low else \
                (candidate > bound or (is_open and candidate == bound))
            if outside:
                relation = (">" if is_open else ">=") if is_low else ("<" if is_open else "<=")
                note = "" if candidate == number else \
                    f" ({candidate:g} in float32, the precision of the computation)"
                raise ValueError(f"{name}: expected a number {relation} {bound:g}, got {number:g}{note}")
    return number


def real_array(values: Any, name: str) -> np.ndarray:
    """An array of reals (a kernel, a table) as float64 numpy, every value finite in float32.

    Shapes are the caller's to check. A non-numeric array (strings, objects, complex, bool) is a
    ``TypeError``; NaN, +-inf or a value beyond float32's range a ``ValueError``.

    Examples
    --------
    >>> from pointillist.core.checks import real_array
    >>> real_array([[1, 2], [3, 4]], "kernel").dtype
    dtype('float64')
    >>> real_array([1.0, 1e39], "table")
    Traceback (most recent call last):
    ...
    ValueError: table: expected values float32 can hold (|x| <= 3.40282e+38), got 1e+39 at index 1
    """
    import numpy as np

    try:
        array = np.asarray(values)
    except (TypeError, ValueError) as error:
        raise TypeError(f"{name}: expected an array of numbers, got {type(values).__name__}") from error
    if array.dtype == np.bool_ or not (np.issubdtype(array.dtype, np.integer) or
                                       np.issubdtype(array.dtype, np.floating)):
        raise TypeError(f"{name}: expected an array of numbers, got dtype {array.dtype}")
    array = array.astype(np.float64)
    bad = ~np.isfinite(array)
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name}: expected finite values, got {array[index]:g} at index "
                         f"{index[0] if len(index) == 1 else index}")
    with np.errstate(over="ignore"):
        over = ~np.isfinite(array.astype(np.float32))
    if over.any():
        index = tuple(int(i) for i in np.argwhere(over)[0])
        raise ValueError(f"{name}: expected values float32 can hold (|x| <= {FLOAT32_MAX:g}), got "
                         f"{array[index]:g} at index {index[0] if len(index) == 1 else index}")
    return array


def float32_finite(value: float, name: str, quantity: str) -> float:
    """Check a quantity derived from argument ``name`` (a slope, a reciprocal): finite in float32.

    Returns ``value``; a ValueError names the argument and the quantity otherwise.

    Examples
    --------
    >>> from pointillist.core.checks import float32_finite
    >>> float32_finite(255 / 1e-40, "r2", "the slope (s2 - s1) / (r2 - r1)")
    Traceback (most recent call last):
    ...
    ValueError: r2: the slope (s2 - s1) / (r2 - r1) is 2.55e+42, beyond float32 (|x| <= 3.40282e+38)
    """
    if not math.isfinite(round_to_float32(value)):
        raise ValueError(f"{name}: {quantity} is {value:g}, beyond float32 (|x| <= {FLOAT32_MAX:g})")
    return value


def integer(value: Any, name: str, *, low: int | None = None, high: int | None = None) -> int:
    """An integer argument in ``low..high`` (either bound optional).

    Examples
    --------
    >>> from pointillist.core.checks import integer
    >>> integer(4, "levels", low=2, high=256)
    4
    >>> integer(2.0, "levels")
    Traceback (most recent call last):
    ...
    TypeError: levels: expected an integer, got float 2.0
    """
    if _is_bool(value) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name}: expected an integer, got {_got(value)}")
    number = int(value)
    if (low is not None and number < low) or (high is not None and number > high):
        span = f"in {low}..{high}" if low is not None and high is not None else \
            (f">= {low}" if low is not None else f"<= {high}")
        raise ValueError(f"{name}: expected an integer {span}, got {number}")
    return number


def integers(value: Any, name: str, count: int | None = None, *, low: int | None = None,
             high: int | None = None) -> tuple[int, ...]:
    """A sequence of integers (a shape, a size): ``count`` of them when given, each in ``low..high``.

    Examples
    --------
    >>> from pointillist.core.checks import integers
    >>> integers((480, 640), "size", 2, low=1)
    (480, 640)
    >>> integers("64", "size", 2)
    Traceback (most recent call last):
    ...
    TypeError: size: expected a sequence of integers, got str '64'
    """
    if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, _numpy_type("ndarray"))):
        raise TypeError(f"{name}: expected a sequence of integers, got {_got(value)}")
    if count is not None and len(value) != count:
        raise ValueError(f"{name}: expected {count} integers, got {len(value)}: {tuple(value)!r}")
    return tuple(integer(item, name, low=low, high=high) for item in value)


def boolean(value: Any, name: str) -> bool:
    """A boolean argument (``True``/``False``; numpy's bool too, never 0/1 or a string).

    Examples
    --------
    >>> from pointillist.core.checks import boolean
    >>> boolean(True, "clamp")
    True
    >>> boolean(1, "clamp")
    Traceback (most recent call last):
    ...
    TypeError: clamp: expected True or False, got int 1
    """
    if not _is_bool(value):
        raise TypeError(f"{name}: expected True or False, got {_got(value)}")
    return bool(value)


def choice(value: Any, name: str, choices: Iterable[Any]) -> Any:
    """One of ``choices``; returns the matching choice.

    A value of another type than every choice (an int among strings, a bool among ints) is a
    ``TypeError``; one of the right type that is not a choice a ``ValueError``.

    Examples
    --------
    >>> from pointillist.core.checks import choice
    >>> choice("bicubic", "method", ("nearest", "bilinear", "bicubic"))
    'bicubic'
    >>> choice("lanczos", "method", ("nearest", "bilinear", "bicubic"))
    Traceback (most recent call last):
    ...
    ValueError: method: expected one of 'nearest', 'bilinear', 'bicubic', got 'lanczos'
    """
    options = tuple(choices)
    expected = ", ".join(map(repr, options))

    def kind(x: Any) -> str:
        return "bool" if _is_bool(x) else "str" if isinstance(x, str) else \
            "number" if isinstance(x, numbers.Number) else type(x).__name__

    if kind(value) not in {kind(option) for option in options}:
        raise TypeError(f"{name}: expected one of {expected}, got {_got(value)}")
    for option in options:
        if kind(option) == kind(value) and option == value:
            return option
    raise ValueError(f"{name}: expected one of {expected}, got {value!r}")


def uint32(value: Any, name: str) -> int:
    """An integer in 0..2^32-1 (what Mitsuba's and Dr.Jit's 32-bit counters hold).

    Examples
    --------
    >>> from pointillist.core.checks import uint32
    >>> uint32(2**32 - 1, "spp")
    4294967295
    >>> uint32(2**32, "spp")
    Traceback (most recent call last):
    ...
    ValueError: spp: expected an integer in 0..4294967295, got 4294967296
    """
    return integer(value, name, low=0, high=UINT32_MAX)


def seed(value: Any, name: str = "seed") -> int:
    """A random seed: an integer in 0..2^32-1 (a sample is reproducible from it; see :func:`uint32`).

    Examples
    --------
    >>> from pointillist.core.checks import seed
    >>> seed(7)
    7
    """
    return uint32(value, name)


def available_memory() -> int:
    """Bytes of memory this machine can give a new allocation now: Linux's ``MemAvailable`` (free
    memory and caches it can drop), else free pages; ``2**63 - 1`` where neither is known."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        import os

        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (OSError, ValueError, AttributeError):
        return 2**63 - 1


def memory(needed: int, what: str) -> None:
    """ValueError when ``needed`` bytes are more than this machine has available
    (:func:`available_memory`): said before allocating, instead of a MemoryError, a swap storm or a
    crash in a library that does not check.

    Examples
    --------
    >>> from pointillist.core.checks import memory
    >>> memory(1024, "a small image")
    >>> try:
    ...     memory(2**62, "the film")
    ... except ValueError as error:
    ...     print(str(error).split(", more than")[0])
    the film needs 4.6e+18 bytes (4294967296.0 GiB)
    """
    free = available_memory()
    if needed > free:
        raise ValueError(f"{what} needs {needed:.2g} bytes ({needed / 2**30:.1f} GiB), more than the "
                         f"{free / 2**30:.1f} GiB of memory available")


#: EXR header attributes that OpenEXR owns: metadata may not use these names.
EXR_RESERVED = frozenset({
    "channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio",
    "screenWindowCenter", "screenWindowWidth", "type", "tiles", "name", "version", "chunkCount",
})

#: The range of an EXR ``int`` attribute (32 bits).
EXR_INT_RANGE = (-2**31, 2**31 - 1)


def exr_attribute(key: Any, value: Any) -> int | float | str:
    """The metadata item ``key: value`` as an EXR header attribute holds it.

    ``key``: a non-empty str, not one of :data:`EXR_RESERVED`. ``value``: str; int (numpy integers
    too) within :data:`EXR_INT_RANGE`, an integer beyond it becomes its decimal text (an EXR ``int``
    has 32 bits: the text keeps a seed of 2^32 - 1 exact); bool (numpy bool too) becomes 0 or 1;
    a real (numpy floats too) a float.

    Examples
    --------
    >>> exr_attribute("spp", True), exr_attribute("seed", 2**32 - 1), exr_attribute("t", 0.5)
    (1, '4294967295', 0.5)
    >>> exr_attribute("channels", 3)
    Traceback (most recent call last):
    ...
    ValueError: metadata: 'channels' is a reserved EXR attribute name
    """
    if not isinstance(key, str) or not key:
        raise TypeError(f"metadata: keys must be non-empty str, got {key!r}")
    if key in EXR_RESERVED:
        raise ValueError(f"metadata: {key!r} is a reserved EXR attribute name")
    if isinstance(value, str):
        return value
    if _is_bool(value):
        return int(value)
    if isinstance(value, numbers.Integral):
        value = int(value)
        return value if EXR_INT_RANGE[0] <= value <= EXR_INT_RANGE[1] else str(value)
    if isinstance(value, numbers.Real):
        return float(value)
    raise TypeError(f"metadata[{key!r}]: expected int, float or str, got {type(value).__name__}")


def numbers_text(text: Any, name: str, count: int, *, what: str = "numbers", low: float | None = None,
                 low_open: bool = False) -> tuple[float, ...]:
    """``count`` reals written in one string, separated by commas and/or spaces (Mitsuba's way
    of writing a vector: ``"1,2,3"``, ``"1 2 3"``, ``"1, 2, 3"``), each checked as :func:`real`.

    ``what`` names the values in the message (``"positive numbers 'sx,sy,sz'"``).

    Examples
    --------
    >>> numbers_text("0.5, 0.5 2", "spacing", 3, low=0, low_open=True)
    (0.5, 0.5, 2.0)
    >>> numbers_text("1,,2", "spacing", 3)
    Traceback (most recent call last):
    ...
    ValueError: spacing: expected 3 numbers separated by commas or spaces, got '1,,2'
    """
    import re

    if not isinstance(text, str):
        raise TypeError(f"{name}: expected a string of {count} {what}, got {_got(text)}")
    parts = re.split(r"\s*,\s*|\s+", text.strip())
    try:
        values = [float(part) for part in parts]
    except ValueError:
        values = []
    if len(values) != count:
        raise ValueError(f"{name}: expected {count} {what} separated by commas or spaces, got {text!r}")
    try:
        return tuple(real(value, name, low=low, low_open=low_open) for value in values)
    except ValueError:
        raise ValueError(f"{name}: expected {count} {what}, got {text!r}") from None


def spacing(text: Any, name: str = "spacing") -> tuple[float, float, float]:
    """A volume's voxel spacing written as text (the ``mip`` integrator's ``spacing`` property and
    ``pointillist mip --spacing``): three positive numbers ``sx,sy,sz`` (commas and/or spaces).

    Examples
    --------
    >>> spacing("0.5,0.5,2")
    (0.5, 0.5, 2.0)
    >>> spacing("1,-2,1")
    Traceback (most recent call last):
    ...
    ValueError: spacing: expected 3 positive numbers 'sx,sy,sz', got '1,-2,1'
    """
    return numbers_text(text, name, 3, what="positive numbers 'sx,sy,sz'", low=0.0, low_open=True)  # type: ignore
