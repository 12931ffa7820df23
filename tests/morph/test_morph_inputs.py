"""Bad and unusual input to :func:`torchfluidwarp.morph` (issue #19): each case gets a clear error that names the
argument, or a valid result, before any work starts."""

from __future__ import annotations

import importlib
import warnings

import pytest
import torch

from torchfluidwarp import morph
from torchfluidwarp.morph import Matching, NaturalSettings, PaperSettings

A = torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(0))
PA = torch.tensor([[4.0, 4.0], [11.0, 9.0], [5.0, 12.0]])
KW = dict(max_iter=3, grid=12, steps=2)  # the method's settings of every morph here
METHODS = {"natural": NaturalSettings, "paper": PaperSettings}


def _morph(*args, method="natural", **kwargs):
    """morph() with KW's settings; keyword arguments that are fields of the method's settings go there."""
    cls = METHODS[method]
    fields = {k: kwargs.pop(k) for k in list(kwargs) if k in cls.__dataclass_fields__}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return morph(*args, settings=cls(**{**KW, **fields}), progress=False, **kwargs)


@pytest.mark.parametrize("method", ["natural", "paper"])
def test_frame_counts_that_do_not_divide_the_steps_work_with_the_paper_inverse(method):
    r = _morph(A, A, PA, PA + 0.5, frames=4, steps=1, inverse="paper", method=method)
    assert r.frames.shape == (4, 3, 16, 16)
    assert torch.isfinite(r.frames).all()
    # the paper's inverse and the flow's agree on where B is read, up to the small fits' error (pixels)
    flow = _morph(A, A, PA, PA + 0.5, frames=4, steps=1, inverse="flow", method=method)
    assert float((r.maps_b - flow.maps_b).abs().max()) < 1.0


def test_mixed_float_dtypes_are_promoted_and_half_precision_computed_in_float32():
    r = _morph(A, A.double(), PA, PA + 0.5, frames=3)
    assert r.frames.dtype == torch.float64
    r = _morph(A.bfloat16(), torch.rand(3, 20, 20).bfloat16(), PA, PA + 0.5, frames=3)
    assert r.frames.dtype == torch.bfloat16
    assert torch.isfinite(r.frames.float()).all()
    # the endpoints are the inputs, in the caller's dtype
    torch.testing.assert_close(r.frames[0], A.bfloat16())


def test_points_that_require_grad_are_used_as_values_and_left_unchanged():
    pa = PA.clone().requires_grad_()
    r = _morph(A, A, pa, PA + 0.5, frames=3)
    assert not r.frames.requires_grad
    assert pa.grad is None
    torch.testing.assert_close(pa.detach(), PA)


def test_several_point_sets_are_refused_instead_of_using_the_first():
    with pytest.raises(ValueError, match=r"points_a must be one set of points \(M, 2\).*\(2, 3, 2\)"):
        _morph(A, A, torch.stack([PA, PA]), torch.stack([PA, PA]) + 0.5, frames=3)


def test_identical_target_points_are_refused_by_name():
    with pytest.raises(ValueError, match="points_b repeats points"):
        _morph(A, A, PA, torch.full_like(PA, 5.0), frames=3)


@pytest.mark.parametrize("margin", [float("inf"), float("nan"), -0.5, 1e30])
def test_margin_is_checked(margin):
    with pytest.raises(ValueError, match="margin must be"):
        _morph(A, A, PA, PA + 0.5, frames=3, method="paper", margin=margin)


def test_warm_start_and_compressible_of_the_wrong_type_name_themselves():
    with pytest.raises(TypeError, match="warm_start must be a KeyframeFit or None, got str 'x'"):
        _morph(A, A, PA, PA + 0.5, frames=3, warm_start="x")
    with pytest.raises(TypeError, match="compressible must be a bool or a number in \\[0, 1\\], got str 'yes'"):
        _morph(A, A, PA, PA + 0.5, frames=3, compressible="yes")
    with pytest.raises(ValueError, match="compressible must be in \\[0, 1\\], got 2"):
        _morph(A, A, PA, PA + 0.5, frames=3, compressible=2)


