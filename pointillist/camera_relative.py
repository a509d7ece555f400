"""Camera-relative rendering: a parsed scene's positions re-expressed relative to the rendered sensor.

Mitsuba 3.9.1 builds every shape, light and camera in float32 world coordinates: 1e4 from the
origin they are 9.8e-4 apart, 1e6 from it 0.0625, so edges, contacts and ray offsets move by that
much wherever a scene sits far from the origin (CAD, GIS, city and planetary models). pbrt-v4
renders in a camera-centred space for this reason. :func:`make_camera_relative` does the same
between parsing a scene and instantiating it (:mod:`pointillist.scene`): every position the scene
states (transforms, ``lookat``, sphere centres, cylinder end points, light and sensor positions,
volume boxes) is composed in float64 with a translation by minus the rendered sensor's position,
then handed to Mitsuba, which rounds the now small numbers to float32. The whole scene moves
rigidly, so the image is the same up to rounding, which is now that of coordinates near the
camera.

What moves (the nodes of the parsed scene reachable from its root, outside shape groups):

- ``to_world`` of shapes, instances, sensors, spot and projector lights, volumes (``gridvolume``,
  wherever they are used: media and volume textures look them up at world positions) and the
  ``mip`` integrator, composed on the left with the translation (and added where the plugin reads
  one but the scene gives none, such as a mesh file whose vertices are stored in world
  coordinates); another integrator's ``to_world`` when the scene states one;
- points: sphere ``center``, cylinder ``p0``/``p1``, point light ``position``, ``radiancemeter``
  ``origin``, ``distant`` sensor ``target``. Where a sphere or cylinder states both a point and a
  ``to_world``, the point is folded into the transform in float64.

What does not: directions (``directional`` and ``distant`` directions, ``envmap``, ``constant``,
``sunsky`` rotations: infinitely far, they have no position), the children of a ``shapegroup``
(they are in the group's own space; the ``instance`` moves), area lights and irradiance meters
(they are attached to a shape, which moves), texture ``to_uv``. Vertices stored inside a mesh file
(PLY, OBJ, serialized) are float32 already: the translation moves them exactly (the offset is
rounded to float32, and a float32 vertex near it minus it is exact), but the rounding the file
holds stays.

The origin is the position of the sensor that is rendered (index ``sensor`` in Mitsuba's order of
the scene's sensors; ``pointillist render`` renders the first). The other sensors move with the
scene: each renders the same image as before, with coordinates relative to the first. A sensor
without a position (``distant``, ``irradiancemeter``) leaves the scene where it is.

When (:func:`recentre_rule`): only where float32 positions would lose precision that shows. A
scene moves when the spacing of float32 numbers at the rendered sensor's distance from the origin
is more than :data:`PRECISION` times the distance from the sensor to the median of the positions
the scene states (shapes, lights, volumes): an angle of 1e-5 radian seen from the camera, about
1/70 of a pixel of a 1000-pixel film with a 40 degree field of view. Every other scene (near the
origin, or a camera far away looking at content near the origin, where moving would make the
content's coordinates large instead) is handed to Mitsuba exactly as parsed, and renders bit for
bit as ``mi.load_file`` loads it. A scene that states no position but the sensor's (only mesh files
without ``to_world``, whose vertices are unknown before loading) and whose sensor is farther than
:data:`FAR` from the origin is built once as written to measure where its shapes are (their
bounding boxes' centres stand for the stated positions); the rule alone moves it beyond
:data:`FAR` when even that tells nothing.

Mitsuba's ``aov`` integrator reports ``position`` in the rendered (camera-relative) space: add
``origin_offset`` (:func:`offset_text`, the EXR header) to get world positions where a ray hit.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

from pointillist.core import checks
from pointillist.parsed_state import read_properties, resolving_from

__all__ = ["PRECISION", "FAR", "Recentring", "recentre_rule", "float32_spacing", "sensor_positions", "stated_positions",
           "make_camera_relative", "offset_text"]

#: A scene moves when the float32 spacing at the rendered sensor's position is more than PRECISION
#: times the distance from the sensor to the median of the scene's stated positions.
PRECISION = 1e-5

#: Without stated positions besides the sensor's, the scene moves when the sensor is farther than
#: this from the origin (float32 coordinates there are 6.1e-5 apart).
FAR = 1e3


#: A position: (x, y, z) in float64. Plain Python floats: a plain render imports no numpy.
Point = tuple[float, float, float]
_ORIGIN: Point = (0.0, 0.0, 0.0)

#: Plugins whose ``to_world`` is a rotation of something infinitely far (translation unused).
_INFINITE = frozenset({"directional", "envmap", "constant", "sunsky", "timed_sunsky", "distant"})
#: Plugins attached to a shape (the shape moves; they refuse a ``to_world`` of their own).
_ATTACHED = frozenset({"area", "directionalarea", "irradiancemeter"})
#: Containers: ``merge`` (made by the parser) holds the scene's objects; a ``shapegroup``'s
#: children are in its own space.
_CONTAINERS = frozenset({"merge", "shapegroup"})
#: Shapes Mitsuba 3.9.1 builds as meshes (the ``merge`` container lists them after other objects).
_MESHES = frozenset({"obj", "ply", "serialized", "cube", "rectangle", "ellipsoidsmesh"})
#: Shapes whose geometry comes from a file (or a tensor): their position is unknown before loading.
_FILE_SHAPES = frozenset({"obj", "ply", "serialized", "bsplinecurve", "linearcurve", "ellipsoids",
                          "ellipsoidsmesh", "sdfgrid"})
#: Shapes given as a tensor (``data``/``centers``) refuse a ``to_world``.
_TENSOR_PROPERTIES = ("data", "centers")


@dataclass(frozen=True)
class Recentring:
    """What :func:`make_camera_relative` did to a parsed scene.

    ``offset``: the world position subtracted from every position (float64 values that are
    float32-representable; zeros when the scene was left as written); ``sensor``: the rendered
    sensor's position as stated (``None`` when it has none); ``reason``: one line saying why the
    scene moved or not.
    """

    offset: tuple[float, float, float]
    sensor: tuple[float, float, float] | None
    reason: str

    @property
    def moved(self) -> bool:
        return any(self.offset)


# ------------------------------------------------------------------------------ the scene graph
@dataclass
class _Node:
    """One node of a parsed scene, read once: object kind (``Shape``, ``Sensor`` ...), plugin
    name, properties (``props``, changed in place), their values and kinds by name (``Vector``,
    ``Transform``, ``ResolvedReference`` or ''), referenced nodes."""

    index: int
    kind: str
    name: str
    props: Any
    values: dict[str, Any]
    types: dict[str, str]
    children: list[int]

    def has(self, key: str, kind: str) -> bool:
        return self.types.get(key) == kind

    def point(self, key: str, default: Point | None = None) -> Point | None:
        if not self.has(key, "Vector"):
            return default
        return _point(self.values[key])

    def to_world(self):
        """The ``to_world`` the scene states (``mitsuba.ScalarAffineTransform4d``), or None."""
        return self.values["to_world"] if self.has("to_world", "Transform") else None


#: The object kinds whose nodes can hold or lead to a position (others are not read: films,
#: samplers, BSDFs, textures, media; volumes are found wherever they are).
_READ = frozenset({"Scene", "Shape", "Sensor", "Emitter", "Volume", "Integrator"})


def _graph(state) -> list[_Node]:
    """Every node of ``state`` (a ``mitsuba.parser.ParserState``) as a :class:`_Node`; the
    properties of kinds outside :data:`_READ` are left unread (empty).

    Property kinds come from the values' Python types (one ``items()`` call per node: asking
    ``props.type`` key by key costs several times more, through Python's enum hashing).
    """
    import drjit as dr
    import mitsuba as mi

    kinds = {mi.Properties.ResolvedReference: "ResolvedReference", mi.ScalarAffineTransform4d: "Transform",
             dr.scalar.Array3f64: "Vector"}
    nodes = []
    for index, node in enumerate(state.nodes):
        kind = node.type.name
        if kind not in _READ:
            nodes.append(_Node(index, kind, "", None, {}, {}, []))
            continue
        props = node.props
        values = read_properties(props)
        types = {key: kinds.get(type(value), "") for key, value in values.items()}
        children = [values[key].index() for key, kind in types.items() if kind == "ResolvedReference"]
        nodes.append(_Node(index, kind, props.plugin_name(), props, values, types, children))
    return nodes


def _point(values) -> Point:
    """Three values (a Mitsuba vector, a numpy array, a sequence) as a :data:`Point`."""
    x, y, z = (float(v) for v in values)
    return (x, y, z)


def _minus(a: Point, b: Point) -> Point:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _float32(point: Point) -> Point:
    """Each coordinate rounded to the nearest float32."""
    return _point(map(checks.round_to_float32, point))


def _shifted(offset: Point, transform=None, then: Point | None = None):
    """translate(-offset) @ transform @ translate(then), composed in float64 by Mitsuba's
    double-precision transforms (``transform`` and ``then`` optional)."""
    import mitsuba as mi

    result = mi.ScalarAffineTransform4d().translate(mi.ScalarVector3d(*_minus(_ORIGIN, offset)))
    if transform is not None:
        result = result @ transform
    if then is not None:
        result = result @ mi.ScalarAffineTransform4d().translate(mi.ScalarVector3d(*then))
    return result


def _point3(p: Point):
    import mitsuba as mi

    return mi.ScalarPoint3d(*p)


def _apply(transform, point: Point) -> Point:
    """``transform @ point`` in float64 (``transform`` None: the point itself)."""
    if transform is None:
        return point
    return _point(transform @ _point3(point))


def _walk(nodes: list[_Node]) -> tuple[list[int], list[int], list[int]]:
    """Nodes reachable from the root: (in world space, in a shape group's space, every volume)."""
    world: dict[int, None] = {}
    local: dict[int, None] = {}
    stack = [(0, True)]
    while stack:
        index, in_world = stack.pop()
        seen = world if in_world else local
        if index in seen:
            continue
        seen[index] = None
        node = nodes[index]
        group = node.kind == "Shape" and node.name == "shapegroup"
        stack.extend((child, in_world and not group) for child in reversed(node.children))
    volumes = [node.index for node in nodes if node.kind == "Volume"]
    return list(world), list(local), volumes


# ------------------------------------------------------------------------------ positions
def _sensor_position(nodes: list[_Node], node: _Node) -> Point | None:
    """Where a sensor node sits (float64), or None for one at infinity or attached to a shape."""
    if node.name in ("distant", "irradiancemeter"):
        return None
    if node.name == "batch":
        inner = [nodes[c] for c in node.children if nodes[c].kind == "Sensor"]
        return _sensor_position(nodes, inner[0]) if inner else None
    if node.name == "radiancemeter" and node.has("origin", "Vector"):
        return node.point("origin")
    return _apply(node.to_world(), _ORIGIN)


def _sensor_positions(nodes: list[_Node]) -> list[Point | None]:
    order, meshes = [], []
    pending = list(nodes[0].children)
    while pending:
        node = nodes[pending.pop(0)]
        if node.kind == "Shape" and node.name == "merge":
            pending = node.children + pending
        elif node.kind == "Sensor":
            order.append(_sensor_position(nodes, node))
        elif node.kind == "Shape" and any(nodes[c].kind == "Sensor" for c in node.children):
            (meshes if node.name in _MESHES else order).append(None)
    return order + meshes


def sensor_positions(state) -> list[Point | None]:
    """The sensors' positions in the order Mitsuba lists them (``scene.sensors()``).

    ``state`` is a parsed scene's ``mitsuba.parser.ParserState``. The scene's top-level objects
    come in the order the file states them (the parser's ``merge`` container lists meshes after
    the other objects); a sensor attached to a shape (``irradiancemeter``) has no position (None);
    each position is an (x, y, z) tuple of floats.
    """
    return _sensor_positions(_graph(state))


def _node_position(node: _Node) -> Point | None:
    """A representative world position of a shape, light, volume or integrator node (None: unknown)."""
    matrix = node.to_world()
    if node.kind == "Shape":
        if node.name in _CONTAINERS or node.name in _FILE_SHAPES:
            return None
        if node.name == "sphere" and node.has("center", "Vector"):
            return _apply(matrix, node.point("center"))
        if node.name == "cylinder":
            p0, p1 = node.point("p0", (0.0, 0.0, 0.0)), node.point("p1", (0.0, 0.0, 1.0))
            return _apply(matrix, _point(0.5 * (a + b) for a, b in zip(p0, p1)))
        return _apply(matrix, _ORIGIN)
    if node.kind == "Emitter":
        if node.name in _INFINITE or node.name in _ATTACHED:
            return None
        if node.name == "point" and node.has("position", "Vector"):
            return node.point("position")
        return _apply(matrix, _ORIGIN)
    if node.kind == "Volume":
        return _apply(matrix, (0.5, 0.5, 0.5))          # the centre of the unit box it fills
    if matrix is not None and node.kind not in ("Sensor", "Scene"):   # e.g. the mip integrator's box
        return _apply(matrix, _ORIGIN)
    return None


def _stated_positions(nodes: list[_Node], world: list[int], volumes: list[int]) -> list[Point]:
    points = [_node_position(nodes[i]) for i in dict.fromkeys(world + volumes)]
    return [p for p in points if p is not None]


def stated_positions(state) -> list[Point]:
    """Positions the scene states for its content (shapes, lights, volumes), (x, y, z) tuples.

    Sensors, things at infinity, shape groups' children (their instances count) and shapes
    whose geometry comes from a file (unknown before loading) are left out.
    """
    nodes = _graph(state)
    world, _local, volumes = _walk(nodes)
    return _stated_positions(nodes, world, volumes)


def float32_spacing(x: float) -> float:
    """The gap between float32 numbers at magnitude ``x`` (``numpy.spacing`` of ``float32(|x|)``).

    Examples
    --------
    >>> float32_spacing(1.0), float32_spacing(-1e4), float32_spacing(0.0)
    (1.1920928955078125e-07, 0.0009765625, 1.401298464324817e-45)
    >>> float32_spacing(3.5e38), float32_spacing(float("nan"))
    (nan, nan)
    """
    try:
        (bits,) = struct.unpack("<I", struct.pack("<f", abs(float(x))))   # float32(|x|), rounded to nearest
    except OverflowError:                                           # beyond float32's (or float64's) range
        return math.nan
    if bits >= 0x7F800000:                                          # inf or NaN
        return math.nan
    here, after = struct.unpack("<2f", struct.pack("<2I", bits, bits + 1))
    return after - here


def _built_positions(parsed) -> list[Point]:
    """The centres of the shapes' bounding boxes once Mitsuba has built the scene as written: for
    a scene whose shapes all come from files (no position stated in the XML) and whose sensor is
    far from the origin, where the rule needs to know where the content is (a Cornell box in
    millimetres seen from 1.3e3 away stays put). Empty when the scene does not build (its error is
    reported when it is built for good)."""
    import mitsuba as mi

    try:
        with resolving_from(parsed.path.resolve().parent, parsed.resolver):
            scene = mi.parser.instantiate(parsed.config, parsed.state)
        boxes = [shape.bbox() for shape in scene.shapes()] if isinstance(scene, mi.Scene) else []
    except RuntimeError:
        boxes = []
    return [_point(0.5 * (float(box.min[i]) + float(box.max[i])) for i in range(3)) for box in boxes if box.valid()]


def recentre_rule(sensor, positions) -> tuple[bool, str]:
    """Whether a scene moves to its sensor, and why (see the module's documentation).

    ``sensor``: (x, y, z) or None; ``positions``: any number of (x, y, z) (sequences or an
    (N, 3) array; non-finite ones are ignored).

    Examples
    --------
    >>> recentre_rule((0.0, -12.0, 5.0), [(0, 0, 1.25), (4, -4, 8.0)])[0]
    False
    >>> moves, reason = recentre_rule((1e4, 1e4, 1e4), [(1e4, 1e4, 1e4 - 5)])
    >>> moves, reason[:64]
    (True, 'float32 spacing 0.00195 at the sensor, 17321 from the origin: > ')
    >>> reason[64:]
    '1e-05 x 5 (distance to the median position)'
    >>> recentre_rule((0.0, 0.0, 3e3), [])[0]
    True
    """
    if sensor is None:
        return False, "the rendered sensor has no position (distant or attached to a shape)"
    sensor = _point(sensor)
    if not all(abs(v) <= checks.FLOAT32_MAX for v in sensor):
        return False, "the sensor's position is not a finite float32 number"
    positions = [p for p in map(_point, positions) if all(map(math.isfinite, p))]
    far = math.hypot(*sensor)
    if far == 0.0:
        return False, "the sensor is at the origin"
    if len(positions) == 0:
        return far > FAR, f"the sensor is {far:.5g} from the origin (no other stated position; moves beyond {FAR:g})"
    # the median by hand: the statistics module takes tens of ms to import, more than the step itself
    distances = sorted(math.hypot(*_minus(p, sensor)) for p in positions)
    half = len(distances) // 2
    near = distances[half] if len(distances) % 2 else 0.5 * (distances[half - 1] + distances[half])
    spacing = float32_spacing(far)
    moves = spacing > PRECISION * near
    return moves, (f"float32 spacing {spacing:.3g} at the sensor, {far:.5g} from the origin: "
                   f"{'>' if moves else '<='} {PRECISION:g} x {near:.5g} (distance to the median position)")


# ------------------------------------------------------------------------------ moving
def _move_to_world(node: _Node, offset: Point, *, add: bool) -> None:
    """``to_world`` <- translate(-offset) @ to_world; with ``add``, also where the scene states none."""
    transform = node.to_world()
    if transform is None and not add:
        return
    node.props["to_world"] = _shifted(offset, transform)


def _move_point(node: _Node, key: str, offset: Point) -> None:
    node.props[key] = _point3(_minus(node.point(key), offset))


def _move_node(node: _Node, offset: Point) -> None:
    """Move one world-space node by ``-offset`` (see the module's documentation for the cases)."""
    props, name, kind = node.props, node.name, node.kind
    if kind == "Shape":
        if name in _CONTAINERS:
            return
        if name == "sphere" and node.has("center", "Vector"):
            transform = node.to_world()
            if transform is None:
                return _move_point(node, "center", offset)
            center = node.point("center")
            del props["center"]
            props["to_world"] = _shifted(offset, transform, center)
            return
        if name == "cylinder" and (node.has("p0", "Vector") or node.has("p1", "Vector")):
            p0, p1 = node.point("p0", (0.0, 0.0, 0.0)), node.point("p1", (0.0, 0.0, 1.0))
            transform = node.to_world()
            if transform is None:
                props["p0"], props["p1"] = _point3(_minus(p0, offset)), _point3(_minus(p1, offset))
                return
            props["to_world"] = _shifted(offset, transform, p0)
            props["p0"], props["p1"] = _point3(_ORIGIN), _point3(_minus(p1, p0))
            return
        return _move_to_world(node, offset, add=True)
    if kind == "Emitter":
        if name in _INFINITE or name in _ATTACHED:
            return
        if name == "point" and node.has("position", "Vector"):
            return _move_point(node, "position", offset)
        return _move_to_world(node, offset, add=True)
    if kind == "Sensor":
        if name == "irradiancemeter":
            return
        if name == "distant":
            if node.has("target", "Vector"):
                _move_point(node, "target", offset)
            return
        if name == "radiancemeter" and (node.has("origin", "Vector") or "direction" in node.types):
            if node.has("origin", "Vector"):
                _move_point(node, "origin", offset)
            else:
                props["origin"] = _point3(_minus(_ORIGIN, offset))
            return
        return _move_to_world(node, offset, add=name != "batch")
    if kind == "Volume" or (kind == "Integrator" and name == "mip"):
        return _move_to_world(node, offset, add=True)
    if kind == "Integrator":
        _move_to_world(node, offset, add=False)


def make_camera_relative(parsed, *, sensor: int = 0):
    """Re-express a parsed scene relative to its rendered sensor's position, in place.

    Parameters
    ----------
    parsed : pointillist.scene.ParsedScene
        A scene parsed by :func:`pointillist.scene.parse_scene` and not yet instantiated. Its
        ``state`` is changed and its ``recentring`` set to a :class:`Recentring`.
    sensor : int, optional
        The index of the sensor that will be rendered (Mitsuba's order); its position becomes
        the origin. Default 0 (the one ``pointillist render`` renders).

    Returns
    -------
    pointillist.scene.ParsedScene
        ``parsed`` itself.

    Notes
    -----
    The scene moves by the sensor's position rounded to float32 (so the camera ends within half a
    float32 spacing of the origin, and float32 data the translation meets, such as mesh vertices,
    moves exactly) when :func:`recentre_rule` says so; otherwise ``state`` is untouched and the
    offset is zero. Calling it again on the same parsed scene does nothing. A positional node
    reachable both from the scene and from inside a shape group cannot be both moved and kept:
    the scene is then left as written (``reason`` says so).

    Examples
    --------
    >>> import pointillist
    >>> from pointillist.scene import parse_scene
    >>> mi = pointillist.setup()
    >>> parsed = make_camera_relative(parse_scene("scenes/default.xml", {"res": "8"}))
    >>> parsed.recentring.offset, parsed.recentring.moved
    ((0.0, 0.0, 0.0), False)
    >>> far = '''<scene version="3.0.0"><sensor type="perspective"><transform name="to_world">
    ...     <lookat origin="1e6, 2, 5" target="1e6, 0, 0" up="0, 1, 0"/></transform></sensor>
    ...     <shape type="sphere"><point name="center" x="1000000.25" y="0" z="0"/></shape></scene>'''
    >>> parsed = make_camera_relative(parse_scene("scenes/default.xml", text=far))
    >>> parsed.recentring.offset
    (1000000.0, 2.0, 5.0)
    >>> [float(v) for v in parsed.state.nodes[2].props["center"]]    # 1000000.25 is no float32
    [0.25, -2.0, -5.0]
    """
    if getattr(parsed, "recentring", None) is not None:
        return parsed
    sensor = checks.integer(sensor, "sensor", low=0)
    nodes = _graph(parsed.state)
    world, local, volumes = _walk(nodes)
    positions = _sensor_positions(nodes)
    where = positions[sensor] if sensor < len(positions) else None
    content = _stated_positions(nodes, world, volumes)
    if len(content) == 0 and where is not None and recentre_rule(where, content)[0]:
        content = _built_positions(parsed)   # only mesh files: measure where they are
    moves, reason = recentre_rule(where, content)
    if sensor >= len(positions):
        reason = f"the scene has no sensor {sensor} ({len(positions)} sensor(s))"
    blocked = _blocked(nodes, world, local) if moves else ""
    if blocked:
        moves, reason = False, blocked
    if not moves:
        parsed.recentring = Recentring(_ORIGIN, where, reason)
        return parsed
    offset = _float32(where)
    if not any(offset):
        parsed.recentring = Recentring(_ORIGIN, where, "the sensor is within float32 rounding of the origin")
        return parsed
    for index in dict.fromkeys(world + volumes):
        _move_node(nodes[index], offset)
    parsed.recentring = Recentring(offset, where, reason)
    return parsed


def _blocked(nodes: list[_Node], world: list[int], local: list[int]) -> str:
    """Why the scene cannot move rigidly ('' when it can)."""
    both = [nodes[i] for i in set(world) & set(local)]
    if any((node.kind == "Shape" and node.name not in _CONTAINERS)
           or (node.kind == "Emitter" and node.name not in _INFINITE | _ATTACHED) for node in both):
        return "a shape or light is used both in the scene and inside a shapegroup (it cannot both move and stay)"
    for index in world:
        node = nodes[index]
        if node.name in ("ellipsoids", "ellipsoidsmesh") and any(key in node.types for key in _TENSOR_PROPERTIES):
            return f"a {node.name} shape given as a tensor cannot move (it refuses a to_world)"
    return ""


def offset_text(recentring: Recentring | None) -> str:
    """The offset as the EXR header's ``origin_offset`` records it: ``"x,y,z"``, exact float64 text.

    Examples
    --------
    >>> offset_text(Recentring((10000.0, 10001.599609375, 10005.5), None, ""))
    '10000.0,10001.599609375,10005.5'
    >>> offset_text(None)
    '0.0,0.0,0.0'
    """
    values: Any = recentring.offset if recentring is not None else (0.0, 0.0, 0.0)
    return ",".join(repr(float(v)) for v in values)
