"""The augmentations refuse tiny images and oversized draws by name (#19)."""

from __future__ import annotations

import pytest
import torch

import torchfluidwarp
from torchfluidwarp.augment import FluidWarpAugment, FluidWarpSettings, random_fluid_warp

SMALL = {"grid": 4, "steps": (1, 2), "radius": (2.0, 4.0), "strength": (0.1, 0.2)}


@pytest.mark.parametrize("shape", [(3, 1, 1), (2, 3, 1, 5), (3, 4, 1)])
def test_an_image_below_two_by_two_pixels_is_refused_by_name(shape):
    with pytest.raises(ValueError, match="image must be .*at least 2 x 2 pixels"):
        random_fluid_warp(torch.rand(shape), **SMALL)


def test_the_v2_transform_refuses_a_one_pixel_image_by_name():
    from torchvision import tv_tensors

    with pytest.raises(ValueError, match="image must be .*at least 2 x 2 pixels"):
        torchfluidwarp.RandomFluidWarp(**SMALL)(tv_tensors.Image(torch.rand(3, 1, 1)))


def test_the_v2_transform_keeps_a_mask_without_objects():
    from torchvision import tv_tensors

    sample = {"image": tv_tensors.Image(torch.rand(3, 12, 12)), "mask": tv_tensors.Mask(torch.zeros(0, 12, 12))}
    out = torchfluidwarp.RandomFluidWarp(**SMALL, generator=torch.Generator().manual_seed(0))(sample)
    assert out["mask"].shape == (0, 12, 12) and isinstance(out["mask"], tv_tensors.Mask)


def test_a_draw_beyond_max_memory_is_refused_before_any_work():
    with pytest.raises(ValueError, match=r"grid of 1000000 x 1000000 cells .* max_memory \(FluidWarpSettings\)"):
        random_fluid_warp(torch.rand(3, 8, 8), **{**SMALL, "grid": 10**6})
    with pytest.raises(ValueError, match="max_memory"):
        FluidWarpAugment(**SMALL, max_memory=100)(torch.rand(3, 8, 8))
    with pytest.raises(ValueError, match="max_memory"):
        FluidWarpSettings(max_memory=-1.0)
    out = FluidWarpAugment(**SMALL, max_memory=10**7)(torch.rand(3, 8, 8))
    assert out.shape == (3, 8, 8)


def test_keypoints_with_the_wrong_rank_name_the_image_they_go_with():
    with pytest.raises(ValueError, match=r"keypoints must have 2 dimensions to go with an image of shape \(3, 8, 8\)"):
        random_fluid_warp(torch.rand(3, 8, 8), keypoints=torch.zeros(1, 4, 2), **SMALL)


def test_complex_images_and_masks_and_empty_images_are_refused_by_name():
    with pytest.raises(ValueError, match="image must be real"):
        random_fluid_warp(torch.rand(3, 8, 8, dtype=torch.complex64), **SMALL)
    with pytest.raises(TypeError, match="masks must be real"):
        random_fluid_warp(torch.rand(3, 8, 8), masks=torch.zeros(1, 8, 8, dtype=torch.complex64), **SMALL)
    with pytest.raises(ValueError, match=r"image must be real, non-empty and at least 2 x 2 .* \(2, 3, 8, 0\)"):
        random_fluid_warp(torch.rand(2, 3, 8, 0), masks=torch.zeros(2, 1, 8, 8), **SMALL)


def test_edge_points_beyond_the_limit_are_refused_before_any_work():
    with pytest.raises(ValueError, match="edge_points must be at most 1024, got 1000000000"):
        FluidWarpSettings(edge_points=10**9)


def test_the_v2_transform_names_the_sample_when_torchvision_cannot_size_it():
    from torchvision import tv_tensors

    sample = {"image": tv_tensors.Image(torch.rand(3, 8, 8)), "mask": tv_tensors.Mask(torch.tensor(0.5))}
    with pytest.raises(TypeError, match="sample: "):
        torchfluidwarp.RandomFluidWarp(**SMALL)(sample)


def test_an_empty_batch_names_the_image_not_the_keypoints():
    with pytest.raises(ValueError, match="image must be real, non-empty"):
        random_fluid_warp(torch.rand(0, 3, 8, 8), keypoints=torch.zeros(2, 3, 2), **SMALL)


@pytest.mark.parametrize("name,value", [("keypoints", torch.rand(2, 4, 2)), ("boxes", torch.rand(2, 1, 4))])
def test_a_batch_that_does_not_match_the_images_names_both(name, value):
    # found by the fuzz suite (seed 3): an image of batch 4 with keypoints of batch 2
    with pytest.raises(ValueError, match=rf"{name} has a batch of 2 but image has 4"):
        random_fluid_warp(torch.rand(4, 1, 19, 24), **{name: value})


def test_a_brush_count_beyond_memory_is_refused_before_drawing():
    # found by the fuzz suite (seed 4): count=10**9 with a huge radius passes the shear bound and used to hang
    with pytest.raises(ValueError, match=r"count=1000000000 brushes .* above the limit"):
        random_fluid_warp(torch.rand(1, 1, 14, 16), count=(1, 10**9), radius=(1e30, 1e30), grid=6)
