"""Force and viscosity parametrisations: the knobs of indirect control and the control vector of fitting.

Force modules are called as ``forces(grid, steps, dt, image_size)`` and return a schedule
``(B|1, T, 2, h, w)`` in fluid cells per time unit^2 (channel 0 = x). Viscosity modules are called as
``viscosity(grid, image_size)`` and return a field ``(B|1, 1, h, w)`` in cells^2 per time unit. Positions and
lengths given to them are in **pixels** of an image of size ``image_size = (H, W)`` (pixel centres at
integers), so the same module drives any fluid resolution. Every parameter is an ``nn.Parameter``, so
brushes and control grids are differentiable and can be fitted. The landmark forces of the natural morph live in
:mod:`torchfluidwarp.warp.landmarks`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from torchfluidwarp._checks import check_int, check_size, check_tensor
from torchfluidwarp.core.grid import FluidGrid, cell_scale
from torchfluidwarp.core.grid import cell_centres as _grid_cell_centres
from torchfluidwarp.errors import InputError

__all__ = [
    "Brushes",
    "SumForces",
    "ControlGrid",
    "CellForces",
    "bicubic_axis",
    "ViscosityBrushes",
    "viscosity_from_mask",
    "cell_centres",
    "gaussian_bumps",
]


def cell_centres(grid: FluidGrid, image_size: tuple[int, int], like: Tensor) -> Tensor:
    """Fluid cell centres in the image's pixels: ``(h, w, 2)`` ``(x, y)``, on ``like``'s device and dtype.

    :func:`torchfluidwarp.core.grid.cell_centres`, which it calls, is the one definition.
    """
    return _grid_cell_centres(grid, image_size, device=like.device, dtype=like.dtype)


def gaussian_bumps(points: Tensor, centers: Tensor, radius: Tensor) -> Tensor:
    """Gaussian brushes ``exp(-|x - c|^2 / (2 r^2))`` evaluated at points: the one brush profile.

    Args:
        points: ``(h, w, 2)`` positions ``(x, y)``, e.g. the fluid cell centres in pixels (:func:`cell_centres`).
        centers: ``(..., 2)`` brush centres ``(x, y)`` in the same units, e.g. ``(K, 2)`` or ``(B, K, 2)``.
        radius: ``(...)`` Gaussian radii in the same units, one per centre.

    Returns:
        ``(..., h, w)`` values in ``(0, 1]``, 1 at a brush's centre.

    Example:
        >>> x = torch.tensor([[[0.0, 0.0], [3.0, 4.0]]])  # (1, 2, 2)
        >>> gaussian_bumps(x, torch.zeros(1, 2), torch.tensor([5.0])).squeeze().tolist()
        [1.0, 0.6065306663513184]
    """
    d2 = ((points - centers[..., None, None, :]) ** 2).sum(-1)  # (..., h, w)
    return torch.exp(-d2 / (2 * radius[..., None, None] ** 2))


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
            raise InputError("centers must hold at least one brush, got shape (0, 2)")
        d = torch.as_tensor(directions, dtype=c.dtype, device=c.device).detach().clone()
        check_tensor("directions", d, shape=[k, 2])
        if bool((d.norm(dim=-1) == 0).any()):
            raise InputError("directions must be non-zero vectors")

        def per_brush(name: str, v: Tensor | Sequence | float, positive: bool) -> nn.Parameter:
            t = torch.as_tensor(v, dtype=c.dtype, device=c.device).detach().clone().flatten()
            t = t.expand(k).clone() if t.numel() == 1 else t
            check_tensor(name, t, shape=[k])
            if positive and bool((t <= 0).any()):
                raise InputError(f"{name} must be > 0, got {t.tolist()}")
            if not positive and name == "frequency" and bool((t < 0).any()):
                raise InputError(f"frequency must be >= 0, got {t.tolist()}")
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
        bump = gaussian_bumps(x, self.centers, self.radius)  # (K, h, w)
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
            raise InputError("SumForces needs at least one force module")
        self.parts = nn.ModuleList(modules)

    def forward(self, grid: FluidGrid, steps: int, dt: float, image_size: tuple[int, int]) -> Tensor:
        return sum(p(grid, steps, dt, image_size) for p in self.parts)  # type: ignore[return-value]


def bicubic_axis(k: int, n: int, *, device: torch.device | None = None, dtype: torch.dtype | None = None) -> Tensor:
    """The ``(n, k)`` matrix of ``F.interpolate(..., mode="bicubic", align_corners=True)`` from ``k`` to ``n``
    samples along one axis.

    Bicubic resizing is separable, so ``R_y @ W @ R_x.T`` equals it exactly on a ``(K_y, K_x)`` grid, and costs two
    small matrix products forward and backward instead of the resize kernels (6% of a keyframe gradient).
    """
    # outside inference mode: a ControlGrid keeps these for the life of the module, also for fits that record
    # gradients after a first call under torch.inference_mode()
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
        init: optional initial values ``(B, T, 2, K_y, K_x)`` of ``weight`` (its device and dtype are kept); zero
            by default.
        cumulative: whether ``weight`` holds running sums of the forces (see above) or the forces.
        device, dtype: of the zero ``weight`` when ``init`` is not given (default: the default dtype on the CPU,
            as for ``torch.nn``'s layers; ``.to()`` moves it later).

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
        *,
        device: torch.device | str | None = None,
        dtype: torch.dtype | None = None,
    ) -> None:
        super().__init__()
        ky, kx = check_size("control", control, minimum=2)
        steps, batch = check_int("steps", steps), check_int("batch", batch)
        if init is None:
            init = torch.zeros(batch, steps, 2, ky, kx, device=device, dtype=dtype)
        check_tensor("init", init, shape=[batch, steps, 2, ky, kx])
        self.weight = nn.Parameter(init.detach().clone())
        self.cumulative = bool(cumulative)
        # the upsampling matrices per fluid grid, device and dtype: built once for the life of this module
        self._upsample: dict[tuple[int, int, torch.device, torch.dtype], tuple[Tensor, Tensor]] = {}

    def extra_repr(self) -> str:
        return f"steps={self.weight.shape[1]}, control={tuple(self.weight.shape[-2:])}, cumulative={self.cumulative}"

    def control_forces(self) -> Tensor:
        """The forces at the control points ``(B, T, 2, K_y, K_x)`` (cells per time unit^2)."""
        w = self.weight
        return torch.cat([w[:, :1], w.diff(dim=1)], dim=1) if self.cumulative else w

    def forward(self, grid: FluidGrid, steps: int, dt: float, image_size: tuple[int, int]) -> Tensor:
        B, T, _, ky, kx = self.weight.shape
        if steps != T:
            raise InputError(f"this ControlGrid holds {T} steps, but {steps} were asked for")
        h, w = FluidGrid.of(grid).shape
        like = self.weight
        key = (h, w, like.device, like.dtype)
        if key not in self._upsample:
            self._upsample[key] = (
                bicubic_axis(ky, h, device=like.device, dtype=like.dtype),
                bicubic_axis(kx, w, device=like.device, dtype=like.dtype),
            )
        ry, rx = self._upsample[key]
        return ry @ self.control_forces() @ rx.T


class CellForces(nn.Module):
    """One free force value per fluid cell and step: ``weight`` ``(B, T, 2, h, w)``, cells per time unit^2.

    ``device`` and ``dtype`` are those of the zero ``weight`` (default: the default dtype on the CPU, as for
    ``torch.nn``'s layers; ``.to()`` moves it later).
    """

    def __init__(
        self,
        steps: int,
        grid: FluidGrid | tuple[int, int] | int,
        batch: int = 1,
        *,
        device: torch.device | str | None = None,
        dtype: torch.dtype | None = None,
    ) -> None:
        super().__init__()
        shape = (check_int("batch", batch), check_int("steps", steps), 2, *FluidGrid.of(grid).shape)
        self.weight = nn.Parameter(torch.zeros(shape, device=device, dtype=dtype))

    def forward(self, grid: FluidGrid, steps: int, dt: float, image_size: tuple[int, int]) -> Tensor:
        if FluidGrid.of(grid).shape != tuple(self.weight.shape[-2:]) or steps != self.weight.shape[1]:
            raise InputError(
                f"CellForces holds {tuple(self.weight.shape)}, but grid {FluidGrid.of(grid).shape} "
                f"and {steps} steps were asked for"
            )
        return self.weight


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
        raise InputError(f"stiff and soft must be >= 0, got stiff={stiff}, soft={soft}")
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
        r = torch.as_tensor(radius, dtype=c.dtype, device=c.device).flatten().expand(k).clone()
        v = torch.as_tensor(value, dtype=c.dtype, device=c.device).flatten().expand(k).clone()
        if bool((r <= 0).any()):
            raise InputError(f"radius must be > 0, got {r.tolist()}")
        if base < 0:
            raise InputError(f"base must be >= 0, got {base}")
        self.centers, self.radius, self.value = nn.Parameter(c), nn.Parameter(r), nn.Parameter(v)
        self.base = float(base)

    def forward(self, grid: FluidGrid, image_size: tuple[int, int]) -> Tensor:
        x = cell_centres(FluidGrid.of(grid), check_size("image_size", image_size), self.centers)
        field = self.base + (self.value[:, None, None] * gaussian_bumps(x, self.centers, self.radius)).sum(0)
        return field.clamp(min=0)[None, None]
