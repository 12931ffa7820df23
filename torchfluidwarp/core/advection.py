"""Semi-Lagrangian advection through a staggered velocity: of fields, of the velocity itself, and of points.

Values are traced back along the characteristics with the explicit midpoint rule (RK2) and sampled bilinearly;
points are carried forward the same way, in sub-steps short enough never to fold (:func:`substeps`). Velocities
are staggered ``(B, 2, h + 1, w + 1)`` in fluid cells per time unit (layout in :mod:`torchfluidwarp.core.grid`);
points are ``(x, y)`` in fluid cells, cell centres at integers. Everything is differentiable and follows the
velocity's device and dtype. :mod:`torchfluidwarp.core.fluid` re-exports the public names.
"""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import check_int, check_positive, check_real, check_tensor
from torchfluidwarp.core.grid import normalized_affine
from torchfluidwarp.core.sampling import SampleMode, sample

__all__ = [
    "check_velocity",
    "sample_velocity",
    "advect",
    "advect_velocity",
    "advect_points",
    "substeps",
    "FlowBlewUp",
    "MAX_STRAIN_PER_SUBSTEP",
    "MAX_SUBSTEPS",
]


def check_velocity(velocity: object, name: str = "velocity") -> Tensor:
    """Validate a staggered velocity ``(B, 2, h + 1, w + 1)`` (finite, floating, h and w at least 2)."""
    v = check_tensor(name, velocity, ndim=4)
    if v.shape[1] != 2 or v.shape[2] < 3 or v.shape[3] < 3:
        raise ValueError(
            f"{name} must be a staggered velocity of shape (B, 2, h + 1, w + 1) with h, w >= 2, got {tuple(v.shape)}"
        )
    return v


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
            "lo": col(-0.5, -0.5),
            "hi": col(w - 0.5, h - 0.5),
            "s2": torch.stack([su, sv], dim=1),  # (1, component, xy, 1)
            "t2": torch.stack([tu, tv], dim=1),
            "sc": sc,
            "tc": tc,
            "faces": torch.cat([positions(h, w - 1, 0.5, 0.0), positions(h - 1, w, 0.0, 0.5)], dim=2),
            "cells": positions(h, w, 0.0, 0.0),
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
"""The default ``max_strain`` of :func:`substeps`: points and maps are carried in sub-steps short enough that
``dt_sub * max|grad v| <= 0.25``, so each sub-step's map ``x -> x + dt_sub v`` has a Jacobian determinant
near 1 and can never fold."""


MAX_SUBSTEPS = 4096
"""The default ``max_substeps`` of :func:`substeps`: a step that would need more sub-steps is refused with a
:class:`FlowBlewUp` (giving the count, the limit and the setting that raises it) instead of running for hours. A
gentle flow needs 1 to 10, forces of 10 cells per time unit^2 about 100, and forces of 1000 some 20000."""


class FlowBlewUp(ValueError, FloatingPointError):
    """A flow that cannot be run or carried: its velocity became non-finite (in a roll-out of
    :class:`~torchfluidwarp.core.simulator.FluidSimulator`, or here), or it needs more than ``max_substeps``.

    A ``ValueError`` naming the forces, velocity and ``dt`` (and a ``FloatingPointError``, what a roll-out's blow-up
    used to be), so callers that catch those keep working. The fits catch this one alone: a trial step that makes
    the flow blow up is a step too long, not a bug (:func:`~torchfluidwarp.control.optim.minimize`'s
    ``undefined``).
    """


def substeps(
    velocity: Tensor, dt: float, max_strain: float = MAX_STRAIN_PER_SUBSTEP, max_substeps: int = MAX_SUBSTEPS
) -> int:
    """Number of sub-steps that keep ``dt_sub * max|grad v|`` within ``max_strain``.

    The largest velocity difference between neighbouring faces of a staggered velocity ``(B, 2, h+1, w+1)``
    bounds its velocity gradient (cells per time unit per cell). Most gentle flows need one sub-step.

    Args:
        velocity: ``(B, 2, h + 1, w + 1)`` staggered, cells per time unit.
        dt: the time to cover (time units; its sign is ignored).
        max_strain: the largest ``dt_sub * max|grad v|`` per sub-step (dimensionless, > 0). Below 1 a sub-step
            cannot fold; the default :data:`MAX_STRAIN_PER_SUBSTEP` keeps its determinant near 1.
        max_substeps: the most sub-steps one step may take (default :data:`MAX_SUBSTEPS`).

    Raises:
        FlowBlewUp: a non-finite velocity, or a flow that needs more than ``max_substeps`` sub-steps (a
            ``ValueError``).
    """
    max_substeps = check_int("max_substeps", max_substeps)
    return _substeps(_extend(velocity.detach()), dt, check_positive("max_strain", max_strain), max_substeps)


