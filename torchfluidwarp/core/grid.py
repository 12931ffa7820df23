"""The fluid grid and the conversions between pixel and fluid-cell coordinates.

Conventions (the one place they are defined):

* Points are ``(x, y)``: channel/last index 0 is x (to the right), 1 is y (down).
* **Pixel coordinates**: pixel centres at integers, so an image of size ``(H, W)`` covers
  ``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` (OpenCV, and kornia/PyTorch with ``align_corners=False``).
* **Fluid-cell coordinates**: the same rule on the fluid grid ``(h, w)``: cell centres at integers,
  the box is ``[-0.5, w - 0.5] x [-0.5, h - 0.5]``. Fluid and image cover the same rectangle, whatever
  their resolutions, so ``x_cell = (x_pixel + 0.5) * w / W - 0.5``.
* **Normalised coordinates** (``grid_sample``'s): the rectangle's outer edges at -1 and +1
  (``align_corners=False``), so ``x_norm = (2 x_pixel + 1) / W - 1``. Samples on nodes that include the
  rectangle's corners use ``align_corners=True`` (the staggered velocity's nodes, see :func:`normalized_affine`).
* **Staggered (MAC) velocity**: a tensor ``(B, 2, h + 1, w + 1)``. Channel 0 holds ``u`` (x-velocity)
  on the vertical faces: ``vel[:, 0, i, j]`` for ``i < h``, ``j <= w`` sits at ``(x, y) = (j - 1/2, i)``.
  Channel 1 holds ``v`` on the horizontal faces: ``vel[:, 1, i, j]`` for ``i <= h``, ``j < w`` sits at
  ``(j, i - 1/2)``. The wall faces (``j = 0, w`` for ``u``; ``i = 0, h`` for ``v``) and the unused padding
  (row ``h`` of ``u``, column ``w`` of ``v``) are always zero. Velocities are in fluid cells per time unit.

Every rescale between pixels, fluid cells and normalised coordinates in the library goes through the functions
below: :func:`scale_factor` and :func:`cell_scale` (per-axis length ratios, tensors on the caller's device),
:func:`rescale_points` (positions between two rasters), :func:`pixel_to_cell` / :func:`cell_to_pixel`,
:func:`cell_centres` (cell centres in pixels), :func:`normalized_affine` (the ``grid_sample`` affine) and
:func:`pixel_to_normalized` / :func:`normalized_to_pixel`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from torchfluidwarp._checks import check_int, check_size, check_tensor

__all__ = [
    "FluidGrid",
    "SquareCells",
    "interior_mask",
    "inside_picture",
    "scale_factor",
    "cell_scale",
    "mean_pixels_per_cell",
    "rescale_points",
    "pixel_to_cell",
    "cell_to_pixel",
    "cell_centres",
    "normalized_affine",
    "pixel_to_normalized",
    "normalized_to_pixel",
]


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


@dataclass(frozen=True)
class SquareCells:
    """About ``count`` fluid cells, square, over whatever rectangle the fluid covers: a grid that follows its box's
    aspect ratio (:meth:`over`), where a :class:`FluidGrid` of as many rows as columns stretches its cells.

    Args:
        count: the number of cells (at least 4).

    Example:
        >>> SquareCells(6400).over((512, 512)).shape, SquareCells(6400).over((400, 900)).shape
        ((80, 80), (53, 120))
    """

    count: int

    def __post_init__(self) -> None:
        check_int("SquareCells.count", self.count, minimum=4)

    def over(self, size: tuple[int, int]) -> FluidGrid:
        """The grid over a rectangle of ``size`` ``(H, W)`` (pixels, or any one unit): ``h = sqrt(count H / W)``
        rows and ``w = sqrt(count W / H)`` columns, rounded, at least 2 each."""
        H, W = check_size("size", size, minimum=1)
        return FluidGrid(max(2, round(math.sqrt(self.count * H / W))), max(2, round(math.sqrt(self.count * W / H))))


def interior_mask(grid: FluidGrid, *, device: torch.device | None = None, dtype: torch.dtype = torch.float32) -> Tensor:
    """Mask ``(1, 2, h + 1, w + 1)`` that is 1 on the free (interior) faces of a staggered velocity, else 0."""
    h, w = grid.shape
    mask = torch.zeros(1, 2, h + 1, w + 1, device=device, dtype=dtype)
    mask[0, 0, :h, 1:w] = 1
    mask[0, 1, 1:h, :w] = 1
    return mask


def scale_factor(
    source: tuple[int, int],
    target: tuple[int, int],
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Per-axis length ratio between two rasters over the same rectangle: ``(W_t / W_s, H_t / H_s)``.

    A length (a displacement, a velocity, an acceleration) measured in the units of ``source`` times this is
    the same length in the units of ``target``; :func:`rescale_points` turns it into the map between positions.
    ``scale_factor(image_size, grid.shape)`` is the fluid cells per pixel (:func:`cell_scale`).

    Args:
        source: ``(H_s, W_s)`` the raster the lengths are measured in (pixels of an image, fluid cells).
        target: ``(H_t, W_t)`` the raster to measure them in.
        device, dtype: of the result.

    Returns:
        ``(2,)`` ``(x, y)`` target units per source unit.

    Example:
        >>> scale_factor((600, 400), (64, 32))
        tensor([0.0800, 0.1067])
    """
    Hs, Ws = source
    Ht, Wt = target
    return torch.tensor([Wt / Ws, Ht / Hs], device=device, dtype=dtype)


