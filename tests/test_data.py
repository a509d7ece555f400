"""``pointillist data DIR``: the sample inputs the guides use, each readable and equal to its source."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    from conftest import run_cli

    folder = tmp_path_factory.mktemp("sample") / "data"
    done = run_cli("data", folder)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == (f"wrote 9 sample inputs in {folder}: scene.xml, render.exr, photo.png, head.nii.gz, "
                                   "head.nhdr, head.raw.gz, head.npy, ct_series, fmri.nii.gz")
    return folder


@pytest.mark.parametrize("name", ["head.nii.gz", "head.nhdr", "head.npy", "ct_series"])
def test_every_volume_format_holds_the_same_phantom_in_patient_space(sample, name):
    """NIfTI (RAS on disk), NRRD with a detached gzip data file, numpy and a DICOM CT series (HU
    through RescaleIntercept): each reads back as the 64^3 phantom, LPS axes, 1 mm."""
    from pointillist.imaging.volumes import load_volume, shepp_logan_phantom

    volume = load_volume(sample / name)
    np.testing.assert_array_equal(volume.data, shepp_logan_phantom(64))
    assert volume.spacing == (1.0, 1.0, 1.0)
    np.testing.assert_allclose(volume.directions, np.eye(3), atol=1e-12)
    if name == "ct_series":
        assert len(list((sample / name).glob("*.dcm"))) == 64


def test_the_photo_and_the_4d_volume_are_the_packages_own(sample):
    import nibabel
    from nibabel.testing import data_path
    from skimage import data

    from pointillist.imaging.io import read_image
    from pointillist.imaging.volumes import load_volume

    photo = read_image(sample / "photo.png").image
    np.testing.assert_array_equal(photo, data.astronaut())
    frame = load_volume(sample / "fmri.nii.gz", frame=1)
    expected = np.asarray(nibabel.load(f"{data_path}/example4d.nii.gz").dataobj)[..., 1].T
    np.testing.assert_array_equal(frame.data, expected)


def test_the_scene_renders_and_the_guides_commands_run_on_the_data(sample, cli, tmp_path):
    for args in (["render", sample / "scene.xml", "-D", "res=16", "--spp", "4", "-o", tmp_path / "r.exr"],
                 ["mip", sample / "head.nhdr", "--turntable", "4", "--size", "32", "-o", tmp_path / "turn.png"],
                 ["mip", sample / "ct_series", "--azimuth", "30", "--elevation", "20", "--size", "32",
                  "-o", tmp_path / "ct.png"],
                 ["mip", sample / "fmri.nii.gz", "--frame", "1", "--view", "sagittal", "-o", tmp_path / "s.png"],
                 ["post", sample / "photo.png", "--steps", "grey;sobel", "-o", tmp_path / "edges.png"]):
        done = cli(*args)
        assert done.returncode == 0, (args, done.stderr)
    assert (tmp_path / "turn.gif").is_file() and (tmp_path / "turn_003.png").is_file()


def test_no_file_is_written_over_and_a_file_is_no_folder(sample, cli, tmp_path):
    again = cli("data", sample)
    assert again.returncode == 2
    assert again.stderr.strip() == (f"pointillist data: error: folder: {sample} already holds scene.xml (sample "
                                    "data is never written over a file)")
    (tmp_path / "f").write_text("x")
    done = cli("data", tmp_path / "f")
    assert done.returncode == 2 and "is a file, not a folder" in done.stderr


def test_the_mip_guide_runs_as_written_on_the_sample_data(sample, tmp_path):
    """The mip guide's first shell block, line by line as a reader types it, in a folder made by
    ``pointillist data``: every command exits 0 and writes what its line names."""
    import os
    import re
    import shutil
    import subprocess
    import sys

    from conftest import ROOT

    text = (ROOT / "docs" / "guides" / "mip.md").read_text()
    block = re.search(r"```sh\n(.*?)```", text, re.S).group(1)
    folder = tmp_path / "sample"
    shutil.copytree(sample, folder)
    env = dict(os.environ, PATH=f"{os.path.dirname(sys.executable)}{os.pathsep}{os.environ.get('PATH', '')}")
    for line in block.strip().splitlines():
        command = line.split("  #")[0].strip()
        done = subprocess.run(["bash", "-c", command], cwd=folder, env=env, capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 0, (command, done.stderr)
        for output in re.findall(r"-o (\S+)", command):
            assert (folder / output).is_file() or (folder / output.replace(".png", "_000.png")).is_file(), command
    assert (folder / "out" / "turn.gif").is_file() and (folder / "out" / "turn_035.png").is_file()
    assert (folder / "out" / "scene.exr").is_file() and (folder / "out" / "scene.png").is_file()


def test_the_differentiable_guide_runs_as_written_on_the_sample_data(sample, tmp_path):
    """The inverse-rendering guide's Python block, as a file run next to ``data/``: its gradient check
    agrees (reverse mode against the central difference within 0.1 %) and every colour it recovers
    is within 0.015 of the scene's (RMSE over the nine components below 0.01)."""
    import re
    import shutil
    import subprocess
    import sys

    from conftest import ROOT

    text = (ROOT / "docs" / "guides" / "differentiable.md").read_text()
    block = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    shutil.copytree(sample, tmp_path / "data")
    (tmp_path / "guide.py").write_text(block)
    done = subprocess.run([sys.executable, "guide.py"], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    check = re.search(r"reverse mode (\S+), central difference (\S+)", done.stdout)
    assert float(check.group(1)) == pytest.approx(float(check.group(2)), rel=1e-3)
    found = re.findall(r"found \[([^\]]+)\], truth \[([^\]]+)\]", done.stdout)
    assert len(found) == 3, done.stdout
    errors = np.concatenate([np.array(f.split(), float) - np.array(t.split(), float) for f, t in found])
    assert np.abs(errors).max() < 0.015 and np.sqrt(np.mean(errors ** 2)) < 0.01, done.stdout


def test_the_sample_render_is_the_sample_scene_as_render_writes_it(sample):
    """render.exr: the sample scene at 128x128 and 16 spp, with the metadata `pointillist render` writes."""
    from pointillist.imaging.io import read_exr

    exr = read_exr(sample / "render.exr")
    assert exr.image.shape == (128, 128, 3) and np.isfinite(exr.image).all() and exr.image.max() > 0.5
    assert exr.metadata["spp"] == 16 and exr.metadata["integrator"] == "whitted"
    assert exr.metadata["seed"] == 0 and exr.metadata["sampler"] == "independent"
