"""The cross-dissolve of a frame (``morph/render.py``): the weights where neither picture covers a pixel."""

from __future__ import annotations

import torch

from torchfluidwarp.morph.render import BEYOND_SHARPNESS, EDGE_MIRROR, _dissolve, read
from torchfluidwarp.morph.settings import FEATHER
from torchfluidwarp.warp import identity_map


def test_where_neither_picture_covers_the_nearer_takes_over_and_no_distance_overflows() -> None:
    # A 16 x 16 canvas and two 16 x 16 pictures, both read 5 px beyond their left edge in the left half: A's map
    # there is crushed (its columns repeat: its stretch is 0, so its distance beyond the edge in output pixels is
    # as good as infinite), B's is a plain shift. The frame must take B there, not inf / inf = NaN.
    canvas = (16, 16)
    ident = identity_map(canvas, dtype=torch.float32)  # (1, 16, 16, 2)
    map_a, map_b = ident.clone(), ident.clone()
    map_a[:, :, :8, 0] = -5.0  # every output pixel of the left half reads A at x = -5: crushed onto one column
    map_b[:, :, :8, 0] = ident[:, :, :8, 0] - 5.0
    a = torch.full((1, 3, 16, 16), 0.2)
    b = torch.full((1, 3, 16, 16), 0.9)
    fa, fb = torch.full((1, 3, 16, 16), 0.2), torch.full((1, 3, 16, 16), 0.9)
    frame = _dissolve((a, b), fa, fb, map_a, map_b, 0.5, (canvas, canvas), canvas, 0, feather=4.0)
    assert torch.isfinite(frame).all()
    # B is read about 1-5 output pixels beyond its edge there, A (crushed) some 1e12: B's weight is
    # 1 - (1 - w) (out_b / out_a)^k, within round-off of 1
    assert torch.allclose(frame[..., :3], torch.full_like(frame[..., :3], 0.9), atol=1e-6)
    # the ratio alone counts: both read alike far beyond their edges gives the colour's schedule, w
    far_a, far_b = ident.clone(), ident.clone()
    far_a[..., 0] = ident[..., 0] - 1e30
    far_b[..., 0] = ident[..., 0] - 1e30
    frame = _dissolve((a, b), fa, fb, far_a, far_b, 0.25, (canvas, canvas), canvas, 0, feather=4.0)
    assert torch.isfinite(frame).all()
    assert torch.allclose(frame, torch.full_like(frame, 0.75 * 0.2 + 0.25 * 0.9), atol=1e-5)
    assert BEYOND_SHARPNESS > 1


def test_a_strip_a_picture_leaves_uncovered_dissolves_into_it_as_it_takes_over() -> None:
    # A covers a 64 x 160 canvas; B, 120 px wide, leaves the right 40 px uncovered (read beyond its right edge),
    # as a picture zoomed by the pre-alignment does until the last frame. Early, A shows there (40 px is more
    # than the strip B may fill mirrored at the start, EDGE_MIRROR * feather = 32 px); late, B fills it mirrored
    # with nearly its weight, so the strip dissolves with the frame instead of showing A until the last frame
    canvas = (64, 160)
    ident = identity_map(canvas, dtype=torch.float32)
    a, b = torch.full((1, 1, 64, 160), 0.2), torch.full((1, 1, 64, 120), 0.8)
    fa, fb = read(a, ident, (64, 160)), read(b, ident, (64, 120))
    outer = slice(130, 160)  # the strip, 10-40 px beyond B's edge

    def b_weight(w: float) -> float:
        frame = _dissolve((a, b), fa, fb, ident, ident, w, ((64, 160), (64, 120)), canvas, 0, feather=FEATHER)
        return float(((frame[..., outer] - 0.2) / 0.6).mean())

    assert EDGE_MIRROR * FEATHER < 40  # the set-up: the strip is wider than the one mirrored at the start
    assert b_weight(0.1) < 0.01 and b_weight(0.5) < 0.01  # A, as before, up to the middle frame
    weights = [b_weight(w) for w in (0.8, 0.9, 0.95, 0.97, 0.99)]
    assert weights == sorted(weights) and weights[0] > 0.05  # B takes the strip over the last frames
    assert weights[-2] > 0.97 - 0.07 and weights[-1] > 0.99 - 0.01, weights  # nearly the frame's own weight
    assert abs(b_weight(1.0) - 1.0) < 1e-6


def test_a_transparent_pixels_hidden_colour_never_shows_and_an_edge_of_alpha_does_not_tint() -> None:
    # A: RGBA, its left half transparent over a hidden red, its right half opaque blue; B: opaque green. Blended
    # straight, the middle frame showed the hidden red at half strength over the left half ((0.5, 0.5, 0) at alpha
    # 0.5); premultiplied, it is B's green at B's share of the alpha. The marks stay put: the frames are a
    # cross-dissolve, so every pixel's expected value is known.
    from torchfluidwarp.morph import NaturalSettings, morph

    a = torch.zeros(1, 4, 64, 64)
    a[:, 0] = 1.0  # red everywhere, hidden where alpha is 0
    a[:, :3, :, 32:] = torch.tensor([0.0, 0.0, 1.0])[:, None, None]
    a[:, 3, :, 32:] = 1.0
    b = torch.zeros(1, 3, 64, 64)
    b[:, 1] = 1.0
    p = torch.tensor([[10.0, 10.0], [50.0, 10.0], [30.0, 50.0], [15.0, 45.0]])
    result = morph(a, b, p, p, frames=3, progress=False, settings=NaturalSettings(dense=None))
    mid = result.frame(0.5)  # (4, H, W)
    left, right = mid[:, :, :24], mid[:, :, 40:]  # away from the edge of alpha, which the flow may blur a pixel
    torch.testing.assert_close(left[3], torch.full_like(left[3], 0.5), atol=1e-3, rtol=0)
    torch.testing.assert_close(
        left[:3], torch.tensor([0.0, 1.0, 0.0])[:, None, None].expand_as(left[:3]), atol=2e-3, rtol=0
    )
    torch.testing.assert_close(right[3], torch.ones_like(right[3]), atol=1e-3, rtol=0)
    torch.testing.assert_close(
        right[:3], torch.tensor([0.0, 0.5, 0.5])[:, None, None].expand_as(right[:3]), atol=2e-3, rtol=0
    )
    # across the edge of alpha, no red at all: the colour is a mix of green and blue only
    assert float(mid[0].abs().max()) < 1e-3
    # the endpoints are the pictures themselves (A's hidden red included: nothing is lost from the input)
    torch.testing.assert_close(result.frame(0.0), a[0])


def test_grey_with_alpha_is_blended_premultiplied_as_rgba_is():
    from torchfluidwarp.morph import NaturalSettings, morph

    a = torch.ones(1, 2, 64, 64)  # white stored everywhere, hidden where alpha is 0 (the left half)
    a[:, 1, :, :32] = 0.0
    b = torch.zeros(1, 2, 64, 64)
    b[:, 1] = 1.0  # opaque black
    p = torch.tensor([[10.0, 10.0], [50.0, 10.0], [30.0, 50.0], [15.0, 45.0]])
    mid = morph(a, b, p, p, frames=3, progress=False, settings=NaturalSettings(dense=None)).frame(0.5)
    assert mid.shape[0] == 2
    torch.testing.assert_close(mid[1, :, :24], torch.full((64, 24), 0.5), atol=1e-3, rtol=0)
    assert float(mid[0, :, :24].abs().max()) < 2e-3  # black at half alpha, not the hidden white at 0.5
