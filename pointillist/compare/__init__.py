"""``pointillist compare``: sampling methods on one scene, error against a reference, time and spp.

:func:`compare_scene` is the whole command as one function. Its parts, one job each:

- :mod:`~pointillist.compare.methods`: the methods a sweep can use (every sampler plugin of
  pointillist and of Mitsuba, and ``adaptive``) and how each is put into the scene;
- :mod:`~pointillist.compare.records`: what is kept on disk: each render's record and scores, the
  scene's facts;
- :mod:`~pointillist.compare.sweep`: the renders (:func:`render_one`, on a Dask cluster
  :func:`prerender_sweep`) and their scores against the reference (:func:`run_sweep`);
- :mod:`~pointillist.compare.tables`: the numbers (summaries over seeds, slopes, rankings, the
  results table, the time format);
- :mod:`~pointillist.compare.report`: ``results.csv``, ``results.md`` and the plots;
- :mod:`~pointillist.compare.html` (with the page's template and scripts in ``page/``):
  ``report.html``;
- :mod:`~pointillist.compare.outputs`: those files written again only when what they are made
  from changed.

Every render, every score and every report file is kept in the comparison folder, so running the
same command again resumes an interrupted sweep and costs, once everything is there, little more
than starting up and reading the records back.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pointillist.core import signals
from pointillist.compare.methods import resolve_methods, sweep_parameter
from pointillist.compare.records import RenderRecord, SceneFacts, Task, record_json
from pointillist.compare.sweep import (REFERENCE_SAMPLER, REFERENCE_SEED, prerender_sweep, render_one,
                                       render_reference, run_sweep)
from pointillist.core.errors import UsageError
from pointillist.core.files import input_file

__all__ = ["compare_scene", "CompareResult", "sweep_tasks", "DEFAULT_SPP", "DEFAULT_METHODS", "Task", "RenderRecord",
           "render_one", "run_sweep", "prerender_sweep", "REFERENCE_SAMPLER", "REFERENCE_SEED", "MAX_SEEDS"]

#: Default sweep of ``pointillist compare``.
DEFAULT_SPP = (1, 4, 16, 64, 256)

DEFAULT_METHODS = ("grid", "jitter", "random", "poisson")

#: The most seeds (renders of each point of the sweep) a compare takes: the mean and spread over
#: seeds settle within tens; 100000 asked a sweep of days without a word.
MAX_SEEDS = 1000


@dataclass
class CompareResult:
    """What :func:`compare_scene` did: the records, the report's files, the reference used.

    ``kept``: the roles of ``paths`` left as they were, because what they are made from had not
    changed since they were written (:mod:`pointillist.compare.outputs`)."""

    records: list[RenderRecord]
    paths: dict[str, Path]
    reference: Path
    out_dir: Path
    cluster_renders: int = 0
    notes: list[str] = field(default_factory=list)
    kept: list[str] = field(default_factory=list)

    @property
    def new(self) -> int:
        """How many renders were made by this run (the rest came from the folder)."""
        return sum(1 for r in self.records if not r.cached)


def sweep_tasks(methods: Sequence[str] | str, spp: Sequence[int], seeds: int) -> list[Task]:
    """The tasks of a sweep: every method at every sweep value (``spp`` for samplers, the
    method's own values otherwise) and seed ``0..seeds-1`` (at most :data:`MAX_SEEDS`)."""
    from pointillist.core import checks

    seeds = checks.integer(seeds, "--seeds", low=1, high=MAX_SEEDS)
    tasks = []
    for method in resolve_methods(methods):
        values = list(spp) if method.parameter == "spp" else list(method.values)
        if not values:
            raise UsageError(f"--samplers: {method.name} sweeps {method.parameter}, which has no values")
        tasks += [Task(method.name, v, seed) for v in values for seed in range(seeds)]
    return tasks


def compare_scene(scene: str | os.PathLike, *, methods: Sequence[str] | str = DEFAULT_METHODS,
                  spp: Sequence[int] = DEFAULT_SPP, seeds: int = 1, reference_spp: int = 4096,
                  reference: str | os.PathLike | None = None, out_dir: str | os.PathLike | None = None,
                  params: dict[str, str] | None = None, workers: int | None = None, scheduler: str | None = None,
                  progress: bool = True, report: bool = True,
                  log: Callable[[str], None] = lambda line: None) -> CompareResult:
    """``pointillist compare``: sweep ``methods`` over ``spp`` and ``seeds`` on one scene, score
    every render against a reference and write the report into ``out_dir``.

    The reference is ``reference`` (an EXR of the render's size) or a render of
    :data:`REFERENCE_SAMPLER` at ``reference_spp``, kept in ``out_dir/reference``.
    Everything that can be checked (scene, sample counts, reference size) is checked
    before the first render. ``log`` receives progress lines (e.g. ``print``; one per
    finished render when ``progress`` is on and standard error is not a terminal).
    With ``report``, ``out_dir/report.html`` (:mod:`pointillist.compare.html`) is
    written too, from every render of the sweep on disk (also those of earlier,
    interrupted runs); ``paths["html"]`` is its path and ``notes`` say its size.
    ``notes`` (also given to ``log`` and listed in results.md) also say which
    reconstruction filter the film uses (only a box filter makes a pixel the plain
    average of its samples) and when the reference took another spp than asked.
    The report's files are written again only when what they are made from changed
    (:mod:`pointillist.compare.outputs`), and the scene is built only when something is
    rendered or its facts (size, film filter) are not stored yet.

    Raises
    ------
    UsageError
        For a missing scene, unknown method, an output folder that is a file, a sample
        count Mitsuba cannot take, or a reference of the wrong size.
    """
    import pointillist
    from pointillist.plan import inputs_digest, scene_inputs
    from pointillist.scene import check_scene_file, filter_note, parse_scene

    params = dict(params or {})
    tasks = sweep_tasks(methods, spp, seeds)
    scene = check_scene_file(scene)
    out = Path(out_dir) if out_dir else Path("out") / "compare" / scene.stem
    if reference is not None:
        input_file(reference, "--reference")
    plan = _plan(scene, out, reference, report)
    pointillist.setup(plugins=False)  # parsing needs the variant; building the scene, the plugins
    inputs = scene_inputs(parse_scene(scene, params))
    plan.add(inputs=inputs)
    key = inputs_digest(inputs, params)[:12]
    facts, learnt = _scene_facts(scene, params, out, key)
    for count in [t.value for t in tasks if sweep_parameter(t.method) == "spp"] + (
            [] if reference else [reference_spp]):
        _check_sample_count(facts, int(count))  # before any render starts (and its progress bar)
    if reference is not None:
        _check_reference(Path(reference), (facts.width, facts.height), what="--reference")
    with plan.writing():
        if learnt:
            from pointillist.compare.records import save_scene_facts

            save_scene_facts(out, key, facts)
        notes: list[str] = [filter_note(facts.film_filter)]
        log(notes[0])
        rendered: list = []
        if workers or scheduler:
            from pointillist.distributed import open_client

            with open_client(workers, scheduler, tasks=len(tasks) + (0 if reference else 1)) as client:
                rendered = prerender_sweep(client, scene, tasks, params=params, out_dir=out,
                                           reference_spp=None if reference else reference_spp,
                                           progress=progress, key=key)
            log(f"{len(rendered)} renders done on the cluster")
        if reference is not None:
            reference = Path(reference)
        else:
            reference = _rendered_reference(scene, params, out, reference_spp, key, facts, notes, log)
        maps: dict[str, dict[str, np.ndarray]] | None = {} if report else None  # FLIP once per render, not twice
        spectra: dict = {}
        records = run_sweep(str(scene), tasks, params=params, out_dir=str(out), reference=reference,
                            progress=progress, log=log, maps=maps, spectra=spectra, key=key, rendered=rendered)
        signals.check()
        paths, kept = _write_outputs(records, out, scene=str(scene), reference=reference, notes=notes,
                                     spectra=spectra, maps=maps)
    return CompareResult(records=records, paths=paths, reference=reference, out_dir=out,
                         cluster_renders=len(rendered), notes=notes, kept=kept)


def _plan(scene: Path, out: Path, reference: str | os.PathLike | None, report: bool):
    """compare's plan, checked before any work: the folder and every file of the report writable,
    none an input (:class:`pointillist.plan.Plan`)."""
    from pointillist.compare.html import REPORT_NAME
    from pointillist.compare.report import report_paths
    from pointillist.plan import Output, Plan

    files = list(report_paths(out).values()) + ([out / REPORT_NAME] if report else [])
    plan = Plan(inputs=[scene] + ([Path(reference)] if reference is not None else []),
                outputs=[Output(out, "--out", folder=True)]
                + [Output(path, f"--out ({path.name})", make_parent=True) for path in files]
                + [Output(out / "renders", "--out (renders)", folder=True),
                   Output(out / "reference", "--out (reference)", folder=True)])
    plan.check()
    return plan


def _scene_facts(scene: Path, params: dict[str, str], out: Path, key: str) -> tuple[SceneFacts, bool]:
    """What the scene renders (size, film filter): stored for its key by an earlier run, or learnt
    by building it (then ``True``: to be stored). Building it also refuses a scene that renders no
    colour (only AOVs): nothing to compare."""
    from pointillist.compare.records import load_scene_facts

    facts = load_scene_facts(out, key)
    if facts is not None:
        return facts, False
    import pointillist
    from pointillist.channels import channel_layout
    from pointillist.scene import film_filter, instantiate_scene, parse_scene, scene_info

    pointillist.setup()  # the plugins, which the scene may use
    loaded = instantiate_scene(parse_scene(scene, params))  # bad scenes fail before any render
    info, rfilter, layout = scene_info(loaded), film_filter(loaded), channel_layout(loaded)
    del loaded
    if not layout.colour:
        raise UsageError(f"scene {scene}: the render has no colour channels (Mitsuba's aov integrator without a "
                         f"nested integrator renders only AOVs: {', '.join(layout.names)}): nothing to compare")
    return SceneFacts(width=int(info["width"]), height=int(info["height"]), film_filter=rfilter), True


def _check_sample_count(facts: SceneFacts, count: int) -> None:
    from pointillist.scene import check_sample_count

    check_sample_count(facts.width, facts.height, count)


def _rendered_reference(scene: Path, params: dict[str, str], out: Path, spp: int, key: str, facts: SceneFacts,
                        notes: list[str], log: Callable[[str], None]) -> Path:
    """The reference rendered (or found) in ``out/reference``, checked; a note when the sampler
    took another spp than asked."""
    log(f"reference: {spp} spp with Mitsuba's stratified sampler (cached in {out / 'reference'})")
    reference = render_reference(str(scene), params, str(out), spp, key, log=log)
    taken = _reference_spp(_check_reference(reference, (facts.width, facts.height), what="reference").metadata)
    if taken is not None and taken != spp:
        note = f"reference: the stratified sampler took {taken} spp for the {spp} asked (it rounds up to a square)"
        notes.append(note)
        log(note)
    return reference


def _write_outputs(records: Sequence[RenderRecord], out: Path, *, scene: str, reference: Path, notes: list[str],
                   spectra: dict, maps: dict | None, title: str | None = None) -> tuple[dict[str, Path], list[str]]:
    """The report's files (:func:`pointillist.compare.report.write_report`) and, with ``maps`` (not
    None), the page (:func:`pointillist.compare.html.write_html_report`), each group written only
    when what it is made from changed (:mod:`pointillist.compare.outputs`); the page's summary is
    added to ``notes``. Returns the paths by role (``html``: the page) and the roles left as they
    were."""
    from pointillist.compare import outputs
    from pointillist.compare.report import report_paths

    title = title or f"Sampler comparison: {Path(scene).name}"
    stat = reference.stat()
    made_from = {"records": [record_json(r) for r in records], "scene": scene, "reference": str(reference),
                 "reference_file": [stat.st_size, stat.st_mtime_ns], "title": title}
    paths, kept = report_paths(out), []
    key = outputs.outputs_key(**made_from, notes=notes)
    if outputs.unchanged(out, "report", key) is None:
        from pointillist.compare.report import write_report

        paths = write_report(records, out, scene=scene, reference=str(reference), title=title, notes=notes,
                             spectra=spectra)
        outputs.remember(out, "report", key, list(paths.values()))
    else:
        kept += list(paths)
    if maps is None:
        return paths, kept
    from pointillist.compare.html import REPORT_NAME

    key = outputs.outputs_key(**made_from)
    info = outputs.unchanged(out, "page", key)
    if info is None or "summary" not in info:
        from pointillist.compare.html import write_html_report

        page = write_html_report(records, out, scene=scene, reference=reference, title=title, maps=maps)
        info = {"summary": page.summary}
        outputs.remember(out, "page", key, [page.path], info)
    else:
        kept.append("html")
    paths["html"] = out / REPORT_NAME
    notes.append(info["summary"])
    return paths, kept


def _reference_spp(metadata: dict) -> int | None:
    """The samples per pixel a rendered reference took (from its EXR header), or None."""
    value = metadata.get("spp")
    return int(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def _check_reference(reference: Path, size: tuple[int, int], *, what: str = "--reference"):
    """The reference must read as a finite image of the render size ``(width, height)``; returns it
    as read (an ``EXRImage``). A NaN or infinite value would make every error against it NaN or
    infinite (and their log-log plots impossible): refused, with the count of each kind."""
    from pointillist.imaging.io import read_exr

    try:
        exr = read_exr(reference, copies=8)  # the reference, its FLIP and error maps beside each render's
    except ValueError as error:
        raise UsageError(f"{what}: {error}") from None
    image = exr.image
    if image.shape[:2] != (size[1], size[0]):
        raise UsageError(f"{what}: {reference} is {image.shape[1]}x{image.shape[0]}, the scene "
                         f"renders {size[0]}x{size[1]}")
    bad = ~np.isfinite(image)
    if bad.any():
        counts = [(int(np.count_nonzero(image == np.inf)), "+inf"), (int(np.count_nonzero(image == -np.inf)), "-inf"),
                  (int(np.count_nonzero(np.isnan(image))), "NaN")]
        y, x = (int(v) for v in np.argwhere(bad.reshape(image.shape[0], image.shape[1], -1).any(axis=2))[0])
        kinds = ", ".join(f"{n} {name}" for n, name in counts if n)
        cause = "" if what == "--reference" else " (the scene renders them)"
        raise UsageError(f"{what}: {reference} holds non-finite values{cause}: {kinds} (first at pixel x={x}, "
                         f"y={y}); errors against it would be NaN or infinite: expected a finite reference")
    return exr
