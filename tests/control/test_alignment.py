import math

import pytest
import torch

from torchfluidwarp.control.alignment import apply_alignment, estimate_alignment, interpolate_alignment


def _similarity(scale, angle, tx, ty):
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[scale * c, -scale * s, tx], [scale * s, scale * c, ty], [0, 0, 1]], dtype=torch.float64)


@pytest.mark.parametrize("kind", ["similarity", "affine"])
def test_recovers_a_known_transform(kind, gen):
    a = torch.rand(10, 2, generator=gen, dtype=torch.float64) * 100
    m = _similarity(1.7, 0.4, 12.0, -5.0)
    if kind == "affine":
        m[0, 1] += 0.3
    b = apply_alignment(m, a)
    torch.testing.assert_close(estimate_alignment(a, b, kind), m)


def test_interpolation_ends_and_centre_path():
    m = _similarity(2.0, 0.8, 30.0, 10.0)
    c = torch.tensor([5.0, 7.0], dtype=torch.float64)
    torch.testing.assert_close(interpolate_alignment(m, 0.0, c), torch.eye(3, dtype=torch.float64))
    torch.testing.assert_close(interpolate_alignment(m, 1.0, c), m)
    half = interpolate_alignment(m, 0.5, c)
    torch.testing.assert_close(apply_alignment(half, c), 0.5 * (c + apply_alignment(m, c)))
    # the scale of a similarity interpolates geometrically
    assert math.isclose(float(torch.linalg.det(half[:2, :2])) ** 0.5, math.sqrt(2.0), rel_tol=1e-9)


def test_bad_inputs():
    with pytest.raises(ValueError, match="points_a has 3 points but points_b has 2"):
        estimate_alignment(torch.zeros(3, 2), torch.zeros(2, 2))
    with pytest.raises(ValueError, match="at least 3 points"):
        estimate_alignment(torch.zeros(2, 2), torch.zeros(2, 2), "affine")
    with pytest.raises(ValueError, match="kind must be"):
        estimate_alignment(torch.rand(3, 2), torch.rand(3, 2), "perspective")
