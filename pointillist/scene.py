"""Loading Mitsuba scenes with user parameters, and rendering them with a timing split."""

from __future__ import annotations

import re
import time
import warnings
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from pointillist.core import signals
from pointillist.core.checks import UINT32_MAX, memory
from pointillist.camera_relative import make_camera_relative
from pointillist.parsed_state import references, resolving_from
from pointillist.core.errors import UsageError

__all__ = ["parse_defines", "ParsedScene", "parse_scene", "instantiate_scene", "attach_films", "load_scene",
           "check_scene_file", "root_cause", "top_level_objects", "add_node",
           "thread_count", "render_error", "DEFAULT_INTEGRATOR", "check_sensor", "MAX_FILTER_RADIUS",
           "mitsuba_message", "MAX_MESSAGE", "RenderTiming", "timed_render", "scene_info", "film_filter",
           "filter_note", "check_sample_count"]

_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_PREFIX = re.compile(r"\[[A-Za-z0-9_]+\.(?:cpp|h|py):\d+\]\s*")
_TRACEBACK = re.compile(r"Traceback \(most recent call last\):\n(?:[ \t].*\n)*(?P<exception>\S.*)")


_INCLUDE = re.compile(r"Error while loading (?P<file>.+?) \(line \d+, col \d+\): while processing <include>: ")

#: The longest message :func:`mitsuba_message` returns (characters; longer ones are cut with "...").
MAX_MESSAGE = 400


def mitsuba_message(error: BaseException) -> str:
    """One line from a Mitsuba exception: source-location prefixes dropped, lines joined.

    A chain of nested ``<include>`` errors (an include cycle repeats it 15 times) keeps
    its first and last link and names the files in between; the line is cut at
    :data:`MAX_MESSAGE` characters.
    """
    text = _PREFIX.sub("", str(error))
    # A Python plugin's exception reaches us as Mitsuba's message with the Python traceback
    # pasted in: keep the text before it and the exception's own last line.
    text = _TRACEBACK.sub(lambda m: m.group("exception"), text)
    text = " ".join(part.strip(" -") for part in text.splitlines() if part.strip())
    links = list(_INCLUDE.finditer(text))
    if len(links) > 2:
        files = list(dict.fromkeys(Path(m.group("file")).name for m in links[1:]))
        text = (text[:links[0].end()] + f"[{len(links) - 1} nested <include>s of {', '.join(files[:4])}"
                + (", ..." if len(files) > 4 else "") + "] " + text[links[-1].end():])
    return text if len(text) <= MAX_MESSAGE else text[:MAX_MESSAGE - 3] + "..."


def root_cause(error: BaseException) -> BaseException:
    """The innermost exception of a chain: ``mi.render`` reports a plugin's failure as
    "drjit.custom(...): error while performing a custom differentiable operation. (see above)",
    with the plugin's own exception chained to it."""
    seen = {id(error)}
    while True:
        inner = error.__cause__ or error.__context__
        if inner is None or id(inner) in seen:
            return error
        seen.add(id(inner))
        error = inner


def render_error(error: RuntimeError) -> Exception:
    """What a failed ``mi.render`` becomes: Mitsuba's own message as one line in a UsageError (the
    scene asks for something this variant or machine cannot do: a blackbody spectrum in an RGB
    variant, a film larger than one tensor), or the root exception itself when it is not Mitsuba's
    (a bug: it stays an internal error)."""
    cause = root_cause(error)
    if isinstance(cause, RuntimeError):
        return UsageError(f"Mitsuba could not render the scene: {mitsuba_message(cause)}")
    return cause


def parse_defines(defines: list[str] | None) -> dict[str, str]:
    """Parse ``-D key=value`` strings into a dict; UsageError names the bad one."""
    params: dict[str, str] = {}
    for item in defines or []:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not _KEY.match(key):
            raise UsageError(f"-D {item!r}: expected key=value with key a scene parameter name")
        params[key] = value
    return params


@dataclass
class ParsedScene:
    """A scene file parsed by Mitsuba's parser but not yet instantiated.

    ``state`` is the ``mitsuba.parser.ParserState`` after Mitsuba's own transformations
    (version upgrade, named references resolved): every node's properties, with transforms and
    positions in float64 as the XML states them, and ``state.files`` (the scene file and every
    ``<include>``). Changing ``state`` before :func:`instantiate_scene` changes the scene Mitsuba
    builds. ``path`` is the scene file, ``params`` the ``-D`` values it was parsed with.
    ``recentring`` is what :func:`pointillist.camera_relative.make_camera_relative` did to
    ``state`` (``None`` before it ran). ``resolver`` is Mitsuba's file resolver as the parser left
    it: the scene's folder first, after the folders its ``<path>`` elements name; files resolve
    through it when the scene is built, as in ``mi.load_file``. A scene that states no
    ``<integrator>`` gets Mitsuba's ``path`` (:data:`DEFAULT_INTEGRATOR`).
    """

    path: Path
    params: dict[str, str]
    state: Any
    config: Any
    recentring: Any = None
    resolver: Any = None


