"""Drawing a random fluid warp: random brushes, one roll-out for the batch, and redraws until no map folds.

:func:`draw_fluid_warp` turns :class:`~torchfluidwarp.augment.settings.FluidWarpSettings` and a generator into
a :class:`FluidWarpParams`: the draw that every input of a call is then moved through
(:mod:`torchfluidwarp.augment.carry`).

The fluid is incompressible, so the continuous flow never folds, but its discretisation can when one step
shears a cell by about its own size or the whole push carries the image many brush radii. Two guards keep
every warp fold-free: the settings refuse strengths past :data:`~torchfluidwarp.augment.settings.MAX_SHEAR`,
and each drawn map is checked (:func:`min_quad_determinant`); a sample whose map would fold is rolled out
again with half the force.

Conventions (see :mod:`torchfluidwarp.core.grid`): points are ``(x, y)`` in **pixels**, pixel centres at
integers; forces and velocities are in fluid cells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from torchfluidwarp._checks import check_int, check_memory, check_size, warn
from torchfluidwarp.augment.settings import FluidWarpSettings
from torchfluidwarp.core.grid import FluidGrid, cell_centres, cell_scale, rescale_points, scale_factor
from torchfluidwarp.core.simulator import FluidSimulator
from torchfluidwarp.core.staggered import StaggeredGrid
from torchfluidwarp.errors import InputError
from torchfluidwarp.warp.forces import gaussian_bumps
from torchfluidwarp.warp.maps import iter_backward_maps, working_raster

__all__ = [
    "MIN_DET",
    "FluidWarpParams",
    "draw_fluid_warp",
    "make_simulator",
    "brush_forces",
    "min_quad_determinant",
    "raster_map",
]

MIN_DET: float = 0.1
"""A drawn map is accepted when its Jacobian determinant stays at least this everywhere (see
:func:`min_quad_determinant`); otherwise the sample is rolled out again with half its force."""


@dataclass(frozen=True)
class FluidWarpParams:
    """One draw of a random fluid warp: everything needed to move any input of the call.

    Attributes:
        velocities: ``(B, T, 2, h + 1, w + 1)`` staggered velocities (fluid cells per time unit); sample ``b``'s
            velocities after its own ``steps[b]`` are zero, so its warp stops there.
        steps: ``(B,)`` the number of fluid steps of each sample.
        dt: the time step.
        centers: ``(B, K, 2)`` brush centres in pixels.
        directions: ``(B, K, 2)`` unit push directions.
        amplitude: ``(B, K)`` peak accelerations in pixels per time unit^2 (0 for the unused brushes).
        radius: ``(B, K)`` Gaussian radii in pixels.
        force_scale: ``(B,)`` the factor the fold check applied to each sample's forces (1 unless its first
            map would have folded; 0 if every retry would have folded too: that sample is left unwarped).
        size: ``(H, W)`` the image size the draw was made for.
        raster_map: ``(B, h_r, w_r, 2)`` the backward map on the composition raster (see
            :func:`~torchfluidwarp.augment.carry.fluid_warp_map`), in pixels of ``size``.
        min_det: ``(B,)`` the smallest Jacobian determinant of each map (:func:`min_quad_determinant`).
    """

    velocities: Tensor
    steps: Tensor
    dt: float
    centers: Tensor
    directions: Tensor
    amplitude: Tensor
    radius: Tensor
    force_scale: Tensor
    size: tuple[int, int]
    raster_map: Tensor
    min_det: Tensor

    @property
    def batch(self) -> int:
        return self.velocities.shape[0]


def brush_forces(
    centers: Tensor,
    directions: Tensor,
    amplitude: Tensor,
    radius: Tensor,
    *,
    grid: FluidGrid | int | tuple[int, int],
    image_size: tuple[int, int],
    steps: int,
) -> Tensor:
    """Steady Gaussian brush pushes for a batch of independent samples.

    Brush ``k`` of sample ``b`` pushes with ``amplitude[b, k] * directions[b, k] * exp(-|x - c|^2 / 2 r^2)``, the
    same force at every step (the batched, steady form of :class:`~torchfluidwarp.warp.forces.Brushes`).

    Args:
        centers: ``(B, K, 2)`` brush centres ``(x, y)`` in pixels.
        directions: ``(B, K, 2)`` unit push directions (channel 0 = x).
        amplitude: ``(B, K)`` peak acceleration in pixels per time unit^2; 0 switches a brush off.
        radius: ``(B, K)`` Gaussian radius in pixels (> 0).
        grid: the fluid grid ``(h, w)``.
        image_size: ``(H, W)`` of the image the pixels refer to.
        steps: ``T``.

    Returns:
        ``(B, T, 2, h, w)`` forces in fluid cells per time unit^2 (an expanded view over ``T``).

    Example:
        >>> f = brush_forces(torch.tensor([[[32.0, 32.0]]]), torch.tensor([[[1.0, 0.0]]]), torch.tensor([[0.5]]),
        ...                  torch.tensor([[8.0]]), grid=16, image_size=(64, 64), steps=3)
        >>> f.shape, round(float(f.amax()), 3)
        (torch.Size([1, 3, 2, 16, 16]), 0.121)
    """
    g = FluidGrid.of(grid)
    device, dtype = centers.device, centers.dtype
    x = cell_centres(g, image_size, device=device, dtype=dtype)  # (h, w, 2) pixels
    bump = gaussian_bumps(x, centers, radius)  # (B, K, h, w)
    # pixels -> cells: accelerations scale like lengths
    push = amplitude[..., None] * directions * cell_scale(image_size, g, device=device, dtype=dtype)  # (B, K, 2)
    field = torch.einsum("bkc,bkhw->bchw", push, bump)
    return field.unsqueeze(1).expand(-1, steps, -1, -1, -1)


def min_quad_determinant(coords: Tensor, size: tuple[int, int]) -> Tensor:
    """The smallest Jacobian determinant of the bilinear interpolant of a coordinate map, per sample ``(B,)``.

    ``coords`` ``(B, h_r, w_r, 2)`` holds positions in pixels of an ``(H, W)`` image at the pixel centres of an
    ``h_r x w_r`` raster covering the same rectangle. Between four raster points the bilinear interpolant's
    determinant is linear along each axis, so its minimum is one of the four corners', each taken from the
    quad's own edges: when all are positive, no resampling of the map (bilinear, at any resolution) folds.

    Example:
        >>> from torchfluidwarp.warp.layer import identity_map
        >>> min_quad_determinant(identity_map((4, 4)), (4, 4)).tolist()
        [1.0]
    """
    H, W = size
    h_r, w_r = coords.shape[1:3]
    ex = coords[:, :, 1:] - coords[:, :, :-1]  # (B, h_r, w_r - 1, 2) along x
    ey = coords[:, 1:] - coords[:, :-1]  # (B, h_r - 1, w_r, 2) along y
    area = (W / w_r) * (H / h_r)  # raster spacing in image pixels
    dets = [
        a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        for a in (ex[:, :-1], ex[:, 1:])
        for b in (ey[:, :, :-1], ey[:, :, 1:])
    ]
    return torch.stack(dets).amin(0).flatten(1).amin(1) / area


def raster_map(velocities: Tensor, size: tuple[int, int], dt: float) -> Tensor:
    """The backward map of the last step on the composition raster: ``(B, h_r, w_r, 2)`` in pixels of ``size``.

    The raster has at most :data:`~torchfluidwarp.warp.maps.OVERSAMPLE` points per fluid cell and axis (the image
    itself when smaller), and the map is composed on it step by step
    (:func:`~torchfluidwarp.warp.maps.iter_backward_maps`).
    """
    raster = working_raster(size, StaggeredGrid.of(velocities).grid.shape)
    back = next(iter_backward_maps(velocities, raster, dt, times=[velocities.shape[1]]))  # raster pixels
    if raster == tuple(size):
        return back
    return rescale_points(back, scale_factor(raster, size, device=back.device, dtype=back.dtype))


def make_simulator(settings: FluidWarpSettings, *, cuda_graphs: bool = False) -> FluidSimulator:
    """The fluid of ``settings`` (grid, ``dt``, viscosity), for :func:`draw_fluid_warp`'s ``simulator``."""
    return FluidSimulator(settings.grid, settings.dt, settings.viscosity, cuda_graphs=cuda_graphs)


