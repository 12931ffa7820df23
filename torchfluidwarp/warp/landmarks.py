"""Landmark forces: marked points travel on straight lines, the rest of the picture as a thin-plate spline says.

The natural morph's control (:class:`LandmarkForces`), and :func:`solve_midpoints`, which finds where a particle
sits in the middle frame of such straight paths. Called like every force module (see
:mod:`torchfluidwarp.warp.forces`, which re-exports these names): ``forces(grid, steps, dt, image_size)`` returns
``(B, T, 2, h, w)`` in fluid cells per time unit^2; positions are in pixels, pixel centres at integers.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from torchfluidwarp._checks import check_int, check_size, check_tensor
from torchfluidwarp.core.grid import FluidGrid, cell_centres, cell_scale
from torchfluidwarp.core.spline import tps_fit
from torchfluidwarp.errors import InputError

__all__ = ["LandmarkForces", "solve_midpoints"]


def _fade(x: Tensor, lo: float, hi: float, end_lo: float, end_hi: float) -> Tensor:
    """1 on ``[lo, hi]``, falling as a half cosine to 0 at ``end_lo < lo`` and ``end_hi > hi``."""
    below = ((lo - x) / max(lo - end_lo, 1e-9)).clamp(0, 1)
    above = ((x - hi) / max(end_hi - hi, 1e-9)).clamp(0, 1)
    return 0.5 * (1 + torch.cos(math.pi * torch.maximum(below, above)))


def solve_midpoints(
    travel: Callable[[Tensor], Tensor], at: Tensor, sigma: float, start: Tensor | None = None
) -> Tensor:
    """The midpoints ``m`` ``(N, 2)`` with ``m + sigma D(m) = at``: where the particles at ``at`` ``(N, 2)`` are
    in the middle frame of straight paths ``m + sigma D(m)`` (see :class:`LandmarkForces`).

    Newton's method, with the Jacobian of ``D = travel`` by forward differences (0.01 px: three evaluations of
    ``travel`` an iteration), from ``start`` (default ``at``); the map is invertible wherever the paths do not fold,
    and a few iterations reach round-off (``1e-9`` px).
    """
    m = at.clone() if start is None else start.clone()
    h = 0.01
    ex, ey = m.new_tensor([h, 0.0]), m.new_tensor([0.0, h])
    for _ in range(12):
        here = travel(m)
        residual = m + sigma * here - at  # (N, 2)
        if float(residual.abs().max()) < 1e-9:
            break
        jx = (travel(m + ex) - here) / h  # (N, 2): dD/dx
        jy = (travel(m + ey) - here) / h
        a, b = 1 + sigma * jx[:, 0], sigma * jy[:, 0]  # I + sigma J, row x
        c, d = sigma * jx[:, 1], 1 + sigma * jy[:, 1]  # row y
        det = a * d - b * c
        det = torch.where(det.abs() > 1e-6, det, torch.full_like(det, 1e-6))
        step = (
            torch.stack([d * residual[:, 0] - b * residual[:, 1], a * residual[:, 1] - c * residual[:, 0]], -1)
            / det[:, None]
        )
        m = m - step
    return m


class LandmarkForces(nn.Module):
    """Forces that move marked points on straight lines at constant speed, and the rest of the picture as a
    thin-plate spline between them says: the natural morph's control.

    Point ``i`` travels ``x_i(s) = m_i + (s - 1/2) d_i`` over the roll-out's fraction ``s = t / T`` in
    ``[0, 1]``, from ``m_i - d_i / 2`` to ``m_i + d_i / 2``; every other particle travels likewise,
    ``x(s) = m + (s - 1/2) D(m)``, with ``D`` the thin-plate spline (:func:`~torchfluidwarp.core.spline.tps_cardinal`)
    through the ``d_i`` at the midpoints ``m_i``. Defined at the midpoints, the middle frame is the spline
    morph to the average shape, and A's and B's sides are treated alike. An inviscid compressible fluid keeps
    every particle's velocity (Burgers' equation), so one kick at step 0 sets this motion going and the fluid
    coasts; the discrete fluid does so only approximately, and a fit corrects the kicks.

    The control vector ``weight`` ``(B, T, M, 2)`` holds corrections to the points' velocities (pixels per
    time unit, running sums: ``weight[:, t]`` is the correction in force during step ``t``); it starts at 0. The
    force of step ``t`` is the spline through the change of the velocities since step ``t - 1``, evaluated
    at each cell's particle (where it is at the middle), so a correction moves the point it belongs to, and
    its neighbours as the spline says.

    Args:
        midpoints: ``(M, 2)`` pixels: ``m_i``, distinct, at least 3 and not all on one line.
        displacements: ``(M, 2)`` pixels: ``d_i``, each point's whole travel.
        steps: ``T``.
        batch: number of independent problems ``B``.
        inside: optional ``(x0, y0, x1, y1)`` pixels: the forces act fully inside this rectangle and fade to
            zero (a half cosine) at the image's edges, where the fluid's walls are; beyond it the travel is that
            of its nearest point, not the spline's extrapolation, which grows without bound. A morph puts the
            walls outside the picture and the picture inside, so the walls leave no seam.
        travel: optional: every particle's whole travel, points ``(N, 2)`` -> ``(N, 2)`` pixels, where it is not
            the spline ``D`` alone: ``D + R``, with ``R`` a correction between the marks (0 at the marks) that the
            pixels found (:func:`~torchfluidwarp.correspond.halfway.halfway_alignment`), so that every particle
            travels ``x(s) = m + (s - 1/2) (D + R)(m)``. The kick at step 0 carries ``R``; the corrections stay the
            marks' own.
        origin: ``(x, y)`` where pixel ``(0, 0)`` of these forces lies in the caller's frame (a morph's fluid box
            in A's pixels), so that another fit's forces can be compared point by point with these (a warm start,
            :func:`~torchfluidwarp.morph.fit.warm_corrections`); it changes nothing in the flow.

    Example:
        >>> mid = torch.tensor([[8.0, 8.0], [24.0, 8.0], [16.0, 24.0]])
        >>> f = LandmarkForces(mid, torch.ones(3, 2), steps=2)
        >>> f(FluidGrid(16, 16), steps=2, dt=1.0, image_size=(32, 32)).shape
        torch.Size([1, 2, 2, 16, 16])
    """

    def __init__(
        self,
        midpoints: Tensor,
        displacements: Tensor,
        steps: int,
        batch: int = 1,
        inside: tuple[float, float, float, float] | None = None,
        travel: Callable[[Tensor], Tensor] | None = None,
        origin: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        super().__init__()
        m = check_tensor("midpoints", midpoints, shape=[None, 2])
        if m.shape[0] < 3:
            raise InputError(f"midpoints must hold at least 3 points, got shape {tuple(m.shape)}")
        d = check_tensor("displacements", displacements, shape=[m.shape[0], 2]).to(m.dtype)
        steps, batch = check_int("steps", steps), check_int("batch", batch)
        self.register_buffer("midpoints", m.detach().clone())
        self.register_buffer("displacements", d.detach().clone())
        self.midpoints: Tensor
        self.displacements: Tensor
        self.weight = nn.Parameter(torch.zeros(batch, steps, m.shape[0], 2, device=m.device, dtype=m.dtype))
        self.inside = None if inside is None else tuple(float(v) for v in inside)
        self.travel = travel
        self.origin = (float(origin[0]), float(origin[1]))
        self._basis: dict[tuple, tuple[Tensor, Tensor]] = {}  # (T, h w, M), (h w, 2) per grid, size, device, dtype

    def extra_repr(self) -> str:
        return f"steps={self.weight.shape[1]}, points={self.weight.shape[2]}, inside={self.inside}"

    def basis(self, grid: FluidGrid, image_size: tuple[int, int]) -> tuple[Tensor, Tensor]:
        """``(T, h w, M)``: per step, the points' cardinal splines at each cell's particle, faded toward the walls;
        and ``(h w, 2)`` pixels: the residual's travel at each cell's particle at step 0, faded likewise (0 without
        a residual)."""
        key = (grid.shape, image_size, self.midpoints.device, self.weight.dtype)
        if key not in self._basis:
            with torch.inference_mode(False), torch.no_grad():  # kept for later fits that record gradients
                mids, disp = self.midpoints.double(), self.displacements.double()
                cells = cell_centres(grid, image_size, device=mids.device, dtype=mids.dtype).reshape(
                    -1, 2
                )  # (h w, 2) px
                fade = torch.ones(cells.shape[0], 1, dtype=torch.float64, device=cells.device)
                if self.inside is not None:
                    x0, y0, x1, y1 = self.inside
                    H, W = image_size
                    fade = (_fade(cells[:, 0], x0, x1, -0.5, W - 0.5) * _fade(cells[:, 1], y0, y1, -0.5, H - 0.5))[
                        :, None
                    ]
                spline = tps_fit(mids, disp)  # D
                whole = spline if self.travel is None else self.travel
                held = lambda p: p  # noqa: E731
                if self.inside is not None:  # beyond the rectangle (and the marks), the travel of its nearest point
                    lo = torch.minimum(cells.new_tensor(self.inside[:2]), mids.min(0).values)
                    hi = torch.maximum(cells.new_tensor(self.inside[2:]), mids.max(0).values)
                    held = lambda p: torch.maximum(torch.minimum(p, hi), lo)  # noqa: E731
                travel = lambda p: whole(held(p))  # noqa: E731
                cardinal = tps_fit(mids, torch.eye(mids.shape[0], dtype=mids.dtype, device=mids.device))  # one solve
                T = self.weight.shape[1]
                rows, at = [], cells
                extra = torch.zeros_like(cells)
                for t in range(T):
                    # the particle at a cell at time t / T has its midpoint m with m + (t / T - 1/2) D(m) = cell
                    at = solve_midpoints(travel, cells, t / T - 0.5, start=at)
                    rows.append(fade * cardinal(held(at)))
                    if t == 0 and self.travel is not None:
                        extra = fade * (travel(at) - spline(held(at)))
                dtype = self.weight.dtype
                self._basis[key] = (torch.stack(rows).to(dtype), extra.to(dtype))
        return self._basis[key]

    def forward(self, grid: FluidGrid, steps: int, dt: float, image_size: tuple[int, int]) -> Tensor:
        B, T, m, _ = self.weight.shape
        if steps != T:
            raise InputError(f"this LandmarkForces holds {T} steps, but {steps} were asked for")
        g = FluidGrid.of(grid)
        H, W = check_size("image_size", image_size)
        v = self.displacements.to(self.weight.dtype) / (T * dt) + self.weight  # (B, T, M, 2) pixels per time unit
        kicks = torch.cat([v[:, :1], v.diff(dim=1)], dim=1)
        to_cells = cell_scale((H, W), g, device=v.device, dtype=v.dtype) / dt
        basis, extra = self.basis(g, (H, W))
        field = torch.einsum("tnm,btmc->btcn", basis, kicks * to_cells)  # (B, T, 2, h w)
        if self.travel is not None:  # the residual's kick, at step 0
            field = field + F.pad((extra.T * to_cells.view(2, 1) / (T * dt)).unsqueeze(0), (0, 0, 0, 0, 0, T - 1))
        return field.reshape(B, T, 2, *g.shape)
