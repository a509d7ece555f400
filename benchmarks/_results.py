"""The one writer of benchmarks/RESULTS.md blocks: ``<!-- BEGIN name -->`` ... ``<!-- END name -->``."""

from __future__ import annotations

from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"


def read_block(name: str, path: Path = RESULTS) -> str:
    """The text between the markers of block ``name`` ('' when there is no such block)."""
    content = path.read_text()
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    if begin not in content:
        return ""
    return content[content.index(begin) + len(begin):content.index(end)]


def write_block(name: str, text: str, path: Path = RESULTS) -> Path:
    """Replace block ``name`` of RESULTS.md by ``text`` (appending the block when it is new)."""
    content = path.read_text()
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    if begin not in content:
        content = content.rstrip("\n") + f"\n\n{begin}\n{end}\n"
    i, j = content.index(begin) + len(begin), content.index(end)
    path.write_text(content[:i] + "\n" + text.strip("\n") + "\n" + content[j:])
    return path
