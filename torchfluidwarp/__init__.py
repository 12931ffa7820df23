"""torchfluidwarp: warp and morph images with a differentiable 2-D incompressible fluid.

The public API, by layer (each module's docstring states its shapes and units):

* fluid core: :class:`FluidSimulator`, :class:`StableFluidsStep`, the functions ``advect``, ``diffuse``,
  ``project``, ``divergence`` and the linear-solve settings :class:`CGConfig`.
"""

from torchfluidwarp._version import __version__
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
from torchfluidwarp.grid import FluidGrid, cell_to_pixel, pixel_to_cell
from torchfluidwarp.linalg import CGConfig, ConvergenceError, ConvergenceWarning, implicit_solve
from torchfluidwarp.simulator import FluidRollout, FluidSimulator, StableFluidsStep

__all__ = [
    "__version__",
    "FluidGrid", "pixel_to_cell", "cell_to_pixel",
    "CGConfig", "ConvergenceWarning", "ConvergenceError", "implicit_solve",
    "advect", "advect_velocity", "advect_points", "sample_velocity", "diffuse", "project", "divergence",
    "faces_from_cells", "cells_from_faces",
    "FluidSimulator", "FluidRollout", "StableFluidsStep",
]
