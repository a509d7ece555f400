"""The volume readers, one module per format.

A module here reads one format into a :class:`~pointillist.imaging.volumes.Volume` and ends with
``register(VolumeReader(...))`` (:mod:`pointillist.imaging.volumes`); importing this package
imports every module in it, so a new format is one new module (and its tests): :func:`load_volume`
(:func:`~pointillist.imaging.volumes.load_volume`), its error message for an unknown suffix, the
format table of :mod:`pointillist.imaging.volumes` and ``pointillist mip -h`` list it from the
registry.
"""

import importlib
import pkgutil

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")
