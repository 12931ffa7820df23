"""Pictures as people bring them (#31): any colour model and any aspect ratio, nothing stretched or dropped.

The frames take the richer colour model of the two pictures, and each picture lies on the output canvas by one
scale factor for both axes (the smallest that covers it, the crop centred on its marks): frame 0 is A so placed,
the last frame B.
"""

import warnings

import imageio.v3 as iio
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from discs import aspect, crop, crop_offset, disc, disc_marks, disc_picture

from torchfluidwarp.control.alignment import apply_alignment, interpolate_alignment
from torchfluidwarp.io import resize_image, write_animation
from torchfluidwarp.morph import Blending, NaturalSettings, morph, morphing
from torchfluidwarp.morph.morphing import placement
from torchfluidwarp.warp import identity_map

FAST = dict(settings=NaturalSettings(grid=16, steps=4, max_iter=30), progress=False)


# ------------------------------------------------------------------ colour models

S = (40, 48)
CENTRE_A, CENTRE_B = (22.0, 20.0), (25.0, 19.0)
R_A, R_B = 11.0, 12.0


def _models(gen):
    grey = lambda centre, r: disc_picture(S, centre, r, [0.9], gen)  # noqa: E731
    rgb = lambda centre, r: disc_picture(S, centre, r, [0.9, 0.3, 0.1], gen)  # noqa: E731

    def alpha(image, centre, r):
        return torch.cat([image, disc(S, centre, r + 4)[None]])  # opaque around the disc, transparent beyond

    return {
        "grey+rgb": (grey(CENTRE_A, R_A), rgb(CENTRE_B, R_B), 3),
        "rgb+grey": (rgb(CENTRE_A, R_A), grey(CENTRE_B, R_B), 3),
        "rgba+rgb": (alpha(rgb(CENTRE_A, R_A), CENTRE_A, R_A), rgb(CENTRE_B, R_B), 4),
        "la+rgb": (alpha(grey(CENTRE_A, R_A), CENTRE_A, R_A), rgb(CENTRE_B, R_B), 4),
    }


def _as(image, channels):
    """``image`` ``(C, H, W)`` in the model of ``channels`` (3 or 4), as the morph must convert it."""
    c = image.shape[0]
    rgb = image[:1].expand(3, -1, -1) if c in (1, 2) else image[:3]
    if channels == 3:
        return rgb
    alpha = image[-1:] if c in (2, 4) else torch.ones_like(image[:1])
    return torch.cat([rgb, alpha])


@pytest.mark.parametrize("pair", ["grey+rgb", "rgb+grey", "rgba+rgb", "la+rgb"])
def test_the_richer_colour_model_and_one_mode_in_every_frame(pair, gen, tmp_path):
    a, b, channels = _models(gen)[pair]
    r = morph(a, b, disc_marks(CENTRE_A, R_A), disc_marks(CENTRE_B, R_B), frames=5, **FAST)
    frames = r.frames
    assert frames.shape == (5, channels, *S)
    # same size, so the placement is the identity: the ends are the pictures themselves, converted exactly
    torch.testing.assert_close(frames[0], _as(a, channels), atol=1e-6, rtol=0)
    torch.testing.assert_close(frames[-1], _as(b, channels), atol=1e-6, rtol=0)
    assert (frames[1:-1].amin() >= -1e-6) and (frames[1:-1].amax() <= 1 + 1e-6)
    if pair in ("grey+rgb", "rgb+grey"):  # the middle frame mixes a grey disc with a coloured one: colour
        mid = frames[2][:, 18:22, 21:25]
        assert float((mid[0] - mid[2]).abs().mean()) > 0.1

    path = write_animation(tmp_path / "m.gif", frames)
    back = iio.imread(path, index=None)  # one array: every frame decodes in one mode
    assert back.shape == (5, *S, 3)
    # against the frames as 8 bits: an opaque GIF quantizes each frame to its own 256 colours (median cut), which
    # for these few flat colours is close to exact; a transparent GIF uses one fixed, dithered 6 x 7 x 6 colour
    # cube, whose levels are 51 (red, blue) and 42.5 (green) apart, so single pixels are off by up to half a step
    # and the dithering keeps the average over a few pixels within a few levels
    expect = frames.clamp(0, 1).mul(255).round().permute(0, 2, 3, 1).numpy()
    rgb = expect[..., :3] if channels >= 3 else np.repeat(expect, 3, -1)
    shown = expect[..., 3] >= 128 if channels == 4 else np.ones(back.shape[:3], bool)
    error = np.abs(back.astype(float) - rgb)[shown]
    if channels == 4:
        assert np.median(error) <= 26 and np.abs(_box(back) - _box(rgb))[_box(shown) == 1].mean() <= 8
    else:
        assert error.max() <= 12 and np.median(error) <= 3
    if channels == 4:  # and it is transparent where the alpha is below a half, in the first and last frames
        alpha = iio.imread(path, index=None, mode="RGBA")[..., 3]
        assert np.array_equal(alpha[[0, -1]] == 255, shown[[0, -1]])


