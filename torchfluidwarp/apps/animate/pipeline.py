"""The one animation pipeline: a configuration and a photo in, frames out, one at a time.

``torchfluidwarp animate`` and the studio's animate preview and export both call :func:`animate_frames`; it
builds the library's modules (:class:`~torchfluidwarp.warp.forces.Brushes`, a viscosity from
:class:`~torchfluidwarp.warp.forces.ViscosityBrushes` and :func:`~torchfluidwarp.warp.forces.viscosity_from_mask`,
:class:`~torchfluidwarp.warp.layer.FluidWarp`) and streams :meth:`~torchfluidwarp.warp.layer.FluidWarp.iter_frames`.
Resizing goes through :func:`~torchfluidwarp.io.images.shrink_image`, and moving the configuration's positions to
the resized image through :func:`~torchfluidwarp.core.grid.scale_factor`.

Example:
    >>> from torchfluidwarp.apps.animate.config import parse_config
    >>> cfg = parse_config({"brushes": [{"position": [20, 30], "direction": [0, 1], "radius": 8,
    ...                                  "frequency": 0.05, "amplitude": 0.5}], "steps": 4, "grid": 16})
    >>> frames = list(animate_frames(cfg, torch.rand(1, 3, 48, 48)))
    >>> len(frames), frames[0].shape
    (5, torch.Size([3, 48, 48]))
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import torch
from torch import Tensor

from torchfluidwarp._checks import check_int, check_tensor, warn
from torchfluidwarp.apps.animate.config import AnimationConfig, BrushSpec, RegionSpec
from torchfluidwarp.core.grid import FluidGrid, scale_factor
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import read_image, shrink_image
from torchfluidwarp.warp.forces import Brushes, ViscosityBrushes, viscosity_from_mask
from torchfluidwarp.warp.layer import FluidWarp

__all__ = ["DEFAULT_GRID", "animate_frames", "auto_grid", "build_forces", "build_viscosity"]

DEFAULT_GRID = 64
"""Fluid cells along the image's longer side when no grid is given."""


def animate_frames(config: AnimationConfig, image: Tensor, *, max_size: int = 0) -> Iterator[Tensor]:
    """Animate ``image`` as ``config`` says: the ``config.steps + 1`` frames, streamed one at a time.

    Everything is checked and built before this returns (a bad mask or no brush raises here, not at the first
    frame); the fluid then runs, and each frame is resampled from the photo when the caller asks for it, so a
    caller can show progress or encode frames as they come. Gradients are not tracked.

    Args:
        config: the animation, its positions and radii in pixels of ``image``.
        image: ``(1, C, H, W)`` photo in ``[0, 1]``.
        max_size: downscale the photo first so its longer side is at most this many pixels (0 keeps its size);
            the configuration's positions, radii and amplitudes move with it, and a viscosity mask keeps the
            original's size.

    Returns:
        An iterator over ``config.steps + 1`` frames ``(C, H', W')`` (``H', W'`` after ``max_size``), with the
        image's dtype and device; the first frame is the (resized) photo.

    Raises:
        ValueError: no brushes, a non-finite image, a mask that cannot be read or has the wrong size.
    """
    check_tensor("image", image, shape=(1, None, None, None))
    check_int("max_size", max_size, minimum=0)
    original = (image.shape[-2], image.shape[-1])
    _warn_outside(config, original)
    small = shrink_image(image, max_size)
    size = (small.shape[-2], small.shape[-1])
    sx, sy = scale_factor(original, size, dtype=torch.float64).tolist()
    scaled = config.rescaled(sx, sy)
    grid = scaled.grid or auto_grid(size)
    viscosity = build_viscosity(scaled, grid, size, mask_size=original)
    forces = build_forces(scaled).to(image.device)
    warp = FluidWarp(grid, scaled.steps, scaled.dt, viscosity).to(image.device)
    return _stream(warp.iter_frames(small, forces))


