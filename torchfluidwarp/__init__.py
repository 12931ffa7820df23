"""torchfluidwarp: warp and morph images with a differentiable 2-D incompressible fluid.

The public API, by layer (each module's docstring states its shapes, units and conventions):

* fluid core (:mod:`~torchfluidwarp.fluid`, :mod:`~torchfluidwarp.simulator`, :mod:`~torchfluidwarp.linalg`):
  :class:`FluidSimulator`, :class:`StableFluidsStep`, ``advect``, ``diffuse``, ``project``, ``divergence``,
  the solve settings :class:`CGConfig`;
* warping (:mod:`~torchfluidwarp.warp`, :mod:`~torchfluidwarp.forces`): the :class:`FluidWarp` layer,
  ``warp_image``, ``jacobian_determinant``, brush and control-grid force modules, viscosity maps;
* control and morphing (:mod:`~torchfluidwarp.control`, :mod:`~torchfluidwarp.morph`): ``fit_keyframes``,
  ``morph``;
* pipelines: :mod:`torchfluidwarp.augment` (``RandomFluidWarp``) and :mod:`torchfluidwarp.registration`
  (``fit_images``);
* files: :mod:`torchfluidwarp.io` and the bundled samples in :mod:`torchfluidwarp.data`.

Conventions: images ``(B, C, H, W)`` in ``[0, 1]``; points ``(x, y)`` in pixels with pixel centres at
integers (``align_corners=False``); fluid quantities in fluid cells and time steps (:mod:`~torchfluidwarp.grid`).
"""

from torchfluidwarp._version import __version__
from torchfluidwarp.alignment import estimate_alignment
from torchfluidwarp.control import KeyframeFit, fit_keyframes, keyframe_loss, velocity_gradient_energy
from torchfluidwarp.fluid import (
    advect,
    advect_points,
    advect_velocity,
    cells_from_faces,
    diffuse,
    divergence,
    faces_from_cells,
    project,
    sample_velocity,
)
from torchfluidwarp.forces import Brushes, CellForces, ControlGrid, SumForces, ViscosityBrushes, viscosity_from_mask
from torchfluidwarp.grid import FluidGrid, cell_to_pixel, pixel_to_cell
from torchfluidwarp.linalg import CGConfig, ConvergenceError, ConvergenceWarning, implicit_solve
from torchfluidwarp.morph import MorphResult, morph
from torchfluidwarp.simulator import FluidRollout, FluidSimulator, StableFluidsStep
from torchfluidwarp.warp import (
    FluidWarp,
    backward_maps,
    forward_maps,
    identity_map,
    jacobian_determinant,
    maps_to_end,
    warp_image,
)

__all__ = [
    "__version__",
    "FluidGrid",
    "pixel_to_cell",
    "cell_to_pixel",
    "CGConfig",
    "ConvergenceWarning",
    "ConvergenceError",
    "implicit_solve",
    "advect",
    "advect_velocity",
    "advect_points",
    "sample_velocity",
    "diffuse",
    "project",
    "divergence",
    "faces_from_cells",
    "cells_from_faces",
    "FluidSimulator",
    "FluidRollout",
    "StableFluidsStep",
    "FluidWarp",
    "warp_image",
    "identity_map",
    "backward_maps",
    "forward_maps",
    "maps_to_end",
    "jacobian_determinant",
    "Brushes",
    "SumForces",
    "ControlGrid",
    "CellForces",
    "ViscosityBrushes",
    "viscosity_from_mask",
    "fit_keyframes",
    "KeyframeFit",
    "keyframe_loss",
    "velocity_gradient_energy",
    "morph",
    "MorphResult",
    "estimate_alignment",
]
