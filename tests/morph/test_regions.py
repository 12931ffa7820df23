"""Regions, backgrounds and pasting back (:mod:`torchfluidwarp.morph.regions`, issue #23)."""

from __future__ import annotations

import pytest
import torch

from torchfluidwarp import morph
from torchfluidwarp.morph import Blending, NaturalSettings, hull_mask, paste_back

G = torch.Generator().manual_seed(3)
A = torch.rand(3, 64, 64, generator=G)
B = torch.rand(3, 64, 64, generator=G)
PA = torch.tensor([[24.0, 24.0], [40.0, 24.0], [32.0, 40.0], [26.0, 36.0]])
PB = PA + torch.tensor([[1.0, 1.5], [-1.0, 1.0], [0.5, -1.0], [1.0, 0.0]])
KW = dict(settings=NaturalSettings(grid=24, steps=4, max_iter=10), progress=False, frames=4)


def test_hull_mask_is_one_inside_zero_outside_and_grows_with_the_margin():
    tri = torch.tensor([[8.0, 8.0], [24.0, 8.0], [16.0, 24.0]])
    m = hull_mask(tri, (32, 32), margin=0.0, band=2.0)
    assert float(m[12, 16]) == 1.0 and float(m[30, 2]) == 0.0
    assert float(m.min()) >= 0 and float(m.max()) <= 1
    grown = hull_mask(tri, (32, 32), margin=0.25, band=2.0)
    assert bool((grown >= m).all()) and float(grown.sum()) > float(m.sum()) + 50
    # the ramp is as wide as the band: the mask is in (0, 1) only near the edge
    soft = hull_mask(tri, (32, 32), margin=0.0, band=6.0)
    assert int(((soft > 0) & (soft < 1)).sum()) > int(((m > 0) & (m < 1)).sum())
    with pytest.raises(ValueError, match="3 points not on one line"):
        hull_mask(torch.tensor([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]), (8, 8))


@pytest.mark.parametrize("background", ["a", "b"])
def test_outside_the_region_every_frame_shows_the_background(background):
    r = morph(A, B, PA, PB, blending=Blending(region="points", background=background), **KW)
    want = A if background == "a" else B
    far = (slice(None), slice(0, 6), slice(0, 6))  # a corner far from both hulls
    for k in range(len(r)):
        torch.testing.assert_close(r.frames[k][far], want[far], atol=1e-6, rtol=0)


def test_inside_the_region_the_frame_is_the_whole_frame_morph():
    plain = morph(A, B, PA, PB, **KW)
    region = morph(A, B, PA, PB, blending=Blending(region="points", region_margin=0.5, background="a"), **KW)
    centre = (slice(None), slice(30, 34), slice(30, 34))
    for k in (1, 2):
        torch.testing.assert_close(region.frames[k][centre], plain.frames[k][centre], atol=1e-5, rtol=0)


def test_masks_given_per_image_and_bad_regions():
    ma = torch.zeros(64, 64)
    ma[16:48, 16:48] = 1
    small_b = torch.nn.functional.interpolate(B[None], size=(32, 32), mode="bilinear", antialias=True)[0]
    mb = torch.zeros(32, 32)  # B at another size: its mask has B's size, and is resized with B
    mb[8:24, 8:24] = 1
    r = morph(A, small_b, PA, (PB + 0.5) / 2 - 0.5, blending=Blending(region=(ma, mb), background="a"), **KW)
    torch.testing.assert_close(r.frames[2][:, :4, :4], A[:, :4, :4], atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match=r"region\[1\] \(mask_b\) must have shape \(64, 64\)"):
        morph(A, B, PA, PB, blending=Blending(region=(ma, torch.zeros(10, 10))), **KW)
    with pytest.raises(ValueError, match="region must be 'points'"):
        morph(A, B, PA, PB, blending=Blending(region="hull"), **KW)
    with pytest.raises(ValueError, match="background must be 'a', 'b' or 'blend'"):
        morph(A, B, PA, PB, blending=Blending(region="points", background="c"), **KW)


