"""The warp layer and the maps refuse bad input by name, bound their work, and follow the dtype policy (#19)."""

from __future__ import annotations

import pytest
import torch

from torchfluidwarp import FluidWarp, jacobian_determinant, warp_image
from torchfluidwarp.errors import FlowBlewUp
from torchfluidwarp.warp.frames import identity_map
from torchfluidwarp.warp.maps import MapConfig, backward_maps, forward_maps


def forces(*shape: int) -> torch.Tensor:
    return torch.randn(*shape, generator=torch.Generator().manual_seed(0)) * 0.1


def test_huge_forces_are_refused_at_the_first_step_instead_of_running_for_minutes():
    warp = FluidWarp(8, 2)
    with pytest.raises(FlowBlewUp, match="max_substeps"):
        warp(torch.rand(1, 3, 12, 12), forces(1, 2, 2, 8, 8) * 1e6)
    with pytest.raises(FlowBlewUp, match="max_substeps"):
        warp.carry_points(torch.full((1, 1, 2), 5.0), forces(1, 2, 2, 8, 8) * 1e6, (12, 12))


def test_map_config_max_substeps_reaches_maps_and_points():
    f = forces(1, 2, 2, 8, 8) * 10
    tight = FluidWarp(8, 2, map_config=MapConfig(max_substeps=1))
    with pytest.raises(FlowBlewUp, match="limit of 1"):
        tight.maps(f, (12, 12))
    with pytest.raises(FlowBlewUp, match="limit of 1"):
        tight.carry_points(torch.full((1, 1, 2), 5.0), f, (12, 12))
    assert FluidWarp(8, 2).maps(f, (12, 12)).isfinite().all()
    with pytest.raises(TypeError, match="max_substeps"):
        MapConfig(max_substeps=0.5)  # type: ignore[arg-type]


def test_maps_beyond_max_memory_are_refused_before_any_work():
    vel = torch.zeros(1, 2, 2, 9, 9)
    with pytest.raises(ValueError, match=r"size \(1000000, 1000000\).*MapConfig\(max_memory=...\)"):
        backward_maps(vel, (10**6, 10**6))
    with pytest.raises(ValueError, match="max_memory"):
        forward_maps(vel, (64, 64), config=MapConfig(max_memory=1000))
    assert forward_maps(vel, (8, 8), config=MapConfig(max_memory=10**6)).shape == (1, 3, 8, 8, 2)


def test_steps_that_do_not_match_the_forces_are_named():
    with pytest.raises(ValueError, match=r"steps=1000000000 on the grid of 4 x 4 cells"):
        FluidWarp(4, 10**9).maps(torch.zeros(1, 2, 2, 4, 4), (8, 8))


def test_carry_points_promotes_half_precision_forces():
    f = forces(1, 2, 2, 8, 8)
    pts = torch.tensor([[[3.0, 4.0], [7.5, 2.0]]])
    half = FluidWarp(8, 2).carry_points(pts, f.half(), (12, 12))
    full = FluidWarp(8, 2).carry_points(pts, f.half().float(), (12, 12))
    assert half.dtype == torch.float32
    torch.testing.assert_close(half, full, atol=1e-2, rtol=1e-2)


@pytest.mark.parametrize("compressible", ["yes", None, 1.5])
def test_compressible_is_checked_by_name(compressible):
    with pytest.raises((TypeError, ValueError), match="compressible"):
        FluidWarp(8, 2, compressible=compressible)


def test_warp_image_names_the_image_when_it_is_empty_or_its_batch_differs():
    coords = identity_map((6, 5)).expand(2, -1, -1, -1)
    with pytest.raises(ValueError, match="image"):
        warp_image(torch.rand(2, 3, 6, 0), coords)
    with pytest.raises(ValueError, match="image .* batch of coords"):
        warp_image(torch.rand(0, 3, 6, 5), coords)
    assert warp_image(torch.rand(2, 3, 6, 5), coords).shape == (2, 3, 6, 5)


def test_jacobian_determinant_refuses_coordinates_whose_products_overflow():
    coords = identity_map((5, 5))
    with pytest.raises(ValueError, match="coords are too large"):
        jacobian_determinant(coords * 1e30)
    torch.testing.assert_close(jacobian_determinant(coords * 3), torch.full((1, 5, 5), 9.0))


def test_a_roll_out_beyond_max_memory_is_refused_before_the_force_module_runs():
    calls = []

    def module(*args: object) -> torch.Tensor:
        calls.append(args)
        return torch.zeros(1, 10**9, 2, 4, 4)

    with pytest.raises(ValueError, match=r"roll-out of steps=1000000000 .* MapConfig\(max_memory=...\)"):
        FluidWarp(4, 10**9).maps(module, (8, 8))
    with pytest.raises(ValueError, match=r"grid of 100000 x 100000 cells"):
        FluidWarp(10**5, 3).maps(module, (8, 8))
    assert not calls


@pytest.mark.parametrize("shape", [(0, 3, 12, 12), (1, 3, 12, 0)])
def test_an_empty_image_is_named_by_forward_and_iter_frames(shape):
    warp = FluidWarp(8, 2)
    with pytest.raises(ValueError, match="image must have B, H and W >= 1"):
        warp(torch.rand(shape), forces(1, 2, 2, 8, 8))
    with pytest.raises(ValueError, match="image must have B, H and W >= 1"):
        list(warp.iter_frames(torch.rand(shape), forces(1, 2, 2, 8, 8)))


@pytest.mark.parametrize("path", ["forward", "iter_frames"])
def test_velocities_that_overflow_are_refused_naming_the_forces_and_dt(path):
    # found by the fuzz suite (seed 4): dt = 1e30 overflowed float32, and the error named internal velocities
    gen = torch.Generator().manual_seed(0)
    forces = torch.rand(1, 2, 2, 6, 6, generator=gen).half()  # half forces: the roll-out overflows
    image = torch.rand(1, 3, 9, 22, generator=gen)
    with pytest.raises(ValueError, match=r"forces overflowed .* dt 1e\+30"):
        out = getattr(FluidWarp(6, 2, dt=1e30), path)(image, forces)
        list(out) if path == "iter_frames" else out


def test_a_models_feature_map_of_many_channels_over_a_few_pixels_is_warped_not_taken_for_channels_last():
    # (B, 256, 4, 4) looks like pictures with their channels last to the morph's check (tests/test_checks.py); the
    # warp layer takes any
    # (B, C, H, W), so zero forces give the map back (up to grid_sample's round-off)
    features = torch.rand(2, 256, 4, 4, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(warp_image(features, identity_map((4, 4)).expand(2, 4, 4, 2)), features)
    frames = FluidWarp((4, 4), steps=2)(features, torch.zeros(2, 2, 2, 4, 4))
    torch.testing.assert_close(frames[:, -1], features, atol=1e-5, rtol=0)
