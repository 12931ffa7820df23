"""Fluid warping: the fluid carries the image's texture coordinates, never its pixel values.

Conventions (as everywhere in the library, see :mod:`torchfluidwarp.core.grid`): images are ``(B, C, H, W)``
floats in ``[0, 1]``; points and coordinate maps are ``(x, y)`` in **pixels**, pixel centres at integers, so
an image covers ``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` (``align_corners=False``). The fluid grid ``(h, w)``
covers the same rectangle whatever the image's resolution.

* The **backward map** ``g_t`` ``(H, W, 2)`` says, for each output pixel of frame ``t``, where in the source
  image to read: frame ``t`` is ``f(g_t(x))``. It is advected semi-Lagrangian at the image's resolution,
  ``g_{t+1}(x) = g_t(x - dt v_t(x))`` (midpoint back-trace), and the image is sampled once per frame from the
  original, so it never blurs from step to step.
* The **forward map** says where each source pixel has gone: its pixel centre carried forward by RK2 through
  the same velocities, like any passive point (:meth:`FluidWarp.advect_points`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from torchfluidwarp._checks import check_int, check_real, check_size, check_tensor
from torchfluidwarp.core.fluid import Viscosity, _advect_points, _backtrace, _extend, _geo, _sample, substeps
from torchfluidwarp.core.grid import FluidGrid, normalized_affine, pixel_to_normalized, rescale_points, scale_factor
from torchfluidwarp.core.linalg import CGConfig
from torchfluidwarp.core.sampling import SampleMode, sample
from torchfluidwarp.core.simulator import FluidRollout, FluidSimulator

__all__ = [
    "FluidWarp",
    "warp_image",
    "identity_map",
    "backward_maps",
    "iter_backward_maps",
    "forward_maps",
    "maps_to_end",
    "jacobian_determinant",
]

ForceSource = Tensor | Callable[..., Tensor]


def identity_map(size: tuple[int, int], *, batch: int = 1, device=None, dtype=torch.float32) -> Tensor:
    """The identity coordinate map ``(B, H, W, 2)``: each pixel's own ``(x, y)``, pixel centres at integers.

    Example:
        >>> identity_map((2, 3))[0, 1, 2].tolist()
        [2.0, 1.0]
    """
    H, W = check_size("size", size)
    ys, xs = torch.meshgrid(
        torch.arange(H, device=device, dtype=dtype), torch.arange(W, device=device, dtype=dtype), indexing="ij"
    )
    return torch.stack([xs, ys], dim=-1).expand(batch, H, W, 2)


def warp_image(image: Tensor, coords: Tensor, mode: SampleMode = "bilinear") -> Tensor:
    """Sample an image through a coordinate map.

    Args:
        image: ``(B, C, H, W)`` source image.
        coords: ``(B, H', W', 2)`` source positions ``(x, y)`` in the source's pixels (pixel centres at
            integers). Positions beyond the image read its edge pixels (border padding).
        mode: ``"bilinear"``, ``"bicubic"`` or ``"nearest"`` (for label masks).

    Returns:
        ``(B, C, H', W')`` the warped image, ``out[b, :, i, j] = image[b, :, coords[b, i, j, 1], coords[b, i, j, 0]]``.

    Raises:
        ValueError: non-finite coordinates, or shapes that do not match.

    Example:
        >>> img = torch.arange(6.0).view(1, 1, 2, 3)
        >>> torch.allclose(warp_image(img, identity_map((2, 3))), img, atol=1e-6)
        True
    """
    check_tensor("image", image, ndim=4)
    check_tensor("coords", coords, shape=[image.shape[0], None, None, 2])
    if mode not in ("bilinear", "bicubic", "nearest"):
        raise ValueError(f"mode must be 'bilinear', 'bicubic' or 'nearest', got {mode!r}")
    return _warp_image(image, coords, mode, check=None)  # coords checked above


def _warp_image(image: Tensor, coords: Tensor, mode: SampleMode, check: str | None = "coords") -> Tensor:
    """:func:`warp_image` without its argument checks, for internal callers.

    The sampling grid is still refused if non-finite (one reduction per call, once per frame), with ``check``
    naming where the coordinates came from; ``check=None`` where they were checked already.
    """
    scale, shift = normalized_affine((image.shape[-2], image.shape[-1]), device=image.device, dtype=image.dtype)
    grid = torch.addcmul(shift.view(1, 1, 1, 2), coords.to(image.dtype), scale.view(1, 1, 1, 2))
    return sample(image, grid, mode=mode, align_corners=False, check=check)


def _cell_scale(size: tuple[int, int], h: int, w: int, like: Tensor) -> Tensor:
    """Cells per pixel of an image of ``size``, ``(1, 2, 1)`` for channel-first points (see :func:`scale_factor`)."""
    return scale_factor(size, (h, w), device=like.device, dtype=like.dtype).view(1, 2, 1)


OVERSAMPLE = 4
"""The maps are composed on a raster of up to this many points per fluid cell and axis, and resized
bilinearly from there to larger images (the fluid makes no finer detail)."""

TRACE_OVERSAMPLE = 3
"""Each step's back-trace is evaluated exactly on a raster of up to this many points per fluid cell and axis
and interpolated bilinearly from there: the displacement of one step is smooth within a cell. On a 600 x 600
image stirred 62 px in 30 steps, the maps stay within 0.2 px of those from a 4-per-cell back-trace, which
costs about 1.8x as much."""


def _displacement(velocity: Tensor, size: tuple[int, int], dt: float) -> Tensor:
    """Back-trace displacement ``x - back(x)`` at every pixel, in pixels: ``(B, 2, H, W)``.

    The midpoint back-trace through the staggered velocity is evaluated exactly at the pixel centres of a
    raster of ``min(H, TRACE_OVERSAMPLE * h) x min(W, TRACE_OVERSAMPLE * w)`` (the image itself when it is
    small) covering the same rectangle, then resized to ``(H, W)`` bilinearly (``align_corners=False``).
    """
    h, w = velocity.shape[-2] - 1, velocity.shape[-1] - 1
    H, W = size
    raster = (min(H, TRACE_OVERSAMPLE * h), min(W, TRACE_OVERSAMPLE * w))
    geo = _geo(h, w, velocity)
    c = _cell_scale(raster, h, w, velocity)
    pix = identity_map(raster, device=velocity.device, dtype=velocity.dtype).reshape(1, -1, 2).transpose(1, 2)
    cells = rescale_points(pix, c).expand(velocity.shape[0], -1, -1)  # (B, 2, N) raster centres in cells
    back = _backtrace(_extend(velocity), cells, dt, geo)
    disp = ((cells - back) / _cell_scale(size, h, w, velocity)).view(-1, 2, *raster)
    if raster == (H, W):
        return disp
    return F.interpolate(disp, size=size, mode="bilinear", align_corners=False)


def _frame_times(T: int, times: Sequence[float] | None) -> list[float]:
    if times is None:
        return [float(t) for t in range(T + 1)]
    out = [float(t) for t in times]
    if any(not (0 <= t <= T) for t in out) or any(b < a for a, b in zip(out, out[1:])):
        raise ValueError(f"times must be non-decreasing and within [0, {T}] (steps), got {out}")
    return out


def _raster(size: tuple[int, int], h: int, w: int) -> tuple[int, int]:
    """The working raster of the maps: the image, or :data:`OVERSAMPLE` points per fluid cell if that is smaller."""
    return (min(size[0], OVERSAMPLE * h), min(size[1], OVERSAMPLE * w))


def _map_composer(
    velocities: Tensor, size: tuple[int, int], dt: float
) -> tuple[Callable[[Tensor, int, float], Tensor], Callable[[Tensor], Tensor], tuple[int, int]]:
    """Map composition on the working raster: ``(compose, to_map, raster)``.

    ``compose(disp, t, duration)`` advances ``disp`` ``(B, 2, Hr, Wr)``, a map minus the identity in raster
    pixels: the result is that map read at ``x - d(x)``, where ``d`` is the midpoint back-trace displacement of
    step ``t``'s velocity over ``duration * dt`` (a negative duration traces forward), in
    :func:`~torchfluidwarp.core.fluid.substeps` sub-steps short enough never to fold. The backward maps
    (``duration > 0``) and the maps to the end (``duration < 0``) share it.

    ``to_map(disp)`` resizes a raster displacement bilinearly to the image and returns the map
    ``(B, H, W, 2)`` in image pixels. The raster (:func:`_raster`) holds every detail the fluid can make, so
    large images cost one resize per map, not a composition at full resolution.
    """
    H, W = size
    B = velocities.shape[0]
    h, w = velocities.shape[-2] - 1, velocities.shape[-1] - 1
    raster = _raster(size, h, w)
    Hr, Wr = raster
    like = velocities
    pix = identity_map(raster, device=like.device, dtype=like.dtype).permute(0, 3, 1, 2).contiguous()  # (1, 2, Hr, Wr)
    lo = torch.tensor([-0.5, -0.5], device=like.device, dtype=like.dtype).view(1, 2, 1, 1)
    hi = torch.tensor([Wr - 0.5, Hr - 0.5], device=like.device, dtype=like.dtype).view(1, 2, 1, 1)
    scale, shift = (a.view(1, 2, 1) for a in normalized_affine(raster, device=like.device, dtype=like.dtype))
    ratio = scale_factor(raster, size, device=like.device, dtype=like.dtype).view(1, 1, 1, 2)  # raster px -> image px
    ident = identity_map(size, device=like.device, dtype=like.dtype)  # (1, H, W, 2)

    def compose(disp: Tensor, t: int, duration: float) -> Tensor:
        n = substeps(velocities[:, t], dt * duration)
        for _ in range(n):
            at = torch.clamp(pix - _displacement(velocities[:, t], raster, dt * duration / n), lo, hi)
            disp = at - pix + _sample(disp, at.view(B, 2, -1), scale, shift, align_corners=False).view(B, 2, Hr, Wr)
        return disp

    def to_map(disp: Tensor) -> Tensor:
        if raster == size:
            return disp.permute(0, 2, 3, 1) + ident
        up = F.interpolate(disp, size=size, mode="bilinear", align_corners=False)
        return torch.addcmul(ident, up.permute(0, 2, 3, 1), ratio)  # one pass, (B, H, W, 2) contiguous

    return compose, to_map, raster


def _iter_displacements(
    velocities: Tensor, size: tuple[int, int], dt: float, times: Sequence[float] | None
) -> tuple[Iterator[Tensor], Callable[[Tensor], Tensor], tuple[int, int]]:
    """The backward maps as raster displacements (see :func:`iter_backward_maps`), and ``to_map`` and the raster."""
    check_tensor("velocities", velocities, ndim=5)
    H, W = check_size("size", size)
    dt = check_real("dt", dt)
    B, T = velocities.shape[:2]
    frame_times = _frame_times(T, times)
    advance, to_map, raster = _map_composer(velocities, (H, W), dt)

    def run() -> Iterator[Tensor]:
        disp = velocities.new_zeros(B, 2, *raster)  # g_t(x) - x at integer step `done`, raster pixels
        done = 0
        for s in frame_times:
            while done + 1 <= s:
                disp = advance(disp, done, 1.0)
                done += 1
            yield disp if s == done else advance(disp, done, s - done)

    return run(), to_map, raster


def iter_backward_maps(
    velocities: Tensor, size: tuple[int, int], dt: float = 1.0, times: Sequence[float] | None = None
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
    """
    displacements, to_map, _ = _iter_displacements(velocities, size, dt, times)
    for disp in displacements:
        yield to_map(disp)


