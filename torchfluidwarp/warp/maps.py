"""Texture-coordinate maps: the fluid carries the image's coordinates, and an image is read through them.

Conventions (see :mod:`torchfluidwarp.core.grid`): maps are ``(x, y)`` in **pixels**, pixel centres at integers,
so an image covers ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``; the fluid grid covers the same rectangle.

* The **backward map** ``g_t`` ``(H, W, 2)`` says, for each output pixel of frame ``t``, where in the source
  image to read: frame ``t`` is ``f(g_t(x))``. It is advected semi-Lagrangian,
  ``g_{t+1}(x) = g_t(x - dt v_t(x))`` (midpoint back-trace), on a working raster of at most ``oversample``
  points per fluid cell and axis, and resized from there (:func:`upsample_raster`); the image is sampled once
  per frame from the original, so it never blurs from step to step.
* The **forward map** says where each source pixel has gone: its pixel centre carried forward by RK2 through
  the same velocities, like any passive point.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import (
    check_int,
    check_memory,
    check_positive,
    check_real,
    check_size,
    check_tensor,
)
from torchfluidwarp.core.grid import normalized_affine, rescale_points, scale_factor
from torchfluidwarp.core.sampling import sample
from torchfluidwarp.core.staggered import MAX_STRAIN_PER_SUBSTEP, MAX_SUBSTEPS, StaggeredGrid, channel_first
from torchfluidwarp.errors import InputError, InputTypeError
from torchfluidwarp.warp.frames import identity_map, sample_map

__all__ = [
    "MapConfig",
    "working_raster",
    "upsample_raster",
    "backward_maps",
    "iter_backward_maps",
    "forward_maps",
    "maps_to_end",
    "raster_displacements",
    "read_displacement",
    "OVERSAMPLE",
    "TRACE_OVERSAMPLE",
]


OVERSAMPLE = 4
"""The default ``oversample`` of the maps: they are composed on a raster of up to this many points per fluid
cell and axis, and resized bilinearly from there to larger images (the fluid makes no finer detail)."""

TRACE_OVERSAMPLE = 3
"""The default ``trace_oversample`` of the maps: each step's back-trace is evaluated exactly on a raster of up
to this many points per fluid cell and axis and interpolated bilinearly from there: the displacement of one
step is smooth within a cell. On a 600 x 600 image stirred 62 px in 30 steps, the maps stay within 0.2 px of
those from a 4-per-cell back-trace, which costs about 1.8x as much."""

Times = Sequence[float] | None
"""Frame times in steps: non-decreasing, within ``[0, T]``; ``None`` for ``0, 1, ..., T``."""


@dataclass(frozen=True)
class MapConfig:
    """How finely the texture-coordinate maps are composed, validated when built.

    Attributes:
        oversample: the maps are composed on a raster of at most this many points per fluid cell and axis
            (the image itself when it is smaller) and resized from there (:func:`upsample_raster`); the fluid
            makes no finer detail. Default :data:`OVERSAMPLE`.
        trace_oversample: each step's back-trace is evaluated exactly on a raster of at most this many points
            per fluid cell and axis and interpolated bilinearly from there. Default :data:`TRACE_OVERSAMPLE`.
        max_strain: maps and points are carried in sub-steps of at most this strain ``dt_sub * max|grad v|``
            (:meth:`~torchfluidwarp.core.staggered.StaggeredGrid.substeps`). Default
            :data:`~torchfluidwarp.core.staggered.MAX_STRAIN_PER_SUBSTEP`.
        max_substeps: the most sub-steps one step may take; a flow that needs more is refused with a
            :class:`~torchfluidwarp.errors.FlowBlewUp`. Default :data:`~torchfluidwarp.core.staggered.MAX_SUBSTEPS`.
        max_memory: bytes the maps of one call may hold; default :data:`torchfluidwarp._checks.MAX_BYTES`.
    """

    oversample: int = OVERSAMPLE
    trace_oversample: int = TRACE_OVERSAMPLE
    max_strain: float = MAX_STRAIN_PER_SUBSTEP
    max_substeps: int = MAX_SUBSTEPS
    max_memory: float | None = None

    def __post_init__(self) -> None:
        check_int("oversample", self.oversample)
        check_int("trace_oversample", self.trace_oversample)
        check_positive("max_strain", self.max_strain)
        check_int("max_substeps", self.max_substeps)
        if self.max_memory is not None:
            check_positive("max_memory", self.max_memory)

    def check_memory(self, velocities: Tensor, size: tuple[int, int], count: int) -> None:
        """Refuse ``count`` maps of ``size`` for ``velocities``' batch beyond ``max_memory``, before any work."""
        nbytes = 3 * velocities.shape[0] * count * size[0] * size[1] * 2 * velocities.element_size()
        what = f"{count} maps of size {tuple(size)} for a batch of {velocities.shape[0]}"
        check_memory(what, nbytes, self.max_memory, "MapConfig(max_memory=...)")