def _box(x, k=4):
    """Means over ``k`` x ``k`` blocks of ``(T, H, W, ...)``."""
    x = np.asarray(x, dtype=float)
    T, H, W = x.shape[:3]
    x = x[:, : H - H % k, : W - W % k]
    return x.reshape(T, H // k, k, W // k, k, *x.shape[3:]).mean((2, 4))


def test_grey_with_alpha_as_two_channels_and_unmatched_channels(gen):
    a, b, _ = _models(gen)["la+rgb"]
    assert a.shape[0] == 2
    r = morph(a, b, disc_marks(CENTRE_A, R_A), disc_marks(CENTRE_B, R_B), frames=3, **FAST)
    assert r.frame(0.5).shape == (4, *S)
    with pytest.raises(ValueError, match="image_a has 5 channels but image_b has 3"):
        morph(torch.rand(5, *S), b, disc_marks(CENTRE_A, R_A), disc_marks(CENTRE_B, R_B), frames=3, **FAST)


# ------------------------------------------------------------------ aspect ratios


CASES = {
    # name: A's size and disc, B's size and disc; B at another resolution and aspect ratio
    "tall B onto a square A": ((64, 64), (32.0, 30.0), 14.0, (160, 80), (40.0, 84.0), 20.0),
    "square B onto a tall A": ((96, 64), (31.0, 50.0), 16.0, (48, 48), (23.0, 25.0), 9.0),
}


@pytest.mark.parametrize("case", list(CASES))
def test_neither_picture_is_stretched_and_b_marks_are_met_in_b_pixels(case, gen):
    size_a, centre_a, r_a, size_b, centre_b, r_b = CASES[case]
    a = disc_picture(size_a, centre_a, r_a, [0.9, 0.9, 0.9], gen)
    b = disc_picture(size_b, centre_b, r_b, [0.9, 0.9, 0.9], gen)
    pa, pb = disc_marks(centre_a, r_a), disc_marks(centre_b, r_b)
    r = morph(a, b, pa, pb, frames=5, **FAST)
    H, W = size_a
    assert r.frames.shape == (5, 3, H, W)  # the canvas is A's size
    # B's placement: one scale factor, the smallest that covers the canvas, the crop centred on B's marks
    s = max(H / size_b[0], W / size_b[1])
    place = r.canvas_from_b
    assert float(place[0, 0]) == pytest.approx(s) and float(place[1, 1]) == pytest.approx(s)
    assert float(place[0, 1]) == 0 and float(place[1, 0]) == 0
    # the last frame is B resized by that one factor (antialiased, as the library resizes) and cropped to the
    # canvas, computed here independently of the renderer
    h, w = round(size_b[0] * s), round(size_b[1] * s)
    if s < 1:
        scaled = resize_image(b[None], (h, w))[0]
    else:
        scaled = F.interpolate(b[None], size=(h, w), mode="bilinear", align_corners=False)[0]
    top, left = (-crop_offset(pb, s, size_b[0], H, 1), -crop_offset(pb, s, size_b[1], W, 0))
    torch.testing.assert_close(r.frames[-1], crop(scaled, top, left, (H, W)), atol=1e-4, rtol=0)
    torch.testing.assert_close(r.frames[0], a, atol=0, rtol=0)
    # B's disc stays a disc (the old resize to A's size made it an ellipse of aspect 1.6 or 0.67)
    assert aspect(r.frames[-1]) == pytest.approx(1.0, abs=0.04)
    assert aspect(r.frame(0.5)) == pytest.approx(1.0, abs=0.06)
    # B's marks are met in B's own pixels
    in_b = apply_alignment(torch.linalg.inv(place), r.points.double())
    assert float((in_b - pb.double()).norm(dim=-1).mean()) < 1.0
    torch.testing.assert_close(r.error, (r.points - apply_alignment(place, pb.double())).norm(dim=-1))
    # the last frame reads B in B's own pixels, through its placement alone
    canvas = identity_map((H, W), dtype=torch.float64)[0]
    want = apply_alignment(torch.linalg.inv(place), canvas)
    torch.testing.assert_close(r.maps_b[-1].double(), want, atol=1e-3, rtol=0)


def test_a_feature_near_the_edge_of_a_wide_b_stays_on_the_canvas(gen):
    # a group photograph: the marked face is near the left edge of a wide B, which a square canvas crops. A crop
    # centred on the picture cut the face off (its marks 40 canvas pixels left of the canvas), so the morph
    # carried A's face off the frame; centred on B's marks, the face stays whole on the canvas
    size_a, centre_a, r_a = (64, 64), (32.0, 30.0), 14.0
    size_b, centre_b, r_b = (64, 192), (20.0, 32.0), 12.0
    a = disc_picture(size_a, centre_a, r_a, [0.9, 0.9, 0.9], gen)
    b = disc_picture(size_b, centre_b, r_b, [0.9, 0.9, 0.9], gen)
    pa, pb = disc_marks(centre_a, r_a), disc_marks(centre_b, r_b)
    centred = apply_alignment(placement(size_b, size_a)[0], pb.double())
    assert float(centred[:, 0].max()) < 0  # what the old, centred crop did: every mark off the canvas
    r = morph(a, b, pa, pb, frames=5, **FAST)
    marks = apply_alignment(r.canvas_from_b, pb.double())
    # the picture's left edge on the canvas's (its marks cannot be centred further), the face whole on it
    assert float(r.canvas_from_b[0, 2]) == pytest.approx(0.0)
    assert float(marks[:, 0].min()) > 0 and float(marks[:, 0].max()) < 63
    assert float(r.error.mean()) < 1.0  # and the morph meets them there
    torch.testing.assert_close(r.frames[-1], b[..., :64], atol=1e-4, rtol=0)  # B at scale 1, its left part
    assert aspect(r.frame(0.5)) == pytest.approx(1.0, abs=0.06)


def test_marks_that_the_output_size_crops_away_are_left_out_with_a_warning(gen):
    # a wide A cropped to a square canvas around its marks' median: its two outermost marks fall beyond the crop
    a = disc_picture((40, 120), (60.0, 20.0), 10.0, [0.9, 0.9, 0.9], gen)
    b = disc_picture((40, 120), (62.0, 21.0), 11.0, [0.9, 0.9, 0.9], gen)
    pa = torch.cat([disc_marks((60.0, 20.0), 10.0), torch.tensor([[5.0, 20.0], [115.0, 20.0]])])
    pb = torch.cat([disc_marks((62.0, 21.0), 11.0), torch.tensor([[6.0, 21.0], [114.0, 21.0]])])
    with pytest.warns(RuntimeWarning, match=r"output size 40 x 40 .*crops image_a: 2 of its 7 points .*5, 6"):
        r = morph(a, b, pa, pb, frames=3, blending=Blending(size=40), **FAST)
    assert r.points.shape == (5, 2) and float(r.error.mean()) < 1.0  # the disc's marks are met
    # marks spread over the whole width: the 40-pixel crop around their median keeps one
    spread = torch.tensor([[5.0, 10.0], [35.0, 30.0], [60.0, 20.0], [85.0, 12.0], [115.0, 28.0]])
    with pytest.raises(ValueError, match=r"only 1 of its 5 points stay on it") as caught:
        morph(a, b, spread, spread + 1.0, frames=3, blending=Blending(size=40), **FAST)
    assert caught.value.argument == "blending"


def test_a_canvas_of_the_pictures_shape_up_to_rounding_is_filled_exactly_and_keeps_its_border_points(gen):
    # 97 x 44 shrunk by half and rounded is 49 x 22: one cover factor (49 / 97) would crop 0.2 px off the width
    # and leave the right border's points off the canvas; the picture fills it instead, each axis by its own factor
    place, scale = placement((97, 44), (49, 22))
    corners = torch.tensor([[-0.5, -0.5], [43.5, 96.5]], dtype=torch.float64)  # the picture's outer corners
    torch.testing.assert_close(apply_alignment(place, corners), torch.tensor([[-0.5, -0.5], [21.5, 48.5]]).double())
    assert scale == pytest.approx(max(49 / 97, 22 / 44)) and abs(49 / 97 - 22 / 44) * 97 < 1
    assert torch.equal(placement((40, 40), (40, 40))[0], torch.eye(3, dtype=torch.float64))  # the same size
    # a panorama 8000 x 1508 shrunk to 1080 x 204: the one cover factor would cut 2.2 px off its width
    wide, _ = placement((1508, 8000), (204, 1080))
    ends = apply_alignment(wide, torch.tensor([[-0.5, -0.5], [7999.5, 1507.5]], dtype=torch.float64))
    torch.testing.assert_close(ends, torch.tensor([[-0.5, -0.5], [1079.5, 203.5]], dtype=torch.float64))
    # a picture of another shape is still covered by one factor and cropped
    other, _ = placement((100, 60), (50, 50))
    assert float(other[0, 0]) == float(other[1, 1]) == pytest.approx(50 / 60)
    a = disc_picture((97, 44), (22.0, 48.0), 10.0, [0.9, 0.9, 0.9], gen)
    b = disc_picture((97, 44), (23.0, 50.0), 11.0, [0.9, 0.9, 0.9], gen)
    border = torch.tensor([[0.0, 0.0], [43.0, 0.0], [43.0, 96.0], [0.0, 96.0]])
    pa, pb = torch.cat([disc_marks((22.0, 48.0), 10.0), border]), torch.cat([disc_marks((23.0, 50.0), 11.0), border])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no point is left out: no "crops image_a" warning
        r = morph(a, b, pa, pb, frames=3, blending=Blending(size=(49, 22)), **FAST)
    assert r.points.shape == (9, 2) and r.frames.shape == (3, 3, 49, 22)
    # the first frame is A shrunk to the canvas, as resize_image shrinks it (the same two factors)
    shrunk = resize_image(a[None] if a.ndim == 3 else a, (49, 22))
    assert float((r.frames[0] - shrunk[0]).abs().mean()) < 0.02


def test_the_output_size_is_a_setting(gen):
    a = disc_picture((40, 40), (20.0, 20.0), 10.0, [0.9, 0.9, 0.9], gen)
    b = disc_picture((60, 30), (15.0, 30.0), 8.0, [0.9, 0.9, 0.9], gen)
    pa, pb = disc_marks((20.0, 20.0), 10.0), disc_marks((15.0, 30.0), 8.0)
    r = morph(a, b, pa, pb, frames=3, blending=Blending(size=(30, 50)), **FAST)
    assert r.frames.shape == (3, 3, 30, 50)
    assert float(r.canvas_from_a[0, 0]) == pytest.approx(
        50 / 40
    )  # A covers the wider canvas, its top and bottom cropped
    assert aspect(r.frames[0]) == pytest.approx(1.0, abs=0.04) and aspect(r.frames[-1]) == pytest.approx(1.0, abs=0.04)
    with pytest.raises(ValueError, match=r"Blending\.size"):
        Blending(size=(0, 10))


# ------------------------------------------------------------------ a small face zoomed into a large one


def _zoomed_marks():
    """25 marks 3 px apart in the middle of a 192-px A, and where they land in B: zoomed 5 times about the centre,
    plus a bend of up to 3 px (B's pixels) that no similarity explains."""
    g = torch.arange(5, dtype=torch.float64) * 3 - 6
    pa = torch.cartesian_prod(g, g) + 96.0
    bend = torch.stack([torch.sin((pa[:, 1] - 96) / 2), torch.cos((pa[:, 0] - 96) / 3)], -1)
    return pa, (pa - 96.0) * 5 + 96.0 + 3.0 * bend


def test_a_small_face_zoomed_into_a_large_one_meets_its_marks(gen, monkeypatch):
    # a small face in a wide photograph morphed into a portrait: the pre-alignment zooms in 5 times, so the last
    # frame shows a fifth of A across. Over the whole picture the fluid's cells (32 over 240 px: 7.5 px) are wider
    # than the marks' gaps (3 px), and the zoom magnifies what they miss; over the part the last frame shows they
    # are 1.9 px (61 px of box), and the marks are met
    a = F.interpolate(torch.rand(1, 3, 12, 12, generator=gen), size=(192, 192), mode="bicubic").clamp(0, 1)
    b = F.interpolate(torch.rand(1, 3, 12, 12, generator=gen), size=(192, 192), mode="bicubic").clamp(0, 1)
    pa, pb = _zoomed_marks()
    settings = NaturalSettings(grid=32, dense=None)
    r = morph(a, b, pa, pb, settings=settings, frames=5, progress=False)
    x0, y0, x1, y1 = r.box
    assert x1 - x0 < 192 / 2 and y1 - y0 < 192 / 2  # the fluid's box: the region and its margin
    assert float(r.error.mean()) < 0.15 and float(r.error.max()) < 0.3  # measured 0.06 and 0.17 px
    assert r.folded == 0
    # outside the box the fluid is still: A's pixels there move by the pre-alignment alone, in the frames that
    # show them (up to the middle one; later frames show the region alone), give or take the fluid's sub-pixel
    # drift at its walls, which the maps hold beyond them (measured 0.30 px at t = 0.25, 0.38 at 0.5)
    maps = r.maps.double()
    canvas = identity_map((192, 192), dtype=torch.float64)[0]
    for k, t in enumerate(r.times[:3] / r.times[-1]):  # fluid steps to the morph's fraction
        step = interpolate_alignment(r.alignment, float(t), r.points.double().mean(0))
        plain = apply_alignment(torch.linalg.inv(step), canvas.reshape(-1, 2)).reshape(192, 192, 2)
        outside = ((plain < torch.tensor([x0, y0]) - 2) | (plain > torch.tensor([x1, y1]) + 2)).any(-1)
        assert int(outside.sum()) > 1000
        assert float((maps[k] - plain)[outside].norm(dim=-1).max()) < 0.5, t
    # the same morph with the fluid over the whole picture misses the marks by over a pixel, and says so
    monkeypatch.setattr(morphing, "focus", lambda *args, **kwargs: None)
    with pytest.warns(RuntimeWarning, match="fluid cells apart"):
        whole = morph(a, b, pa, pb, settings=settings, frames=2, progress=False)
    assert float(whole.error.mean()) > 1.0  # measured 1.41 px
