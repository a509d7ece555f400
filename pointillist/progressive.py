"""Progressive rendering: passes, a running error estimate without a reference, and budgets.

A progressive render is a sequence of *passes*: ``mi.render(scene, spp=n_k, seed=s_k)``, each an
independent estimate of the image (its own seed, :func:`pass_seed`). The passes are accumulated
per pixel and channel with Welford's update in the weighted form of West (1979), weights = the
passes' sample counts, in float64:

    W += n;  delta = x - mean;  mean += (n / W) * delta;  M2 += n * delta * (x - mean)

With a box reconstruction filter a pass image is the plain mean of its samples in each pixel, so
``mean`` is the mean of all ``W`` samples: statistically one render of ``W`` spp (bit for bit the
same mean when every pass gives the same image, e.g. a deterministic estimator with a seed-free
sampler). If a sample has variance ``sigma^2``, a pass of ``n`` spp has ``sigma^2 / n`` and
``E[M2] = (K - 1) sigma^2`` for ``K`` passes of any sizes, so

    var_of_mean = M2 / ((K - 1) * W)          (unbiased; needs K >= 2)

**Estimated relMSE** (the relMSE of :func:`pointillist.imaging.metrics.image_errors`, epsilon
:data:`pointillist.imaging.metrics.RELMSE_EPSILON`, without the reference ``r``): the expected squared
error of a pixel is ``var_of_mean``; its reference is unknown, and the running mean is a noisy
stand-in whose square is biased high, ``E[mean^2] = r^2 + var``, which makes the plain
``var / (mean^2 + eps)`` under-estimate noisy images (by up to 2-3x at a few passes of a path
tracer). The denominator therefore subtracts the variance, but never goes below a quarter of
``mean^2`` (where the noise exceeds the mean, ``mean^2 - var`` says nothing and would put the
pixel at the ``eps`` floor)::

    estimated_relmse = mean over pixels and colour channels of
                       var_of_mean / (max(mean^2 - var_of_mean, mean^2 / 4) + eps)

It is reported from :data:`MIN_PASSES` passes on (before: NaN). It assumes the passes are
independent and the estimator unbiased; it under-estimates the error of rare bright paths
(fireflies: a pixel whose few hits all landed in one pass, or in none), of samplers whose passes
are correlated (a seed-free ``grid`` gives identical passes: estimate 0) and of biased estimators
(clamping, a ``max_depth`` cut-off: the bias is not in the spread).

:func:`render_passes` is the engine (a generator of ``(image so far, PassStats)``),
:class:`Budget` decides the size of each pass (time, error and spp budgets, auto pass size),
:func:`render_progressive` is the workflow of ``pointillist render --time/--target-error``
(progress bar, checkpoints, resume, Ctrl-C/SIGTERM) and :func:`write_progress` writes the
``.progress.csv`` log and the log-log ``.progress.png`` plot.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pointillist import signals
from pointillist.errors import UsageError
from pointillist.imaging.metrics import RELMSE_EPSILON
from pointillist.scene import MAX_SAMPLES, RenderTiming, scene_info, timed_render

__all__ = ["MIN_PASSES", "TARGET_PASS_SECONDS", "FIRST_PASS_SAMPLES", "CHECKPOINT_VERSION", "pass_seed",
           "tea32", "PassStats", "Accumulator", "Budget", "render_passes", "ProgressiveResult",
           "render_progressive", "write_progress", "checkpoint_path", "progress_paths", "scene_fingerprint"]

#: Passes before the first error estimate (the spread of fewer passes is too noisy to use: at 4
#: passes the estimate was off by up to 2x on small path-traced images, at 8 within 1.8x).
MIN_PASSES = 8

#: Auto pass size: aim at passes of about this many seconds (at most an eighth of a time budget).
#: A pass costs tens of ms besides its samples (tracing the integrator again, film set-up, the
#: tail of each kernel): passes of ~1 s measured 6-9 % of overhead at 256x256-512x512 here
#: (benchmarks/RESULTS.md), so passes are twice that.
TARGET_PASS_SECONDS = 2.0

#: Auto pass size: samples (pixels x spp) of the first pass, which also compiles the kernels.
FIRST_PASS_SAMPLES = 2**18

#: Format version of the checkpoint file (2: the inputs' digest and a checksum of the contents).
CHECKPOINT_VERSION = 2

_U32 = 0xFFFFFFFF


def tea32(v0: int, v1: int, rounds: int = 4) -> tuple[int, int]:
    """The TEA hash Mitsuba seeds with (``mi.sample_tea_32``), on Python ints.

    Examples
    --------
    >>> tea32(0, 0)
    (1576399551, 1422788794)
    """
    v0, v1, total = v0 & _U32, v1 & _U32, 0
    for _ in range(rounds):
        total = (total + 0x9E3779B9) & _U32
        v0 = (v0 + ((((v1 << 4) + 0xA341316C) & _U32) ^ ((v1 + total) & _U32) ^ ((v1 >> 5) + 0xC8013EA4))) & _U32
        v1 = (v1 + ((((v0 << 4) + 0xAD90777D) & _U32) ^ ((v0 + total) & _U32) ^ ((v0 >> 5) + 0x7E95761E))) & _U32
    return v0, v1


def pass_seed(seed: int, index: int) -> int:
    """Mitsuba seed of pass ``index`` (0, 1, ...) of a render with ``seed``: ``(TEA(seed, 0) + index) mod 2^32``.

    Passes of one render never share a seed (for fewer than 2^32 passes); renders with other
    seeds start at hashed, unrelated offsets.

    Examples
    --------
    >>> [pass_seed(0, k) for k in range(3)]
    [1576399551, 1576399552, 1576399553]
    """
    return (tea32(int(seed), 0)[0] + int(index)) & _U32


@dataclass(frozen=True)
class PassStats:
    """Where a progressive render stands after a pass (``passes == 0``: before the first).

    ``seconds``: render seconds of all passes so far (rendering, JIT compilation, accumulation;
    resumed renders include the earlier ones); ``compile_seconds``: the JIT compilation part;
    ``estimated_relmse``: NaN before :data:`MIN_PASSES` passes; ``seed``: the Mitsuba seed of
    the last pass.
    """

    passes: int
    spp: int
    pass_spp: int
    seconds: float
    pass_seconds: float
    pass_compile_seconds: float
    compile_seconds: float
    estimated_relmse: float
    width: int
    height: int
    seed: int = 0

    def seconds_per_spp(self) -> float:
        """Seconds one spp of the last pass took, JIT compilation left out (NaN before a pass)."""
        if self.pass_spp < 1:
            return math.nan
        return max(self.pass_seconds - self.pass_compile_seconds, 1e-9) / self.pass_spp


class Accumulator:
    """Per-pixel, per-channel weighted Welford sums of pass images, in float64 (immutable).

    ``mean`` and ``m2`` are Dr.Jit float64 tensors of the image's shape; ``weight`` the spp so
    far, ``passes`` the number of passes. :meth:`add` returns a new accumulator, so a render
    interrupted at any point keeps a consistent one.

    Examples
    --------
    >>> import numpy as np, pointillist
    >>> mi = pointillist.setup()
    >>> acc = Accumulator.empty()
    >>> for x, n in [(1.0, 1), (3.0, 1), (2.0, 2)]:
    ...     acc = acc.add(mi.TensorXf(np.full((1, 1, 1), x, np.float32)), n)
    >>> float(acc.mean.numpy()[0, 0, 0]), float(acc.variance_of_mean().numpy()[0, 0, 0])
    (2.0, 0.25)
    """

    __slots__ = ("mean", "m2", "weight", "passes")

    def __init__(self, mean=None, m2=None, weight: int = 0, passes: int = 0):
        self.mean, self.m2, self.weight, self.passes = mean, m2, int(weight), int(passes)

    @classmethod
    def empty(cls) -> Accumulator:
        return cls()

    def add(self, image, spp: int) -> Accumulator:
        """The accumulator with ``image`` (a pass of ``spp`` samples per pixel) added; evaluated."""
        import drjit as dr

        x = dr.float64_array_t(type(image))(image)
        if self.mean is None:
            mean, m2 = x, dr.zeros(type(x), x.shape)
        else:
            if tuple(x.shape) != tuple(self.mean.shape):
                raise ValueError(f"image: expected shape {tuple(self.mean.shape)}, got {tuple(x.shape)}")
            weight = self.weight + spp
            frac = dr.opaque(dr.float64_array_t(dr.array_t(x)), spp / weight)
            n = dr.opaque(dr.float64_array_t(dr.array_t(x)), float(spp))
            delta = x - self.mean
            mean = self.mean + delta * frac
            m2 = self.m2 + n * delta * (x - mean)
        dr.eval(mean, m2)
        return Accumulator(mean, m2, self.weight + spp, self.passes + 1)

    def variance_of_mean(self):
        """``M2 / ((K - 1) W)``: the variance of each pixel's mean (zeros before two passes)."""
        import drjit as dr

        if self.passes < 2:
            return dr.zeros(type(self.mean), self.mean.shape)
        scale = dr.opaque(dr.float64_array_t(dr.array_t(self.mean)), 1.0 / ((self.passes - 1) * self.weight))
        return self.m2 * scale

    def estimated_relmse(self, channels: int = 3) -> float:
        """The image's relMSE estimated from the spread between passes (NaN before :data:`MIN_PASSES`).

        Averaged over all pixels and the first ``channels`` channels (the colour; not AOVs).
        """
        import drjit as dr

        if self.passes < MIN_PASSES:
            return math.nan
        mean, var = self.mean, self.variance_of_mean()
        if mean.shape[-1] > channels:
            mean, var = mean[..., :channels], var[..., :channels]
        square = mean * mean
        ratio = var / (dr.maximum(square - var, 0.25 * square) + RELMSE_EPSILON)
        return float(dr.mean(ratio, axis=None).array[0])

    def image(self):
        """The mean so far as a float32 Dr.Jit tensor (lazy: costs nothing unless used)."""
        import mitsuba as mi

        return mi.TensorXf(self.mean)

    # -- checkpoint I/O
    def to_numpy(self) -> dict[str, Any]:
        return {"mean": self.mean.numpy().astype(np.float64), "m2": self.m2.numpy().astype(np.float64),
                "weight": np.int64(self.weight), "passes": np.int64(self.passes)}

    @classmethod
    def from_numpy(cls, data: dict[str, Any]) -> Accumulator:
        import mitsuba as mi
        import drjit as dr

        t64 = dr.float64_array_t(mi.TensorXf)
        return cls(t64(np.asarray(data["mean"], np.float64)), t64(np.asarray(data["m2"], np.float64)),
                   int(data["weight"]), int(data["passes"]))


