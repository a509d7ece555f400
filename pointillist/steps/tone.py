"""``pointillist post`` steps for tone and colour (imaging.tone, imaging.colour).

Examples: ``--steps "tonemap:reinhard,exposure=1;gamma:2.2"``,
``--steps "tonemap:aces;equalize;quantize:8"``, ``--steps "stretch:50,20,200,235"``,
``--steps "hsv:hue=30,saturation=1.2;grey"``, ``--steps "lut:curve.txt"``.
"""

from __future__ import annotations

import re

import numpy as np

from pointillist.imaging import colour, tone
from pointillist.core.files import input_file
from pointillist.steps import step


@step("tonemap", params=("operator",), linear=True,
      help="linear HDR -> display 0..255: operator " + "|".join(tone.TONEMAP_OPERATORS)
           + " (default clip), exposure=STOPS, white=W (reinhard, reinhard_extended, hable, log)")
def _tonemap(image, operator="clip", exposure=0.0, **params):
    return tone.tonemap(image, operator, exposure, **params)


@step("gamma", params=("gamma", "a"), help="gamma correction V = (I/a)^(1/gamma) on 0..1 (gamma > 1 lightens)")
def _gamma(image, gamma, a=1.0):
    return tone.gamma(image, gamma, a)


@step("stretch", params=("r1", "s1", "r2", "s2"),
      help="piecewise-linear contrast stretch through (r1,s1) and (r2,s2), 0 <= r1 <= r2 <= 255")
def _stretch(image, r1, s1, r2, s2):
    return tone.contrast_stretch(image, r1, s1, r2, s2)


@step("equalize", params=("levels",), help="histogram equalisation (colour: on HSV V), levels default 256")
def _equalize(image, levels=256):
    return tone.equalize_histogram(image, levels)


@step("quantize", params=("levels", "mode"),
      help="quantise to N evenly spaced grey levels: mode nearest (the nearest level, default) or bins "
           "(N equal-width bins)")
def _quantize(image, levels, mode="nearest"):
    return tone.quantize(image, levels, mode=mode)


@step("hsv", params=("hue", "saturation", "value"),
      help="RGB only: shift hue by degrees, scale saturation and value (defaults 0,1,1)")
def _hsv(image, hue=0.0, saturation=1.0, value=1.0):
    return colour.adjust_hsv(image, hue=hue, saturation=saturation, value=value, max_value=255.0)


@step("grey", help="Rec. 709 weighted grey (luma of display values); grey input unchanged", takes_bytes=True)
def _grey(image):
    return colour.luminance(image, max_value=255.0)


@step("lut", params=("file",), help="apply a 256-entry table read from a text or .npy file (one value per level)")
def _lut(image, file):
    path = input_file(str(file), "file")
    try:
        table = np.load(path) if path.suffix == ".npy" else np.loadtxt(path, ndmin=1)
    except (OSError, ValueError) as error:
        # name the place, never the text: the file may be one the user may not show (a key, a password file)
        where = re.search(r"at row (\d+)", str(error))
        line = f" (row {int(where.group(1)) + 1} is not a number)" if where else ""
        raise ValueError(f"lut: file: {path} is not a table of numbers{line}") from None
    return tone.lut(image, table)