def upsample_raster(field: Tensor, size: tuple[int, int]) -> Tensor:
    """Resize a field on a working raster to the image: the one raster-to-map upsample.

    Args:
        field: ``(B, C, H_r, W_r)`` values at the pixel centres of a raster covering the image's rectangle
            (e.g. a displacement, channel 0 = x).
        size: ``(H, W)`` of the image.

    Returns:
        ``(B, C, H, W)`` bilinearly resized, pixel centres aligned (``align_corners=False``); ``field`` itself
        when it already has that size. Values keep their units: a displacement in raster pixels stays in raster
        pixels.
    """
    if tuple(field.shape[-2:]) == tuple(size):
        return field
    return F.interpolate(field, size=size, mode="bilinear", align_corners=False)


def _displacement(
    grid: StaggeredGrid, velocity: Tensor, size: tuple[int, int], dt: float, oversample: int = TRACE_OVERSAMPLE
) -> Tensor:
    """Back-trace displacement ``x - back(x)`` at every pixel, in pixels: ``(B, 2, H, W)``.

    The midpoint back-trace through the staggered velocity is evaluated exactly at the pixel centres of a
    raster of ``min(H, oversample * h) x min(W, oversample * w)`` (the image itself when it is small) covering
    the same rectangle, then resized to ``(H, W)`` (:func:`upsample_raster`).
    """
    raster = working_raster(size, grid.grid.shape, oversample)
    like = velocity
    c = scale_factor(raster, grid.grid.shape, device=like.device, dtype=like.dtype)
    pix = channel_first(identity_map(raster, device=like.device, dtype=like.dtype).reshape(1, -1, 2))
    cells = rescale_points(pix, c).expand(velocity.shape[0], -1, -1)  # (B, N, 2) raster centres in cells
    back = grid.backtrace(grid.extend(velocity), cells, dt)
    per_pixel = scale_factor(size, grid.grid.shape, device=like.device, dtype=like.dtype)
    disp = ((cells - back) / per_pixel).transpose(1, 2).reshape(-1, 2, *raster)  # a view: channel-first memory
    return upsample_raster(disp, size)


def _frame_times(T: int, times: Times) -> list[float]:
    if times is None:
        return [float(t) for t in range(T + 1)]
    out = [float(t) for t in times]
    if any(not (0 <= t <= T) for t in out) or any(b < a for a, b in zip(out, out[1:])):
        raise InputError(f"times must be non-decreasing and within [0, {T}] (steps), got {out}")
    return out


def working_raster(size: tuple[int, int], grid: tuple[int, int], oversample: int = OVERSAMPLE) -> tuple[int, int]:
    """The working raster of the maps, ``(H_r, W_r)``: the image of ``size`` ``(H, W)``, or ``oversample`` points
    per fluid cell of ``grid`` ``(h, w)`` along each axis where that is smaller."""
    return (min(size[0], oversample * grid[0]), min(size[1], oversample * grid[1]))


