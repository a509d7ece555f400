"""Patient orientation of medical volumes: the LPS frame, voxel-to-patient transforms, view labels.

The project's one patient frame is **LPS** (as DICOM and ITK use): +x points to the
patient's Left, +y to Posterior, +z to Superior, in millimetres. A volume's
``affine`` maps a voxel index ``(i, j, k, 1)`` (i along x of ``data[z, y, x]``, the
fastest axis) to LPS. NIfTI and RAS-space NRRD files are converted with
:data:`LPS_FROM_RAS` (negate x and y).

:func:`check_affine` splits an affine into voxel spacing (column norms) and
direction cosines and refuses sheared (non-orthogonal) ones; :func:`orientation_letters`
names a patient direction with the radiology letters (R/L, A/P, S/I);
:func:`view_labels` and :func:`draw_labels` put them at the middle of an image's edges.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pointillist.core import checks

__all__ = ["LPS_FROM_RAS", "ORTHOGONALITY_TOLERANCE", "check_affine", "snap_directions", "inverse_directions",
           "orientation_letters", "axis_codes", "view_labels", "draw_labels"]

#: ``diag(-1, -1, 1, 1)``: RAS+ (NIfTI, Slicer) coordinates to LPS and back (its own inverse).
LPS_FROM_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])

#: Largest ``|D^T D - I|`` entry accepted for the unit direction cosines ``D`` of an affine
#: (header round-off is ~1e-6; a 1 degree shear is 1.7e-2).
ORTHOGONALITY_TOLERANCE = 1e-4

#: Letters of the LPS axes' positive and negative directions.
_LETTERS = (("L", "R"), ("P", "A"), ("S", "I"))


def check_affine(affine: Any, *, name: str = "affine") -> tuple[np.ndarray, tuple[float, float, float], np.ndarray]:
    """Validate a voxel-to-patient affine: ``(affine 4x4, spacing, directions 3x3)``.

    Raises ``ValueError`` naming ``name`` for a non-finite or non-4x4 matrix, a zero
    column, or a sheared (non-orthogonal) transform.

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.orientation import check_affine
    >>> a, spacing, d = check_affine(np.diag([-2.0, 2.0, 3.0, 1.0]))
    >>> spacing, d.diagonal().tolist()
    ((2.0, 2.0, 3.0), [-1.0, 1.0, 1.0])
    """
    try:
        matrix = np.array(affine, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a 4x4 matrix of numbers, got {affine!r}") from None
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise ValueError(f"{name}: expected a finite 4x4 matrix, got shape {matrix.shape}")
    if not np.allclose(matrix[3], (0.0, 0.0, 0.0, 1.0)):
        raise ValueError(f"{name}: expected a last row 0 0 0 1, got {matrix[3].tolist()}")
    scale = np.abs(matrix[:3, :3]).max(axis=0)  # column norms without overflow (a spacing of 1e300)
    with np.errstate(invalid="ignore", divide="ignore"):
        norms = np.where(scale > 0, scale * np.linalg.norm(matrix[:3, :3] / np.where(scale > 0, scale, 1.0), axis=0),
                         0.0)
    if not np.all(norms > 0) or not np.all(np.isfinite(norms)):
        raise ValueError(f"{name}: a voxel axis has zero length (column norms {norms.tolist()})")
    directions = matrix[:3, :3] / norms
    error = float(np.abs(directions.T @ directions - np.eye(3)).max())
    if error > ORTHOGONALITY_TOLERANCE:
        raise ValueError(f"{name}: the voxel axes are not orthogonal (sheared transform, e.g. a CT gantry "
                         f"tilt; |D^T D - I| = {error:.3g}); resample the volume to an orthogonal grid first")
    return matrix, tuple(float(n) for n in norms), directions  # type: ignore[return-value]


def snap_directions(directions: Any, tolerance: float = 1e-6) -> np.ndarray:
    """Direction cosines with entries within ``tolerance`` of 0 or +-1 made exact.

    Header round-off (a qform quaternion, printed DICOM cosines) then does not turn an
    axis-aligned acquisition into a slightly oblique one: its views stay axis-aligned in
    voxel space and take the integrator's column fast path.
    """
    checks.real(tolerance, "tolerance", low=0.0, float32=False)
    d = np.array(directions, dtype=np.float64)
    d[np.abs(d) < tolerance] = 0.0
    d[np.abs(np.abs(d) - 1.0) < tolerance] = np.sign(d[np.abs(np.abs(d) - 1.0) < tolerance])
    return d


def inverse_directions(matrix: Any) -> np.ndarray:
    """Inverse of a rotation / reflection (3x3 direction cosines, or a 4x4 pose of them).

    A signed permutation (an axis-aligned acquisition, see :func:`snap_directions`) is inverted
    exactly by its transpose, so views along patient axes stay exactly along voxel axes (the
    ``mip`` integrator's column fast path); anything else by numpy's inverse.

    >>> inverse_directions([[0, 1, 0], [-1, 0, 0], [0, 0, 1]]).tolist()
    [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    """
    matrix = np.asarray(matrix, dtype=np.float64)
    if np.all(np.isin(matrix, (-1.0, 0.0, 1.0))):
        return matrix.T
    return np.linalg.inv(matrix)


def orientation_letters(vector: Any, *, threshold: float = 0.25, most: int = 3) -> str:
    """The radiology letters of an LPS direction, strongest component first.

    Components of the unit vector with magnitude >= ``threshold`` count (at most
    ``most``): ``(1, 0, 0)`` is ``"L"``, ``(0, -0.8, 0.6)`` is ``"AS"``.

    Examples
    --------
    >>> from pointillist.imaging.orientation import orientation_letters
    >>> orientation_letters((1, 0, 0)), orientation_letters((0, -0.8, 0.6)), orientation_letters((0, 0, -1))
    ('L', 'AS', 'I')
    """
    checks.real(threshold, "threshold", low=0.0, float32=False)
    checks.integer(most, "most", low=0)
    v = np.asarray(vector, dtype=np.float64)
    norm = float(np.linalg.norm(v))
    if v.shape != (3,) or not norm > 0:
        raise ValueError(f"vector: expected a nonzero 3-vector, got {vector!r}")
    v = v / norm
    order = np.argsort(-np.abs(v), kind="stable")
    letters = [_LETTERS[a][0 if v[a] > 0 else 1] for a in order if abs(v[a]) >= threshold]
    return "".join(letters[:most])


def axis_codes(directions: Any) -> str:
    """Where each voxel axis (i, j, k) points in LPS, e.g. ``"LPS"`` or ``"RAS"`` (strongest letter).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.orientation import axis_codes
    >>> axis_codes(np.diag([-1.0, 1.0, 1.0]))
    'RPS'
    """
    d = np.asarray(directions, dtype=np.float64)
    return "".join(orientation_letters(d[:, a], threshold=0.0, most=1) for a in range(3))


def view_labels(right: Any, up: Any) -> dict[str, str]:
    """Letters for the middle of each image edge, given the image's right and up in LPS.

    Returns ``{"left", "right", "top", "bottom"}`` -> letters (see :func:`orientation_letters`).

    Examples
    --------
    >>> from pointillist.imaging.orientation import view_labels
    >>> view_labels((1, 0, 0), (0, -1, 0))  # axial, radiological
    {'left': 'R', 'right': 'L', 'top': 'A', 'bottom': 'P'}
    """
    r, u = np.asarray(right, dtype=np.float64), np.asarray(up, dtype=np.float64)
    return {"left": orientation_letters(-r), "right": orientation_letters(r),
            "top": orientation_letters(u), "bottom": orientation_letters(-u)}


def draw_labels(image: np.ndarray, labels: dict[str, str]) -> np.ndarray:
    """Draw orientation letters at the middle of each edge of an 8-bit RGB image (a copy).

    Pillow's default font, white with a black outline (readable on any grey level),
    sized to about 1/20 of the image's smaller side (at least 10 pixels).

    Examples
    --------
    >>> import numpy as np
    >>> from pointillist.imaging.orientation import draw_labels
    >>> out = draw_labels(np.zeros((64, 64, 3), np.uint8), {"left": "R", "right": "L", "top": "A", "bottom": "P"})
    >>> out.shape, int(out.max()) > 200, int(out[20:44, 20:44].max())  # letters at the edges only
    ((64, 64, 3), True, 0)
    """
    from PIL import Image, ImageDraw, ImageFont

    rgb = np.asarray(image)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"image: expected an (H, W, 3) uint8 array, got {rgb.shape} {rgb.dtype}")
    height, width = rgb.shape[:2]
    size = max(10, min(width, height) // 20)
    try:
        font = ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        font = ImageFont.load_default()
    canvas = Image.fromarray(rgb)
    draw = ImageDraw.Draw(canvas)
    stroke = max(1, size // 8)
    margin = stroke + max(1, size // 4)
    anchors = {"left": ((margin, height / 2), "lm"), "right": ((width - 1 - margin, height / 2), "rm"),
               "top": ((width / 2, margin), "mt"), "bottom": ((width / 2, height - 1 - margin), "mb")}
    for edge, text in labels.items():
        if text:
            xy, anchor = anchors[edge]
            draw.text(xy, text, fill=(255, 255, 255), font=font, anchor=anchor, stroke_width=stroke,
                      stroke_fill=(0, 0, 0))
    return np.asarray(canvas)
