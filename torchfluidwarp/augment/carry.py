"""Moving the inputs of a call through one drawn warp: images and masks resampled, points and boxes carried.

* images are resampled bilinearly through the **backward map** (where each output pixel reads from,
  :func:`fluid_warp_map`), through the library's one guarded sampler
  (:func:`~torchfluidwarp.warp.frames.warp_image`, over :func:`~torchfluidwarp.core.sampling.sample`);
* masks are resampled by nearest sampling, so label values survive unchanged;
* keypoints are carried by the **forward map**: RK2 particles through the very same velocities
  (:meth:`~torchfluidwarp.warp.layer.FluidWarp.carry_points`), not an approximate inverse (:func:`carry_points`);
* boxes and polygons become points along their outlines, carried like keypoints (:func:`carry_boxes`,
  :func:`polygon_outline`).

Conventions (see :mod:`torchfluidwarp.core.grid`): points and boxes are in **pixels** ``(x, y)`` with pixel
centres at integers, so the image covers ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``; boxes are ``(x1, y1, x2, y2)``.
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor

from torchfluidwarp.augment.draw import FluidWarpParams, raster_map
from torchfluidwarp.core.grid import rescale_points, scale_factor
from torchfluidwarp.core.staggered import StaggeredGrid
from torchfluidwarp.warp.frames import identity_map, warp_image
from torchfluidwarp.warp.maps import upsample_raster

__all__ = [
    "fluid_warp_map",
    "carry_points",
    "carry_boxes",
    "box_outline",
    "polygon_outline",
    "apply_fluid_warp",
]


def _upsample(coords: Tensor, size: tuple[int, int]) -> Tensor:
    """Resize a raster map ``(B, h_r, w_r, 2)`` to ``(B, H, W, 2)`` by resizing its displacement bilinearly."""
    H, W = size
    h_r, w_r = coords.shape[1:3]
    if (h_r, w_r) == (H, W):
        return coords
    device, dtype = coords.device, coords.dtype
    scale = scale_factor((h_r, w_r), (H, W), device=device, dtype=dtype)  # raster pixels -> image pixels
    ident = rescale_points(identity_map((h_r, w_r), device=device, dtype=dtype), scale)  # raster centres, image px
    disp = upsample_raster((coords - ident).permute(0, 3, 1, 2), (H, W))  # image pixels
    return identity_map((H, W), device=device, dtype=dtype) + disp.permute(0, 2, 3, 1)


def fluid_warp_map(params: FluidWarpParams, size: tuple[int, int] | None = None) -> Tensor:
    """The backward map of each sample's last step: ``(B, H, W, 2)`` source positions in pixels.

    The map is composed on a raster of at most :data:`~torchfluidwarp.warp.maps.OVERSAMPLE` points per fluid cell
    and axis (:func:`~torchfluidwarp.augment.draw.raster_map`), then its displacement is resized bilinearly to
    ``(H, W)`` once (:func:`~torchfluidwarp.warp.maps.upsample_raster`), as
    :func:`~torchfluidwarp.warp.maps.iter_backward_maps` does for a full-size map; the raster map is kept in the
    draw (its folds are checked there), so this costs one resize.

    Args:
        params: a draw.
        size: ``(H, W)``; the draw's own size by default (any other size is composed afresh).
    """
    size = params.size if size is None else size
    coords = params.raster_map if size == params.size else raster_map(params.velocities, size, params.dt)
    return _upsample(coords, size)


def _clamp_to_image(points: Tensor, size: tuple[int, int]) -> Tensor:
    """Points ``(..., 2)`` (pixels) clamped into the image rectangle ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``."""
    H, W = size
    lo = torch.tensor([-0.5, -0.5], device=points.device, dtype=points.dtype)
    hi = torch.tensor([W - 0.5, H - 0.5], device=points.device, dtype=points.dtype)
    return torch.maximum(torch.minimum(points, hi), lo)


def carry_points(params: FluidWarpParams, points: Tensor, size: tuple[int, int] | None = None) -> Tensor:
    """Carry points ``(B, M, 2)`` (pixels) to each sample's last step with RK2 through the velocities.

    This is :meth:`~torchfluidwarp.warp.layer.FluidWarp.carry_points` on the drawn velocities: the same particles
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
    inside = _clamp_to_image(p, (H, W))
    carried = StaggeredGrid.of(vel).trajectories(vel, inside, params.dt, (H, W))[:, -1]
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
    if N == 0:
        return boxes.clone()
    outline = box_outline(boxes.to(params.velocities.dtype), edge_points)  # (B, N, 4E, 2)
    moved = carry_points(params, outline.reshape(B, -1, 2), size).view(B, N, -1, 2)
    out = torch.cat([moved.amin(2), moved.amax(2)], dim=-1)
    if clip:
        out = _clamp_to_image(out.unflatten(-1, (2, 2)), size).flatten(-2)  # both corners of each box
    return out.to(boxes.dtype)


def _resample(x: Tensor, coords: Tensor, mode: Literal["bilinear", "nearest"]) -> Tensor:
    """Warp ``(B, C, H, W)`` of any dtype through a backward map ``(B, H, W, 2)`` (pixels).

    Floating images are sampled in their dtype; integer ones are sampled in ``coords``' dtype, then rounded
    back and clamped to their range; booleans are sampled nearest and stay booleans.
    """
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
        params: a draw (:func:`~torchfluidwarp.augment.draw.draw_fluid_warp`).
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
