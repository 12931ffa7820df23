"""Force and viscosity parametrisations: the knobs of indirect control and the control vector of fitting.

Force modules are called as ``forces(grid, steps, dt, image_size)`` and return a schedule
``(B|1, T, 2, h, w)`` in fluid cells per time unit^2 (channel 0 = x). Viscosity modules are called as
``viscosity(grid, image_size)`` and return a field ``(B|1, 1, h, w)`` in cells^2 per time unit. Positions and
lengths given to them are in **pixels** of an image of size ``image_size = (H, W)`` (pixel centres at
integers), so the same module drives any fluid resolution. Every parameter is an ``nn.Parameter``, so
brushes and control grids are differentiable and can be fitted.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from torchfluidwarp._checks import check_int, check_size, check_tensor
from torchfluidwarp.core.grid import FluidGrid, cell_scale
from torchfluidwarp.core.grid import cell_centres as _grid_cell_centres
from torchfluidwarp.core.spline import tps_fit

__all__ = [
    "Brushes",
    "SumForces",
    "ControlGrid",
    "CellForces",
    "LandmarkForces",
    "ViscosityBrushes",
    "viscosity_from_mask",
    "cell_centres",
]


def cell_centres(grid: FluidGrid, image_size: tuple[int, int], like: Tensor) -> Tensor:
    """Fluid cell centres in the image's pixels: ``(h, w, 2)`` ``(x, y)``, on ``like``'s device and dtype.

    :func:`torchfluidwarp.core.grid.cell_centres`, which it calls, is the one definition.
    """
    return _grid_cell_centres(grid, image_size, device=like.device, dtype=like.dtype)


class Brushes(nn.Module):
    """Gaussian brush forces, optionally oscillating: the paper's indirect control.

    Brush ``k`` pushes with acceleration ``amplitude_k * direction_k * exp(-|x - c_k|^2 / (2 r_k^2))
    * s_k(t)`` where ``s_k(t) = sin(2 pi f_k t + phase_k)`` for ``f_k > 0`` and ``s_k = 1`` for ``f_k = 0``
    (a steady push); ``t = step * dt``.

    Args:
        centers: ``(K, 2)`` brush centres ``(x, y)`` in pixels.
        directions: ``(K, 2)`` push directions (normalised internally; their length is ignored).
        radius: ``(K,)`` or a float: Gaussian radius in pixels.
        amplitude: ``(K,)`` or a float: peak acceleration in pixels per time unit^2.
        frequency: ``(K,)`` or a float: oscillations per time unit (0 = steady).
        phase: ``(K,)`` or a float: phase in radians.

    Example:
        >>> b = Brushes([[32.0, 20.0]], [[0.0, 1.0]], radius=6.0, amplitude=0.5, frequency=0.1)
        >>> b(FluidGrid(16, 16), steps=8, dt=1.0, image_size=(64, 64)).shape
        torch.Size([1, 8, 2, 16, 16])
    """

    def __init__(
        self,
        centers: Tensor | Sequence,
        directions: Tensor | Sequence,
        radius: Tensor | Sequence | float = 8.0,
        amplitude: Tensor | Sequence | float = 1.0,
        frequency: Tensor | Sequence | float = 0.0,
        phase: Tensor | Sequence | float = 0.0,
    ) -> None:
        super().__init__()
        c = torch.as_tensor(centers, dtype=torch.get_default_dtype()).detach().clone()
        check_tensor("centers", c, shape=[None, 2])
        k = c.shape[0]
        if k < 1:
            raise ValueError("centers must hold at least one brush, got shape (0, 2)")
        d = torch.as_tensor(directions, dtype=c.dtype).detach().clone()
        check_tensor("directions", d, shape=[k, 2])
        if bool((d.norm(dim=-1) == 0).any()):
            raise ValueError("directions must be non-zero vectors")

        def per_brush(name: str, v: Tensor | Sequence | float, positive: bool) -> nn.Parameter:
            t = torch.as_tensor(v, dtype=c.dtype).detach().clone().flatten()
            t = t.expand(k).clone() if t.numel() == 1 else t
            check_tensor(name, t, shape=[k])
            if positive and bool((t <= 0).any()):
                raise ValueError(f"{name} must be > 0, got {t.tolist()}")
            if not positive and name == "frequency" and bool((t < 0).any()):
                raise ValueError(f"frequency must be >= 0, got {t.tolist()}")
            return nn.Parameter(t)

        self.centers = nn.Parameter(c)
        self.directions = nn.Parameter(d)
        self.radius = per_brush("radius", radius, True)
        self.amplitude = per_brush("amplitude", amplitude, False)
        self.frequency = per_brush("frequency", frequency, False)
        self.phase = per_brush("phase", phase, False)

    def forward(self, grid: FluidGrid, steps: int, dt: float, image_size: tuple[int, int]) -> Tensor:
        grid = FluidGrid.of(grid)
        H, W = check_size("image_size", image_size)
        steps = check_int("steps", steps)
        x = cell_centres(grid, (H, W), self.centers)  # (h, w, 2) pixels
        d2 = ((x[None] - self.centers[:, None, None]) ** 2).sum(-1)  # (K, h, w)
        bump = torch.exp(-d2 / (2 * self.radius[:, None, None] ** 2))
        unit = self.directions / self.directions.norm(dim=-1, keepdim=True)
        # pixels -> cells: accelerations scale like lengths
        to_cells = cell_scale((H, W), grid, device=unit.device, dtype=unit.dtype)
        push = self.amplitude[:, None] * unit * to_cells  # (K, 2)
        t = torch.arange(steps, dtype=unit.dtype, device=unit.device) * dt
        osc = torch.sin(2 * math.pi * self.frequency[None] * t[:, None] + self.phase[None])  # (T, K)
        osc = torch.where(self.frequency[None] > 0, osc, torch.ones_like(osc))
        field = torch.einsum("tk,kc,khw->tchw", osc, push, bump)
        return field.unsqueeze(0)


class SumForces(nn.Module):
    """The sum of several force modules (e.g. several groups of brushes)."""

    def __init__(self, *modules: nn.Module) -> None:
        super().__init__()
        if not modules:
            raise ValueError("SumForces needs at least one force module")
        self.parts = nn.ModuleList(modules)

    def forward(self, grid: FluidGrid, steps: int, dt: float, image_size: tuple[int, int]) -> Tensor:
        return sum(p(grid, steps, dt, image_size) for p in self.parts)  # type: ignore[return-value]


@functools.lru_cache(maxsize=32)
def _bicubic_axis(k: int, n: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    """Memo of a pure function: the ``(n, k)`` matrix of ``F.interpolate(..., mode="bicubic", align_corners=True)``
    from ``k`` to ``n`` samples along one axis.

    Bicubic resizing is separable, so ``R_y @ W @ R_x.T`` equals it exactly on a ``(K_y, K_x)`` grid, and costs two
    small matrix products forward and backward instead of the resize kernels (6% of a keyframe gradient).
    """
    with torch.inference_mode(False), torch.no_grad():
        basis = torch.eye(k, device=device, dtype=dtype).view(k, 1, k, 1).expand(k, 1, k, 4)
        rows = F.interpolate(basis, size=(n, 4), mode="bicubic", align_corners=True)  # constant along the width
        return rows[:, 0, :, 0].T.contiguous()


class ControlGrid(nn.Module):
    """A coarse grid of force values per time step, smoothly upsampled to the fluid grid: the default control.

    The control vector ``u`` is ``weight`` of shape ``(B, T, 2, K_y, K_x)`` (cells per time unit^2), upsampled
    bicubically with the corner values at the box's corners (``align_corners=True``), a linear map, so the
    fitted forces stay smooth. ``control=(5, 5)`` over 10 steps is the paper's 500 parameters.

    With ``cumulative=True`` (the default) ``weight[:, t]`` is the running sum of the forces of steps
    ``0..t``: the force of step ``t`` is ``weight[:, t] - weight[:, t - 1]``. Starting from rest, the flow at
    step ``t`` is then about ``dt * weight[:, t]`` (advection and projection reshape it), so every control
    value acts on the points with about the same leverage, where a force of step ``t`` moves them in
    proportion to the ``T - t`` steps left. It is the same set of force schedules in other coordinates, but
    L-BFGS needs fewer evaluations in them (``benchmarks/bench_keyframes.py``, ``bench_morph.py``), and a fit
    without a penalty settles on a flow whose speed is spread evenly over the steps rather than one that
    keeps accelerating. ``cumulative=False``: ``weight[:, t]`` is the force of step ``t`` itself.

    Args:
        steps: ``T``.
        control: ``(K_y, K_x)`` control points per step (each at least 2).
        batch: number of independent problems ``B``.
        init: optional initial values ``(B, T, 2, K_y, K_x)`` of ``weight``; zero by default.
        cumulative: whether ``weight`` holds running sums of the forces (see above) or the forces.

    Example:
        >>> cg = ControlGrid(3, (2, 2), init=torch.ones(1, 3, 2, 2, 2))
        >>> cg.control_forces()[0, :, 0, 0, 0]  # running sums 1, 1, 1: one kick at step 0, then coasting
        tensor([1., 0., 0.], grad_fn=<SelectBackward0>)
    """

    def __init__(
        self,
        steps: int,
        control: tuple[int, int] | int = (5, 5),
        batch: int = 1,
        init: Tensor | None = None,
        cumulative: bool = True,
    ) -> None:
        super().__init__()
        ky, kx = check_size("control", control, minimum=2)
        steps, batch = check_int("steps", steps), check_int("batch", batch)
        if init is None:
            init = torch.zeros(batch, steps, 2, ky, kx)
        check_tensor("init", init, shape=[batch, steps, 2, ky, kx])
        self.weight = nn.Parameter(init.detach().clone())
        self.cumulative = bool(cumulative)

    def extra_repr(self) -> str:
        return f"steps={self.weight.shape[1]}, control={tuple(self.weight.shape[-2:])}, cumulative={self.cumulative}"

    def control_forces(self) -> Tensor:
        """The forces at the control points ``(B, T, 2, K_y, K_x)`` (cells per time unit^2)."""
        w = self.weight
        return torch.cat([w[:, :1], w.diff(dim=1)], dim=1) if self.cumulative else w

    def forward(self, grid: FluidGrid, steps: int, dt: float, image_size: tuple[int, int]) -> Tensor:
        B, T, _, ky, kx = self.weight.shape
        if steps != T:
            raise ValueError(f"this ControlGrid holds {T} steps, but {steps} were asked for")
        h, w = FluidGrid.of(grid).shape
        like = self.weight
        ry, rx = _bicubic_axis(ky, h, like.device, like.dtype), _bicubic_axis(kx, w, like.device, like.dtype)
        return ry @ self.control_forces() @ rx.T


class CellForces(nn.Module):
    """One free force value per fluid cell and step: ``weight`` ``(B, T, 2, h, w)``, cells per time unit^2."""

    def __init__(self, steps: int, grid: FluidGrid | tuple[int, int] | int, batch: int = 1) -> None:
        super().__init__()
        g = FluidGrid.of(grid)
        self.weight = nn.Parameter(torch.zeros(check_int("batch", batch), check_int("steps", steps), 2, *g.shape))

    def forward(self, grid: FluidGrid, steps: int, dt: float, image_size: tuple[int, int]) -> Tensor:
        if FluidGrid.of(grid).shape != tuple(self.weight.shape[-2:]) or steps != self.weight.shape[1]:
            raise ValueError(
                f"CellForces holds {tuple(self.weight.shape)}, but grid {FluidGrid.of(grid).shape} "
                f"and {steps} steps were asked for"
            )
        return self.weight


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

    Newton's method, with the Jacobian of ``D = travel`` by central differences (0.01 px), from ``start`` (default
    ``at``); the map is invertible wherever the paths do not fold, and a few iterations reach round-off.
    """
    m = at.clone() if start is None else start.clone()
    h = 0.01
    ex, ey = m.new_tensor([h, 0.0]), m.new_tensor([0.0, h])
    for _ in range(12):
        residual = m + sigma * travel(m) - at  # (N, 2)
        if float(residual.abs().max()) < 1e-9:
            break
        jx = (travel(m + ex) - travel(m - ex)) / (2 * h)  # (N, 2): dD/dx
        jy = (travel(m + ey) - travel(m - ey)) / (2 * h)
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
            zero (a half cosine) at the image's edges, where the fluid's walls are. A morph puts the walls
            outside the picture and the picture inside, so the walls leave no seam.

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
    ) -> None:
        super().__init__()
        m = check_tensor("midpoints", midpoints, shape=[None, 2])
        if m.shape[0] < 3:
            raise ValueError(f"midpoints must hold at least 3 points, got shape {tuple(m.shape)}")
        d = check_tensor("displacements", displacements, shape=[m.shape[0], 2]).to(m.dtype)
        steps, batch = check_int("steps", steps), check_int("batch", batch)
        self.register_buffer("midpoints", m.detach().clone())
        self.register_buffer("displacements", d.detach().clone())
        self.midpoints: Tensor
        self.displacements: Tensor
        self.weight = nn.Parameter(torch.zeros(batch, steps, m.shape[0], 2, dtype=m.dtype))
        self.inside = None if inside is None else tuple(float(v) for v in inside)
        self._basis: dict[tuple, Tensor] = {}  # (T, h w, M) per grid, image size, device and dtype

    def extra_repr(self) -> str:
        return f"steps={self.weight.shape[1]}, points={self.weight.shape[2]}, inside={self.inside}"

    def basis(self, grid: FluidGrid, image_size: tuple[int, int]) -> Tensor:
        """``(T, h w, M)``: per step, the points' cardinal splines at each cell's particle, faded toward the walls."""
        key = (grid.shape, image_size, self.midpoints.device, self.weight.dtype)
        if key not in self._basis:
            with torch.no_grad():
                mids, disp = self.midpoints.double(), self.displacements.double()
                cells = cell_centres(grid, image_size, mids).reshape(-1, 2)  # (h w, 2) pixels
                fade = torch.ones(cells.shape[0], 1, dtype=torch.float64, device=cells.device)
                if self.inside is not None:
                    x0, y0, x1, y1 = self.inside
                    H, W = image_size
                    fade = (_fade(cells[:, 0], x0, x1, -0.5, W - 0.5) * _fade(cells[:, 1], y0, y1, -0.5, H - 0.5))[
                        :, None
                    ]
                travel = tps_fit(mids, disp)  # D
                cardinal = tps_fit(mids, torch.eye(mids.shape[0], dtype=mids.dtype, device=mids.device))  # one solve
                T = self.weight.shape[1]
                rows, at = [], cells
                for t in range(T):
                    # the particle at a cell at time t / T has its midpoint m with m + (t / T - 1/2) D(m) = cell
                    at = solve_midpoints(travel, cells, t / T - 0.5, start=at)
                    rows.append(fade * cardinal(at))
                self._basis[key] = torch.stack(rows).to(self.weight.dtype)
        return self._basis[key]

    def forward(self, grid: FluidGrid, steps: int, dt: float, image_size: tuple[int, int]) -> Tensor:
        B, T, m, _ = self.weight.shape
        if steps != T:
            raise ValueError(f"this LandmarkForces holds {T} steps, but {steps} were asked for")
        g = FluidGrid.of(grid)
        H, W = check_size("image_size", image_size)
        v = self.displacements.to(self.weight.dtype) / (T * dt) + self.weight  # (B, T, M, 2) pixels per time unit
        kicks = torch.cat([v[:, :1], v.diff(dim=1)], dim=1)
        to_cells = cell_scale((H, W), g, device=v.device, dtype=v.dtype) / dt
        field = torch.einsum("tnm,btmc->btcn", self.basis(g, (H, W)), kicks * to_cells)  # (B, T, 2, h w)
        return field.reshape(B, T, 2, *g.shape)


