"""Semi-Lagrangian advection through a staggered velocity: of fields, of the velocity itself, and of points.

Values are traced back along the characteristics with the explicit midpoint rule (RK2) and sampled bilinearly;
points are carried forward the same way, in sub-steps short enough never to fold (:func:`substeps`). Velocities
are staggered ``(B, 2, h + 1, w + 1)`` in fluid cells per time unit (layout in :mod:`torchfluidwarp.core.grid`);
points are ``(B, N, 2)`` ``(x, y)`` in fluid cells, cell centres at integers. Everything is differentiable and
follows the velocity's device and dtype. These functions check their inputs and call the unchecked kernels of
:class:`~torchfluidwarp.core.staggered.StaggeredGrid`, which the layers above call directly.
"""

from __future__ import annotations

from torch import Tensor

from torchfluidwarp._checks import check_int, check_positive, check_real, check_tensor
from torchfluidwarp.core.staggered import MAX_STRAIN_PER_SUBSTEP, MAX_SUBSTEPS, StaggeredGrid
from torchfluidwarp.errors import InputError

__all__ = [
    "check_velocity",
    "sample_velocity",
    "advect",
    "advect_velocity",
    "advect_points",
    "substeps",
]


def check_velocity(velocity: object, name: str = "velocity") -> Tensor:
    """Validate a staggered velocity ``(B, 2, h + 1, w + 1)`` (finite, floating, h and w at least 2)."""
    v = check_tensor(name, velocity, ndim=4)
    if v.shape[1] != 2 or v.shape[2] < 3 or v.shape[3] < 3:
        raise InputError(
            f"{name} must be a staggered velocity of shape (B, 2, h + 1, w + 1) with h, w >= 2, got {tuple(v.shape)}"
        )
    return v


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
    grid = StaggeredGrid.of(velocity)
    return grid.velocity_at(grid.extend(velocity), points)


def advect(quantity: Tensor, velocity: Tensor, dt: float) -> Tensor:
    """Semi-Lagrangian advection of a cell-centred field ``(B, C, h, w)`` through a staggered velocity.

    Each cell centre is traced back by ``dt`` with the explicit midpoint rule and the field is sampled there
    bilinearly (values beyond the outermost centres are held constant). This moves *values*, so repeated
    steps blur; the warp layer advects texture coordinates instead.

    Returns:
        ``(B, C, h, w)`` the advected field.
    """
    check_velocity(velocity)
    grid = StaggeredGrid.of(velocity)
    check_tensor("quantity", quantity, shape=[velocity.shape[0], None, grid.h, grid.w])
    dt = check_real("dt", dt)
    return grid.advect(quantity, velocity, dt)


def advect_velocity(velocity: Tensor, dt: float) -> Tensor:
    """Self-advection of a staggered velocity (semi-Lagrangian, midpoint back-trace), walls kept at zero."""
    check_velocity(velocity)
    return StaggeredGrid.of(velocity).advect_velocity(velocity, check_real("dt", dt))


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
            cannot fold; the default :data:`~torchfluidwarp.core.staggered.MAX_STRAIN_PER_SUBSTEP` keeps its
            determinant near 1.
        max_substeps: the most sub-steps one step may take (default
            :data:`~torchfluidwarp.core.staggered.MAX_SUBSTEPS`).

    Raises:
        ~torchfluidwarp.errors.FlowBlewUp: a non-finite velocity, or a flow that needs more than ``max_substeps``
            sub-steps.
    """
    max_substeps = check_int("max_substeps", max_substeps)
    grid = StaggeredGrid.of(velocity)
    return grid.substeps(grid.extend(velocity.detach()), dt, check_positive("max_strain", max_strain), max_substeps)


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
        max_substeps: the most sub-steps allowed (:data:`~torchfluidwarp.core.staggered.MAX_SUBSTEPS`); a flow
            that needs more is refused with a :class:`~torchfluidwarp.errors.FlowBlewUp`.

    Returns:
        ``(B, M, 2)`` the carried points, in fluid cells.
    """
    check_velocity(velocity)
    check_tensor("points", points, shape=[velocity.shape[0], None, 2])
    dt = check_real("dt", dt)
    max_substeps = check_int("max_substeps", max_substeps)
    return StaggeredGrid.of(velocity).carry(
        velocity, points, dt, max_strain=check_positive("max_strain", max_strain), max_substeps=max_substeps
    )