#: The integrator of a scene that states none: Mitsuba's path tracer with its defaults, the
#: integrator Mitsuba's documentation names as the default.
DEFAULT_INTEGRATOR = "path"


def parse_scene(path: str | Path, params: dict[str, str] | None = None, *, text: str | None = None,
                what: str = "", merge_meshes: bool = True) -> ParsedScene:
    """Parse a Mitsuba scene file with ``$param`` overrides, without building it.

    ``text``, when given, is parsed instead of the file's contents (relative paths still resolve
    against the file's folder). Errors become one-line UsageErrors (``what`` is added to their
    subject, e.g. ``" with jitter"``). The variant must be set
    (:func:`pointillist.setup`).

    ``merge_meshes``: Mitsuba's optimisation that merges the meshes sharing a BSDF (on, as in
    ``mi.load_file``). It orders the scene's shapes, and so its emitters, by a hash of addresses that
    changes from process to process: on a scene with several emitters the light a sample picks, and
    so the image, then differs between processes even on one thread. Off: each shape as declared, the
    same scene in every process (what renders that must agree across processes load: a tiled
    progressive render's passes, :mod:`pointillist.progressive.tiled`).
    """
    import mitsuba as mi

    path = check_scene_file(path)
    params = dict(params or {})
    config = mi.parser.ParserConfig(mi.variant())
    # parallel=False: Mitsuba's parallel loader instantiates plugins in a random order, which
    # changes the generated kernels from run to run and defeats the ~/.drjit kernel cache.
    config.parallel = False
    config.merge_meshes = bool(merge_meshes)
    try:
        with resolving_from(path.resolve().parent):
            if text is None:
                state = mi.parser.parse_file(config, str(path), **params)
            else:
                state = mi.parser.parse_string(config, text, **params)
            # Mitsuba's parser adds the folders of <path> elements to the resolver it finds
            # set: keep them for building the scene (mi.load_file does the same in one call).
            resolver = mi.FileResolver(mi.file_resolver())
            mi.parser.transform_all(config, state)
    except RuntimeError as error:
        raise UsageError(f"scene {path}{what}: {mitsuba_message(error)}") from None
    signals.check()
    if _add_default_integrator(state):
        warnings.warn(f"scene {path}: no <integrator>; rendering with Mitsuba's default, "
                      f"<integrator type=\"{DEFAULT_INTEGRATOR}\"/>", stacklevel=2)
    return ParsedScene(path=path, params=params, state=state, config=config, resolver=resolver)


def top_level_objects(state) -> list[int]:
    """The node indices of a parsed scene's top-level objects (its integrator, sensors, shapes,
    emitters ...), wherever an ``<include>`` stated them: the root's references, and those of the
    ``merge`` containers Mitsuba's parser gathers meshes in."""
    import mitsuba as mi

    found, pending, seen = [], list(references(state.nodes[0].props)), set()
    while pending:
        index = pending.pop(0)
        if index in seen:
            continue
        seen.add(index)
        node = state.nodes[index]
        if node.type == mi.ObjectType.Shape and node.props.plugin_name() == "merge":
            pending = references(node.props) + pending
        else:
            found.append(index)
    return found


def _add_default_integrator(state) -> bool:
    """Give a parsed scene root that states no integrator Mitsuba's default one
    (:data:`DEFAULT_INTEGRATOR`, its defaults); True when it was added.

    ``mi.render`` refuses such a scene ("No integrator specified"); Mitsuba's documentation says a
    scene without one renders with the path tracer, which is what a user of its scenes expects.
    """
    import mitsuba as mi

    if state.nodes[0].type != mi.ObjectType.Scene:
        return False
    if any(state.nodes[index].type == mi.ObjectType.Integrator for index in top_level_objects(state)):
        return False
    add_node(state, 0, mi.ObjectType.Integrator, mi.Properties(DEFAULT_INTEGRATOR), "_default_integrator")
    return True


