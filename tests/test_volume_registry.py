"""The volume-reader registry: one list behind load_volume, its unknown-suffix error, the package
docstring's table and ``pointillist mip -h``; a reader registered at run time is picked up by each."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pytest

import pointillist.imaging.volumes as volumes
import pointillist.imaging.volumes._registry as registry
from pointillist.commands import mip as mip_command
from pointillist.imaging.volumes import Volume, VolumeReader, load_volume, volume_readers


def _suffixes() -> list[str]:
    return [suffix for reader in volume_readers() for suffix in reader.suffixes]


def _mip_help() -> str:
    parser = argparse.ArgumentParser(prog="pointillist mip", formatter_class=argparse.RawTextHelpFormatter)
    mip_command.add_arguments(parser)
    return " ".join(parser.format_help().split())


def test_every_format_of_the_issue_is_registered_once():
    suffixes = _suffixes()
    known = [".vol", ".npy", ".nrrd", ".nhdr", ".nii", ".nii.gz", ".dcm"]  # in their listing order
    assert [suffix for suffix in suffixes if suffix in known] == known
    assert len(set(suffixes)) == len(suffixes)
    assert [reader.label for reader in volume_readers() if reader.folder] == ["DICOM"]


def test_unknown_suffix_error_docstring_table_and_mip_help_list_every_suffix(tmp_path):
    (tmp_path / "x.xyz").write_bytes(b"")
    with pytest.raises(ValueError) as caught:
        load_volume(tmp_path / "x.xyz")
    message, text = str(caught.value), _mip_help()
    for suffix in _suffixes():
        assert f"{suffix}," in message or f"{suffix} or" in message
        assert f"``{suffix}``" in volumes.__doc__
        assert suffix in text
    assert message.endswith(f"unknown format; expected {', '.join(_suffixes())} or a DICOM folder")
    assert "READER_TABLE" not in volumes.__doc__


def test_longest_suffix_wins_and_case_is_ignored(tmp_path):
    """``.nii.gz`` is NIfTI's, not a plain ``.gz``; ``V.NPY`` is a .npy file."""
    np.save(tmp_path / "v.npy", np.arange(24, dtype=np.int16).reshape(2, 3, 4))
    (tmp_path / "v.npy").rename(tmp_path / "V.NPY")
    assert np.array_equal(load_volume(tmp_path / "V.NPY").data, np.arange(24).reshape(2, 3, 4))
    assert registry._reader_for("a.nii.gz").label == "NIfTI"


def test_a_suffix_claimed_twice_or_spelt_badly_is_refused():
    nifti = next(reader for reader in volume_readers() if reader.label == "NIfTI")
    with pytest.raises(ValueError, match=r"\.nii is already read by the NIfTI reader"):
        registry.register(dataclasses.replace(nifti, label="other"))
    with pytest.raises(ValueError, match="lower-case suffix"):
        registry.register(dataclasses.replace(nifti, label="other", suffixes=(".NII",)))
    assert "other" not in {reader.label for reader in volume_readers()}


def test_a_registered_reader_is_picked_up_everywhere(tmp_path, monkeypatch):
    """What a new module of ``formats/`` does (its ``register`` call), seen by each list at once."""
    monkeypatch.setattr(registry, "_READERS", dict(registry._READERS))

    def read_text(path):
        values = np.loadtxt(path, dtype=np.float32)
        return Volume(values.reshape(1, 1, -1), metadata={"format": "text"})

    registry.register(VolumeReader(name="numbers in text", label="text", suffixes=(".txt",), read=read_text,
                                   spacing_from="(none: 1)", order=60))
    (tmp_path / "v.txt").write_text("1 2 3\n")
    assert load_volume(tmp_path / "v.txt").data.tolist() == [[[1.0, 2.0, 3.0]]]
    (tmp_path / "x.xyz").write_bytes(b"")
    with pytest.raises(ValueError, match=r"expected .vol, .*\.dcm, \.txt or a DICOM folder"):
        load_volume(tmp_path / "x.xyz")
    assert "``.txt``" in registry.reader_table()
    assert ".txt" in _mip_help()


def test_building_the_command_line_imports_no_imaging_module():
    """``mip -h`` lists the registry's formats, but only when the help is shown: building the parser
    (every command does) must not load Dr.Jit, or a missing libLLVM would escape the one-line exit 2."""
    import subprocess
    import sys

    code = ("import sys, pointillist.cli as cli; cli.build_parser(); "
            "print(sorted(m for m in sys.modules if m.startswith(('pointillist.imaging', 'drjit'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("module, reader, label, package", [
    ("nibabel", "nifti.read_nifti", "NIfTI", "nibabel"),
    ("pydicom", "dicom.read_dicom_series", "DICOM", "pydicom"),
    ("nrrd", "nrrd.read_nrrd", "NRRD", "pynrrd"),
])
def test_a_missing_medical_package_is_one_clear_error(monkeypatch, tmp_path, module, reader, label, package):
    """Without its package a reader says which one and the extra that installs it."""
    import importlib
    import sys

    monkeypatch.setitem(sys.modules, module, None)  # `import module` now raises ImportError
    name, function = reader.split(".")
    read = getattr(importlib.import_module(f"pointillist.imaging.volumes.formats.{name}"), function)
    with pytest.raises(ValueError, match=rf"^volume: reading {label} needs {package} "
                                         r"\(pip install 'pointillist\[medical\]'\)$"):
        read(tmp_path / "volume")
