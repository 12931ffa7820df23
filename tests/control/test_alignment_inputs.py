"""estimate_alignment names the point set it cannot align (#19)."""

from __future__ import annotations

import pytest
import torch

from torchfluidwarp.control import estimate_alignment


@pytest.mark.parametrize("points", [torch.zeros(0, 2), torch.full((4, 2), 3.0)])
def test_a_similarity_needs_distinct_points_in_points_a(points):
    with pytest.raises(ValueError, match="2 distinct points in points_a"):
        estimate_alignment(points, points + 1.0)
