"""Reading an image through a coordinate map, and checking a map: the identity, ``warp_image`` and the Jacobian
determinant.

Maps are ``(B, H, W, 2)`` in pixels, ``(x, y)``, pixel centres at integers (:mod:`torchfluidwarp.core.grid`);
images ``(B, C, H, W)``. :mod:`~torchfluidwarp.warp.maps` builds the maps that the fluid carries.
"""

from __future__ import annotations

import torch
from torch import Tensor

from torchfluidwarp._checks import all_finite, check_picture, check_size, check_tensor
from torchfluidwarp.core.grid import normalized_affine
from torchfluidwarp.core.sampling import SampleMode, sample
from torchfluidwarp.errors import InputError

__all__ = ["identity_map", "warp_image", "sample_map", "jacobian_determinant"]


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
    check_picture("image", image, ndim=4, features=True)
    check_tensor("coords", coords, shape=[None, None, None, 2])
    if image.shape[0] != coords.shape[0] or min(image.shape[-2:]) < 1:
        raise InputError(f"image {tuple(image.shape)} must be non-empty with the batch of coords {tuple(coords.shape)}")
    if mode not in ("bilinear", "bicubic", "nearest"):
        raise InputError(f"mode must be 'bilinear', 'bicubic' or 'nearest', got {mode!r}")
    return sample_map(image, coords, mode, check=None)  # coords checked above


def sample_map(image: Tensor, coords: Tensor, mode: SampleMode = "bilinear", check: str | None = "coords") -> Tensor:
    """:func:`warp_image` without its shape checks, for callers that built ``image`` and ``coords`` themselves
    (the renderer, once per frame).

    Args:
        image: ``(B, C, H, W)``.
        coords: ``(B, H', W', 2)`` source positions in ``image``'s pixels.
        mode: ``"bilinear"``, ``"bicubic"`` or ``"nearest"``.
        check: the name under which non-finite ``coords`` are refused (one reduction per call); ``None`` where
            they were checked already.

    Returns:
        ``(B, C, H', W')``.
    """
    scale, shift = normalized_affine((image.shape[-2], image.shape[-1]), device=image.device, dtype=image.dtype)
    grid = torch.addcmul(shift.view(1, 1, 1, 2), coords.to(image.dtype), scale.view(1, 1, 1, 2))
    return sample(image, grid, mode=mode, align_corners=False, check=check)


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
        raise InputError(f"coords must have shape (B, H, W, 2) with H, W >= 2, got {tuple(coords.shape)}")
    dx_dy, dx_dx = torch.gradient(coords[..., 0], dim=(1, 2))
    dy_dy, dy_dx = torch.gradient(coords[..., 1], dim=(1, 2))
    det = dx_dx * dy_dy - dx_dy * dy_dx
    if det.numel() and not all_finite(det):  # finite coordinates whose products overflow the dtype
        raise InputError(f"coords are too large for {coords.dtype}: their Jacobian determinant overflows")
    return det