@pytest.mark.parametrize("kwargs", [{"steps": 10**9}, {"grid": 100_000}], ids=["steps", "grid"])
def test_requests_beyond_the_memory_limit_are_refused_before_work_with_the_setting_that_raises_it(kwargs):
    with pytest.raises(ValueError, match=r"would need about .* above the limit of 8\.0 GiB.*max_memory"):
        _morph(A, A, PA, PA + 0.5, **{"frames": 3, **kwargs})
    # the limit is a setting: a small one refuses an ordinary morph, naming both numbers
    with pytest.raises(ValueError, match=r"above the limit of 1\.0 KiB"):
        _morph(A, A, PA, PA + 0.5, frames=3, max_memory=1024)


@pytest.mark.parametrize(
    "image, match",
    [
        (torch.rand(0, 16, 16), "image_a must be a single image"),
        ((A * 255).to(torch.uint8), "image_a must be a floating-point tensor"),
        (A.to(torch.complex64), "image_a must be a floating-point tensor"),
        (torch.rand(2, 3, 16, 16), "image_a must be a single image"),
        (torch.rand(3, 1, 1), r"image_a must be a single image .* at least 2 x 2 pixels, got \(3, 1, 1\)"),
    ],
    ids=["no-channels", "uint8", "complex", "batch", "one-pixel"],
)
def test_images_that_cannot_be_morphed_are_refused(image, match):
    with pytest.raises((TypeError, ValueError), match=match):
        _morph(image, A, PA, PA + 0.5, frames=3)


def test_a_billion_frames_stream_but_are_refused_all_at_once():
    r = _morph(A, A, PA, PA + 0.5, frames=10**9)
    assert len(r) == 10**9
    first = next(r.iter_frames(chunk=2))
    torch.testing.assert_close(first, A)  # frame 0 is image A
    with pytest.raises(ValueError, match=r"all 1000000000 frames .* above the limit of 8\.0 GiB.*iter_frames"):
        r.frames  # noqa: B018


def test_without_points_the_morph_finds_them_from_the_pictures():
    from torchfluidwarp.data import load_sample

    photo = load_sample("astronaut").reshape(1, 3, 512, 512)
    a = torch.nn.functional.interpolate(photo, size=(160, 160), mode="bilinear", antialias=True)[0]
    b = torch.roll(a, shifts=(3, -4), dims=(1, 2))  # B: A moved 4 px left and 3 px down
    with pytest.raises(ValueError, match="give both points_a and points_b, or neither"):
        _morph(a, b, PA, None, frames=3)
    r = _morph(a, b, frames=3, match=Matching("features"), grid=24, steps=4, max_iter=20)
    pa = r.trajectories[0]
    pb = r.points  # where A's points ended
    shift = (pb - pa).median(0).values.float()  # the matched points moved with the picture
    torch.testing.assert_close(shift, torch.tensor([-4.0, 3.0]), atol=1.0, rtol=0)
    assert r.folded == 0


def test_match_takes_the_mode_alone_as_the_matchers_hints_spell_it():
    # the notes and errors of the matchers say match='pixels' or match='features': morph takes that as given
    gen = torch.Generator().manual_seed(5)
    small = torch.nn.functional.interpolate(torch.rand(1, 3, 6, 6, generator=gen), size=(40, 40), mode="bicubic")
    a = small[0].clamp(0, 1)
    b = torch.roll(a, shifts=(2, -1), dims=(1, 2))
    by_mode = _morph(a, b, frames=3, match="pixels")
    by_settings = _morph(a, b, frames=3, match=Matching("pixels"))
    torch.testing.assert_close(by_mode.points, by_settings.points, atol=0, rtol=0)
    torch.testing.assert_close(by_mode.frames, by_settings.frames, atol=0, rtol=0)
    with pytest.raises(ValueError, match=r"match must be a Matching or one of \('auto', .*'pixels'\), got 'optical'"):
        _morph(a, b, frames=3, match="optical")


