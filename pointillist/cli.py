"""The ``pointillist`` command line.

Sub-commands are the modules of :mod:`pointillist.commands`. Bad input exits
with status 2 and one line on stderr, never a traceback (set
``POINTILLIST_DEBUG=1`` to see one for an unexpected error).
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

from pointillist import __version__
from pointillist.errors import UsageError

__all__ = ["main", "build_parser"]


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr and exit status 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message}\n")


def _commands():
    import pointillist.commands as package

    modules = []
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda i: i.name):
        if not info.name.startswith("_"):
            modules.append(importlib.import_module(f"pointillist.commands.{info.name}"))
    return modules


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="pointillist", description=(
        "Render Mitsuba scenes with pointillist's Python plugins, compare sampling patterns, "
        "post-process renders and project volumes."))
    parser.add_argument("--version", action="version", version=f"pointillist {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for module in _commands():
        command = sub.add_parser(module.NAME, help=module.HELP, description=module.__doc__)
        module.add_arguments(command)
        command.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except UsageError as error:
        print(f"pointillist {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"pointillist {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as error:  # noqa: BLE001 - the one place that turns errors into exit codes
        from pointillist.llvm import LLVMNotFoundError

        if os.environ.get("POINTILLIST_DEBUG"):
            raise
        if isinstance(error, LLVMNotFoundError):
            print(f"pointillist: error: {error}", file=sys.stderr)
            return 2
        if isinstance(error, (ValueError, TypeError)):
            print(f"pointillist {args.command}: error: {error}", file=sys.stderr)
            return 2
        print(f"pointillist {args.command}: internal error: {type(error).__name__}: {error} "
              "(POINTILLIST_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
