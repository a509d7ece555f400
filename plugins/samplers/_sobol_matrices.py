"""Sobol' generator matrices from Joe and Kuo's direction numbers (numpy only; no Mitsuba variant needed).

Column ``k`` of dimension ``j`` is the direction number ``V_{k+1} = m_{k+1} * 2^(31 - k)`` of Joe
and Kuo's table ``new-joe-kuo-6.21201`` (S. Joe, F. Y. Kuo, "Constructing Sobol sequences with
better two-dimensional projections", SIAM J. Sci. Comput. 30, 2008), derived with Bratley and
Fox's recurrence (:func:`joe_kuo_matrices`). The first :data:`SOBOL_DIMENSIONS` dimensions are
shipped in ``sobol_matrices.npz`` (32 KB); this module rebuilds that file from the copy of the
table that scipy ships::

    python -m pointillist.plugins.samplers._sobol_matrices

Point ``i`` of dimension ``j`` is the XOR of the columns of the bits set in ``i`` (natural order;
``scipy.stats.qmc.Sobol`` lists the same points in Gray-code order: its point ``n`` is point
``n ^ (n >> 1)`` here).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

__all__ = ["SOBOL_BITS", "SOBOL_DIMENSIONS", "SHIPPED_MATRICES", "joe_kuo_matrices", "sobol_matrices",
           "scipy_direction_numbers", "build_shipped_matrices", "sobol_points"]

#: Bits of a Sobol' coordinate (columns of a generator matrix).
SOBOL_BITS = 32

#: Dimensions shipped: a path of about 40 bounces of Mitsuba's ``path`` integrator (about 6
#: dimensions a bounce) stays inside them; the samplers pad the dimensions beyond.
SOBOL_DIMENSIONS = 256

SHIPPED_MATRICES = Path(__file__).with_name("sobol_matrices.npz")


def joe_kuo_matrices(poly: np.ndarray, vinit: np.ndarray, dimensions: int) -> np.ndarray:
    """Sobol' generator matrices from primitive polynomials and initial direction numbers.

    Parameters
    ----------
    poly : array of int
        Per dimension, the primitive polynomial of degree ``s`` as the bits ``1 a_1 ... a_{s-1} 1``
        (``1`` for the first dimension, the van der Corput sequence), as in scipy's copy of the
        Joe-Kuo table.
    vinit : array of int, shape (dimensions, >= s)
        The initial odd integers ``m_1 .. m_s`` of each dimension (``m_k < 2^k``).
    dimensions : int
        How many dimensions to build (``1 .. len(poly)``).

    Returns
    -------
    numpy.ndarray
        uint32 ``(dimensions, 32)``: column ``k`` (0-based) is ``m_{k+1} << (31 - k)``, where
        ``m_k = 2 a_1 m_{k-1} ^ 4 a_2 m_{k-2} ^ ... ^ 2^{s-1} a_{s-1} m_{k-s+1} ^ 2^s m_{k-s} ^ m_{k-s}``
        for ``k > s`` (Bratley and Fox, ACM TOMS 14, 1988).

    Examples
    --------
    >>> m = joe_kuo_matrices(np.array([1, 3]), np.array([[1], [1]]), 2)
    >>> [hex(v) for v in m[0, :3]], [hex(v) for v in m[1, :3]]
    (['0x80000000', '0x40000000', '0x20000000'], ['0x80000000', '0xc0000000', '0xa0000000'])
    """
    poly, vinit = np.asarray(poly), np.asarray(vinit)
    if isinstance(dimensions, bool) or not isinstance(dimensions, (int, np.integer)) \
            or not 1 <= dimensions <= len(poly):
        raise ValueError(f"dimensions: expected an integer in 1..{len(poly)}, got {dimensions!r}")
    out = np.zeros((int(dimensions), SOBOL_BITS), np.uint32)
    for j in range(int(dimensions)):
        p = int(poly[j])
        s = p.bit_length() - 1
        if s == 0:  # van der Corput: every m_k = 1
            m = [1] * SOBOL_BITS
        else:
            a = (p >> 1) & ((1 << (s - 1)) - 1)
            m = [int(v) for v in vinit[j, :s]]
            if any(v % 2 == 0 or v >= 1 << (k + 1) for k, v in enumerate(m)):
                raise ValueError(f"vinit: dimension {j}: expected odd m_k < 2^k, got {m}")
            for k in range(s, SOBOL_BITS):
                value = m[k - s] ^ (m[k - s] << s)
                for i in range(1, s):
                    if (a >> (s - 1 - i)) & 1:
                        value ^= m[k - i] << i
                m.append(value)
        out[j] = [(m[k] << (SOBOL_BITS - 1 - k)) & 0xFFFFFFFF for k in range(SOBOL_BITS)]
    return out


def scipy_direction_numbers() -> tuple[np.ndarray, np.ndarray]:
    """Joe and Kuo's table as scipy ships it beside ``scipy.stats.qmc.Sobol``: ``(poly, vinit)``."""
    import scipy.stats

    with np.load(Path(scipy.stats.__file__).with_name("_sobol_direction_numbers.npz")) as data:
        return data["poly"], data["vinit"]


@functools.lru_cache(maxsize=1)
def sobol_matrices() -> np.ndarray:
    """The shipped generator matrices: read-only uint32 ``(SOBOL_DIMENSIONS, 32)``.

    Examples
    --------
    >>> m = sobol_matrices()
    >>> m.shape, hex(m[0, 0]), hex(m[1, 1]), hex(m[2, 1])
    ((256, 32), '0x80000000', '0xc0000000', '0xc0000000')
    """
    with np.load(SHIPPED_MATRICES) as data:
        matrices = data["matrices"].astype(np.uint32)
    matrices.setflags(write=False)
    return matrices


def sobol_points(indices, dimensions: int) -> np.ndarray:
    """Unscrambled Sobol' points (numpy, natural order) from the shipped matrices, as 32-bit integers.

    Returns uint32 ``(len(indices), dimensions)``; divide by 2^32 for the points in [0, 1).

    Examples
    --------
    >>> (sobol_points([0, 1, 2, 3], 2) / 2**32).tolist()
    [[0.0, 0.0], [0.5, 0.5], [0.25, 0.75], [0.75, 0.25]]
    """
    indices = np.asarray(indices, np.uint64)
    matrices = sobol_matrices()[:dimensions].astype(np.uint64)
    out = np.zeros((indices.size, dimensions), np.uint64)
    for k in range(SOBOL_BITS):
        bit = ((indices >> np.uint64(k)) & np.uint64(1)).astype(bool)
        out[bit] ^= matrices[:, k]
    return out.astype(np.uint32)


def build_shipped_matrices(path: Path = SHIPPED_MATRICES) -> Path:
    """Write the shipped file from the Joe-Kuo table scipy ships."""
    poly, vinit = scipy_direction_numbers()
    np.savez_compressed(path, matrices=joe_kuo_matrices(poly, vinit, SOBOL_DIMENSIONS))
    return path


if __name__ == "__main__":
    print(build_shipped_matrices())
