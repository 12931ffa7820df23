"""Random fluid warps for data augmentation, over plain tensors.

One call draws random brush forces per sample (how many brushes, how strong, how wide, for how many steps),
rolls the fluid out once for the whole batch, and then moves every input of the call through that same flow:

* images are resampled bilinearly through the **backward map** (where each output pixel reads from);
* masks are resampled by nearest sampling, so label values survive unchanged;
* keypoints are carried by the **forward map**: RK2 particles through the very same velocities
  (:meth:`~torchfluidwarp.warp.layer.FluidWarp.advect_points`), not an approximate inverse;
* boxes become the axis-aligned box around their carried corners *and* points along their edges.

Conventions (as everywhere in the library, see :mod:`torchfluidwarp.core.grid`): images are ``(B, C, H, W)``;
points and boxes are in **pixels** ``(x, y)`` with pixel centres at integers, so the image covers
``[-0.5, W - 0.5] x [-0.5, H - 0.5]``; boxes are ``(x1, y1, x2, y2)`` in the same coordinates.

Two names, one augmentation:

* :class:`FluidWarpAugment` (this module) is the tensor-level ``nn.Module``: it warps a batch ``(B, C, H, W)``
  with one independent draw per sample, and takes keypoints, masks and boxes as keyword tensors;
  :func:`random_fluid_warp` is the same as a one-shot function.
* ``torchfluidwarp.RandomFluidWarp`` (:class:`torchfluidwarp.augment.transforms.RandomFluidWarp`) is the torchvision v2
  ``Transform`` over tv_tensors (boxes with edges at ``0`` and ``W``) and plain tensors; it draws through a
  :class:`FluidWarpAugment`. torchvision is imported there only: this module never imports it.

The fluid is incompressible, so the continuous flow never folds, but its discretisation can when one step
shears a cell by about its own size or the whole push carries the image many brush radii. Two guards keep
every warp fold-free: :class:`FluidWarpAugment` refuses settings past :data:`MAX_SHEAR`, and each drawn map
is checked (:func:`min_quad_determinant`); a sample whose map would fold is rolled out again with half the
force (see :meth:`FluidWarpAugment.make_params`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from torchfluidwarp._checks import check_int, check_positive, check_size, check_tensor, describe
from torchfluidwarp.core.grid import FluidGrid
from torchfluidwarp.warp.forces import cell_centres
from torchfluidwarp.warp.layer import FluidWarp, _carry, _raster, identity_map, iter_backward_maps, warp_image

__all__ = [
    "MAX_SHEAR",
    "MIN_DET",
    "FluidWarpParams",
    "FluidWarpAugment",
    "random_fluid_warp",
    "brush_forces",
    "min_quad_determinant",
    "raster_map",
    "fluid_warp_map",
    "carry_points",
    "carry_boxes",
    "box_outline",
    "polygon_outline",
    "apply_fluid_warp",
]

MAX_SHEAR: float = 2.0
"""Bound on ``S * max(1, T / 4)`` where ``S = count_max * strength_max * steps_max * dt**2 / radius_min``.