def add_node(state, parent: int, kind, props, key: str) -> int:
    """Append a node of object type ``kind`` holding ``props`` to a parsed scene, referenced by the
    node ``parent`` under the property ``key``; returns its index. (A node read from
    ``state.nodes`` is a view into the list, which the append may move: it is read again after.)"""
    import mitsuba as mi

    node = mi.parser.SceneNode()
    node.type = kind
    node.props = props
    node.file_index = state.nodes[parent].file_index
    state.nodes.append(node)
    index = len(state.nodes) - 1
    state.nodes[parent].props[key] = mi.Properties.ResolvedReference(index)
    return index


def instantiate_scene(parsed: ParsedScene, *, what: str = ""):
    """Build the Mitsuba scene of a :class:`ParsedScene`; errors become one-line UsageErrors.

    Relative file names (textures, meshes, volumes) resolve against the scene file's folder.
    ``what`` is added to the error's subject (e.g. ``" with jitter"``).
    """
    import mitsuba as mi

    try:
        with resolving_from(parsed.path.resolve().parent, parsed.resolver):
            scene = mi.parser.instantiate(parsed.config, parsed.state)
    except RuntimeError as error:
        raise UsageError(f"scene {parsed.path}{what}: {mitsuba_message(error)}") from None
    if not isinstance(scene, mi.Scene):
        raise UsageError(f"scene {parsed.path}: expected a <scene> root element, got {type(scene).__name__}")
    check_sensor(scene, parsed.path)
    attach_films(scene)
    signals.check()
    return scene


def attach_films(scene) -> None:
    """Give each sensor's sampler that lays samples out over the film (``zsobol``: its
    ``attach_film`` method) the sensor's film: a Mitsuba sampler is built before, and apart
    from, the film whose pixels it samples."""
    for sensor in scene.sensors():
        attach = getattr(sensor.sampler(), "attach_film", None)
        if attach is not None:
            attach(sensor.film())


def load_scene(path: str | Path, params: dict[str, str] | None = None, *, merge_meshes: bool = True):
    """Load a Mitsuba scene file with ``$param`` overrides; errors become one-line UsageErrors.

    :func:`parse_scene` (``merge_meshes``: see there), then the scene re-expressed relative to its
    first sensor where it sits far from the origin (:mod:`pointillist.camera_relative`), then
    :func:`instantiate_scene`. The variant must be set and the plugins registered
    (:func:`pointillist.setup`).
    """
    return instantiate_scene(make_camera_relative(parse_scene(path, params, merge_meshes=merge_meshes)))


def check_scene_file(path: str | Path) -> Path:
    """``path`` as a Path; UsageError unless it is an existing file (a folder is named as such) whose
    full name is UTF-8 (Mitsuba takes file names as UTF-8 text only)."""
    from pointillist.core.files import input_file

    path = input_file(path, "scene")
    try:
        str(path.resolve()).encode("utf-8")
    except UnicodeEncodeError:
        raise UsageError(f"scene: {path}: its name or its folder's is not UTF-8 text, and Mitsuba reads only "
                         "UTF-8 file names; rename it") from None
    return path


#: The widest reconstruction filter a film may have, in pixels (its radius): a Gaussian of standard
#: deviation 4, or Lanczos with 16 lobes. Each sample is splatted over (2 x radius + 1)^2 pixels; a
#: filter wider than this costs minutes per sample batch and blurs the image beyond use.
MAX_FILTER_RADIUS = 16.0


def check_sensor(scene, path: str | Path) -> None:
    """UsageError unless the loaded ``scene`` has a sensor (Mitsuba loads a scene without one) whose
    film's reconstruction filter has a radius in (0, :data:`MAX_FILTER_RADIUS`] pixels (Mitsuba
    builds a ``tent`` of radius -1 or a ``lanczos`` of 5000 lobes, and then renders for hours)."""
    if not scene.sensors():
        raise UsageError(f"scene {path}: has no <sensor> (a camera to render from)")
    rfilter = scene.sensors()[0].film().rfilter()
    radius = float(rfilter.radius())
    if not 0.0 < radius <= MAX_FILTER_RADIUS:  # also NaN
        name = str(rfilter).split("[", 1)[0]
        raise UsageError(f"scene {path}: the film's reconstruction filter ({name}) has radius {radius:g} pixels; "
                         f"expected more than 0 and at most {MAX_FILTER_RADIUS:g} (a Gaussian's radius is 4 x its "
                         "stddev, Lanczos' its lobes)")


