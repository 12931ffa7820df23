"""Stable Fluids on a staggered grid: pure functions.

One step is Stam's splitting (Stable Fluids, 1999): add force -> advect -> diffuse -> project. Every function
takes and returns a staggered velocity ``(B, 2, h + 1, w + 1)`` in fluid cells per time unit (layout in
:mod:`torchfluidwarp.core.grid`), with solid walls, is differentiable, and follows the input's device and dtype.
The modules in :mod:`torchfluidwarp.core.simulator` are thin wrappers over these.
"""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import check_positive, check_real, check_tensor
from torchfluidwarp.core.grid import FluidGrid, interior_mask, normalized_affine
from torchfluidwarp.core.linalg import CGConfig, implicit_solve
from torchfluidwarp.core.sampling import SampleMode, sample
from torchfluidwarp.core.spectral import neumann_filter, solve_pressure_poisson, solve_velocity_helmholtz

__all__ = [
    "divergence",
    "gradient",
    "faces_from_cells",
    "cells_from_faces",
    "sample_velocity",
    "advect",
    "advect_velocity",
    "advect_points",
    "vector_laplacian",
    "strain_operator",
    "diffuse",
    "project",
    "check_velocity",
]

Viscosity = float | Tensor


def check_velocity(velocity: object, name: str = "velocity") -> Tensor:
    """Validate a staggered velocity ``(B, 2, h + 1, w + 1)`` (finite, floating, h and w at least 2)."""
    v = check_tensor(name, velocity, ndim=4)
    if v.shape[1] != 2 or v.shape[2] < 3 or v.shape[3] < 3:
        raise ValueError(
            f"{name} must be a staggered velocity of shape (B, 2, h + 1, w + 1) with h, w >= 2, got {tuple(v.shape)}"
        )
    return v


def _split(vel: Tensor) -> tuple[Tensor, Tensor]:
    h, w = vel.shape[-2] - 1, vel.shape[-1] - 1
    return vel[:, 0, :h, :], vel[:, 1, :, :w]  # (B, h, w + 1), (B, h + 1, w)


def _pack(u: Tensor, v: Tensor) -> Tensor:
    return torch.stack([F.pad(u, (0, 0, 0, 1)), F.pad(v, (0, 1))], dim=1)


def divergence(velocity: Tensor) -> Tensor:
    """Discrete divergence of a staggered velocity, per cell: ``(B, 1, h, w)`` in 1 / time unit.

    ``u[j, i + 1] - u[j, i] + v[j + 1, i] - v[j, i]``, as one 2x2 convolution (the padding row and column get
    zero weight).
    """
    stencil = _geo(velocity.shape[-2] - 1, velocity.shape[-1] - 1, velocity)["div_stencil"]
    return F.conv2d(velocity, stencil)


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
    u, v = _split(velocity)
    return torch.stack([0.5 * (u[..., 1:] + u[..., :-1]), 0.5 * (v[:, 1:] + v[:, :-1])], dim=1)


# Internally point sets are channel-first, ``(B, 2, N)`` (row 0 = x): elementwise maths over a trailing
# dimension of size 2 is several times slower on CPUs than over N. Public functions take ``(B, N, 2)``.