def cell_scale(
    image_size: tuple[int, int],
    grid: FluidGrid | int | tuple[int, int],
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Fluid cells per pixel along each axis: ``(w / W, h / H)`` ``(2,)``.

    Lengths in pixels (displacements, brush accelerations) times this are lengths in cells; divide to go back.

    Example:
        >>> cell_scale((600, 300), (60, 60))
        tensor([0.2000, 0.1000])
    """
    return scale_factor(image_size, FluidGrid.of(grid).shape, device=device, dtype=dtype)


def inside_picture(points: Tensor, size: tuple[int, int]) -> Tensor:
    """``(...)`` bool: which of ``points`` ``(..., 2)`` (pixels, ``(x, y)``) lie on a picture of ``size``
    ``(H, W)``, edges included: ``x`` in ``[-0.5, W - 0.5]`` and ``y`` in ``[-0.5, H - 0.5]``.

    Example:
        >>> inside_picture(torch.tensor([[-0.5, 0.0], [10.0, 3.0], [3.0, 19.6]]), (20, 10))
        tensor([ True, False, False])
    """
    H, W = size
    x, y = points[..., 0], points[..., 1]
    return (x >= -0.5) & (x <= W - 0.5) & (y >= -0.5) & (y <= H - 0.5)


def mean_pixels_per_cell(image_size: tuple[int, int], grid: FluidGrid | int | tuple[int, int]) -> float:
    """The mean of the two axes' pixels per fluid cell, ``(H / h + W / w) / 2``: one length scale for both axes.

    Example:
        >>> mean_pixels_per_cell((600, 300), (60, 60))
        7.5
    """
    h, w = FluidGrid.of(grid).shape
    H, W = image_size
    return 0.5 * (H / h + W / w)


def rescale_points(points: Tensor, scale: Tensor | float, *, inverse: bool = False) -> Tensor:
    """Move positions between two rasters over the same rectangle, keeping sample centres at integers.

    ``x' = (x + 0.5) * s - 0.5`` (``inverse``: ``(x + 0.5) / s - 0.5``), so the rectangle's edges ``-0.5`` and
    ``W - 0.5`` map onto ``-0.5`` and ``W' - 0.5``. No argument checks: internal hot paths call it per step.

    Args:
        points: positions, with ``(x, y)`` along whichever dimension ``scale`` broadcasts over: ``(..., 2)``
            with a ``(2,)`` scale, or channel-first ``(B, 2, N)`` with a ``(1, 2, 1)`` scale.
        scale: :func:`scale_factor` from the points' raster to the new one (a float for one axis at a time).
        inverse: divide by ``scale`` instead (from the new raster back to the points' own).

    Returns:
        The positions in the new raster's units, the shape of ``points``.

    Example:
        >>> rescale_points(torch.tensor([[-0.5, 0.0], [599.5, 7.0]]), scale_factor((600, 600), (64, 64)))
        tensor([[-0.5000, -0.4467],
                [63.5000,  0.3000]])
    """
    return (points + 0.5) / scale - 0.5 if inverse else (points + 0.5) * scale - 0.5


def cell_centres(
    grid: FluidGrid | int | tuple[int, int],
    image_size: tuple[int, int],
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """The fluid cell centres in the image's pixels: ``(h, w, 2)`` ``(x, y)``.

    Cell ``(i, j)`` sits at ``((j + 0.5) W / w - 0.5, (i + 0.5) H / h - 0.5)``: the centre of the pixels it
    averages (:func:`torch.nn.functional.interpolate` with ``mode="area"`` when ``W / w`` is an integer).

    Example:
        >>> cell_centres((2, 2), (4, 4))[0].tolist()
        [[0.5, 0.5], [2.5, 0.5]]
    """
    h, w = FluidGrid.of(grid).shape
    H, W = image_size
    ys = rescale_points(torch.arange(h, device=device, dtype=dtype), H / h)
    xs = rescale_points(torch.arange(w, device=device, dtype=dtype), W / w)
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([gx, gy], dim=-1)


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
    scale = cell_scale(check_size("image_size", image_size), grid, device=points.device, dtype=points.dtype)
    return rescale_points(points, scale)


def cell_to_pixel(points: Tensor, image_size: tuple[int, int], grid: FluidGrid | tuple[int, int]) -> Tensor:
    """Convert ``(..., 2)`` points from fluid-cell to pixel coordinates (inverse of :func:`pixel_to_cell`)."""
    check_tensor("points", points, shape=[*([None] * (points.ndim - 1)), 2])
    scale = cell_scale(check_size("image_size", image_size), grid, device=points.device, dtype=points.dtype)
    return rescale_points(points, scale, inverse=True)


def normalized_affine(
    size: tuple[int, int],
    *,
    align_corners: bool = False,
    offset: tuple[float, float] = (0.0, 0.0),
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> tuple[Tensor, Tensor]:
    """The affine ``x_norm = x * scale + shift`` from a raster's own coordinates to ``grid_sample``'s.

    Element ``k`` of an axis of ``n`` samples sits at ``offset + k``. With ``align_corners=False`` (pixels and
    cells: the rectangle's edges ``offset - 0.5`` and ``offset + n - 0.5`` at -1 and +1)
    ``x_norm = (2 (x - offset) + 1) / n - 1``; with ``align_corners=True`` (nodes: the first and last sample at
    -1 and +1, as for the staggered velocity's faces) ``x_norm = 2 (x - offset) / (n - 1) - 1``. Two tensors
    rather than a function, so a hot path applies them in one fused ``addcmul``.

    Args:
        size: ``(H, W)`` samples of the raster (each at least 2 with ``align_corners=True``).
        align_corners: ``grid_sample``'s flag the affine is for.
        offset: ``(x, y)`` position of element 0 in the coordinates mapped (e.g. ``(-0.5, 0)`` for ``u`` faces).
        device, dtype: of the results.

    Returns:
        ``(scale, shift)``, each ``(2,)`` ``(x, y)``; view them as ``(1, 1, 1, 2)`` for a ``(B, H', W', 2)``
        grid, or ``(1, 2, 1)`` for channel-first ``(B, 2, N)`` points.

    Example:
        >>> scale, shift = normalized_affine((2, 4))
        >>> (torch.tensor([-0.5, 3.5]) * scale[0] + shift[0]).tolist()
        [-1.0, 1.0]
    """
    H, W = check_size("size", size, minimum=2 if align_corners else 1)
    ox, oy = offset
    if align_corners:
        sx, sy = 2.0 / (W - 1), 2.0 / (H - 1)
        shift = [-1 - ox * sx, -1 - oy * sy]
    else:
        sx, sy = 2.0 / W, 2.0 / H
        shift = [(1 - 2 * ox) / W - 1, (1 - 2 * oy) / H - 1]
    return (
        torch.tensor([sx, sy], device=device, dtype=dtype),
        torch.tensor(shift, device=device, dtype=dtype),
    )


def pixel_to_normalized(points: Tensor, size: tuple[int, int]) -> Tensor:
    """Convert ``(..., 2)`` pixel points to ``grid_sample``'s normalised coordinates (``align_corners=False``).

    ``x_norm = (x + 0.5) * 2 / W - 1``: the image's edges ``-0.5`` and ``W - 0.5`` go to -1 and +1. The same map
    as :func:`normalized_affine`, which hot paths apply fused.

    Args:
        points: ``(..., 2)`` ``(x, y)`` pixels of an image of size ``size = (H, W)``.
        size: ``(H, W)``.

    Returns:
        ``(..., 2)`` ``(x, y)`` in ``[-1, 1]`` over the image.

    Example:
        >>> pixel_to_normalized(torch.tensor([[-0.5, 0.0], [3.5, 1.0]]), (2, 4))
        tensor([[-1.0000, -0.5000],
                [ 1.0000,  0.5000]])
    """
    check_tensor("points", points, shape=[*([None] * (points.ndim - 1)), 2])
    H, W = check_size("size", size)
    return (points + 0.5) * points.new_tensor([2 / W, 2 / H]) - 1


def normalized_to_pixel(points: Tensor, size: tuple[int, int]) -> Tensor:
    """Convert ``(..., 2)`` normalised points (``align_corners=False``) to pixels of an image of ``size = (H, W)``.

    The inverse of :func:`pixel_to_normalized`: ``x = (x_norm + 1) * W / 2 - 0.5``.
    """
    check_tensor("points", points, shape=[*([None] * (points.ndim - 1)), 2])
    H, W = check_size("size", size)
    return (points + 1) / points.new_tensor([2 / W, 2 / H]) - 0.5
