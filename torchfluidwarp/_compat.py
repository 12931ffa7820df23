"""The module paths of the flat layout (0.x), kept for one release.

The package was flat until the subpackages ``core``, ``warp``, ``control``, ``morph``, ``augment`` and ``apps``
(see ``docs/design.rst``). ``import torchfluidwarp.grid`` and ``from torchfluidwarp.fluid import advect`` still
work: each old path is a stand-in module whose attributes resolve, on first use, from the new module, with a
``DeprecationWarning`` naming it. ``torchfluidwarp.control``, ``.warp``, ``.morph`` and ``.augment`` were modules
and are now subpackages that re-export the same names, so they need no stand-in.
"""

from __future__ import annotations

import importlib
import sys
import types
import warnings
from typing import Any

MOVED_MODULES = {
    "torchfluidwarp.grid": "torchfluidwarp.core.grid",
    "torchfluidwarp.spectral": "torchfluidwarp.core.spectral",
    "torchfluidwarp.linalg": "torchfluidwarp.core.linalg",
    "torchfluidwarp.fluid": "torchfluidwarp.core.fluid",
    "torchfluidwarp.simulator": "torchfluidwarp.core.simulator",
    "torchfluidwarp.sampling": "torchfluidwarp.core.sampling",
    "torchfluidwarp.spline": "torchfluidwarp.core.spline",
    "torchfluidwarp.forces": "torchfluidwarp.warp.forces",
    "torchfluidwarp.optim": "torchfluidwarp.control.optim",
    "torchfluidwarp.registration": "torchfluidwarp.control.images",
    "torchfluidwarp.alignment": "torchfluidwarp.control.alignment",
    "torchfluidwarp.augment_tv": "torchfluidwarp.augment.transforms",
    "torchfluidwarp.animate_config": "torchfluidwarp.apps.animate",
    "torchfluidwarp.cli": "torchfluidwarp.apps.cli",
    "torchfluidwarp.studio": "torchfluidwarp.apps.studio",
}


class _MovedModule(types.ModuleType):
    """A stand-in for a module that moved: attribute lookups warn once per name and forward."""

    def __init__(self, old: str, new: str) -> None:
        super().__init__(old, f"Deprecated: moved to :mod:`{new}`; this path goes in the next release.")
        self._new = new

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        value = getattr(importlib.import_module(self._new), name)
        warnings.warn(
            f"{self.__name__} moved to {self._new}: use `from {self._new} import {name}`. "
            f"The old path goes in the next release.",
            DeprecationWarning,
            stacklevel=2,
        )
        return value

    def __dir__(self) -> list[str]:
        return dir(importlib.import_module(self._new))


def install() -> None:
    """Register the stand-ins in ``sys.modules`` (idempotent; the new modules are imported only on use)."""
    for old, new in MOVED_MODULES.items():
        if old not in sys.modules:
            sys.modules[old] = _MovedModule(old, new)
