"""Stable Fluids on a staggered grid: pure functions.

One step is Stam's splitting (Stable Fluids, 1999): add force -> advect -> diffuse -> project. Every function
takes and returns a staggered velocity ``(B, 2, h + 1, w + 1)`` in fluid cells per time unit (layout in
:mod:`torchfluidwarp.core.grid`), with solid walls, is differentiable, and follows the input's device and dtype.
The modules in :mod:`torchfluidwarp.core.simulator` are thin wrappers over these.

This module holds the grid operators (divergence, gradient, the staggered <-> cell-centred averages, the
Laplacian and strain operators) and the two implicit solves, :func:`diffuse` and :func:`project`. The
semi-Lagrangian steps live in :mod:`torchfluidwarp.core.advection`; the layout itself in
:class:`~torchfluidwarp.core.staggered.StaggeredGrid`.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import check_positive, check_tensor
from torchfluidwarp.core.linalg import CGConfig, implicit_solve
from torchfluidwarp.core.spectral import (
    SpectralBases,
    neumann_filter,
    solve_pressure_poisson,
    solve_velocity_helmholtz,
)
from torchfluidwarp.core.staggered import StaggeredGrid
from torchfluidwarp.errors import InputError

__all__ = [
    "divergence",
    "gradient",
    "faces_from_cells",
    "cells_from_faces",
    "vector_laplacian",
    "strain_operator",
    "diffuse",
    "project",
    "check_viscosity",
]

Viscosity = float | Tensor


def divergence(velocity: Tensor) -> Tensor:
    """Discrete divergence of a staggered velocity, per cell: ``(B, 1, h, w)`` in 1 / time unit.

    ``u[j, i + 1] - u[j, i] + v[j + 1, i] - v[j, i]``.
    """
    u, v = StaggeredGrid.components(velocity)
    return (u.diff(dim=-1) + v.diff(dim=-2)).unsqueeze(1)


def gradient(p: Tensor) -> Tensor:
    """Gradient of a cell-centred ``(B, 1, h, w)`` field onto the interior faces: ``(B, 2, h + 1, w + 1)``."""
    q = p[:, 0]
    gu = F.pad(q[..., 1:] - q[..., :-1], (1, 1, 0, 1))
    gv = F.pad(q[:, 1:] - q[:, :-1], (0, 1, 1, 1))
    return torch.stack([gu, gv], dim=1)


def faces_from_cells(field: Tensor) -> Tensor:
    """Average a cell-centred vector field ``(B, 2, h, w)`` onto the interior faces ``(B, 2, h + 1, w + 1)``."""
    fu = F.pad(0.5 * (field[:, 0, :, 1:] + field[:, 0, :, :-1]), (1, 1, 0, 1))
    fv = F.pad(0.5 * (field[:, 1, 1:] + field[:, 1, :-1]), (0, 1, 1, 1))
    return torch.stack([fu, fv], dim=1)


def cells_from_faces(velocity: Tensor) -> Tensor:
    """Average a staggered velocity onto cell centres: ``(B, 2, h, w)``, channel 0 = x."""
    u, v = StaggeredGrid.components(velocity)
    return torch.stack([0.5 * (u[..., 1:] + u[..., :-1]), 0.5 * (v[:, 1:] + v[:, :-1])], dim=1)


def vector_laplacian(velocity: Tensor) -> Tensor:
    """Vector Laplacian of a staggered velocity: no flow through the walls, free slip along them."""
    u, v = StaggeredGrid.components(velocity)
    uy = F.pad(u.unsqueeze(1), (0, 0, 1, 1), mode="replicate")[:, 0]
    lu = (u[..., 2:] - 2 * u[..., 1:-1] + u[..., :-2]) + (uy[:, 2:, 1:-1] - 2 * u[:, :, 1:-1] + uy[:, :-2, 1:-1])
    vx = F.pad(v.unsqueeze(1), (1, 1, 0, 0), mode="replicate")[:, 0]
    lv = (v[:, 2:] - 2 * v[:, 1:-1] + v[:, :-2]) + (vx[:, 1:-1, 2:] - 2 * v[:, 1:-1] + vx[:, 1:-1, :-2])
    return StaggeredGrid.pack(F.pad(lu, (1, 1)), F.pad(lv, (0, 0, 1, 1)))


def strain_operator(velocity: Tensor, viscosity: Tensor) -> Tensor:
    """``-div(mu (grad v + grad v^T))`` on the staggered grid, for a viscosity field ``mu`` ``(B|1, 1, h, w)``.

    It is the gradient of the discrete energy ``sum_cells mu (e_xx^2 + e_yy^2) + sum_corners mu/2 (u_y + v_x)^2``
    (shear is zero on the walls: free slip), hence symmetric positive semi-definite, and it couples ``u``
    and ``v``. The viscosity at a corner is the mean of its four cells.
    """
    u, v = StaggeredGrid.components(velocity)
    mu = viscosity[:, 0]
    mu_n = 0.25 * (mu[:, 1:, 1:] + mu[:, :-1, 1:] + mu[:, 1:, :-1] + mu[:, :-1, :-1])  # (B, h-1, w-1)
    qx = 2 * mu * (u[..., 1:] - u[..., :-1])  # (B, h, w)
    qy = 2 * mu * (v[:, 1:] - v[:, :-1])  # (B, h, w)
    t = mu_n * ((u[:, 1:, 1:-1] - u[:, :-1, 1:-1]) + (v[:, 1:-1, 1:] - v[:, 1:-1, :-1]))  # (B, h-1, w-1)
    gu = F.pad(qx, (1, 0)) - F.pad(qx, (0, 1))
    gu = gu + F.pad(F.pad(t, (0, 0, 1, 0)) - F.pad(t, (0, 0, 0, 1)), (1, 1))
    gv = F.pad(qy, (0, 0, 1, 0)) - F.pad(qy, (0, 0, 0, 1))
    gv = gv + F.pad(F.pad(t, (1, 0)) - F.pad(t, (0, 1)), (0, 0, 1, 1))
    h, w = u.shape[-2], v.shape[-1]
    gu = torch.cat([gu[..., :1] * 0, gu[..., 1:w], gu[..., :1] * 0], dim=-1)
    gv = torch.cat([gv[:, :1] * 0, gv[:, 1:h], gv[:, :1] * 0], dim=1)
    return StaggeredGrid.pack(gu, gv)


# The diffusion operators act on the interior faces and as the identity on walls and padding, with no
# coupling between the two, so that they stay symmetric on the whole tensor (adjoint right-hand sides may
# carry values on the walls).


def _constant_operator(alpha: float, mask: Tensor):
    def op(x: Tensor) -> Tensor:
        return x - alpha * vector_laplacian(x * mask)

    return op


def _variable_operator(dt: float, mask: Tensor):
    def op(x: Tensor, mu: Tensor) -> Tensor:
        return x + dt * strain_operator(x * mask, mu)

    return op


def _strain_preconditioner(r: Tensor, alpha: Tensor, mask: Tensor, bases: SpectralBases) -> Tensor:
    """Exact inverse of ``I + alpha K_mu`` for a constant ``mu`` (``alpha = dt * mu``, ``(B,)``).

    With these walls the vector Laplacian commutes with the discrete gradient and divergence, so on
    ``r = G q + w`` (Helmholtz split) ``I - a (Lap + G D)`` acts as ``I - a Lap`` on ``w`` and as
    ``G (I - 2 a L)`` on ``q``. Hence ``x = (I - a Lap)^-1 r + G s`` with, per cosine mode of eigenvalue ``e``,
    ``s = a / ((1 + 2 a e)(1 + a e)) * D r``: two fast solves and no null space.
    """
    a = alpha.view(-1, 1, 1, 1)
    s = neumann_filter(divergence(r * mask), lambda e: a / ((1 + 2 * a * e) * (1 + a * e)), bases)
    return solve_velocity_helmholtz(r, alpha, bases) + gradient(s)


def diffuse(
    velocity: Tensor,
    viscosity: Viscosity,
    dt: float,
    *,
    config: CGConfig = CGConfig(),
    adjoint_config: CGConfig | None = None,
    return_iterations: bool = False,
    grid: StaggeredGrid | None = None,
) -> Tensor | tuple[Tensor, int]:
    """Implicit viscous diffusion ``(I - dt L_mu) v_new = v``.

    Args:
        velocity: ``(B, 2, h + 1, w + 1)`` staggered velocity.
        viscosity: a non-negative float ``mu`` (cells^2 per time unit; the operator is the vector Laplacian,
            solved exactly by DST/DCT) or a field ``(B|1, 1, h, w)`` (the full term
            ``div(mu (grad v + grad v^T))``, solved by CG preconditioned with the mean viscosity's exact solve;
            differentiable in the field). Zero viscosity is the identity.
        dt: time step (time units).
        config: CG settings of the solve; ``adjoint_config`` those of its backward solve.
        return_iterations: also return the CG iteration count.
        grid: the velocity's :class:`~torchfluidwarp.core.staggered.StaggeredGrid`, whose spectral bases the
            solve reuses (a simulator passes its own); built anew when ``None``.

    Returns:
        ``(B, 2, h + 1, w + 1)`` the diffused velocity (and the iteration count if asked).
    """
    grid = StaggeredGrid.of(velocity) if grid is None else grid
    mask, bases = grid.mask(velocity), grid.spectral
    if isinstance(viscosity, Tensor):
        mu = viscosity
        alpha = dt * mu.detach().flatten(1).mean(1).expand(velocity.shape[0])
        x, iters = implicit_solve(
            _variable_operator(dt, mask),
            velocity,
            (mu,),
            precond=lambda r: _strain_preconditioner(r, alpha, mask, bases),
            config=config,
            adjoint_config=adjoint_config,
            name="viscosity solve",
        )
    elif viscosity == 0:
        x, iters = velocity, 0
    else:
        coefficient = dt * viscosity
        if not math.isfinite(coefficient) or abs(coefficient) > torch.finfo(velocity.dtype).max:
            raise InputError(
                f"dt * viscosity = {float(coefficient):.3g} is beyond the range of {velocity.dtype} "
                f"(dt {dt!r}, viscosity {viscosity!r}); use a smaller dt or viscosity"
            )
        a = torch.full((velocity.shape[0],), coefficient, device=velocity.device, dtype=velocity.dtype)
        x, iters = implicit_solve(
            _constant_operator(dt * viscosity, mask),
            velocity,
            precond=lambda r: solve_velocity_helmholtz(r, a, bases),
            config=config,
            adjoint_config=adjoint_config,
            name="viscosity solve",
            exact=True,
        )
    return (x, iters) if return_iterations else x


def _pressure_operator(p: Tensor) -> Tensor:
    # -L p + mean(p): the Neumann Laplacian made definite on constants, so that every right-hand side (also an
    # adjoint one with a non-zero mean) is consistent; a zero-mean b gets the zero-mean pressure.
    return p.mean(dim=(-2, -1), keepdim=True) - divergence(gradient(p))


def project(
    velocity: Tensor,
    *,
    config: CGConfig = CGConfig(),
    adjoint_config: CGConfig | None = None,
    return_iterations: bool = False,
    grid: StaggeredGrid | None = None,
) -> Tensor | tuple[Tensor, int]:
    """Pressure projection: solve ``-L p = -div v`` and return ``v - grad p``, divergence-free.

    On the staggered grid the 5-point Neumann Laplacian is exactly ``div(grad)``, so after the solve the
    discrete :func:`divergence` is zero to round-off; the DCT preconditioner is the exact inverse, so CG's
    first iterate is the solution and is returned unchecked (``CGConfig(verify_exact=True)`` runs CG with
    its residual checks).

    ``grid`` is the velocity's :class:`~torchfluidwarp.core.staggered.StaggeredGrid`, whose spectral bases the
    solve reuses (a simulator passes its own); built anew when ``None``.

    Returns:
        ``(B, 2, h + 1, w + 1)`` the projected velocity (and the iteration count if asked).
    """
    bases = (StaggeredGrid.of(velocity) if grid is None else grid).spectral
    rhs = -divergence(velocity)
    rhs = rhs - rhs.mean(dim=(-2, -1), keepdim=True)  # the walls make it zero-mean; remove round-off
    p, iters = implicit_solve(
        _pressure_operator,
        rhs,
        precond=lambda r: solve_pressure_poisson(r, bases),
        config=config,
        adjoint_config=adjoint_config,
        name="pressure solve",
        exact=True,
    )
    out = velocity - gradient(p)
    return (out, iters) if return_iterations else out


def check_viscosity(viscosity: object, batch: int, grid: tuple[int, int]) -> Viscosity:
    """Validate a viscosity: a float ``>= 0`` or a field ``(B|1, 1, h, w)`` of finite values ``>= 0``."""
    if isinstance(viscosity, Tensor):
        mu = check_tensor("viscosity", viscosity)
        if mu.ndim == 0:
            mu = mu.reshape(1, 1, 1, 1).expand(1, 1, *grid)
        if mu.ndim != 4 or mu.shape[1] != 1 or tuple(mu.shape[-2:]) != tuple(grid) or mu.shape[0] not in (1, batch):
            raise InputError(
                f"viscosity must be a float or a field of shape ({batch} or 1, 1, {grid[0]}, {grid[1]}), "
                f"got {tuple(mu.shape)}"
            )
        if bool((mu < 0).any()):
            raise InputError(f"viscosity must be >= 0 everywhere, got a minimum of {float(mu.min()):.3g}")
        return mu
    return check_positive("viscosity", viscosity, allow_zero=True)  # type: ignore[arg-type]
