"""Memory of the file boundary: an image decodes to one float32 copy, and a streamed animation lets each frame go
before it asks for the next (#31, item 8: a 6000 x 6000 pair morphs within 3 GB)."""

from __future__ import annotations

import tracemalloc
import weakref

import numpy as np
import pytest
import torch
from PIL import Image

from torchfluidwarp.io import read_image, write_animation


def traced_peak(fn):
    """``fn()`` and the peak of the memory Python and numpy allocated meanwhile (numpy reports its arrays to
    tracemalloc; a float64 or second float copy of the pixels would show here)."""
    tracemalloc.start()
    try:
        out = fn()
        return out, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize(
    "mode, suffix, bound",
    [
        # the 8-bit pixels (3 bytes) and the float32 result (12 bytes): 1.25x the result
        ("RGB", ".png", 1.3),
        # float pixels: the decoded float32 and the result, 2x; float64 on the way would be at least 4x
        ("F", ".tif", 2.5),
    ],
)
def test_an_image_decodes_to_one_float32_copy(tmp_path, mode, suffix, bound):
    rng = np.random.default_rng(0)
    shape = (1500, 2000)
    if mode == "RGB":
        pixels = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
    else:
        pixels = rng.random(shape, dtype=np.float32) * 1.2 - 0.1  # beyond [0, 1] both ways: clipped
    path = tmp_path / f"big{suffix}"
    Image.fromarray(pixels, mode).save(path)
    image, peak = traced_peak(lambda: read_image(path))
    assert image.dtype == torch.float32 and image.shape == (1, 3 if mode == "RGB" else 1, *shape)
    assert peak < bound * image.numel() * image.element_size(), f"{peak / image.nbytes:.2f}x the result"
    expected = pixels / 255.0 if mode == "RGB" else pixels.clip(0, 1)
    got = image[0].permute(1, 2, 0).numpy() if mode == "RGB" else image[0, 0].numpy()
    np.testing.assert_allclose(got, expected, atol=1e-6)


class Frames:
    """Frames made on demand that keep only a weak reference to the last one: asking for frame ``k`` while frame
    ``k - 1`` is still held by the writer fails (a streamed morph renders frame ``k`` then)."""

    def __init__(self, n: int, channels: int = 3) -> None:
        self.n, self.channels, self.made = n, channels, 0
        self.last: weakref.ref[torch.Tensor] | None = None

    def __iter__(self) -> Frames:
        return self

    def __next__(self) -> torch.Tensor:
        if self.last is not None:
            assert self.last() is None, f"frame {self.made - 1} is still held when frame {self.made} is asked for"
        if self.made == self.n:
            raise StopIteration
        frame = torch.full((self.channels, 16, 18), self.made / self.n)
        self.last = weakref.ref(frame)
        self.made += 1
        return frame


@pytest.mark.parametrize("name, channels", [("a.gif", 3), ("t.gif", 4), ("a.mp4", 3), ("frames/", 1), ("a.webp", 4)])
def test_a_streamed_animation_lets_each_frame_go(tmp_path, name, channels):
    frames = Frames(4, channels)
    write_animation(tmp_path / name, frames)
    assert frames.made == 4
