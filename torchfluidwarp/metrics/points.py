"""Where points show in a frame, and the errors built on it: the end error (held out or marked), ghosting, and
the fit's landmark error. Maps ``(1, H, W, 2)`` (or ``(H, W, 2)``) are backward maps in pixels, ``(x, y)``."""

from __future__ import annotations

import torch
from torch import Tensor

from torchfluidwarp._checks import check_tensor
from torchfluidwarp.control.keyframes import KeyframeFit
from torchfluidwarp.metrics.maps import _one_map
from torchfluidwarp.warp import warp_image

LOCATE_TOLERANCE = 0.1
"""Source pixels: a point is located in a frame when the map at the found position is this close to it."""


def read_map(map1: Tensor, points: Tensor) -> Tensor:
    """A map ``(1, H, W, 2)`` read bilinearly at ``points`` ``(K, 2)`` (pixels of the map's grid): ``(K, 2)``
    float64 (beyond the grid the edge values are held)."""
    img = map1.permute(0, 3, 1, 2)  # (1, 2, H, W): the map as a 2-channel image
    out = warp_image(img, points.to(img.dtype).view(1, 1, -1, 2))  # (1, 2, 1, K)
    return out[0, :, 0].T.double()


def invert_map_at(map1: Tensor, targets: Tensor, init: Tensor, iters: int = 30) -> tuple[Tensor, Tensor]:
    """Points ``y`` with ``map1(y) = targets`` by Newton's method from ``init``.

    Args:
        map1: ``(1, H, W, 2)`` backward map, pixels.
        targets: ``(K, 2)`` source positions, pixels.
        init: ``(K, 2)`` starting positions in the map's grid, pixels.
        iters: Newton steps. The Jacobian is a central difference of the bilinearly read map over half a pixel;
            a step is capped at 16 px.

    Returns:
        ``(y, residual)``: ``(K, 2)`` float64 positions and ``(K,)`` ``|map1(y) - targets|`` in source pixels.
    """
    y = init.double().clone()
    h = 0.5
    ex, ey = y.new_tensor([h, 0.0]), y.new_tensor([0.0, h])
    for _ in range(iters):
        r = read_map(map1, y) - targets  # (K, 2)
        jx = (read_map(map1, y + ex) - read_map(map1, y - ex)) / (2 * h)
        jy = (read_map(map1, y + ey) - read_map(map1, y - ey)) / (2 * h)
        jac = torch.stack([jx, jy], dim=-1)  # (K, 2, 2): columns d/dx, d/dy
        ok = torch.linalg.det(jac).abs() > 1e-9
        step = torch.zeros_like(y)
        step[ok] = torch.linalg.solve(jac[ok], r[ok].unsqueeze(-1)).squeeze(-1)
        norm = step.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        y = y - step * (16.0 / norm).clamp(max=1.0)
    return y, (read_map(map1, y) - targets).norm(dim=-1)


def locate(
    map1: Tensor, targets: Tensor, init: Tensor | None = None, tolerance: float = LOCATE_TOLERANCE
) -> tuple[Tensor, Tensor]:
    """Where a frame shows source points: the ``y`` with ``map1(y) = targets``.

    Args:
        map1: ``(H, W, 2)`` or ``(1, H, W, 2)`` the frame's backward map, pixels.
        targets: ``(K, 2)`` points in the source's pixels.
        init: ``(K, 2)`` where to start Newton's method; by default the pixel whose map value is nearest each
            target.
        tolerance: source pixels: a point is located when ``|map1(y) - target|`` is at most this.

    Returns:
        ``(y, located)``: ``(K, 2)`` float64 positions in the frame's pixels and a ``(K,)`` bool mask.
    """
    m = _one_map("map1", map1)
    check_tensor("targets", targets, shape=[None, 2])
    W = m.shape[2]
    flat = m.reshape(-1, 2).double()
    targets = targets.double().to(flat.device)
    if init is None:
        idx = torch.cat([torch.cdist(t, flat).argmin(1) for t in targets.split(16)]) if len(targets) else flat[:0, 0]
        init = torch.stack([idx % W, idx // W], dim=-1).double()
    y, residual = invert_map_at(m, targets, init)
    return y, residual <= tolerance


def end_error(
    map_last: Tensor, points_a: Tensor, points_b: Tensor, init: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    """The end error of points: how far from B's points A's points show in the last frame.

    For points that were not marked (held out) this is the held-out error; for the marked ones it agrees with the
    fit's own error up to the rendering.

    Args:
        map_last: ``(H, W, 2)`` or ``(1, H, W, 2)`` the last frame's backward map into A, pixels.
        points_a: ``(K, 2)`` A's points, A's pixels.
        points_b: ``(K, 2)`` B's corresponding points, in the last frame's pixels.
        init: ``(K, 2)`` Newton's starting points (see :func:`locate`).

    Returns:
        ``(distance, located)``: ``(K,)`` float64 pixels and the ``(K,)`` mask of A's points located.
    """
    check_tensor("points_b", points_b, shape=[points_a.shape[0], 2])
    y, ok = locate(map_last, points_a, init)
    return (y - points_b.to(y)).norm(dim=-1), ok


def ghosting(map_a: Tensor, map_b: Tensor, points_a: Tensor, points_b: Tensor) -> tuple[Tensor, Tensor]:
    """Ghosting in a frame: the distance between where A's copy and where B's copy of each point show in it.

    Args:
        map_a: ``(H, W, 2)`` or ``(1, H, W, 2)`` the frame's backward map into A, pixels.
        map_b: the same into B.
        points_a: ``(K, 2)`` points in A's pixels.
        points_b: ``(K, 2)`` the same features in B's pixels.

    Returns:
        ``(distance, located)``: ``(K,)`` float64 frame pixels, and the mask of the points located in both.
    """
    check_tensor("points_b", points_b, shape=[points_a.shape[0], 2])
    y, ok_y = locate(map_a, points_a)
    z, ok_z = locate(map_b, points_b)
    return (y - z).norm(dim=-1), ok_y & ok_z


def landmark_error(fit: KeyframeFit) -> Tensor:
    """``(M,)`` the fit's distance in pixels from each marked point to its target at the last keyframe
    (``fit.error`` of a single-pair fit); 0 for an exact fit."""
    return fit.error.detach().reshape(-1).double()
