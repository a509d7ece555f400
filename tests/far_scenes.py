"""The far-from-the-origin test scene of the far-origin round, written as Mitsuba XML with its positions offset.

Three spheres (Phong, mirror conductor, glass dielectric) on a diffuse floor, one point light,
80x80 at 4 spp, box filter (the scene of tests/test_stiff.py, main variant): every position the
XML states (the camera's ``lookat``, the floor's ``to_world``, the sphere centres, the light) is
moved by ``offset`` in the text itself, so Mitsuba's parser reads the large coordinates as a
user's file would hold them. The benchmark (benchmarks/far_origin.py) and tests/test_far_origin.py
share it; both count changed pixels with tests/test_stiff.py's ``fraction_off``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

RES, SPP, SEED = 80, 4, 1

#: Directions of the offsets: along one axis, or along (1, 1, 1) (every coordinate moved by it).
AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0), "xyz": (1.0, 1.0, 1.0)}

#: The integrators compared (``path`` with max_depth 6 follows the delta chains whitted follows).
INTEGRATORS = {
    "whitted": '<integrator type="whitted"/>',
    "path": '<integrator type="path"><integer name="max_depth" value="6"/></integrator>',
    "direct": '<integrator type="direct"/>',
}


def _xyz(p) -> str:
    """``x="..." y="..." z="..."`` with each float written so that it parses back exactly."""
    return " ".join(f'{axis}="{float(v)!r}"' for axis, v in zip("xyz", p))


def _csv(p) -> str:
    return ", ".join(repr(float(v)) for v in p)


#: The spheres: name -> (centre, radius, BSDF as XML).
SPHERES = {
    "phong": ((-1.2, 0.5, 0.2), 0.5, '<bsdf type="phong"><float name="exponent" value="30"/>'
              '<rgb name="diffuse_reflectance" value="0.6, 0.2, 0.15"/>'
              '<float name="specular_reflectance" value="0.3"/></bsdf>'),
    "mirror": ((0.0, 0.6, -0.8), 0.6, '<bsdf type="conductor"><string name="material" value="none"/></bsdf>'),
    "glass": ((1.1, 0.5, 0.6), 0.5, '<bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>'),
}
#: The floor: a rectangle 8 x 8 at y = 0.
FLOOR_HALF_SIZE, FLOOR_BSDF = 4.0, '<bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.6, 0.55"/></bsdf>'
CAMERA_ORIGIN, CAMERA_TARGET = (0.0, 1.6, 5.5), (0.0, 0.4, 0.0)
LIGHT_POSITION, LIGHT_INTENSITY = (2.0, 4.0, 3.0), 40.0


def far_scene_xml(offset: float = 0.0, axis: str = "xyz", integrator: str = "whitted", *,
                  res: int = RES, spp: int = SPP, shapes: str | None = None) -> str:
    """The scene's XML with every stated position moved by ``offset`` along ``AXES[axis]``.

    ``shapes`` replaces the floor and the spheres (XML of ``<shape>`` elements, e.g. as meshes).
    """
    shift = np.asarray(AXES[axis]) * float(offset)

    def at(p):
        return np.asarray(p, dtype=np.float64) + shift

    if shapes is None:
        shapes = f'''    <shape type="rectangle">
        <transform name="to_world">
            <scale value="{FLOOR_HALF_SIZE!r}"/>
            <rotate x="1" angle="-90"/>
            <translate {_xyz(shift)}/>
        </transform>
        {FLOOR_BSDF}
    </shape>
''' + "".join(f'''    <shape type="sphere">
        <point name="center" {_xyz(at(centre))}/>
        <float name="radius" value="{radius!r}"/>
        {bsdf}
    </shape>
''' for centre, radius, bsdf in SPHERES.values())
    return f'''<scene version="3.0.0">
    {INTEGRATORS[integrator]}
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <float name="near_clip" value="0.01"/>
        <float name="far_clip" value="1000"/>
        <transform name="to_world">
            <lookat origin="{_csv(at(CAMERA_ORIGIN))}" target="{_csv(at(CAMERA_TARGET))}" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="{res}"/>
            <integer name="height" value="{res}"/>
            <rfilter type="box"/>
        </film>
    </sensor>
{shapes}    <emitter type="point">
        <point name="position" {_xyz(at(LIGHT_POSITION))}/>
        <rgb name="intensity" value="{LIGHT_INTENSITY!r}"/>
    </emitter>
</scene>
'''


def write_far_scene(folder: str | Path, offset: float = 0.0, axis: str = "xyz", integrator: str = "whitted",
                    **kw) -> Path:
    """Write :func:`far_scene_xml` to ``folder`` (a name telling its settings); returns the path."""
    path = Path(folder) / f"far_{integrator}_{axis}_{offset:g}.xml"
    path.write_text(far_scene_xml(offset, axis, integrator, **kw))
    return path

