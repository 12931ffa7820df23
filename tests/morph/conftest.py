"""Fixtures shared by the morph's tests."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture
def shuffled_marks() -> tuple[torch.Tensor, torch.Tensor]:
    """12 marks ``(12, 2)`` float64 pixels in a 64 x 64 picture, and the same marks in a shuffled order: a
    similarity explains 7% of the shuffled set's spread, an affine 12% (no common pose)."""
    pa = torch.tensor(
        [
            [8, 21],
            [46, 15],
            [45, 38],
            [16, 29],
            [27, 46],
            [16, 37],
            [29, 24],
            [56, 11],
            [12, 34],
            [55, 13],
            [40, 34],
            [9, 20],
        ],
        dtype=torch.float64,
    )
    return pa, pa[torch.tensor([7, 3, 10, 0, 11, 5, 1, 9, 2, 6, 4, 8])]
