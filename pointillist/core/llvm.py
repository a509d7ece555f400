"""Find a libLLVM that Dr.Jit's LLVM backend can use, before Dr.Jit starts.

Dr.Jit 1.5 compiles its kernels with whatever ``libLLVM`` it finds first. Debian
bookworm ships libLLVM 14 (refused by Dr.Jit as too old) and 15, with which the
first kernel that uses ``dr.minimum``/``dr.maximum`` aborts the *whole process*
("LLVM ERROR: Cannot select ... fminimum"). libLLVM 19 (Debian ``libllvm19``)
works. This module therefore

1. lists the libLLVM shared libraries on the machine (``DRJIT_LIBLLVM_PATH``
   first if the user set it, then the usual library folders, newest version
   first; ``POINTILLIST_LLVM_DIRS``, a ``:``-separated list of folders,
   replaces the usual folders),
2. skips versions known not to work (< :data:`MIN_LLVM_VERSION`),
3. checks the best candidate once in a *subprocess* (a kernel with
   ``dr.minimum``), so that a library that would abort kills only the probe,
   and caches the verdict in ``~/.cache/pointillist/llvm.json``,
4. sets ``DRJIT_LIBLLVM_PATH`` to the first library that passed.

When none is usable, :func:`ensure_llvm` raises :class:`LLVMNotFoundError`
whose message names the Debian package to install. The module uses only the
standard library so that ``python3 pointillist/core/llvm.py`` can run before the
project's virtual environment exists (the Makefile uses it to decide whether to
``apt-get install libllvm19``).
"""

from __future__ import annotations

import glob
import json
import os
import re
import subprocess
import sys
from pathlib import Path

__all__ = [
    "LLVMNotFoundError",
    "MIN_LLVM_VERSION",
    "candidates",
    "ensure_llvm",
    "find_llvm",
]

#: Oldest libLLVM major version accepted. 14 is refused by Dr.Jit 1.5 and 15
#: aborts on ``fminimum``; 19 is the version tested here (Debian ``libllvm19``).
MIN_LLVM_VERSION = 16

#: The Debian package named in the error message.
DEBIAN_PACKAGE = "libllvm19"

_DEFAULT_DIRS = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib64",
    "/usr/lib",
    "/usr/local/lib",
    "/usr/lib/llvm-*/lib",
    "/opt/homebrew/opt/llvm/lib",
    "/usr/local/opt/llvm/lib",
)

_VERSION_RE = re.compile(r"libLLVM(?:-|\.so\.|\.)(\d+)")

_PROBE = (
    "import drjit as dr\n"
    "from drjit.llvm import Float\n"
    "x = dr.minimum(Float(1.0, 2.0, 3.0), Float(2.5))\n"
    "y = dr.maximum(x, Float(0.5))\n"
    "assert list(y) == [1.0, 2.0, 2.5], list(y)\n"
    "print('ok')\n"
)


class LLVMNotFoundError(RuntimeError):
    """No libLLVM usable by Dr.Jit's LLVM backend was found."""


def _version(path: str) -> int | None:
    match = _VERSION_RE.search(os.path.basename(path))
    return int(match.group(1)) if match else None


def candidates() -> list[tuple[int, str]]:
    """Return ``(major_version, path)`` of every libLLVM found, best first.

    A path given in ``DRJIT_LIBLLVM_PATH`` comes first whatever its version (also a missing file:
    :func:`find_llvm` then says why it is not used);
    the others are sorted newest version first. Duplicates (symlinks to the
    same file) are listed once.
    """
    dirs = os.environ.get("POINTILLIST_LLVM_DIRS")
    patterns = dirs.split(os.pathsep) if dirs is not None else list(_DEFAULT_DIRS)
    seen: set[str] = set()
    found: list[tuple[int, str]] = []
    for pattern in patterns:
        for folder in sorted(glob.glob(pattern)):
            for name in ("libLLVM*.so*", "libLLVM*.dylib"):
                for path in glob.glob(os.path.join(folder, name)):
                    version = _version(path)
                    real = os.path.realpath(path)
                    if version is None or real in seen or not os.path.isfile(real):
                        continue
                    seen.add(real)
                    found.append((version, path))
    found.sort(key=lambda item: (-item[0], len(item[1])))
    user = os.environ.get("DRJIT_LIBLLVM_PATH")
    if user:
        found = [(v, p) for v, p in found if os.path.realpath(p) != os.path.realpath(user)]
        found.insert(0, (_version(user) or 0, user))
    return found


