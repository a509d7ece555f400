"""Medians by sorting networks held in registers: the fixed median-of-9 and median-of-25 networks,
and Batcher's odd-even merge sort for other window sizes (:func:`pointillist.imaging.filters.median`
uses them up to ``MEDIAN_NETWORK_MAX_SIZE``; larger windows use radix selection, :mod:`.rank`)."""

from __future__ import annotations

import drjit as dr
from drjit.llvm.ad import Float

__all__ = ["MEDIAN9", "MEDIAN25", "MEDIAN_NETWORKS", "batcher", "exchange", "median_of"]

#: Devillard's / Paeth's 19-exchange median-of-9 network (N. Devillard, "Fast median search:
#: an ANSI C implementation", 1998, ``opt_med9``); pairs (i, j) leave min in i, max in j.
MEDIAN9 = ((1, 2), (4, 5), (7, 8), (0, 1), (3, 4), (6, 7), (1, 2), (4, 5), (7, 8), (0, 3),
            (5, 8), (4, 7), (3, 6), (1, 4), (2, 5), (4, 7), (4, 2), (6, 4), (4, 2))


#: Devillard's 99-exchange median-of-25 network (N. Devillard 1998, ``opt_med25``, after
#: Graphics Gems); median in wire 12. Checked on all 2^25 0-1 inputs against Batcher's sort
#: (0-1 principle) in the tests. 113 exchanges remain of a pruned Batcher.
MEDIAN25 = (
    (0, 1), (3, 4), (2, 4), (2, 3), (6, 7), (5, 7), (5, 6), (9, 10), (8, 10), (8, 9), (12, 13),
    (11, 13), (11, 12), (15, 16), (14, 16), (14, 15), (18, 19), (17, 19), (17, 18), (21, 22),
    (20, 22), (20, 21), (23, 24), (2, 5), (3, 6), (0, 6), (0, 3), (4, 7), (1, 7), (1, 4),
    (11, 14), (8, 14), (8, 11), (12, 15), (9, 15), (9, 12), (13, 16), (10, 16), (10, 13),
    (20, 23), (17, 23), (17, 20), (21, 24), (18, 24), (18, 21), (19, 22), (8, 17), (9, 18),
    (0, 18), (0, 9), (10, 19), (1, 19), (1, 10), (11, 20), (2, 20), (2, 11), (12, 21), (3, 21),
    (3, 12), (13, 22), (4, 22), (4, 13), (14, 23), (5, 23), (5, 14), (15, 24), (6, 24), (6, 15),
    (7, 16), (7, 19), (13, 21), (15, 23), (7, 13), (7, 15), (1, 9), (3, 11), (5, 17), (11, 17),
    (9, 17), (4, 10), (6, 12), (7, 14), (4, 6), (4, 7), (12, 14), (10, 14), (6, 7), (10, 12),
    (6, 10), (6, 17), (12, 17), (7, 17), (7, 10), (12, 18), (7, 12), (10, 18), (12, 20),
    (10, 20), (10, 12))
#: Fixed median networks: window size -> (exchanges, wire holding the median).
MEDIAN_NETWORKS = {9: (MEDIAN9, 4), 25: (MEDIAN25, 12)}


def batcher(n: int) -> list[tuple[int, int]]:
    """Batcher's odd-even merge sort network on the next power of two >= n (Knuth, TAOCP 5.3.4)."""
    size = 1 << max(0, (n - 1).bit_length())
    pairs = []
    p = 1
    while p < size:
        k = p
        while k >= 1:
            for j in range(k % p, size - k, 2 * k):
                for i in range(min(k, size - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    return pairs


def exchange(a: Float, b: Float) -> tuple[Float, Float]:
    """Compare-exchange: (min, max) from one compare and two selects (``vminps``/``vmaxps``-like;
    ``dr.minimum``/``dr.maximum`` lower to NaN-propagating ``llvm.minimum``, 8x slower here)."""
    less = a < b
    return dr.select(less, a, b), dr.select(less, b, a)


def median_of(values: list[Float]) -> Float:
    """Median of the values with compare-exchanges only (Dr.Jit drops the unused halves)."""
    n = len(values)
    if n in MEDIAN_NETWORKS:
        network, middle = MEDIAN_NETWORKS[n]
        wires = list(values)
        for i, j in network:
            wires[i], wires[j] = exchange(wires[i], wires[j])
        return wires[middle]
    wires: list[Float | None] = list(values) + [None] * ((1 << (n - 1).bit_length()) - n)  # None = +inf
    for i, j in batcher(n):
        if wires[j] is None:
            continue                       # min(x, +inf) = x: nothing moves
        if wires[i] is None:
            wires[i], wires[j] = wires[j], None
            continue
        wires[i], wires[j] = exchange(wires[i], wires[j])
    return wires[n // 2]
