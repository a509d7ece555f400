"""Blue-noise threshold masks: Ulichney's void-and-cluster generator (an offline numpy tool).

The 64 x 64 mask shipped with the package (``imaging/data/blue_noise_64.npy``, read by
:func:`pointillist.imaging.dither.blue_noise_mask`) comes from :func:`void_and_cluster`.
"""

from __future__ import annotations

import numpy as np

from pointillist.core import checks

__all__ = ["void_and_cluster"]


def void_and_cluster(n: int = 64, *, sigma: float = 1.5, seed: int = 0, density: float = 0.1) -> np.ndarray:
    """An n x n blue-noise threshold mask by Ulichney's void-and-cluster method, entries 1..n^2.

    R. Ulichney, "The void-and-cluster method for dither array generation", Proc. SPIE 1913,
    1993. Energy = toroidal Gaussian (``sigma``) filter of the binary pattern. (1) A random initial
    pattern (``density`` of the cells, seeded) is relaxed by moving the tightest cluster's point to
    the largest void until that move changes nothing; (2) its points are ranked downward by
    repeatedly removing the tightest cluster; (3) ranks continue upward by filling the largest
    void up to half the cells; (4) then by turning off the tightest cluster of the remaining
    zeros. An offline tool (numpy; O(n^4) work): the shipped mask comes from it.

    Examples
    --------
    >>> from pointillist.imaging.blue_noise import void_and_cluster
    >>> sorted(void_and_cluster(4, seed=1).ravel().tolist()) == list(range(1, 17))
    True
    """
    n = checks.integer(n, "n", low=2, high=256)
    sigma = checks.real(sigma, "sigma", low=0.0, low_open=True)
    density = checks.real(density, "density", low=0.0, high=0.5, low_open=True, high_open=True)
    seed = checks.seed(seed)
    d = np.minimum(np.arange(n), n - np.arange(n)).astype(np.float64)
    kernel = np.exp(-(d[:, None] ** 2 + d[None, :] ** 2) / (2.0 * sigma * sigma))

    def splat(energy: np.ndarray, index: int, sign: float) -> None:
        y, x = divmod(index, n)
        energy += sign * np.roll(np.roll(kernel, y, axis=0), x, axis=1)

    rng = np.random.default_rng(seed)
    count = max(1, int(density * n * n))
    pattern_ = np.zeros((n, n), dtype=bool)
    pattern_.flat[rng.choice(n * n, count, replace=False)] = True
    energy = np.real(np.fft.ifft2(np.fft.fft2(pattern_) * np.fft.fft2(kernel)))
    for _ in range(n * n):
        cluster = int(np.argmax(np.where(pattern_, energy, -np.inf)))
        pattern_.flat[cluster] = False
        splat(energy, cluster, -1.0)
        void = int(np.argmin(np.where(pattern_, np.inf, energy)))
        pattern_.flat[void] = True
        splat(energy, void, 1.0)
        if void == cluster:
            break
    rank = np.zeros(n * n, dtype=np.int64)
    work, work_energy = pattern_.copy(), energy.copy()
    for r in range(count - 1, -1, -1):
        cluster = int(np.argmax(np.where(work, work_energy, -np.inf)))
        work.flat[cluster] = False
        splat(work_energy, cluster, -1.0)
        rank[cluster] = r
    work, work_energy = pattern_.copy(), energy.copy()
    for r in range(count, n * n // 2):
        void = int(np.argmin(np.where(work, np.inf, work_energy)))
        work.flat[void] = True
        splat(work_energy, void, 1.0)
        rank[void] = r
    # Phase 3: the zeros are now the minority; their energy is that of the inverted pattern.
    zero_energy = np.real(np.fft.ifft2(np.fft.fft2(~work) * np.fft.fft2(kernel)))
    for r in range(n * n // 2, n * n):
        cluster = int(np.argmax(np.where(work, -np.inf, zero_energy)))
        work.flat[cluster] = True
        splat(zero_energy, cluster, -1.0)
        rank[cluster] = r
    return rank.reshape(n, n) + 1