@functools.lru_cache(maxsize=32)
def _geometry(h: int, w: int, device: torch.device, dtype: torch.dtype) -> dict[str, Tensor]:
    """Memo of a pure function: constants of an ``(h, w)`` grid (box bounds, sampling affines, positions)."""
    with torch.inference_mode(False), torch.no_grad():

        def positions(ny: int, nx: int, x0: float, y0: float) -> Tensor:
            gy, gx = torch.meshgrid(
                torch.arange(ny, dtype=dtype, device=device) + y0,
                torch.arange(nx, dtype=dtype, device=device) + x0,
                indexing="ij",
            )
            return torch.stack([gx, gy]).reshape(1, 2, -1)

        def col(a: float, b: float) -> Tensor:
            return torch.tensor([a, b], dtype=dtype, device=device).view(1, 2, 1)

        def affine(nx: int, ny: int, x0: float, y0: float) -> tuple[Tensor, Tensor]:
            # align_corners=True: node k of n, at cell coordinate x0 + k, sits at normalised 2k/(n-1) - 1
            scale, shift = normalized_affine((ny, nx), align_corners=True, offset=(x0, y0), device=device, dtype=dtype)
            return scale.view(1, 2, 1), shift.view(1, 2, 1)

        # both components on (h + 1, w + 1) nodes (see _extend): u at (j - 1/2, i), v at (j, i - 1/2)
        su, tu = affine(w + 1, h + 1, -0.5, 0.0)
        sv, tv = affine(w + 1, h + 1, 0.0, -0.5)
        sc, tc = affine(w, h, 0.0, 0.0)
        # flat indices into a staggered (2, h + 1, w + 1) velocity: the extended layout of _extend (u's padding
        # row repeats its last row, v's padding column its last column), and the interior faces in the order of
        # "faces" below (u's, then v's)
        flat = torch.arange(2 * (h + 1) * (w + 1), device=device).view(2, h + 1, w + 1)
        ext_u, ext_v = flat[0].clone(), flat[1].clone()
        ext_u[h] = flat[0, h - 1]
        ext_v[:, w] = flat[1, :, w - 1]
        return {
            "extend_index": torch.stack([ext_u, ext_v]).flatten(),
            "face_index": torch.cat([flat[0, :h, 1:w].flatten(), flat[1, 1:h, :w].flatten()]),
            # divergence as one 2x2 convolution: cell (j, i) reads u at (j, i), (j, i + 1) and v at (j, i), (j + 1, i)
            "div_stencil": torch.tensor(
                [[[[-1.0, 1.0], [0.0, 0.0]], [[-1.0, 0.0], [1.0, 0.0]]]], device=device, dtype=dtype
            ),
            "lo": col(-0.5, -0.5),
            "hi": col(w - 0.5, h - 0.5),
            "s2": torch.stack([su, sv], dim=1),  # (1, component, xy, 1)
            "t2": torch.stack([tu, tv], dim=1),
            "sc": sc,
            "tc": tc,
            "faces": torch.cat([positions(h, w - 1, 0.5, 0.0), positions(h - 1, w, 0.0, 0.5)], dim=2),
            "cells": positions(h, w, 0.0, 0.0),
            "mask": interior_mask(FluidGrid(h, w), device=device, dtype=dtype),
        }


def _geo(h: int, w: int, like: Tensor) -> dict[str, Tensor]:
    return _geometry(h, w, like.device, like.dtype)


def _sample(
    image: Tensor,
    points: Tensor,
    scale: Tensor,
    shift: Tensor,
    align_corners: bool = True,
    mode: SampleMode = "bilinear",
) -> Tensor:
    """Sample ``image`` ``(B, C, n_y, n_x)`` at channel-first points ``(B, 2, N)`` mapped by ``p * scale + shift``.

    Returns ``(B, C, N)``. Internal and per sub-step, so unchecked (see :mod:`torchfluidwarp.core.sampling`):
    callers guarantee finite points (inputs checked at the public boundary, positions clamped into the box).
    """
    g = torch.addcmul(shift, points, scale).transpose(1, 2).unsqueeze(2)  # (B, N, 1, 2)
    return sample(image, g, mode=mode, align_corners=align_corners, check=None)[..., 0]


def _extend(velocity: Tensor) -> Tensor:
    """Both components of a staggered velocity on ``(h + 1, w + 1)`` nodes, as a batch ``(2B, 1, h + 1, w + 1)``.

    The padding row of ``u`` and the padding column of ``v`` repeat their last row / column, so that bilinear
    sampling with border padding holds each component constant beyond its outermost nodes: one
    ``grid_sample`` call then samples both components (see :func:`_velocity_at`). One gather, whose backward is
    one scatter-add (slicing and concatenating cost several autograd nodes).
    """
    h, w = velocity.shape[-2] - 1, velocity.shape[-1] - 1
    index = _geo(h, w, velocity)["extend_index"]
    return velocity.reshape(velocity.shape[0], -1).index_select(1, index).view(-1, 1, h + 1, w + 1)


def _velocity_at(extended: Tensor, points: Tensor, geo: dict[str, Tensor]) -> Tensor:
    """Velocity ``(B, 2, N)`` at channel-first points ``(B, 2, N)`` (fluid cells), in one ``grid_sample``.

    ``extended`` is :func:`_extend` of the velocity. Points outside the box sample its border values, as if
    clamped into it.
    """
    return _components_at(extended, points.unsqueeze(1), geo)