def _map_composer(
    velocities: Tensor, size: tuple[int, int], dt: float, config: MapConfig = MapConfig()
) -> tuple[Callable[[Tensor, int, float], Tensor], Callable[[Tensor], Tensor], tuple[int, int]]:
    """Map composition on the working raster: ``(compose, to_map, raster)``.

    ``compose(disp, t, duration)`` advances ``disp`` ``(B, 2, Hr, Wr)``, a map minus the identity in raster
    pixels: the result is that map read at ``x - d(x)``, where ``d`` is the midpoint back-trace displacement of
    step ``t``'s velocity over ``duration * dt`` (a negative duration traces forward), in
    :meth:`~torchfluidwarp.core.staggered.StaggeredGrid.substeps` sub-steps short enough never to fold. The
    backward maps (``duration > 0``) and the maps to the end (``duration < 0``) share it.

    ``to_map(disp)`` resizes a raster displacement bilinearly to the image and returns the map
    ``(B, H, W, 2)`` in image pixels. The raster (:func:`working_raster`, ``config.oversample`` points per cell)
    holds every detail the fluid can make, so large images cost one resize per map, not a composition at full
    resolution.
    """
    H, W = size
    grid = StaggeredGrid.of(velocities)
    raster = working_raster(size, grid.grid.shape, config.oversample)
    Hr, Wr = raster
    like = velocities
    pix = identity_map(raster, device=like.device, dtype=like.dtype).permute(0, 3, 1, 2).contiguous()  # (1, 2, Hr, Wr)
    lo = torch.tensor([-0.5, -0.5], device=like.device, dtype=like.dtype).view(1, 2, 1, 1)
    hi = torch.tensor([Wr - 0.5, Hr - 0.5], device=like.device, dtype=like.dtype).view(1, 2, 1, 1)
    scale, shift = (a.view(1, 1, 1, 2) for a in normalized_affine(raster, device=like.device, dtype=like.dtype))
    ratio = scale_factor(raster, size, device=like.device, dtype=like.dtype).view(1, 1, 1, 2)  # raster px -> image px
    ident: list[Tensor] = []  # the image's identity map (1, H, W, 2), built by the first to_map only

    def compose(disp: Tensor, t: int, duration: float) -> Tensor:
        velocity = velocities[:, t]
        n = grid.substeps(grid.extend(velocity.detach()), dt * duration, config.max_strain, config.max_substeps)
        # every sub-step traces the same velocity over the same time: one back-trace serves them all
        back = _displacement(grid, velocity, raster, dt * duration / n, config.trace_oversample)
        at = torch.clamp(pix - back, lo, hi)
        step = at - pix
        # unchecked: the velocity was refused by substeps if non-finite, and `at` is clamped into the raster
        at = torch.addcmul(shift, at.permute(0, 2, 3, 1), scale)  # (B, Hr, Wr, 2) grid_sample's coordinates
        for _ in range(n):
            disp = step + sample(disp, at, align_corners=False, check=None)
        return disp

    def to_map(disp: Tensor) -> Tensor:  # one pass, (B, H, W, 2) contiguous (ratio is 1 when raster == size)
        if not ident:
            ident.append(identity_map(size, device=like.device, dtype=like.dtype))
        return torch.addcmul(ident[0], upsample_raster(disp, size).permute(0, 2, 3, 1), ratio)

    return compose, to_map, raster


class _Maps:
    """The checked arguments of a map computation and its composer (see :func:`_map_composer`)."""

    def __init__(
        self, velocities: Tensor, size: tuple[int, int], dt: float, times: Times, config: MapConfig, held: str = "size"
    ) -> None:
        check_tensor("velocities", velocities, ndim=5)
        size = check_size("size", size)
        dt = check_real("dt", dt)
        if not isinstance(config, MapConfig):
            raise InputTypeError(f"config must be a MapConfig, got {type(config).__name__}")
        self.T = velocities.shape[1]
        self.times = _frame_times(self.T, times)
        grid = StaggeredGrid.of(velocities).grid.shape
        config.check_memory(
            velocities, size if held == "size" else working_raster(size, grid, config.oversample), len(self.times)
        )
        self.compose, self.to_map, self.raster = _map_composer(velocities, size, dt, config)
        self.zero = velocities.new_zeros(velocities.shape[0], 2, *self.raster)  # the identity's displacement


def _iter_displacements(
    velocities: Tensor, size: tuple[int, int], dt: float, times: Times, config: MapConfig = MapConfig()
) -> tuple[Iterator[Tensor], Callable[[Tensor], Tensor], tuple[int, int]]:
    """The backward maps as raster displacements (see :func:`iter_backward_maps`), and ``to_map`` and the raster."""
    maps = _Maps(velocities, size, dt, times, config)
    return _backward_displacements(maps), maps.to_map, maps.raster


def _backward_displacements(maps: _Maps) -> Iterator[Tensor]:
    """``g_s(x) - x`` on the raster (raster pixels), one per time of ``maps``, in order."""
    disp = maps.zero  # g_t(x) - x at integer step `done`, raster pixels
    done = 0
    for s in maps.times:
        while done + 1 <= s:
            disp = maps.compose(disp, done, 1.0)
            done += 1
        yield disp if s == done else maps.compose(disp, done, s - done)


