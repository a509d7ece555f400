"""The ``poisson`` sampler: Poisson-disk sub-pixel positions (Bridson's algorithm, toroidal)."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from pointillist.plugins.samplers._base import PIXEL_OFFSET_TAG, TEA_ROUNDS, PatternSampler, unit_float

__all__ = ["PoissonSampler", "poisson_disk_points", "generate_poisson_disk_points", "SHIPPED_COUNTS",
           "toroidal_min_distance", "hexagonal_radius", "BRIDSON_CANDIDATES", "START_RELATIVE_RADIUS", "RADIUS_STEP"]

#: Candidates tried around an active point before it is retired: k = 30, the value
#: of Bridson, "Fast Poisson disk sampling in arbitrary dimensions", SIGGRAPH 2007 sketch.
BRIDSON_CANDIDATES = 30

#: First radius tried, relative to the densest packing of ``n`` disks on the unit
#: torus (hexagonal, :func:`hexagonal_radius`). Lagae and Dutre ("A comparison of
#: methods for generating Poisson disk distributions", CGF 2008) recommend a
#: relative radius of 0.65 to 0.85; Bridson's maximal sets (k = 30) end near 0.72 on the torus.
START_RELATIVE_RADIUS = 0.72

#: Factor applied to the radius when a maximal set at the current radius has fewer
#: than ``n`` points.
RADIUS_STEP = 0.98

#: Largest point count generated (the sets are built in NumPy on first use).
MAX_POINTS = 1 << 16


def hexagonal_radius(n: int) -> float:
    """The largest possible minimum distance of ``n`` points on the unit torus.

    Hexagonal packing: each point owns a hexagon of area ``sqrt(3)/2 * r^2``, so
    ``r_max = sqrt(2 / (sqrt(3) * n))`` (Lagae and Dutre 2008).
    """
    return math.sqrt(2.0 / (math.sqrt(3.0) * n))


def toroidal_min_distance(points: np.ndarray) -> float:
    """Smallest pairwise distance of ``points`` (N, 2) in [0, 1)^2 on the unit torus.

    ``inf`` for fewer than two points.
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return math.inf
    delta = np.abs(points[:, None, :] - points[None, :, :])
    delta = np.minimum(delta, 1.0 - delta)
    dist = np.sqrt((delta ** 2).sum(-1))
    np.fill_diagonal(dist, np.inf)
    return float(dist.min())


def _bridson_torus(radius: float, rng: np.random.Generator, k: int = BRIDSON_CANDIDATES) -> np.ndarray:
    """A maximal Poisson-disk set on the unit torus (Bridson 2007 with a periodic grid).

    Each step takes a random active point, draws ``k`` candidates uniformly in the
    annulus [r, 2r] around it, and tests them all at once against the points
    within 3r (the only ones a candidate can conflict with); the first valid
    candidate is kept, or the active point retires when none is.
    """
    cells = max(int(math.floor(math.sqrt(2.0) / radius)), 1)  # cell side <= r / sqrt(2)
    grid = -np.ones((cells, cells), dtype=np.int64)
    reach = int(math.ceil(3.0 * radius * cells))
    window = np.arange(-reach, reach + 1)
    wrap_all = len(window) >= cells  # the 3r neighbourhood covers the whole torus
    capacity = int(2.0 / (math.sqrt(3.0) * radius * radius)) + 8
    points = np.empty((capacity, 2))
    points[0] = rng.random(2)
    grid[int(points[0, 1] * cells) % cells, int(points[0, 0] * cells) % cells] = 0
    count = 1
    active = [0]
    r2 = radius * radius
    while active:
        pick = int(rng.integers(len(active)))
        centre = points[active[pick]]
        angle = rng.random(k) * (2.0 * math.pi)
        dist = np.sqrt(rng.random(k) * 3.0 + 1.0) * radius  # uniform in area over the annulus
        cand = np.mod(centre + np.stack([np.cos(angle), np.sin(angle)], 1) * dist[:, None], 1.0)
        if wrap_all:
            near = grid.ravel()
        else:
            cx, cy = int(centre[0] * cells) % cells, int(centre[1] * cells) % cells
            near = grid[np.ix_((cy + window) % cells, (cx + window) % cells)].ravel()
        near = near[near >= 0]
        delta = np.abs(cand[:, None, :] - points[near][None, :, :])
        delta = np.minimum(delta, 1.0 - delta)
        ok = ((delta * delta).sum(-1) >= r2).all(1)
        hits = np.flatnonzero(ok)
        if hits.size and count < capacity:
            c = cand[hits[0]]
            cx, cy = int(c[0] * cells) % cells, int(c[1] * cells) % cells
            grid[cy, cx] = count
            points[count] = c
            active.append(count)
            count += 1
        else:
            active[pick] = active[-1]
            active.pop()
    return points[:count]


