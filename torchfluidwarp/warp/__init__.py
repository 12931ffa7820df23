"""Forces in, warped images out: force modules, texture-coordinate maps and the :class:`FluidWarp` layer.

* :mod:`~torchfluidwarp.warp.forces`: force fields over time, ``(B, T, 2, h, w)`` in cells per step²: control
  grids, brushes, viscosity maps;
* :mod:`~torchfluidwarp.warp.landmarks`: the natural morph's landmark forces;
* :mod:`~torchfluidwarp.warp.frames`: reading an image through a map (``warp_image``), the identity map and the
  Jacobian determinant;
* :mod:`~torchfluidwarp.warp.maps`: texture-coordinate maps ``(B, T+1, H, W, 2)``, their working raster and
  its upsample;
* :mod:`~torchfluidwarp.warp.layer`: the differentiable :class:`FluidWarp` layer.
"""

from torchfluidwarp.warp.forces import (
    Brushes,
    CellForces,
    ControlGrid,
    SumForces,
    ViscosityBrushes,
    viscosity_from_mask,
)
from torchfluidwarp.warp.frames import identity_map, jacobian_determinant, warp_image
from torchfluidwarp.warp.landmarks import LandmarkForces
from torchfluidwarp.warp.layer import FluidWarp
from torchfluidwarp.warp.maps import backward_maps, forward_maps, iter_backward_maps, maps_to_end

__all__ = [
    "Brushes",
    "CellForces",
    "ControlGrid",
    "LandmarkForces",
    "SumForces",
    "ViscosityBrushes",
    "viscosity_from_mask",
    "FluidWarp",
    "backward_maps",
    "forward_maps",
    "identity_map",
    "iter_backward_maps",
    "jacobian_determinant",
    "maps_to_end",
    "warp_image",
]
