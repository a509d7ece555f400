"""The seeds of a progressive render's passes: pass ``k`` of a render with seed ``s`` renders with
Mitsuba's seed ``(TEA(s, 0) + k) mod 2^32``.

Passes of one render never share a seed (for fewer than 2^32 passes), and renders with other seeds
start at hashed, unrelated offsets. :func:`tea32` is the TEA hash Mitsuba seeds its own samplers
with (``mi.sample_tea_32``), on Python ints.
"""

from __future__ import annotations

from pointillist.core.checks import UINT32_MAX

__all__ = ["tea32", "pass_seed"]


def tea32(v0: int, v1: int, rounds: int = 4) -> tuple[int, int]:
    """The TEA hash Mitsuba seeds with (``mi.sample_tea_32``), on Python ints.

    Examples
    --------
    >>> from pointillist.progressive.seeds import tea32
    >>> tea32(0, 0)
    (1576399551, 1422788794)
    """
    m = UINT32_MAX  # the mask of 32-bit unsigned arithmetic
    v0, v1, total = v0 & m, v1 & m, 0
    for _ in range(rounds):
        total = (total + 0x9E3779B9) & m
        v0 = (v0 + ((((v1 << 4) + 0xA341316C) & m) ^ ((v1 + total) & m) ^ ((v1 >> 5) + 0xC8013EA4))) & m
        v1 = (v1 + ((((v0 << 4) + 0xAD90777D) & m) ^ ((v0 + total) & m) ^ ((v0 >> 5) + 0x7E95761E))) & m
    return v0, v1


def pass_seed(seed: int, index: int) -> int:
    """Mitsuba seed of pass ``index`` (0, 1, ...) of a render with ``seed``: ``(TEA(seed, 0) + index) mod 2^32``.

    Passes of one render never share a seed (for fewer than 2^32 passes); renders with other
    seeds start at hashed, unrelated offsets.

    Examples
    --------
    >>> from pointillist.progressive.seeds import pass_seed
    >>> [pass_seed(0, k) for k in range(3)]
    [1576399551, 1576399552, 1576399553]
    """
    return (tea32(int(seed), 0)[0] + int(index)) & UINT32_MAX
