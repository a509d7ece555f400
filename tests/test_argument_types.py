"""A string where a number belongs raises TypeError, naming the argument, in every public function of
``pointillist.imaging`` (found by walking the package: a new function is covered without an edit
here, and one whose required arguments the table below cannot fill fails until it can).

A parameter is numeric when its annotation offers ``int`` or ``float`` (and not ``str``), or, without
an annotation, when its default is a number. Each function is first called with valid arguments
(that call must succeed), then once per numeric parameter with the string ``"3"`` in its place.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import pointillist.imaging as imaging

#: Engine functions whose callers are the operations above them, which check the arguments first
#: (they run per kernel launch with already-checked plain values); each named with its reason.
ENGINE = {
    "pointillist.imaging.arrays.divmod_u32": "bound and divisor come from checked shapes",
    "pointillist.imaging.arrays.warn_non_finite": "stacklevel is set by the calling operation",
    "pointillist.imaging.neighbourhood.finite_extrema": "the filters pass the image's shape and their checked ring",
    "pointillist.imaging.neighbourhood.window_apply": "the windowed filters check their radii",
    "pointillist.imaging.rank.radix_median": "filters.median checks size",
    "pointillist.imaging.median_networks.batcher": "filters.median checks size (n is its window's value count)",
    "pointillist.imaging.wavefront.blocked": "the dithering methods check the shape",
    "pointillist.imaging.wavefront.diffuse_wavefront": "the dithering methods check the shape",
    "pointillist.imaging.wavefront.wavefront_schedule": "the dithering methods check the shape",
}

_RNG = np.random.default_rng(5)
RGB = _RNG.uniform(0, 255, (8, 8, 3)).astype(np.float32)
GREY = RGB[..., 0].copy()


def _volume_files(folder: Path) -> dict[str, Path]:
    from pydicom.data import get_testdata_file

    import nibabel

    np.save(folder / "v.npy", np.zeros((2, 3, 4), np.int16))
    nibabel.save(nibabel.Nifti1Image(np.zeros((4, 3, 2), np.int16), np.eye(4)), folder / "v.nii")
    (folder / "dicom").mkdir()
    shutil.copy(get_testdata_file("CT_small.dcm"), folder / "dicom")
    return {"npy": folder / "v.npy", "nifti": folder / "v.nii", "dicom": folder / "dicom"}


def _values(folder: Path) -> dict[str, list]:
    """Candidate valid values of each required parameter, by name (the first that works is used)."""
    from drjit.llvm.ad import Float

    from pointillist.imaging.dither import bayer
    from pointillist.imaging.io import write_exr

    files = _volume_files(folder)
    write_exr(folder / "image.exr", RGB)
    return {
        "image": [RGB, GREY], "reference": [RGB, GREY], "original": [GREY], "result": [GREY],
        "gamma": [2.2], "r1": [30.0], "s1": [10.0], "r2": [200.0], "s2": [240.0], "levels": [4],
        "table": [np.arange(256)], "n": [4], "template": [bayer(4)], "kernel": [np.ones((3, 3)) / 9],
        "size": [(4, 6)], "x": [np.array([1.5, 2.0])], "y": [np.array([2.5, 0.0])], "t": [np.array([0.5])],
        "shape": [(8, 8)], "level": [40.0], "width": [400.0],
        "values": [np.array([0.0, 40.0, 500.0]), Float(0.0, 40.0, 500.0)],
        "extreme": [40.0],
        "vector": [np.array([0.9, 0.1, 0.0])], "directions": [np.eye(3)],
        "path": [files["npy"], files["nifti"], folder / "image.exr"], "folder": [files["dicom"]],
        "spectrum": ["radial_power_spectrum"],
    }


def public_functions() -> dict[str, object]:
    """Full name -> function, for every public function of every public module (once, where defined)."""
    found: dict[object, str] = {}
    for info in sorted(pkgutil.walk_packages(imaging.__path__, prefix="pointillist.imaging."), key=lambda i: i.name):
        if any(part.startswith("_") for part in info.name.split(".")):
            continue
        module = importlib.import_module(info.name)
        names = getattr(module, "__all__", None) or [
            name for name, value in vars(module).items()
            if not name.startswith("_") and inspect.isfunction(value) and value.__module__ == module.__name__]
        for name in names:
            value = getattr(module, name)
            if inspect.isfunction(value) or inspect.isfunction(getattr(value, "__wrapped__", None)):
                found.setdefault(getattr(value, "__wrapped__", value), (f"{module.__name__}.{name}", value))
    return dict(found.values())


def _alternatives(annotation: str) -> list[str]:
    """The top-level alternatives of a string annotation ``"int | tuple[int, int] | None"``."""
    parts, depth, current = [], 0, ""
    for char in annotation:
        depth += char in "[(" and 1 or 0
        depth -= char in "])" and 1 or 0
        if char == "|" and depth == 0:
            parts.append(current.strip())
            current = ""
        else:
            current += char
    return [*parts, current.strip()]


def numeric(parameter: inspect.Parameter) -> bool:
    if parameter.kind in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD):
        return False
    annotation = parameter.annotation
    if isinstance(annotation, str) and annotation != "Any":
        kinds = _alternatives(annotation)
        return "str" not in kinds and any(re.match(r"(int|float)$|tuple\[(int|float)\b", kind) for kind in kinds)
    default = parameter.default
    return isinstance(default, (int, float)) and not isinstance(default, bool)


FUNCTIONS = public_functions()
CASES = [(name, parameter.name) for name, function in FUNCTIONS.items() if name not in ENGINE
         for parameter in inspect.signature(function).parameters.values() if numeric(parameter)]


def test_the_walk_finds_the_operations():
    names = {name.rsplit(".", 1)[1] for name, _ in CASES}
    assert {"gamma", "tonemap", "threshold", "zero_crossings", "floyd_steinberg", "resize", "load_volume"} <= names
    assert len(CASES) > 60


@pytest.fixture(scope="module")
def valid_calls(tmp_path_factory):
    """Function name -> keyword arguments with which it runs (the required ones filled from the table)."""
    table = _values(tmp_path_factory.mktemp("inputs"))
    calls = {}
    for name, function in FUNCTIONS.items():
        required = [p for p in inspect.signature(function).parameters.values()
                    if p.default is p.empty and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
        calls[name] = [{}]
        for parameter in required:
            options = table.get(parameter.name, [])
            calls[name] = [{**call, parameter.name: value} for call in calls[name] for value in options]
    return calls


def _prepare(call: dict) -> dict:
    if call.get("spectrum") == "radial_power_spectrum":
        from pointillist.imaging.spectrum import radial_power_spectrum

        call = {**call, "spectrum": radial_power_spectrum(GREY)}
    return call


@pytest.mark.parametrize("name, parameter", CASES, ids=[f"{n.rsplit('.', 1)[1]}-{p}" for n, p in CASES])
def test_a_string_for_a_number_is_a_type_error(name, parameter, valid_calls, tmp_path):
    function = FUNCTIONS[name]
    if "path" in inspect.signature(function).parameters and name.endswith(("write_png", "write_vol")):
        valid_calls = {name: [{**call, "path": tmp_path / "out.png"} for call in valid_calls[name]]}
    working = None
    for call in valid_calls[name]:
        try:
            function(**_prepare(call))
        except Exception:  # noqa: BLE001 - try the next candidate
            continue
        working = _prepare(call)
        break
    assert working is not None, f"{name}: no valid call from the table of values; add its arguments there"
    with pytest.raises(TypeError, match=rf"^[\w ]*\b{re.escape(parameter)}\b[^:]*:"):  # "window level: ..." too
        function(**{**working, parameter: "3"})
