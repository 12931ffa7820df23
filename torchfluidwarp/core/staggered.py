"""The one owner of the staggered (MAC) layout: :class:`StaggeredGrid`.

A staggered velocity is ``(B, 2, h + 1, w + 1)`` in fluid cells per time unit (:mod:`torchfluidwarp.core.grid`
gives the positions): channel 0 holds ``u`` on the ``h x (w + 1)`` vertical faces, channel 1 holds ``v`` on the
``(h + 1) x w`` horizontal faces, and the one row of ``u`` and the one column of ``v`` beyond those are padding,
always zero. One tensor per field keeps a roll-out's velocities one ``(B, T, 2, h + 1, w + 1)`` tensor; this
module is the only place that knows where the padding is (:meth:`StaggeredGrid.split`, :meth:`~StaggeredGrid.pack`,
:meth:`~StaggeredGrid.extend`).

It also holds the unchecked kernels that every layer above shares: the velocity at points, the midpoint
back-trace, and the points' carry, on one point layout, ``(B, N, 2)`` ``(x, y)`` in fluid cells, cell centres at
integers. They check nothing (they run once per sub-step on inputs checked at the public boundary: the functions
of :mod:`torchfluidwarp.core.advection`, :mod:`torchfluidwarp.warp.maps`, ...), and never let a non-finite value
reach ``grid_sample``: :meth:`~StaggeredGrid.substeps` refuses a non-finite velocity first.

The grid's constants (sampling affines, index maps, positions) are built on first use per device and dtype and
held by the instance, never by the module: a simulator or warp holds its ``StaggeredGrid`` and so its constants,
and they go when it goes.
"""

from __future__ import annotations

import math
from types import ModuleType

import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp.core.grid import FluidGrid, normalized_affine, rescale_points, scale_factor
from torchfluidwarp.core.sampling import SampleMode, sample
from torchfluidwarp.core.spectral import SpectralBases
from torchfluidwarp.errors import FlowBlewUp, Hint

__all__ = ["StaggeredGrid", "channel_first", "MAX_STRAIN_PER_SUBSTEP", "MAX_SUBSTEPS"]

MAX_STRAIN_PER_SUBSTEP = 0.25
"""The default ``max_strain`` of :meth:`StaggeredGrid.substeps`: points and maps are carried in sub-steps short
enough that ``dt_sub * max|grad v| <= 0.25``, so each sub-step's map ``x -> x + dt_sub v`` has a Jacobian
determinant near 1 and can never fold."""

MAX_SUBSTEPS = 4096
"""The default ``max_substeps``: a step that would need more sub-steps is refused with a :class:`FlowBlewUp`
(giving the count, the limit and the setting that raises it) instead of running for hours. A gentle flow needs
1 to 10, forces of 10 cells per time unit^2 about 100, and forces of 1000 some 20000."""


def channel_first(points: Tensor) -> Tensor:
    """Points ``(..., N, 2)`` with the same values, laid out in memory as ``(..., 2, N)`` (a transposed view).

    The kernels' arithmetic on points broadcasts per-axis constants ``(..., 2)`` (bounds, affines); over a
    trailing axis of 2 in memory that runs about 2x slower on CPUs than over ``N``, which this layout makes the
    innermost axis. Elementwise results keep it, so the kernels lay points out once per call, not per sub-step.
    """
    if points.shape[-2] <= 1 or points.stride(-2) == 1:
        return points
    return points.transpose(-1, -2).contiguous().transpose(-1, -2)


