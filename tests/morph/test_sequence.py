"""Morphing through several images and averaging them (:mod:`torchfluidwarp.morph.sequence`, issue #23)."""

from __future__ import annotations

import pytest
import torch

from torchfluidwarp.morph import NaturalSettings, average, morph_sequence

KW = dict(settings=NaturalSettings(grid=24, steps=4, max_iter=15), progress=False)
BASE = torch.tensor([[20.0, 20.0], [44.0, 20.0], [32.0, 44.0], [22.0, 40.0]])


def _blobs(points: torch.Tensor, size: int = 64) -> torch.Tensor:
    yy, xx = torch.meshgrid(
        torch.arange(size, dtype=torch.float32), torch.arange(size, dtype=torch.float32), indexing="ij"
    )
    img = torch.zeros(3, size, size)
    for i, (x, y) in enumerate(points.tolist()):
        img[i % 3] += torch.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 18.0)
    return img.clamp(0, 1)


def test_a_sequence_passes_through_every_image_at_one_speed():
    sets = [BASE, BASE + torch.tensor([2.0, 0.0]), BASE + torch.tensor([6.0, 0.0])]  # travels of 2 and 4 pixels
    images = [_blobs(p) for p in sets]
    seq = morph_sequence(images, sets, frames=19, **KW)
    assert len(seq) == 19 and seq.frames.shape == (19, 3, 64, 64)
    torch.testing.assert_close(seq.frame(0.0), images[0])
    torch.testing.assert_close(seq.frame(1.0), images[2])
    joint = seq.counts[0] - 1  # the middle image is shown exactly, once
    torch.testing.assert_close(seq.frames[joint], images[1])
    # the frames are shared out by travel, so the points move as fast before the joint as after it
    speeds = [2.0 / (seq.counts[0] - 1), 4.0 / (seq.counts[1] - 1)]
    assert abs(speeds[1] / speeds[0] - 1) < 0.15, (seq.counts, speeds)  # an even split would give 2.0
    streamed = torch.stack(list(seq.iter_frames(chunk=3)))
    torch.testing.assert_close(streamed, seq.frames)


def test_sequence_arguments_are_checked():
    with pytest.raises(ValueError, match="one point set per image"):
        morph_sequence([_blobs(BASE)] * 3, [BASE] * 2, **KW)
    with pytest.raises(ValueError, match="at least 2 images"):
        morph_sequence([_blobs(BASE)], [BASE], **KW)
    with pytest.raises(TypeError, match="frames"):  # average renders each warp's end only: it takes no frames
        average([_blobs(BASE)] * 2, [BASE, BASE + 1], frames=5, **KW)


def test_the_average_of_two_shifted_images_sits_halfway_without_folds():
    left, right = BASE - torch.tensor([3.0, 0.0]), BASE + torch.tensor([3.0, 0.0])
    result = average([_blobs(left), _blobs(right)], [left, right], **KW)
    torch.testing.assert_close(result.points, BASE, atol=0.05, rtol=0)  # the mean shape
    assert result.folded == 0
    assert float(result.errors.max()) < 0.5  # each image's points reached the mean shape (pixels)
    # both warped images put their blobs on the mean shape, so the average is sharp there: it matches the blobs
    # drawn at the mean shape far better than the plain average of the two inputs does
    want = _blobs(BASE)
    plain = 0.5 * (_blobs(left) + _blobs(right))
    assert float((result.image - want).abs().mean()) < 0.5 * float((plain - want).abs().mean())
