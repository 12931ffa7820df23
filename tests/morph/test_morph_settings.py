"""The morph's typed settings (:mod:`torchfluidwarp.morph.settings`) and the frames of its results: the fit in
the fluid box's frame, the result's own figures in the frames' pixels (issue #30)."""

from __future__ import annotations

import dataclasses
import inspect

import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.core.grid import SquareCells
from torchfluidwarp.morph import (
    Blending,
    Matching,
    NaturalSettings,
    PaperSettings,
    Timing,
    average,
    morph,
    morph_sequence,
)
from torchfluidwarp.morph.settings import MAX_MARGIN, METHODS

PA = torch.tensor([[14.0, 16.0], [32.0, 14.0], [24.0, 30.0], [16.0, 34.0], [33.0, 33.0]])
PB = PA + torch.tensor([[2.0, 1.0], [-1.0, 2.0], [1.5, -1.5], [-2.0, 0.0], [0.0, 2.0]])


@pytest.fixture
def pair(gen):
    # a smooth picture, so that sampling differences between two renderers stay small
    a = F.interpolate(torch.rand(1, 3, 8, 8, generator=gen), size=(48, 48), mode="bicubic").clamp(0, 1)[0]
    return a, torch.rand(3, 48, 48, generator=gen)


@pytest.mark.parametrize("fn", [morph, morph_sequence, average])
def test_the_morph_functions_take_fewer_than_15_parameters(fn):
    assert len(inspect.signature(fn).parameters) < 15


def test_no_default_is_a_none_sentinel_resolved_per_method():
    # the defaults live on the settings classes, and differ by method
    for name, parameter in inspect.signature(morph).parameters.items():
        if name not in ("points_a", "points_b", "placed", "warm_start", "max_memory"):  # optional inputs
            assert parameter.default is not None, name
    assert NaturalSettings().grid == SquareCells(80 * 80) and PaperSettings().grid.shape == (64, 64)
    assert NaturalSettings().compressible is True and PaperSettings().compressible is False
    assert METHODS == {"natural": NaturalSettings, "paper": PaperSettings}
    assert NaturalSettings.method == "natural" and PaperSettings.method == "paper"
    # one meaning per name: the natural fit's weight on velocity corrections is not the paper's smoothness
    assert "smoothness" not in {f.name for f in dataclasses.fields(NaturalSettings)}
    assert "straightness" not in {f.name for f in dataclasses.fields(PaperSettings)}


def test_settings_are_frozen_and_normalised():
    s = PaperSettings(grid=32, control=4)
    assert s.grid.shape == (32, 32) and s.control == (4, 4)
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.steps = 3  # type: ignore[misc]
    assert Timing(motion=[[0, 0], [0.5, 0.8], [1, 1]]).motion == ((0.0, 0.0), (0.5, 0.8), (1.0, 1.0))
    assert Matching(face_index=[0, None]).face_index == (0, None)
    assert Matching(face_index=2).face_index == 2  # one index: the face of each picture that shows several


@pytest.mark.parametrize(
    "build, error, message",
    [
        (lambda: NaturalSettings(steps=0), ValueError, r"NaturalSettings\.steps must be >= 1, got 0"),
        (lambda: NaturalSettings(grid=1), ValueError, r"NaturalSettings\.grid must be a pair of ints >= 2"),
        (lambda: NaturalSettings(straightness=-1.0), ValueError, r"NaturalSettings\.straightness .* got -1\.0"),
        (lambda: NaturalSettings(compressible=1.5), ValueError, r"NaturalSettings\.compressible .* got 1\.5"),
        (lambda: NaturalSettings(viscosity=float("nan")), ValueError, r"NaturalSettings\.viscosity .* got nan"),
        (lambda: NaturalSettings(max_iter=2.5), TypeError, r"NaturalSettings\.max_iter must be an int, got float"),
        (lambda: NaturalSettings(align="rigid"), ValueError, r"NaturalSettings\.align must be .*, got 'rigid'"),
        (lambda: NaturalSettings(lattice=0), ValueError, r"NaturalSettings\.lattice must be >= 1, got 0"),
        (lambda: NaturalSettings(lattice=4.5), TypeError, r"NaturalSettings\.lattice must be an int, got float"),
        (lambda: PaperSettings(inverse="magic"), ValueError, r"PaperSettings\.inverse must be .*, got 'magic'"),
        (lambda: PaperSettings(smoothness=float("inf")), ValueError, r"PaperSettings\.smoothness .* got inf"),
        (lambda: PaperSettings(control=(4, 0)), ValueError, r"PaperSettings\.control .* got \(4, 0\)"),
        (lambda: PaperSettings(margin=MAX_MARGIN + 1), ValueError, r"PaperSettings\.margin must be <= 10\.0"),
        (lambda: PaperSettings(tolerance=-0.1), ValueError, r"PaperSettings\.tolerance .* got -0\.1"),
        (lambda: Timing(motion="bouncy"), ValueError, r"Timing\.motion must be one of .* got 'bouncy'"),
        (lambda: Timing(blend=[(0, 0), (0.5, 1)]), ValueError, r"Timing\.blend's control points must run from"),
        (lambda: Blending(feather=-2.0), ValueError, r"Blending\.feather .* got -2\.0"),
        (lambda: Blending(region="hull"), ValueError, r"Blending\.region must be 'points'.* got 'hull'"),
        (lambda: Blending(region=3), TypeError, r"Blending\.region must be .* got int 3"),
        (lambda: Blending(background="c"), ValueError, r"Blending\.background must be .* got 'c'"),
        (lambda: Matching(mode="eyes"), ValueError, r"Matching\.mode must be .* got 'eyes'"),
        (lambda: Matching(face_index=(0, -1)), ValueError, r"Matching\.face_index must be >= 0, got -1"),
        (lambda: Matching(face_index=-1), ValueError, r"Matching\.face_index must be >= 0, got -1"),
        (lambda: Matching(face_index="1"), TypeError, r"Matching\.face_index must be an int or a pair"),
    ],
)
def test_a_bad_setting_is_refused_naming_its_field_and_value(build, error, message):
    with pytest.raises(error, match=message):
        build()


