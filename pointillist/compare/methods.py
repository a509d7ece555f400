"""The methods ``pointillist compare`` can sweep, and how each is put into a scene.

Methods live in :data:`METHODS`, built from the plugin registries, not from a list of names:
every sampler plugin of pointillist (:func:`pointillist.plugins.available`: a new module in
``plugins/samplers/`` is a new method, under its plugin name) and every sampler of Mitsuba
(:data:`MITSUBA_SAMPLERS`) is a sampler method, which swaps the ``<sampler>`` of every
``<sensor>`` of the scene XML (so any user scene works, whatever its sampler); ``random`` is
Mitsuba's ``independent`` under the course's name (:data:`SAMPLER_ALIASES`). Methods of another
kind are added with :func:`register_method`: ``adaptive`` (adaptive super-sampling, whose sweep
parameter is a threshold) swaps the ``<integrator>``.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from pointillist.core.errors import UsageError

__all__ = [
    "Method", "METHODS", "MITSUBA_SAMPLERS", "SAMPLER_ALIASES", "ADAPTIVE_THRESHOLDS", "ADAPTIVE_DEPTHS",
    "register_method", "describe_methods", "resolve_methods", "sweep_parameter", "setting_label", "configure_scene",
    "swap_samplers",
    "scene_key", "load_configured_scene",
]


#: Mitsuba's samplers: the plugins whose type Mitsuba's plugin manager reports as a sampler
#: (checked against Mitsuba in tests/test_compare.py, which would fail if a version added one).
MITSUBA_SAMPLERS = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")

#: Other names of sampler methods: ``random`` is uniform random sampling, Mitsuba's ``independent``.
SAMPLER_ALIASES = {"random": "independent"}


# ----------------------------------------------------------------------------- methods
@dataclass(frozen=True)
class Method:
    """How the scene is configured for one compared method.

    Attributes
    ----------
    name : str
        The name on the command line (``random``).
    plugin : str
        The Mitsuba plugin type put into the scene (``independent``).
    kind : {"sampler", "integrator"}
        ``sampler``: every sensor's ``<sampler>`` becomes ``<sampler type=plugin>``
        with ``sample_count`` = the sweep value; ``integrator``: the scene's
        ``<integrator>`` becomes ``<integrator type=plugin>`` with the property
        ``parameter`` = the sweep value.
    parameter : str
        The sweep parameter: ``spp`` for samplers (the ``--spp`` list), or the
        integrator property swept (e.g. ``threshold``).
    values : tuple of float
        The default sweep of a non-``spp`` parameter.
    configure : callable, optional
        ``configure(root, value)`` edits the parsed scene XML in place instead of
        the default for ``kind`` (must be a module-level function: tasks are pickled).
    summary : str
        What the method does, in one line (``compare -h``); for a sampler plugin, its own
        summary (:func:`pointillist.plugins.summary`) is shown instead.
    """

    name: str
    plugin: str
    kind: str = "sampler"
    parameter: str = "spp"
    values: tuple[float, ...] = ()
    configure: Callable[[ET.Element, float], None] | None = None
    summary: str = ""

#: Registered methods by name: every sampler plugin of pointillist and of Mitsuba, the aliases, then the others.
METHODS: dict[str, Method] = {}

def register_method(method: Method) -> None:
    """Add ``method`` to :data:`METHODS` (replacing one of the same name)."""
    if method.kind not in ("sampler", "integrator"):
        raise ValueError(f"method.kind: expected 'sampler' or 'integrator', got {method.kind!r}")
    METHODS[method.name] = method

def _register_samplers() -> None:
    """Every sampler plugin of pointillist and of Mitsuba as a sampler method of its plugin name,
    and the :data:`SAMPLER_ALIASES` (the plugin files are read, not imported: no Mitsuba needed)."""
    from pointillist import plugins

    for name in (*plugins.available("sampler"), *MITSUBA_SAMPLERS):
        register_method(Method(name, name))
    for alias, plugin in SAMPLER_ALIASES.items():
        register_method(Method(alias, plugin))

_register_samplers()

def _configure_adaptive(root: ET.Element, value: float) -> None:
    """Wrap the scene's ``<integrator>`` in ``<integrator type="adaptive">`` with
    ``threshold`` = ``value`` (an adaptive integrator already there gets the threshold)."""
    old = root.findall("integrator")
    if old and old[0].get("type") == "adaptive":
        adaptive = old[0]
        for element in adaptive.findall("*[@name='threshold']"):
            adaptive.remove(element)
        adaptive.insert(0, _property("float", "threshold", float(value)))
        return
    position = list(root).index(old[0]) if old else 0
    for element in old:
        root.remove(element)
    adaptive = ET.Element("integrator", {"type": "adaptive"})
    adaptive.append(_property("float", "threshold", float(value)))
    for name, depth in ADAPTIVE_DEPTHS.items():
        adaptive.append(_property("integer", name, depth))
    adaptive.append(old[0] if old else ET.Element("integrator", {"type": "path"}))
    root.insert(position, adaptive)

#: Adaptive super-sampling (plugins/integrators/adaptive.py) sweeps its threshold on
#: the 0..255 display scale, around the scene's own integrator, starting from the 3 x 3
#: lattice per pixel (min_depth 1) down to depth 3: the best error-vs-time curve on
#: scenes/edges.xml (benchmarks/RESULTS.md, "adaptive"); below 16 the error stops falling.
ADAPTIVE_THRESHOLDS = (128.0, 64.0, 32.0, 16.0)

ADAPTIVE_DEPTHS = {"min_depth": 1, "max_depth": 3}

register_method(Method("adaptive", "adaptive", kind="integrator", parameter="threshold",
                       values=ADAPTIVE_THRESHOLDS, configure=_configure_adaptive,
                       summary="adaptive super-sampling around the scene's integrator, sweeping its threshold "
                               "instead of --spp"))

def describe_methods() -> str:
    """The methods as ``pointillist compare -h`` lists them: pointillist's samplers with what each
    does, Mitsuba's samplers (and their other names), then the methods of another kind.

    Examples
    --------
    >>> text = describe_methods()
    >>> "grid (samples at the centres of a regular sub-pixel grid)" in text
    True
    >>> "Mitsuba's independent (also random)" in text
    True
    """
    from pointillist import plugins

    ours = [f"{name} ({plugins.summary(name)})" for name in plugins.available("sampler")]
    mitsuba = [name + "".join(f" (also {alias})" for alias, plugin in SAMPLER_ALIASES.items() if plugin == name)
               for name in MITSUBA_SAMPLERS]
    others = [f"{method.name} ({method.summary})" for method in METHODS.values() if method.kind != "sampler"]
    return f"pointillist's {', '.join(ours)}; Mitsuba's {', '.join(mitsuba)}" + \
        "".join(f"; or {text}" for text in others)

def resolve_methods(names: str | Iterable[str]) -> list[Method]:
    """Parse ``grid,jitter,...`` into methods; UsageError names an unknown one."""
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",")]
    names = [n for n in names if n]
    if not names:
        raise UsageError("--samplers: expected a comma-separated list of sampler names")
    methods, seen = [], set()
    for name in names:
        if name not in METHODS:
            raise UsageError(f"--samplers: unknown sampler {name!r}; expected some of "
                             f"{', '.join(sorted(METHODS))}")
        if name not in seen:
            seen.add(name)
            methods.append(METHODS[name])
    return methods


def sweep_parameter(method: str) -> str:
    """What ``method`` sweeps: ``spp`` for samplers (and unknown names), else its integrator property."""
    spec = METHODS.get(method)
    return "spp" if spec is None else spec.parameter


def setting_label(method: str, value: float) -> str:
    """The sweep point as people read it: ``16 spp`` for a sampler, ``threshold 64``
    for an integrator method (its :attr:`Method.parameter`)."""
    parameter = sweep_parameter(method)
    return f"{value:g} spp" if parameter == "spp" else f"{parameter} {value:g}"


# ------------------------------------------------------------------------ scene set-up
def _property(tag: str, name: str, value: Any) -> ET.Element:
    return ET.Element(tag, {"name": name, "value": str(value)})

def configure_scene(xml_text: str | bytes, method: Method, value: float) -> str:
    """The scene XML text with integrator ``method`` swapped in at sweep value ``value``.

    The scene's ``<integrator>`` is replaced by ``<integrator type=plugin>`` holding only the
    method's parameter (or edited by the method's own ``configure``). ``xml_text`` may be the
    file's bytes: their XML declaration or byte-order mark says the encoding (UTF-16, Latin-1 ...).
    Sampler methods are swapped in the parsed scene instead (:func:`swap_samplers`), wherever an
    ``<include>`` put the sensors.

    Raises UsageError for XML that does not parse, ValueError for a sampler method.
    """
    if method.kind == "sampler":
        raise ValueError(f"method: {method.name} is a sampler method; swap_samplers puts it into a parsed scene")
    try:
        root = ET.fromstring(xml_text)
    except ET.ParseError as error:
        raise UsageError(f"scene: not valid XML ({error})") from None
    if method.configure is not None:
        method.configure(root, value)
    else:
        old = root.findall("integrator")
        position = list(root).index(old[0]) if old else 0
        for element in old:
            root.remove(element)
        integrator = ET.Element("integrator", {"type": method.plugin})
        integrator.append(_property("float", method.parameter, float(value)))
        root.insert(position, integrator)
    return ET.tostring(root, encoding="unicode")


def swap_samplers(parsed, plugin: str, sample_count: int) -> None:
    """Give every top-level sensor of a parsed scene (:class:`pointillist.scene.ParsedScene`, in
    place) the sampler ``<sampler type=plugin>`` holding only ``sample_count``: the old sampler's
    other properties (which the new type may not have) are dropped; a sensor without a sampler
    gets one. Sensors stated in an ``<include>`` count as the scene's own.

    Raises UsageError for a scene without a sensor.
    """
    import mitsuba as mi

    from pointillist.parsed_state import references
    from pointillist.scene import add_node, top_level_objects

    state = parsed.state
    sensors = [i for i in top_level_objects(state) if state.nodes[i].type == mi.ObjectType.Sensor]
    if not sensors:
        raise UsageError(f"scene {parsed.path}: has no <sensor> (compare swaps the sensor's <sampler>)")

    def sampler() -> Any:
        props = mi.Properties(plugin)
        props["sample_count"] = int(sample_count)
        return props

    for index in sensors:
        own = [i for i in references(state.nodes[index].props) if state.nodes[i].type == mi.ObjectType.Sampler]
        for child in own:
            state.nodes[child].props = sampler()
        if not own:
            add_node(state, index, mi.ObjectType.Sampler, sampler(), "_swapped_sampler")


def scene_key(scene_path: str | os.PathLike, params: dict[str, str] | None = None) -> str:
    """A short hash of the scene's inputs (the scene file and every file it reads) and parameters
    (:func:`pointillist.plan.scene_digest`): the validity of cached renders. Parses the scene
    (:func:`pointillist.setup` first)."""
    from pointillist.plan import scene_digest

    return scene_digest(scene_path, params)[:12]

def load_configured_scene(scene_path: str | os.PathLike, method: Method, value: float,
                          params: dict[str, str] | None = None):
    """Load ``scene_path`` with ``method`` swapped in; relative paths resolve as in the file.

    Camera-relative where the scene sits far from the origin, as :func:`pointillist.scene.load_scene`
    loads it. Pointillist must be set up (:func:`pointillist.setup`).
    """
    from pointillist.camera_relative import make_camera_relative
    from pointillist.scene import check_scene_file, instantiate_scene, parse_scene

    path = check_scene_file(scene_path)
    what = f" with {method.name}"
    if method.kind == "sampler":
        parsed = parse_scene(path, params, what=what)
        swap_samplers(parsed, method.plugin, int(value))
    else:
        parsed = parse_scene(path, params, text=configure_scene(path.read_bytes(), method, value), what=what)
    return instantiate_scene(make_camera_relative(parsed), what=what)
