"""Measures of one backward map or a stack of them: folded pixels and the seam figure."""

from __future__ import annotations

import torch
from torch import Tensor

from torchfluidwarp._checks import check_tensor
from torchfluidwarp.warp import jacobian_determinant

SEAM_QUANTILE = 0.999
"""The quantile of :func:`seam_figure` over a map's interior pixels."""


def _one_map(name: str, map1: Tensor) -> Tensor:
    """A map ``(H, W, 2)`` or ``(1, H, W, 2)`` as ``(1, H, W, 2)``."""
    check_tensor(name, map1)
    m = map1.unsqueeze(0) if map1.ndim == 3 else map1
    check_tensor(name, m, shape=[1, None, None, 2])
    return m


def folded_pixels(maps: Tensor) -> Tensor:
    """Folded pixels per frame: where a map's Jacobian determinant
    (:func:`~torchfluidwarp.warp.jacobian_determinant`) is ``<= 0``.

    Args:
        maps: ``(N, H, W, 2)`` or one map ``(H, W, 2)``, pixels.

    Returns:
        ``(N,)`` int64 counts (``(1,)`` for one map); 0 everywhere for a fold-free morph.

    Example:
        >>> from torchfluidwarp.warp import identity_map
        >>> m = identity_map((4, 8))
        >>> folded_pixels(m).tolist()
        [0]
        >>> m[..., 0] = 7 - m[..., 0]  # mirrored left to right: det J = -1 everywhere
        >>> folded_pixels(m).tolist()
        [32]
    """
    check_tensor("maps", maps)
    m = maps.unsqueeze(0) if maps.ndim == 3 else maps
    return (jacobian_determinant(m) <= 0).flatten(1).sum(1)


def seam_figure(map1: Tensor, q: float = SEAM_QUANTILE) -> float:
    """The seam figure of a map: the ``q`` quantile over its interior pixels of the second derivative's norm,
    ``sqrt(sum_c (d_xx m_c)^2 + 2 (d_xy m_c)^2 + (d_yy m_c)^2)`` by central second differences (float64).

    Zero for an affine map; a seam where the warp's stretch jumps (a triangle's edge, a fluid box's wall) raises
    it: a stretch that jumps from 1 to 1.5 at one column gives 0.5.

    Args:
        map1: ``(H, W, 2)`` or ``(1, H, W, 2)`` backward map, pixels, ``H, W >= 3``.
        q: the quantile, in ``[0, 1]``.

    Returns:
        px/px^2.
    """
    m = _one_map("map1", map1)[0].double()
    c = m[1:-1, 1:-1]
    dxx = m[1:-1, 2:] - 2 * c + m[1:-1, :-2]
    dyy = m[2:, 1:-1] - 2 * c + m[:-2, 1:-1]
    dxy = (m[2:, 2:] - m[2:, :-2] - m[:-2, 2:] + m[:-2, :-2]) / 4
    norm = (dxx.square() + 2 * dxy.square() + dyy.square()).sum(-1).sqrt()  # (H - 2, W - 2)
    return float(torch.quantile(norm.flatten(), q))