def test_settings_of_the_wrong_class_are_refused_by_name(pair):
    a, b = pair
    with pytest.raises(TypeError, match="settings must be a NaturalSettings or PaperSettings, got str 'paper'"):
        morph(a, b, PA, PB, settings="paper", progress=False)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="timing must be a Timing, got dict"):
        morph(a, b, PA, PB, timing={"motion": "smooth"}, progress=False)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "settings",
    [
        PaperSettings(grid=16, steps=4, control=4, max_iter=20, margin=None, align=None),
        NaturalSettings(grid=16, steps=4, max_iter=10, align=None),
    ],
    ids=["paper-box-is-the-picture", "natural-padded-box"],
)
def test_the_fit_is_in_one_frame_and_replays_the_morphs_forward_frames(pair, settings):
    a, b = pair
    steps = settings.steps
    r = morph(a, b, PA, PB, settings=settings, frames=steps + 1, progress=False)  # frame k at fluid step k
    fit = r.fit
    # the fit's error is its last keyframe's, at the last step
    last_step, last_error = fit.keyframe_errors[-1]
    assert last_step == steps
    torch.testing.assert_close(fit.error, last_error)
    # its paths, in the box's pixels, are the result's, in the frames' pixels, moved by the box's corner
    x0, y0, x1, y1 = r.box
    corner = torch.tensor([x0, y0], dtype=r.trajectories.dtype)
    torch.testing.assert_close(fit.trajectories[0].to(r.trajectories.dtype) + corner, r.trajectories)
    torch.testing.assert_close(r.points, r.trajectories[-1])
    # without a pre-alignment the frames' pixels are A's: the result's error is the fit's
    torch.testing.assert_close(r.error, fit.error[0].to(r.error.dtype), atol=1e-5, rtol=0)
    # fit.animate replays the flow on a picture of the box: A, with its edge pixels beyond the picture (what
    # the renderer reads there), gives the morph's forward frames
    H, W = a.shape[-2:]
    in_box = F.pad(a[None], (-x0, x1 - W, -y0, y1 - H), mode="replicate")
    if settings.method == "paper":
        assert r.box == (0, 0, W, H)  # the box is the picture: fit.animate(image_a) itself
        in_box = a[None]
    replay = fit.animate(in_box)[0, :, :, -y0 : -y0 + H, -x0 : -x0 + W]  # (T + 1, C, H, W)
    torch.testing.assert_close(replay, r.forward_frames, atol=1e-5, rtol=0)


def test_the_results_error_is_in_the_last_frames_pixels_with_a_pre_alignment(pair):
    a, _ = pair
    centre = PA.mean(0)
    pb = (PB - centre) * 1.5 + centre  # B's marks spread 1.5 times as far: the pre-alignment magnifies
    settings = PaperSettings(grid=16, steps=4, control=4, max_iter=2, margin=None)  # a few iterations: errors
    r = morph(a, a, PA, pb, settings=settings, frames=2, progress=False)
    want = (r.points - pb.double()).norm(dim=-1)
    torch.testing.assert_close(r.error, want.to(r.error.dtype))
    assert float(r.error.min()) > 0.05
    # the fit's error is in the box's pixels, before the pre-alignment: a similarity of scale s makes the frames'
    # distances s times the box's
    scale = float(torch.linalg.det(r.alignment[:2, :2]).sqrt())
    assert 1.3 < scale < 1.7
    torch.testing.assert_close(r.error, scale * r.fit.error[0].to(r.error.dtype), atol=1e-4, rtol=1e-4)
    assert "in the last frame's pixels" in r.message
