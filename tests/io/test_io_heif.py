"""HEIC/HEIF photographs (an iPhone's default format), read with the optional pillow-heif (torchfluidwarp.io)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from torchfluidwarp.io import read_image, read_image_bytes

pillow_heif = pytest.importorskip("pillow_heif")


def _photo(gen: torch.Generator, h: int = 24, w: int = 40) -> np.ndarray:
    """A smooth colour picture ``(h, w, 3)`` uint8 (HEVC is lossy: smooth content comes back within a few levels)."""
    y, x = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    phase = torch.rand(3, generator=gen) * 6
    rgb = torch.stack([0.5 + 0.4 * torch.sin(3 * x + 2 * y + p) for p in phase], -1)
    return (rgb * 255).round().to(torch.uint8).numpy()


def _save(path, pictures: list[np.ndarray], **kwargs) -> None:
    heif = pillow_heif.from_pillow(Image.fromarray(pictures[0]))
    for extra in pictures[1:]:
        heif.add_from_pillow(Image.fromarray(extra))
    heif.save(path, quality=95, **kwargs)


def test_a_heic_photograph_reads_as_its_pixels(tmp_path, gen):
    stored = _photo(gen)
    _save(tmp_path / "photo.heic", [stored])
    image = read_image(tmp_path / "photo.heic")
    assert image.shape == (1, 3, 24, 40)  # H and W as stored, not swapped
    error = (image[0].permute(1, 2, 0) - torch.from_numpy(stored) / 255).abs()
    assert float(error.mean()) < 3 / 255
    other = torch.from_numpy(_photo(torch.Generator().manual_seed(1))) / 255  # a different picture is far off
    assert float((image[0].permute(1, 2, 0) - other).abs().mean()) > 10 / 255
    # the same bytes without a name: told apart by their "ftyp" brand
    torch.testing.assert_close(read_image_bytes((tmp_path / "photo.heic").read_bytes()), image, atol=0, rtol=0)


def test_a_heic_of_several_pictures_gives_its_primary_and_says_how_many(tmp_path, gen):
    first, second = _photo(gen), _photo(gen)
    _save(tmp_path / "burst.heic", [first, second])
    with pytest.warns(UserWarning, match=r"burst\.heic' holds 2 frames"):
        image = read_image(tmp_path / "burst.heic")
    error = [float((image[0].permute(1, 2, 0) - torch.from_numpy(p) / 255).abs().mean()) for p in (first, second)]
    assert error[0] < 3 / 255 < error[1]


def test_a_heic_larger_than_max_pixels_is_refused_from_its_header(tmp_path, gen):
    _save(tmp_path / "photo.heic", [_photo(gen)])
    with pytest.raises(ValueError, match=r"40 x 24 = 960 pixels, more than max_pixels=959"):
        read_image(tmp_path / "photo.heic", max_pixels=959)