@dataclass
class RenderTiming:
    """Seconds spent in each phase of a render.

    ``trace``: everything but compiling and running kernels (Python building the
    Dr.Jit graph, memsets, reductions); ``compile``: LLVM code
    generation and compilation of the kernels (near zero when the kernels come
    from the ``~/.drjit`` cache); ``execute``: running the kernels;
    ``total``: wall time from the render call until the image is evaluated.
    """

    trace: float
    compile: float
    execute: float
    total: float
    kernels: int
    cache_hits: int

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def check_sample_count(width: int, height: int, spp: int, channels: int = 4) -> None:
    """UsageError unless ``width x height`` has pixels, ``width x height x spp`` is at most
    :data:`pointillist.core.checks.UINT32_MAX`, the film's ``channels`` (and weights) fit one tensor, and
    the render's memory (the film three times over) is available
    (:func:`pointillist.core.checks.memory`): a 30000 x 30000 film crashed Mitsuba.

    That many samples make one wavefront of 32-bit lanes. Above it Mitsuba splits the render into
    passes, which fails (an spp that is not a multiple of the pass count, Python integrators) or
    silently breaks samplers that key their stream on the lane index (measured with Mitsuba 3.9).

    Examples
    --------
    >>> check_sample_count(256, 256, 65535)
    >>> check_sample_count(256, 256, 65536)
    Traceback (most recent call last):
    ...
    pointillist.core.errors.UsageError: spp: 256x256 pixels at 65536 spp is 4294967296 samples, more than one render
    takes (2^32 - 1); use fewer spp, or --tiles to split the film
    """
    if width < 1 or height < 1:
        raise UsageError(f"scene: the film has no pixels ({width}x{height}); expected width and height >= 1")
    if spp < 1:
        raise UsageError(f"spp: expected a positive integer, got {spp}")
    total = int(width) * int(height) * int(spp)
    if total > UINT32_MAX:
        raise UsageError(f"spp: {width}x{height} pixels at {spp} spp is {total} samples, more than one render "
                         "takes (2^32 - 1); use fewer spp, or --tiles to split the film")
    values = int(width) * int(height) * (int(channels) + 1)  # the film's channels and its weights
    if values > UINT32_MAX:
        raise UsageError(f"scene: a {width}x{height} film of {channels} channels is {values} values, more than one "
                         "tensor holds (2^32 - 1); use a smaller film, or --tiles")
    try:   # the film's block, the developed image and its copy (the samples are not kept: a render's
        # peak memory measured the same at 64 and 1024 spp)
        memory(values * 4 * 3, f"scene: a {width}x{height} film")
    except ValueError as error:
        raise UsageError(f"{error}; use a smaller film, or --tiles") from None


@contextmanager
def thread_count(threads: int | None):
    """Dr.Jit's kernels run on ``threads`` threads inside the block (``None``: as they are); the
    count before is restored after. On one thread the film's atomic additions of samples that land
    on the same pixel (any filter wider than a pixel, the particle tracer) come in one fixed order,
    so a render is the same to the last bit on every run, as Mitsuba's own renders on one thread
    are; on several the order, and so the last bit, varies from run to run. (Across processes, a
    scene with several emitters loaded with Mitsuba's mesh merging may order its emitters otherwise:
    :func:`parse_scene`'s ``merge_meshes``.) Used around rendering,
    and around Mitsuba's EXR writer, which never returns on a pool of one thread (Mitsuba 3.9.1): never
    around loading, as Mitsuba's scene loading waits on its own parallel tasks and must keep its threads."""
    import drjit as dr

    if threads is None or int(threads) == dr.thread_count():
        yield
        return
    # Resizing Dr.Jit's thread pool while kernels it launched are still running crashes (or
    # corrupts their results): wait for them before each change.
    dr.sync_thread()
    before = dr.thread_count()
    dr.set_thread_count(int(threads))
    try:
        yield
    finally:
        dr.sync_thread()
        dr.set_thread_count(before)


