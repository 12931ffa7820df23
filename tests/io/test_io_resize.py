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


def test_rgba_is_resized_premultiplied_so_a_hidden_colour_does_not_bleed() -> None:
    # left half transparent over a hidden red, right half opaque blue: halving the size mixes the two across
    # the edge; the mixed pixels are blue at part alpha, never reddish
    image = torch.zeros(1, 4, 8, 8)
    image[:, 0, :, :4] = 1.0
    image[:, 2, :, 4:] = 1.0
    image[:, 3, :, 4:] = 1.0
    small = resize_image(image, (4, 3))  # an odd width: a column straddles the edge
    assert float(small[0, 0].abs().max()) < 1e-6
    seen = small[0, 3] > 0
    torch.testing.assert_close(small[0, 2][seen], torch.ones_like(small[0, 2][seen]))
    assert bool(((small[0, 3] > 0) & (small[0, 3] < 1)).any())  # the edge column is part transparent
