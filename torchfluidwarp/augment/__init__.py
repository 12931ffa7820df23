"""Random fluid warps for data augmentation.

* :mod:`~torchfluidwarp.augment.tensor`: the tensor-level :class:`FluidWarpAugment` (an ``nn.Module``) and
  :func:`random_fluid_warp`, carrying keypoints, boxes and masks exactly;
* :mod:`~torchfluidwarp.augment.transforms`: :class:`~torchfluidwarp.augment.transforms.RandomFluidWarp`, the
  torchvision v2 transform over ``tv_tensors`` (the only module that imports torchvision; reach it as
  ``torchfluidwarp.RandomFluidWarp``).
"""

from __future__ import annotations

import warnings
from typing import Any

from torchfluidwarp.augment.tensor import (
    MAX_SHEAR,
    MIN_DET,
    FluidWarpAugment,
    FluidWarpParams,
    apply_fluid_warp,
    box_outline,
    brush_forces,
    carry_boxes,
    carry_points,
    fluid_warp_map,
    min_quad_determinant,
    polygon_outline,
    random_fluid_warp,
    raster_map,
)

__all__ = [
    "MAX_SHEAR",
    "MIN_DET",
    "FluidWarpAugment",
    "FluidWarpParams",
    "apply_fluid_warp",
    "box_outline",
    "brush_forces",
    "carry_boxes",
    "carry_points",
    "fluid_warp_map",
    "min_quad_determinant",
    "polygon_outline",
    "random_fluid_warp",
    "raster_map",
]


def __getattr__(name: str) -> Any:
    # Deprecated names, kept for one release. Nothing here imports torchvision: the old lazy alias of the v2
    # transform resolves through the package's lazy top level.
    if name == "RandomFluidWarp":
        warnings.warn(
            "torchfluidwarp.augment.RandomFluidWarp (the tensor-level nn.Module) is renamed "
            "torchfluidwarp.augment.FluidWarpAugment (function: torchfluidwarp.augment.random_fluid_warp); "
            "torchfluidwarp.RandomFluidWarp is now the torchvision v2 transform. The old name goes in the next release",
            DeprecationWarning,
            stacklevel=2,
        )
        return FluidWarpAugment
    if name == "RandomFluidWarpV2":
        warnings.warn(
            "torchfluidwarp.augment.RandomFluidWarpV2 is deprecated: import the torchvision v2 transform as "
            "torchfluidwarp.RandomFluidWarp (or from torchfluidwarp.augment.transforms); the old name goes in the "
            "next release",
            DeprecationWarning,
            stacklevel=2,
        )
        import torchfluidwarp

        return torchfluidwarp.RandomFluidWarp
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
