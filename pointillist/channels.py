"""The one split of a rendered image into colour, alpha and AOV layers, from the film's channels.

``mi.render`` returns one (H, W, C) tensor. Which channel is what depends on the film and the
integrator, and only they say it:

* a film's base channels are its colour (``Y`` for ``luminance``, ``R G B`` for ``rgb``) and,
  when its pixel format has alpha, ``A`` (``Film.base_channels_count()``, ``FilmFlags.Alpha``);
* an ordinary integrator appends its AOVs, named by ``Integrator.aov_names()``, after them
  (``sample_count`` of the ``adaptive`` integrator);
* Mitsuba's own ``aov`` integrator renders no base channels of its own: its image is, for each
  integrator nested in it, that integrator's image (its base channels, then its AOVs), and then
  its own AOVs. ``aov_names()`` lists a nested integrator ``inner`` as ``inner.R inner.G inner.B
  inner.A`` followed by ``inner.<its AOVs>``; the four names stand for the film's base channels.
  Mitsuba's documentation: the first nested integrator's image is the colour (and alpha) of the
  render. Without a nested integrator the render has no colour at all (only AOVs).

:func:`channel_layout` reads this from a loaded scene into a :class:`ChannelLayout`, whose
:meth:`ChannelLayout.split` cuts an image into ``colour`` (H, W, 1 or 3, or None), ``alpha``
(H, W or None) and ``layers`` (name -> (H, W)). ``render``, progressive rendering, ``compare``
and tiled renders all go through it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

__all__ = ["ChannelLayout", "SplitImage", "channel_layout", "layout_from_names", "BASE_NAMES"]

#: Names of a film's base channels by their count (colour, then alpha).
BASE_NAMES = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}

#: Mitsuba's class name of its ``aov`` integrator.
_AOV_CLASS = "AOVIntegrator"


class SplitImage(NamedTuple):
    """An image cut by :meth:`ChannelLayout.split` (numpy, float32)."""

    colour: np.ndarray | None
    alpha: np.ndarray | None
    layers: dict[str, np.ndarray]


@dataclass(frozen=True)
class ChannelLayout:
    """What each channel of a rendered (H, W, C) image is.

    Attributes
    ----------
    names : tuple of str
        One name per channel, in order.
    colour : tuple of int
        The colour channels (``Y``, or ``R G B``); always the first ones; empty when the render
        has no colour (Mitsuba's ``aov`` integrator without a nested integrator).
    alpha : int or None
        The alpha channel.
    layers : tuple of (str, int)
        Every other channel, by name: the AOVs, in order.
    """

    names: tuple[str, ...]
    colour: tuple[int, ...]
    alpha: int | None
    layers: tuple[tuple[str, int], ...]

    @property
    def channels(self) -> int:
        return len(self.names)

    def layer_names(self) -> list[str]:
        return [name for name, _ in self.layers]

    def check(self, image: Any) -> np.ndarray:
        """``image`` as float32 numpy (H, W, C); ValueError unless C is :attr:`channels`."""
        pixels = np.asarray(image, dtype=np.float32)
        if pixels.ndim == 2:
            pixels = pixels[..., None]
        if pixels.ndim != 3 or pixels.shape[2] != self.channels:
            raise ValueError(f"image: the film and the integrator name {self.channels} channels "
                             f"({', '.join(self.names)}), the render has shape {tuple(pixels.shape)}")
        return pixels

    def split(self, image: Any) -> SplitImage:
        """Cut ``image`` into colour (H, W, 1|3), alpha (H, W) and AOV layers (name -> (H, W)).

        Examples
        --------
        >>> layout = layout_from_names(3, False, ["sample_count"])
        >>> parts = layout.split(np.arange(8, dtype=np.float32).reshape(1, 2, 4))
        >>> parts.colour.shape, parts.alpha, parts.layers["sample_count"].tolist()
        ((1, 2, 3), None, [[3.0, 7.0]])
        """
        pixels = self.check(image)
        colour = pixels[..., list(self.colour)] if self.colour else None
        alpha = pixels[..., self.alpha] if self.alpha is not None else None
        return SplitImage(colour, alpha, {name: pixels[..., index] for name, index in self.layers})

    def with_colour_alpha(self, image: Any) -> np.ndarray | None:
        """The colour with alpha appended when there is one ((H, W, 1|2|3|4)); None without colour."""
        parts = self.split(image)
        if parts.colour is None:
            return None
        if parts.alpha is None:
            return parts.colour
        return np.concatenate([parts.colour, parts.alpha[..., None]], axis=2)


def layout_from_names(base: int, aov_integrator: bool, aov_names) -> ChannelLayout:
    """The layout for a film of ``base`` base channels (colour + alpha) and an integrator's AOV names.

    ``aov_integrator``: the integrator is Mitsuba's ``aov`` (see the module's description).

    Examples
    --------
    >>> layout_from_names(3, True, ["inner.R", "inner.G", "inner.B", "inner.A", "dd.y.T"]).names
    ('inner.R', 'inner.G', 'inner.B', 'dd.y.T')
    >>> layout = layout_from_names(4, True, ["dd.y.T", "nn.X", "nn.Y", "nn.Z"])
    >>> layout.colour, layout.alpha, layout.layer_names()
    ((), None, ['dd.y.T', 'nn.X', 'nn.Y', 'nn.Z'])
    """
    aov_names = [str(name) for name in aov_names]
    base_names = BASE_NAMES.get(int(base))
    if base_names is None:  # a film whose base channels are not Y/YA/RGB/RGBA: all of them are layers
        base_names = tuple(f"channel{k}" for k in range(int(base)))
    colour_count = {1: 1, 2: 1, 3: 3, 4: 3}.get(int(base), 0)
    if not aov_integrator:
        names = list(base_names) + aov_names
        colour = tuple(range(colour_count))
        alpha = colour_count if len(base_names) > colour_count and colour_count else None
    else:
        names, colour, alpha = [], (), None
        k = 0
        while k < len(aov_names):
            prefix = aov_names[k][:-2]
            if aov_names[k].endswith(".R") and aov_names[k:k + 4] == [f"{prefix}.{c}" for c in "RGBA"]:
                start = len(names)
                names += [f"{prefix}.{c}" for c in base_names]
                if not colour and colour_count:  # the first nested integrator: the render's colour
                    colour = tuple(range(start, start + colour_count))
                    alpha = start + colour_count if len(base_names) > colour_count else None
                k += 4
            else:
                names.append(aov_names[k])
                k += 1
    used = set(colour) | ({alpha} if alpha is not None else set())
    layers = tuple((name, index) for index, name in enumerate(names) if index not in used)
    return ChannelLayout(tuple(names), colour, alpha, layers)


def channel_layout(scene, sensor: int = 0) -> ChannelLayout:
    """The :class:`ChannelLayout` of ``scene``'s renders (its film and integrator).

    ValueError when two channels would share a name (an AOV named like a colour channel), and for
    a film whose pixel format is CIE XYZ (``xyz``, ``xyza``: not a colour this project writes).
    """
    film = scene.sensors()[sensor].film()
    described = str(film)
    if re.search(r"pixel_format = xyza?\b", described):
        raise ValueError("scene: the film's pixel_format is xyz/xyza: its channels are CIE XYZ, which would be "
                         "written and previewed as RGB; use rgb, rgba, luminance or luminance_alpha")
    integrator = scene.integrator()
    is_aov = integrator.class_name() == _AOV_CLASS if hasattr(integrator, "class_name") else False
    layout = layout_from_names(int(film.base_channels_count()), is_aov, integrator.aov_names())
    seen: set[str] = set()
    for name in layout.names:
        if name in seen:
            raise ValueError(f"scene: two channels of the render are both named {name!r}")
        seen.add(name)
    return layout