def iter_backward_maps(
    velocities: Tensor, size: tuple[int, int], dt: float = 1.0, times: Times = None, *, config: MapConfig = MapConfig()
) -> Iterator[Tensor]:
    """Yield the backward maps ``(B, H, W, 2)`` (pixels) one at a time, at the given times.

    ``g_{t+1}(x) = g_t(x - d_t(x))`` where ``d_t`` is the midpoint back-trace displacement of step ``t``
    (see :func:`_displacement`), clamped to the image rectangle. The maps are carried as displacements
    ``g_t(x) - x``, sampled bilinearly: small numbers keep float32 round-off small, and a flow at rest gives
    exactly the identity. A time ``s`` between steps ``t`` and ``t + 1`` applies step ``t``'s velocity for
    ``(s - t) dt``.

    Args:
        velocities: ``(B, T, 2, h + 1, w + 1)`` staggered velocities (cells per time unit).
        size: ``(H, W)`` of the image.
        dt: the roll-out's time step.
        times: non-decreasing times in steps, within ``[0, T]`` (default ``0, 1, ..., T``).
        config: the rasters' resolutions and the sub-steps' strain (:class:`MapConfig`).
    """
    displacements, to_map, _ = _iter_displacements(velocities, size, dt, times, config)
    for disp in displacements:
        yield to_map(disp)


def backward_maps(
    velocities: Tensor, size: tuple[int, int], dt: float = 1.0, times: Times = None, *, config: MapConfig = MapConfig()
) -> Tensor:
    """Backward coordinate maps of a roll-out, advected semi-Lagrangian on the maps' working raster.

    The raster is the image itself, or ``config.oversample`` points per fluid cell and axis when the image is
    larger; the maps are resized from there to ``size`` bilinearly.

    Args:
        velocities: ``(B, T, 2, h + 1, w + 1)`` staggered velocities (fluid cells per time unit), as returned
            by :class:`~torchfluidwarp.core.simulator.FluidSimulator`.
        size: ``(H, W)`` of the image the maps are for.
        dt: the roll-out's time step.
        times: optional times in steps (default ``0..T``); see :func:`iter_backward_maps`.
        config: the rasters' resolutions and the sub-steps' strain (:class:`MapConfig`).

    Returns:
        ``(B, len(times), H, W, 2)`` maps in pixels (``T + 1`` by default; map 0 is the identity). Frame ``t``
        is ``warp_image(f, maps[:, t])``.
    """
    return torch.stack(list(iter_backward_maps(velocities, size, dt, times, config=config)), dim=1)


def maps_to_end(
    velocities: Tensor, size: tuple[int, int], dt: float = 1.0, times: Times = None, *, config: MapConfig = MapConfig()
) -> Tensor:
    """Where the fluid carries each pixel from time ``s`` to the end ``T``: ``(B, len(times), H, W, 2)`` pixels.

    ``K_s = F_{s -> T}``, built backwards in time like the backward maps run forwards:
    ``K_T(z) = z`` and ``K_s(z) = K_{t+1}(z + e(z))`` for ``s`` in ``[t, t + 1)``, where ``e`` is the forward
    RK2 displacement of step ``t``'s velocity over ``(t + 1 - s) dt``. The morph uses it to pull the target
    image back along the very flow that carries the source (``K_s`` inverts the backward map ``g_s`` composed
    with ``K_0``).

    Args:
        velocities: ``(B, T, 2, h + 1, w + 1)`` staggered velocities.
        size: ``(H, W)``. dt: time step. times: non-decreasing times in ``[0, T]`` (default ``0..T``).
        config: the rasters' resolutions and the sub-steps' strain (:class:`MapConfig`).
    """
    maps = _Maps(velocities, size, dt, times, config)
    return torch.stack([maps.to_map(d) for d in _to_end_displacements(maps)], dim=1)


def _to_end_displacements(maps: _Maps) -> list[Tensor]:
    """``K_s(z) - z`` on the raster (raster pixels), one per time of ``maps``, in order (see :func:`maps_to_end`)."""

    def pull(disp: Tensor, t: int, fraction: float) -> Tensor:
        return maps.compose(disp, t, -fraction)  # read ahead: trace forward over the step's remaining time

    disp = maps.zero  # K_t(z) - z at integer step `done`, raster pixels
    done = maps.T
    out: list[Tensor] = []
    for s in reversed(maps.times):
        while done - 1 >= s:
            disp = pull(disp, done - 1, 1.0)
            done -= 1
        out.append(disp if s == done else pull(disp, done - 1, done - s))
    return out[::-1]


