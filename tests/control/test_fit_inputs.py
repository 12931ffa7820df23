"""fit_keyframes and fit_images refuse bad input by name before any work (#19)."""

from __future__ import annotations

import pytest
import torch

from torchfluidwarp import fit_images, fit_keyframes

SRC = torch.tensor([[4.0, 4.0], [11.0, 9.0], [6.0, 12.0]])
SMALL = {"image_size": (16, 16), "grid": 8, "steps": 2, "control": 2, "max_iter": 1, "progress": False}


def image() -> torch.Tensor:
    return torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0))


IMAGES = {"grid": 8, "levels": None, "steps": 2, "control": 2, "max_iter": 1, "progress": False}


@pytest.mark.parametrize("dtype", ["float32", torch.complex64, torch.int64, None])
def test_a_dtype_that_is_not_a_float_dtype_is_refused_by_name(dtype):
    with pytest.raises(TypeError, match="dtype must be"):
        fit_keyframes(SRC, SRC + 1, dtype=dtype, **SMALL)
    with pytest.raises(TypeError, match="dtype must be"):
        fit_images(image(), image(), dtype=dtype, **IMAGES)


def test_half_precision_fits_run_in_float32():
    fit = fit_keyframes(SRC, SRC + 1, dtype=torch.float16, **SMALL)
    assert fit.points.dtype == torch.float32 and fit.points.isfinite().all()


@pytest.mark.parametrize("target", [None, "x", 3])
def test_a_target_of_the_wrong_type_is_named(target):
    with pytest.raises(TypeError, match="target must be a tensor of points or a list"):
        fit_keyframes(SRC, target, **SMALL)


def test_forces_that_are_not_a_module_are_named():
    with pytest.raises(TypeError, match="forces must be a Module or None"):
        fit_keyframes(SRC, SRC + 1, forces="x", **SMALL)


@pytest.mark.parametrize("compressible", ["yes", None, 2])
def test_compressible_is_checked_by_name(compressible):
    with pytest.raises((TypeError, ValueError), match="compressible"):
        fit_keyframes(SRC, SRC + 1, compressible=compressible, **SMALL)
    with pytest.raises((TypeError, ValueError), match="compressible"):
        fit_images(image(), image(), compressible=compressible, **IMAGES)


def test_huge_integer_settings_are_refused_or_used_as_floats():
    with pytest.raises(ValueError, match="smoothness"):
        fit_keyframes(SRC, SRC + 1, smoothness=10**400, **SMALL)
    fit = fit_keyframes(SRC, SRC + 1, smoothness=10**30, **SMALL)  # used to overflow inside the loss
    assert fit.points.isfinite().all()


def test_a_fit_beyond_max_memory_is_refused_before_any_work():
    with pytest.raises(ValueError, match=r"fit_keyframes over 1000000000 steps .* max_memory"):
        fit_keyframes(SRC, SRC + 1, **{**SMALL, "steps": 10**9})
    with pytest.raises(ValueError, match="fit_images .* max_memory"):
        fit_images(image(), image(), **{**IMAGES, "steps": 10**9})
    with pytest.raises(ValueError, match="max_memory"):
        fit_keyframes(SRC, SRC + 1, max_memory=1000, **SMALL)


def test_max_iter_that_is_not_an_int_is_named():
    with pytest.raises(TypeError, match="max_iter"):
        fit_images(image(), image(), **{**IMAGES, "max_iter": float("inf")})


def test_a_loss_that_is_nan_gives_a_value_error_not_nan_losses():
    def nan_loss(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return (x - y).pow(2).mean() * float("nan")

    with pytest.raises(ValueError, match="loss must be finite"):
        fit_images(image(), image().roll(1, -1), loss=nan_loss, **IMAGES)


def test_a_control_grid_beyond_max_memory_is_refused_before_any_work():
    with pytest.raises(ValueError, match="fit_keyframes .* control 1000000 x 1000000.*max_memory"):
        fit_keyframes(SRC, SRC + 1, **{**SMALL, "control": 10**6})
    with pytest.raises(ValueError, match="fit_images .* control 1000000 x 1000000.*max_memory"):
        fit_images(image(), image(), **{**IMAGES, "control": 10**6})
