"""Digests that name inputs and results: a file's SHA-256, and the SHA-256 of a value as canonical JSON.

The plan of a command, the tile and sweep caches and compare's re-run checks all key their work
by these two; neither imports numpy (a plain render computes its plan's digest).

Examples
--------
>>> json_key({"b": (1, 2), "a": "x"}) == json_key({"a": "x", "b": [1, 2]})
True
>>> file_digest("/no/such/file")
''
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

__all__ = ["file_digest", "json_key", "json_default"]

_DIGESTS: dict[tuple[str, int, int], str] = {}


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (memoised on path, size and mtime); '' if it does not exist."""
    try:
        stat = os.stat(path)
    except OSError:
        return ""
    key = (str(Path(path).resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _DIGESTS:
        _DIGESTS[key] = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return _DIGESTS[key]


def json_default(value: Any) -> Any:
    """JSON for what ``json`` does not know: tuples and sets as lists, paths as text, numpy scalars
    as Python numbers; TypeError for anything else."""
    if isinstance(value, (tuple, set, frozenset)):
        return list(value)
    if isinstance(value, Path):
        return str(value)
    if type(value).__module__ == "numpy" and hasattr(value, "item") and getattr(value, "ndim", None) == 0:
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def json_key(value: Any) -> str:
    """SHA-256 (hex) of ``value`` as canonical JSON (sorted keys; tuples as lists, paths as strings)."""
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=json_default).encode()).hexdigest()