#: Precomputed sets shipped with the plugin (``python -m plugins.samplers.poisson``
#: rebuilds it): counts 1..1024 that are powers of two or squares. They are exactly
#: what :func:`generate_poisson_disk_points` returns (it is deterministic per count);
#: shipping them makes the set cost a file read instead of 2 to 120 ms of NumPy.
SHIPPED = Path(__file__).with_name("poisson_sets.npz")
SHIPPED_COUNTS = tuple(sorted({1 << k for k in range(11)} | {k * k for k in range(1, 33)}))


def _shipped(n: int) -> tuple[np.ndarray, float] | None:
    """The shipped set of ``n`` points (reads only that array), or None."""
    if n not in SHIPPED_COUNTS:
        return None
    try:
        with np.load(SHIPPED) as data:
            return data[f"p{n}"].astype(np.float32), float(data[f"r{n}"])
    except (OSError, ValueError, KeyError):
        return None


@functools.lru_cache(maxsize=64)
def poisson_disk_points(n: int) -> tuple[np.ndarray, float]:
    """``n`` Poisson-disk points on the unit torus and their radius (shipped or generated).

    The shipped set when there is one for ``n`` (:data:`SHIPPED_COUNTS`), else
    :func:`generate_poisson_disk_points`; cached per process.
    """
    shipped = _shipped(int(n)) if isinstance(n, (int, np.integer)) else None
    return shipped if shipped is not None else generate_poisson_disk_points(n)


def generate_poisson_disk_points(n: int) -> tuple[np.ndarray, float]:
    """``n`` Poisson-disk points on the unit torus and their radius.

    Runs Bridson's algorithm on the torus at radius ``r = 0.72 r_max(n)``; if the
    maximal set holds fewer than ``n`` points, ``r`` shrinks by 2% and it runs again;
    surplus points are dropped at random (dropping keeps the minimum distance). The
    generator is seeded with ``n``: the same count always gives the same set.

    Returns
    -------
    points : numpy.ndarray
        float32 (n, 2) in [0, 1)^2, no two closer than ``radius`` on the torus.
    radius : float
        The disk radius used (``inf`` for n = 1).

    Examples
    --------
    >>> pts, r = poisson_disk_points(16)
    >>> pts.shape, toroidal_min_distance(pts) >= r
    ((16, 2), True)
    """
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"sample_count: expected a positive integer, got {n!r}")
    if n > MAX_POINTS:
        raise ValueError(f"sample_count: the poisson sampler supports at most {MAX_POINTS} samples per "
                         f"pixel, got {n}")
    rng = np.random.default_rng(0x5EED0000 + int(n))
    if n == 1:
        return rng.random((1, 2)).astype(np.float32), math.inf
    radius = START_RELATIVE_RADIUS * hexagonal_radius(n)
    while True:
        points = _bridson_torus(radius, rng)
        if len(points) >= n:
            break
        radius *= RADIUS_STEP
    keep = np.sort(rng.choice(len(points), size=n, replace=False))
    points = points[keep].astype(np.float32)
    points = np.where(points >= 1.0, 0.0, points).astype(np.float32)  # float32 rounding of 1 - eps
    return points, float(radius)


