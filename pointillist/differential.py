"""Differential check against Mitsuba: a scene renders in pointillist as Mitsuba renders it.

For one scene file, :func:`check_scene` runs:

``mitsuba``
    ``pointillist render``'s library call (:func:`pointillist.render.render_file`, from a temporary
    working folder, the EXR read back) against ``mi.load_file`` + ``mi.render`` (same spp and seed;
    Mitsuba's default ``path`` integrator where the scene states none): every channel of the EXR
    (colour, alpha, AOV layers) must be **bit-identical** to Mitsuba's image. Both render on one
    thread (:func:`pointillist.scene.thread_count`): on several, the film's atomic additions of samples that land on
    the same pixel (any filter wider than a pixel; the particle tracer) come in another order from
    run to run, and Mitsuba's own renders differ from each other in the last bit. Where Mitsuba's
    own image of a scene varies from one load to the next (it does, now and then, for some scenes),
    pointillist's must be one of the images Mitsuba makes (:data:`REPEATS` more loads). A scene Mitsuba
    refuses (a misspelt property, a missing file, a blackbody in an RGB variant) must be refused
    by pointillist too, with a one-line error.
``whitted``
    the scene rendered with the ``whitted`` integrator instead of its own: a finite image.
``samplers``
    the scene rendered with each of pointillist's samplers swapped in as ``compare`` swaps them
    (:func:`pointillist.compare.methods.load_configured_scene`): finite images.
``compare``
    a small ``pointillist compare`` sweep (``random`` and ``jitter`` at 1 and 2 spp against a
    16-spp reference), report page included.
``progressive``
    a progressive render with a time budget (``render --time``).

:func:`verify_scenes` runs :func:`check_scene` over many scenes, each in a process of its own
(``python -m pointillist.differential``): a scene that aborts the process (a crash in Dr.Jit or
LLVM) is a finding, not the end of the run. ``pointillist verify`` is its command line.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from pointillist.core.errors import UsageError

__all__ = ["STEPS", "REPEATS", "SCENE_TIMEOUT", "REFUSED_BY_BOTH", "Check", "SceneReport", "check_scene",
           "verify_scenes", "scene_files", "mitsuba_render"]

#: The checks :func:`check_scene` can run, in order.
STEPS = ("mitsuba", "whitted", "samplers", "compare", "progressive")

#: Extra loads of a scene whose image differs, when Mitsuba's own image varies from load to load.
REPEATS = 3

#: Seconds a scene's own process may take in :func:`verify_scenes` before it is stopped.
SCENE_TIMEOUT = 600.0


#: What the ``mitsuba`` check says of a scene that Mitsuba and pointillist both refuse (a pass:
#: they agree; the summary counts these apart, since nothing was rendered).
REFUSED_BY_BOTH = "refused, as Mitsuba refuses it"


@dataclass
class Check:
    """One check of one scene: ``name`` (a :data:`STEPS` entry), ``ok``, and one line saying what
    was found."""

    name: str
    ok: bool
    detail: str


@dataclass
class SceneReport:
    """What :func:`check_scene` found for the scene ``path``."""

    path: str
    checks: list[Check] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return bool(self.checks) and all(check.ok for check in self.checks)

    @property
    def refused(self) -> bool:
        """Whether both Mitsuba and pointillist refused the scene (they agree; nothing was rendered)."""
        return any(check.name == "mitsuba" and check.detail.startswith(REFUSED_BY_BOTH) for check in self.checks)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> SceneReport:
        data = json.loads(text)
        return cls(data["path"], [Check(**check) for check in data["checks"]])


# ----------------------------------------------------------------------------- Mitsuba alone
def mitsuba_render(path: str | os.PathLike, *, spp: int, seed: int, params: dict[str, str] | None = None,
                   threads: int | None = 1):
    """``(image, scene)`` as Mitsuba alone renders the scene: ``mi.load_file`` (serial loading)
    and ``mi.render`` on ``threads`` threads, with Mitsuba's ``path`` integrator when the scene
    states none. Raises Mitsuba's own exceptions."""
    import mitsuba as mi

    from pointillist.scene import thread_count

    scene = mi.load_file(str(path), parallel=False, **dict(params or {}))
    integrator = None if scene.integrator() is not None else mi.load_dict({"type": "path"})
    with thread_count(threads):
        image = mi.render(scene, spp=spp, seed=seed, integrator=integrator)
    return np.asarray(image, dtype=np.float32), scene


