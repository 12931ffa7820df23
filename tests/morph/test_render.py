"""The cross-dissolve of a frame (``morph/render.py``): the weights where neither picture covers a pixel."""

from __future__ import annotations

import torch

from torchfluidwarp.morph.render import BEYOND_SHARPNESS, _dissolve
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
