"""Reading Mitsuba's parsed scene state (``mi.parser.parse_file``) without changing what it builds.

Two things every reader of a parsed scene must get right, in one place:

* **Properties are read from a copy** (:func:`read_properties`, :func:`references`). Reading a
  property marks it used, and Mitsuba refuses a scene holding a property no plugin used (a
  misspelt ``radience``: "Found 1 unreferenced property") only while the marks are its plugins'
  own.
* **Files resolve as the parser left them** (:func:`resolving_from`): the folders of the scene's
  ``<path>`` elements first, then the scene's folder, as Mitsuba builds the scene.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["read_properties", "references", "resolving_from"]


def read_properties(props) -> dict[str, Any]:
    """The properties of a parsed node, ``{name: value}``, read from a copy (the node's own
    marks of which properties were used stay as they were)."""
    import mitsuba as mi

    return dict(mi.Properties(props).items())


def references(props) -> list[int]:
    """The node indices a parsed node's properties refer to, in order."""
    import mitsuba as mi

    return [value.index() for value in read_properties(props).values()
            if isinstance(value, mi.Properties.ResolvedReference)]


@contextmanager
def resolving_from(folder: Path, resolver=None):
    """Mitsuba's file resolver for loading a scene; the one before is restored after.

    Without ``resolver``: the current one with ``folder`` first, as ``mi.load_file`` sets it up
    before parsing. With one (a parsed scene's ``resolver``): a copy of it, which holds the
    folders the scene's ``<path>`` elements added. Yields the resolver in use.
    """
    import mitsuba as mi

    saved = mi.file_resolver()
    if resolver is None:
        resolver = mi.FileResolver(saved)
        resolver.prepend(str(folder))
    else:
        resolver = mi.FileResolver(resolver)
    mi.set_file_resolver(resolver)
    try:
        yield resolver
    finally:
        mi.set_file_resolver(saved)
