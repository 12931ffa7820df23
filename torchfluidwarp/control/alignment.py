"""Global pre-alignment from corresponding points: similarity or affine, and its interpolation over time.

A closed incompressible fluid can neither translate a whole picture nor change areas, so a morph between
two photos first estimates a global transform ``M`` with ``M a_i ~ b_i`` and lets the fluid handle the local,
non-rigid rest. Matrices are ``(3, 3)`` homogeneous, acting on pixel coordinates ``(x, y, 1)``.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
from torch import Tensor

from torchfluidwarp._checks import check_tensor
from torchfluidwarp.errors import InputError

__all__ = ["estimate_alignment", "interpolate_alignment", "apply_alignment"]

AlignKind = Literal["similarity", "affine", "none"]


def estimate_alignment(points_a: Tensor, points_b: Tensor, kind: AlignKind | None = "similarity") -> Tensor:
    """Least-squares transform ``M`` ``(3, 3)`` with ``M [a_i; 1] ~ [b_i; 1]``.

    Args:
        points_a, points_b: ``(M, 2)`` corresponding points in pixels.
        kind: ``"similarity"`` (scale, rotation, translation; Umeyama 1991; needs 2 points), ``"affine"``
            (needs 3 non-collinear points) or ``"none"``/``None`` (identity).

    Example:
        >>> a = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
        >>> M = estimate_alignment(a, 2 * a + 3)  # scale 2, shift (3, 3)
        >>> torch.allclose(M, torch.tensor([[2.0, 0.0, 3.0], [0.0, 2.0, 3.0], [0.0, 0.0, 1.0]]), atol=1e-6)
        True
    """
    a = check_tensor("points_a", points_a, shape=[None, 2]).double()
    b = check_tensor("points_b", points_b, shape=[None, 2]).double()
    if a.shape != b.shape:
        raise InputError(f"points_a has {a.shape[0]} points but points_b has {b.shape[0]}", argument="points_b")
    eye = torch.eye(3, dtype=torch.float64, device=a.device)
    if kind in (None, "none"):
        return eye.to(points_a.dtype)
    ca, cb = a.mean(0), b.mean(0)
    da, db = a - ca, b - cb
    if kind == "similarity":
        if a.shape[0] < 2 or float((da**2).sum()) == 0:
            raise InputError(
                f"a similarity alignment needs at least 2 distinct points in points_a, got {a.shape[0]} points "
                f"spread over {float((da**2).sum()):.3g} px^2",
                argument="points_a",
            )
        u, s, vh = torch.linalg.svd(db.T @ da / a.shape[0])
        d = torch.ones(2, dtype=torch.float64, device=a.device)
        d[1] = torch.sign(torch.linalg.det(u @ vh))  # no reflections
        rot = u @ torch.diag(d) @ vh
        scale = float((s * d).sum() / (da**2).sum(1).mean())
        lin = scale * rot
    elif kind == "affine":
        if a.shape[0] < 3:
            raise InputError(f"an affine alignment needs at least 3 points, got {a.shape[0]}", argument="points_a")
        sol = torch.linalg.lstsq(da, db).solution  # (2, 2): db ~ da @ sol
        lin = sol.T
        if abs(float(torch.linalg.det(lin))) < 1e-9:
            raise InputError("an affine alignment needs 3 non-collinear points", argument="points_a")
    else:
        raise InputError(f"kind must be 'similarity', 'affine' or 'none', got {kind!r}", argument="kind")
    m = eye.clone()
    m[:2, :2] = lin
    m[:2, 2] = cb - lin @ ca
    return m.to(points_a.dtype)


def interpolate_alignment(matrix: Tensor, u: float, center: Tensor | None = None) -> Tensor:
    """The transform a fraction ``u`` in ``[0, 1]`` of the way from the identity to ``matrix``.

    A similarity (``A = s R``) interpolates its scale geometrically and its angle linearly; any other linear
    part interpolates linearly. The translation is chosen so that ``center`` (e.g. the centroid of the
    source points; default the origin) moves on a straight line to its image.
    """
    m = matrix.double()
    lin = m[:2, :2]
    ata = lin.T @ lin
    eye = torch.eye(2, dtype=torch.float64, device=m.device)
    is_similarity = bool(torch.allclose(ata, ata[0, 0] * eye, atol=1e-9 * float(ata.abs().max() + 1)))
    if is_similarity and float(torch.linalg.det(lin)) > 0:
        s = math.sqrt(float(ata[0, 0]))
        angle = math.atan2(float(lin[1, 0]), float(lin[0, 0]))
        su, au = s**u, angle * u
        rotation = [[math.cos(au), -math.sin(au)], [math.sin(au), math.cos(au)]]
        lin_u = su * torch.tensor(rotation, dtype=torch.float64, device=m.device)
    else:
        lin_u = (1 - u) * eye + u * lin
    c = m.new_zeros(2) if center is None else center.to(m)
    target = c + u * (lin @ c + m[:2, 2] - c)
    out = torch.eye(3, dtype=torch.float64, device=m.device)
    out[:2, :2] = lin_u
    out[:2, 2] = target - lin_u @ c
    return out.to(matrix.dtype)


def apply_alignment(matrix: Tensor, points: Tensor) -> Tensor:
    """Apply a ``(3, 3)`` transform to ``(..., 2)`` points."""
    m = matrix.to(points.dtype).to(points.device)
    return points @ m[:2, :2].T + m[:2, 2]