def _mitsuba_layout(scene):
    """The channel layout of Mitsuba's render of ``scene`` (its integrator's, or ``path``'s)."""
    from pointillist.channels import channel_layout, layout_from_names

    if scene.integrator() is not None:
        return channel_layout(scene)
    return layout_from_names(int(scene.sensors()[0].film().base_channels_count()), False, [])


def _difference(name: str, ours: np.ndarray | None, theirs: np.ndarray | None) -> str:
    """'' when two channel blocks are bit-identical, else one line saying how they differ."""
    if ours is None or theirs is None:
        return "" if ours is None and theirs is None else f"{name}: present in only one image"
    # (H, W) and (H, W, 1) are the same one-channel image (an EXR's Y, a tensor's last axis)
    ours, theirs = (np.asarray(a, np.float32).reshape(a.shape[0], a.shape[1], -1) for a in (ours, theirs))
    if ours.shape != theirs.shape:
        return f"{name}: shape {ours.shape} against Mitsuba's {theirs.shape}"
    if ours.tobytes() == theirs.tobytes():
        return ""
    differ = ~((ours == theirs) | (np.isnan(ours) & np.isnan(theirs)))
    pixels = differ.reshape(ours.shape[0], ours.shape[1], -1).any(axis=-1)
    worst = float(np.nanmax(np.abs(ours.astype(np.float64) - theirs)[differ])) if differ.any() else 0.0
    return f"{name}: {int(pixels.sum())} of {pixels.size} pixels differ (largest difference {worst:.3g})"


def _check_mitsuba(path: Path, *, spp: int, seed: int, params: dict[str, str], work: Path) -> Check:
    from pointillist.imaging.io import read_exr
    from pointillist.render import render_file
    from pointillist.scene import mitsuba_message

    try:
        reference, mi_scene = mitsuba_render(path, spp=spp, seed=seed, params=params)
        refused = ""
    except Exception as error:  # noqa: BLE001 - whatever Mitsuba refuses, pointillist must refuse too
        from pointillist.scene import root_cause

        refused = mitsuba_message(root_cause(error))
    renders = []

    def ours_render():
        out = work / f"ours{len(renders)}.exr"  # a new name each time: a file read is never written over
        renders.append(out)
        with contextlib.chdir(work):  # from another working folder than the scene's or the caller's
            render_file(path, out, spp=spp, seed=seed, params=params, threads=1)
        return read_exr(out)

    try:
        ours = ours_render()
    except UsageError as error:
        if refused:
            return Check("mitsuba", True, f"{REFUSED_BY_BOTH}: {error}")
        return Check("mitsuba", False, f"pointillist refuses what Mitsuba renders: {error}")
    if refused:
        return Check("mitsuba", False, f"pointillist renders what Mitsuba refuses ({refused})")
    layout = _mitsuba_layout(mi_scene)
    height, width, channels = reference.shape
    same = f"bit-identical to Mitsuba ({width}x{height}x{channels} at {spp} spp)"
    problems = _differences(layout, ours, reference)
    if not problems:
        return Check("mitsuba", True, same)
    # Mitsuba's own image of some scenes varies from one load to the next (a rare variant every few
    # loads, measured with an environment map beside textured spot and projector lights; the first
    # render of ptracer in a process): then pointillist's must be one of the images Mitsuba makes.
    images = [reference]
    for _ in range(REPEATS):
        images.append(mitsuba_render(path, spp=spp, seed=seed, params=params)[0])
        if not _differences(layout, ours, images[-1]):
            return Check("mitsuba", True, f"{same}; {_varies(images)}")
    for _ in range(REPEATS):  # pointillist's load may have given the rare variant, Mitsuba's the common one
        ours = ours_render()
        if any(not _differences(layout, ours, image) for image in images):
            varies = (_varies(images) if len({image.tobytes() for image in images}) > 1 else
                      "this scene's image varies between loads (pointillist's first load gave another one)")
            return Check("mitsuba", True, f"{same}; {varies}")
    if len({image.tobytes() for image in images}) == 1:
        return Check("mitsuba", False, "; ".join(problems))
    return Check("mitsuba", False, f"{'; '.join(problems)} ({_varies(images)}, pointillist's is none of them)")


def _varies(images: list[np.ndarray]) -> str:
    return (f"Mitsuba's own image of this scene varies between loads ({len({i.tobytes() for i in images})} "
            f"different images in {len(images)} loads)")