def _cache_file() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "pointillist" / "llvm.json"


def _probe(path: str) -> tuple[bool, str]:
    """Run a ``dr.minimum`` kernel with ``path`` in a subprocess (cached)."""
    try:
        stat = os.stat(path)
    except OSError as error:
        return False, str(error)
    key = f"{os.path.realpath(path)}:{stat.st_size}:{int(stat.st_mtime)}"
    cache_path = _cache_file()
    try:
        cache = json.loads(cache_path.read_text())
    except (OSError, ValueError):
        cache = {}
    if not isinstance(cache, dict):  # a damaged cache ([true], null ...) is probed again, then rewritten
        cache = {}
    entry = cache.get(key)
    if isinstance(entry, list) and len(entry) == 2 and isinstance(entry[0], bool) and isinstance(entry[1], str):
        return entry[0], entry[1]
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=path)
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        ok = proc.returncode == 0 and proc.stdout.strip().endswith("ok")
        why = "" if ok else (proc.stderr.strip().splitlines() or [f"exit status {proc.returncode}"])[-1]
    except (OSError, subprocess.TimeoutExpired) as error:
        ok, why = False, str(error)
    if "No module named 'drjit'" in why:
        # Nothing to learn about the library itself: do not cache, do not reject.
        return True, ""
    cache[key] = [ok, why]
    try:
        cache_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = cache_path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(cache, indent=1))
        os.replace(tmp, cache_path)
    except OSError:
        pass
    return ok, why


def find_llvm(*, probe: bool = True) -> str:
    """Return the path of the best usable libLLVM, or raise :class:`LLVMNotFoundError`."""
    rejected: list[str] = []
    user = os.environ.get("DRJIT_LIBLLVM_PATH")
    for version, path in candidates():
        if not os.path.isfile(path):
            rejected.append(f"{path} (no such file)")
            continue
        if version and version < MIN_LLVM_VERSION:
            rejected.append(f"{path} (LLVM {version} is too old: Dr.Jit 1.5 aborts with it)")
            continue
        if probe:
            ok, why = _probe(path)
            if not ok:
                rejected.append(f"{path} (failed a Dr.Jit test kernel: {why})")
                continue
        if user and path != user:  # the library asked for is not usable: say so, and which one is used
            import warnings

            warnings.warn(f"DRJIT_LIBLLVM_PATH: {rejected[0] if rejected else user + ' (not usable)'}; "
                          f"using {path} instead", stacklevel=2)
        return path
    detail = "; ".join(rejected) if rejected else "no libLLVM shared library found"
    raise LLVMNotFoundError(
        f"no usable libLLVM for Dr.Jit's LLVM backend ({detail}). "
        f"Install LLVM {MIN_LLVM_VERSION} or newer, e.g. `sudo apt-get install {DEBIAN_PACKAGE}` "
        "on Debian/Ubuntu, or point DRJIT_LIBLLVM_PATH at a libLLVM.so of version "
        f">= {MIN_LLVM_VERSION}."
    )


_CHOSEN: str | None = None


def ensure_llvm() -> str:
    """Point Dr.Jit at a usable libLLVM (sets ``DRJIT_LIBLLVM_PATH``); idempotent.

    Must run before ``drjit`` is imported; every package of this project calls
    it first thing. Raises :class:`LLVMNotFoundError` when none is usable.
    """
    global _CHOSEN
    if _CHOSEN is not None:
        return _CHOSEN
    if "drjit" in sys.modules and os.environ.get("DRJIT_LIBLLVM_PATH"):
        _CHOSEN = os.environ["DRJIT_LIBLLVM_PATH"]
        return _CHOSEN
    path = find_llvm()
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    _CHOSEN = path
    return path


def _main(argv: list[str]) -> int:
    check_only = "--check" in argv
    try:
        path = find_llvm(probe=not check_only)
    except LLVMNotFoundError as error:
        print(f"pointillist: {error}", file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == "__main__":  # pragma: no cover - exercised by the Makefile
    sys.exit(_main(sys.argv[1:]))
