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
  torchvision v2 transform over ``tv_tensors`` (the only module that imports torchvision; reach it as
  ``torchfluidwarp.RandomFluidWarp``).
"""

from __future__ import annotations

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

__all__ = [
    "MAX_SHEAR",
    "MIN_DET",
    "FluidWarpAugment",
    "FluidWarpParams",
    "FluidWarpSettings",
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