def _warn_outside(config: AnimationConfig, size: tuple[int, int]) -> None:
    """Warn of each brush and viscosity region of ``config`` that lies wholly outside a picture of ``size``
    ``(H, W)`` (its centre more than 3 radii beyond the picture's edge, where its Gaussian is about 1 % of its
    peak): it changes nothing, as when its position was given in another picture's pixels or as fractions."""
    H, W = size
    placed: list[tuple[str, Sequence[BrushSpec | RegionSpec]]] = [
        ("brush", config.brushes),
        ("viscosity region", config.viscosity.regions),
    ]
    for kind, items in placed:
        for i, item in enumerate(items):
            x, y = item.position
            beyond = max(-0.5 - x, x - (W - 0.5), -0.5 - y, y - (H - 0.5), 0.0)
            if beyond > OUTSIDE_RADII * item.radius:
                warn(
                    f"{kind} {i} at ({x:g}, {y:g}), radius {item.radius:g} px, lies outside the {W} x {H} picture "
                    f"(width x height): it changes nothing; positions are the picture's pixels (x, y)",
                    RuntimeWarning,
                )


OUTSIDE_RADII = 3.0
"""A brush or a viscosity region whose centre lies more than this many radii beyond the picture's edge reaches it at
about 1 % of its peak at most (a Gaussian at 3 sigma): :func:`animate_frames` says it changes nothing."""


def _stream(frames: Iterator[Tensor]) -> Iterator[Tensor]:
    # no_grad around each step only: a `with` around the `yield` would switch gradients off in the caller too
    while True:
        with torch.no_grad():
            frame = next(frames, None)
        if frame is None:
            return
        yield frame[0]


def auto_grid(image_size: tuple[int, int], cells: int = DEFAULT_GRID) -> tuple[int, int]:
    """A fluid grid with ``cells`` along the image's longer side and about square cells.

    Example:
        >>> auto_grid((300, 600))
        (32, 64)
    """
    H, W = image_size
    scale = cells / max(H, W)
    return (max(2, round(H * scale)), max(2, round(W * scale)))


def build_forces(config: AnimationConfig) -> Brushes:
    """The configuration's brushes as one :class:`~torchfluidwarp.warp.forces.Brushes` module.

    Example:
        >>> from torchfluidwarp.apps.animate.config import BrushSpec
        >>> brush = BrushSpec(position=(20.0, 30.0), direction=(0.0, 1.0), radius=8.0, amplitude=0.5)
        >>> build_forces(AnimationConfig(brushes=(brush,)))(FluidGrid(16, 16), 10, 1.0, (48, 48)).shape
        torch.Size([1, 10, 2, 16, 16])

    Raises:
        ValueError: the configuration has no brushes.
    """
    if not config.brushes:
        raise InputError("nothing to animate: give at least one brush")
    b = config.brushes
    return Brushes(
        centers=[p.position for p in b],
        directions=[p.direction for p in b],
        radius=[p.radius for p in b],
        amplitude=[p.amplitude for p in b],
        frequency=[p.frequency for p in b],
        phase=[p.phase for p in b],
    )


def build_viscosity(
    config: AnimationConfig,
    grid: tuple[int, int],
    image_size: tuple[int, int],
    mask_size: tuple[int, int] | None = None,
) -> float | Tensor:
    """The viscosity: a float when it is uniform, else a field ``(1, 1, h, w)`` in cells^2 per time unit.

    Args:
        config: the animation settings, its positions in pixels of an image of size ``image_size``.
        grid: the fluid grid ``(h, w)``.
        image_size: ``(H, W)`` of the image being animated.
        mask_size: the size a mask image must have (the original image's, before any resizing);
            ``image_size`` by default.

    Raises:
        ValueError: the mask cannot be read or its size differs from ``mask_size``.
    """
    spec = config.viscosity
    field: float | Tensor = spec.base
    if spec.regions:
        r = spec.regions
        module = ViscosityBrushes(
            centers=[p.position for p in r], radius=[p.radius for p in r], value=[p.value for p in r], base=spec.base
        )
        with torch.no_grad():
            field = module(FluidGrid.of(grid), image_size).detach()
    if spec.mask is not None:
        try:
            mask = read_image(spec.mask, channels=1)
        except InputError as exc:
            raise InputError(f"viscosity.mask: {exc}") from None
        want = mask_size or image_size
        if tuple(mask.shape[-2:]) != tuple(want):
            raise InputError(
                f"viscosity.mask {str(spec.mask)!r} is {mask.shape[-1]}x{mask.shape[-2]} pixels, "
                f"but the image is {want[1]}x{want[0]}"
            )
        field = field + viscosity_from_mask(mask, grid, stiff=spec.stiff, soft=spec.soft)
    return field