def timed_render(scene, *, spp: int | None = None, seed: int = 0, sensor: int = 0, integrator=None,
                 threads: int | None = None):
    """Render ``scene`` and return ``(image, RenderTiming)`` with the image evaluated.

    Kernel compile time comes from Dr.Jit's kernel history (codegen + backend
    time of every JIT kernel launched by this render). ``threads``: the render's thread count
    (:func:`thread_count`; default all cores). Raises UsageError before
    rendering for a film without pixels or more than 2^32 - 1 samples
    (:func:`check_sample_count`), or what the sampler's ``check_render(spp)`` refuses.
    """
    import drjit as dr
    import mitsuba as mi

    sensor_obj = scene.sensors()[sensor]
    width, height = (int(v) for v in sensor_obj.film().crop_size())
    count = int(spp) if spp else int(sensor_obj.sampler().sample_count())
    used = integrator if integrator is not None else scene.integrator()
    aovs = len(used.aov_names()) if used is not None and hasattr(used, "aov_names") else 0
    check_sample_count(width, height, count, int(sensor_obj.film().base_channels_count()) + aovs)
    check = getattr(sensor_obj.sampler(), "check_render", None)  # a sampler's own limits (zsobol's Morton index)
    if check is not None:
        try:
            check(count)
        except ValueError as error:
            raise UsageError(str(error)) from None
    signals.check()  # a safe point: nothing rendered yet

    dr.sync_thread()
    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clear
    try:
        start = time.perf_counter()
        kwargs: dict[str, Any] = {"seed": seed, "sensor": sensor}
        if spp:
            kwargs["spp"] = spp
        if integrator is not None:
            kwargs["integrator"] = integrator
        try:
            with thread_count(threads):
                image = mi.render(scene, **kwargs)
                dr.eval(image)
                dr.sync_thread()
        except RuntimeError as error:
            raise render_error(error) from None
        end = time.perf_counter()
        history = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)
    jit = [k for k in history if "codegen_time" in k]
    compile_s = sum(k.get("codegen_time", 0.0) + k.get("backend_time", 0.0) for k in jit) / 1000.0
    # mi.render(evaluate=True) launches its kernels itself, so compilation and
    # execution may happen before `traced`: split the whole span with the history.
    compile_s = min(compile_s, end - start)
    execute_s = min(sum(k.get("execution_time", 0.0) for k in jit) / 1000.0, end - start - compile_s)
    timing = RenderTiming(
        trace=max(end - start - compile_s - execute_s, 0.0),
        compile=compile_s,
        execute=execute_s,
        total=end - start,
        kernels=len(jit),
        cache_hits=sum(1 for k in jit if k.get("cache_hit")),
    )
    return image, timing


def scene_info(scene, sensor: int = 0) -> dict[str, Any]:
    """Plugin names and settings of a loaded scene, for EXR metadata and reports."""
    sensor_obj = scene.sensors()[sensor]
    film = sensor_obj.film()
    return {
        "integrator": _plugin_id(scene.integrator()),
        "sampler": _plugin_id(sensor_obj.sampler()),
        "spp": int(sensor_obj.sampler().sample_count()),
        "width": int(film.crop_size()[0]),
        "height": int(film.crop_size()[1]),
    }


def film_filter(scene, sensor: int = 0) -> str:
    """The film's reconstruction filter as Mitsuba prints it (``BoxFilter[]``,
    ``GaussianFilter[stddev=0.50, radius=2.00]`` ...)."""
    return str(scene.sensors()[sensor].film().rfilter()).splitlines()[0].strip()


def filter_note(description: str) -> str:
    """One line saying whether a film filter makes a pixel the plain average of its samples."""
    if description.startswith("BoxFilter"):
        return f"film filter: {description} (box: each pixel is the plain average of its samples)"
    return (f"film filter: {description}: a pixel is a weighted sum of nearby samples, not the plain "
            "average of its own (the course's super-sampling needs <rfilter type=\"box\"/> in the film)")


def _plugin_id(obj) -> str:
    """The plugin type name of a Mitsuba object (e.g. ``path``, ``whitted``)."""
    name = getattr(obj, "PLUGIN_NAME", None)
    if name:
        return name
    python = type(obj).__name__
    if python in _CLASS_TO_PLUGIN:
        return _CLASS_TO_PLUGIN[python]
    text = obj.class_name() if hasattr(obj, "class_name") else python
    return _CLASS_TO_PLUGIN.get(text, text)


_CLASS_TO_PLUGIN = {
    # Mitsuba's C++ integrators and samplers, by class_name()
    "AOVIntegrator": "aov", "DepthIntegrator": "depth", "DirectIntegrator": "direct", "MomentIntegrator": "moment",
    "PathIntegrator": "path", "ParticleTracerIntegrator": "ptracer", "StokesIntegrator": "stokes",
    "VolumetricPathIntegrator": "volpath", "VolpathMisIntegratorImpl": "volpathmis",
    "IndependentSampler": "independent", "StratifiedSampler": "stratified", "MultijitterSampler": "multijitter",
    "OrthogonalSampler": "orthogonal", "LowDiscrepancySampler": "ldsampler",
    # Mitsuba's Python integrators, by Python class (their class_name() is their base's)
    "PRBIntegrator": "prb", "BasicPRBIntegrator": "prb_basic", "PRBVolpathIntegrator": "prbvolpath",
    "DirectProjectiveIntegrator": "direct_projective", "PathProjectiveIntegrator": "prb_projective",
}