def backward_maps(
    velocities: Tensor, size: tuple[int, int], dt: float = 1.0, times: Sequence[float] | None = None
) -> Tensor:
    """Backward coordinate maps of a roll-out, advected semi-Lagrangian on the maps' working raster.

    The raster is the image itself, or :data:`OVERSAMPLE` points per fluid cell and axis when the image is
    larger; the maps are resized from there to ``size`` bilinearly.

    Args:
        velocities: ``(B, T, 2, h + 1, w + 1)`` staggered velocities (fluid cells per time unit), as returned
            by :class:`~torchfluidwarp.core.simulator.FluidSimulator`.
        size: ``(H, W)`` of the image the maps are for.
        dt: the roll-out's time step.
        times: optional times in steps (default ``0..T``); see :func:`iter_backward_maps`.

    Returns:
        ``(B, len(times), H, W, 2)`` maps in pixels (``T + 1`` by default; map 0 is the identity). Frame ``t``
        is ``warp_image(f, maps[:, t])``.
    """
    return torch.stack(list(iter_backward_maps(velocities, size, dt, times)), dim=1)


def maps_to_end(
    velocities: Tensor, size: tuple[int, int], dt: float = 1.0, times: Sequence[float] | None = None
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
    """
    check_tensor("velocities", velocities, ndim=5)
    H, W = check_size("size", size)
    dt = check_real("dt", dt)
    B, T = velocities.shape[:2]
    times = _frame_times(T, times)
    compose, to_map, raster = _map_composer(velocities, (H, W), dt)

    def pull(disp: Tensor, t: int, fraction: float) -> Tensor:
        return compose(disp, t, -fraction)  # read ahead: trace forward over the step's remaining time

    disp = velocities.new_zeros(B, 2, *raster)  # K_t(z) - z at integer step `done`, raster pixels
    done = T
    out: list[Tensor] = []
    for s in reversed(times):
        while done - 1 >= s:
            disp = pull(disp, done - 1, 1.0)
            done -= 1
        out.append(to_map(disp if s == done else pull(disp, done - 1, done - s)))
    return torch.stack(out[::-1], dim=1)


def forward_maps(velocities: Tensor, size: tuple[int, int], dt: float = 1.0) -> Tensor:
    """Where each source pixel has gone: ``(B, T + 1, H, W, 2)`` pixel positions, carried forward by RK2.

    The forward and backward maps of one roll-out are inverse to each other up to discretisation error
    (see the tests: within 0.1 px away from the walls for smooth flows).
    """
    check_tensor("velocities", velocities, ndim=5)
    H, W = check_size("size", size)
    dt = check_real("dt", dt)
    B, T = velocities.shape[:2]
    pix = identity_map((H, W), batch=B, device=velocities.device, dtype=velocities.dtype).reshape(B, -1, 2)
    return _carry(velocities, pix, (H, W), dt).view(B, T + 1, H, W, 2)


def _carry(velocities: Tensor, points: Tensor, size: tuple[int, int], dt: float) -> Tensor:
    """Carry ``(B, M, 2)`` pixel points through each step: ``(B, T + 1, M, 2)`` pixels."""
    h, w = velocities.shape[-2] - 1, velocities.shape[-1] - 1
    c = _cell_scale(size, h, w, points)
    traj = [rescale_points(points.transpose(1, 2), c)]  # (B, 2, M) cells
    for velocity in velocities.unbind(1):
        traj.append(_advect_points(traj[-1], velocity, dt))
    return rescale_points(torch.stack(traj, dim=1), c.unsqueeze(1), inverse=True).transpose(2, 3)


def jacobian_determinant(coords: Tensor) -> Tensor:
    """Jacobian determinant of a coordinate map, by central differences (one-sided at the edges).

    Args:
        coords: ``(B, H, W, 2)`` map in pixels (backward or forward).

    Returns:
        ``(B, H, W)`` ``det(d coords / d (x, y))``: 1 where area is preserved, ``<= 0`` where the map folds.

    Example:
        >>> jacobian_determinant(2 * identity_map((4, 5))).unique().tolist()
        [4.0]
    """
    check_tensor("coords", coords, ndim=4)
    if coords.shape[-1] != 2 or min(coords.shape[1:3]) < 2:
        raise ValueError(f"coords must have shape (B, H, W, 2) with H, W >= 2, got {tuple(coords.shape)}")
    dx_dy, dx_dx = torch.gradient(coords[..., 0], dim=(1, 2))
    dy_dy, dy_dx = torch.gradient(coords[..., 1], dim=(1, 2))
    return dx_dx * dy_dy - dx_dy * dy_dx


class FluidWarp(nn.Module):
    """A differentiable fluid warp layer.

    Args:
        grid: fluid grid ``(h, w)`` (an int for square); it covers the whole image whatever its size.
        steps: number of fluid steps ``T``; the layer returns ``T + 1`` frames.
        dt: time step (time units).
        viscosity: float, field ``(B|1, 1, h, w)``, or a viscosity module from :mod:`torchfluidwarp.warp.forces`.
        image_size: ``(H, W)`` used by :meth:`advect_points` when no image is at hand (optional).
        compressible: ``True`` skips the pressure projection (the warp may then change areas); a weight in
            ``[0, 1]`` keeps that fraction of the divergent part (see
            :class:`~torchfluidwarp.core.simulator.StableFluidsStep`).
        mode: image sampling, ``"bilinear"`` or ``"bicubic"``.
        pressure, diffusion, adjoint: CG settings (:class:`~torchfluidwarp.core.linalg.CGConfig`).

    Forces are a tensor ``(B|1, T, 2, h, w)`` in fluid cells per time unit^2 (channel 0 = x), or a force
    module from :mod:`torchfluidwarp.warp.forces` called as ``forces(grid, steps, dt, image_size)``.

    Example:
        >>> warp = FluidWarp(grid=(16, 16), steps=4)
        >>> image = torch.rand(2, 3, 40, 50)
        >>> forces = torch.zeros(2, 4, 2, 16, 16); forces[:, :, 0, 6:10, 6:10] = 0.3
        >>> warp(image, forces).shape
        torch.Size([2, 5, 3, 40, 50])
    """

    def __init__(
        self,
        grid: FluidGrid | int | tuple[int, int],
        steps: int,
        dt: float = 1.0,
        viscosity: Viscosity | nn.Module = 0.0,
        *,
        image_size: tuple[int, int] | None = None,
        compressible: bool | float = False,
        mode: SampleMode = "bilinear",
        pressure: CGConfig = CGConfig(),
        diffusion: CGConfig = CGConfig(),
        adjoint: CGConfig | None = None,
    ) -> None:
        super().__init__()
        self.simulator = FluidSimulator(
            grid, dt, viscosity, pressure=pressure, diffusion=diffusion, adjoint=adjoint, compressible=compressible
        )
        self.steps = check_int("steps", steps)
        self.image_size = None if image_size is None else check_size("image_size", image_size)
        if mode not in ("bilinear", "bicubic"):
            raise ValueError(f"mode must be 'bilinear' or 'bicubic', got {mode!r}")
        self.mode: SampleMode = mode

    @property
    def grid(self) -> FluidGrid:
        return self.simulator.grid

    @property
    def dt(self) -> float:
        return self.simulator.dt

    def _size(self, size: tuple[int, int] | None) -> tuple[int, int]:
        if size is not None:
            return check_size("size", size)
        if self.image_size is None:
            raise ValueError("size is needed: pass size=(H, W) or build FluidWarp with image_size=(H, W)")
        return self.image_size

    def resolve_forces(self, forces: ForceSource, image_size: tuple[int, int]) -> Tensor:
        """The force schedule ``(B|1, T, 2, h, w)`` from a tensor or a force module, validated."""
        if not isinstance(forces, Tensor):
            if not callable(forces):
                raise TypeError(
                    f"forces must be a tensor (B, T, 2, h, w) or a force module, got {type(forces).__name__}"
                )
            forces = forces(self.grid, self.steps, self.dt, image_size)
        h, w = self.grid.shape
        return check_tensor("forces", forces, shape=[None, self.steps, 2, h, w])

    def rollout(
        self, forces: ForceSource, size: tuple[int, int] | None = None, points: Tensor | None = None
    ) -> FluidRollout:
        """Run the fluid: velocities ``(B, T, 2, h + 1, w + 1)`` and, given ``points`` in fluid cells, their paths."""
        size = self._size(size)
        return self.simulator(self.resolve_forces(forces, size), points, image_size=size)

    def _velocities(self, forces: ForceSource, size: tuple[int, int], batch: int, name: str) -> Tensor:
        """The roll-out's velocities ``(batch, T, 2, h + 1, w + 1)``: a batch of one is shared."""
        vel = self.rollout(forces, size).velocities
        if vel.shape[0] not in (1, batch):
            raise ValueError(f"forces have batch {vel.shape[0]}, but {name} has batch {batch} (or give forces batch 1)")
        return vel.expand(batch, *vel.shape[1:])

    def forward(self, image: Tensor, forces: ForceSource) -> Tensor:
        """Warp ``image`` ``(B, C, H, W)``: returns the frames ``(B, T + 1, C, H, W)``; frame 0 is the input."""
        check_tensor("image", image, ndim=4)
        size = (image.shape[-2], image.shape[-1])
        vel = self._velocities(forces, size, image.shape[0], "image").to(image.dtype)
        maps = backward_maps(vel, size, self.dt)[:, 1:]  # (B, T, H, W, 2); map 0 is the identity
        B, T = maps.shape[:2]
        rep = image.unsqueeze(1).expand(B, T, *image.shape[1:]).reshape(B * T, *image.shape[1:])
        flat = maps.reshape(B * T, *maps.shape[2:])
        frames = _warp_image(rep, flat, self.mode, check="the backward maps of forces").view(B, T, *image.shape[1:])
        return torch.cat([image.unsqueeze(1), frames], dim=1)

    def iter_frames(self, image: Tensor, forces: ForceSource, *, prefetch: bool = True) -> Iterator[Tensor]:
        """Yield the frames ``(B, C, H, W)`` one at a time (``T + 1`` of them): long animations in little memory.

        The fluid is rolled out first (cheap at fluid resolution); each frame is then resampled on demand, so a
        caller can show progress.

        Args:
            image: ``(B, C, H, W)``.
            forces: as for :meth:`forward`.
            prefetch: build the next frame's sampling grid in a worker thread while this frame is resampled and
                consumed (PyTorch releases the GIL inside its operators, so on two cores the two overlap).
                ``False`` does everything in the calling thread.
        """
        check_tensor("image", image, ndim=4)
        size = (image.shape[-2], image.shape[-1])
        vel = self._velocities(forces, size, image.shape[0], "image").to(image.dtype)
        yield image
        displacements, _, (Hr, Wr) = _iter_displacements(vel, size, self.dt, None)
        # sampling grids straight from the raster: grid = identity + disp * 2 / raster size, normalised
        ident = pixel_to_normalized(identity_map(size, device=vel.device, dtype=vel.dtype), size)
        ratio = normalized_affine((Hr, Wr), device=vel.device, dtype=vel.dtype)[0]  # raster px -> normalised
        grad = torch.is_grad_enabled()  # grad mode is per thread: the worker follows the caller's

        def next_grid() -> Tensor | None:
            with torch.set_grad_enabled(grad):
                disp = next(displacements, None)
                if disp is None:
                    return None
                if (Hr, Wr) != size:
                    disp = F.interpolate(disp, size=size, mode="bilinear", align_corners=False)
                return torch.addcmul(ident, disp.permute(0, 2, 3, 1), ratio)

        # grid_sample reads a channels-last image about 1.5x faster on CPUs, which repays the one copy over
        # a whole animation (not over one call); the frames come back contiguous
        src = image.contiguous(memory_format=torch.channels_last) if image.shape[1] > 1 else image
        next(displacements)  # map 0 is the identity: frame 0 is the input
        with ThreadPoolExecutor(max_workers=1) if prefetch else nullcontext() as pool:
            pending = pool.submit(next_grid) if pool is not None else None
            while True:
                grid = pending.result() if pending is not None else next_grid()
                if grid is None:
                    return
                if pool is not None:
                    pending = pool.submit(next_grid)
                frame = sample(src, grid, mode=self.mode, align_corners=False, check="the backward maps of forces")
                yield frame.contiguous()

    def maps(self, forces: ForceSource, size: tuple[int, int] | None = None) -> Tensor:
        """Backward coordinate maps ``(B, T + 1, H, W, 2)`` in pixels (see :func:`backward_maps`)."""
        size = self._size(size)
        return backward_maps(self.rollout(forces, size).velocities, size, self.dt)

    def forward_maps(self, forces: ForceSource, size: tuple[int, int] | None = None) -> Tensor:
        """Forward maps ``(B, T + 1, H, W, 2)``: where each source pixel has gone (see :func:`forward_maps`)."""
        size = self._size(size)
        return forward_maps(self.rollout(forces, size).velocities, size, self.dt)

    def advect_points(self, points: Tensor, forces: ForceSource, size: tuple[int, int] | None = None) -> Tensor:
        """Carry points ``(B, M, 2)`` (pixels) through the warp: ``(B, T + 1, M, 2)`` pixels."""
        size = self._size(size)
        check_tensor("points", points, shape=[None, None, 2])
        return _carry(self._velocities(forces, size, points.shape[0], "points"), points, size, self.dt)
