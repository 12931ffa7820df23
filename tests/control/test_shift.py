"""The best plain shift (control.alignment.best_shift), and fit_images' warning when a shift beats its flow (#32:
no default returns a map farther from the truth than no motion without saying so)."""

import warnings

import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.control import best_shift, fit_images, mse_loss
from torchfluidwarp.control.images import shift_rivals
from torchfluidwarp.errors import InputError, InputTypeError
from torchfluidwarp.warp.forces import Brushes
from torchfluidwarp.warp.frames import identity_map, warp_image
from torchfluidwarp.warp.layer import FluidWarp

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def _texture(gen: torch.Generator, h: int, w: int) -> torch.Tensor:
    """A smooth random texture ``(1, 3, h, w)`` float64: noise blurred over about 4 pixels."""
    noise = torch.rand(1, 3, h // 4 + 2, w // 4 + 2, generator=gen, dtype=torch.float64)
    return F.interpolate(noise, size=(h, w), mode="bicubic", align_corners=False).clamp(0, 1)


def _shifted(image: torch.Tensor, dx: float, dy: float) -> torch.Tensor:
    """``image`` read at ``x + dx`` (its content moves by ``-dx``), border padding."""
    ident = identity_map(tuple(image.shape[-2:]), dtype=image.dtype)
    return warp_image(image, ident + ident.new_tensor([dx, dy]))


@pytest.mark.parametrize(
    "size, shift, tol", [((96, 128), (7, -5), 0), ((96, 128), (-20, 11), 0), ((420, 600), (40, 0), 3)]
)
def test_best_shift_finds_a_known_shift(gen, size, shift, tol):
    source = _texture(gen, *size)
    target = _shifted(source, *shift)  # source read at x + shift is the target
    found, value = best_shift(source, target, mse_loss)
    assert (found - torch.tensor(shift, dtype=found.dtype)).abs().max() <= tol, found
    assert value <= float(mse_loss(_shifted(source, *found.tolist()), target)) + 1e-12
    assert value < 0.2 * float(mse_loss(source, target))  # the border padding leaves a strip unmatched, no more


def test_best_shift_of_a_picture_against_itself_is_zero(gen):
    source = _texture(gen, 64, 80)
    found, value = best_shift(source, source.clone(), mse_loss)
    assert found.tolist() == [0.0, 0.0] and value == pytest.approx(0.0, abs=1e-20)


@pytest.mark.parametrize("candidates, error", [(0, InputError), (2.5, InputTypeError), (True, InputTypeError)])
def test_best_shift_names_a_bad_candidates(gen, candidates, error):
    source = _texture(gen, 32, 32)
    with pytest.raises(error, match="candidates") as caught:
        best_shift(source, source, mse_loss, candidates=candidates)
    assert caught.value.argument == "candidates"


def _epe(fit, shift: tuple[float, float], size: tuple[int, int]) -> tuple[float, float]:
    """Mean end-point error of the fit's last map and of no motion against the true map ``identity + shift``, over
    the pixels whose true source lies inside the picture."""
    with torch.no_grad():
        last = fit.warp.maps(fit.forces, size)[0, -1].double()
    ident = identity_map(size, dtype=torch.float64)[0]
    truth = ident + ident.new_tensor(shift)
    inside = (
        (truth[..., 0] >= 0) & (truth[..., 0] <= size[1] - 1) & (truth[..., 1] >= 0) & (truth[..., 1] <= size[0] - 1)
    )
    return float((last - truth).norm(dim=-1)[inside].mean()), float((ident - truth).norm(dim=-1)[inside].mean())


PAPER = {"loss": "mse", "compressible": False}
"""The paper's incompressible fluid and the MSE: ``fit_images``' defaults until the eighth session, and the closed
box that cannot carry a shift."""


def _fit(source, target, **settings):
    """``fit_images`` on a 32 x 32 fluid with ``settings`` (its defaults where none are given), and the warnings
    that a plain shift rivals it."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = fit_images(source, target, grid=32, levels=(16,), steps=6, max_iter=(15, 15), progress=False, **settings)
    return fit, [str(w.message) for w in caught if "moving source's content" in str(w.message)]


def test_a_fit_that_misses_a_large_shift_says_so(gen):
    # a quarter of the picture's width: the closed, incompressible box cannot carry it, the fit settles on a swirl
    size, shift = (64, 64), (16.0, 0.0)
    source = _texture(gen, *size)
    target = _shifted(source, *shift)
    fit, said = _fit(source, target, **PAPER)
    fitted, none = _epe(fit, shift, size)
    assert fitted > 0.5 * none, (fitted, none)  # the flow did not find the motion (the case this test is about)
    assert fit.final_loss > 0.1 * fit.initial_loss
    assert len(said) == 1 and "content by (-16, +0) px" in said[0], said  # target is source moved 16 px left


@pytest.mark.parametrize("shift", [(4.0, -3.0), (-6.0, 2.0), (8.0, 0.0), (16.0, 0.0)])
def test_the_defaults_never_end_farther_than_no_motion_in_silence(gen, shift):
    # fit_images' own loss and fluid (the local correlation, compressible): a shift of up to a quarter of the
    # picture, which a closed box can carry only in part; wherever the map is not closer to the truth than no
    # motion, the fit says so
    size = (64, 64)
    source = _texture(gen, *size)
    target = _shifted(source, *shift)
    fit, said = _fit(source, target)
    fitted, none = _epe(fit, shift, size)
    assert fitted < none or said, (fitted, none)
    if shift == (4.0, -3.0):  # a shift of 5 px: the compressible fluid carries it (the incompressible one ends
        assert fitted < 0.6 * none, (fitted, none)  # 6.6 px off, farther than no motion, 5 px)


def test_a_fit_that_finds_the_motion_does_not_warn(gen):
    # a warp the fluid itself made: the fit finds it, and no plain shift comes near
    source = _texture(gen, 64, 64)
    brushes = Brushes([[24.0, 30.0], [44.0, 36.0]], [[1.0, 0.3], [-0.2, -1.0]], radius=9.0, amplitude=0.3).double()
    with torch.no_grad():
        target = FluidWarp(32, 6).double()(source, brushes)[:, -1]
    fit, said = _fit(source, target, **PAPER)
    assert fit.final_loss < 0.1 * fit.initial_loss, fit.message
    assert said == []


def test_pictures_that_no_shift_relates_do_not_warn(gen):
    # two unrelated textures: the best shift barely moves the loss, so it says nothing about a poor fit
    source, target = _texture(gen, 64, 64), _texture(gen, 64, 64)
    fit, said = _fit(source, target, **PAPER)
    _, by_shift = best_shift(source, target, mse_loss)
    assert by_shift > 0.75 * fit.initial_loss and fit.final_loss > 0.1 * fit.initial_loss  # the case this is about
    assert said == []


@pytest.mark.parametrize(
    "shift, by_shift, final, initial, size, rivals",
    [
        ((49.0, 0.0), 0.03444, 0.03189, 0.05433, (500, 741), True),  # the stereo motorcycle, the old defaults
        ((16.0, 0.0), 0.020, 0.030, 0.100, (64, 64), True),  # a quarter of the picture out: still a motion
        ((-269.0, -66.0), 0.5137, 0.3561, 0.8491, (354, 709), False),  # two plain masks: half out, worse
        ((30.0, 0.0), 0.040, 0.030, 0.100, (64, 64), False),  # 47% out of the frame, worse than the fit
        ((30.0, 0.0), 0.020, 0.030, 0.100, (64, 64), True),  # 47% out, but beating the fit outright
        ((1.0, 1.0), 0.020, 0.030, 0.100, (64, 64), False),  # under 2 pixels
        ((8.0, 0.0), 0.060, 0.030, 0.100, (64, 64), False),  # twice the fit's loss
        ((8.0, 0.0), 0.040, 0.030, 0.050, (64, 64), False),  # removes a fifth of the mismatch only
    ],
)
def test_a_shift_rivals_the_fit_only_when_it_is_a_plausible_motion(shift, by_shift, final, initial, size, rivals):
    assert shift_rivals(torch.tensor(shift), by_shift, final, initial, size) is rivals