def test_a_matchers_note_is_warned_in_the_morphs_own_terms(monkeypatch):
    # the faces matcher's hint names face_index, which morph() takes inside Matching
    from torchfluidwarp.correspond import FoundPoints, MatchNotice
    from torchfluidwarp.correspond.auto import Note
    from torchfluidwarp.errors import Hint

    note = Note("b.jpg shows 2 faces: used the largest", Hint("choose another with {setting}", "face_index"), True)
    found = FoundPoints(PA, PA + 0.5, "faces", note)
    monkeypatch.setattr(importlib.import_module("torchfluidwarp.morph.morphing"), "find_points", lambda *a, **k: found)
    with pytest.warns(MatchNotice) as caught:
        _morph(A, A, frames=3)
    assert str(caught[0].message) == (
        "b.jpg shows 2 faces: used the largest; choose another with match=Matching(face_index=(i, j))"
    )
    assert caught[0].message.note is note


def test_points_as_lists_arrays_or_integers_morph_as_the_same_tensors():

    reference = _morph(A, A, PA, PA + 1.0, frames=3)
    for pa, pb in (
        (PA.tolist(), (PA + 1.0).tolist()),
        (PA.numpy(), (PA + 1.0).numpy()),
        (PA.round().long(), (PA.round() + 1).long()),
    ):
        result = _morph(A, A, pa, pb, frames=3)
        expected = reference if not isinstance(pa, torch.Tensor) else _morph(A, A, PA.round(), PA.round() + 1, frames=3)
        torch.testing.assert_close(result.frames, expected.frames)
    with pytest.raises(TypeError, match="points_a must be a torch.Tensor, got str"):
        _morph(A, A, "corners", PA, frames=3)


def test_empty_or_malformed_points_are_said_in_the_callers_shape():
    with pytest.raises(ValueError, match=r"points_a must have shape \(M, 2\) .* got \(0, 2\)"):
        _morph(A, A, torch.zeros(0, 2), torch.zeros(0, 2), frames=3)
    with pytest.raises(ValueError, match=r"points_a must have shape \(M, 2\) .* got \(3, 3\)"):
        _morph(A, A, torch.zeros(3, 3), PA, frames=3)


def test_points_where_a_picture_goes_are_told_the_order_of_the_arguments():
    with pytest.raises(ValueError, match=r"image_b has shape \(3, 2\), a set of points, not a picture; the order is "
                       r"morph\(image_a, image_b, points_a, points_b\)"):  # fmt: skip
        morph(A, PA, A, PA)


def test_points_in_normalised_coordinates_are_refused_with_the_product_that_gives_pixels():
    with pytest.raises(ValueError, match=r"points_b: all 3 points lie within \[0, 1\] on a 16 x 16 picture: "
                       r"normalised coordinates\? .* multiply by \(16, 16\)") as caught:  # fmt: skip
        _morph(A, A, PA, PA / 16, frames=3)
    assert caught.value.argument == "points_b"
    small = A[:, :12, :12]  # a picture this small may be marked within its corner pixel
    _morph(small, small, PA / 16, PA / 15, frames=2)


@pytest.mark.parametrize("scale, advice", [(255.0, "divide by 255"), (-1.0, "bring them to")])
def test_values_outside_a_pictures_range_are_said_naming_the_image(scale, advice):
    with pytest.warns(UserWarning, match=rf"image_b's values span \[.*\], not a picture's \[0, 1\].*{advice}"):
        morph(A, A * scale, PA, PA + 0.5, frames=3, progress=False, settings=NaturalSettings(**KW))
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # a picture in [0, 1] says nothing
        warnings.simplefilter("ignore", RuntimeWarning)
        morph(A, A, PA, PA + 0.5, frames=3, progress=False, settings=NaturalSettings(**KW))


def test_points_keep_their_fraction_with_a_half_precision_picture_and_booleans_are_refused():
    from torchfluidwarp.morph.morphing import _as_points

    picture = torch.zeros(1, 3, 2000, 2000, dtype=torch.bfloat16)
    p = _as_points("points_a", [[300.7, 1500.3], [10.0, 20.0], [40.0, 5.0]], picture)
    assert p.dtype == torch.float32
    torch.testing.assert_close(p[0], torch.tensor([300.7, 1500.3]))
    with pytest.raises(TypeError, match="points_a must be a torch.Tensor, got list"):
        _as_points("points_a", [[True, False], [False, True], [True, True]], picture)
