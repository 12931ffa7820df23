"""The solver as ``nn.Module`` objects: one module per operator, a step, and a roll-out.

:class:`StableFluidsStep` is ``AddForce -> Advect -> Diffuse -> Project`` (Stam 1999), each a thin module over
the functions of :mod:`torchfluidwarp.core.fluid`. :class:`FluidSimulator` rolls a step out over a force schedule
and carries passive points along.
"""

from __future__ import annotations

import inspect
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypedDict, cast

import torch
from torch import Tensor, nn

from torchfluidwarp._checks import all_finite, check_fraction, check_positive, check_tensor, compute_dtype
from torchfluidwarp.core.fluid import (
    Viscosity,
    check_viscosity,
    diffuse,
    faces_from_cells,
    project,
)
from torchfluidwarp.core.graphs import StepGraphs
from torchfluidwarp.core.grid import FluidGrid
from torchfluidwarp.core.linalg import CGConfig
from torchfluidwarp.core.staggered import StaggeredGrid
from torchfluidwarp.errors import FlowBlewUp, InputError, InputTypeError

if TYPE_CHECKING:
    from typing_extensions import Unpack  # typing.Unpack from Python 3.11

__all__ = ["AddForce", "Advect", "Diffuse", "Project", "StableFluidsStep", "FluidSimulator", "FluidRollout"]


class AddForce(nn.Module):
    """``v + dt * f``: a cell-centred force ``(B, 2, h, w)`` (cells per time unit^2) added on the faces."""

    def __init__(self, dt: float = 1.0) -> None:
        super().__init__()
        self.dt = check_positive("dt", dt)

    def forward(self, velocity: Tensor, force: Tensor, staggered: bool = False) -> Tensor:
        """``velocity`` ``(B, 2, h + 1, w + 1)`` plus ``dt`` times ``force``: cell-centred ``(B, 2, h, w)``, or
        already on the faces ``(B, 2, h + 1, w + 1)`` with ``staggered=True``."""
        return velocity + self.dt * (force if staggered else faces_from_cells(force))


class _HoldsLayout(nn.Module):
    """A step module that holds the :class:`~torchfluidwarp.core.staggered.StaggeredGrid` of the velocities it
    is called on (their constants and spectral bases), made anew only when the grid changes."""

    _layout: StaggeredGrid | None = None

    def layout(self, velocity: Tensor) -> StaggeredGrid:
        held = self._layout
        if held is None or held.shape != tuple(velocity.shape[-2:]):
            held = self._layout = StaggeredGrid.of(velocity)
        return held


class Advect(_HoldsLayout):
    """Semi-Lagrangian self-advection of the velocity (:func:`~torchfluidwarp.core.advection.advect_velocity`)."""

    def __init__(self, dt: float = 1.0) -> None:
        super().__init__()
        self.dt = check_positive("dt", dt)

    def forward(self, velocity: Tensor) -> Tensor:
        return self.layout(velocity).advect_velocity(velocity, self.dt)


class Diffuse(_HoldsLayout):
    """Implicit diffusion (:func:`~torchfluidwarp.core.fluid.diffuse`); the viscosity is passed per call."""

    def __init__(self, dt: float = 1.0, config: CGConfig = CGConfig(), adjoint_config: CGConfig | None = None):
        super().__init__()
        self.dt = check_positive("dt", dt)
        self.config, self.adjoint_config = config, adjoint_config

    def forward(self, velocity: Tensor, viscosity: Viscosity) -> tuple[Tensor, int]:
        return diffuse(  # type: ignore[return-value]
            velocity,
            viscosity,
            self.dt,
            config=self.config,
            adjoint_config=self.adjoint_config,
            return_iterations=True,
            grid=self.layout(velocity),
        )


class Project(_HoldsLayout):
    """Pressure projection (:func:`~torchfluidwarp.core.fluid.project`)."""

    def __init__(self, config: CGConfig = CGConfig(), adjoint_config: CGConfig | None = None) -> None:
        super().__init__()
        self.config, self.adjoint_config = config, adjoint_config

    def forward(self, velocity: Tensor) -> tuple[Tensor, int]:
        return project(  # type: ignore[return-value]
            velocity,
            config=self.config,
            adjoint_config=self.adjoint_config,
            return_iterations=True,
            grid=self.layout(velocity),
        )


