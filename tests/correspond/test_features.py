"""Feature matching against known maps: B(y) = A(phi(y)), so a match (a, b) is right when a = phi(b)."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
import torch

from torchfluidwarp.correspond import match_features
from torchfluidwarp.correspond.features import consistent_matches, thin_matches
from torchfluidwarp.data import load_sample
from torchfluidwarp.warp.frames import identity_map, warp_image

SIZE = 512


def similarity(y: torch.Tensor) -> torch.Tensor:
    """Rotate by 8 degrees and scale by 1.1 about the centre, then shift by (6, -4) pixels."""
    c, t = (SIZE - 1) / 2, math.radians(8.0)
    rotation = torch.tensor([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]], dtype=y.dtype)
    return c + 1.1 * (y - c) @ rotation.T + torch.tensor([6.0, -4.0], dtype=y.dtype)


def smooth(y: torch.Tensor) -> torch.Tensor:
    """A smooth non-rigid map: sine displacements of 8 pixels' amplitude."""
    u = y / (SIZE - 1) * 2 * math.pi
    dx = 8.0 * torch.sin(u[..., 1]) * torch.cos(0.5 * u[..., 0])
    dy = 8.0 * torch.sin(u[..., 0]) * torch.cos(0.5 * u[..., 1])
    return y + torch.stack([dx, dy], -1)


MAPS: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "similarity": similarity,
    "smooth": smooth,
    "similarity+smooth": lambda y: smooth(similarity(y)),
}


@pytest.fixture(scope="module")
def astronaut() -> torch.Tensor:
    return load_sample("astronaut")


@pytest.mark.parametrize("name", sorted(MAPS))
def test_matches_agree_with_a_known_map(astronaut: torch.Tensor, name: str):
    phi = MAPS[name]
    a = astronaut.double()
    b = warp_image(a, phi(identity_map((SIZE, SIZE), dtype=torch.float64))).float()
    pa, pb = match_features(astronaut, b, max_points=64, cells=10)
    # the map was not used to match, so every match is held out; measured: median 0.4 to 0.6 px, 90th
    # percentile 1.2 to 1.5 px, worst 2.7 to 5.4 px over 64 matches
    error = (phi(pb.double()) - pa.double()).norm(dim=-1)
    assert len(pa) >= 20
    assert float(error.median()) < 1.5
    assert float(error.quantile(0.9)) < 3.0
    assert float((error > 8.0).float().mean()) <= 0.05
    # spread: one match per cell of a 10 x 10 grid over A
    cells = (pa * 10 / SIZE).floor().clamp(0, 9).long()
    assert len(set(map(tuple, cells.tolist()))) == len(pa)


def test_a_crop_of_different_size_matches_at_its_offset_and_the_result_repeats(astronaut: torch.Tensor):
    b = astronaut[..., 8:, 4:]  # b = a - (4, 8)
    pa, pb = match_features(astronaut, b, max_points=30)
    assert 20 <= len(pa) <= 30 and pa.dtype == pb.dtype == astronaut.dtype
    assert float((pa - pb - torch.tensor([4.0, 8.0])).norm(dim=-1).median()) < 0.5
    again = match_features(astronaut, b, max_points=30)
    assert torch.equal(again[0], pa) and torch.equal(again[1], pb)


def test_a_blank_image_has_no_matches(astronaut: torch.Tensor):
    pa, pb = match_features(astronaut, torch.full((3, 64, 64), 0.5))
    assert pa.shape == pb.shape == (0, 2)


def test_thin_matches_keeps_the_best_of_each_cell():
    points = torch.tensor([[1.0, 1.0], [2.0, 2.0], [60.0, 1.0], [61.0, 2.0], [1.0, 60.0]])
    scores = torch.tensor([0.5, 0.2, 0.1, 0.3, 0.9])
    keep = thin_matches(points, scores, (100, 100), cells=2)  # 50-pixel cells
    assert keep.tolist() == [2, 1, 4]  # best first, one per cell


def test_the_consistency_check_drops_the_match_that_moves_unlike_its_neighbours(gen: torch.Generator):
    a = torch.rand(40, 2, generator=gen) * 100
    b = a + torch.tensor([3.0, -2.0]) + 0.01 * a  # a smooth motion
    b[7] += torch.tensor([15.0, 0.0])  # one wrong match
    keep = consistent_matches(a, b, neighbours=8, tolerance=3.0)
    assert keep.tolist() == [i != 7 for i in range(40)]


def test_bad_arguments_are_named(astronaut: torch.Tensor):
    with pytest.raises(ValueError, match=r"ratio must be in \(0, 1\], got 1.5"):
        match_features(astronaut, astronaut, ratio=1.5)
    with pytest.raises(ValueError, match="model must be"):
        match_features(astronaut, astronaut, model="projective")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="image_b must have 3 or 4 dimensions"):
        match_features(astronaut, torch.zeros(8, 8))
    with pytest.raises(ValueError, match="max_points"):
        match_features(astronaut, astronaut, max_points=0)
