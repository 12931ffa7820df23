"""Transparency and formats (#23): an RGBA morph written as PNG frames, a transparent GIF and an animated WebP."""

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from PIL import Image, ImageSequence

from torchfluidwarp.io import encode_animation, read_image, write_animation
from torchfluidwarp.io.animation import MAX_WEBP_BYTES
from torchfluidwarp.morph import NaturalSettings, morph

FAST = dict(settings=NaturalSettings(grid=12, steps=3, max_iter=5), progress=False)


def read_webp(path):
    """All frames of an animated WebP, ``(T, H, W, C)`` uint8 (imageio's reader gives only the first)."""
    with Image.open(path) as im:
        return np.stack([np.asarray(frame.copy()) for frame in ImageSequence.Iterator(im)])


@pytest.fixture(scope="module")
def rgba_morph():
    """An RGBA morph whose alpha is opaque in a disc and transparent around it, and its frames as uint8."""
    gen = torch.Generator().manual_seed(5)
    H, W = 32, 40
    ys, xs = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    disc = (((xs - 20.0) ** 2 + (ys - 16.0) ** 2) < 100).float()
    a = torch.cat([torch.rand(3, H, W, generator=gen), disc[None]])
    b = torch.cat([torch.rand(3, H, W, generator=gen), disc[None]])
    pa = torch.tensor([[14.0, 10.0], [26.0, 11.0], [20.0, 22.0]])
    pb = torch.tensor([[15.0, 11.0], [25.0, 10.0], [21.0, 21.0]])
    result = morph(a, b, pa, pb, frames=4, **FAST)
    frames = result.frames
    expect = frames.double().clamp(0, 1).mul(255).round().to(torch.uint8).permute(0, 2, 3, 1).numpy()  # as the writer
    return frames, expect


def test_png_frames_keep_rgba_exactly(tmp_path, rgba_morph):
    frames, expect = rgba_morph
    assert frames.shape[1] == 4
    out = write_animation(tmp_path / "frames/", frames)
    got = np.stack([iio.imread(p) for p in sorted(out.iterdir())])
    assert got.shape == expect.shape and np.array_equal(got, expect)
    back = read_image(sorted(out.iterdir())[0])
    assert back.shape[1] == 4 and torch.equal(back[0, 3], frames[0, 3].mul(255).round().div(255))


def test_gif_is_transparent_where_alpha_is_below_half(tmp_path, rgba_morph):
    frames, expect = rgba_morph
    out = write_animation(tmp_path / "m.gif", frames, fps=10)
    got = iio.imread(out, index=None, mode="RGBA")
    assert got.shape == expect.shape
    alpha = expect[..., 3]
    assert np.array_equal(got[..., 3] == 0, alpha < 128)  # each frame its own: nothing shows through
    assert np.all(got[..., 3][alpha >= 128] == 255)
    opaque = alpha >= 128
    colour_error = np.abs(got[..., :3].astype(int) - expect[..., :3].astype(int))[opaque]
    # a transparent GIF shares one fixed palette over all frames (a 6 x 7 x 6 colour cube, dithered) so that it
    # reads back as one array (test_morph_pictures.py): on uniform noise the nearest of its levels is off by up to
    # half a step (25.5 of 255 in red and blue, 21.25 in green), a quarter step (about 12) on the median
    assert np.median(colour_error) <= 13  # was 8 with a palette per frame, which imageio cannot stack (#31)
    assert np.array_equal(iio.imread(out, index=None)[..., :3], got[..., :3])  # every frame in one mode
    assert encode_animation(frames, "gif") == out.read_bytes()


def test_opaque_frames_make_an_opaque_gif(tmp_path):
    frames = torch.rand(2, 4, 8, 8, generator=torch.Generator().manual_seed(0))
    frames[:, 3] = 1.0
    got = iio.imread(write_animation(tmp_path / "o.gif", frames), index=None, mode="RGBA")
    assert np.all(got[..., 3] == 255)


def test_webp_keeps_alpha_within_tolerance(tmp_path, rgba_morph):
    frames, expect = rgba_morph
    out = write_animation(tmp_path / "m.webp", iter(frames.unbind(0)), fps=8)
    got = read_webp(out)
    assert got.shape == expect.shape
    assert np.abs(got[..., 3].astype(int) - expect[..., 3].astype(int)).max() <= 2  # lossless alpha
    opaque = expect[..., 3] == 255
    colour_error = np.abs(got[..., :3].astype(int) - expect[..., :3].astype(int))[opaque]
    assert colour_error.mean() < 40  # lossy colour at quality 90, on random noise
    assert encode_animation(frames, "webp")[8:12] == b"WEBP"


def test_webp_refuses_more_frames_than_it_may_hold_and_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr("torchfluidwarp.io.animation.MAX_WEBP_BYTES", 3 * 8 * 8 * 4)
    assert MAX_WEBP_BYTES == 2**30
    with pytest.raises(ValueError, match="WebP holds its frames in memory"):
        write_animation(tmp_path / "big.webp", torch.rand(4, 3, 8, 8))
    assert list(tmp_path.iterdir()) == []
    write_animation(tmp_path / "ok.webp", torch.rand(3, 3, 8, 8))
    assert read_webp(tmp_path / "ok.webp").shape == (3, 8, 8, 3)
