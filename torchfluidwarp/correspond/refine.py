"""Pixels refine sparse points: fit the flow to the images, anchored at the points, and read new points off it.

:func:`refine_points` fits :func:`~torchfluidwarp.control.images.fit_images` from A to B with the given pairs
as anchors (its point term) and an image term (``1 - NCC`` by default, robust to brightness), coarse to fine,
on the images' luminance, then carries a grid of extra points of A through the fitted flow
(:meth:`~torchfluidwarp.warp.layer.FluidWarp.carry_points`). The pairs come back with the extra ones appended:
the points still anchor what they marked, and the pixels place the rest. Any point morph can then use them.

With no pairs to anchor it, the pixels must find the main motion alone: B is first moved back by the plain shift
that best matches A (:func:`~torchfluidwarp.control.alignment.best_shift`), and the flow fits what is left. A
stereo pair's views, 40 px apart, are the case: the fluid's coarse levels would otherwise stop short of the shift.
Only a shift that :func:`~torchfluidwarp.control.images.usable_shift` accepts is used (it keeps most of B in the
frame and removes part of the mismatch itself): between pictures whose content does not correspond, the best
shift only moves B out of the way (a cup against a cat: 64% of B out, 0.77 of the loss; the stereo motorcycle's
views: 6% out, 0.67).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import check_int, check_positive, check_tensor
from torchfluidwarp.control.alignment import best_shift
from torchfluidwarp.control.images import ImageFit, fit_images, usable_shift
from torchfluidwarp.control.losses import LossName, image_loss
from torchfluidwarp.core.grid import rescale_points, scale_factor
from torchfluidwarp.correspond._image import gray, single_image
from torchfluidwarp.warp import identity_map, warp_image

__all__ = ["extra_points", "refine_points"]


def extra_points(size: tuple[int, int], per_side: int, avoid: Tensor, spacing: float) -> Tensor:
    """A ``per_side x per_side`` lattice of points inside the image, less those near the ``avoid`` points.

    Args:
        size: the image's ``(H, W)``.
        per_side: lattice points along each axis, evenly spaced at the centres of ``per_side`` equal bands.
        avoid: ``(M, 2)`` points (pixels); lattice points closer than ``spacing`` to one are left out.
        spacing: that distance, in pixels.

    Returns:
        ``(K, 2)`` pixels ``(x, y)``, pixel centres at integers, ``K <= per_side**2``, with ``avoid``'s dtype.
    """
    H, W = size
    u = (torch.arange(per_side, dtype=torch.float64, device=avoid.device) + 0.5) / per_side
    ys, xs = torch.meshgrid(u * H - 0.5, u * W - 0.5, indexing="ij")
    lattice = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1).to(device=avoid.device, dtype=avoid.dtype)
    if len(avoid):
        lattice = lattice[torch.cdist(lattice, avoid).amin(dim=1) >= spacing]
    return lattice


def refine_points(
    image_a: Tensor,
    image_b: Tensor,
    points_a: Tensor,
    points_b: Tensor,
    *,
    extra: int = 6,
    loss: LossName = "ncc",
    point_weight: float = 1e-2,
    grid: int | tuple[int, int] = (32, 32),
    levels: tuple[int, ...] | None = (16, 32),
    steps: int = 8,
    control: int | tuple[int, int] = (6, 6),
    max_iter: int = 40,
    progress: bool = False,
) -> tuple[Tensor, Tensor, ImageFit]:
    """Add pairs that the pixels place to sparse pairs (from :func:`~torchfluidwarp.correspond.auto.auto_points`, say).

    Args:
        image_a: ``(C, H, W)`` or ``(1, C, H, W)`` float image in ``[0, 1]``.
        image_b: the other image; resized to A's size for the fit (the points come back in B's own pixels).
        points_a: ``(M, 2)`` points of A, pixels.
        points_b: ``(M, 2)`` their partners in B, pixels of B.
        extra: the extra points form an ``extra x extra`` lattice over A, less those within half a lattice
            step of a given point; 0 for none (then only ``fit`` is of use).
        loss: the image term of :func:`~torchfluidwarp.control.images.fit_images` (``"ncc"``, ``"mse"``,
            ``"ssim"``).
        point_weight: the point term's weight (mean squared pixels); the anchors.
        grid, levels, steps, control, max_iter: the fit's fluid grid, coarse-to-fine levels, steps, control
            points and L-BFGS iterations per level, as for ``fit_images``.
        progress: show the fit's progress bars.

    Returns:
        ``(points_a, points_b, fit)``: the given pairs followed by the ``K`` extra ones, ``(M + K, 2)`` each
        (A's dtype and device), and the :class:`~torchfluidwarp.control.images.ImageFit` (compressible,
        float64; its ``min_det > 0`` says the fitted map does not fold). With no pairs given and ``extra > 0``, the
        fit may be from A to B (at A's size) read through the best plain shift ``s`` (``B(x - s)``, see the
        module's docstring): the extra points are then where the fit carries them, less ``s``.

    Raises:
        TypeError / ValueError: as for ``fit_images``, with the argument named.

    Conventions:
        ``(x, y)`` pixels, pixel centres at integers, each image in its own pixels.
    """
    a, b = single_image("image_a", image_a), single_image("image_b", image_b)
    Ha, Wa = a.shape[-2:]
    Hb, Wb = b.shape[-2:]
    pa = check_tensor("points_a", points_a, shape=[None, 2]).to(a.dtype)
    pb = check_tensor("points_b", points_b, shape=[pa.shape[0], 2]).to(a.dtype)
    extra = check_int("extra", extra, minimum=0)
    point_weight = check_positive("point_weight", point_weight)
    to_a = scale_factor((Hb, Wb), (Ha, Wa), device=a.device, dtype=torch.float64)
    b_in_a = F.interpolate(b, size=(Ha, Wa), mode="bilinear", align_corners=False, antialias=True)
    anchors = (pa.double(), rescale_points(pb.double(), to_a))
    source, target = gray(a).double(), gray(b_in_a).double()
    shift = source.new_zeros(2)  # (dx, dy): B is read at x - shift, so the flow fits what the shift leaves
    if extra and not len(pa):  # the pixels alone: B read through its main motion, if it has one
        objective = image_loss(loss)
        found, by_shift = best_shift(source, target, objective)
        if usable_shift(found, by_shift, float(objective(source, target)), (Ha, Wa)):
            shift = found
            ident = identity_map((Ha, Wa), device=a.device, dtype=target.dtype)
            target = warp_image(target, ident - shift)
    fit = fit_images(
        source,
        target,
        loss=loss,
        points=anchors if len(pa) else None,
        point_weight=point_weight,
        grid=grid,
        levels=levels,
        steps=steps,
        control=control,
        max_iter=max_iter,
        compressible=True,
        progress=progress,
    )
    if extra == 0:
        return pa, pb, fit
    step = min(Ha, Wa) / extra
    new_a = extra_points((Ha, Wa), extra, pa.double(), 0.5 * step)
    with torch.no_grad():
        carried = fit.warp.carry_points(new_a[None], fit.forces)[0, -1] - shift  # B at A's size, not moved back
    new_b = rescale_points(carried, to_a, inverse=True)
    out_a = torch.cat([pa, new_a.to(pa.dtype)])
    out_b = torch.cat([pb, new_b.to(pb.dtype)])
    return out_a, out_b, fit