class PoissonSampler(PatternSampler):
    r"""
    Poisson-disk sampler (:monosp:`poisson`)
    ----------------------------------------

    .. pluginparameters::

     * - sample_count
       - |int|
       - Number of samples per pixel (Default: 4), any count from 1 to 65536.
     * - seed
       - |int|
       - Seed offset (Default: 0).

    Every pixel uses the same set of ``sample_count`` Poisson-disk points on the unit
    torus (no two closer than ``r`` when distances wrap around the pixel), shifted by
    a random per-pixel offset modulo 1 (a Cranley-Patterson rotation hashed from
    ``(seed, pixel)``). The shift preserves toroidal distances, so inside each pixel
    no two samples are closer than ``r`` (across the boundary of two pixels with
    different shifts they may be).

    The sets come precomputed with the plugin (``poisson_sets.npz``: counts up to
    1024 that are powers of two or squares; a file read of under 3 ms) or, for other
    counts, are built once per count and process with Bridson's algorithm on the
    torus (k = 30 candidates; 2 ms for 16 points, 18 ms for 64, 120 ms for 1024):
    radius ``r = 0.72 r_max`` first, ``r_max = sqrt(2 / (sqrt(3) n))`` being the
    hexagonal (densest) packing, shrunk by 2% until the maximal set holds ``n``
    points; surplus points are dropped at random. Achieved minimum distances are
    0.70 to 0.72 ``r_max`` (higher for tiny counts; see :attr:`radius` and
    :attr:`relative_radius`): 16 points 0.20 pixel, 64 points 0.095, 256 points
    0.048. One sample is a uniformly random position (no distance to keep). The
    radius is derived from the count, so it is never too large for it.

    Only the image plane (the first 2D request after ``seed``) follows the pattern;
    other dimensions get decorrelated uniform random numbers.

    .. tabs::
        .. code-tab:: xml

            <sampler type="poisson">
                <integer name="sample_count" value="64"/>
            </sampler>

        .. code-tab:: python

            'type': 'poisson',
            'sample_count': 64
    """

    def _configure(self, spp: int) -> None:
        points, radius = poisson_disk_points(int(spp))
        self.points = points
        self.radius = radius
        self.relative_radius = radius / hexagonal_radius(spp) if spp > 1 else math.inf
        # Keep the Dr.Jit buffer in a tuple so that it is not traversed as per-lane state.
        self._buffer = (mi.Float(points.ravel()),)
        dr.eval(self._buffer[0])

    def _pattern(self, sample, pixel_key):
        buffer = self._buffer[0]
        x = dr.gather(mi.Float, buffer, sample * 2)
        y = dr.gather(mi.Float, buffer, sample * 2 + 1)
        u, v = mi.sample_tea_32(pixel_key, mi.UInt32(PIXEL_OFFSET_TAG), TEA_ROUNDS)
        x = x + unit_float(u)
        y = y + unit_float(v)
        x = dr.select(x >= 1.0, x - 1.0, x)
        y = dr.select(y >= 1.0, y - 1.0, y)
        return x, y

    def to_string(self) -> str:
        return (f"PoissonSampler[sample_count={self.sample_count()}, radius={self.radius:.4g}, "
                f"relative_radius={self.relative_radius:.3f}, seed={self._base_seed}]")


#: The plugin's class, which pointillist.plugins registers with Mitsuba under this file's name.
PLUGIN_CLASS = PoissonSampler


def _build_shipped() -> None:
    """Write :data:`SHIPPED` with the sets of :data:`SHIPPED_COUNTS`."""
    arrays = {}
    for n in SHIPPED_COUNTS:
        points, radius = generate_poisson_disk_points(n)
        arrays[f"p{n}"] = points
        arrays[f"r{n}"] = np.float64(radius if math.isfinite(radius) else np.inf)
    np.savez_compressed(SHIPPED, **arrays)


if __name__ == "__main__":  # python -m plugins.samplers.poisson (after the variant is set)
    _build_shipped()
