"""Post-processing steps for ``pointillist post``: a registry filled by this package's modules.

A step is one imaging operation with a name the command line knows. Modules
of this package (``tone``, ``filters``, ``dither`` ...) declare theirs with
:func:`step`::

    @step("gamma", help="gamma correction V = (I/a)^(1/gamma)", params=("gamma",))
    def _gamma(image, gamma, a=1.0):
        return tone.gamma(image, gamma, a=a)

Steps take and return Dr.Jit tensors. A step with ``linear=True`` expects
linear-light HDR input (an EXR render) and returns display values on 0..255
(tone mapping); every other step works on 0..255 intensities. ``report``
(optional) is called as ``report(before, after)`` by ``post --report`` and
returns a dict of numbers to print (dithering reports its error this way).

The step string syntax is ``name[:arg,arg,key=value,...]`` joined by ``;``,
e.g. ``"tonemap:reinhard,exposure=1;gamma:2.2;sobel;threshold:level=128"``.
Positional arguments fill ``params`` in order; values are converted to int,
float, bool (true/false) or left as strings.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import pkgutil
from dataclasses import dataclass, field
from typing import Any, Callable

from pointillist.core.errors import UsageError

__all__ = ["Step", "STEPS", "step", "steps", "parse_steps", "parse_value"]


@dataclass(frozen=True)
class Step:
    """A registered step. ``ring(kwargs)`` (window steps) gives the width of the border ring the
    step leaves uncomputed (0 with a padded border; ``None`` for steps that map each value and keep
    the ring as it was); ``normalize`` leaves that ring out of its min and max. ``takes_bytes``: the step
    takes 8-bit input as it is and returns what it returns for its float32 conversion (so a chain
    on an 8-bit image reads the bytes there, without a float32 copy); every other step gets float32."""

    name: str
    function: Callable[..., Any]
    help: str
    params: tuple[str, ...] = ()
    linear: bool = False
    report: Callable[[Any, Any], dict[str, float]] | None = field(default=None)
    ring: Callable[[dict[str, Any]], int] | None = field(default=None)
    takes_bytes: bool = False


STEPS: dict[str, Step] = {}


def step(name: str, *, help: str, params: tuple[str, ...] = (), linear: bool = False,
         report: Callable[[Any, Any], dict[str, float]] | None = None,
         ring: Callable[[dict[str, Any]], int] | None = None, takes_bytes: bool = False):
    """Decorator registering ``function`` as the post step ``name`` (``ring``, ``takes_bytes``: see :class:`Step`)."""

    def decorate(function):
        if name in STEPS and STEPS[name].function is not function:
            raise RuntimeError(f"post step {name!r} is defined twice")
        STEPS[name] = Step(name, function, help, tuple(params), linear, report, ring, takes_bytes)
        return function

    return decorate


def steps() -> dict[str, Step]:
    """Every registered step (imports this package's modules once)."""
    for info in pkgutil.iter_modules(__path__):
        if not info.name.startswith("_"):
            importlib.import_module(f"{__name__}.{info.name}")
    return dict(sorted(STEPS.items()))


def parse_value(text: str) -> Any:
    """``"2"`` -> 2, ``"2.5"`` -> 2.5, ``"true"`` -> True, anything else stays a string."""
    lowered = text.strip().lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text.strip()


@functools.lru_cache(maxsize=None)
def _signature(function: Callable[..., Any]) -> inspect.Signature:
    """``inspect.signature`` of a step function, computed once (about 0.2 ms a call, each parse)."""
    return inspect.signature(function)


def _check_arguments(spec: Step, kwargs: dict[str, Any], chunk: str) -> None:
    """UsageError, before any work, for a missing required or an unknown keyword argument."""
    signature = _signature(spec.function)
    try:
        signature.bind(None, **kwargs)
    except TypeError as error:
        names = [p.name for p in list(signature.parameters.values())[1:]
                 if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)]
        raise UsageError(f"--steps: {chunk!r}: {error} (step {spec.name!r} takes "
                         f"{', '.join(names) or 'no arguments'})") from None


def parse_steps(text: str) -> list[tuple[Step, dict[str, Any]]]:
    """Parse a ``;``-separated step string into ``(Step, keyword arguments)`` pairs.

    Raises UsageError naming the unknown step, the surplus, repeated, missing or
    unknown argument, or the bad syntax, before any step runs (values themselves
    are checked by the step).
    """
    known = steps()
    parsed = []
    for chunk in (c.strip() for c in text.split(";")):
        if not chunk:
            continue
        name, _, rest = chunk.partition(":")
        name = name.strip()
        if name not in known:
            raise UsageError(f"--steps: unknown step {name!r}; known steps: {', '.join(known)}")
        spec = known[name]
        kwargs: dict[str, Any] = {}
        positional = 0
        for arg in (a.strip() for a in rest.split(",")) if rest.strip() else ():
            if not arg:
                raise UsageError(f"--steps: empty argument in {chunk!r}")
            key, eq, value = arg.partition("=")
            if eq:
                key = key.strip()
                if not key:
                    raise UsageError(f"--steps: argument {arg!r} of {chunk!r} has no name before '='")
            else:
                if positional >= len(spec.params):
                    raise UsageError(f"--steps: step {name!r} takes at most {len(spec.params)} "
                                     f"positional argument(s) ({', '.join(spec.params) or 'none'}), got {chunk!r}")
                key, value = spec.params[positional], key
                positional += 1
            if key in kwargs:
                raise UsageError(f"--steps: {key} given twice in {chunk!r}")
            kwargs[key] = parse_value(value)
        _check_arguments(spec, kwargs, chunk)
        parsed.append((spec, kwargs))
    if not parsed:
        raise UsageError("--steps: no step given")
    return parsed
