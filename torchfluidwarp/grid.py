"""The fluid grid and the conversions between pixel and fluid-cell coordinates.

Conventions (the one place they are defined):

* Points are ``(x, y)``: channel/last index 0 is x (to the right), 1 is y (down).
* **Pixel coordinates**: pixel centres at integers, so an image of size ``(H, W)`` covers
  ``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` (OpenCV, and kornia/PyTorch with ``align_corners=False``).
* **Fluid-cell coordinates**: the same rule on the fluid grid ``(h, w)``: cell centres at integers,
  the box is ``[-0.5, w - 0.5] x [-0.5, h - 0.5]``. Fluid and image cover the same rectangle, whatever
  their resolutions, so ``x_cell = (x_pixel + 0.5) * w / W - 0.5``.
* **Staggered (MAC) velocity**: a tensor ``(B, 2, h + 1, w + 1)``. Channel 0 holds ``u`` (x-velocity)
  on the vertical faces: ``vel[:, 0, i, j]`` for ``i < h``, ``j <= w`` sits at ``(x, y) = (j - 1/2, i)``.
  Channel 1 holds ``v`` on the horizontal faces: ``vel[:, 1, i, j]`` for ``i <= h``, ``j < w`` sits at
  ``(j, i - 1/2)``. The wall faces (``j = 0, w`` for ``u``; ``i = 0, h`` for ``v``) and the unused padding
  (row ``h`` of ``u``, column ``w`` of ``v``) are always zero. Velocities are in fluid cells per time unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from torchfluidwarp._checks import check_size, check_tensor

__all__ = ["FluidGrid", "pixel_to_cell", "cell_to_pixel", "interior_mask"]


@dataclass(frozen=True)
class FluidGrid:
    """A rectangle of ``height x width`` fluid cells with solid walls.

    Args:
        height: number of cell rows ``h`` (at least 2).
        width: number of cell columns ``w`` (at least 2).

    Example:
        >>> FluidGrid.of((32, 48)).staggered_shape
        (33, 49)
    """

    height: int
    width: int

    def __post_init__(self) -> None:
        check_size("grid", (self.height, self.width), minimum=2)

    @classmethod
    def of(cls, grid: FluidGrid | int | tuple[int, int]) -> FluidGrid:
        """Build a grid from ``(h, w)``, an int (square), or return a grid unchanged."""
        if isinstance(grid, FluidGrid):
            return grid
        h, w = check_size("grid", grid, minimum=2)
        return cls(h, w)

    @property
    def shape(self) -> tuple[int, int]:
        """``(h, w)``: the shape of a cell-centred field."""
        return (self.height, self.width)

    @property
    def staggered_shape(self) -> tuple[int, int]:
        """``(h + 1, w + 1)``: the spatial shape of a staggered velocity."""
        return (self.height + 1, self.width + 1)


def interior_mask(grid: FluidGrid, *, device: torch.device | None = None, dtype: torch.dtype = torch.float32) -> Tensor:
    """Mask ``(1, 2, h + 1, w + 1)`` that is 1 on the free (interior) faces of a staggered velocity, else 0."""
    h, w = grid.shape
    mask = torch.zeros(1, 2, h + 1, w + 1, device=device, dtype=dtype)
    mask[0, 0, :h, 1:w] = 1
    mask[0, 1, 1:h, :w] = 1
    return mask


def _scale(image_size: tuple[int, int], grid: FluidGrid, points: Tensor) -> Tensor:
    h, w = grid.shape
    H, W = image_size
    return torch.tensor([w / W, h / H], device=points.device, dtype=points.dtype)


def pixel_to_cell(points: Tensor, image_size: tuple[int, int], grid: FluidGrid | tuple[int, int]) -> Tensor:
    """Convert ``(..., 2)`` points from pixel to fluid-cell coordinates.

    Args:
        points: ``(..., 2)`` ``(x, y)`` in pixels of an image of size ``image_size = (H, W)``.
        image_size: ``(H, W)`` of the image.
        grid: the fluid grid ``(h, w)``.

    Returns:
        ``(..., 2)`` ``(x, y)`` in fluid cells.

    Example:
        >>> pixel_to_cell(torch.tensor([[-0.5, -0.5], [599.5, 599.5]]), (600, 600), (64, 64))
        tensor([[-0.5000, -0.5000],
                [63.5000, 63.5000]])
    """
    check_tensor("points", points, shape=[*([None] * (points.ndim - 1)), 2])
    grid = FluidGrid.of(grid)
    return (points + 0.5) * _scale(check_size("image_size", image_size), grid, points) - 0.5


def cell_to_pixel(points: Tensor, image_size: tuple[int, int], grid: FluidGrid | tuple[int, int]) -> Tensor:
    """Convert ``(..., 2)`` points from fluid-cell to pixel coordinates (inverse of :func:`pixel_to_cell`)."""
    check_tensor("points", points, shape=[*([None] * (points.ndim - 1)), 2])
    grid = FluidGrid.of(grid)
    return (points + 0.5) / _scale(check_size("image_size", image_size), grid, points) - 0.5
