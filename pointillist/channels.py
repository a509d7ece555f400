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
  render. Without a nested integrator the render has no colour at all (only AOVs). Mitsuba
  3.9 then repeats the names after the nested images (all but their ``R G B A``), computed
  again by its own film: those copies are left out.

:func:`channel_layout` reads this from a loaded scene into a :class:`ChannelLayout`, whose
:meth:`ChannelLayout.split` cuts an image into ``colour`` (H, W, 1 or 3, or None), ``alpha``
(H, W or None) and ``layers`` (name -> (H, W)); :meth:`ChannelLayout.kept` names what a file
of the render holds, in order, and :meth:`ChannelLayout.pick` takes those channels out of a
Dr.Jit tensor without numpy. ``render``, progressive rendering, ``compare`` and tiled renders all
go through it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
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

    def kept(self) -> list[tuple[str, int]]:
        """The channels a file of the render holds, as (name, index in the render): the colour
        (``Y`` or ``R G B``) and alpha (``A``) under their standard names, then every layer.

        Examples
        --------
        >>> layout_from_names(4, False, ["sample_count"]).kept()
        [('R', 0), ('G', 1), ('B', 2), ('A', 3), ('sample_count', 4)]
        """
        colour = BASE_NAMES[len(self.colour)] if self.colour else ()
        named = list(zip(colour, self.colour))
        if self.alpha is not None:
            named.append(("A", self.alpha))
        return named + list(self.layers)

    def _check_shape(self, shape: tuple[int, ...]) -> None:
        if len(shape) != 3 or shape[2] != self.channels:
            raise ValueError(f"image: the film and the integrator name {self.channels} channels "
                             f"({', '.join(self.names)}), the render has shape {tuple(shape)}")

    def check(self, image: Any) -> np.ndarray:
        """``image`` as float32 numpy (H, W, C); ValueError unless C is :attr:`channels`."""
        import numpy as np

        pixels = np.asarray(image, dtype=np.float32)
        if pixels.ndim == 2:
            pixels = pixels[..., None]
        self._check_shape(pixels.shape)
        return pixels

    def pick(self, image: Any, indices) -> Any:
        """Channels ``indices`` of the render ``image`` (H, W, C), in that order, as an (H, W, K)
        image of the same kind: a Dr.Jit tensor (one gather, no numpy) or a numpy array.
        ValueError unless C is :attr:`channels`.

        Examples
        --------
        >>> import drjit as dr
        >>> from drjit.llvm import TensorXf
        >>> layout = layout_from_names(3, False, ["sample_count"])
        >>> image = TensorXf(dr.arange(dr.llvm.Float, 8), shape=(1, 2, 4))
        >>> layout.pick(image, [3, 0]).numpy().tolist()
        [[[3.0, 0.0], [7.0, 4.0]]]
        """
        indices = [int(i) for i in indices]
        shape = tuple(int(n) for n in image.shape)
        if len(shape) == 2:
            shape = (*shape, 1)
        self._check_shape(shape)
        if not hasattr(image, "array"):                      # numpy (or anything numpy takes)
            return self.check(image)[..., indices]
        if indices == list(range(shape[2])):
            return image
        import drjit as dr

        flat = image.array
        height, width, channels = shape
        count = len(indices)
        index_type = dr.uint32_array_t(type(flat))
        slot = dr.arange(index_type, height * width * count)
        table = index_type(indices)
        source = (slot // count) * channels + dr.gather(index_type, table, slot % count)
        return type(image)(dr.gather(type(flat), flat, source), shape=(height, width, count))

    def split(self, image: Any) -> SplitImage:
        """Cut ``image`` into colour (H, W, 1|3), alpha (H, W) and AOV layers (name -> (H, W)).

        Examples
        --------
        >>> layout = layout_from_names(3, False, ["sample_count"])
        >>> import numpy as np
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
        import numpy as np

        return np.concatenate([parts.colour, parts.alpha[..., None]], axis=2)


def layout_from_names(base: int, aov_integrator: bool, aov_names) -> ChannelLayout:
    """The layout for a film of ``base`` base channels (colour + alpha) and an integrator's AOV names.

    ``aov_integrator``: the integrator is Mitsuba's ``aov`` (see the module's description). Its
    render repeats the AOVs of the integrators nested in it (once in their own image, once after
    it, where Mitsuba computes them anew: an ``adaptive`` integrator's sample count is 1 there);
    the first copy is the layer, the others are left out.

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
    if aov_integrator:
        names, leading = _aov_channels(base_names, aov_names)
    else:
        names, leading = list(base_names) + aov_names, True
    colour = tuple(range(colour_count)) if leading else ()
    alpha = colour_count if colour and len(base_names) > colour_count else None
    used, seen, layers = set(colour) | ({alpha} if alpha is not None else set()), set(), []
    for index, name in enumerate(names):
        if index not in used and name not in seen:
            layers.append((name, index))
        seen.add(name)
    return ChannelLayout(tuple(names), colour, alpha, tuple(layers))


def _nested(names: list[str]) -> list[tuple[str, list[str]]]:
    """The integrators nested in an ``aov`` integrator, from its AOV names: ``[(name, its AOV
    names)]``. Each is listed as ``name.R name.G name.B name.A`` and then ``name.<its AOVs>``,
    all of them before the ``aov`` integrator's own AOVs."""
    nested, k = [], 0
    while k < len(names):
        prefix = names[k][:-2]
        if not (names[k].endswith(".R") and names[k:k + 4] == [f"{prefix}.{c}" for c in "RGBA"]):
            break
        k += 4
        children = []
        while k < len(names) and names[k].startswith(prefix + "."):
            children.append(names[k][len(prefix) + 1:])
            k += 1
        nested.append((prefix, children))
    return nested


def _aov_channels(base_names: tuple[str, ...], names: list[str]) -> tuple[list[str], bool]:
    """The channels of an ``aov`` integrator's render, and whether they start with a colour.

    Mitsuba 3.9 renders each nested integrator (its base channels and AOVs; a nested ``aov``
    integrator: its own channels, recursively), then its own film with every name of
    ``aov_names()`` but the nested integrators' ``R G B A``."""
    nested = _nested(names)
    channels: list[str] = []
    leading = None
    for prefix, children in nested:
        if _nested(children):
            inner, starts_with_colour = _aov_channels(base_names, children)
        else:
            inner, starts_with_colour = list(base_names) + children, True
        channels += [f"{prefix}.{name}" for name in inner]
        leading = starts_with_colour if leading is None else leading
    rgba = {f"{prefix}.{c}" for prefix, _ in nested for c in "RGBA"}
    channels += [name for name in names if name not in rgba]
    return channels, bool(leading)


def channel_layout(scene, sensor: int = 0) -> ChannelLayout:
    """The :class:`ChannelLayout` of ``scene``'s renders (its film and integrator).

    ValueError when an AOV is named like a colour channel (``R``, ``Y``...), and for
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
    kept = [layout.names[i] for i in layout.colour] + layout.layer_names()
    if len(set(kept)) != len(kept) or {"R", "G", "B", "A", "Y"} & set(layout.layer_names()):
        raise ValueError(f"scene: an AOV is named like a colour channel or another AOV ({', '.join(layout.names)})")
    return layout
