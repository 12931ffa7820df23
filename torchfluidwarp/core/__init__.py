"""The fluid itself: coordinates, spectral solves, linear algebra, the Stable Fluids steps and the simulator.

Nothing here knows about images, forces' parameters or fits; every layer above builds on it.

* :mod:`~torchfluidwarp.core.grid`: the one coordinate module (pixels <-> fluid cells <-> ``grid_sample``'s
  normalised coordinates; ``(x, y)`` order, pixel centres at integers);
* :mod:`~torchfluidwarp.core.sampling`: the one guarded ``grid_sample``;
* :mod:`~torchfluidwarp.core.spectral`: DCT/DST transforms and the exact Poisson/Helmholtz solves;
* :mod:`~torchfluidwarp.core.linalg`: conjugate gradients and the implicit adjoint;
* :mod:`~torchfluidwarp.core.spline`: thin-plate splines (the morph's straight paths);
* :mod:`~torchfluidwarp.core.staggered`: :class:`StaggeredGrid`, the one owner of the staggered layout, its
  constants and the unchecked point kernels (velocity at points, back-trace, carry), points ``(B, N, 2)``;
* :mod:`~torchfluidwarp.core.fused`: Triton kernels for the back-trace and the velocity's self-advection on
  CUDA, with hand-written adjoints (:class:`StaggeredGrid` dispatches to them; the torch path is the reference);
* :mod:`~torchfluidwarp.core.advection`: the checked semi-Lagrangian functions (advect, advect_points, ...);
* :mod:`~torchfluidwarp.core.fluid`: the pure step functions (diffuse, project, the grid operators);
* :mod:`~torchfluidwarp.core.simulator`: the steps as ``nn.Module`` s and :class:`FluidSimulator`.
"""

from torchfluidwarp.core.grid import (
    FluidGrid,
    SquareCells,
    cell_centres,
    cell_scale,
    cell_to_pixel,
    inside_picture,
    interior_mask,
    mean_pixels_per_cell,
    normalized_affine,
    normalized_to_pixel,
    pixel_to_cell,
    pixel_to_normalized,
    rescale_points,
    scale_factor,
)
from torchfluidwarp.core.linalg import (
    CGConfig,
    CGInfo,
    ConvergenceError,
    ConvergenceWarning,
    conjugate_gradient,
    implicit_solve,
)
from torchfluidwarp.core.sampling import SampleMode, sample
from torchfluidwarp.core.simulator import (
    AddForce,
    Advect,
    Diffuse,
    FluidRollout,
    FluidSimulator,
    Project,
    StableFluidsStep,
)
from torchfluidwarp.core.staggered import StaggeredGrid

__all__ = [
    "FluidGrid",
    "SquareCells",
    "cell_centres",
    "cell_scale",
    "cell_to_pixel",
    "inside_picture",
    "interior_mask",
    "mean_pixels_per_cell",
    "normalized_affine",
    "normalized_to_pixel",
    "pixel_to_cell",
    "pixel_to_normalized",
    "rescale_points",
    "scale_factor",
    "CGConfig",
    "CGInfo",
    "ConvergenceError",
    "ConvergenceWarning",
    "conjugate_gradient",
    "implicit_solve",
    "SampleMode",
    "sample",
    "AddForce",
    "Advect",
    "Diffuse",
    "FluidRollout",
    "FluidSimulator",
    "Project",
    "StableFluidsStep",
    "StaggeredGrid",
]
