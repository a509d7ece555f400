"""Long reference renders with their own noise, cached outside git (``benchmarks/.cache/``).

A reference is two independent halves ``A`` and ``B`` of ``spp`` samples per pixel each (chunks
of :data:`CHUNK_SPP` spp with seeds that no progressive render uses). Their mean is the
reference ``R``; ``(A - B)^2 / 4`` estimates the variance of ``R`` per pixel and channel, so the
true relMSE of an image ``X`` is measured as

    mean((X - R)^2 - (A - B)^2 / 4) / (R^2 + eps)

(the expected squared error against ``R`` is the error against the truth plus ``var(R)``). The
cache key is the SHA-256 of the scene file and the files next to it that it names, the ``-D``
values and ``spp``.
"""

from __future__ import annotations

import hashlib
import json
import re
import time
from pathlib import Path

import numpy as np

CACHE = Path(__file__).resolve().parent / ".cache"
CHUNK_SPP = 512
SEED_BASE = 3_000_000_000   # chunk seeds SEED_BASE + 2 * chunk (+ 1 for half B)


def _key(scene: Path, params: dict, spp: int) -> str:
    digest = hashlib.sha256(scene.read_bytes())
    for name in sorted(set(re.findall(r'value="([^"$]+\.(?:exr|png|obj|ply|vol))"', scene.read_text()))):
        digest.update((scene.parent / name).read_bytes())
    digest.update(json.dumps(sorted(params.items())).encode())
    return f"{scene.stem}-{spp}-{digest.hexdigest()[:16]}"


def reference(scene_path: str | Path, params: dict, spp: int, *, progress: bool = True) -> dict:
    """``{"A", "B", "R", "var", "spp", "seconds"}`` of a reference (rendered once, then cached)."""
    from tqdm import tqdm

    scene_path = Path(scene_path)
    params = {k: str(v) for k, v in params.items()}
    path = CACHE / f"{_key(scene_path, params, spp)}.npz"
    if path.exists():
        with np.load(path) as data:
            a, b, seconds = data["A"], data["B"], float(data["seconds"])
    else:
        from pointillist.scene import load_scene, timed_render

        scene = load_scene(scene_path, params)
        halves, start = [], time.perf_counter()
        chunks = max(spp // CHUNK_SPP, 1)
        with tqdm(total=2 * chunks, desc=f"reference {scene_path.name}", disable=not progress) as bar:
            for half in range(2):
                total = None
                for c in range(chunks):
                    image = np.asarray(timed_render(scene, spp=spp // chunks, seed=SEED_BASE + 2 * c + half)[0],
                                       np.float64)
                    total = image if total is None else total + image
                    bar.update()
                halves.append(total / chunks)
        seconds = time.perf_counter() - start
        a, b = halves
        CACHE.mkdir(exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, A=a, B=b, seconds=seconds, spp=spp)
        tmp.replace(path)
        del scene
    r = 0.5 * (a + b)
    return {"A": a, "B": b, "R": r, "var": 0.25 * (a - b) ** 2, "spp": 2 * spp, "seconds": seconds}


def true_relmse(image, ref: dict, channels: int = 3) -> float:
    """relMSE of ``image`` against the reference with the reference's own noise subtracted."""
    from pointillist.imaging.metrics import RELMSE_EPSILON

    x = np.asarray(image, np.float64)[..., :channels]
    r, var = ref["R"][..., :channels], ref["var"][..., :channels]
    return float((((x - r) ** 2 - var) / (r * r + RELMSE_EPSILON)).mean())


def reference_noise(ref: dict, channels: int = 3) -> float:
    """The part of relMSE(X, R) that is the reference's own noise (what :func:`true_relmse` subtracts)."""
    from pointillist.imaging.metrics import RELMSE_EPSILON

    r, var = ref["R"][..., :channels], ref["var"][..., :channels]
    return float((var / (r * r + RELMSE_EPSILON)).mean())
