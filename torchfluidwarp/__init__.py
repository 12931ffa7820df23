"""torchfluidwarp: warp and morph images with a differentiable 2-D fluid.

The top level holds what most users need:

* simulate and warp: :class:`FluidSimulator` (its :class:`FluidRollout`), :class:`FluidWarp`, ``warp_image``,
  ``jacobian_determinant``, the grid :class:`FluidGrid` and the solve settings :class:`CGConfig`;
* fit and morph: ``fit_keyframes`` (:class:`KeyframeFit`), ``fit_images`` (:class:`ImageFit`), ``morph``
  (:class:`MorphResult`; its typed settings are in :mod:`torchfluidwarp.morph`, the package that ``morph`` is:
  calling it calls :func:`torchfluidwarp.morph.morphing.morph`);
* augment: :class:`RandomFluidWarp`, the torchvision v2 transform (imported on first access: torchvision is
  needed only then); the tensor-level ``nn.Module`` is :class:`torchfluidwarp.augment.FluidWarpAugment`.

Everything else lives in the subpackage of its stage of the pipeline, and imports point one way,
``apps -> morph, augment -> control -> warp -> core``:

* :mod:`torchfluidwarp.core`: coordinates, the guarded sampler, spectral and CG solves, the fluid steps;
* :mod:`torchfluidwarp.warp`: force modules, texture-coordinate maps and the :class:`FluidWarp` layer;
* :mod:`torchfluidwarp.control`: the one L-BFGS driver, ``fit_keyframes``, ``fit_images``, pre-alignment;
* :mod:`torchfluidwarp.morph` and :mod:`torchfluidwarp.augment`: the two clients of the warp layer;
* :mod:`torchfluidwarp.io` (files) and :mod:`torchfluidwarp.data` (bundled samples), used by all;
* :mod:`torchfluidwarp.apps`: the command line and the studio.

Errors say whose fault they are (:mod:`torchfluidwarp.errors`): :class:`~torchfluidwarp.errors.InputError` for a
value the caller passed, :class:`~torchfluidwarp.errors.FlowBlewUp` for forces that make the flow blow up.

Conventions: images ``(B, C, H, W)`` in ``[0, 1]``; points ``(x, y)`` in pixels with pixel centres at
integers (``align_corners=False``); fluid quantities in fluid cells and time steps (:mod:`~torchfluidwarp.core.grid`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from torchfluidwarp._version import __version__
from torchfluidwarp.errors import FlowBlewUp, InputError

if TYPE_CHECKING:  # the names below are imported on first access (PEP 562): see _LAZY
    from torchfluidwarp.augment.transforms import RandomFluidWarp
    from torchfluidwarp.control import ImageFit, KeyframeFit, fit_images, fit_keyframes
    from torchfluidwarp.core import CGConfig, FluidGrid, FluidRollout, FluidSimulator
    from torchfluidwarp.morph import MorphResult, morph
    from torchfluidwarp.warp import FluidWarp, jacobian_determinant, warp_image

__all__ = [
    "__version__",
    "FluidSimulator",
    "FluidRollout",
    "FluidWarp",
    "FluidGrid",
    "CGConfig",
    "warp_image",
    "jacobian_determinant",
    "fit_keyframes",
    "KeyframeFit",
    "fit_images",
    "ImageFit",
    "morph",
    "MorphResult",
    "RandomFluidWarp",
    "InputError",
    "FlowBlewUp",
]

# Each name's home, imported on first access and without a warning: ``import torchfluidwarp`` imports neither
# torch nor torchvision, so a program that only needs the command line's argument checks (or the errors, or
# ``__version__``) starts in a fraction of a second; the first use of a name imports torch with its module.
_LAZY = {
    "FluidSimulator": "torchfluidwarp.core",
    "FluidRollout": "torchfluidwarp.core",
    "FluidGrid": "torchfluidwarp.core",
    "CGConfig": "torchfluidwarp.core",
    "FluidWarp": "torchfluidwarp.warp",
    "warp_image": "torchfluidwarp.warp",
    "jacobian_determinant": "torchfluidwarp.warp",
    "fit_keyframes": "torchfluidwarp.control",
    "KeyframeFit": "torchfluidwarp.control",
    "fit_images": "torchfluidwarp.control",
    "ImageFit": "torchfluidwarp.control",
    "MorphResult": "torchfluidwarp.morph",
    "RandomFluidWarp": "torchfluidwarp.augment.transforms",
}
# the subpackages, so that ``import torchfluidwarp; torchfluidwarp.io.read_image`` works as when they were
# imported eagerly
_SUBPACKAGES = frozenset({"core", "warp", "control", "correspond", "morph", "metrics", "augment", "io", "data", "apps"})


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
    elif name in _SUBPACKAGES:
        value = importlib.import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value  # later lookups skip this hook
    return value


def __dir__() -> list[str]:
    """The public names and the subpackages (not this module's own imports: ``importlib``, ``Any``, ...)."""
    return sorted(set(__all__) | _SUBPACKAGES)
