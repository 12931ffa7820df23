"""Image similarity terms for :func:`~torchfluidwarp.control.images.fit_images` and any other image fit.

Each takes the warped image and the target, ``(B, C, H, W)`` each, values in ``[0, 1]`` unless said
otherwise, and returns a scalar: the per-sample loss summed over the batch, 0 for a perfect match.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import kornia.losses
import torch
from torch import Tensor

from torchfluidwarp._checks import check_int, check_positive, describe
from torchfluidwarp.errors import InputError, InputTypeError

__all__ = ["LossName", "ImageLoss", "image_loss", "mse_loss", "ncc_loss", "ssim_loss"]

LossName = Literal["mse", "ncc", "ssim"]
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


def image_loss(loss: LossName | ImageLoss) -> ImageLoss:
    """The image term for a name (``"mse"``, ``"ncc"``, ``"ssim"``) or a callable ``loss(warped, target) -> scalar``."""
    if callable(loss):
        return loss
    if loss == "mse":
        return mse_loss
    if loss == "ncc":
        return ncc_loss
    if loss == "ssim":
        return ssim_loss
    kind = InputError if isinstance(loss, str) else InputTypeError
    raise kind(
        f"loss must be 'mse', 'ncc', 'ssim' or a callable (warped, target) -> scalar, got {describe(loss)}",
        argument="loss",
    )
