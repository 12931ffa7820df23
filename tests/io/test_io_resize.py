import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.io import resize_image, shrink_image
from torchfluidwarp.io.images import premultiplied, straight


def _image(h=40, w=30, dtype=torch.float64):
    return torch.rand(1, 3, h, w, generator=torch.Generator().manual_seed(0), dtype=dtype)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("size", [(20, 15), (13, 29), (64, 48)])
def test_resize_is_torchs_antialiased_bilinear(dtype, size):
    image = _image(dtype=dtype)
    expected = F.interpolate(image, size=size, mode="bilinear", align_corners=False, antialias=True)
    out = resize_image(image, size)
    assert out.dtype == dtype
    torch.testing.assert_close(out, expected, rtol=0, atol=0)
    assert out.amin() >= image.amin() - 1e-6 and out.amax() <= image.amax() + 1e-6


def test_resize_to_the_same_size_returns_the_image():
    image = _image()
    assert resize_image(image, (40, 30)) is image


def test_a_checkerboard_averages_to_gray_at_a_mild_factor():
    # the reason for torch's filter over kornia's Gaussian pre-blur (docs/design.rst): no aliasing at 512 -> 320
    yy, xx = torch.meshgrid(torch.arange(64), torch.arange(64), indexing="ij")
    board = ((xx + yy) % 2).double()[None, None]
    assert resize_image(board, (40, 40)).std() < 0.01


@pytest.mark.parametrize(
    "shape, longest, expected",
    [((300, 200), 150, (150, 100)), ((200, 300), 150, (100, 150)), ((1000, 3), 100, (100, 2))],
)
def test_shrink_keeps_the_aspect_ratio(shape, longest, expected):
    out = shrink_image(torch.rand(1, 3, *shape, generator=torch.Generator().manual_seed(1)), longest)
    assert tuple(out.shape[-2:]) == expected
    assert out.amin() >= 0 and out.amax() <= 1


@pytest.mark.parametrize("longest", [0, 40, 100])
def test_shrink_keeps_an_image_small_enough_already(longest):
    image = _image()
    assert shrink_image(image, longest) is image


def test_shrink_names_a_bad_longest():
    with pytest.raises(ValueError, match="longest"):
        shrink_image(_image(), -1)
    with pytest.raises(TypeError, match="image"):
        resize_image([[0.0]], (2, 2))


def test_premultiplied_and_straight_are_inverse_where_there_is_alpha() -> None:
    g = torch.Generator().manual_seed(0)
    image = torch.rand(1, 4, 8, 8, generator=g)
    image[:, 3, 0, 0] = 0.0
    back = straight(premultiplied(image))
    torch.testing.assert_close(back[:, :, 1:], image[:, :, 1:])
    assert float(back[0, :3, 0, 0].abs().max()) == 0.0  # no alpha: no colour to recover
    rgb = torch.rand(1, 3, 8, 8, generator=g)
    assert premultiplied(rgb) is rgb and straight(rgb) is rgb


def test_four_channels_are_resized_like_any_others_whatever_the_last_holds():
    # resize_image knows nothing of alpha: a 4-channel feature map, its last channel zero or negative, is resized
    # channel by channel (a picture with alpha is premultiplied by its caller, as the morph does)
    g = torch.Generator().manual_seed(1)
    data = torch.randn(1, 4, 9, 7, generator=g) * 5
    data[:, 3] = 0.0
    out = resize_image(data, (4, 3))
    want = F.interpolate(data, size=(4, 3), mode="bilinear", align_corners=False, antialias=True)
    torch.testing.assert_close(out, want)


def test_grey_with_alpha_is_premultiplied_too():
    image = torch.tensor([[[[0.8, 0.2]], [[0.5, 0.0]]]])  # (1, 2, 1, 2): grey, then alpha
    torch.testing.assert_close(premultiplied(image), torch.tensor([[[[0.4, 0.0]], [[0.5, 0.0]]]]))
    torch.testing.assert_close(straight(premultiplied(image)), torch.tensor([[[[0.8, 0.0]], [[0.5, 0.0]]]]))
    tiny = torch.tensor([0.5, 0.5, 0.5, 1e-40]).view(1, 4, 1, 1)  # alpha below float32's smallest normal
    back = straight(premultiplied(tiny))[0, :3, 0, 0]  # divided by alpha itself, not a clamp (it gave 0.004)
    torch.testing.assert_close(back, torch.full((3,), 0.5), atol=0.02, rtol=0)