def test_paste_back_round_trip_and_only_the_box_changes():
    photo = torch.rand(3, 80, 100, generator=G)
    box = (20, 10, 60, 50)
    crop = photo[:, 10:50, 20:60]
    torch.testing.assert_close(paste_back(crop, photo, box), photo, atol=1e-6, rtol=0)
    frame = torch.zeros(3, 20, 20)  # a smaller frame is resized to the box
    out = paste_back(frame, photo, box, band=4.0)
    outside = torch.ones(80, 100, dtype=torch.bool)
    outside[10:50, 20:60] = False
    torch.testing.assert_close(out[:, outside], photo[:, outside], atol=0, rtol=0)
    assert float(out[:, 20:40, 30:50].abs().max()) < 1e-6  # deep inside: the frame
    assert not torch.equal(out, photo) and torch.equal(photo, photo.clone())
    # a box reaching beyond the photo is clipped
    edge = paste_back(frame, photo, (90, 70, 110, 90))
    assert edge.shape == photo.shape


def test_paste_back_blends_pictures_with_alpha_premultiplied():
    # an opaque blue RGBA photo; a frame whose left half is transparent over a hidden red, its right half opaque
    # green, pasted at half strength (the frame replaces the region by half): the left half is blue at half alpha,
    # the right half blue-green, opaque; no red anywhere (straight blending gave the left half (0.5, 0, 0.5))
    photo = torch.zeros(4, 40, 40)
    photo[2], photo[3] = 1.0, 1.0
    frame = torch.zeros(4, 20, 20)
    frame[0, :, :10] = 1.0
    frame[1, :, 10:], frame[3, :, 10:] = 1.0, 1.0
    out = paste_back(frame, photo, (10, 10, 30, 30), mask=torch.full((20, 20), 0.5), band=0.0)
    assert float(out[0].abs().max()) < 1e-6  # the hidden red never shows
    torch.testing.assert_close(out[:3, 15:25, 12:16], photo[:3, 15:25, 12:16])  # the photo's colour
    torch.testing.assert_close(out[3, 15:25, 12:16], torch.full((10, 4), 0.5))  # at half alpha
    torch.testing.assert_close(out[3, 15:25, 24:28], torch.ones(10, 4))
    torch.testing.assert_close(out[1:3, 15:25, 24:28], torch.full((2, 10, 4), 0.5))


def test_alpha_is_warped_like_colour():
    from torchfluidwarp.io.images import premultiplied, straight
    from torchfluidwarp.warp import warp_image

    alpha = hull_mask(PA, (64, 64), margin=0.2, band=4.0)
    rgba_a = torch.cat([A, alpha[None]])
    rgba_b = torch.cat([B, hull_mask(PB, (64, 64), margin=0.2, band=4.0)[None]])
    r = morph(rgba_a, rgba_b, PA, PB, **KW)
    assert r.frames.shape == (4, 4, 64, 64)
    assert float(r.frames[:, 3].min()) >= 0 and float(r.frames[:, 3].max()) <= 1
    k = 2
    # alpha is warped like colour; the colour is warped premultiplied, so the colour under alpha 0 does not bleed
    warped = warp_image(premultiplied(rgba_a[None]), r.maps[k : k + 1])
    torch.testing.assert_close(r.forward_frames[k], straight(warped)[0], atol=1e-5, rtol=0)
    torch.testing.assert_close(
        r.forward_frames[k][3], warp_image(rgba_a[None], r.maps[k : k + 1])[0, 3], atol=1e-5, rtol=0
    )
    # an RGB B with an RGBA A gets an opaque alpha
    mixed = morph(rgba_a, B, PA, PB, **KW)
    torch.testing.assert_close(mixed.frames[-1][3], torch.ones(64, 64))


@pytest.mark.parametrize("region", [None, "points"])
def test_frames_rendered_in_bands_of_rows_are_the_same_bitwise(region, monkeypatch):
    import sys

    r = morph(A, B, PA, PB, blending=Blending(region=region, background="a"), **KW)
    ts = [0.0, 0.3, 0.7, 1.0]
    whole = r.render(ts)
    monkeypatch.setattr(sys.modules["torchfluidwarp.morph.render"], "BAND_PIXELS", 64 * 7)  # bands of 7 rows
    banded = r.render(ts)
    for name in ("frames", "forward", "backward", "maps_a", "maps_b"):
        assert torch.equal(getattr(whole, name), getattr(banded, name)), name
    assert whole.folded == banded.folded
    streamed = torch.stack(list(r.iter_frames(chunk=3)))  # streaming keeps the frames only
    assert torch.equal(streamed, r.frames)
