"""Image similarity terms for :func:`~torchfluidwarp.control.images.fit_images` and any other image fit.

Each takes the warped image and the target, ``(B, C, H, W)`` each, values in ``[0, 1]`` unless said
otherwise, and returns a scalar: the per-sample loss summed over the batch, 0 for a perfect match.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import kornia.losses
import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import check_int, check_positive, describe
from torchfluidwarp.errors import InputError, InputTypeError

__all__ = [
    "LossName",
    "ImageLoss",
    "image_loss",
    "mse_loss",
    "ncc_loss",
    "ssim_loss",
    "lncc_loss",
    "local_ncc2",
    "box_mean",
]

LossName = Literal["mse", "ncc", "ssim", "lncc"]
ImageLoss = Callable[[Tensor, Tensor], Tensor]


def mse_loss(warped: Tensor, target: Tensor) -> Tensor:
    """Mean squared error per sample, summed over the batch: ``(B, C, H, W)`` twice -> scalar."""
    return ((warped - target) ** 2).flatten(1).mean(1).sum()


def ncc_loss(warped: Tensor, target: Tensor, eps: float = 1e-8) -> Tensor:
    """``1 - NCC`` per sample (global normalised cross-correlation over all channels and pixels), summed.

    Zero when the images match up to brightness and contrast (``warped = a * target + b`` with ``a > 0``).

    Example:
        >>> x = torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0))
        >>> abs(float(ncc_loss(2 * x + 0.1, x))) < 1e-6
        True
    """
    a = warped.flatten(1) - warped.flatten(1).mean(1, keepdim=True)
    b = target.flatten(1) - target.flatten(1).mean(1, keepdim=True)
    ncc = (a * b).sum(1) / torch.sqrt((a * a).sum(1) * (b * b).sum(1) + eps)
    return (1 - ncc).sum()


def ssim_loss(warped: Tensor, target: Tensor, window_size: int = 11, data_range: float = 1.0) -> Tensor:
    """Structural dissimilarity ``(1 - SSIM) / 2`` per sample (mean over channels and pixels), summed over the batch.

    The SSIM map is kornia's (``kornia.losses.ssim_loss``): a Gaussian window of ``window_size`` pixels
    (sigma 1.5), ``data_range`` the images' dynamic range (1 for images in ``[0, 1]``), reflected borders. Local
    means, contrasts and structure are compared, so it is less swayed than the MSE by a slow change of brightness
    across the image. On images under 6 pixels a side (the coarsest levels of a fit) the window shrinks to the
    largest odd size the border padding allows, ``2 * min(H, W) - 1``.

    Args:
        warped: ``(B, C, H, W)``.
        target: ``(B, C, H, W)``.
        window_size: odd width of the Gaussian window in pixels.
        data_range: the images' dynamic range (``max - min`` of the scale they are on).

    Returns:
        a scalar: 0 for identical images, at most ``B``.

    Example:
        >>> x = torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(0))
        >>> float(ssim_loss(x, x))
        0.0
        >>> float(ssim_loss(x, x.roll(3, -1))) > 0.1
        True
    """
    check_int("window_size", window_size)
    check_positive("data_range", data_range)
    window = min(window_size, 2 * min(warped.shape[-2:]) - 1)
    window -= 1 - window % 2  # odd
    dssim = kornia.losses.ssim_loss(warped, target, window, max_val=data_range, reduction="none")  # (B, C, H, W)
    return dssim.flatten(1).mean(1).sum()


def _along(x: Tensor, dim: int, r: int) -> Tensor:
    """The mean over ``2 r + 1`` neighbours along ``dim`` (``-1`` or ``-2``) of those inside the raster."""
    n = x.shape[dim]
    pad = (r + 1, r, 0, 0) if dim == -1 else (0, 0, r + 1, r)
    running = F.pad(x, pad).cumsum(dim)
    sums = running.narrow(dim, 2 * r + 1, n) - running.narrow(dim, 0, n)
    i = torch.arange(n, device=x.device, dtype=x.dtype)
    count = (i + r).clamp(max=n - 1) - (i - r).clamp(min=0) + 1  # the neighbours inside the raster
    return sums / (count if dim == -1 else count.unsqueeze(-1))


def box_mean(x: Tensor, window: int) -> Tensor:
    """The mean of ``x`` ``(B, C, h, w)`` over the ``window x window`` pixels (odd) centred on each pixel, of those
    inside the raster at its edges, ``(B, C, h, w)``: ``avg_pool2d(x, window, stride=1, padding=window // 2,
    count_include_pad=False)`` to round-off, by running sums (``cumsum`` along each axis), so that neither its cost
    nor its backward's grows with the window (``avg_pool2d``'s backward was half of an alignment step's time).
    Round-off: about ``eps * w * max|x - mean x|`` (x is centred first), a few ``1e-6`` in float32 at 512 pixels."""
    r = window // 2
    centre = x.mean((-2, -1), keepdim=True)
    return _along(_along(x - centre, -1, r), -2, r) + centre


def local_ncc2(x: Tensor, y: Tensor, window: int, eps: float = 1e-4) -> Tensor:
    """The squared normalised cross-correlation of ``x`` and ``y`` ``(B, 1, h, w)`` over ``window x window``
    pixels around each pixel, ``(B, 1, h, w)`` in ``[0, 1]``; ``eps`` (intensity^2) keeps flat windows at 0."""
    mx, my, xx, yy, xy = box_mean(torch.cat([x, y, x * x, y * y, x * y], 1), window).split(x.shape[1], 1)
    vx = (xx - mx * mx).clamp(min=0)
    vy = (yy - my * my).clamp(min=0)
    cov = xy - mx * my
    return cov.square() / ((vx + eps) * (vy + eps))


LNCC_WINDOW = 9
""":func:`lncc_loss`'s window, pixels a side, at every level of a coarse-to-fine fit (VoxelMorph's and ANTs' usual
size; Liao et al.'s halfway morph uses 5-9)."""


