"""The one place the library calls ``grid_sample``.

``grid_sample`` given a NaN in its grid returns garbage (with border padding it even looks finite), and its CPU
backward crashes the process. So every sampling path goes through :func:`sample`, whose ``check`` argument
says, at each call site, whether that grid is guarded here or is finite by construction.

The policy (see ``docs/design.rst``, "Sampling"):

* **Once per frame** (an image read through a map: :func:`~torchfluidwarp.warp.frames.warp_image`, the frames of
  :class:`~torchfluidwarp.warp.layer.FluidWarp`, the morph): the grid is checked here, one reduction per call.
* **Per sub-step** (velocity sampling in advection, carrying points, composing maps): unchecked. These run
  dozens of times per fluid step; their inputs are validated once at the public boundary (forces, velocities,
  points, viscosity, ``dt``), the positions they sample are clamped into the box, and each step's velocity is
  checked by the simulator and by :func:`~torchfluidwarp.core.advection.substeps`. A check here would add a reduction
  and, on an accelerator, a host synchronisation to every call.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import all_finite
from torchfluidwarp.errors import InputError

__all__ = ["sample", "SampleMode"]

SampleMode = Literal["bilinear", "bicubic", "nearest"]


def sample(
    image: Tensor, grid: Tensor, *, mode: SampleMode = "bilinear", align_corners: bool, check: str | None
) -> Tensor:
    """``grid_sample`` with border padding: the library's only call to it.

    Args:
        image: ``(N, C, H_in, W_in)`` what is sampled.
        grid: ``(N, H_out, W_out, 2)`` normalised positions ``(x, y)`` in ``[-1, 1]``; beyond that, the border.
        mode: ``"bilinear"``, ``"bicubic"`` or ``"nearest"``.
        align_corners: as for ``torch.nn.functional.grid_sample``.
        check: the name of what the grid was made from (e.g. ``"coords"``), quoted in the error, to refuse a
            non-finite grid; ``None`` where the caller guarantees a finite grid (the per-sub-step paths, whose
            inputs were checked at the public boundary).

    Returns:
        ``(N, C, H_out, W_out)``.

    Raises:
        InputError: ``check`` is given and the grid holds NaN or inf.

    Example:
        >>> import torch
        >>> grid = torch.zeros(1, 1, 1, 2)  # the centre of the image
        >>> sample(torch.arange(4.0).view(1, 1, 2, 2), grid, align_corners=False, check="grid").item()
        1.5
        >>> sample(torch.zeros(1, 1, 2, 2), grid * float("nan"), align_corners=False, check="xy")
        Traceback (most recent call last):
        ...
        torchfluidwarp.errors.InputError: non-finite sampling positions (NaN or inf) from xy; grid of shape (1, 1, 1, 2)
    """
    # one sum in the grid's own dtype (a NaN or inf makes it non-finite); only then the exact test, which also
    # clears a sum that merely overflowed
    if check is not None and grid.numel() and not (math.isfinite(float(grid.detach().sum())) or all_finite(grid)):
        raise InputError(f"non-finite sampling positions (NaN or inf) from {check}; grid of shape {tuple(grid.shape)}")
    # a lone picture is read as `bands` pictures, each for a band of the output points: torch's CPU kernel runs one
    # thread per picture of the batch, so a lone picture would be sampled on one thread (docs/benchmarks.md, #30)
    bands = _bands(image, grid)
    C, Hg, Wg = image.shape[1], grid.shape[1], grid.shape[2]
    if bands > 1:  # views, of a contiguous grid or a channels-first one
        image, grid = image.expand(bands, -1, -1, -1), grid.reshape(bands, 1, Hg * Wg // bands, 2)
    out = F.grid_sample(image, grid, mode=mode, padding_mode="border", align_corners=align_corners)
    return out if bands == 1 else out.permute(2, 1, 0, 3).reshape(1, C, Hg, Wg)


GRAIN = 8192
"""Output points per band at least: torch's own grain (``GRAIN_SIZE`` 32768 elements, 4 per sampled point)."""


def _bands(image: Tensor, grid: Tensor) -> int:
    """How many bands to sample a lone CPU picture in: one per thread, each at least :data:`GRAIN` points, a
    divisor of the output's points; 1 for a batch, an accelerator, or a picture whose gradient autograd records
    (the bands' gradients would take one copy of the picture each)."""
    if image.shape[0] != 1 or image.device.type != "cpu" or (torch.is_grad_enabled() and image.requires_grad):
        return 1
    points = grid.shape[1] * grid.shape[2]
    bands = min(torch.get_num_threads(), points // GRAIN)
    while bands > 1 and points % bands:
        bands -= 1
    return max(bands, 1)
