"""Sub-commands of ``pointillist``, one module each.

A command module defines ``NAME`` (the sub-command), ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``. :mod:`pointillist.cli`
finds every module of this package; none needs to be listed anywhere.
"""