class StaggeredGrid:
    """The staggered layout of an ``h x w`` fluid grid, its constants, and its unchecked point kernels.

    Args:
        grid: the fluid grid, ``(h, w)`` or an int (square).
        fused: whether the self-advection, the back-trace and the carry run the fused Triton kernels of
            :mod:`torchfluidwarp.core.fused`: ``None`` (default) where :func:`~torchfluidwarp.core.fused.usable`
            says so (CUDA tensors, Triton installed), ``True`` always (CPU tensors under Triton's interpreter, in
            the tests), ``False`` never. The attribute of that name may be changed later.

    Example:
        >>> g = StaggeredGrid((4, 6))
        >>> u, v = g.split(torch.zeros(1, 2, 5, 7))
        >>> tuple(u.shape), tuple(v.shape)
        ((1, 4, 7), (1, 5, 6))
        >>> g.velocity_at(g.extend(torch.ones(1, 2, 5, 7)), torch.tensor([[[2.0, 1.0]]]))
        tensor([[[1., 1.]]])
    """

    def __init__(self, grid: FluidGrid | int | tuple[int, int], *, fused: bool | None = None) -> None:
        self.grid = FluidGrid.of(grid)
        self.fused = fused
        self.h, self.w = self.grid.shape
        self._constants: dict[tuple[torch.device, torch.dtype], dict[str, Tensor]] = {}
        self.spectral = SpectralBases()  # the pressure and viscosity solves' transforms, held here too

    @classmethod
    def of(cls, velocity: Tensor) -> StaggeredGrid:
        """The grid of a staggered velocity ``(..., 2, h + 1, w + 1)`` (its constants are built anew)."""
        return cls((velocity.shape[-2] - 1, velocity.shape[-1] - 1))

    def __repr__(self) -> str:
        return f"StaggeredGrid(({self.h}, {self.w}))"

    @property
    def shape(self) -> tuple[int, int]:
        """``(h + 1, w + 1)``: the spatial shape of a staggered velocity."""
        return (self.h + 1, self.w + 1)

    # ---- the layout -------------------------------------------------------------------------------------------

    def split(self, velocity: Tensor) -> tuple[Tensor, Tensor]:
        """The two components without their padding: ``u`` ``(B, h, w + 1)`` and ``v`` ``(B, h + 1, w)`` (views)."""
        return self.components(velocity)

    @staticmethod
    def components(velocity: Tensor) -> tuple[Tensor, Tensor]:
        """:meth:`split` of any staggered velocity ``(..., 2, h + 1, w + 1)``, with no grid built: for the grid
        operators, called several times per step on velocities whose grid they do not hold."""
        return velocity[..., 0, :-1, :], velocity[..., 1, :, :-1]

    @staticmethod
    def pack(u: Tensor, v: Tensor) -> Tensor:
        """Inverse of :meth:`split`: ``(B, 2, h + 1, w + 1)`` with zero padding."""
        return torch.stack([F.pad(u, (0, 0, 0, 1)), F.pad(v, (0, 1))], dim=1)

    def zeros(self, batch: int, *, like: Tensor) -> Tensor:
        """A velocity at rest ``(batch, 2, h + 1, w + 1)`` on ``like``'s device and dtype."""
        return like.new_zeros(batch, 2, self.h + 1, self.w + 1)

    def constants(self, like: Tensor) -> dict[str, Tensor]:
        """The grid's sampling constants on ``like``'s device and dtype, built on first use and held by this instance.

        ``extend_index`` and ``face_index`` (flat indices into a ``(2, h + 1, w + 1)`` velocity), ``lo``/``hi``
        (the box's bounds ``(1, 1, 2)``), ``affine``/``shift`` (cell coordinates to ``grid_sample``'s, per
        component ``(1, 2, 1, 2)``), ``cell_scale``/``cell_shift`` (the same for cell-centred fields), ``faces``
        ``(1, h (w - 1) + (h - 1) w, 2)`` (the interior faces, ``u``'s then ``v``'s), ``cells`` ``(1, h w, 2)``
        and ``mask`` (see :meth:`mask`).
        """
        key = (like.device, like.dtype)
        found = self._constants.get(key)
        if found is None:
            with torch.inference_mode(False), torch.no_grad():
                found = self._constants[key] = self._build(like.device, like.dtype)
        return found

    def mask(self, like: Tensor) -> Tensor:
        """``(1, 2, h + 1, w + 1)``: 1 on the interior (free) faces, 0 on the walls and the padding."""
        return self.constants(like)["mask"]

    def _build(self, device: torch.device, dtype: torch.dtype) -> dict[str, Tensor]:
        h, w = self.h, self.w

        def positions(ny: int, nx: int, x0: float, y0: float) -> Tensor:
            gy, gx = torch.meshgrid(
                torch.arange(ny, dtype=dtype, device=device) + y0,
                torch.arange(nx, dtype=dtype, device=device) + x0,
                indexing="ij",
            )
            return channel_first(torch.stack([gx, gy]).reshape(1, 2, -1).transpose(1, 2))

        def affine(nx: int, ny: int, x0: float, y0: float) -> tuple[Tensor, Tensor]:
            # align_corners=True: node k of n, at cell coordinate x0 + k, sits at normalised 2k/(n-1) - 1
            return normalized_affine((ny, nx), align_corners=True, offset=(x0, y0), device=device, dtype=dtype)

        # both components on (h + 1, w + 1) nodes (see extend): u at (j - 1/2, i), v at (j, i - 1/2)
        su, tu = affine(w + 1, h + 1, -0.5, 0.0)
        sv, tv = affine(w + 1, h + 1, 0.0, -0.5)
        sc, tc = affine(w, h, 0.0, 0.0)
        # the extended layout of `extend` (u's padding row repeats its last row, v's padding column its last
        # column), and the interior faces in the order of "faces" (u's, then v's)
        flat = torch.arange(2 * (h + 1) * (w + 1), device=device).view(2, h + 1, w + 1)
        ext_u, ext_v = flat[0].clone(), flat[1].clone()
        ext_u[h] = flat[0, h - 1]
        ext_v[:, w] = flat[1, :, w - 1]
        mask = torch.zeros(1, 2, h + 1, w + 1, device=device, dtype=dtype)
        mask[0, 0, :h, 1:w] = 1
        mask[0, 1, 1:h, :w] = 1
        return {
            "mask": mask,
            "extend_index": torch.stack([ext_u, ext_v]).flatten(),
            "face_index": torch.cat([flat[0, :h, 1:w].flatten(), flat[1, 1:h, :w].flatten()]),
            "lo": torch.tensor([-0.5, -0.5], dtype=dtype, device=device).view(1, 1, 2),
            "hi": torch.tensor([w - 0.5, h - 0.5], dtype=dtype, device=device).view(1, 1, 2),
            "affine": torch.stack([su, sv]).view(1, 2, 1, 2),  # (1, component, 1, xy)
            "shift": torch.stack([tu, tv]).view(1, 2, 1, 2),
            "cell_scale": sc.view(1, 1, 2),
            "cell_shift": tc.view(1, 1, 2),
            "faces": channel_first(torch.cat([positions(h, w - 1, 0.5, 0.0), positions(h - 1, w, 0.0, 0.5)], dim=1)),
            "cells": positions(h, w, 0.0, 0.0),
        }

    def extend(self, velocity: Tensor) -> Tensor:
        """Both components of a staggered velocity on ``(h + 1, w + 1)`` nodes, as a batch ``(2B, 1, h + 1, w + 1)``.

        The padding row of ``u`` and the padding column of ``v`` repeat their last row / column, so that bilinear
        sampling with border padding holds each component constant beyond its outermost nodes: one
        ``grid_sample`` call then samples both components (:meth:`velocity_at`). One gather, whose backward is
        one scatter-add (slicing and concatenating cost several autograd nodes).
        """
        index = self.constants(velocity)["extend_index"]
        return velocity.reshape(velocity.shape[0], -1).index_select(1, index).view(-1, 1, self.h + 1, self.w + 1)

    def _fused_kernels(self, *tensors: Tensor) -> ModuleType | None:
        """:mod:`torchfluidwarp.core.fused` when a call on ``tensors`` runs its kernels (see ``fused``), else None."""
        if self.fused is False or (self.fused is None and not tensors[0].is_cuda):
            return None  # the CPU path never imports Triton
        from torchfluidwarp.core import fused

        return fused if self.fused or fused.usable(*tensors) else None

    # ---- the unchecked kernels, points (B, N, 2) in cells ----------------------------------------------------

    def velocity_at(self, extended: Tensor, points: Tensor) -> Tensor:
        """Velocity ``(B, N, 2)`` (cells per time unit) at points ``(B, N, 2)`` (cells), in one ``grid_sample``.

        ``extended`` is :meth:`extend` of the velocity. Points outside the box sample its border values, as if
        clamped into it.
        """
        return self.components_at(extended, points.unsqueeze(1))

    def components_at(self, extended: Tensor, points: Tensor) -> Tensor:
        """Each component at its own points ``(B, 2, N, 2)`` (or ``(B, 1, N, 2)`` for both at the same points):
        ``(B, N, 2)``, in one ``grid_sample`` over the ``2B`` extended images."""
        B, _, N, _ = points.shape
        c = self.constants(extended)
        g = torch.addcmul(c["shift"], points, c["affine"]).reshape(2 * B, N, 1, 2)  # (2B, N, 1, xy)
        # unchecked: per sub-step, on velocities and points checked at the public boundary
        return sample(extended, g, align_corners=True, check=None).view(B, 2, N).transpose(1, 2)

    def clamp(self, points: Tensor) -> Tensor:
        """Points ``(B, N, 2)`` clamped into the box ``[-1/2, w - 1/2] x [-1/2, h - 1/2]``."""
        c = self.constants(points)
        return torch.clamp(points, c["lo"], c["hi"])

    def backtrace(self, extended: Tensor, points: Tensor, dt: float) -> Tensor:
        """Where points ``(B, N, 2)`` came from ``dt`` ago: the explicit midpoint rule (RK2) back along the
        characteristic, clamped into the box (the midpoint needs no clamp: sampling holds the velocity constant
        outside the box)."""
        kernels = self._fused_kernels(extended, points)
        if kernels is not None:  # one kernel, one adjoint kernel
            return kernels.backtrace(extended, points, dt)
        mid = points - (0.5 * dt) * self.velocity_at(extended, points)
        return self.clamp(points - dt * self.velocity_at(extended, mid))

    def sample_cells(self, field: Tensor, points: Tensor, mode: SampleMode = "bilinear") -> Tensor:
        """A cell-centred field ``(B, C, h, w)`` at points ``(B, N, 2)`` (cells), held constant beyond the
        outermost centres: ``(B, C, N)``."""
        c = self.constants(points)
        g = torch.addcmul(c["cell_shift"], points, c["cell_scale"]).unsqueeze(2)  # (B, N, 1, 2)
        return sample(field, g, mode=mode, align_corners=True, check=None)[..., 0]

    def substeps(
        self, extended: Tensor, dt: float, max_strain: float = MAX_STRAIN_PER_SUBSTEP, max_substeps: int = MAX_SUBSTEPS
    ) -> int:
        """Sub-steps that keep ``dt_sub * max|grad v|`` within ``max_strain``, for :meth:`extend` of a velocity.

        Raises:
            FlowBlewUp: a non-finite velocity, or one that needs more than ``max_substeps`` sub-steps.
        """
        # on the extended layout the differences between neighbours along both axes are exactly the staggered
        # ones: the repeated padding row / column adds zero differences
        with torch.no_grad():
            strain = float(torch.maximum(extended.diff(dim=-1).abs().amax(), extended.diff(dim=-2).abs().amax()))
        # the strain is on the host already, so this guard of the unchecked sub-step sampling costs nothing: a NaN
        # or inf anywhere in the velocity makes it non-finite (NaN propagates through amax)
        if not math.isfinite(strain * dt):
            raise FlowBlewUp(
                f"velocity: non-finite velocity or strain times dt (strain {strain!r}, dt {dt!r}): "
                "the flow blew up (forces or dt too large?)"
            )
        n = max(1, math.ceil(strain * abs(dt) / max_strain))
        if n > max_substeps:
            raise FlowBlewUp(
                f"the flow needs {n if n < 10**9 else f'about {float(n):.3g}'} sub-steps in one step "
                f"(velocity strain {strain:.3g} per time unit, dt {dt:.3g}), above the limit of {max_substeps}",
                hint=Hint(
                    "reduce the forces, the initial velocity or dt, or raise the limit with {setting}",
                    "max_substeps",
                    spelling="max_substeps (MapConfig(max_substeps=...) for FluidWarp and the maps)",
                    otherwise="reduce the forces, the initial velocity or dt",
                ),
            )
        return n

    def carry(
        self,
        velocity: Tensor,
        points: Tensor,
        dt: float,
        n: int | None = None,
        max_strain: float = MAX_STRAIN_PER_SUBSTEP,
        max_substeps: int = MAX_SUBSTEPS,
    ) -> Tensor:
        """Carry points ``(B, N, 2)`` (cells) by one velocity for one step: RK2 in ``n`` sub-steps (default
        :meth:`substeps`), clamped into the box after each. Returns ``(B, N, 2)``."""
        ext = self.extend(velocity)
        n = self.substeps(ext, dt, max_strain, max_substeps) if n is None else n
        h = dt / n
        points = channel_first(points)
        kernels = self._fused_kernels(ext, points)
        for _ in range(n):
            if kernels is not None:  # a sub-step forward is the back-trace over -h: one kernel
                points = kernels.backtrace(ext, points, -h)
                continue
            mid = points + (0.5 * h) * self.velocity_at(ext, points)
            points = self.clamp(points + h * self.velocity_at(ext, mid))
        return points

    def trajectories(
        self,
        velocities: Tensor,
        points: Tensor,
        dt: float,
        size: tuple[int, int] | None = None,
        max_strain: float = MAX_STRAIN_PER_SUBSTEP,
        max_substeps: int = MAX_SUBSTEPS,
    ) -> Tensor:
        """Carry points ``(B, M, 2)`` through every step of a roll-out ``(B, T, 2, h + 1, w + 1)``.

        Points are in fluid cells, or in the pixels of an image of ``size`` ``(H, W)`` when given (the image
        covers the grid's rectangle). Returns ``(B, T + 1, M, 2)`` in the same units, in the promoted dtype
        (half precision is carried in float32).
        """
        dtype = torch.promote_types(velocities.dtype, points.dtype)
        work = torch.float32 if dtype in (torch.float16, torch.bfloat16) else dtype
        velocities, points = velocities.to(work), points.to(work)
        c = None if size is None else scale_factor(size, self.grid.shape, device=points.device, dtype=work)
        points = channel_first(points)
        traj = [points if c is None else rescale_points(points, c)]
        for velocity in velocities.unbind(1):
            traj.append(self.carry(velocity, traj[-1], dt, max_strain=max_strain, max_substeps=max_substeps))
        out = torch.stack(traj, dim=1)
        return (out if c is None else rescale_points(out, c, inverse=True)).to(dtype)

    def advect_velocity(self, velocity: Tensor, dt: float) -> Tensor:
        """Self-advection of a staggered velocity (semi-Lagrangian, midpoint back-trace), walls kept at zero."""
        kernels = self._fused_kernels(velocity)
        if kernels is not None:  # one kernel, one adjoint kernel
            return kernels.advect_velocity(velocity, dt)
        h, w = self.h, self.w
        c = self.constants(velocity)
        ext = self.extend(velocity)
        B = velocity.shape[0]
        back = self.backtrace(ext, c["faces"].expand(B, -1, -1), dt).transpose(1, 2)  # (B, 2, faces), a view
        nu, nv = h * (w - 1), (h - 1) * w
        # each component only at its own faces' feet, both in one grid_sample: the shorter list of feet is padded
        # with copies of its last point (sampled, then dropped) when h != w
        n = max(nu, nv)
        feet_u, feet_v = back[..., :nu], back[..., nu:]
        if nu != nv:
            feet_u, feet_v = (F.pad(f, (0, n - f.shape[-1]), mode="replicate") for f in (feet_u, feet_v))
        feet = torch.stack([feet_u, feet_v], dim=1).transpose(2, 3)  # (B, component, n, 2), channel-first memory
        sampled = self.components_at(ext, feet)  # (B, n, 2)
        values = torch.cat([sampled[:, :nu, 0], sampled[:, :nv, 1]], dim=1)
        out = values.new_zeros(B, 2 * (h + 1) * (w + 1)).index_copy(1, c["face_index"], values)
        return out.view(B, 2, h + 1, w + 1)

    def advect(self, quantity: Tensor, velocity: Tensor, dt: float) -> Tensor:
        """Semi-Lagrangian advection of a cell-centred field ``(B, C, h, w)``: ``(B, C, h, w)``."""
        c = self.constants(velocity)
        back = self.backtrace(self.extend(velocity), c["cells"].expand(velocity.shape[0], -1, -1), dt)
        return self.sample_cells(quantity, back).view_as(quantity)
