"""The plugin registry drives every list of plugins: a plugin's name is its module's file name,
written nowhere else; compare's samplers, its help and the docs' plugin reference come from it."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _plugin_sources() -> dict[str, Path]:
    """The plugin modules, found by globbing the folders (pointillist.plugins lists them with pkgutil)."""
    return {path.stem: path for kind in ("integrators", "samplers", "bsdfs")
            for path in sorted((ROOT / "plugins" / kind).glob("*.py")) if not path.stem.startswith("_")}


def _kinds() -> dict[str, str]:
    return {name: path.parent.name[:-1] for name, path in _plugin_sources().items()}


def test_available_lists_what_register_registers(mi):
    from pointillist import plugins

    assert plugins.available() == plugins.registered() == _kinds()
    assert {"whitted", "adaptive", "mip", "grid", "jitter", "poisson", "sobol", "zsobol", "lambert",
            "phong"} <= set(_kinds())
    assert plugins.available("sampler") == {n: k for n, k in _kinds().items() if k == "sampler"}
    with pytest.raises(ValueError, match="kind: expected one of integrator, sampler, bsdf, got 'samplers'"):
        plugins.available("samplers")
    # each class carries its file's name, which Mitsuba knows it by
    for name, kind in plugins.registered().items():
        cls = plugins.plugin_class(name)
        assert cls.PLUGIN_NAME == name and cls is sys.modules[f"pointillist.plugins.{kind}s.{name}"].PLUGIN_CLASS
    scene = mi.load_dict({"type": "scene", "sensor": {"type": "perspective", "sampler": {"type": "zsobol"}}})
    assert type(scene.sensors()[0].sampler()).PLUGIN_NAME == "zsobol"


def test_a_plugin_name_is_written_once():
    """No plugin module assigns its name: the file's name is the name."""
    assigned = {}
    for name, path in _plugin_sources().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "PLUGIN_NAME" for t in node.targets):
                assigned.setdefault(name, []).append(ast.literal_eval(node.value))
    assert not assigned, f"plugins that spell their name again: {assigned}"


def test_summary_is_the_module_docstrings_first_line():
    from pointillist import plugins

    assert plugins.summary("grid") == "samples at the centres of a regular sub-pixel grid"
    assert plugins.summary("whitted") == "classic recursive (Whitted-style) ray tracing, in Python on Dr.Jit"
    for name, path in _plugin_sources().items():  # every plugin has one
        assert plugins.summary(name) and f"The ``{name}``" in path.read_text().splitlines()[0]
    with pytest.raises(ValueError, match="no pointillist plugin named 'nope'"):
        plugins.summary("nope")


def test_the_registry_reads_the_folders(tmp_path, monkeypatch):
    """A module is a plugin named after its file (``_`` helpers are not); its docstring must say what it is."""
    from pointillist import plugins

    for kind in plugins.KINDS:
        (tmp_path / kind).mkdir()
    (tmp_path / "samplers" / "halton.py").write_text('"""The ``halton`` sampler: Halton points, scrambled."""\n')
    (tmp_path / "samplers" / "_helpers.py").write_text('"""Shared code."""\n')
    (tmp_path / "samplers" / "bad.py").write_text('"""A sampler without its one line."""\n')
    monkeypatch.setattr(plugins, "__path__", [str(tmp_path)])
    assert plugins.available() == {"bad": "sampler", "halton": "sampler"}
    assert plugins.summary("halton") == "Halton points, scrambled"
    with pytest.raises(ValueError, match=r"bad: its module docstring must open with 'The ``bad`` sampler: \.\.\.'"):
        plugins.summary("bad")


def test_plugins_and_compare_help_need_no_libllvm(tmp_path):
    """Listing the plugins imports neither Mitsuba nor Dr.Jit: `compare -h` works where no libLLVM does."""
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    env.update(POINTILLIST_LLVM_DIRS=str(tmp_path), XDG_CACHE_HOME=str(tmp_path / "cache"))
    code = ("import sys; from pointillist import plugins; print(sorted(plugins.available('sampler')), "
            "'drjit' in sys.modules, 'mitsuba' in sys.modules)")
    listed = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True,
                            timeout=120)
    assert listed.returncode == 0, listed.stderr
    samplers = sorted(n for n, k in _kinds().items() if k == "sampler")
    assert listed.stdout.strip() == f"{samplers} False False"
    helped = subprocess.run([sys.executable, "-m", "pointillist", "compare", "-h"], env=env, cwd=ROOT,
                            capture_output=True, text=True, timeout=120)
    assert helped.returncode == 0, helped.stderr
    assert "zsobol (pbrt-v4's ZSobolSampler" in " ".join(helped.stdout.split())
    plugin = subprocess.run([sys.executable, "-c", "import pointillist.plugins.samplers"], env=env, cwd=ROOT,
                            capture_output=True, text=True, timeout=120)
    assert plugin.returncode == 1 and "LLVMNotFoundError" in plugin.stderr  # the plugins themselves need it


def test_mitsuba_samplers_are_the_samplers_mitsuba_has(mi):
    from pointillist.compare.methods import MITSUBA_SAMPLERS

    manager = mi.PluginManager.instance()
    names = sorted(path.stem for path in (Path(mi.__file__).parent / "plugins").glob("*.so"))
    assert len(names) > 50
    assert sorted(n for n in names if manager.plugin_type(n) == mi.ObjectType.Sampler) == sorted(MITSUBA_SAMPLERS)


def test_compare_methods_come_from_the_registries():
    from pointillist import plugins
    from pointillist.compare.methods import METHODS, MITSUBA_SAMPLERS, SAMPLER_ALIASES, describe_methods

    samplers = {name for name, method in METHODS.items() if method.kind == "sampler"}
    assert samplers == set(plugins.available("sampler")) | set(MITSUBA_SAMPLERS) | set(SAMPLER_ALIASES)
    assert all(METHODS[name].plugin == name for name in samplers - set(SAMPLER_ALIASES))
    assert METHODS["random"].plugin == "independent"
    text = describe_methods()
    for name in plugins.available("sampler"):
        assert f"{name} ({plugins.summary(name)})" in text
    assert "Mitsuba's independent (also random), stratified" in text and "; or adaptive (adaptive super" in text