def raster_displacements(
    velocities: Tensor,
    size: tuple[int, int],
    dt: float = 1.0,
    times: Times = None,
    *,
    to_end: bool = False,
    config: MapConfig = MapConfig(),
) -> Tensor:
    """The maps of :func:`backward_maps` (or of :func:`maps_to_end` with ``to_end=True``) before their one resize:
    each map minus the identity on the maps' working raster, ``(B, len(times), 2, H_r, W_r)``, channel 0 = x, in
    pixels of the image of ``size``.

    The raster (``config.oversample`` points per fluid cell and axis, or the image when smaller) holds all the
    detail the fluid makes, so a large image's maps cost the raster's memory, not the image's: a morph of a
    6000 x 6000 pair reads each frame's maps from rasters of about 2 MB instead of two 0.45 GB maps. Read them at
    any pixel positions with :func:`read_displacement`; the maps of :func:`backward_maps` are those readings at
    the pixel centres.
    """
    maps = _Maps(velocities, size, dt, times, config, held="raster")
    if to_end:
        disps = _to_end_displacements(maps)
    else:
        disps = list(_backward_displacements(maps))
    ratio = scale_factor(maps.raster, size, device=velocities.device, dtype=velocities.dtype).view(1, 2, 1, 1)
    return torch.stack([d * ratio for d in disps], dim=1)


def read_displacement(displacement: Tensor, size: tuple[int, int], at: Tensor) -> Tensor:
    """Read a displacement field on a raster covering an image of ``size`` at pixel positions of that image.

    Args:
        displacement: ``(B, 2, H_r, W_r)`` (channel 0 = x), e.g. a frame of :func:`raster_displacements`, its
            samples at the centres of an ``H_r x W_r`` raster over the image's rectangle; any unit.
        size: ``(H, W)`` of the image.
        at: ``(B, H', W', 2)`` positions in the image's pixels, ``(x, y)``, pixel centres at integers.

    Returns:
        ``(B, H', W', 2)`` the displacement at ``at``, bilinear between the raster's samples and held constant
        beyond its outermost ones (as :func:`upsample_raster` holds it), so ``at + result`` continues as a
        translation beyond the raster instead of collapsing onto its edge.

    Raises:
        ValueError, TypeError: shapes other than the above, a batch of ``at`` other than the field's, a bad
            ``size``, or non-finite positions ``at`` (refused by the sampler, naming ``at``).
    """
    # shapes only: the sampler refuses non-finite positions itself, and NaN in the field stays NaN in the result
    check_tensor("displacement", displacement, ndim=4, finite=False)
    check_tensor("at", at, shape=[displacement.shape[0], None, None, 2], finite=False)
    size = check_size("size", size)
    if displacement.shape[1] != 2:
        raise InputError(f"displacement must have 2 channels (x, y), got shape {tuple(displacement.shape)}")
    Hr, Wr = displacement.shape[-2:]
    ratio = at.new_tensor([Wr / size[1], Hr / size[0]])
    on_raster = (at + 0.5) * ratio - 0.5  # the same point in raster pixels
    return sample_map(displacement, on_raster, "bilinear", check="at").permute(0, 2, 3, 1)


def forward_maps(
    velocities: Tensor, size: tuple[int, int], dt: float = 1.0, *, config: MapConfig = MapConfig()
) -> Tensor:
    """Where each source pixel has gone: ``(B, T + 1, H, W, 2)`` pixel positions, carried forward by RK2.

    The forward and backward maps of one roll-out are inverse to each other up to discretisation error
    (see the tests: within 0.1 px away from the walls for smooth flows). Of ``config`` only ``max_strain``
    applies: every pixel is carried, with no raster.
    """
    check_tensor("velocities", velocities, ndim=5)
    H, W = check_size("size", size)
    dt = check_real("dt", dt)
    B, T = velocities.shape[:2]
    config.check_memory(velocities, (H, W), T + 1)
    pix = identity_map((H, W), batch=B, device=velocities.device, dtype=velocities.dtype).reshape(B, -1, 2)
    grid = StaggeredGrid.of(velocities)
    return grid.trajectories(velocities, pix, dt, (H, W), config.max_strain, config.max_substeps).view(
        B, T + 1, H, W, 2
    )