``S`` is the velocity difference across one brush radius, per step, of all brushes stacked on one spot (the
worst case): a step folds where it nears 1 to 2. ``S * T / 4`` is half the stacked brushes' free displacement
``count * strength * (T dt)^2 / 2`` in radii. In a sweep over 64 to 512 px images, 16 to 64 cell grids,
2 to 16 steps and dt 1 to 2, stacked brushes at this bound folded no map when their radius was 8% of the
image size; at 20% and 40% of it some did (the walls crowd the flow), and the map check catches those."""

MIN_DET: float = 0.1
"""A drawn map is accepted when its Jacobian determinant stays at least this everywhere (see
:func:`min_quad_determinant`); otherwise the sample is rolled out again with half its force."""

Number = int | float
RangeArg = Number | Sequence[Number]


def _range(name: str, value: RangeArg, *, integer: bool, minimum: float, strict: bool) -> tuple[Any, Any]:
    """``value`` or ``(lo, hi)`` as a validated closed range."""
    pair = (value, value) if isinstance(value, (int, float)) and not isinstance(value, bool) else value
    if not isinstance(pair, (tuple, list)) or len(pair) != 2:
        raise TypeError(f"{name} must be a number or a pair (min, max), got {describe(value)}")
    lo, hi = pair
    for v in (lo, hi):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (integer and not isinstance(v, int)):
            raise TypeError(f"{name} must hold {'ints' if integer else 'numbers'}, got {describe(value)}")
        if not math.isfinite(v) or v < minimum or (strict and v == minimum):
            raise ValueError(f"{name} must be finite and {'>' if strict else '>='} {minimum}, got {tuple(pair)}")
    if hi < lo:
        raise ValueError(f"{name} must be (min, max) with min <= max, got {tuple(pair)}")
    return (int(lo), int(hi)) if integer else (float(lo), float(hi))


@dataclass(frozen=True)
class FluidWarpParams:
    """One draw of a random fluid warp: everything needed to move any input of the call.

    Attributes:
        velocities: ``(B, T, 2, h + 1, w + 1)`` staggered velocities (fluid cells per time unit); sample ``b``'s
            velocities after its own ``steps[b]`` are zero, so its warp stops there.
        steps: ``(B,)`` the number of fluid steps of each sample.
        dt: the time step.
        centers: ``(B, K, 2)`` brush centres in pixels.
        directions: ``(B, K, 2)`` unit push directions.
        amplitude: ``(B, K)`` peak accelerations in pixels per time unit^2 (0 for the unused brushes).
        radius: ``(B, K)`` Gaussian radii in pixels.
        force_scale: ``(B,)`` the factor the fold check applied to each sample's forces (1 unless its first
            map would have folded; 0 if every retry would have folded too: that sample is left unwarped).
        size: ``(H, W)`` the image size the draw was made for.
        raster_map: ``(B, h_r, w_r, 2)`` the backward map on the composition raster (see
            :func:`fluid_warp_map`), in pixels of ``size``.
        min_det: ``(B,)`` the smallest Jacobian determinant of each map (:func:`min_quad_determinant`).
    """

    velocities: Tensor
    steps: Tensor
    dt: float
    centers: Tensor
    directions: Tensor
    amplitude: Tensor
    radius: Tensor
    force_scale: Tensor
    size: tuple[int, int]
    raster_map: Tensor
    min_det: Tensor

    @property
    def batch(self) -> int:
        return self.velocities.shape[0]


def brush_forces(
    centers: Tensor,
    directions: Tensor,
    amplitude: Tensor,
    radius: Tensor,
    *,
    grid: FluidGrid | int | tuple[int, int],
    image_size: tuple[int, int],
    steps: int,
) -> Tensor:
    """Steady Gaussian brush pushes for a batch of independent samples.

    Brush ``k`` of sample ``b`` pushes with ``amplitude[b, k] * directions[b, k] * exp(-|x - c|^2 / 2 r^2)``, the
    same force at every step (the batched, steady form of :class:`~torchfluidwarp.warp.forces.Brushes`).

    Args:
        centers: ``(B, K, 2)`` brush centres ``(x, y)`` in pixels.
        directions: ``(B, K, 2)`` unit push directions (channel 0 = x).
        amplitude: ``(B, K)`` peak acceleration in pixels per time unit^2; 0 switches a brush off.
        radius: ``(B, K)`` Gaussian radius in pixels (> 0).
        grid: the fluid grid ``(h, w)``.
        image_size: ``(H, W)`` of the image the pixels refer to.
        steps: ``T``.

    Returns:
        ``(B, T, 2, h, w)`` forces in fluid cells per time unit^2 (an expanded view over ``T``).

    Example:
        >>> f = brush_forces(torch.tensor([[[32.0, 32.0]]]), torch.tensor([[[1.0, 0.0]]]), torch.tensor([[0.5]]),
        ...                  torch.tensor([[8.0]]), grid=16, image_size=(64, 64), steps=3)
        >>> f.shape, round(float(f.amax()), 3)
        (torch.Size([1, 3, 2, 16, 16]), 0.121)
    """
    g = FluidGrid.of(grid)
    H, W = image_size
    x = cell_centres(g, (H, W), centers)  # (h, w, 2) pixels
    d2 = ((x[None, None] - centers[:, :, None, None]) ** 2).sum(-1)  # (B, K, h, w)
    bump = torch.exp(-d2 / (2 * radius[:, :, None, None] ** 2))
    # pixels -> cells: accelerations scale like lengths
    to_cells = torch.tensor([g.width / W, g.height / H], device=centers.device, dtype=centers.dtype)
    push = amplitude[..., None] * directions * to_cells  # (B, K, 2)
    field = torch.einsum("bkc,bkhw->bchw", push, bump)
    return field.unsqueeze(1).expand(-1, steps, -1, -1, -1)


def min_quad_determinant(coords: Tensor, size: tuple[int, int]) -> Tensor:
    """The smallest Jacobian determinant of the bilinear interpolant of a coordinate map, per sample ``(B,)``.

    ``coords`` ``(B, h_r, w_r, 2)`` holds positions in pixels of an ``(H, W)`` image at the pixel centres of an
    ``h_r x w_r`` raster covering the same rectangle. Between four raster points the bilinear interpolant's
    determinant is linear along each axis, so its minimum is one of the four corners', each taken from the
    quad's own edges: when all are positive, no resampling of the map (bilinear, at any resolution) folds.

    Example:
        >>> from torchfluidwarp.warp.layer import identity_map
        >>> min_quad_determinant(identity_map((4, 4)), (4, 4)).tolist()
        [1.0]
    """
    H, W = size
    h_r, w_r = coords.shape[1:3]
    ex = coords[:, :, 1:] - coords[:, :, :-1]  # (B, h_r, w_r - 1, 2) along x
    ey = coords[:, 1:] - coords[:, :-1]  # (B, h_r - 1, w_r, 2) along y
    area = (W / w_r) * (H / h_r)  # raster spacing in image pixels
    dets = [
        a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        for a in (ex[:, :-1], ex[:, 1:])
        for b in (ey[:, :, :-1], ey[:, :, 1:])
    ]
    return torch.stack(dets).amin(0).flatten(1).amin(1) / area


def raster_map(velocities: Tensor, size: tuple[int, int], dt: float) -> Tensor:
    """The backward map of the last step on the composition raster: ``(B, h_r, w_r, 2)`` in pixels of ``size``.

    The raster has at most ``OVERSAMPLE`` points per fluid cell and axis (the image itself when smaller), and
    the map is composed on it step by step (:func:`~torchfluidwarp.warp.layer.iter_backward_maps`).
    """
    H, W = size
    raster = _raster(size, velocities.shape[-2] - 1, velocities.shape[-1] - 1)
    back = next(iter_backward_maps(velocities, raster, dt, times=[velocities.shape[1]]))  # raster pixels
    if raster == (H, W):
        return back
    scale = torch.tensor([W / raster[1], H / raster[0]], device=back.device, dtype=back.dtype)
    return (back + 0.5) * scale - 0.5


def _upsample(coords: Tensor, size: tuple[int, int]) -> Tensor:
    """Resize a raster map ``(B, h_r, w_r, 2)`` to ``(B, H, W, 2)`` by resizing its displacement bilinearly."""
    H, W = size
    h_r, w_r = coords.shape[1:3]
    if (h_r, w_r) == (H, W):
        return coords
    scale = torch.tensor([W / w_r, H / h_r], device=coords.device, dtype=coords.dtype)
    ident = (identity_map((h_r, w_r), device=coords.device, dtype=coords.dtype) + 0.5) * scale - 0.5
    disp = F.interpolate((coords - ident).permute(0, 3, 1, 2), size=(H, W), mode="bilinear", align_corners=False)
    return identity_map((H, W), device=coords.device, dtype=coords.dtype) + disp.permute(0, 2, 3, 1)


def fluid_warp_map(params: FluidWarpParams, size: tuple[int, int] | None = None) -> Tensor:
    """The backward map of each sample's last step: ``(B, H, W, 2)`` source positions in pixels.

    The map is composed on a raster of at most ``OVERSAMPLE`` points per fluid cell and axis
    (:func:`raster_map`), then its displacement is resized bilinearly to ``(H, W)`` once, as
    :func:`~torchfluidwarp.warp.layer.iter_backward_maps` does for a full-size map; the raster map is kept in the draw
    (its folds are checked there), so this costs one resize.

    Args:
        params: a draw.
        size: ``(H, W)``; the draw's own size by default (any other size is composed afresh).
    """
    size = params.size if size is None else size
    coords = params.raster_map if size == params.size else raster_map(params.velocities, size, params.dt)
    return _upsample(coords, size)


def carry_points(params: FluidWarpParams, points: Tensor, size: tuple[int, int] | None = None) -> Tensor:
    """Carry points ``(B, M, 2)`` (pixels) to each sample's last step with RK2 through the velocities.

    This is :meth:`~torchfluidwarp.warp.layer.FluidWarp.advect_points` on the drawn velocities: the same particles
    whose flow the images follow. Points outside the image move with the nearest point of its border (the
    fluid's wall), so a keypoint marked just off the canvas keeps its offset.

    Args:
        params: a draw.
        points: ``(B, M, 2)`` ``(x, y)`` in pixels of ``size``.
        size: ``(H, W)``; the draw's own size by default.

    Returns:
        ``(B, M, 2)`` pixels, in the dtype of ``points``.
    """
    H, W = params.size if size is None else size
    vel = params.velocities
    p = points.to(device=vel.device, dtype=vel.dtype)
    lo = torch.tensor([-0.5, -0.5], device=p.device, dtype=p.dtype)
    hi = torch.tensor([W - 0.5, H - 0.5], device=p.device, dtype=p.dtype)
    inside = torch.maximum(torch.minimum(p, hi), lo)
    carried = _carry(vel, inside, (H, W), params.dt)[:, -1]
    return (carried + (p - inside)).to(device=points.device, dtype=points.dtype)


def polygon_outline(corners: Tensor, edge_points: int) -> Tensor:
    """Points along a closed polygon ``(..., P, 2)``: ``(..., P * edge_points, 2)``, each corner then its edge."""
    t = torch.arange(edge_points, device=corners.device, dtype=corners.dtype) / edge_points  # [0, 1)
    nxt = corners.roll(-1, dims=-2)
    pts = corners[..., None, :] + (nxt - corners)[..., None, :] * t[:, None]  # (..., P, E, 2)
    return pts.flatten(-3, -2)


def box_outline(boxes: Tensor, edge_points: int) -> Tensor:
    """Points along the outline of ``(..., 4)`` xyxy boxes: ``(..., 4 * edge_points, 2)``, corners included."""
    x1, y1, x2, y2 = boxes.unbind(-1)
    corners = torch.stack([torch.stack(c, -1) for c in ((x1, y1), (x2, y1), (x2, y2), (x1, y2))], dim=-2)
    return polygon_outline(corners, edge_points)


def carry_boxes(
    params: FluidWarpParams,
    boxes: Tensor,
    size: tuple[int, int] | None = None,
    edge_points: int = 8,
    *,
    clip: bool = True,
) -> Tensor:
    """Carry boxes ``(B, N, 4)`` ``(x1, y1, x2, y2)`` (pixels) through the warp.

    Each box becomes the axis-aligned box around its carried outline: ``edge_points`` points per edge,
    corners included, each carried like a keypoint (:func:`carry_points`).

    Args:
        params: a draw.
        boxes: ``(B, N, 4)`` in pixels of ``size`` (the draw's own size by default).
        edge_points: points per edge.
        clip: clip the boxes to the image rectangle ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``.

    Returns:
        ``(B, N, 4)`` in the dtype of ``boxes``.
    """
    B, N = boxes.shape[:2]
    size = params.size if size is None else size
    H, W = size
    if N == 0:
        return boxes.clone()
    outline = box_outline(boxes.to(params.velocities.dtype), edge_points)  # (B, N, 4E, 2)
    moved = carry_points(params, outline.reshape(B, -1, 2), size).view(B, N, -1, 2)
    out = torch.cat([moved.amin(2), moved.amax(2)], dim=-1)
    if clip:
        lo = torch.tensor([-0.5, -0.5, -0.5, -0.5], device=out.device, dtype=out.dtype)
        hi = torch.tensor([W - 0.5, H - 0.5, W - 0.5, H - 0.5], device=out.device, dtype=out.dtype)
        out = torch.maximum(torch.minimum(out, hi), lo)
    return out.to(boxes.dtype)


def _resample(x: Tensor, coords: Tensor, mode: Literal["bilinear", "nearest"]) -> Tensor:
    """Warp ``(B, C, H, W)`` of any dtype: integers are rounded back and clamped to their range."""
    coords = coords.to(x.device)
    if x.is_floating_point():
        return warp_image(x, coords.to(x.dtype), mode)
    if x.dtype == torch.bool:
        return warp_image(x.to(coords.dtype), coords, "nearest") > 0.5
    out = warp_image(x.to(coords.dtype), coords, mode)
    if mode != "nearest":
        info = torch.iinfo(x.dtype)
        out = out.round_().clamp_(info.min, info.max)
    return out.to(x.dtype)


def apply_fluid_warp(
    params: FluidWarpParams,
    image: Tensor | None = None,
    *,
    keypoints: Tensor | None = None,
    masks: Tensor | None = None,
    boxes: Tensor | None = None,
    size: tuple[int, int] | None = None,
    edge_points: int = 8,
) -> dict[str, Tensor]:
    """Move every given input of one call through the same drawn warp.

    Args:
        params: a draw from :meth:`FluidWarpAugment.make_params`.
        image: ``(B, C, H, W)``, resampled bilinearly (integer images are rounded back to their dtype).
        keypoints: ``(B, M, 2)`` pixels, carried by the forward map (:func:`carry_points`).
        masks: ``(B, K, H, W)`` labels or binary masks of any dtype, resampled by nearest sampling.
        boxes: ``(B, N, 4)`` ``(x1, y1, x2, y2)`` pixels (:func:`carry_boxes`).
        size: ``(H, W)`` the points and boxes refer to; the image's (or the masks', or the draw's) by default.
        edge_points: points per box edge.

    Returns:
        a dict with the keys of the inputs given (``"image"``, ``"keypoints"``, ``"masks"``, ``"boxes"``).
    """
    sized = image if image is not None else masks
    if size is None:
        size = params.size if sized is None else (sized.shape[-2], sized.shape[-1])
    out: dict[str, Tensor] = {}
    coords = None
    if image is not None or masks is not None:
        coords = fluid_warp_map(params, size)
    if image is not None:
        out["image"] = _resample(image, coords, "bilinear")  # type: ignore[arg-type]
    if keypoints is not None:
        out["keypoints"] = carry_points(params, keypoints, size)
    if masks is not None:
        out["masks"] = _resample(masks, coords, "nearest")  # type: ignore[arg-type]
    if boxes is not None:
        out["boxes"] = carry_boxes(params, boxes, size, edge_points)
    return out


class FluidWarpAugment(nn.Module):
    """Random fluid warp augmentation over plain tensors: Gaussian brushes push an incompressible fluid that
    carries the image, one independent draw per sample of the batch.

    This is the tensor-level module (formerly ``torchfluidwarp.augment.tensor.RandomFluidWarp``); for a torchvision v2
    pipeline over tv_tensors use ``torchfluidwarp.RandomFluidWarp``
    (:class:`~torchfluidwarp.augment.transforms.RandomFluidWarp`), which draws through this module.

    Per sample, ``count`` brushes are placed uniformly over the image, each pushing in a uniformly random
    direction with its own ``strength`` and ``radius``, steadily for ``steps`` fluid steps. Every range is
    ``(min, max)`` (closed; a single number fixes the value) and is drawn uniformly, once per call
    (:meth:`make_params`); all inputs of the call share that draw. The whole batch is rolled out in one
    :class:`~torchfluidwarp.warp.layer.FluidWarp` call with per-sample forces, on the input's device and in its
    floating dtype (float32 for integer images).

    Args:
        count: number of brushes per sample (ints).
        strength: peak acceleration of a brush in pixels per time unit^2. A single brush of strength ``a``,
            radius ``r`` pushing for ``T`` steps moves the image's centre by roughly ``a T^2 dt^2 / 2`` px
            (less: the fluid around it resists).
        radius: Gaussian radius of a brush in pixels (keep it above a fluid cell, ``W / w`` px).
        steps: number of fluid steps per sample (ints).
        grid: fluid grid ``(h, w)`` (an int for square); it covers the whole image whatever its size.
        dt: time step (time units).
        viscosity: constant viscosity (cells^2 per time unit); it smooths the flow.
        edge_points: points carried per box edge.
        max_retries: how many times a sample whose map would fold is rolled out again with half its force
            before it is left unwarped.
        generator: a ``torch.Generator`` for the draws; ``None`` uses torch's global RNG. In a
            ``DataLoader`` worker the generator is re-seeded once from its seed and the worker's seed, so
            workers draw different, reproducible warps.

    Raises:
        ValueError: a range that is empty, negative or non-finite, or a setting strong enough to fold:
            ``S * max(1, steps_max / 4)`` with ``S = count_max * strength_max * steps_max * dt**2 / radius_min``
            must be at most :data:`MAX_SHEAR`.

    Folds: within that bound, stacked brushes fold no map unless they are wider than about a tenth of the
    image. Each drawn map is checked anyway (:func:`min_quad_determinant` on the composition raster, at
    least :data:`MIN_DET`); a sample that fails is rolled out again with half its force, up to
    ``max_retries`` times (``params.force_scale`` records it). So no warp this module returns folds.

    Conventions: images ``(B, C, H, W)`` or ``(C, H, W)``; keypoints ``(B, M, 2)`` and boxes ``(B, N, 4)``
    ``(x1, y1, x2, y2)`` in pixels, pixel centres at integers (the image covers ``[-0.5, W - 0.5]``);
    masks ``(B, K, H, W)``. Unbatched inputs drop the leading ``B`` everywhere.

    Example:
        >>> aug = FluidWarpAugment(strength=(0.2, 0.4), generator=torch.Generator().manual_seed(0))
        >>> image = torch.rand(2, 3, 64, 64)
        >>> aug(image).shape
        torch.Size([2, 3, 64, 64])
        >>> out = aug(image, keypoints=torch.tensor([[[20.0, 30.0]], [[40.0, 10.0]]]),
        ...           masks=(image[:, :1] > 0.5), boxes=torch.tensor([[[10.0, 10.0, 30.0, 40.0]]] * 2))
        >>> sorted(out), out["masks"].dtype
        (['boxes', 'image', 'keypoints', 'masks'], torch.bool)
    """

    def __init__(
        self,
        count: RangeArg = (1, 4),
        strength: RangeArg = (0.1, 0.5),
        radius: RangeArg = (16.0, 48.0),
        steps: RangeArg = (4, 8),
        *,
        grid: FluidGrid | int | tuple[int, int] = 32,
        dt: float = 1.0,
        viscosity: float = 0.0,
        edge_points: int = 8,
        max_retries: int = 3,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        self.count = _range("count", count, integer=True, minimum=1, strict=False)
        self.strength = _range("strength", strength, integer=False, minimum=0.0, strict=False)
        self.radius = _range("radius", radius, integer=False, minimum=0.0, strict=True)
        self.steps = _range("steps", steps, integer=True, minimum=1, strict=False)
        self.grid = FluidGrid.of(grid)
        self.dt = check_positive("dt", dt)
        self.viscosity = check_positive("viscosity", viscosity, allow_zero=True)
        self.edge_points = check_int("edge_points", edge_points, minimum=2)
        if generator is not None and not isinstance(generator, torch.Generator):
            raise TypeError(f"generator must be a torch.Generator or None, got {describe(generator)}")
        self.generator = generator
        self._worker: int | None = None
        self.max_retries = check_int("max_retries", max_retries, minimum=0)
        # dimensionless worst case: all brushes stacked, at the largest strength and steps, smallest radius
        shear = self.count[1] * self.strength[1] * self.steps[1] * self.dt**2 / self.radius[0]
        stretch = shear * max(1.0, self.steps[1] / 4)
        if stretch > MAX_SHEAR:
            limit = self.strength[1] * MAX_SHEAR / stretch
            raise ValueError(
                f"strength up to {self.strength[1]} px/time^2 could fold the warp: with count={self.count}, "
                f"steps={self.steps}, radius={self.radius} px and dt={self.dt}, S * max(1, T / 4) = {stretch:.3g} "
                f"> MAX_SHEAR = {MAX_SHEAR} (S = count_max * strength_max * steps_max * dt^2 / radius_min); "
                f"keep strength <= {limit:.4g}, or widen the smallest radius"
            )

    def extra_repr(self) -> str:
        return (
            f"count={self.count}, strength={self.strength}, radius={self.radius}, steps={self.steps}, "
            f"grid={self.grid.shape}, dt={self.dt}, viscosity={self.viscosity}"
        )

    def _rng(self) -> torch.Generator | None:
        """The generator for this call; a DataLoader worker re-seeds its own copy once."""
        if self.generator is None:
            return None
        info = torch.utils.data.get_worker_info()
        if info is not None and self._worker != info.id:
            # every worker starts from the same pickled state: mix in the worker's seed
            seed = (self.generator.initial_seed() * 6364136223846793005 + info.seed) % (2**63)
            self.generator = torch.Generator(self.generator.device).manual_seed(seed)
            self._worker = info.id
        return self.generator

    def make_params(
        self,
        batch: int,
        size: tuple[int, int],
        *,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> FluidWarpParams:
        """Draw the random brushes of one call and roll the fluid out for the whole batch.

        Draws happen on the generator's device (CPU without one), so a seed gives the same warp on any
        device; the roll-out then runs on ``device`` in ``dtype`` without autograd.

        Args:
            batch: ``B``.
            size: ``(H, W)`` of the images in pixels.
            device, dtype: where and in which floating dtype to roll out.

        Returns:
            a :class:`FluidWarpParams`.
        """
        B = check_int("batch", batch)
        H, W = check_size("size", size)
        device = torch.device("cpu") if device is None else torch.device(device)
        g = self._rng()
        draw_device = g.device if g is not None else torch.device("cpu")
        K = self.count[1]

        def uniform(lo: float, hi: float, *shape: int) -> Tensor:
            return lo + (hi - lo) * torch.rand(*shape, generator=g, device=draw_device, dtype=torch.float64)

        counts = torch.randint(self.count[0], self.count[1] + 1, (B,), generator=g, device=draw_device)
        steps = torch.randint(self.steps[0], self.steps[1] + 1, (B,), generator=g, device=draw_device)
        centers = uniform(0.0, 1.0, B, K, 2) * torch.tensor([W - 1.0, H - 1.0], dtype=torch.float64, device=draw_device)
        angle = uniform(0.0, 2 * math.pi, B, K)
        amplitude = uniform(*self.strength, B, K)
        radius = uniform(*self.radius, B, K)
        active = torch.arange(K, device=draw_device)[None] < counts[:, None]
        amplitude = torch.where(active, amplitude, torch.zeros_like(amplitude))

        centers, amplitude = centers.to(device=device, dtype=dtype), amplitude.to(device=device, dtype=dtype)
        radius = radius.to(device=device, dtype=dtype)
        directions = torch.stack([angle.cos(), angle.sin()], -1).to(device=device, dtype=dtype)
        steps = steps.to(device)
        T = int(steps.max())
        warp = FluidWarp(self.grid, T, self.dt, self.viscosity)
        running = (torch.arange(T, device=device)[None] < steps[:, None]).to(dtype)  # (B, T)
        scale = torch.ones(B, device=device, dtype=dtype)

        def roll(forces: Tensor, running: Tensor) -> tuple[Tensor, Tensor, Tensor]:
            # a sample's warp stops after its own steps: zero velocity leaves maps and points in place
            v = warp.rollout(forces, (H, W)).velocities * running[:, :, None, None, None]
            m = raster_map(v, (H, W), self.dt)
            return v, m, min_quad_determinant(m, (H, W))

        with torch.no_grad():
            forces = brush_forces(centers, directions, amplitude, radius, grid=self.grid, image_size=(H, W), steps=T)
            vel, maps, det = roll(forces, running)
            todo = (det < MIN_DET).nonzero().flatten()
            for attempt in range(self.max_retries + 1):
                if todo.numel() == 0:
                    break
                # half the force, or, once the retries are spent, none: that sample is left unwarped
                scale[todo] = 0.0 if attempt == self.max_retries else 0.5 * scale[todo]
                v, m, d = roll(forces[todo] * scale[todo, None, None, None, None], running[todo])
                vel[todo], maps[todo], det[todo] = v, m, d
                todo = todo[d < MIN_DET]
        return FluidWarpParams(
            velocities=vel,
            steps=steps,
            dt=self.dt,
            centers=centers,
            directions=directions,
            amplitude=amplitude,
            radius=radius,
            force_scale=scale,
            size=(H, W),
            raster_map=maps,
            min_det=det,
        )

    def forward(
        self,
        image: Tensor,
        *,
        keypoints: Tensor | None = None,
        masks: Tensor | None = None,
        boxes: Tensor | None = None,
    ) -> Tensor | dict[str, Tensor]:
        """Warp ``image`` and, through the same draw, the optional keypoints, masks and boxes.

        Args:
            image: ``(B, C, H, W)`` or ``(C, H, W)``, any dtype (integers are rounded back).
            keypoints: ``(B, M, 2)`` (``(M, 2)`` unbatched) pixels ``(x, y)``.
            masks: ``(B, K, H, W)`` (``(K, H, W)`` unbatched), any dtype; nearest sampling.
            boxes: ``(B, N, 4)`` (``(N, 4)`` unbatched) ``(x1, y1, x2, y2)`` pixels.

        Returns:
            the warped image when only an image is given; otherwise a dict with the keys ``"image"`` and those
            of the other inputs given.

        Raises:
            TypeError, ValueError: inputs that are not tensors or whose shapes do not match the image.
        """
        check_tensor("image", image, ndim=(3, 4), floating=False)
        unbatched = image.ndim == 3
        img = image.unsqueeze(0) if unbatched else image
        B, _, H, W = img.shape

        def batched(name: str, x: Tensor | None, tail: list[int | None], floating: bool) -> Tensor | None:
            if x is None:
                return None
            check_tensor(name, x, ndim=len(tail) + (0 if unbatched else 1), floating=floating)
            x = x.unsqueeze(0) if unbatched else x
            return check_tensor(name, x, shape=[B, *tail], floating=floating)

        kp = batched("keypoints", keypoints, [None, 2], True)
        mk = batched("masks", masks, [None, H, W], False)
        bx = batched("boxes", boxes, [None, 4], True)
        dtype = img.dtype if img.is_floating_point() else torch.float32
        params = self.make_params(B, (H, W), device=img.device, dtype=dtype)
        out = apply_fluid_warp(params, img, keypoints=kp, masks=mk, boxes=bx, edge_points=self.edge_points)
        if unbatched:
            out = {k: v.squeeze(0) for k, v in out.items()}
        return out["image"] if len(out) == 1 else out


def random_fluid_warp(
    image: Tensor,
    *,
    keypoints: Tensor | None = None,
    masks: Tensor | None = None,
    boxes: Tensor | None = None,
    count: RangeArg = (1, 4),
    strength: RangeArg = (0.1, 0.5),
    radius: RangeArg = (16.0, 48.0),
    steps: RangeArg = (4, 8),
    grid: FluidGrid | int | tuple[int, int] = 32,
    dt: float = 1.0,
    viscosity: float = 0.0,
    edge_points: int = 8,
    max_retries: int = 3,
    generator: torch.Generator | None = None,
) -> Tensor | dict[str, Tensor]:
    """One random fluid warp of a batch of tensors: ``FluidWarpAugment(**settings)(image, ...)`` in one call.

    Each sample gets its own draw; the optional keypoints, masks and boxes of a sample follow its image. Use
    :class:`FluidWarpAugment` to keep the settings (and a generator) across calls, and
    ``torchfluidwarp.RandomFluidWarp`` (:class:`~torchfluidwarp.augment.transforms.RandomFluidWarp`) in a torchvision
    pipeline.

    Args:
        image: ``(B, C, H, W)`` or ``(C, H, W)``, any dtype (integers are rounded back).
        keypoints: ``(B, M, 2)`` (``(M, 2)`` unbatched) pixels ``(x, y)``, pixel centres at integers.
        masks: ``(B, K, H, W)`` (``(K, H, W)`` unbatched), any dtype; nearest sampling.
        boxes: ``(B, N, 4)`` (``(N, 4)`` unbatched) ``(x1, y1, x2, y2)`` pixels.
        count, strength, radius, steps, grid, dt, viscosity, edge_points, max_retries, generator: the settings
            of :class:`FluidWarpAugment`.

    Returns:
        the warped image when only an image is given; otherwise a dict with the keys ``"image"`` and those of
        the other inputs given.

    Raises:
        TypeError, ValueError: as :class:`FluidWarpAugment` and its ``forward``.

    Example:
        >>> out = random_fluid_warp(torch.rand(3, 32, 32), keypoints=torch.tensor([[10.0, 12.0]]),
        ...                         strength=(0.1, 0.2), radius=(8.0, 12.0), generator=torch.Generator().manual_seed(0))
        >>> out["image"].shape, out["keypoints"].shape
        (torch.Size([3, 32, 32]), torch.Size([1, 2]))
    """
    aug = FluidWarpAugment(
        count,
        strength,
        radius,
        steps,
        grid=grid,
        dt=dt,
        viscosity=viscosity,
        edge_points=edge_points,
        max_retries=max_retries,
        generator=generator,
    )
    return aug(image, keypoints=keypoints, masks=masks, boxes=boxes)
