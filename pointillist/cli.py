"""The ``pointillist`` command line.

Sub-commands are the modules of :mod:`pointillist.commands`. Bad input (and a
file or folder that cannot be read or written) exits with status 2 and one line
on stderr, never a traceback (set ``POINTILLIST_DEBUG=1`` to see one for an
unexpected error). Ctrl-C exits with 130, SIGTERM with 143 (:mod:`pointillist.core.signals`).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import pkgutil
import select
import signal
import sys
import warnings

from pointillist import __version__

from pointillist.core import signals
from pointillist.core.errors import ClusterError, Terminated, UsageError

__all__ = ["main", "build_parser"]


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr and exit status 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message}\n")

    def parse_known_args(self, args=None, namespace=None):
        """argparse's, and an empty or blank value is a usage error (``-o ''`` would otherwise mean
        the default folder, a volume ``''`` the current folder)."""
        namespace, extras = super().parse_known_args(args, namespace)
        for action in self._actions:
            value = getattr(namespace, action.dest, None)
            if any(isinstance(v, str) and not v.strip() for v in (value if isinstance(value, list) else [value])):
                name = "/".join(action.option_strings) or action.dest
                self.error(f"argument {name}: expected a value, got an empty one")
        return namespace, extras


def _commands():
    import pointillist.commands as package

    modules = []
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda i: i.name):
        if not info.name.startswith("_"):
            modules.append(importlib.import_module(f"pointillist.commands.{info.name}"))
    return modules


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The ``pointillist`` argument parser, with one sub-command per module of :mod:`pointillist.commands`.

    With ``argv`` (the arguments about to be parsed), only the sub-command they name gets its
    options (the others their one-line help): ``pointillist --help`` and ``pointillist render -h``
    import no workflow, no numpy and no Mitsuba. Without it, every sub-command is complete.
    """
    parser = _Parser(prog="pointillist", description=(
        "Render Mitsuba scenes with pointillist's Python plugins, compare sampling patterns, "
        "post-process renders and project volumes."))
    parser.add_argument("--version", action="version", version=f"pointillist {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    chosen = None if argv is None else next((a for a in argv if not a.startswith("-")), "")
    for module in _commands():
        command = sub.add_parser(module.NAME, help=module.HELP, description=module.__doc__)
        if chosen is None or chosen == module.NAME:
            module.add_arguments(command)
        command.set_defaults(_run=module.run)
    return parser


def _os_message(error: OSError) -> str:
    """One line for an OSError: its message, and the path when the message does not name it."""
    text = error.strerror or str(error)
    name = error.filename
    if name is not None and str(name) not in text:
        text = f"{text}: {name}"
    return text


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status.

    Runs inside the signal boundary (:mod:`pointillist.core.signals`; installed here for the call when
    the console script has not installed it already): SIGINT and SIGTERM stop the command at its
    next safe point, where the ``KeyboardInterrupt`` / :class:`~pointillist.core.errors.Terminated`
    raised unwinds it (temporary files removed, clusters closed); the status is 130 (Ctrl-C) or
    143 (SIGTERM), with one line on stderr. A signal that arrives after the last safe point still
    makes the status 130 / 143.
    """
    with signals.boundary(), warnings.catch_warnings():
        arguments = sys.argv[1:] if argv is None else list(argv)
        args = build_parser(arguments).parse_args(arguments)
        name = f"pointillist {args.command}"
        signals.set_command(name)
        warnings.showwarning = _warning_line(name)
        status = _run(args, name)
        signum = signals.received()
        if signum is not None and status == 0:
            signals.report(signum, name)
            status = signals.status(signum)
        return status


def _run(args: argparse.Namespace, name: str) -> int:
    """Run the parsed command; every error becomes its exit status and one line on stderr."""
    try:
        signals.check()
        return int(args._run(args) or 0)
    except UsageError as error:
        print(f"{name}: error: {error}", file=sys.stderr)
        return 2
    except ClusterError as error:  # not the user's input: the cluster went away
        print(f"{name}: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as interrupt:  # also Terminated (SIGTERM)
        signum = signals.received()
        if signum is None:
            signum = signal.SIGTERM if isinstance(interrupt, Terminated) else signal.SIGINT
        signals.report(signum, name)
        return signals.status(signum)
    except BrokenPipeError as error:
        if _stdout_closed():  # `pointillist post --list-steps | head`: the reader has all it wanted
            return STATUS_BROKEN_PIPE
        print(f"{name}: error: {_os_message(error)}", file=sys.stderr)
        return 2
    except OSError as error:  # a file or folder that cannot be read or written
        if os.environ.get("POINTILLIST_DEBUG"):
            raise
        print(f"{name}: error: {_os_message(error)}", file=sys.stderr)
        return 2
    except Exception as error:  # noqa: BLE001 - the one place that turns errors into exit codes
        from pointillist.core.llvm import LLVMNotFoundError

        if os.environ.get("POINTILLIST_DEBUG"):
            raise
        if isinstance(error, LLVMNotFoundError):
            print(f"pointillist: error: {error}", file=sys.stderr)
            return 2
        if isinstance(error, (ValueError, TypeError)):
            print(f"{name}: error: {error}", file=sys.stderr)
            return 2
        print(f"{name}: internal error: {type(error).__name__}: {error} "
              "(POINTILLIST_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


def _warning_line(name: str):
    """A ``warnings.showwarning`` for the command line: each warning once, as one line
    ``NAME: warning: MESSAGE`` (not Python's file, line number and source line, nor once per place
    that warns: a plugin configured twice says it once)."""
    shown: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        if text in shown:
            return
        shown.add(text)
        with contextlib.suppress(Exception):
            print(f"{name}: warning: {text}", file=sys.stderr if file is None else file)

    return show


#: Exit status when the reader of stdout went away (``| head``): 128 + SIGPIPE, silently, as a
#: Unix tool killed by SIGPIPE ends (Python ignores SIGPIPE, so the write raises instead).
STATUS_BROKEN_PIPE = 128 + 13


def _stdout_closed() -> bool:
    """Whether stdout's reader is gone (a pipe with no reader polls as an error); if so stdout is
    pointed at /dev/null, so that nothing (the interpreter's last flush included) writes there
    again."""
    try:
        fd = sys.stdout.fileno()
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        closed = any(events & select.POLLERR for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):  # no real stdout (a notebook, a closed stream)
        return False
    if closed:
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), fd)
    return closed


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