class StepSettings(TypedDict, total=False):
    """The keyword settings of :class:`StableFluidsStep`, which :class:`FluidSimulator` passes on to it."""

    pressure: CGConfig
    diffusion: CGConfig
    adjoint: CGConfig | None
    compressible: bool | float


class StableFluidsStep(nn.Module):
    """One Stable Fluids step: add force -> advect -> diffuse -> project.

    Args:
        dt: time step (time units).
        pressure: CG settings of the pressure solve (and ``adjoint`` those of every backward solve).
        diffusion: CG settings of the viscosity solve.
        compressible: ``False`` (incompressible), ``True`` (skip the projection: the flow may compress and
            expand), or a weight ``c`` in ``[0, 1]``: the step keeps ``c`` of the divergent part,
            ``v <- c v + (1 - c) P(v)`` with ``P`` the projection.

    Example:
        >>> step = StableFluidsStep()
        >>> v = torch.zeros(1, 2, 9, 9)
        >>> f = torch.zeros(1, 2, 8, 8); f[:, 0, 3:5, 3:5] = 1.0
        >>> v1, _ = step(v, f, 0.0)
        >>> v1.shape
        torch.Size([1, 2, 9, 9])
    """

    def __init__(
        self,
        dt: float = 1.0,
        *,
        pressure: CGConfig = CGConfig(),
        diffusion: CGConfig = CGConfig(),
        adjoint: CGConfig | None = None,
        compressible: bool | float = False,
    ) -> None:
        super().__init__()
        self.add_force = AddForce(dt)
        self.advect = Advect(dt)
        self.diffuse = Diffuse(dt, diffusion, adjoint)
        keep = check_fraction("compressible", compressible)
        self.keep_divergence = keep
        self.project = None if keep == 1.0 else Project(pressure, adjoint)

    def forward(
        self, velocity: Tensor, force: Tensor, viscosity: Viscosity, staggered: bool = False
    ) -> tuple[Tensor, tuple[int, int]]:
        """Advance ``velocity`` ``(B, 2, h + 1, w + 1)`` by one step under ``force`` ``(B, 2, h, w)`` (or the
        force already averaged onto the faces, ``(B, 2, h + 1, w + 1)``, with ``staggered=True``).

        Returns:
            the new staggered velocity and the CG iteration counts ``(viscosity, pressure)``.
        """
        return self.relax(self.advect(self.add_force(velocity, force, staggered)), viscosity)

    def relax(self, velocity: Tensor, viscosity: Viscosity) -> tuple[Tensor, tuple[int, int]]:
        """The step's linear part, diffusion then projection, of an advected velocity ``(B, 2, h + 1, w + 1)``.

        Returns:
            the new staggered velocity and the CG iteration counts ``(viscosity, pressure)``.
        """
        v, it_visc = self.diffuse(velocity, viscosity)
        it_p = 0
        if self.project is not None:
            projected, it_p = self.project(v)
            v = projected if self.keep_divergence == 0 else torch.lerp(projected, v, self.keep_divergence)
        return v, (it_visc, it_p)


@dataclass
class FluidRollout:
    """What :class:`FluidSimulator` returns.

    Attributes:
        velocities: ``(B, T, 2, h + 1, w + 1)`` the staggered velocity at the end of each step (cells per
            time unit); step ``t`` moves points from time ``t`` to ``t + 1``.
        points: ``(B, T + 1, M, 2)`` trajectories of the passive points in fluid cells, or ``None``.
        iterations: per step, the CG iteration counts ``(viscosity, pressure)``.
    """

    velocities: Tensor
    points: Tensor | None = None
    iterations: list[tuple[int, int]] = field(default_factory=list)