def _differences(layout, ours, reference: np.ndarray) -> list[str]:
    """How an EXR read back (``ours``) differs from Mitsuba's image, channel block by block."""
    expected = layout.split(reference)
    colour, layers = ours.image, dict(ours.layers)
    if colour is not None and expected.alpha is not None and colour.ndim == 2 and "A" in layers:
        colour = np.stack([colour, layers.pop("A")], axis=-1)  # read_exr gives a YA file's A as a layer
    problems = [_difference("colour", colour, layout.with_colour_alpha(reference))]
    names = sorted(set(layers) | set(expected.layers))
    problems += [_difference(f"layer {name}", layers.get(name), expected.layers.get(name)) for name in names]
    return [p for p in problems if p]


def _finite(image) -> str:
    values = np.asarray(image)
    bad = int(np.sum(~np.isfinite(values)))
    return "" if bad == 0 else f"{bad} values are NaN or infinite"


def _check_whitted(path: Path, *, spp: int, seed: int, params: dict[str, str]) -> Check:
    import mitsuba as mi

    from pointillist.scene import load_scene, timed_render

    try:
        scene = load_scene(path, params)
        image, _ = timed_render(scene, spp=spp, seed=seed, integrator=mi.load_dict({"type": "whitted"}))
    except UsageError as error:
        return Check("whitted", False, str(error))
    problem = _finite(image)
    return Check("whitted", not problem, problem or "renders")


def _check_samplers(path: Path, *, spp: int, seed: int, params: dict[str, str]) -> Check:
    from pointillist import plugins
    from pointillist.compare.methods import METHODS, load_configured_scene
    from pointillist.scene import timed_render

    failed, names = [], sorted(plugins.available("sampler"))
    for name in names:
        try:
            scene = load_configured_scene(path, METHODS[name], spp, params)
            image, _ = timed_render(scene, seed=seed)
            problem = _finite(image)
        except UsageError as error:
            problem = str(error)
        if problem:
            failed.append(f"{name}: {problem}")
    return Check("samplers", not failed, "; ".join(failed) or f"renders with {', '.join(names)}")


def _check_compare(path: Path, *, params: dict[str, str], work: Path) -> Check:
    from pointillist.compare import compare_scene

    try:
        result = compare_scene(path, methods=("random", "jitter"), spp=(1, 2), reference_spp=16,
                               out_dir=work / "compare", params=params, progress=False)
    except UsageError as error:
        return Check("compare", False, str(error))
    return Check("compare", True, f"{len(result.records)} renders scored, report written")


def _check_progressive(path: Path, *, params: dict[str, str], work: Path, seconds: float) -> Check:
    from pointillist.render import render_file

    try:
        summary = render_file(path, work / "passes.exr", params=params, time_budget=seconds, pass_spp=1)
    except UsageError as error:
        return Check("progressive", False, str(error))
    stats = summary.progressive.stats
    return Check("progressive", True, f"{stats.spp} spp in passes within --time {seconds:g}")


def check_scene(path: str | os.PathLike, *, spp: int = 2, seed: int = 0, params: dict[str, str] | None = None,
                steps: Sequence[str] = STEPS, seconds: float = 0.5) -> SceneReport:
    """Check one scene file against Mitsuba (see the module's documentation for the steps).

    ``spp`` and ``seed`` are those of every render (``seconds`` the budget of the progressive
    one); ``params`` the ``-D`` values; ``steps`` which of :data:`STEPS` run. The steps after
    ``mitsuba`` run only when the scene loads. Sets up pointillist (:func:`pointillist.setup`).
    Raises UsageError for a path that is not a file or an unknown step.
    """
    import pointillist
    from pointillist.scene import check_scene_file

    scene = check_scene_file(path).resolve()
    unknown = [step for step in steps if step not in STEPS]
    if unknown:
        raise UsageError(f"steps: unknown step {unknown[0]!r}; expected some of {', '.join(STEPS)}")
    params = dict(params or {})
    pointillist.setup()
    report = SceneReport(str(path))
    with tempfile.TemporaryDirectory(prefix="pointillist-verify-") as folder:
        work = Path(folder)
        runs: dict[str, Callable[[], Check]] = {
            "mitsuba": lambda: _check_mitsuba(scene, spp=spp, seed=seed, params=params, work=work),
            "whitted": lambda: _check_whitted(scene, spp=spp, seed=seed, params=params),
            "samplers": lambda: _check_samplers(scene, spp=spp, seed=seed, params=params),
            "compare": lambda: _check_compare(scene, params=params, work=work),
            "progressive": lambda: _check_progressive(scene, params=params, work=work, seconds=seconds),
        }
        for step in STEPS:
            if step not in steps:
                continue
            check = runs[step]()
            report.checks.append(check)
            if step == "mitsuba" and check.detail.startswith("refused"):
                break  # a scene both refuse: nothing more to render
    return report


