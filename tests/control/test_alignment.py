import math

import pytest
import torch

from torchfluidwarp.control.alignment import (
    apply_alignment,
    estimate_alignment,
    interpolate_alignment,
    robust_alignment,
)


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


@pytest.mark.parametrize("kind", ["similarity", "affine"])
@pytest.mark.parametrize("noise, n", [(0.0, 40), (0.5, 40), (0.5, 80)])  # 80: 3,160 pairs, more than are tried
def test_a_robust_pose_is_not_dragged_by_pairs_far_off(kind, noise, n, gen):
    a = torch.rand(n, 2, generator=gen, dtype=torch.float64) * 400
    m = _similarity(0.8, 0.5, -20.0, 35.0)
    if kind == "affine":
        m[0, 1] += 0.2
    b = apply_alignment(m, a) + noise * torch.randn(n, 2, generator=gen, dtype=torch.float64)
    far = torch.tensor([3, 11, 12, 25, 30, 38])  # 15% of the pairs, thrown 150-600 px off
    b[far] += torch.rand(6, 2, generator=gen, dtype=torch.float64) * 450 + 150
    least_squares = estimate_alignment(a, b, kind)
    robust, inliers = robust_alignment(a, b, kind)
    flagged = set((~inliers).nonzero()[:, 0].tolist())
    assert flagged >= set(far.tolist()) and len(flagged - set(far.tolist())) <= (0 if noise == 0 else 2)
    err = (apply_alignment(robust, a) - apply_alignment(m, a)).norm(dim=-1).max()
    err_ls = (apply_alignment(least_squares, a) - apply_alignment(m, a)).norm(dim=-1).max()
    assert float(err) < 1e-6 + 2 * noise and float(err_ls) > 40, (float(err), float(err_ls))
    again, _ = robust_alignment(a, b, kind)
    torch.testing.assert_close(again, robust, atol=0, rtol=0)  # no randomness from call to call


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_robust_pose_keeps_every_pair_when_none_is_far_off(dtype, gen):
    # few pairs with a little noise: each candidate is judged by the pairs it was not made from, so the two it
    # passes through exactly do not shrink the scale to nothing
    a = torch.tensor([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [0.0, 10.0], [10.0, 10.0], [20.0, 10.0]], dtype=dtype)
    noise = torch.tensor([[0.2, 0], [0, -0.1], [-0.1, 0.2], [0.1, 0.1], [0, 0.1], [-0.2, 0]], dtype=dtype)
    assert bool(robust_alignment(a, a + 3 + noise)[1].all())
    assert bool(robust_alignment(a[:4], a[:4] + 3 + noise[:4])[1].all())  # 4 pairs: too few to judge any
    flagged = 0
    for _ in range(20):  # pure similarities in float32 rounding, and Gaussian noise of 1 px on 12 pairs
        p = torch.rand(12, 2, generator=gen, dtype=torch.float64) * 400
        q = apply_alignment(_similarity(0.9, 0.2, 7.0, -4.0), p)
        assert bool(robust_alignment(p.to(dtype), q.to(dtype))[1].all())
        flagged += int((~robust_alignment(p, q + torch.randn(12, 2, generator=gen, dtype=torch.float64))[1]).sum())
    assert flagged <= 6  # of 240 pairs: about 1 % lie beyond INLIER standard deviations by chance


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