def lncc_loss(warped: Tensor, target: Tensor, window: int = LNCC_WINDOW) -> Tensor:
    """``1 - NCC_w^2`` per sample: one minus the squared local normalised cross-correlation over ``window x window``
    pixels around each pixel (:func:`local_ncc2`), averaged over the pixels, summed over the batch.

    The images are compared by their channels' mean (grey), window by window, so a change of brightness, contrast
    or even contrast sign between them, slow across the picture, does not matter; a flat window counts as a
    mismatch that no motion improves (no gradient). Windows keep their size in pixels at every level of a
    coarse-to-fine fit, so the coarse levels compare large structures and the fine levels small ones.

    Args:
        warped: ``(B, C, H, W)``.
        target: ``(B, C, H, W)``.
        window: odd width of the window in pixels (shrunk to the image's shorter side on tiny images).

    Returns:
        a scalar in ``[0, B]``: about 0 where every textured window matches.

    Example:
        >>> x = torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(0))
        >>> float(lncc_loss(1 - 2 * x, x)) < 0.01
        True
        >>> float(lncc_loss(x.roll(3, -1), x)) > 0.5
        True
    """
    check_int("window", window)
    if window % 2 == 0:
        raise InputError(f"window must be odd, got {window}", argument="window")
    side = min(warped.shape[-2:])
    window = min(window, side - 1 + side % 2)
    ncc2 = local_ncc2(warped.mean(1, keepdim=True), target.mean(1, keepdim=True), window)
    return (1 - ncc2).flatten(1).mean(1).sum()


def image_loss(loss: LossName | ImageLoss) -> ImageLoss:
    """The image term for a name (``"mse"``, ``"ncc"``, ``"ssim"``, ``"lncc"``) or a callable
    ``loss(warped, target) -> scalar``."""
    if callable(loss):
        return loss
    if loss == "mse":
        return mse_loss
    if loss == "ncc":
        return ncc_loss
    if loss == "ssim":
        return ssim_loss
    if loss == "lncc":
        return lncc_loss
    kind = InputError if isinstance(loss, str) else InputTypeError
    raise kind(
        f"loss must be 'mse', 'ncc', 'ssim', 'lncc' or a callable (warped, target) -> scalar, got {describe(loss)}",
        argument="loss",
    )