class FluidSimulator(nn.Module):
    """Roll Stable Fluids out over a force schedule, starting from rest.

    Args:
        grid: ``(h, w)`` fluid cells (or an int for a square grid).
        dt: time step in time units; forces are in cells per time unit^2.
        viscosity: float ``>= 0``, a field ``(B|1, 1, h, w)`` (stored as a buffer, or a parameter if it is one),
            or a module called as ``viscosity(grid, image_size)`` that returns such a field (see
            :mod:`torchfluidwarp.warp.forces`; ``image_size`` is the grid's own size unless a warp passes the image's).
        cuda_graphs: on a GPU, capture the step in a CUDA graph on the first no-grad roll-out of at least
            :data:`~torchfluidwarp.core.graphs.GRAPH_MIN_STEPS` steps and replay it in every later one of the same
            batch shape, dtype and viscosity (:class:`~torchfluidwarp.core.graphs.StepGraphs`, held by this
            simulator as ``graphs``). Off by default: a capture synchronises the device and holds memory.
        **step: the keyword settings of :class:`StableFluidsStep` (:class:`StepSettings`): ``pressure``,
            ``diffusion`` and ``adjoint`` CG settings, and ``compressible``; its defaults otherwise.

    Example:
        >>> sim = FluidSimulator(grid=(16, 24), dt=1.0)
        >>> forces = torch.zeros(2, 5, 2, 16, 24); forces[:, :, 0, 6:10, 8:12] = 0.2
        >>> out = sim(forces, points=torch.tensor([[[10.0, 8.0]]]).expand(2, 1, 2))
        >>> out.velocities.shape, out.points.shape
        (torch.Size([2, 5, 2, 17, 25]), torch.Size([2, 6, 1, 2]))
    """

    def __init__(
        self,
        grid: FluidGrid | int | tuple[int, int],
        dt: float = 1.0,
        viscosity: Viscosity | nn.Module = 0.0,
        *,
        cuda_graphs: bool = False,
        **step: Unpack[StepSettings],
    ) -> None:
        super().__init__()
        self.grid = FluidGrid.of(grid)
        self.layout = StaggeredGrid(self.grid)  # the staggered layout and its constants, held with the simulator
        self.dt = check_positive("dt", dt)
        unknown = sorted(set(step) - set(StepSettings.__annotations__))
        if unknown:  # the step's own TypeError would name a class the caller never called
            own = [n for n in inspect.signature(FluidSimulator.__init__).parameters if n not in ("self", "step")]
            raise InputTypeError(
                f"FluidSimulator got unexpected keyword argument(s) {', '.join(map(repr, unknown))}; its settings "
                f"are {', '.join(own)} and {', '.join(StepSettings.__annotations__)}"
                + (
                    "; there is no device argument: the simulator runs where its forces are (.to(device) moves it "
                    "and a viscosity field it holds)"
                    if "device" in unknown
                    else ""
                ),
                argument=unknown[0],
            )
        self.step = StableFluidsStep(dt, **step)
        for module in (self.step.advect, self.step.diffuse, self.step.project):
            if module is not None:  # the step's modules share this grid's constants and spectral bases
                module._layout = self.layout
        self.graphs = StepGraphs(self.step) if cuda_graphs else None
        self.viscosity: Viscosity | nn.Module
        if isinstance(viscosity, (nn.Module, nn.Parameter)):
            self.viscosity = viscosity
        elif isinstance(viscosity, Tensor):
            batch = viscosity.shape[0] if viscosity.ndim else 1  # a 0-d tensor is one constant viscosity
            self.register_buffer("viscosity", cast(Tensor, check_viscosity(viscosity, batch, self.grid.shape)))
        else:
            self.viscosity = check_viscosity(viscosity, 1, self.grid.shape)

    def current_viscosity(self, batch: int, image_size: tuple[int, int] | None = None) -> Viscosity:
        """The viscosity in force: a float or a validated field ``(B|1, 1, h, w)``."""
        mu = self.viscosity
        if isinstance(mu, nn.Module) and not isinstance(mu, nn.Parameter):
            mu = mu(self.grid, image_size or self.grid.shape)
        return check_viscosity(mu, batch, self.grid.shape)

    def check_forces(self, forces: Tensor) -> Tensor:
        """Validate a force schedule ``(B, T, 2, h, w)`` on this grid, with ``B, T >= 1``."""
        h, w = self.grid.shape
        check_tensor("forces", forces, finite=False)
        if forces.ndim != 5 or forces.shape[0] < 1 or forces.shape[1] < 1 or tuple(forces.shape[2:]) != (2, h, w):
            raise InputError(
                f"forces must have shape (*, *, 2, {h}, {w}) on the grid of {h} x {w} cells, with a batch B >= 1 "
                f"and at least one step T >= 1, "
                f"got {tuple(forces.shape)}"
            )
        return check_tensor("forces", forces)

    def forward(
        self,
        forces: Tensor,
        points: Tensor | None = None,
        velocity: Tensor | None = None,
        image_size: tuple[int, int] | None = None,
    ) -> FluidRollout:
        """Simulate ``T`` steps.

        Args:
            forces: ``(B, T, 2, h, w)`` cell-centred forces per step, channel 0 = x (cells per time unit^2).
            points: optional ``(B, M, 2)`` passive points ``(x, y)`` in fluid cells (cell centres at integers),
                carried by RK2 through each step's velocity.
            velocity: optional initial staggered velocity ``(B, 2, h + 1, w + 1)``; zero by default.
            image_size: ``(H, W)`` handed to a viscosity module (pixel-based maps); the grid's size by default.

        Returns:
            a :class:`FluidRollout`. Inputs of different float dtypes are promoted; half precision is computed in
            float32 and the velocities and points come back in the inputs' (promoted) dtype.
        """
        forces = self.check_forces(forces)
        B, T = forces.shape[:2]
        h, w = self.grid.shape
        given = [forces]
        if velocity is not None:
            given.append(
                check_tensor("velocity", velocity, shape=[_same_batch("velocity", velocity, B), 2, h + 1, w + 1])
            )
        if points is not None:
            given.append(check_tensor("points", points, shape=[_same_batch("points", points, B), None, 2]))
        out_dtype = given[0].dtype
        for x in given[1:]:
            out_dtype = torch.promote_types(out_dtype, x.dtype)
        dtype = compute_dtype(out_dtype)
        forces, points = forces.to(dtype), None if points is None else points.to(dtype)
        velocity = forces.new_zeros(B, 2, h + 1, w + 1) if velocity is None else velocity.to(dtype)
        mu = self.current_viscosity(B, image_size)
        if isinstance(mu, Tensor):
            mu = mu.to(dtype)
        vels, iters = [], []
        traj = [points] if points is not None else []  # (B, M, 2) cells
        # all steps' forces onto the faces at once, then unbind: one backward node each for the whole schedule
        # (per-step selects would each scatter their gradient into a full-size zero tensor)
        on_faces = faces_from_cells(forces.flatten(0, 1)).view(B, T, 2, h + 1, w + 1)
        # with cuda_graphs, on a GPU where it can, each step is one replay of a captured step (core.graphs)
        with (
            nullcontext(self.step)
            if self.graphs is None
            else self.graphs.rollout_step(on_faces, velocity, mu, T) as step
        ):
            for t, force in enumerate(on_faces.unbind(1)):
                velocity, it = step(velocity, force, mu, staggered=True)
                vels.append(velocity)
                iters.append(it)
                if points is not None:
                    traj.append(self.layout.carry(velocity, traj[-1], self.dt))
                if not all_finite(velocity):
                    raise FlowBlewUp(
                        f"the flow blew up at step {t}: non-finite velocity (forces, velocity or dt too large)"
                    )
        pts = torch.stack(traj, 1).to(out_dtype) if points is not None else None
        return FluidRollout(torch.stack(vels, 1).to(out_dtype), pts, iters)


def _same_batch(name: str, x: object, batch: int) -> int:
    """``batch``, after refusing a tensor ``x`` whose batch differs from the forces' (naming both)."""
    if isinstance(x, Tensor) and x.ndim and x.shape[0] != batch:
        raise InputError(f"{name} has batch {x.shape[0]} but forces have batch {batch}; got shape {tuple(x.shape)}")
    return batch
