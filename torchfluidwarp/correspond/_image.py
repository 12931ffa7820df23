"""The one image check of the correspondence finders: one picture, ``(C, H, W)`` or ``(1, C, H, W)``."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from torchfluidwarp._checks import argument_of, check_tensor
from torchfluidwarp.errors import InputError


def single_image(name: str, image: object) -> Tensor:
    """``image`` as ``(1, C, H, W)`` with ``C`` in 1, 3 or 4 (RGBA: alpha is ignored), values in ``[0, 1]``.

    Raises:
        TypeError: not a floating-point tensor.
        ValueError: not one image of 1, 3 or 4 channels, or non-finite values.
    """
    x = check_tensor(name, image, ndim=(3, 4))
    shape = tuple(x.shape)
    if x.ndim == 3:
        x = x.unsqueeze(0)
    if x.shape[0] != 1 or x.shape[1] not in (1, 3, 4):
        raise InputError(
            f"{name} must be one image (C, H, W) or (1, C, H, W) with 1, 3 or 4 channels, got {shape}",
            argument=argument_of(name),
        )
    return x


def gray(image: Tensor) -> Tensor:
    """``(1, 1, H, W)`` luminance (ITU-R 601) of a :func:`single_image`."""
    if image.shape[1] == 1:
        return image
    weights = torch.tensor([0.299, 0.587, 0.114], device=image.device, dtype=image.dtype)
    return torch.einsum("bchw,c->bhw", image[:, :3], weights).unsqueeze(1)


def rgb_uint8(image: Tensor) -> np.ndarray:
    """``(H, W, 3)`` uint8 RGB, C-contiguous, of a :func:`single_image` (gray is repeated, alpha dropped)."""
    rgb = image[0, :3] if image.shape[1] >= 3 else image[0].expand(3, -1, -1)
    array = (rgb.detach().float().clamp(0, 1) * 255).round().to(torch.uint8).permute(1, 2, 0).cpu().numpy()
    return np.ascontiguousarray(array)
