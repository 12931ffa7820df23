"""The textbook thin-plate spline (Bookstein 1989), as a linear interpolation operator.

``f(x) = a_0 + a_1 x + a_2 y + sum_i w_i U(|x - c_i|)`` with ``U(r) = r^2 log r``, the function through
given values at the centres ``c_i`` that minimises the bending energy ``int f_xx^2 + 2 f_xy^2 + f_yy^2``.
:func:`tps_fit` solves the system once and returns the spline as a function; for fixed centres the spline is
linear in the values, so :func:`tps_cardinal` returns the matrix that takes values at the centres to the
spline at any points (:class:`~torchfluidwarp.warp.landmarks.LandmarkForces` caches it).

kornia's ``get_tps_transform`` solves a different system (kernels centred on the destination points, evaluated
at the source points), which cannot prescribe values at fixed centres; hence this small module.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from torchfluidwarp._checks import check_tensor
from torchfluidwarp.errors import InputError

__all__ = ["tps_kernel", "tps_fit", "tps_cardinal", "tps_interpolate"]


def tps_kernel(a: Tensor, b: Tensor) -> Tensor:
    """``U(|a_i - b_j|) = r^2 log r`` for points ``a`` ``(N, 2)`` and ``b`` ``(M, 2)``: ``(N, M)`` (0 at r = 0)."""
    r2 = torch.cdist(a, b).square()
    return torch.where(r2 > 0, 0.5 * r2 * torch.log(torch.where(r2 > 0, r2, torch.ones_like(r2))), torch.zeros_like(r2))


def tps_fit(centers: Tensor, values: Tensor, smoothing: float = 0.0) -> Callable[[Tensor], Tensor]:
    """The thin-plate spline through ``values`` ``(M, D)`` at ``centers`` ``(M, 2)``, as a function of points.

    The system is solved once, in float64; the returned function maps points ``(N, 2)`` to ``(N, D)`` (in
    ``values``' dtype) and costs one ``N x M`` kernel evaluation per call.

    Args:
        centers: ``(M, 2)`` distinct points (any unit, e.g. pixels), ``M >= 3`` and not all on one line.
        values: ``(M, D)`` the values at the centres.
        smoothing: ``lambda >= 0``: 0 interpolates; larger values trade the values at the centres for less
            bending (the smoothing spline of Wahba 1990, kernel matrix ``K + lambda I``), with ``lambda`` in
            units of the centres' half-spread squared, so it means the same at any scale.

    Raises:
        ValueError: fewer than 3 centres, or centres that repeat or lie on one line (the system is singular).

    Example:
        >>> c = torch.tensor([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
        >>> f = tps_fit(c, c @ torch.tensor([[2.0], [3.0]]) + 1)  # an affine function is reproduced exactly
        >>> round(float(f(torch.tensor([[5.0, 5.0]]))[0, 0]), 6)
        26.0
    """
    c = check_tensor("centers", centers, shape=[None, 2]).double()
    v = check_tensor("values", values, ndim=2)
    m = c.shape[0]
    if m < 3:
        raise InputError(f"a thin-plate spline needs at least 3 centres, got {m}")
    if v.shape[0] != m:
        raise InputError(f"values must have one row per centre ({m}), got shape {tuple(v.shape)}")
    # shift and scale to a unit box: the same spline, a better-conditioned system
    origin, scale = c.mean(0), float((c - c.mean(0)).abs().max()) or 1.0
    c = (c - origin) / scale
    ones = torch.ones(m, 1, dtype=torch.float64, device=c.device)
    poly = torch.cat([ones, c], 1)  # (M, 3)
    system = torch.zeros(m + 3, m + 3, dtype=torch.float64, device=c.device)
    system[:m, :m] = tps_kernel(c, c) + smoothing * torch.eye(m, dtype=torch.float64, device=c.device)
    system[:m, m:] = poly
    system[m:, :m] = poly.T
    rhs = torch.zeros(m + 3, v.shape[1], dtype=torch.float64, device=c.device)
    rhs[:m] = v.double()
    coef = torch.linalg.solve_ex(system, rhs)[0]  # (M + 3, D): kernel weights, then a_0, a_1, a_2
    if not bool(torch.isfinite(coef).all()) or float(coef.abs().max()) > 1e12 * (1 + float(v.abs().max())):
        raise InputError(
            f"centers must be at least 3 distinct points, not all on one line: the spline's system is singular "
            f"for the {m} centres given"
        )

    def spline(at: Tensor) -> Tensor:
        x = (check_tensor("at", at, shape=[None, 2]).double() - origin) / scale
        basis = torch.cat([tps_kernel(x, c), torch.ones(x.shape[0], 1, dtype=torch.float64, device=c.device), x], 1)
        return (basis @ coef).to(v.dtype)

    return spline


def tps_cardinal(centers: Tensor, at: Tensor, smoothing: float = 0.0) -> Tensor:
    """The matrix ``C`` ``(N, M)`` with ``f(at) = C @ values``, the spline through ``values`` at ``centers``.

    Column ``i`` is the cardinal function of centre ``i``: 1 there, 0 at the other centres, minimal bending
    elsewhere. Returned in ``at``'s dtype; ``smoothing`` as for :func:`tps_fit`.

    Example:
        >>> c = torch.tensor([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
        >>> bool(torch.allclose(tps_cardinal(c, c), torch.eye(4), atol=1e-9))
        True
    """
    eye = torch.eye(centers.shape[0], dtype=torch.float64, device=centers.device)
    return tps_fit(centers, eye, smoothing)(at).to(at.dtype)


def tps_interpolate(centers: Tensor, values: Tensor, at: Tensor, smoothing: float = 0.0) -> Tensor:
    """The thin-plate spline through ``values`` ``(M, D)`` at ``centers`` ``(M, 2)``, evaluated at ``at`` ``(N, 2)``
    (see :func:`tps_fit`)."""
    return tps_fit(centers, values, smoothing)(at)
