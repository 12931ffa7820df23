import sys

import pytest
import torch

from torchfluidwarp.morph import morph
from torchfluidwarp.warp import jacobian_determinant, warp_image


def _blobs(size, centers, gen):
    H, W = size
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32), indexing="ij")
    img = 0.1 * torch.rand(3, H, W, generator=gen)
    for k, (x, y) in enumerate(centers):
        img[k % 3] += torch.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * 3.0**2))
    return img.clamp(0, 1)


POINTS_A = torch.tensor([[20.0, 22.0], [44.0, 20.0], [32.0, 40.0], [22.0, 46.0], [44.0, 44.0]])
POINTS_B = POINTS_A + torch.tensor([[2.0, 1.0], [-1.0, 2.0], [1.5, -1.5], [-2.0, 0.0], [0.0, 2.0]])
KW = dict(grid=24, steps=6, control=(5, 5), progress=False, max_iter=60)


@pytest.fixture
def pair(gen):
    return _blobs((64, 64), POINTS_A.tolist(), gen), _blobs((64, 64), POINTS_B.tolist(), gen)


@pytest.mark.parametrize("inverse", ["flow", "paper"])
def test_first_and_last_frames_are_the_inputs(pair, inverse):
    a, b = pair
    r = morph(a, b, POINTS_A, POINTS_B, frames=7, inverse=inverse, **KW)
    assert r.frames.shape == (7, 3, 64, 64)
    torch.testing.assert_close(r.frames[0], a, atol=1e-5, rtol=0)
    torch.testing.assert_close(r.frames[-1], b, atol=1e-5, rtol=0)
    # the fitted points reach B's points, and the warp never folds
    assert r.fit.error.mean() < 0.3
    assert jacobian_determinant(r.maps).min() > 0 and r.folded == 0


def test_identical_images_and_points_give_a_constant_morph(pair):
    a, _ = pair
    r = morph(a, a, POINTS_A, POINTS_A, frames=5, **KW)
    for k in range(5):
        torch.testing.assert_close(r.frames[k], a, atol=1e-5, rtol=0)


def test_flow_inverse_agrees_with_the_forward_warp(pair):
    a, b = pair
    r = morph(a, b, POINTS_A, POINTS_B, frames=5, align=None, margin=None, **KW)
    # a pixel x of B's frame read at frame k: maps_b[k](y) = K(y); composing A's backward map g_k and K
    # sends A's points to where the fit carried them
    traj = r.fit.trajectories[0]  # (T + 1, M, 2), frame coordinates
    last = r.maps_b[0]  # frame 0: where B is read for each pixel of A's frame
    at = warp_image(last.permute(2, 0, 1)[None].double(), POINTS_A[None, None].double())[0, :, 0].T  # (M, 2)
    inner = ((POINTS_A > 8) & (POINTS_A < 56)).all(-1)
    assert (at - traj[-1])[inner].norm(dim=-1).max() < 0.1


def test_different_sizes_and_alignment(gen):
    a = _blobs((64, 64), POINTS_A.tolist(), gen)
    b_points = POINTS_B * 2 + 0.5  # B at twice the size: pixel centres scale as (x + 0.5) * 2 - 0.5
    b = torch.nn.functional.interpolate(
        _blobs((64, 64), POINTS_B.tolist(), gen)[None], size=(128, 128), mode="bilinear", align_corners=False
    )[0]
    r = morph(a, b, POINTS_A, b_points, frames=4, **KW)
    assert r.frames.shape == (4, 3, 64, 64)
    assert r.fit.error.mean() < 0.3


def test_bad_inputs(pair):
    a, b = pair
    with pytest.raises(ValueError, match="points_a has 5 points but points_b has 4"):
        morph(a, b, POINTS_A, POINTS_B[:4], **KW)
    with pytest.raises(ValueError, match="frames must be >= 2"):
        morph(a, b, POINTS_A, POINTS_B, frames=1, **KW)
    with pytest.raises(ValueError, match="inverse must be"):
        morph(a, b, POINTS_A, POINTS_B, inverse="magic", **KW)
    with pytest.raises(ValueError, match="points_b has a point outside"):
        morph(a, b, POINTS_A, POINTS_B + 100, **KW)


def test_a_map_that_reads_beyond_its_image_hands_the_frame_to_the_other_image(gen, monkeypatch):
    feather = 4.0  # a narrow hand-over band, so that a 64-pixel frame has room beyond it
    monkeypatch.setattr(sys.modules["torchfluidwarp.morph"], "FEATHER", feather)
    # B's points spread 2.2 times as far as A's: the similarity pre-alignment magnifies, so the middle
    # frames read B far beyond its edges near the frame's borders
    a = _blobs((64, 64), POINTS_A.tolist(), gen)
    centre = POINTS_A.mean(0)
    points_b = (POINTS_A - centre) * 2.2 + centre
    inside = ((points_b > 0) & (points_b < 63)).all()
    assert inside, "the test's points must stay in the image"
    b = _blobs((64, 64), points_b.tolist(), gen)
    r = morph(a, b, POINTS_A, points_b, frames=5, compressible=0.5, **KW)
    k = 2
    x, y = r.maps_b[k, ..., 0], r.maps_b[k, ..., 1]
    f = feather + 0.5  # B read more than the feather beyond its edge
    far_b = (x < -f) | (x > 63 + f) | (y < -f) | (y > 63 + f)
    xa, ya = r.maps[k, ..., 0], r.maps[k, ..., 1]
    in_a = (xa > -0.5) & (xa < 63.5) & (ya > -0.5) & (ya < 63.5)
    assert (far_b & in_a).sum() > 50, "the set-up must make B's map leave B"
    sel = far_b & in_a
    torch.testing.assert_close(r.frames[k][:, sel], r.forward_frames[k][:, sel], atol=1e-6, rtol=0)
    # where both maps read inside their images, the frame is the plain cross-dissolve
    both = in_a & (x > -0.5) & (x < 63.5) & (y > -0.5) & (y < 63.5)
    w = float(r.times[k] / r.times[-1])
    plain = torch.lerp(r.forward_frames[k], r.backward_frames[k], w)
    torch.testing.assert_close(r.frames[k][:, both], plain[:, both], atol=1e-5, rtol=0)