def _components_at(extended: Tensor, points: Tensor, geo: dict[str, Tensor]) -> Tensor:
    """Each velocity component at its own channel-first points ``(B, 2 components, 2, N)`` (or ``(B, 1, 2, N)``
    for both at the same points): ``(B, 2, N)``, in one ``grid_sample`` over the ``2B`` extended images."""
    B, _, _, N = points.shape
    g = torch.addcmul(geo["t2"], points, geo["s2"])  # (B, component, xy, N)
    g = g.transpose(2, 3).reshape(2 * B, N, 1, 2)
    # unchecked: per sub-step, on velocities and points checked at the public boundary
    return sample(extended, g, align_corners=True, check=None).view(B, 2, N)


def _clamp(points: Tensor, geo: dict[str, Tensor]) -> Tensor:
    return torch.clamp(points, geo["lo"], geo["hi"])


def _backtrace(extended: Tensor, points: Tensor, dt: float, geo: dict[str, Tensor]) -> Tensor:
    # explicit midpoint (RK2) back along the characteristic, clamped into the box (the midpoint needs no
    # clamp: sampling holds the velocity constant outside the box)
    mid = points - (0.5 * dt) * _velocity_at(extended, points, geo)
    return _clamp(points - dt * _velocity_at(extended, mid, geo), geo)


def sample_velocity(velocity: Tensor, points: Tensor) -> Tensor:
    """Bilinear velocity of a staggered field at points.

    Args:
        velocity: ``(B, 2, h + 1, w + 1)`` staggered, cells per time unit.
        points: ``(B, N, 2)`` ``(x, y)`` in fluid cells; points outside the box are clamped to it.

    Returns:
        ``(B, N, 2)`` velocity ``(u, v)`` in cells per time unit.

    Raises:
        ValueError: non-finite velocity or points, or wrong shapes.
    """
    check_velocity(velocity)
    check_tensor("points", points, shape=[velocity.shape[0], None, 2])
    geo = _geo(velocity.shape[-2] - 1, velocity.shape[-1] - 1, velocity)
    return _velocity_at(_extend(velocity), points.transpose(1, 2), geo).transpose(1, 2)


def advect(quantity: Tensor, velocity: Tensor, dt: float) -> Tensor:
    """Semi-Lagrangian advection of a cell-centred field ``(B, C, h, w)`` through a staggered velocity.

    Each cell centre is traced back by ``dt`` with the explicit midpoint rule and the field is sampled there
    bilinearly (values beyond the outermost centres are held constant). This moves *values*, so repeated
    steps blur; the warp layer advects texture coordinates instead.

    Returns:
        ``(B, C, h, w)`` the advected field.
    """
    check_velocity(velocity)
    h, w = velocity.shape[-2] - 1, velocity.shape[-1] - 1
    check_tensor("quantity", quantity, shape=[velocity.shape[0], None, h, w])
    dt = check_real("dt", dt)
    geo = _geo(h, w, velocity)
    back = _backtrace(_extend(velocity), geo["cells"].expand(velocity.shape[0], -1, -1), dt, geo)
    return _sample(quantity, back, geo["sc"], geo["tc"]).view_as(quantity)


def advect_velocity(velocity: Tensor, dt: float) -> Tensor:
    """Self-advection of a staggered velocity (semi-Lagrangian, midpoint back-trace), walls kept at zero."""
    check_velocity(velocity)
    return _advect_velocity(velocity, check_real("dt", dt))


def _advect_velocity(velocity: Tensor, dt: float) -> Tensor:
    h, w = velocity.shape[-2] - 1, velocity.shape[-1] - 1
    geo = _geo(h, w, velocity)
    ext = _extend(velocity)
    back = _backtrace(ext, geo["faces"].expand(velocity.shape[0], -1, -1), dt, geo)
    nu, nv = h * (w - 1), (h - 1) * w
    # each component only at its own faces' feet, both in one grid_sample: the shorter list of feet is padded
    # with copies of its last point (sampled, then dropped) when h != w
    n = max(nu, nv)
    feet_u, feet_v = back[..., :nu], back[..., nu:]
    if nu != nv:
        feet_u, feet_v = (F.pad(f, (0, n - f.shape[-1]), mode="replicate") for f in (feet_u, feet_v))
    sampled = _components_at(ext, torch.stack([feet_u, feet_v], dim=1), geo)  # (B, 2, n)
    values = torch.cat([sampled[:, 0, :nu], sampled[:, 1, :nv]], dim=1)
    out = values.new_zeros(values.shape[0], 2 * (h + 1) * (w + 1)).index_copy(1, geo["face_index"], values)
    return out.view(-1, 2, h + 1, w + 1)