# ----------------------------------------------------------------------------- many scenes
def scene_files(paths: Iterable[str | os.PathLike]) -> list[Path]:
    """The scene files named by ``paths``: files as given, folders searched for ``*.xml`` files that
    hold a ``<scene`` root (an ``<include>``'s fragment counts as a scene too when it is one).
    UsageError for a path that does not exist or a folder without scenes."""
    found: list[Path] = []
    for item in paths:
        path = Path(item)
        if path.is_file():
            found.append(path)
        elif path.is_dir():
            inside = sorted(p for p in path.rglob("*.xml") if p.is_file() and _is_scene(p))
            if not inside:
                raise UsageError(f"scenes: no scene XML file under {path}")
            found.extend(inside)
        else:
            raise UsageError(f"scenes: no such file or folder: {path}")
    from pointillist.scene import check_scene_file

    return [check_scene_file(path) for path in dict.fromkeys(found)]


def _is_scene(path: Path) -> bool:
    """True for an XML file (in any encoding its byte-order mark or declaration names) whose root
    element is ``<scene>`` and that holds or includes a sensor."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return False
    return root.tag == "scene" and any(child.tag in ("sensor", "include") for child in root)


def _child(path: Path, *, spp: int, seed: int, params: dict[str, str], steps: Sequence[str],
           timeout: float) -> SceneReport:
    """:func:`check_scene` in a process of its own: an abort or a hang is a failed check."""
    command = [sys.executable, "-m", "pointillist.differential", str(path), "--spp", str(spp), "--seed", str(seed),
               "--steps", ",".join(steps)] + [f"-D{key}={value}" for key, value in params.items()]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        return SceneReport(str(path), [Check("process", False, f"still running after {timeout:g} s: stopped")])
    # Mitsuba logs to standard output too (its colour codes may open the report's line)
    lines = [line[line.index('{"path"'):] for line in done.stdout.splitlines() if '{"path"' in line]
    if done.returncode == 0 and lines:
        return SceneReport.from_json(lines[-1])
    tail = [line.strip() for line in done.stderr.splitlines() if line.strip()]
    last = next((line for line in reversed(tail) if "error" in line.lower()), tail[-1] if tail else "")
    how = (f"killed by signal {-done.returncode}" if done.returncode < 0 else f"exit status {done.returncode}")
    return SceneReport(str(path), [Check("process", False, f"{how}: {last[:300]}")])


def verify_scenes(paths: Iterable[str | os.PathLike], *, spp: int = 2, seed: int = 0,
                  params: dict[str, str] | None = None, steps: Sequence[str] = STEPS, isolate: bool = True,
                  timeout: float = SCENE_TIMEOUT, progress: bool = True) -> list[SceneReport]:
    """:func:`check_scene` for every scene :func:`scene_files` finds in ``paths`` (files or folders).

    With ``isolate`` (the default) each scene runs in a process of its own, stopped after
    ``timeout`` seconds: one that aborts or hangs is reported, and the others still run.
    """
    from pointillist.core.checks import integer

    spp = integer(spp, "spp", low=1)
    seed = integer(seed, "seed", low=0)
    files = scene_files(paths)
    params = dict(params or {})
    reports = []
    from pointillist.core.terminal import progress_bar

    for path in progress_bar(files, progress=progress, desc="scenes", unit="scene"):
        if isolate:
            reports.append(_child(path, spp=spp, seed=seed, params=params, steps=steps, timeout=timeout))
        else:
            reports.append(check_scene(path, spp=spp, seed=seed, params=params, steps=steps))
    return reports


def _main(argv: list[str] | None = None) -> int:
    """The process :func:`verify_scenes` starts for one scene: prints the report as one JSON line."""
    import argparse

    from pointillist.scene import parse_defines

    parser = argparse.ArgumentParser(prog="python -m pointillist.differential")
    parser.add_argument("scene")
    parser.add_argument("--spp", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", default=",".join(STEPS))
    parser.add_argument("-D", dest="defines", action="append", default=[])
    args = parser.parse_args(argv)
    report = check_scene(args.scene, spp=args.spp, seed=args.seed, params=parse_defines(args.defines),
                         steps=[s for s in args.steps.split(",") if s])
    print(report.to_json(), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(_main())
