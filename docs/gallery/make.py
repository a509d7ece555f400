"""Make the documentation's gallery: one picture per guide and per plugin, from the sample data.

Run by the documentation build (``docs/_ext/pointillist_sphinx.py``, before the pages are read) as
``python docs/gallery/make.py FOLDER``: it writes ``FOLDER/<name>.png`` for each entry of
:data:`PICTURES`, with the sample inputs of ``pointillist data`` and the scenes of ``scenes/``,
small enough to take about a minute on 2 cores. Nothing here is committed: the pictures are what
the code makes at build time.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

#: Picture name -> what it shows (the gallery page's captions).
PICTURES = {
    "whitted": "whitted on the sample scene: mirror, glass and Phong spheres over a Lambert checkerboard",
    "phong": "phong: a Cornell box with a Phong sphere, exponents 10, 100 and 1000",
    "samplers": "grid, jitter, poisson, sobol and zsobol: 64 samples in one pixel",
    "compare": ("error against spp on scenes/edges.xml for random, jitter and zsobol (mean of two seeds), and the "
                "power spectrum of each one's error at 4 spp (zsobol's is blue noise: little at low frequencies)"),
    "adaptive": "adaptive super-sampling: the render and its samples per pixel",
    "progressive": "a render with a 2 s budget: the estimated error against time",
    "tone": "tone maps of an HDR render: clip, reinhard, reinhard_extended, hable, aces, log",
    "dither": "dithering a photo: threshold, floyd_steinberg, ordered, blue_noise",
    "mip": "maximum-intensity projections of the sample CT phantom: axial, coronal, sagittal, oblique",
    "turntable": "a turntable of the phantom: six of the frames `mip --turntable 6` writes (and a GIF)",
    "tiles": "a render in 2x2 tiles, each its own task (the tasks a cluster runs)",
    "scenes": "a Mitsuba test scene with textured emitters: pointillist's render, Mitsuba's, and their difference",
    "differentiable": "the derivative of the sample scene's image with respect to the Phong ball's colour",
}


def _save(fig, path: Path) -> None:
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)


def _strip(images, titles, path: Path, *, cmap=None) -> None:
    fig, axes = plt.subplots(1, len(images), figsize=(2.6 * len(images), 2.9))
    for ax, image, title in zip(np.atleast_1d(axes), images, titles):
        ax.imshow(image, cmap=cmap, interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    _save(fig, path)


def main(out: Path) -> None:
    import drjit as dr

    import pointillist
    from pointillist.imaging.io import to_8bit

    out.mkdir(parents=True, exist_ok=True)
    mi = pointillist.setup()
    work = Path(tempfile.mkdtemp(prefix="gallery-"))
    data = work / "data"
    subprocess.run([sys.executable, "-m", "pointillist", "data", str(data)], check=True, capture_output=True)
    scene_path = str(data / "scene.xml")

    # whitted
    scene = mi.load_file(scene_path, res="192", spp="16")
    hdr = np.asarray(mi.render(scene, seed=1))[..., :3]
    _strip([to_8bit(hdr)], ["whitted, 16 spp"], out / "whitted.png")

    # phong
    images = []
    for n in (10, 100, 1000):
        s = mi.load_file(str(ROOT / "scenes" / "cornell_phong.xml"), res="96", spp="16", exponent=str(n))
        images.append(to_8bit(np.asarray(mi.render(s, seed=1))[..., :3]))
    _strip(images, [f"exponent {n}" for n in (10, 100, 1000)], out / "phong.png")

    # samplers: one pixel's samples
    fig, axes = plt.subplots(1, 5, figsize=(13, 2.9))
    for ax, name in zip(axes, ("grid", "jitter", "poisson", "sobol", "zsobol")):
        sampler = mi.load_dict({"type": name, "sample_count": 64})
        sampler.seed(7, 64)
        points = np.asarray(sampler.next_2d()).T
        ax.scatter(points[:, 0], points[:, 1], s=8)
        ax.set_xlim(0, 1), ax.set_ylim(0, 1), ax.set_aspect("equal"), ax.set_title(name, fontsize=9)
        ax.set_xticks([]), ax.set_yticks([])
    _save(fig, out / "samplers.png")

    # compare: error against spp (the scene with each sampler, as `pointillist compare` loads it)
    from pointillist.compare.methods import METHODS, load_configured_scene

    edges = ROOT / "scenes" / "edges.xml"        # thin edges and a checkerboard: where patterns differ
    reference = np.asarray(mi.render(mi.load_file(str(edges), res="64", spp="1"), spp=1024, seed=1000))[..., :3]
    from pointillist.imaging.spectrum import radial_power_spectrum

    fig, (ax, ax_spectrum) = plt.subplots(1, 2, figsize=(10, 3.4), gridspec_kw={"wspace": 0.35})
    for name in ("random", "jitter", "zsobol"):
        errors = []
        for spp in (1, 4, 16, 64):
            s = load_configured_scene(edges, METHODS[name], spp, {"res": "64"})
            images = [np.asarray(mi.render(s, seed=seed))[..., :3] for seed in (3, 4)]
            errors.append(float(np.mean([np.mean((image - reference) ** 2) for image in images])))
            if spp == 4:        # where the error of 4 spp lies: its radially averaged power spectrum
                spectrum = radial_power_spectrum((images[0] - reference).mean(axis=2))
                ax_spectrum.semilogy(spectrum.frequency, spectrum.power, label=name)
        ax.loglog((1, 4, 16, 64), errors, "o-", label=name)
    ax.set_xlabel("samples per pixel"), ax.set_ylabel("MSE against 1024 spp"), ax.legend()
    ax_spectrum.set_xlabel("frequency (cycles per pixel)"), ax_spectrum.set_ylabel("error power, 4 spp")
    ax_spectrum.legend()
    _save(fig, out / "compare.png")

    # adaptive
    from pointillist.plugins.integrators.adaptive import SAMPLE_COUNT_AOV

    s = mi.load_file(scene_path, res="96", spp="1")
    adaptive = mi.load_dict({"type": "adaptive", "threshold": 20.0, "max_depth": 3, "nested": {"type": "whitted"}})
    image = np.asarray(mi.render(s, integrator=adaptive, seed=0))
    counts = image[..., 3 + list(adaptive.aov_names()).index(SAMPLE_COUNT_AOV)]
    _strip([to_8bit(image[..., :3]), counts], ["adaptive render", "samples per pixel"], out / "adaptive.png",
           cmap="inferno")

    # progressive (the command's own plot)
    subprocess.run([sys.executable, "-m", "pointillist", "render", scene_path, "--time", "2", "--png", "-D", "res=64",
                    "-o", str(work / "progressive.exr")], check=True, capture_output=True)
    (out / "progressive.png").write_bytes((work / "progressive.progress.png").read_bytes())

    # tone maps of the HDR render
    from pointillist.imaging.tone import tonemap

    operators = ("clip", "reinhard", "reinhard_extended", "hable", "aces", "log")
    _strip([np.asarray(tonemap(hdr, op)) / 255.0 for op in operators], operators, out / "tone.png")

    # dithering the sample photo
    from pointillist.imaging.dither import dither
    from pointillist.imaging.io import read_image

    photo = read_image(data / "photo.png").image
    grey = (photo[..., :3] @ np.array([0.2126, 0.7152, 0.0722], np.float32))[96:224, 160:288]
    methods = ("threshold", "floyd_steinberg", "ordered", "blue_noise")
    _strip([grey] + [np.asarray(dither(grey, m)) for m in methods], ("photo",) + methods, out / "dither.png",
           cmap="gray")

    # MIP views of the phantom
    from PIL import Image

    from pointillist.mip import render_mip

    views = {}
    for view, kwargs in (("axial", {"view": "axial"}), ("coronal", {"view": "coronal"}),
                         ("sagittal", {"view": "sagittal"}), ("oblique", {"azimuth": 30.0, "elevation": 20.0})):
        path = work / f"mip_{view}.png"
        render_mip(data / "head.nii.gz", path, size=(128, 128), progress=False, **kwargs)
        views[view] = np.asarray(Image.open(path))
    _strip(list(views.values()), list(views), out / "mip.png")
    render_mip(data / "head.nii.gz", work / "turn.png", size=(96, 96), progress=False, turntable=6)
    frames = [np.asarray(Image.open(work / f"turn_{k:03d}.png")) for k in range(6)]
    _strip(frames, [f"frame {k}" for k in range(6)], out / "turntable.png")

    # tiles: the same render in 2x2 tiles, the grid drawn over it
    subprocess.run([sys.executable, "-m", "pointillist", "render", scene_path, "--tiles", "2x2", "--png",
                    "-D", "res=96", "-D", "spp=8", "-o", str(work / "tiles.exr")], check=True, capture_output=True)
    tiled = np.asarray(Image.open(work / "tiles.png"))
    fig, ax = plt.subplots(figsize=(3, 3))
    ax.imshow(tiled)
    for k in (1,):
        ax.axhline(k * tiled.shape[0] / 2 - 0.5, color="w", lw=1, ls="--")
        ax.axvline(k * tiled.shape[1] / 2 - 0.5, color="w", lw=1, ls="--")
    ax.axis("off"), ax.set_title("2x2 tiles", fontsize=9)
    _save(fig, out / "tiles.png")

    # a Mitsuba test scene: pointillist's render against Mitsuba's own
    from pointillist.scene import load_scene

    corpus = ROOT / "scenes" / "corpus" / "textured_emitters.xml"
    ours = np.asarray(mi.render(load_scene(corpus), seed=1))[..., :3]
    theirs = np.asarray(mi.render(mi.load_file(str(corpus)), seed=1))[..., :3]
    _strip([to_8bit(ours), to_8bit(theirs), np.abs(ours - theirs).sum(axis=2)],
           ["pointillist", "Mitsuba", f"|difference| (max {np.abs(ours - theirs).max():.1g})"], out / "scenes.png",
           cmap="magma")

    # a gradient image (forward mode)
    s = mi.load_file(scene_path, res="96")
    params = mi.traverse(s)
    key = "ball.bsdf.diffuse_reflectance.value"
    theta = mi.Float(0.0)
    dr.enable_grad(theta)
    params[key] = mi.Color3f(params[key]) + theta
    params.update()
    dr.forward(theta, dr.ADFlag.ClearEdges)
    gradient = np.asarray(s.integrator().render_forward(s, theta, seed=1, spp=16))[..., :3].sum(axis=2)
    _strip([gradient], ["d image / d Kd (the ball)"], out / "differentiable.png", cmap="magma")


def write_page(out: Path) -> None:
    """``out/gallery.md``: every picture with its caption (the gallery page includes it)."""
    lines = []
    for name, caption in PICTURES.items():
        lines += [f"```{{figure}} /gallery/_generated/{name}.png", f":alt: {caption}", "", caption, "```", ""]
    (out / "gallery.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
    write_page(Path(sys.argv[1]))
    os._exit(0)   # skip Dr.Jit's slow teardown