MAX_STRAIN_PER_SUBSTEP = 0.25
"""Points and maps are carried in sub-steps short enough that ``dt_sub * max|grad v| <= 0.25``: each
sub-step's map ``x -> x + dt_sub v`` then has a Jacobian determinant near 1 and can never fold."""


def substeps(velocity: Tensor, dt: float) -> int:
    """Number of sub-steps that keep ``dt_sub * max|grad v|`` within :data:`MAX_STRAIN_PER_SUBSTEP`.

    The largest velocity difference between neighbouring faces of a staggered velocity ``(B, 2, h+1, w+1)``
    bounds its velocity gradient (cells per time unit per cell). Most gentle flows need one sub-step.
    """
    return _substeps(_extend(velocity.detach()), dt)


def _substeps(extended: Tensor, dt: float) -> int:
    # on the extended layout (see _extend) the differences between neighbours along both axes are exactly the
    # staggered ones: the repeated padding row / column adds zero differences
    with torch.no_grad():
        strain = float(torch.maximum(extended.diff(dim=-1).abs().amax(), extended.diff(dim=-2).abs().amax()))
    # the strain is on the host already, so this guard of the unchecked sub-step sampling costs nothing: a NaN or
    # inf anywhere in the velocity makes it non-finite (NaN propagates through amax)
    if not math.isfinite(strain * dt):
        raise ValueError(
            f"velocity: non-finite velocity or strain times dt (strain {strain!r}, dt {dt!r}): "
            "the flow blew up (forces or dt too large?)"
        )
    return max(1, math.ceil(strain * abs(dt) / MAX_STRAIN_PER_SUBSTEP))


def advect_points(points: Tensor, velocity: Tensor, dt: float) -> Tensor:
    """Carry points ``(B, M, 2)`` (fluid cells) forward by ``dt`` with RK2 (midpoint); they stay in the box.

    Strong flows are integrated in :func:`substeps` sub-steps."""
    check_velocity(velocity)
    check_tensor("points", points, shape=[velocity.shape[0], None, 2])
    return _advect_points(points.transpose(1, 2), velocity, check_real("dt", dt)).transpose(1, 2)


def _advect_points(points: Tensor, velocity: Tensor, dt: float, n: int | None = None) -> Tensor:
    """Channel-first version: ``(B, 2, M)`` in, ``(B, 2, M)`` out, in ``n`` sub-steps (default: :func:`substeps`)."""
    geo = _geo(velocity.shape[-2] - 1, velocity.shape[-1] - 1, velocity)
    ext = _extend(velocity)
    n = _substeps(ext, dt) if n is None else n
    h = dt / n
    for _ in range(n):
        mid = points + (0.5 * h) * _velocity_at(ext, points, geo)
        points = _clamp(points + h * _velocity_at(ext, mid, geo), geo)
    return points


def vector_laplacian(velocity: Tensor) -> Tensor:
    """Vector Laplacian of a staggered velocity: no flow through the walls, free slip along them."""
    u, v = _split(velocity)
    uy = F.pad(u.unsqueeze(1), (0, 0, 1, 1), mode="replicate")[:, 0]
    lu = (u[..., 2:] - 2 * u[..., 1:-1] + u[..., :-2]) + (uy[:, 2:, 1:-1] - 2 * u[:, :, 1:-1] + uy[:, :-2, 1:-1])
    vx = F.pad(v.unsqueeze(1), (1, 1, 0, 0), mode="replicate")[:, 0]
    lv = (v[:, 2:] - 2 * v[:, 1:-1] + v[:, :-2]) + (vx[:, 1:-1, 2:] - 2 * v[:, 1:-1] + vx[:, 1:-1, :-2])
    return _pack(F.pad(lu, (1, 1)), F.pad(lv, (0, 0, 1, 1)))