def draw_fluid_warp(
    settings: FluidWarpSettings,
    batch: int,
    size: tuple[int, int],
    *,
    generator: torch.Generator | None = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
    simulator: FluidSimulator | None = None,
) -> FluidWarpParams:
    """Draw the random brushes of one call and roll the fluid out for the whole batch, fold-free.

    Draws happen on the generator's device (CPU without one), so a seed gives the same warp on any device; the
    roll-out then runs on ``device`` in ``dtype`` without autograd, for the whole batch in one call of a
    :class:`~torchfluidwarp.core.simulator.FluidSimulator` (a sample's map depends only on its own brushes). Each
    random quantity is drawn for all ``B`` samples at once (counts, steps, centres, angles, strengths, radii),
    so a generator state fixes the draw of a given ``batch``, but sample ``b`` of a batch is not the warp that
    the ``b``-th of ``B`` batch-1 draws from the same state would give. A sample whose map would fold
    (:func:`min_quad_determinant` below :data:`MIN_DET`) is rolled out again with half its force, up to
    ``settings.max_retries`` times, then left unwarped (``force_scale`` records it).

    Args:
        settings: the ranges, the fluid and the retries.
        batch: ``B``, one independent draw per sample.
        size: ``(H, W)`` of the images in pixels.
        generator: the random source; ``None`` uses torch's global RNG.
        device, dtype: where and in which floating dtype to roll out.
        simulator: the fluid to roll out, made by :func:`make_simulator` from ``settings``; a caller that draws
            many times (:class:`~torchfluidwarp.augment.tensor.FluidWarpAugment`) passes the one it holds, so a
            draw sets nothing up (and, with ``cuda_graphs``, replays the step captured by an earlier draw). A new
            one by default.

    Returns:
        a :class:`FluidWarpParams`.

    Example:
        >>> p = draw_fluid_warp(FluidWarpSettings(grid=16), 2, (32, 32), generator=torch.Generator().manual_seed(0))
        >>> p.velocities.shape[0], p.size, bool((p.min_det >= MIN_DET).all())
        (2, (32, 32), True)
    """
    B = check_int("batch", batch)
    H, W = check_size("size", size, minimum=0)
    if min(H, W) < 2:  # a fluid warp needs a pixel's neighbours: refuse, naming the image, instead of an IndexError
        raise InputError(f"the image must be at least 2 x 2 pixels to warp, got size {(H, W)}")
    (h, w), itemsize = settings.grid.shape, dtype.itemsize
    T, K = settings.steps[1], settings.count[1]
    # roll-out and maps, a few copies of each, and each brush's force field on the grid
    nbytes = 3 * B * (T * 2 * (h + 1) * (w + 1) + 2 * H * W + K * h * w) * itemsize
    what = f"a fluid warp of {B} images of size {(H, W)} with up to count={K} brushes"
    what += f" on a grid of {h} x {w} cells for {T} steps"
    check_memory(what, nbytes, settings.max_memory, "max_memory (FluidWarpSettings)")
    cell, typical = max(H / h, W / w), sum(settings.radius) / 2
    if typical < cell:  # the fluid cannot hold a push narrower than its cells: the warp is faint
        warn(
            f"the brushes' radius, {typical:.3g} px on average, is under a fluid cell ({cell:.3g} px on a {W} x {H} "
            f"image over {w} x {h} cells): the fluid smooths them away and the warp is faint; raise radius (and "
            "strength, both in pixels) with the image's size, or use a finer grid",
            RuntimeWarning,
        )
    device = torch.device("cpu") if device is None else torch.device(device)
    g = generator
    draw_device = g.device if g is not None else torch.device("cpu")
    s = settings
    K = s.count[1]

    def uniform(lo: float, hi: float, *shape: int) -> Tensor:
        return lo + (hi - lo) * torch.rand(*shape, generator=g, device=draw_device, dtype=torch.float64)

    counts = torch.randint(s.count[0], s.count[1] + 1, (B,), generator=g, device=draw_device)
    steps = torch.randint(s.steps[0], s.steps[1] + 1, (B,), generator=g, device=draw_device)
    # brush centres uniform over the pixel centres [0, W - 1] x [0, H - 1]
    centers = uniform(0.0, 1.0, B, K, 2) * torch.tensor([W - 1.0, H - 1.0], dtype=torch.float64, device=draw_device)
    angle = uniform(0.0, 2 * math.pi, B, K)
    amplitude = uniform(*s.strength, B, K)
    radius = uniform(*s.radius, B, K)
    active = torch.arange(K, device=draw_device)[None] < counts[:, None]
    amplitude = torch.where(active, amplitude, torch.zeros_like(amplitude))

    centers, amplitude = centers.to(device=device, dtype=dtype), amplitude.to(device=device, dtype=dtype)
    radius = radius.to(device=device, dtype=dtype)
    directions = torch.stack([angle.cos(), angle.sin()], -1).to(device=device, dtype=dtype)
    steps = steps.to(device)
    T = int(steps.max())
    sim = make_simulator(s) if simulator is None else simulator
    running = (torch.arange(T, device=device)[None] < steps[:, None]).to(dtype)  # (B, T)
    scale = torch.ones(B, device=device, dtype=dtype)

    def roll(forces: Tensor, running: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        # a sample's warp stops after its own steps: zero velocity leaves maps and points in place
        v = sim(forces, image_size=(H, W)).velocities * running[:, :, None, None, None]
        m = raster_map(v, (H, W), s.dt)
        return v, m, min_quad_determinant(m, (H, W))

    with torch.no_grad():
        forces = brush_forces(centers, directions, amplitude, radius, grid=s.grid, image_size=(H, W), steps=T)
        vel, maps, det = roll(forces, running)
        todo = (det < MIN_DET).nonzero().flatten()
        for attempt in range(s.max_retries + 1):
            if todo.numel() == 0:
                break
            # half the force, or, once the retries are spent, none: that sample is left unwarped
            scale[todo] = 0.0 if attempt == s.max_retries else 0.5 * scale[todo]
            v, m, d = roll(forces[todo] * scale[todo, None, None, None, None], running[todo])
            vel[todo], maps[todo], det[todo] = v, m, d
            todo = todo[d < MIN_DET]
    return FluidWarpParams(
        velocities=vel,
        steps=steps,
        dt=s.dt,
        centers=centers,
        directions=directions,
        amplitude=amplitude,
        radius=radius,
        force_scale=scale,
        size=(H, W),
        raster_map=maps,
        min_det=det,
    )
