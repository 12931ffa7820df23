"""The differentiable fluid warp layer: forces in, frames out.

:class:`FluidWarp` rolls the fluid out over a force schedule (:class:`~torchfluidwarp.core.simulator.FluidSimulator`)
and reads the image through the roll-out's texture-coordinate maps (:mod:`torchfluidwarp.warp.maps`).
Conventions: images ``(B, C, H, W)``; points ``(x, y)`` in pixels, pixel centres at integers (see
:mod:`torchfluidwarp.core.grid`).
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Iterator
from contextlib import closing

import torch
from torch import Tensor, nn

from torchfluidwarp._checks import all_finite, check_int, check_memory, check_picture, check_size, check_tensor
from torchfluidwarp.core.fluid import Viscosity
from torchfluidwarp.core.grid import FluidGrid, normalized_affine, pixel_to_normalized
from torchfluidwarp.core.linalg import CGConfig
from torchfluidwarp.core.sampling import SampleMode, sample
from torchfluidwarp.core.simulator import FluidRollout, FluidSimulator
from torchfluidwarp.errors import InputError, InputTypeError
from torchfluidwarp.warp.frames import identity_map
from torchfluidwarp.warp.maps import MapConfig, _iter_displacements, backward_maps, forward_maps, upsample_raster

__all__ = ["FluidWarp"]

ForceSource = Tensor | Callable[..., Tensor]


def check_image(image: object) -> Tensor:
    """Validate an image ``(B, C, H, W)`` to warp, with ``B, H, W >= 1``."""
    x = check_picture("image", image, ndim=4, features=True)
    if min(x.shape[0], *x.shape[-2:]) < 1:
        raise InputError(f"image must have B, H and W >= 1, got shape {tuple(x.shape)}")
    return x


class FluidWarp(nn.Module):
    """A differentiable fluid warp layer.

    Args:
        grid: fluid grid ``(h, w)`` (an int for square); it covers the whole image whatever its size.
        steps: number of fluid steps ``T``; the layer returns ``T + 1`` frames.
        dt: time step (time units).
        viscosity: float, field ``(B|1, 1, h, w)``, or a viscosity module from :mod:`torchfluidwarp.warp.forces`.
        image_size: ``(H, W)`` used by :meth:`maps` and :meth:`carry_points` when no image is at hand (optional).
        compressible: ``True`` skips the pressure projection (the warp may then change areas); a weight in
            ``[0, 1]`` keeps that fraction of the divergent part (see
            :class:`~torchfluidwarp.core.simulator.StableFluidsStep`).
        mode: image sampling, ``"bilinear"`` or ``"bicubic"``.
        pressure, diffusion, adjoint: CG settings (:class:`~torchfluidwarp.core.linalg.CGConfig`).
        map_config: how finely the maps are composed, and the sub-steps' strain for maps and points
            (:class:`~torchfluidwarp.warp.maps.MapConfig`; its defaults when ``None``).
        cuda_graphs: replay the fluid step from a CUDA graph that this layer's simulator captures once and keeps
            (no-grad roll-outs on a GPU; see :class:`~torchfluidwarp.core.simulator.FluidSimulator`).

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
        map_config: MapConfig | None = None,
        cuda_graphs: bool = False,
    ) -> None:
        super().__init__()
        self.simulator = FluidSimulator(
            grid,
            dt,
            viscosity,
            pressure=pressure,
            diffusion=diffusion,
            adjoint=adjoint,
            compressible=compressible,
            cuda_graphs=cuda_graphs,
        )
        self.steps = check_int("steps", steps)
        self.image_size = None if image_size is None else check_size("image_size", image_size)
        if mode not in ("bilinear", "bicubic"):
            raise InputError(f"mode must be 'bilinear' or 'bicubic', got {mode!r}")
        self.mode: SampleMode = mode
        if not isinstance(map_config, (MapConfig, type(None))):
            raise InputTypeError(f"map_config must be a MapConfig or None, got {type(map_config).__name__}")
        self.map_config = MapConfig() if map_config is None else map_config

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
            raise InputError("size is needed: pass size=(H, W) or build FluidWarp with image_size=(H, W)")
        return self.image_size

    def resolve_forces(self, forces: ForceSource, image_size: tuple[int, int]) -> Tensor:
        """The force schedule ``(B|1, T, 2, h, w)`` from a tensor or a force module, validated.

        A roll-out whose forces and velocities (some 8 tensors of ``T x 2 x (h + 1) x (w + 1)`` float32 per sample)
        would exceed ``map_config.max_memory`` is refused before a force module is even called.
        """
        h, w = self.grid.shape
        nbytes = 8 * self.steps * 2 * (h + 1) * (w + 1) * 4
        what = f"a roll-out of steps={self.steps} on the grid of {h} x {w} cells"
        check_memory(what, nbytes, self.map_config.max_memory, "MapConfig(max_memory=...)")
        if not isinstance(forces, Tensor):
            if not callable(forces):
                raise InputTypeError(
                    f"forces must be a tensor (B, T, 2, h, w) or a force module, got {type(forces).__name__}"
                )
            forces = forces(self.grid, self.steps, self.dt, image_size)
        check_tensor("forces", forces, finite=False)
        if forces.ndim != 5 or tuple(forces.shape[1:]) != (self.steps, 2, h, w):
            raise InputError(
                f"forces must have shape (*, {self.steps}, 2, {h}, {w}) for steps={self.steps} on the grid of "
                f"{h} x {w} cells, got {tuple(forces.shape)}"
            )
        return check_tensor("forces", forces)

    def rollout(
        self, forces: ForceSource, size: tuple[int, int] | None = None, points: Tensor | None = None
    ) -> FluidRollout:
        """Run the fluid: velocities ``(B, T, 2, h + 1, w + 1)`` and, given ``points`` in fluid cells, their paths."""
        size = self._size(size)
        return self.simulator(self.resolve_forces(forces, size), points, image_size=size)

    def _velocities(
        self, forces: ForceSource, size: tuple[int, int], batch: int, name: str, dtype: torch.dtype | None = None
    ) -> Tensor:
        """The roll-out's velocities ``(batch, T, 2, h + 1, w + 1)`` (in ``dtype`` if given): a batch of one is
        shared. Velocities that overflowed (in the roll-out, or on the way to ``dtype``) are refused by name."""
        vel = self.rollout(forces, size).velocities
        if vel.shape[0] not in (1, batch):
            raise InputError(f"forces have batch {vel.shape[0]}, but {name} has batch {batch} (or give forces batch 1)")
        vel = vel if dtype is None else vel.to(dtype)
        if not all_finite(vel):
            raise InputError(
                f"the flow of these forces overflowed {vel.dtype} (non-finite velocities, dt {self.dt!r}): "
                "use smaller forces or dt, or a wider dtype"
            )
        return vel.expand(batch, *vel.shape[1:])

    def forward(self, image: Tensor, forces: ForceSource) -> Tensor:
        """Warp ``image`` ``(B, C, H, W)``: returns the frames ``(B, T + 1, C, H, W)``; frame 0 is the input.

        The frames come from the same machinery as :meth:`iter_frames` (one resampling of ``image`` per frame);
        without grad they are written straight into the output, so the only large allocation is the output itself.
        """
        check_image(image)
        size = (image.shape[-2], image.shape[-1])
        vel = self._velocities(forces, size, image.shape[0], "image", image.dtype)
        if torch.is_grad_enabled() and (image.requires_grad or vel.requires_grad):
            return torch.stack([image, *self._resampled(image, vel)], dim=1)  # autograd keeps each frame
        # zeroing maps the output's fresh pages in on all of torch's threads at once, where the frame copies below
        # would fault them in one frame at a time: 0.93x of the 600 x 600 job (docs/benchmarks.md, issue #30)
        out = image.new_zeros(image.shape[0], self.steps + 1, *image.shape[1:])
        out[:, 0] = image
        for t, frame in enumerate(self._resampled(image, vel), start=1):
            out[:, t] = frame
        return out

    def iter_frames(self, image: Tensor, forces: ForceSource) -> Iterator[Tensor]:
        """Yield the frames ``(B, C, H, W)`` one at a time (``T + 1`` of them): long animations in little memory.

        The fluid is rolled out first (cheap at fluid resolution); each frame is then resampled on demand, so a
        caller can show progress.

        Args:
            image: ``(B, C, H, W)``.
            forces: as for :meth:`forward`.
        """
        check_image(image)
        size = (image.shape[-2], image.shape[-1])
        vel = self._velocities(forces, size, image.shape[0], "image", image.dtype)
        yield image
        with closing(self._resampled(image, vel)) as frames:
            for frame in frames:
                yield frame.contiguous()

    def _resampled(self, image: Tensor, vel: Tensor) -> Generator[Tensor, None, None]:
        """Frames 1 to ``T`` of ``image`` through the backward maps of ``vel``, one ``grid_sample`` each.

        The sampling grids are built straight from the maps' raster (identity + upsampled displacement, in
        normalised coordinates, one pass). A frame may come back channels-last.
        """
        size = (image.shape[-2], image.shape[-1])
        displacements, _, (Hr, Wr) = _iter_displacements(vel, size, self.dt, None, self.map_config)
        # built channels-first, (B, 2, H, W), and handed to grid_sample as a permuted view: a contiguous pass
        # instead of a strided one (grid_sample reads either; the grid's values are the same)
        ident = pixel_to_normalized(identity_map(size, device=vel.device, dtype=vel.dtype), size)
        ident = ident.permute(0, 3, 1, 2).contiguous()
        ratio = normalized_affine((Hr, Wr), device=vel.device, dtype=vel.dtype)[0].view(1, 2, 1, 1)  # raster px
        # without autograd (which keeps each grid for the backward) every frame's grid goes into one buffer: new
        # memory costs about 1 ms per MB to touch on some machines, 2.5 ms of a 600 x 600 frame's grid
        keep = torch.is_grad_enabled() and (image.requires_grad or vel.requires_grad)
        buffer = None if keep else ident.new_empty(vel.shape[0], 2, *size)
        next(displacements)  # map 0 is the identity: frame 0 is the input
        for disp in displacements:
            grid = torch.addcmul(ident, upsample_raster(disp, size), ratio, out=buffer).permute(0, 2, 3, 1)
            # the image is read in the layout it came in: no layout wins on every CPU (docs/benchmarks.md, #30)
            yield sample(image, grid, mode=self.mode, align_corners=False, check="the backward maps of forces")

    def maps(self, forces: ForceSource, size: tuple[int, int] | None = None) -> Tensor:
        """Backward coordinate maps ``(B, T + 1, H, W, 2)`` in pixels (see :func:`backward_maps`)."""
        size = self._size(size)
        return self._backward_maps(self.rollout(forces, size).velocities, size)

    def _backward_maps(self, velocities: Tensor, size: tuple[int, int]) -> Tensor:
        return backward_maps(velocities, size, self.dt, config=self.map_config)

    def forward_maps(self, forces: ForceSource, size: tuple[int, int] | None = None) -> Tensor:
        """Forward maps ``(B, T + 1, H, W, 2)``: where each source pixel has gone (see :func:`forward_maps`)."""
        size = self._size(size)
        return forward_maps(self.rollout(forces, size).velocities, size, self.dt, config=self.map_config)

    def carry_points(self, points: Tensor, forces: ForceSource, size: tuple[int, int] | None = None) -> Tensor:
        """Carry points through the whole roll-out, step by step: their trajectories.

        Each point moves like a particle of the fluid, by RK2 through each step's velocity (the one-step function
        is :func:`torchfluidwarp.core.advection.advect_points`), so it lands where the warped frames show its pixel.

        Args:
            points: ``(B|1, M, 2)`` ``(x, y)`` in pixels of an image of ``size``.
            forces: as for :meth:`forward`.
            size: ``(H, W)``; ``image_size`` of the layer by default.

        Returns:
            ``(B, T + 1, M, 2)`` pixels; entry 0 is ``points``.
        """
        size = self._size(size)
        check_tensor("points", points, shape=[None, None, 2])
        velocities = self._velocities(forces, size, points.shape[0], "points")
        config = self.map_config
        return self.simulator.layout.trajectories(
            velocities, points, self.dt, size, config.max_strain, config.max_substeps
        )
