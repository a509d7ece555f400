"""compare's report files, written again only when what they are made from changed.

``results.csv``, ``results.md``, the plots and ``report.html`` are made from the sweep's records
(every render's scores and times), the reference, the notes and the code that writes them. A
rerun whose renders are all cached would write them again byte for byte, only slowly (the three
plots alone take seconds), so each group of files is written together with a key of what it is
made from (:func:`outputs_key`), kept in ``DIR/renders/outputs.json`` with the SHA-256 of each
file as written (:func:`remember`). The next run leaves a group alone when its key is the same
and each of its files is still there with the bytes written (:func:`unchanged`); a file removed,
edited or replaced since is written again with the rest of its group.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pointillist.core.digests import file_digest, json_key

__all__ = ["MANIFEST_NAME", "manifest_path", "outputs_key", "unchanged", "remember"]

#: The file, in ``DIR/renders/``, that keeps each group's key and the digests of its files.
MANIFEST_NAME = "outputs.json"


def manifest_path(out_dir: str | os.PathLike) -> Path:
    """Where :func:`remember` keeps what it wrote: ``DIR/renders/outputs.json``."""
    return Path(out_dir) / "renders" / MANIFEST_NAME


@functools.lru_cache(maxsize=1)
def _code_digest() -> str:
    """SHA-256 of the code and data that write the report (this package's modules and the page's
    files) and of the versions of what else shapes its bytes (pointillist, matplotlib, numpy)."""
    import importlib.metadata

    folder = Path(__file__).resolve().parent
    files = sorted([*folder.glob("*.py"), *(folder / "page").glob("*")])
    versions = {}
    for name in ("pointillist", "matplotlib", "numpy"):
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = ""
    return json_key({"files": {path.name: file_digest(path) for path in files}, "versions": versions})


def outputs_key(**made_from: Any) -> str:
    """A key (SHA-256, hex) of what a group of outputs is made from: ``made_from`` (JSON-able
    values: the records as stored, the reference's identity, the notes, ...) and the code that
    writes them."""
    return json_key({"code": _code_digest(), "made_from": made_from})


def _read(out_dir: str | os.PathLike) -> dict[str, Any]:
    try:
        data = json.loads(manifest_path(out_dir).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def unchanged(out_dir: str | os.PathLike, group: str, key: str) -> dict[str, Any] | None:
    """What :func:`remember` kept for ``group`` (its ``info``) when it was written with ``key`` and
    each of its files is still the file written; else None (the group must be written)."""
    entry = _read(out_dir).get(group)
    if not isinstance(entry, dict) or entry.get("key") != key or not isinstance(entry.get("files"), dict):
        return None
    for name, digest in entry["files"].items():
        path = Path(out_dir) / name
        if not digest or not path.is_file() or file_digest(path) != digest:
            return None
    info = entry.get("info")
    return info if isinstance(info, dict) else {}


def remember(out_dir: str | os.PathLike, group: str, key: str, files: Sequence[str | os.PathLike],
             info: dict[str, Any] | None = None) -> Path:
    """Record that ``group``'s ``files`` (in ``out_dir``) were written with ``key``, with their
    SHA-256 and ``info`` (JSON-able: what the caller needs back when they are left alone).
    Call it after the files are written: an interrupted run leaves the old key, which no longer
    matches the files, and the next run writes them again."""
    from pointillist.compare.records import write_json

    out = Path(out_dir)
    data = _read(out)
    data[group] = {"key": key, "files": {Path(f).relative_to(out).as_posix(): file_digest(f) for f in files},
                   "info": info or {}}
    path = manifest_path(out)
    write_json(path, data)
    return path