def viscosity_from_mask(
    mask: Tensor, grid: FluidGrid | tuple[int, int] | int, *, stiff: float = 5.0, soft: float = 0.0
) -> Tensor:
    """A viscosity field from a mask image: ``soft + (stiff - soft) * mask`` averaged onto the fluid grid.

    Args:
        mask: ``(B|1, 1, H, W)`` or ``(H, W)`` values in ``[0, 1]``; 1 marks stiff regions.
        grid: the fluid grid.
        stiff: viscosity where the mask is 1 (cells^2 per time unit); high values resist deformation.
        soft: viscosity where the mask is 0.

    Returns:
        ``(B|1, 1, h, w)`` viscosity field, differentiable in ``mask``.
    """
    m = mask if mask.ndim == 4 else mask.reshape(1, 1, *mask.shape[-2:])
    check_tensor("mask", m, shape=[None, 1, None, None])
    if stiff < 0 or soft < 0:
        raise ValueError(f"stiff and soft must be >= 0, got stiff={stiff}, soft={soft}")
    cells = F.adaptive_avg_pool2d(m.clamp(0, 1), FluidGrid.of(grid).shape)
    return soft + (stiff - soft) * cells


class ViscosityBrushes(nn.Module):
    """A viscosity field painted with Gaussian brushes: ``base + sum_k value_k * exp(-|x - c_k|^2 / 2 r_k^2)``.

    Args:
        centers: ``(K, 2)`` pixels. radius: ``(K,)`` or float, pixels. value: ``(K,)`` or float, added viscosity
            (cells^2 per time unit; negative values soften, and the field is clamped at 0).
        base: the background viscosity.
    """

    def __init__(
        self,
        centers: Tensor | Sequence,
        radius: Tensor | Sequence | float = 10.0,
        value: Tensor | Sequence | float = 5.0,
        base: float = 0.0,
    ) -> None:
        super().__init__()
        c = torch.as_tensor(centers, dtype=torch.get_default_dtype()).detach().clone()
        check_tensor("centers", c, shape=[None, 2])
        k = c.shape[0]
        r = torch.as_tensor(radius, dtype=c.dtype).flatten().expand(k).clone()
        v = torch.as_tensor(value, dtype=c.dtype).flatten().expand(k).clone()
        if bool((r <= 0).any()):
            raise ValueError(f"radius must be > 0, got {r.tolist()}")
        if base < 0:
            raise ValueError(f"base must be >= 0, got {base}")
        self.centers, self.radius, self.value = nn.Parameter(c), nn.Parameter(r), nn.Parameter(v)
        self.base = float(base)

    def forward(self, grid: FluidGrid, image_size: tuple[int, int]) -> Tensor:
        x = cell_centres(FluidGrid.of(grid), check_size("image_size", image_size), self.centers)
        d2 = ((x[None] - self.centers[:, None, None]) ** 2).sum(-1)
        field = self.base + (self.value[:, None, None] * torch.exp(-d2 / (2 * self.radius[:, None, None] ** 2))).sum(0)
        return field.clamp(min=0)[None, None]
