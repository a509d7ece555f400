"""A command's plan, made before any work: every file it reads and every file it will write.

Every command builds a :class:`Plan` before it starts working and checks it (:meth:`Plan.check`):

* **inputs**: the scene file and every file the scene reads (:func:`scene_inputs`: its
  ``<include>`` files and every file a property names: textures, meshes, environment maps,
  volumes, spectra, resolved as Mitsuba's file resolver resolves them), or the image, volume
  and tables of ``post`` and ``mip``;
* **outputs**: every file (or folder) the command will write: the main output, the PNG preview,
  the progress log and plot, the checkpoint, compare's tables, plots, report and caches, mip's
  frames and GIF.

Each output must be writable now (its folder exists, or can be made, and takes new files: a
file is created and removed there to find out), must not be a folder where a file is expected,
must not be an input (the same file by device and inode: through ``..``, symbolic and hard links
too) nor lie inside an input folder, and no two outputs may be the same file. A failure is a
:class:`~pointillist.core.errors.UsageError` naming the option, before any work.

:func:`inputs_digest` is the SHA-256 of the inputs' contents and the ``-D`` values: the cache key
of compare's renders and tiles, and the fingerprint of progressive checkpoints, so that a changed
texture, mesh or included file is never mistaken for the scene rendered before.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import stat
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pointillist.core.digests import file_digest
from pointillist.core.errors import UsageError
from pointillist.core.files import check_output_path, existing_ancestor, unwritable
from pointillist.parsed_state import read_properties, resolving_from

__all__ = ["Output", "Plan", "scene_inputs", "inputs_digest", "scene_digest"]

#: Longest string property value looked up as a file name (longer ones are not file names).
_MAX_NAME = 4096


@dataclass(frozen=True)
class Output:
    """One thing a command writes.

    ``what`` names it in messages (the option, e.g. ``--output``, or ``PNG preview``);
    ``folder``: a folder (made when missing, with its parents); ``make_parent``: the file's folder
    may be made (the default ``out/``), else it must exist; ``suffixes``: the file name's suffixes
    the command can write (lower case, e.g. ``(".png", ".exr")``; any when empty).
    """

    path: Path
    what: str
    folder: bool = False
    make_parent: bool = False
    suffixes: tuple[str, ...] = ()


def _probe(folder: Path, what: str, target: Path) -> None:
    """UsageError unless a new file can be created in ``folder``."""
    refused = unwritable(folder)
    if refused:
        raise UsageError(f"{what}: cannot write {target} ({refused})")


@dataclass
class Plan:
    """The inputs and outputs of one command; :meth:`check` them before any work.

    Examples
    --------
    >>> plan = Plan(outputs=[Output(Path("a.exr"), "--output"), Output(Path("a.exr"), "PNG preview")])
    >>> plan.check()
    Traceback (most recent call last):
    ...
    pointillist.core.errors.UsageError: PNG preview: a.exr is also the --output file
    >>> Plan(outputs=[Output(Path("a.jpg"), "--output", suffixes=(".png", ".exr"))]).check()
    Traceback (most recent call last):
    ...
    pointillist.core.errors.UsageError: --output: expected a .png or .exr file name, got a.jpg
    """

    inputs: list[Path] = field(default_factory=list)
    outputs: list[Output] = field(default_factory=list)
    _made: list[Path] = field(default_factory=list, repr=False)

    def add(self, *, inputs: Iterable[str | os.PathLike] = (), outputs: Iterable[Output] = ()) -> Plan:
        """Add inputs and outputs and check the plan again; returns the plan."""
        self.inputs.extend(Path(p) for p in inputs)
        self.outputs.extend(outputs)
        self.check()
        return self

    def output(self, what: str) -> Path:
        """The path of the output named ``what``."""
        for out in self.outputs:
            if out.what == what:
                return out.path
        raise KeyError(what)

    def check(self) -> None:
        """UsageError for the first output that cannot be written, is an input or repeats another
        (:func:`pointillist.core.files.check_output_path` for each file)."""
        seen: dict[str, Output] = {}
        for out in self.outputs:
            key = os.path.realpath(out.path)
            if key in seen:
                raise UsageError(f"{out.what}: {out.path} is also the {seen[key].what} file")
            seen[key] = out
            if out.suffixes and out.path.suffix.lower() not in out.suffixes:
                raise UsageError(f"{out.what}: expected a {' or '.join(out.suffixes)} file name, got {out.path}")
            if out.folder:
                self._check_folder(out)
            else:
                check_output_path(out.path, self.inputs, out.what, make_parent=out.make_parent)

    def _check_folder(self, out: Output) -> None:
        path = out.path
        if path.exists():
            if not path.is_dir():
                raise UsageError(f"{out.what}: {path} exists and is not a folder")
            _probe(path, out.what, path)
            return
        ancestor = existing_ancestor(path)
        if not ancestor.is_dir():
            raise UsageError(f"{out.what}: cannot create the folder {path} ({ancestor} is not a folder)")
        _probe(ancestor, out.what, path)

    @contextlib.contextmanager
    def writing(self) -> Iterator[Plan]:
        """Make the missing folders of the outputs for the block; those still empty when it ends
        are removed again (a command that stops before writing leaves no empty folder)."""
        try:
            for out in self.outputs:
                folder = out.path if out.folder else out.path.parent
                self._make(folder)
            yield self
        finally:
            for folder in reversed(self._made):
                with contextlib.suppress(OSError):
                    folder.rmdir()  # only when empty
            self._made.clear()

    def _make(self, folder: Path) -> None:
        missing = []
        current = Path(os.path.abspath(folder))
        while not current.exists() and current != current.parent:
            missing.append(current)
            current = current.parent
        for path in reversed(missing):
            try:
                path.mkdir()
            except FileExistsError:
                continue
            except OSError as error:
                raise UsageError(f"cannot create the folder {path} ({error.strerror or error})") from None
            self._made.append(path)


def scene_inputs(parsed) -> list[Path]:
    """The files a parsed scene (:class:`pointillist.scene.ParsedScene`) reads, in the scene's order.

    The scene file and its ``<include>`` files (as the parser found them), then every file a
    string property names (``filename`` of bitmaps, meshes, environment maps, volumes, spectra,
    and any other property whose value is the name of an existing file), resolved as Mitsuba's
    file resolver does when the scene is built (the folders of its ``<path>`` elements, then the
    scene's folder). A name that resolves to no file is left
    out (Mitsuba reports it when the scene is built); one that names a device, a pipe or a socket
    is a UsageError (reading ``/dev/zero`` as a PLY never ends). Each file once.
    """
    found: list[Path] = [Path(str(name)) for name in parsed.state.files]
    with resolving_from(parsed.path.resolve().parent, getattr(parsed, "resolver", None)) as resolver:
        for node in parsed.state.nodes:
            for key, value in read_properties(node.props).items():
                if not isinstance(value, str):
                    continue
                if not value or len(value) > _MAX_NAME or "\0" in value:
                    continue
                try:
                    resolved = Path(str(resolver.resolve(value)))
                    kind = resolved.stat().st_mode if resolved.exists() else 0
                except (OSError, ValueError, RuntimeError):
                    continue
                if stat.S_ISREG(kind):
                    found.append(resolved)
                elif stat.S_ISCHR(kind) or stat.S_ISBLK(kind) or stat.S_ISFIFO(kind) or stat.S_ISSOCK(kind):
                    raise UsageError(f"scene {parsed.path}: {key} {value!r} is {resolved}, not a regular file "
                                     "(a device, a pipe or a socket: it may never end, e.g. /dev/zero)")
    unique: dict[str, Path] = {}
    for path in found:
        unique.setdefault(os.path.realpath(path), Path(path))
    return list(unique.values())


def inputs_digest(inputs: Sequence[str | os.PathLike], params: dict[str, str] | None = None) -> str:
    """SHA-256 (hex) of the inputs' contents, in order, and the ``-D`` values.

    Names do not count (a scene folder moved or renamed keeps its renders), contents and their
    order do. A missing input hashes as empty.
    """
    digest = hashlib.sha256()
    digest.update(json.dumps(sorted((params or {}).items())).encode())
    for path in inputs:
        digest.update(b"\0" + file_digest(path).encode())
    return digest.hexdigest()


def scene_digest(scene: str | os.PathLike, params: dict[str, str] | None = None) -> str:
    """:func:`inputs_digest` of a scene file's inputs (:func:`scene_inputs`); parses the scene
    (Mitsuba must be set up: :func:`pointillist.setup`)."""
    from pointillist.scene import parse_scene

    params = dict(params or {})
    return inputs_digest(scene_inputs(parse_scene(scene, params)), params)