def _substeps(
    extended: Tensor, dt: float, max_strain: float = MAX_STRAIN_PER_SUBSTEP, max_substeps: int = MAX_SUBSTEPS
) -> int:
    # on the extended layout (see _extend) the differences between neighbours along both axes are exactly the
    # staggered ones: the repeated padding row / column adds zero differences
    with torch.no_grad():
        strain = float(torch.maximum(extended.diff(dim=-1).abs().amax(), extended.diff(dim=-2).abs().amax()))
    # the strain is on the host already, so this guard of the unchecked sub-step sampling costs nothing: a NaN or
    # inf anywhere in the velocity makes it non-finite (NaN propagates through amax)
    if not math.isfinite(strain * dt):
        raise FlowBlewUp(
            f"velocity: non-finite velocity or strain times dt (strain {strain!r}, dt {dt!r}): "
            "the flow blew up (forces or dt too large?)"
        )
    n = max(1, math.ceil(strain * abs(dt) / max_strain))
    if n > max_substeps:
        raise FlowBlewUp(
            f"the flow needs {n if n < 10**9 else f'about {float(n):.3g}'} sub-steps in one step "
            f"(velocity strain {strain:.3g} per time unit, dt {dt:.3g}), "
            f"above the limit of {max_substeps}: reduce the forces, the initial velocity or dt, or raise the "
            "limit with max_substeps (MapConfig(max_substeps=...) for FluidWarp and the maps)"
        )
    return n


def advect_points(
    points: Tensor,
    velocity: Tensor,
    dt: float,
    *,
    max_strain: float = MAX_STRAIN_PER_SUBSTEP,
    max_substeps: int = MAX_SUBSTEPS,
) -> Tensor:
    """Carry points by one velocity field for one step: RK2 (midpoint) over ``dt``; they stay in the box.

    This is the one-step function; :meth:`torchfluidwarp.warp.layer.FluidWarp.carry_points` carries points
    through a whole roll-out.

    Args:
        points: ``(B, M, 2)`` ``(x, y)`` in fluid cells.
        velocity: ``(B, 2, h + 1, w + 1)`` staggered, cells per time unit.
        dt: time step (time units).
        max_strain: strong flows are integrated in :func:`substeps` sub-steps of at most this strain.
        max_substeps: the most sub-steps allowed (:data:`MAX_SUBSTEPS`); a flow that needs more is refused.

    Returns:
        ``(B, M, 2)`` the carried points, in fluid cells.
    """
    check_velocity(velocity)
    check_tensor("points", points, shape=[velocity.shape[0], None, 2])
    dt = check_real("dt", dt)
    max_substeps = check_int("max_substeps", max_substeps)
    return _advect_points(
        points.transpose(1, 2), velocity, dt, max_strain=max_strain, max_substeps=max_substeps
    ).transpose(1, 2)


def _advect_points(
    points: Tensor,
    velocity: Tensor,
    dt: float,
    n: int | None = None,
    max_strain: float = MAX_STRAIN_PER_SUBSTEP,
    max_substeps: int = MAX_SUBSTEPS,
) -> Tensor:
    """Channel-first version: ``(B, 2, M)`` in, ``(B, 2, M)`` out, in ``n`` sub-steps (default: :func:`substeps`
    with ``max_strain`` and ``max_substeps``)."""
    geo = _geo(velocity.shape[-2] - 1, velocity.shape[-1] - 1, velocity)
    ext = _extend(velocity)
    n = _substeps(ext, dt, check_positive("max_strain", max_strain), max_substeps) if n is None else n
    h = dt / n
    for _ in range(n):
        mid = points + (0.5 * h) * _velocity_at(ext, points, geo)
        points = _clamp(points + h * _velocity_at(ext, mid, geo), geo)
    return points
