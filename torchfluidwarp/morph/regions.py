"""Regions and backgrounds: limit a morph to part of the picture, and put a morphed frame back into a photo.

A region is a soft mask ``(H, W)`` in ``[0, 1]`` over each image (1 inside, 0 outside, a smooth ramp between),
given per image or made from the points (:func:`hull_mask`: their convex hull grown by a margin). Each frame
carries A's mask along A's map and B's along B's, mixes them with the colour weight, and shows the morph inside
and the background outside (A's, B's, or their cross-dissolve), blended over the ramp so that no seam shows.
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor

from torchfluidwarp._checks import check_positive, check_tensor
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import premultiplied, resize_image, straight

__all__ = ["Background", "hull_mask", "paste_back"]

Background = Literal["a", "b", "blend"]


def _convex_hull(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Counter-clockwise hull (Andrew's monotone chain) of a few points (image axes: x right, y down)."""
    pts = sorted(set(points))
    if len(pts) < 3:
        return pts

    def cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    upper: list[tuple[float, float]] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return lower[:-1] + upper[:-1]


def hull_mask(points: Tensor, size: tuple[int, int], margin: float = 0.25, band: float | None = None) -> Tensor:
    """A soft mask ``(H, W)`` of the points' convex hull, grown by ``margin`` times its extent.

    Args:
        points: ``(M, 2)`` pixels ``(x, y)``, at least 3 not on one line.
        size: ``(H, W)`` of the mask.
        margin: how far the region reaches beyond the hull, as a fraction of the points' larger extent.
        band: width in pixels of the ramp from 1 to 0 at the region's edge (default a tenth of the extent).

    Returns:
        ``(H, W)`` in ``[0, 1]``, on the points' device, in their dtype (float32 at least).

    Example:
        >>> m = hull_mask(torch.tensor([[8.0, 8.0], [24.0, 8.0], [16.0, 24.0]]), (32, 32), margin=0.0, band=2.0)
        >>> float(m[14, 16]), float(m[2, 2])
        (1.0, 0.0)
    """
    p = check_tensor("points", points, shape=[None, 2])
    margin = check_positive("margin", margin, allow_zero=True)
    hull = _convex_hull([(float(x), float(y)) for x, y in p.tolist()])
    if len(hull) < 3:
        raise InputError(f"points must hold 3 points not on one line to make a region, got {p.shape[0]} points")
    extent = float((p.max(0).values - p.min(0).values).max())
    band = 0.1 * extent if band is None else check_positive("band", band)
    dtype = p.dtype if p.dtype in (torch.float32, torch.float64) else torch.float32
    H, W = size
    ys = torch.arange(H, device=p.device, dtype=dtype).view(H, 1)
    xs = torch.arange(W, device=p.device, dtype=dtype).view(1, W)
    # outward distance to each edge's line; for a convex polygon their maximum is <= 0 exactly inside it
    distance = torch.full((H, W), -float("inf"), device=p.device, dtype=dtype)
    for (x0, y0), (x1, y1) in zip(hull, hull[1:] + hull[:1]):
        length = max(((x1 - x0) ** 2 + (y1 - y0) ** 2) ** 0.5, 1e-12)
        nx, ny = (y1 - y0) / length, -(x1 - x0) / length  # outward normal of a counter-clockwise edge (y down)
        distance = torch.maximum(distance, (xs - x0) * nx + (ys - y0) * ny)
    return ((margin * extent - distance) / band + 0.5).clamp(0, 1)


def composite(frame: Tensor, background: Tensor, mask: Tensor) -> Tensor:
    """``mask * frame + (1 - mask) * background``: ``(1, C, H, W)`` twice and a mask ``(1, 1, H, W)``."""
    return torch.lerp(background, frame, mask)


def paste_back(
    frame: Tensor, photo: Tensor, box: tuple[int, int, int, int], *, mask: Tensor | None = None, band: float = 8.0
) -> Tensor:
    """Place a morphed ``frame`` ``(C, h, w)`` into the full-size ``photo`` ``(C, H, W)`` over ``box``.

    The frame is resized to the box ``(x0, y0, x1, y1)`` (pixels of the photo; x1, y1 exclusive) and blended in
    with ``mask`` ``(h, w)`` (the region the frame should replace; default the whole box), whose edge, and the
    box's, fades over ``band`` photo pixels so that no seam shows. Parts of the box beyond the photo are
    dropped. Pictures with alpha (``C`` 2 or 4) are resized and blended premultiplied, as the morph's frames are
    (:func:`~torchfluidwarp.io.images.premultiplied`): no colour stored under a transparent pixel shows. Returns a
    new photo ``(C, H, W)``; ``photo`` is left as it was, and so is the new one outside the box.
    """
    f = check_tensor("frame", frame, ndim=3)
    ph = check_tensor("photo", photo, ndim=3)
    if f.shape[0] != ph.shape[0]:
        raise InputError(f"frame has {f.shape[0]} channels but photo has {ph.shape[0]}")
    x0, y0, x1, y1 = (int(v) for v in box)
    if x1 <= x0 or y1 <= y0:
        raise InputError(f"box must be (x0, y0, x1, y1) with x1 > x0 and y1 > y0, got {box}")
    band = check_positive("band", band, allow_zero=True)
    h, w = y1 - y0, x1 - x0
    resized = resize_image(premultiplied(f[None].to(ph.dtype)), (h, w))[0]
    m = torch.ones(1, f.shape[1], f.shape[2], dtype=ph.dtype, device=ph.device) if mask is None else mask[None]
    m = check_tensor("mask", m, shape=[1, f.shape[1], f.shape[2]]).to(ph.dtype)
    m = resize_image(m[None], (h, w))[0]
    if band > 0:  # fade in from the box's edges too
        ys = torch.arange(h, device=ph.device, dtype=ph.dtype).view(h, 1)
        xs = torch.arange(w, device=ph.device, dtype=ph.dtype).view(1, w)
        inside = torch.minimum(torch.minimum(xs + 0.5, w - 0.5 - xs), torch.minimum(ys + 0.5, h - 0.5 - ys))
        m = m * (inside / band).clamp(0, 1)
    out = ph.clone()
    # the part of the box inside the photo
    H, W = ph.shape[-2:]
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    if cx1 <= cx0 or cy1 <= cy0:
        return out
    sl = (slice(None), slice(cy0 - y0, cy1 - y0), slice(cx0 - x0, cx1 - x0))
    region = premultiplied(out[None, :, cy0:cy1, cx0:cx1])[0]
    out[:, cy0:cy1, cx0:cx1] = straight(torch.lerp(region, resized[sl], m[sl])[None])[0]
    return out
