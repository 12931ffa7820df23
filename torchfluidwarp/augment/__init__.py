"""Random fluid warps for data augmentation.

* :mod:`~torchfluidwarp.augment.settings`: :class:`FluidWarpSettings`, the one validated set of settings that
  every entry point below takes (by keyword, or ready-made as ``settings=``);
* :mod:`~torchfluidwarp.augment.draw`: :func:`draw_fluid_warp`, random brushes rolled out for a batch and
  redrawn at half force until no map folds, giving a :class:`FluidWarpParams`;
* :mod:`~torchfluidwarp.augment.carry`: :func:`apply_fluid_warp` and its parts, which move images, masks,
  keypoints and boxes through one draw;
* :mod:`~torchfluidwarp.augment.tensor`: the tensor-level :class:`FluidWarpAugment` (an ``nn.Module``) and
  :func:`random_fluid_warp`;
* :mod:`~torchfluidwarp.augment.transforms`: :class:`~torchfluidwarp.augment.transforms.RandomFluidWarp`, the
  torchvision v2 transform over ``tv_tensors`` (the only module that imports torchvision: imported on first
  access, as ``torchfluidwarp.augment.RandomFluidWarp`` or ``torchfluidwarp.RandomFluidWarp``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from torchfluidwarp.augment.carry import (
    apply_fluid_warp,
    box_outline,
    carry_boxes,
    carry_points,
    fluid_warp_map,
    polygon_outline,
)
from torchfluidwarp.augment.draw import (
    MIN_DET,
    FluidWarpParams,
    brush_forces,
    draw_fluid_warp,
    min_quad_determinant,
    raster_map,
)
from torchfluidwarp.augment.settings import MAX_SHEAR, FluidWarpSettings
from torchfluidwarp.augment.tensor import FluidWarpAugment, random_fluid_warp

if TYPE_CHECKING:  # imported on first access (PEP 562): torchvision is needed only then
    from torchfluidwarp.augment.transforms import RandomFluidWarp

__all__ = [
    "MAX_SHEAR",
    "MIN_DET",
    "FluidWarpAugment",
    "FluidWarpParams",
    "FluidWarpSettings",
    "RandomFluidWarp",
    "apply_fluid_warp",
    "box_outline",
    "brush_forces",
    "carry_boxes",
    "carry_points",
    "draw_fluid_warp",
    "fluid_warp_map",
    "min_quad_determinant",
    "polygon_outline",
    "random_fluid_warp",
    "raster_map",
]


def __getattr__(name: str) -> Any:
    if name == "RandomFluidWarp":  # the torchvision transform: its module imports torchvision
        return importlib.import_module("torchfluidwarp.augment.transforms").RandomFluidWarp
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