def strain_operator(velocity: Tensor, viscosity: Tensor) -> Tensor:
    """``-div(mu (grad v + grad v^T))`` on the staggered grid, for a viscosity field ``mu`` ``(B|1, 1, h, w)``.

    It is the gradient of the discrete energy ``sum_cells mu (e_xx^2 + e_yy^2) + sum_corners mu/2 (u_y + v_x)^2``
    (shear is zero on the walls: free slip), hence symmetric positive semi-definite, and it couples ``u``
    and ``v``. The viscosity at a corner is the mean of its four cells.
    """
    u, v = _split(velocity)
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
    return _pack(gu, gv)


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


def _strain_preconditioner(r: Tensor, alpha: Tensor, mask: Tensor) -> Tensor:
    """Exact inverse of ``I + alpha K_mu`` for a constant ``mu`` (``alpha = dt * mu``, ``(B,)``).

    With these walls the vector Laplacian commutes with the discrete gradient and divergence, so on
    ``r = G q + w`` (Helmholtz split) ``I - a (Lap + G D)`` acts as ``I - a Lap`` on ``w`` and as
    ``G (I - 2 a L)`` on ``q``. Hence ``x = (I - a Lap)^-1 r + G s`` with, per cosine mode of eigenvalue ``e``,
    ``s = a / ((1 + 2 a e)(1 + a e)) * D r``: two fast solves and no null space.
    """
    a = alpha.view(-1, 1, 1, 1)
    s = neumann_filter(divergence(r * mask), lambda e: a / ((1 + 2 * a * e) * (1 + a * e)))
    return solve_velocity_helmholtz(r, alpha) + gradient(s)


def diffuse(
    velocity: Tensor,
    viscosity: Viscosity,
    dt: float,
    *,
    config: CGConfig = CGConfig(),
    adjoint_config: CGConfig | None = None,
    return_iterations: bool = False,
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

    Returns:
        ``(B, 2, h + 1, w + 1)`` the diffused velocity (and the iteration count if asked).
    """
    mask = _geo(velocity.shape[-2] - 1, velocity.shape[-1] - 1, velocity)["mask"]
    if isinstance(viscosity, Tensor):
        mu = viscosity
        alpha = dt * mu.detach().flatten(1).mean(1).expand(velocity.shape[0])
        x, iters = implicit_solve(
            _variable_operator(dt, mask),
            velocity,
            (mu,),
            precond=lambda r: _strain_preconditioner(r, alpha, mask),
            config=config,
            adjoint_config=adjoint_config,
            name="viscosity solve",
        )
    elif viscosity == 0:
        x, iters = velocity, 0
    else:
        a = torch.full((velocity.shape[0],), dt * viscosity, device=velocity.device, dtype=velocity.dtype)
        x, iters = implicit_solve(
            _constant_operator(dt * viscosity, mask),
            velocity,
            precond=lambda r: solve_velocity_helmholtz(r, a),
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
) -> Tensor | tuple[Tensor, int]:
    """Pressure projection: solve ``-L p = -div v`` and return ``v - grad p``, divergence-free.

    On the staggered grid the 5-point Neumann Laplacian is exactly ``div(grad)``, so after the solve the
    discrete :func:`divergence` is zero to round-off; the DCT preconditioner is the exact inverse, so CG's
    first iterate is the solution and is returned unchecked (``CGConfig(verify_exact=True)`` runs CG with
    its residual checks).

    Returns:
        ``(B, 2, h + 1, w + 1)`` the projected velocity (and the iteration count if asked).
    """
    rhs = -divergence(velocity)
    rhs = rhs - rhs.mean(dim=(-2, -1), keepdim=True)  # the walls make it zero-mean; remove round-off
    p, iters = implicit_solve(
        _pressure_operator,
        rhs,
        precond=solve_pressure_poisson,
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
            raise ValueError(
                f"viscosity must be a float or a field of shape ({batch} or 1, 1, {grid[0]}, {grid[1]}), "
                f"got {tuple(mu.shape)}"
            )
        if bool((mu < 0).any()):
            raise ValueError(f"viscosity must be >= 0 everywhere, got a minimum of {float(mu.min()):.3g}")
        return mu
    return check_positive("viscosity", viscosity, allow_zero=True)  # type: ignore[arg-type]