def _pow2_floor(n: int) -> int:
    return 1 << (int(n).bit_length() - 1)


@dataclass(frozen=True)
class Budget:
    """When a progressive render stops, and how many spp each pass takes.

    Parameters
    ----------
    seconds : float, optional
        Stop when the render seconds (:attr:`PassStats.seconds`) reach this; the last passes
        shrink (halving their spp) to end close to it. At least one pass always runs.
    target_error : float, optional
        Stop when the estimated relMSE is at most this (checked from ``min_passes`` on). Auto
        passes take 1 spp until the first estimate, then no more than the 1/spp law says is
        still needed (rounded down to a power of two), so the render stops close to the target.
    spp : int, optional
        Stop at this many samples per pixel (the last pass is cut to land on it exactly).
    pass_spp : int, optional
        Samples per pass; default (None): the first pass takes about
        :data:`FIRST_PASS_SAMPLES` samples (it compiles the kernels), the others the power of
        two nearest to :data:`TARGET_PASS_SECONDS` (at most an eighth of ``seconds``).
    min_passes : int
        Passes before ``target_error`` is checked (at least :data:`MIN_PASSES`).

    Without ``seconds``, ``target_error`` or ``spp`` the passes go on until interrupted (Ctrl-C).
    The budget is a callable: ``budget(stats)`` is the spp of the next pass (0: stop). Auto
    and shrunk passes are powers of two, which share one compiled kernel (a pass cut to land on
    ``spp`` exactly may take one more compilation).

    Examples
    --------
    >>> from dataclasses import replace
    >>> b = Budget(spp=10, pass_spp=4)
    >>> start = PassStats(0, 0, 0, 0.0, 0.0, 0.0, 0.0, math.nan, 8, 8)
    >>> b(start), b(replace(start, passes=2, spp=8, pass_spp=4)), b(replace(start, passes=3, spp=10))
    (4, 2, 0)
    """

    seconds: float | None = None
    target_error: float | None = None
    spp: int | None = None
    pass_spp: int | None = None
    min_passes: int = MIN_PASSES

    def __post_init__(self):
        for name in ("seconds", "target_error"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                      or not math.isfinite(value) or value <= 0):
                raise ValueError(f"{name}: expected a positive finite number, got {value!r}")
        for name in ("spp", "pass_spp"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer))
                                      or not 1 <= value <= MAX_SAMPLES):
                raise ValueError(f"{name}: expected an integer in 1..2^32-1, got {value!r}")
        if isinstance(self.min_passes, bool) or not isinstance(self.min_passes, int) or self.min_passes < MIN_PASSES:
            raise ValueError(f"min_passes: expected an integer >= {MIN_PASSES}, got {self.min_passes!r}")

    def stop_reason(self, stats: PassStats) -> str | None:
        """Why the render is done after ``stats`` (``"spp"``, ``"time"``, ``"error"``), or None."""
        if stats.passes == 0:
            return None
        if self.spp is not None and stats.spp >= self.spp:
            return "spp"
        if self.target_error is not None and stats.passes >= self.min_passes \
                and stats.estimated_relmse <= self.target_error:
            return "error"
        if self.seconds is not None and stats.seconds >= self.seconds:
            return "time"
        return None

    def __call__(self, stats: PassStats) -> int:
        if self.stop_reason(stats):
            return 0
        pixels = max(stats.width * stats.height, 1)
        largest = _pow2_floor(max(MAX_SAMPLES // pixels, 1))
        rate = stats.seconds_per_spp()
        if self.pass_spp is not None:
            n = self.pass_spp
        elif self.target_error is not None and stats.passes < self.min_passes:
            n = 1  # until the first estimate, as few samples as possible: the target may need only a few
        elif stats.passes == 0 or not math.isfinite(rate):
            n = _pow2_floor(max(FIRST_PASS_SAMPLES // pixels, 1))
        else:
            target = TARGET_PASS_SECONDS if self.seconds is None else min(TARGET_PASS_SECONDS, self.seconds / 8)
            n = 1 << max(round(math.log2(max(target / rate, 1.0))), 0)  # nearest power of two
        n = min(n, largest)
        if self.target_error is not None and stats.passes >= self.min_passes and math.isfinite(
                stats.estimated_relmse):
            needed = stats.spp * stats.estimated_relmse / self.target_error - stats.spp
            n = min(n, _pow2_floor(max(int(math.ceil(needed)), 1)))  # approach it from below
        if self.spp is not None and self.spp - stats.spp < n:
            left = self.spp - stats.spp
            n = left if left <= largest else _pow2_floor(left)
        if self.seconds is not None and stats.passes > 0 and math.isfinite(rate):
            fit = int((self.seconds - stats.seconds) / rate + 0.5)
            if fit < 1:
                return 0
            if fit < n:
                n = _pow2_floor(fit)
        return int(n)


def _passes(scene, plan: Callable[[PassStats], int], *, seed: int, sensor: int, accumulator: Accumulator,
            start: PassStats, clock: Callable[[], float],
            channels: int | None = None) -> Iterator[tuple[Accumulator, PassStats, RenderTiming]]:
    """The pass loop: render, accumulate, estimate; yields ``(accumulator, stats, timing)``.

    ``channels``: the leading channels the estimate takes (the colour; default from the scene's
    :func:`pointillist.channels.channel_layout`)."""
    import drjit as dr
    import mitsuba as mi

    if channels is None:
        from pointillist.channels import channel_layout

        layout = channel_layout(scene, sensor)
        channels = len(layout.colour) or layout.channels
    acc, stats = accumulator, start
    while True:
        spp = int(plan(stats))
        if spp < 1:
            return
        seed_k = pass_seed(seed, acc.passes)
        begin = clock()
        image, timing = timed_render(scene, spp=spp, seed=dr.opaque(mi.UInt32, seed_k), sensor=sensor)
        new = acc.add(image, spp)
        estimate = new.estimated_relmse(channels)
        seconds = clock() - begin
        acc = new
        stats = PassStats(passes=acc.passes, spp=acc.weight, pass_spp=spp, seconds=stats.seconds + seconds,
                          pass_seconds=seconds, pass_compile_seconds=timing.compile,
                          compile_seconds=stats.compile_seconds + timing.compile, estimated_relmse=estimate,
                          width=stats.width, height=stats.height, seed=seed_k)
        yield acc, stats, timing


def _start_stats(scene, sensor: int, accumulator: Accumulator) -> PassStats:
    info = scene_info(scene, sensor)
    return PassStats(passes=accumulator.passes, spp=accumulator.weight, pass_spp=0, seconds=0.0, pass_seconds=0.0,
                     pass_compile_seconds=0.0, compile_seconds=0.0, estimated_relmse=math.nan,
                     width=info["width"], height=info["height"])


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= _U32:
        raise ValueError(f"seed: expected an integer in 0..2^32-1, got {seed!r}")
    return int(seed)


def render_passes(scene, *, pass_spp: int | Callable[[PassStats], int], seed: int = 0, sensor: int = 0,
                  clock: Callable[[], float] = time.perf_counter) -> Iterator[tuple[Any, PassStats]]:
    """Render ``scene`` in passes; yield ``(image so far, PassStats)`` after each.

    Parameters
    ----------
    scene : mitsuba.Scene
        A loaded scene (:func:`pointillist.scene.load_scene`).
    pass_spp : int or callable
        Samples per pixel of every pass (the generator is endless: stop iterating when done), or a
        callable ``(PassStats) -> int`` giving each pass's spp, 0 to stop, e.g. a :class:`Budget`.
    seed : int
        Pass ``k`` uses the Mitsuba seed :func:`pass_seed(seed, k) <pass_seed>`.
    sensor : int
        Sensor index.
    clock : callable
        Wall clock in seconds (injectable for tests).

    Yields
    ------
    image : mitsuba.TensorXf
        The mean of all samples so far, (H, W, C) float32 (lazy: evaluated when used).
    stats : PassStats
        Passes, spp, seconds and the estimated relMSE so far.

    Examples
    --------
    >>> import pointillist
    >>> mi = pointillist.setup()
    >>> from pointillist.scene import load_scene
    >>> scene = load_scene("scenes/edges.xml", {"res": "16"})
    >>> for image, stats in render_passes(scene, pass_spp=Budget(spp=16, pass_spp=2)):
    ...     pass
    >>> stats.passes, stats.spp, image.shape, stats.estimated_relmse > 0
    (8, 16, (16, 16, 3), True)
    """
    seed = _check_seed(seed)
    if callable(pass_spp):
        plan = pass_spp
    else:
        if isinstance(pass_spp, bool) or not isinstance(pass_spp, (int, np.integer)) \
                or not 1 <= pass_spp <= MAX_SAMPLES:
            raise ValueError(f"pass_spp: expected an integer in 1..2^32-1 or a callable, got {pass_spp!r}")
        plan = lambda _stats, n=int(pass_spp): n  # noqa: E731
    acc = Accumulator.empty()
    for acc, stats, _timing in _passes(scene, plan, seed=seed, sensor=sensor, accumulator=acc,
                                        start=_start_stats(scene, sensor, acc), clock=clock):
        yield acc.image(), stats


# ------------------------------------------------------------------------------ checkpoints
def checkpoint_path(out: str | Path) -> Path:
    """``OUT.checkpoint.npz`` beside the EXR ``OUT.exr``."""
    return Path(out).with_suffix(".checkpoint.npz")


def progress_paths(out: str | Path) -> tuple[Path, Path]:
    """``(OUT.progress.csv, OUT.progress.png)`` beside the EXR ``OUT.exr``."""
    return Path(out).with_suffix(".progress.csv"), Path(out).with_suffix(".progress.png")


def scene_fingerprint(scene, scene_path: str | Path, params: dict[str, str] | None, seed: int,
                      sensor: int = 0, *, inputs: Sequence[str | Path] | None = None) -> dict[str, Any]:
    """What a checkpoint must match to be resumed: the SHA-256 of the scene's inputs (the scene file
    and every file it reads: includes, textures, meshes, volumes; :func:`pointillist.plan.inputs_digest`)
    with the ``-D`` values, the seed, the film, integrator and sampler.

    ``inputs``: the scene's inputs when known (:func:`pointillist.plan.scene_inputs`); else the
    scene file is parsed again to list them.
    """
    import mitsuba as mi

    from pointillist.plan import inputs_digest, scene_inputs
    from pointillist.scene import parse_scene

    if inputs is None:
        inputs = scene_inputs(parse_scene(scene_path, params))
    info = scene_info(scene, sensor)
    return {"inputs_sha256": inputs_digest(inputs, params),
            "params": json.dumps(dict(sorted((params or {}).items()))), "seed": int(seed), "sensor": int(sensor),
            "film": f"{info['width']}x{info['height']}", "integrator": info["integrator"],
            "sampler": info["sampler"], "variant": mi.variant()}


def _checksum(arrays: dict[str, Any]) -> str:
    """SHA-256 of a checkpoint's contents (every entry but the checksum, by name, dtype, shape, bytes)."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        if name == "checksum":
            continue
        value = np.ascontiguousarray(np.asarray(arrays[name]))
        digest.update(f"{name}|{value.dtype.str}|{value.shape}|".encode())
        digest.update(value.tobytes())
    return digest.hexdigest()


def _save_checkpoint(path: Path, acc: Accumulator, stats: PassStats, history: list, identity: dict) -> None:
    from pointillist.imaging.io import atomic_write

    arrays = dict(acc.to_numpy(), history=np.asarray(history, np.float64).reshape(-1, 4),
                  stats=np.array(json.dumps(asdict(stats))), identity=np.array(json.dumps(identity)),
                  version=np.int64(CHECKPOINT_VERSION))
    arrays["checksum"] = np.array(_checksum(arrays))
    atomic_write(path, lambda tmp: np.savez(tmp, **arrays))


def _load_checkpoint(path: Path, identity: dict, channels: int | None = None) -> tuple[Accumulator, PassStats, list]:
    """Read a checkpoint; UsageError unless it is one this version wrote, unchanged (its checksum),
    for the same scene and settings (``identity``), and consistent (``channels``: the render's)."""
    if not path.is_file():
        raise UsageError(f"--resume: no checkpoint {path} (write one with --checkpoint SECONDS)")
    try:
        with np.load(path, allow_pickle=False) as data:
            if "version" not in data.files or int(data["version"]) != CHECKPOINT_VERSION:
                version = int(data["version"]) if "version" in data.files else "none"
                raise UsageError(f"--resume: checkpoint {path} has format version {version}, "
                                 f"expected {CHECKPOINT_VERSION}")
            arrays = {name: data[name] for name in data.files}
    except UsageError:
        raise
    except Exception as error:  # noqa: BLE001 - any unreadable file is a usage error here
        raise UsageError(f"--resume: {path} is not a readable checkpoint ({type(error).__name__}: {error})") from None
    if "checksum" not in arrays or str(arrays["checksum"]) != _checksum(arrays):
        raise UsageError(f"--resume: checkpoint {path} was changed or damaged after it was written "
                         "(its checksum does not match its contents)")
    try:
        saved = json.loads(str(arrays["identity"]))
        stats = PassStats(**json.loads(str(arrays["stats"])))
        mean, m2 = np.asarray(arrays["mean"]), np.asarray(arrays["m2"])
        weight, passes = int(arrays["weight"]), int(arrays["passes"])
        history = [tuple(float(v) for v in row) for row in np.asarray(arrays["history"], np.float64).reshape(-1, 4)]
    except (KeyError, TypeError, ValueError) as error:
        raise UsageError(f"--resume: {path} is not a readable checkpoint ({type(error).__name__}: {error})") from None
    for key, value in identity.items():
        if saved.get(key) != value:
            what = ("another scene (the scene file or a file it reads changed)" if key == "inputs_sha256"
                    else f"other settings ({key} {saved.get(key)!r}, now {value!r})")
            raise UsageError(f"--resume: checkpoint {path} was made from {what}")
    problem = _inconsistency(mean, m2, weight, passes, stats, history, channels)
    if problem:
        raise UsageError(f"--resume: checkpoint {path} is inconsistent ({problem})")
    return Accumulator.from_numpy({"mean": mean, "m2": m2, "weight": weight, "passes": passes}), stats, history


def _inconsistency(mean, m2, weight: int, passes: int, stats: PassStats, history: list,
                   channels: int | None) -> str:
    """What is wrong with a checkpoint's numbers ('' when nothing is): counts in range and agreeing
    with each other, arrays of the film's shape, times finite."""
    if mean.ndim != 3 or m2.shape != mean.shape or mean.dtype != np.float64 or m2.dtype != np.float64:
        return f"sums of shape {mean.shape} and {m2.shape}, expected two equal (H, W, C) float64 arrays"
    if tuple(mean.shape[:2]) != (stats.height, stats.width) or (channels is not None and mean.shape[2] != channels):
        return f"sums of shape {mean.shape}, the render is {stats.height}x{stats.width}x{channels or mean.shape[2]}"
    largest = max(MAX_SAMPLES // max(stats.width * stats.height, 1), 1)
    if not 1 <= passes <= weight <= passes * largest:
        return f"{passes} passes of {weight} spp in all (each pass takes 1..{largest} spp)"
    if stats.passes != passes or stats.spp != weight or len(history) != passes:
        return (f"{passes} passes and {weight} spp in the sums, {stats.passes} and {stats.spp} in the stats, "
                f"{len(history)} rows of history")
    if not (math.isfinite(stats.seconds) and stats.seconds >= 0 and math.isfinite(stats.compile_seconds)):
        return f"render seconds {stats.seconds}"
    return ""


# ------------------------------------------------------------------------------ the workflow
@dataclass
class ProgressiveResult:
    """What :func:`render_progressive` rendered.

    ``image``: (H, W, C) float32 mean of all samples; ``variance``: (H, W) float32 variance of
    the pixel mean averaged over the colour channels; ``history``: one ``(pass, seconds, spp,
    estimated_relmse)`` row per pass; ``timing``: phases summed over the passes (``total`` = the
    render seconds); ``stop``: ``"spp"``, ``"time"``, ``"error"`` or ``"interrupted"``; ``signum``:
    the signal that interrupted it (``signal.SIGINT``/``SIGTERM``; None otherwise).
    """

    image: np.ndarray
    variance: np.ndarray
    stats: PassStats
    history: list[tuple[float, float, float, float]]
    timing: RenderTiming
    interrupted: bool
    stop: str
    resumed_from: int = 0
    checkpoints: int = 0
    metadata: dict[str, Any] = field(default_factory=dict)
    signum: int | None = None


def _is_interrupt(error: BaseException | None) -> bool:
    """KeyboardInterrupt, or an error caused by one (Dr.Jit wraps exceptions raised inside a render)."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


def _bar(budget: Budget, start: PassStats, progress: bool):
    from tqdm import tqdm

    total, unit = ((budget.seconds, "s") if budget.seconds is not None else (budget.spp, "spp")
                   if budget.spp is not None else (None, "pass"))
    return tqdm(total=total, initial=_bar_position(budget, start), unit=unit, desc="render", leave=False,
                disable=None if progress else True,
                bar_format="{l_bar}{bar}| {n:.4g}/{total:.4g} {unit} [{elapsed}<{remaining}{postfix}]"
                if total is not None else None)


def _bar_position(budget: Budget, stats: PassStats) -> float:
    """Where the bar stands: seconds (time budget), spp (spp budget) or passes, never past the total."""
    if budget.seconds is not None:
        return min(stats.seconds, budget.seconds)
    if budget.spp is not None:
        return min(stats.spp, budget.spp)
    return stats.passes


def _postfix(budget: Budget, stats: PassStats) -> str:
    text = f"{stats.passes} passes, {stats.spp} spp"
    if math.isfinite(stats.estimated_relmse):
        text += f", est. relMSE {stats.estimated_relmse:.3g}"
        if budget.target_error is not None and stats.estimated_relmse > budget.target_error:
            more = stats.spp * (stats.estimated_relmse / budget.target_error - 1)
            text += f", error ETA ~{more * stats.seconds_per_spp():.0f} s"
    return text


def render_progressive(scene, scene_path: str | Path, budget: Budget, *, params: dict[str, str] | None = None,
                       seed: int = 0, sensor: int = 0, checkpoint_seconds: float | None = None,
                       checkpoint_file: str | Path | None = None, resume: bool = False, progress: bool = True,
                       clock: Callable[[], float] = time.perf_counter, inputs: Sequence[str | Path] | None = None,
                       layout=None, abandon: Callable[[ProgressiveResult], None] | None = None) -> ProgressiveResult:
    """Render ``scene`` in passes until ``budget`` is spent; Ctrl-C or SIGTERM keep what is done.

    Parameters
    ----------
    scene : mitsuba.Scene
        The loaded scene; ``scene_path`` its XML (hashed into checkpoints).
    budget : Budget
        When to stop, and the pass sizes.
    params, seed, sensor
        The ``-D`` values the scene was loaded with (checked on resume), the seed, the sensor.
    checkpoint_seconds : float, optional
        Write ``checkpoint_file`` (atomically) when this many wall seconds passed since the last
        write, after a pass, and once at the end.
    checkpoint_file : path, optional
        The checkpoint (``OUT.checkpoint.npz``); needed with ``checkpoint_seconds`` or ``resume``.
    resume : bool
        Continue from ``checkpoint_file`` (same scene file, ``-D`` values, seed, film, integrator
        and sampler, else :class:`~pointillist.errors.UsageError`); the budget counts the
        resumed passes too.
    progress : bool
        Draw a tqdm bar on stderr (only when stderr is a terminal; it is cleared at the end).
    clock : callable
        Wall clock in seconds (injectable for tests).
    inputs : sequence of paths, optional
        The scene's inputs (:func:`pointillist.plan.scene_inputs`), whose contents the checkpoint's
        fingerprint holds; listed from ``scene_path`` when not given.
    layout : pointillist.channels.ChannelLayout, optional
        The render's channels (read from ``scene`` when not given): the estimate and the variance
        take the colour channels.
    abandon : callable, optional
        Under ``pointillist``'s signal boundary, a second signal during the passes ends the process
        at once; ``abandon(result)`` is then called (from another thread, numpy data only) with
        the passes done, to write them; the checkpoint is written too.

    Returns
    -------
    ProgressiveResult
        With ``interrupted=True`` after SIGINT (Ctrl-C) or SIGTERM (``signum`` says which): the
        pass in flight finishes and the result holds the passes done; also after a
        KeyboardInterrupt raised elsewhere (re-raised when no pass was done).
    """
    from pointillist.channels import channel_layout

    seed = _check_seed(seed)
    if not isinstance(budget, Budget):
        raise TypeError(f"budget: expected a Budget, got {type(budget).__name__}")
    if checkpoint_seconds is not None and not (math.isfinite(checkpoint_seconds) and checkpoint_seconds > 0):
        raise ValueError(f"checkpoint_seconds: expected a positive finite number, got {checkpoint_seconds!r}")
    if (checkpoint_seconds is not None or resume) and checkpoint_file is None:
        raise ValueError("checkpoint_file: needed with checkpoint_seconds or resume")
    layout = layout or channel_layout(scene, sensor)
    channels = len(layout.colour) or layout.channels  # the colour channels lead; none: every channel
    checkpoint_file = None if checkpoint_file is None else Path(checkpoint_file)
    identity = scene_fingerprint(scene, scene_path, params, seed, sensor, inputs=inputs) if checkpoint_file else {}
    acc, history = Accumulator.empty(), []
    start = _start_stats(scene, sensor, acc)
    if resume:
        acc, start, history = _load_checkpoint(checkpoint_file, identity, layout.channels)
    resumed_from, stats, stop, checkpoints, signum = acc.passes, start, None, 0, None
    sums = [0.0, 0.0, 0.0, 0, 0]  # trace, compile, execute, kernels, cache hits
    # What a second signal writes (read by the signal watcher's thread: replaced, never changed).
    done = {"acc": acc, "stats": stats, "history": list(history), "sums": list(sums)}

    def finish(stop: str, signum: int | None, *, done: dict) -> ProgressiveResult:
        return _result(done["acc"], done["stats"], done["history"], done["sums"], stop, signum, budget, seed,
                       resumed_from, checkpoints, channels)

    def abandoned() -> None:
        current = dict(done)
        if current["acc"].passes == resumed_from:
            return
        if checkpoint_seconds is not None:
            _save_checkpoint(checkpoint_file, current["acc"], current["stats"], current["history"], identity)
        if abandon is not None:
            abandon(finish("interrupted", signals.received(), done=current))

    last_write = clock()
    bar = _bar(budget, start, progress)
    try:
        with signals.deferred() as requested, signals.on_abandon(abandoned):
            for acc, new, timing in _passes(scene, budget, seed=seed, sensor=sensor, accumulator=acc, start=start,
                                            clock=clock, channels=channels):
                history.append((new.passes, new.seconds, new.spp, new.estimated_relmse))
                sums = [sums[0] + timing.trace, sums[1] + timing.compile, sums[2] + timing.execute,
                        sums[3] + timing.kernels, sums[4] + timing.cache_hits]
                bar.update(_bar_position(budget, new) - _bar_position(budget, stats))
                stats = new
                done = {"acc": acc, "stats": stats, "history": list(history), "sums": list(sums)}
                bar.set_postfix_str(_postfix(budget, stats), refresh=False)
                if requested() is not None:  # first signal: stop after the pass in flight
                    stop, signum = "interrupted", requested()
                    break
                if checkpoint_seconds is not None and clock() - last_write >= checkpoint_seconds:
                    _save_checkpoint(checkpoint_file, acc, stats, history, identity)
                    last_write, checkpoints = clock(), checkpoints + 1
        stop = stop or budget.stop_reason(stats) or "spp"
    except BaseException as error:  # noqa: BLE001 - only interruptions are handled here
        if not _is_interrupt(error) or acc.passes == 0:
            raise
        stop = "interrupted"
    finally:
        bar.close()
    if checkpoint_seconds is not None and acc.passes > resumed_from:
        _save_checkpoint(checkpoint_file, acc, stats, history, identity)
        checkpoints += 1
    return finish(stop, (signum or signals.received()) if stop == "interrupted" else None,
                  done={"acc": acc, "stats": stats, "history": history, "sums": sums})


def _result(acc: Accumulator, stats: PassStats, history: list, sums: list, stop: str, signum: int | None,
            budget: Budget, seed: int, resumed_from: int, checkpoints: int, channels: int) -> ProgressiveResult:
    """The :class:`ProgressiveResult` of the passes in ``acc`` (numpy only: also called from the
    signal watcher's thread while the main thread renders)."""
    image = acc.mean.numpy().astype(np.float32)
    if acc.passes >= 2:
        variance = acc.m2.numpy()[..., :channels] * (1.0 / ((acc.passes - 1) * acc.weight))
    else:
        variance = np.zeros(tuple(acc.mean.shape)[:2] + (channels,))
    variance = variance.mean(axis=2).astype(np.float32)
    timing = RenderTiming(trace=sums[0], compile=sums[1], execute=sums[2], total=stats.seconds, kernels=int(sums[3]),
                          cache_hits=int(sums[4]))
    metadata = {"spp": stats.spp, "passes": stats.passes, "estimated_relmse": stats.estimated_relmse,
                "interrupted": stop == "interrupted", "stopped_by": stop,
                "pass_seeds": "(TEA(seed, 0) + pass) mod 2^32", "seed": seed}
    for name, value in (("time_budget", budget.seconds), ("target_error", budget.target_error),
                        ("spp_budget", budget.spp), ("pass_spp", budget.pass_spp)):
        if value is not None:
            metadata[name] = value
    if resumed_from:
        metadata["resumed_from_passes"] = resumed_from
    return ProgressiveResult(image=image, variance=variance, stats=stats, history=list(history), timing=timing,
                             interrupted=stop == "interrupted", stop=stop, resumed_from=resumed_from,
                             checkpoints=checkpoints, metadata=metadata, signum=signum)


def write_progress(out: str | Path, history: list, *, png: bool = False, inputs=()) -> list[Path]:
    """Write ``OUT.progress.csv`` (pass, seconds, spp, estimated_relmse) and, with ``png``, ``OUT.progress.png``.

    The plot shows the estimated relMSE against render seconds on log-log axes with a line of
    slope -1 (error proportional to 1/t, the Monte Carlo rate) through the last estimate.
    Returns the paths written.
    """
    from pointillist.imaging.io import atomic_write, check_output_path, save_figure

    csv_path, png_path = progress_paths(out)
    check_output_path(csv_path, inputs)
    rows = ["pass,seconds,spp,estimated_relmse"] + [
        f"{int(k)},{t:.6f},{int(n)},{'' if not math.isfinite(e) else f'{e:.6g}'}" for k, t, n, e in history]
    atomic_write(csv_path, lambda tmp: Path(tmp).write_text("\n".join(rows) + "\n"))
    written = [csv_path]
    if png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        check_output_path(png_path, inputs)
        data = np.asarray(history, np.float64).reshape(-1, 4)
        ok = np.isfinite(data[:, 3]) & (data[:, 3] > 0) & (data[:, 1] > 0)
        fig, ax = plt.subplots(figsize=(5.5, 4), dpi=110)
        if ok.any():
            t, e = data[ok, 1], data[ok, 3]
            ax.loglog(t, e, "o-", ms=3, label="estimated relMSE")
            span = np.array([t.min(), t.max()])
            ax.loglog(span, e[-1] * t[-1] / span, "--", color="grey", label="1/t (slope -1)")
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, f"no estimate yet (from {MIN_PASSES} passes on)", ha="center", transform=ax.transAxes)
        ax.set_xlabel("render seconds")
        ax.set_ylabel("estimated relMSE")
        ax.set_title(f"{int(data[-1, 0]) if len(data) else 0} passes, {int(data[-1, 2]) if len(data) else 0} spp",
                     fontsize=9)
        ax.grid(True, which="both", lw=0.3)
        fig.tight_layout()
        save_figure(fig, png_path)
        written.append(png_path)
    return written
