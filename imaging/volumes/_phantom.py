"""A 3-D Shepp-Logan CT phantom in Hounsfield units."""

from __future__ import annotations

from typing import Any

import numpy as np

from pointillist.core import checks

#: Voxels per slab when the phantom is evaluated (bounds its temporary memory).
_PHANTOM_SLAB_VOXELS = 8 << 20

#: The ten ellipsoids of the modified 3-D Shepp-Logan phantom, in Hounsfield units; geometry of
#: Matthias Schabel's ``phantom3d`` after Kak and Slaney ("Principles of Computerized
#: Tomographic Imaging", 1988), with additive Hounsfield-unit values chosen so
#: the sums are CT-like: air -1000 outside, skull bone 800, brain 40,
#: CSF-filled ventricles 5, lesions 70 and 100, and one 1200 HU calcification
#: (brighter than bone, so a MIP shows it through the skull). Columns: delta HU, semi-axes
#: a b c, centre x0 y0 z0 (in [-1, 1]), Euler angles phi theta psi (degrees).
SHEPP_LOGAN_HU = (
    (1800.0, 0.6900, 0.920, 0.810, 0.00, 0.0000, 0.00, 0.0, 0.0, 0.0),
    (-760.0, 0.6624, 0.874, 0.780, 0.00, -0.0184, 0.00, 0.0, 0.0, 0.0),
    (-35.0, 0.1100, 0.310, 0.220, 0.22, 0.0000, 0.00, -18.0, 0.0, 10.0),
    (-35.0, 0.1600, 0.410, 0.280, -0.22, 0.0000, 0.00, 18.0, 0.0, 10.0),
    (30.0, 0.2100, 0.250, 0.410, 0.00, 0.3500, -0.15, 0.0, 0.0, 0.0),
    (1160.0, 0.0460, 0.046, 0.050, 0.00, 0.1000, 0.25, 0.0, 0.0, 0.0),
    (60.0, 0.0460, 0.046, 0.050, 0.00, -0.1000, 0.25, 0.0, 0.0, 0.0),
    (60.0, 0.0460, 0.023, 0.050, -0.08, -0.6050, 0.00, 0.0, 0.0, 0.0),
    (60.0, 0.0230, 0.023, 0.020, 0.00, -0.6060, 0.00, 0.0, 0.0, 0.0),
    (60.0, 0.0230, 0.046, 0.020, 0.06, -0.6050, 0.00, 0.0, 0.0, 0.0),
)


def _euler(phi: float, theta: float, psi: float) -> np.ndarray:
    """Rotation matrix of phantom3d (z-x-z Euler angles in degrees)."""
    p, t, s = np.radians([phi, theta, psi])
    cp, sp, ct, st, cs, ss = np.cos(p), np.sin(p), np.cos(t), np.sin(t), np.cos(s), np.sin(s)
    return np.array([
        [cs * cp - ct * sp * ss, cs * sp + ct * cp * ss, ss * st],
        [-ss * cp - ct * sp * cs, -ss * sp + ct * cp * cs, cs * st],
        [st * sp, -st * cp, ct],
    ])


def shepp_logan_phantom(shape: int | tuple[int, int, int] = 64, *, dtype: Any = np.int16,
                        background: float = -1000.0) -> np.ndarray:
    """A 3-D Shepp-Logan head phantom in Hounsfield units, ``(Z, Y, X)``.

    Parameters
    ----------
    shape : int or (nz, ny, nx)
        Voxel counts; an int gives a cube. Each axis spans [-1, 1] (voxel centres).
    dtype : numpy dtype
        int16 (default, like CT scanners store HU) or a float type.
    background : float
        The value outside the head (air, -1000 HU).

    Returns
    -------
    numpy.ndarray
        Values -1000 (air), 800 (skull), 40 (brain), 5 (ventricles), 70 and
        100 (lesions) and 1200 (a calcification), from the additive ellipsoids
        of :data:`SHEPP_LOGAN_HU`.

    Notes
    -----
    Evaluated slab by slab with each ellipsoid restricted to the slices it
    meets, so a clinical 512 x 512 x 1800 phantom needs only its own memory.
    A one-voxel axis samples the centre plane (coordinate 0).

    Examples
    --------
    >>> from pointillist.imaging.volumes import shepp_logan_phantom
    >>> v = shepp_logan_phantom(32)
    >>> v.shape, v.dtype, int(v[0, 0, 0]), int(v[16, 16, 16])
    ((32, 32, 32), dtype('int16'), -1000, 40)
    """
    if isinstance(shape, (tuple, list, np.ndarray)):
        shape = checks.integers(shape, "shape", 3, low=1)
    else:
        shape = (checks.integer(shape, "shape", low=1),) * 3
    checks.real(background, "background")
    nz, ny, nx = shape
    out = np.empty(shape, dtype=dtype)

    def axis(n: int) -> np.ndarray:
        return (np.arange(n) + 0.5) / n * 2.0 - 1.0 if n > 1 else np.zeros(1)

    xs, ys, zs = axis(nx), axis(ny), axis(nz)
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    ellipsoids = []
    for value, a, b, c, x0, y0, z0, phi, theta, psi in SHEPP_LOGAN_HU:
        rot = _euler(phi, theta, psi)
        half_z = np.sqrt((rot[:, 2] ** 2 * np.array([a, b, c]) ** 2).sum())  # z half-extent
        ellipsoids.append((value, np.array([a, b, c]), np.array([x0, y0, z0]), rot, half_z))
    slab = max(1, _PHANTOM_SLAB_VOXELS // (nx * ny))
    for z_start in range(0, nz, slab):
        z = zs[z_start:z_start + slab]
        acc = np.full((len(z), ny, nx), background, dtype=np.float32)
        for value, axes, centre, rot, half_z in ellipsoids:
            hit = np.nonzero(np.abs(z - centre[2]) <= half_z + 1e-12)[0]
            if hit.size == 0:
                continue
            lo, hi = hit[0], hit[-1] + 1
            dz = (z[lo:hi] - centre[2])[:, None, None]
            dx, dy = (xx - centre[0])[None], (yy - centre[1])[None]
            q = np.zeros((hi - lo, ny, nx))
            for row in range(3):
                q += ((rot[row, 0] * dx + rot[row, 1] * dy + rot[row, 2] * dz) / axes[row]) ** 2
            acc[lo:hi] += np.where(q <= 1.0, value, 0.0).astype(np.float32)
        out[z_start:z_start + len(z)] = acc.astype(dtype) if np.issubdtype(np.dtype(dtype), np.integer) \
            else acc
    return out


# --------------------------------------------------------------------------------------------
# Dr.Jit textures
