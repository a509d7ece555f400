"""The ground every layer may import: argument checks, errors, files, signals, the terminal, the
libLLVM bootstrap and digests. Nothing here imports Mitsuba, Dask, numpy at import time, or any
other part of pointillist.

===============  ======================================================================
Module           What it holds
===============  ======================================================================
``llvm``         finding a libLLVM Dr.Jit's LLVM backend can use (runs before install too)
``errors``       the one-line error types and wording of the command line
``checks``       the argument checks every layer shares (one rule for each kind of value)
``terminal``     whether to draw a progress bar, and the bar
``digests``      a file's SHA-256 and a value's canonical-JSON SHA-256
``signals``      the signal boundary: a first Ctrl-C or SIGTERM is a request, a second ends at once
``files``        input and output checks, atomic writes, figures
===============  ======================================================================
"""
