"""Image similarity terms: local statistics by running sums, and the local cross-correlation loss."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.control.losses import box_mean, image_loss, lncc_loss, local_ncc2
from torchfluidwarp.errors import InputError


def test_local_ncc2_ignores_gain_offset_and_sign() -> None:
    x = torch.rand(1, 1, 32, 32, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    y = x.roll(1, -1)
    base = local_ncc2(x, y, 5, eps=0)
    assert torch.allclose(local_ncc2(x, 3 - 2 * y, 5, eps=0), base, atol=1e-9)
    assert torch.allclose(local_ncc2(x, x, 5, eps=0)[..., 3:-3, 3:-3], torch.ones(1, 1, 26, 26, dtype=torch.float64))


@pytest.mark.parametrize("window", [1, 3, 7, 9])
@pytest.mark.parametrize("shape", [(1, 1, 16, 16), (2, 3, 9, 23), (1, 2, 30, 5)])
def test_box_mean_is_the_window_mean_of_the_pixels_inside(window, shape) -> None:
    x = torch.rand(shape, generator=torch.Generator().manual_seed(window), dtype=torch.float64) * 5 - 1
    expected = F.avg_pool2d(x, window, stride=1, padding=window // 2, count_include_pad=False)
    assert torch.allclose(box_mean(x, window), expected, atol=1e-12)
    # and its gradient is avg_pool2d's
    w = torch.rand(shape, generator=torch.Generator().manual_seed(7), dtype=torch.float64)
    x.requires_grad_(True)
    (g_box,) = torch.autograd.grad((box_mean(x, window) * w).sum(), x)
    (g_pool,) = torch.autograd.grad((F.avg_pool2d(x, window, 1, window // 2, count_include_pad=False) * w).sum(), x)
    assert torch.allclose(g_box, g_pool, atol=1e-12)


def _texture(size: int = 48, seed: int = 0) -> torch.Tensor:
    """``(1, 1, size, size)`` float64: smooth random texture in ``[0, 1]``."""
    x = torch.rand(1, 1, size // 4, size // 4, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))
    return F.interpolate(x, size=(size, size), mode="bicubic", align_corners=False).clamp(0, 1)


def test_lncc_loss_ignores_gain_offset_and_sign_and_sees_a_shift() -> None:
    x = _texture()
    same = float(lncc_loss(x, x))
    assert same < 0.01  # not 0: eps (1e-4 intensity^2) weighs on the windows of least contrast
    assert abs(float(lncc_loss(0.2 + 0.5 * x, x)) - same) < 0.02  # halving the contrast halves it against eps
    assert abs(float(lncc_loss(1 - x, x)) - same) < 1e-9
    # a shift by 2 pixels costs far more than any change of tone
    assert float(lncc_loss(x.roll(2, -1), x)) > 0.5
    # colour channels are compared by their mean, batches summed
    rgb = x.expand(2, 3, -1, -1)
    assert torch.allclose(lncc_loss(rgb, rgb.flip(0)), 2 * lncc_loss(x, x), atol=1e-9)
    assert image_loss("lncc") is lncc_loss


def test_lncc_loss_gradient_matches_finite_differences() -> None:
    x = _texture(24, seed=3).requires_grad_(True)
    y = _texture(24, seed=4)
    assert torch.autograd.gradcheck(lambda z: lncc_loss(z, y, window=5), (x,), eps=1e-6, atol=1e-6)


def test_lncc_loss_window_on_tiny_images_and_even_windows() -> None:
    x = _texture(8)[..., :3, :]  # 3 x 8: the window shrinks to 3
    assert torch.isfinite(lncc_loss(x, x.flip(-1)))
    with pytest.raises(InputError, match="window must be odd") as caught:
        lncc_loss(x, x, window=4)
    assert caught.value.argument == "window"
