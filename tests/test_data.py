"""Tests for the bundled samples in torchfluidwarp.data."""

from __future__ import annotations

import pytest
import torch

from torchfluidwarp.data import POINT_LABELS, SAMPLES, load_sample, load_sample_points, sample_path
from torchfluidwarp.io import check_point_counts


@pytest.mark.parametrize("name", SAMPLES)
def test_sample_loads_with_points_inside(name):
    image = load_sample(name)
    assert image.shape == (1, 3, 512, 512) and image.dtype == torch.float32
    assert 0.0 <= image.min() and image.max() <= 1.0 and image.std() > 0.1
    points = load_sample_points(name)
    assert points.shape == (len(POINT_LABELS), 2)
    h, w = image.shape[-2:]
    assert bool(((points >= 0) & (points <= torch.tensor([w - 1, h - 1]))).all())


def test_sample_points_correspond():
    # Same count, and the same left/right and top/bottom layout of the key landmarks.
    a, b = load_sample_points("astronaut"), load_sample_points("cat")
    check_point_counts(a, b, "astronaut", "cat")
    for pts in (a, b):
        assert pts[1, 0] < pts[6, 0] < pts[4, 0]  # left eye, nose bridge, right eye
        assert pts[10, 0] < pts[11, 0] < pts[12, 0]  # mouth corners around the upper lip
        assert pts[20, 1] < pts[17, 1] < pts[6, 1] < pts[7, 1] < pts[11, 1] < pts[13, 1] < pts[14, 1]


def test_channels_and_paths():
    assert load_sample("cat", channels=1).shape == (1, 1, 512, 512)
    assert sample_path("astronaut").name == "astronaut.png" and sample_path("astronaut").is_file()
    assert sample_path("cat", "points").read_text().startswith("version: 1\nn_points: 23\n{")


def test_unknown_sample_lists_names():
    with pytest.raises(ValueError, match="unknown sample 'dog'; available samples: astronaut, cat"):
        load_sample("dog")
    with pytest.raises(ValueError, match="kind"):
        sample_path("cat", "mask")  # type: ignore[arg-type]
