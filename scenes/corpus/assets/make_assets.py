"""Write the corpus's asset files (meshes, textures, a volume); run from anywhere:

    python scenes/corpus/assets/make_assets.py

The files are committed; this script says how they were made and makes them again byte for byte.
Mitsuba writes the PLY and the volume; the OBJ, the serialized mesh (Mitsuba's own compressed
format: a 0x041C tag, version 4, a zlib stream with the mesh, a table of offsets) and the images
are written here.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def pyramid():
    """A square pyramid: 5 vertices, 6 triangles (base of two), outward-facing."""
    v = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1], [0, 1.5, 0]], dtype=np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 4, 1], [1, 4, 2], [2, 4, 3], [3, 4, 0]], dtype=np.uint32)
    return v, f


def write_obj(path: Path) -> None:
    v, f = pyramid()
    uv = v[:, [0, 2]] * 0.5 + 0.5
    lines = ["# a square pyramid, with texture coordinates"]
    lines += [f"v {x:g} {y:g} {z:g}" for x, y, z in v]
    lines += [f"vt {s:g} {t:g}" for s, t in uv]
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")


def write_serialized(path: Path) -> None:
    """Mitsuba's serialized format, version 4: one mesh, float32 positions, no normals."""
    v, f = pyramid()
    single_precision = 0x1000
    body = struct.pack("<I", single_precision) + b"pyramid\0"
    body += struct.pack("<QQ", len(v), len(f)) + v.astype("<f4").tobytes() + f.astype("<u4").tobytes()
    data = struct.pack("<HH", 0x041C, 4) + zlib.compress(body, 9)
    data += struct.pack("<Q", 0) + struct.pack("<I", 1)  # the offset of mesh 0, then the mesh count
    path.write_bytes(data)


def write_ply(path: Path) -> None:
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    v, f = pyramid()
    mesh = mi.Mesh("pyramid", len(v), len(f))
    params = mi.traverse(mesh)
    params["vertex_positions"] = v.ravel()
    params["faces"] = f.ravel()
    params.update()
    mesh.write_ply(str(path))


def write_png(path: Path) -> None:
    """An 8x8 sRGB checkerboard of four colours (Pillow)."""
    from PIL import Image

    y, x = np.mgrid[0:8, 0:8]
    colours = np.array([[230, 60, 40], [40, 160, 220], [250, 220, 60], [60, 200, 90]], dtype=np.uint8)
    Image.fromarray(colours[(y // 2 + x // 2) % 2 * 2 + (y // 4) % 2]).save(path)


def write_exr(path: Path) -> None:
    """A 16x8 equirectangular sky: blue above, brown below, one bright sun texel."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    sky = np.zeros((8, 16, 3), dtype=np.float32)
    sky[:4] = [0.3, 0.5, 0.9]
    sky[4:] = [0.25, 0.18, 0.1]
    sky[2, 5] = [40.0, 36.0, 30.0]
    mi.Bitmap(sky).write(str(path))


def write_volume(path: Path) -> None:
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    z, y, x = np.mgrid[0:6, 0:6, 0:6] / 5.0
    density = (4.0 * np.exp(-((x - 0.5) ** 2 + (y - 0.5) ** 2 + (z - 0.5) ** 2) * 6)).astype(np.float32)
    mi.VolumeGrid(density[..., None]).write(str(path))


if __name__ == "__main__":
    write_obj(HERE / "meshes" / "pyramid.obj")
    write_serialized(HERE / "meshes" / "pyramid.serialized")
    write_ply(HERE / "meshes" / "pyramid.ply")
    write_png(HERE / "textures" / "checker.png")
    write_exr(HERE / "textures" / "sky.exr")
    write_volume(HERE / "fog.vol")
