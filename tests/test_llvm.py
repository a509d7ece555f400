"""libLLVM discovery: a usable one is chosen, an unusable one gives a clear error, never an abort."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pointillist.core import llvm

ROOT = Path(__file__).resolve().parent.parent
SYSTEM_LLVM15 = Path("/usr/lib/x86_64-linux-gnu/libLLVM-15.so")


def _env(tmp_path: Path, dirs: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    env["POINTILLIST_LLVM_DIRS"] = dirs
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    return env


def _run(code: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def test_version_parsing_and_order(tmp_path, monkeypatch):
    for name in ("libLLVM-14.so", "libLLVM-15.so.1", "libLLVM.so.19.1", "libLLVM-17.so", "libfoo.so"):
        (tmp_path / name).write_bytes(b"x")
    monkeypatch.setenv("POINTILLIST_LLVM_DIRS", str(tmp_path))
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    assert [v for v, _ in llvm.candidates()] == [19, 17, 15, 14]
    # A user's DRJIT_LIBLLVM_PATH comes first whatever its version.
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "libLLVM-15.so.1"))
    assert llvm.candidates()[0] == (15, str(tmp_path / "libLLVM-15.so.1"))


def test_old_versions_are_refused_without_running_them(tmp_path, monkeypatch):
    (tmp_path / "libLLVM-15.so").write_bytes(b"x")
    (tmp_path / "libLLVM-14.so").write_bytes(b"x")
    monkeypatch.setenv("POINTILLIST_LLVM_DIRS", str(tmp_path))
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    with pytest.raises(llvm.LLVMNotFoundError, match="libllvm19") as info:
        llvm.find_llvm()
    assert "LLVM 15 is too old" in str(info.value) and "LLVM 14 is too old" in str(info.value)


def test_chosen_library_is_usable_and_exported():
    path = llvm.ensure_llvm()
    assert os.environ["DRJIT_LIBLLVM_PATH"] == path
    assert llvm._version(path) >= llvm.MIN_LLVM_VERSION
    import drjit as dr

    assert dr.detail.llvm_version()[0] >= llvm.MIN_LLVM_VERSION


def test_no_library_gives_clear_error_not_abort(tmp_path):
    proc = _run("import pointillist.imaging", _env(tmp_path, str(tmp_path)))
    assert proc.returncode == 1, proc.stderr
    assert "LLVMNotFoundError" in proc.stderr
    assert "no libLLVM shared library found" in proc.stderr and "apt-get install libllvm19" in proc.stderr


def test_broken_library_fails_the_probe(tmp_path):
    folder = tmp_path / "lib"
    folder.mkdir()
    (folder / "libLLVM-19.so").write_bytes(b"not a shared library")
    proc = _run("import pointillist.plugins.samplers", _env(tmp_path, str(folder)))
    assert proc.returncode == 1
    assert "failed a Dr.Jit test kernel" in proc.stderr and "libllvm19" in proc.stderr


def test_cli_with_only_old_llvm_exits_2_with_one_line(tmp_path):
    folder = tmp_path / "lib"
    folder.mkdir()
    (folder / "libLLVM-15.so").write_bytes(b"x")
    proc = subprocess.run([sys.executable, "-m", "pointillist", "render", "scenes/default.xml",
                           "-o", str(tmp_path / "x.exr")], env=_env(tmp_path, str(folder)), cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "libllvm19" in lines[0] and "Traceback" not in proc.stderr
    assert not (tmp_path / "x.exr").exists()


@pytest.mark.skipif(not SYSTEM_LLVM15.exists(), reason="needs Debian's libLLVM 15")
def test_probe_survives_the_llvm15_abort(tmp_path, monkeypatch):
    # Dr.Jit aborts the process with LLVM 15 ("Cannot select ... fminimum"); the probe runs it
    # in a subprocess, so only the probe dies and the verdict is "unusable".
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    ok, why = llvm._probe(str(SYSTEM_LLVM15))
    assert not ok and why
    assert llvm._probe(str(SYSTEM_LLVM15)) == (ok, why)  # cached verdict
