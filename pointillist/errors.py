"""The error the command line turns into exit status 2 and one line on stderr."""

from __future__ import annotations

__all__ = ["UsageError"]


class UsageError(ValueError):
    """Bad input from the user (file, option, scene): exit status 2, one line on stderr."""
