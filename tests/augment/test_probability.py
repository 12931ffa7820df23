"""``p``: the probability that a sample is warped, for the tensor-level module (per sample of a batch) and for
the torchvision v2 transform (per call), like torchvision's random transforms."""

from __future__ import annotations

import math

import pytest
import torch
from torchvision import tv_tensors
from torchvision.transforms import v2

from torchfluidwarp.augment import FluidWarpAugment, random_fluid_warp
from torchfluidwarp.augment.transforms import RandomFluidWarp

S = 16  # image side, pixels
SETTINGS = {"count": 1, "strength": (0.3, 0.5), "radius": (4.0, 6.0), "steps": (2, 3), "grid": 8}
"""Small and quick, strong enough that every warp moves every image, too gentle to fold (no retries)."""

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def _gen(seed=0):
    return torch.Generator().manual_seed(seed)


def _batch(n, seed=1):
    """``n`` images, a keypoint, a mask and a box per sample."""
    g = _gen(seed)
    image = torch.rand(n, 3, S, S, generator=g)
    keypoints = 3.0 + torch.rand(n, 2, 2, generator=g) * (S - 6)
    masks = (torch.rand(n, 1, S, S, generator=g) > 0.5).to(torch.uint8)
    boxes = torch.tensor([[[3.0, 4.0, 11.0, 12.0]]]).expand(n, -1, -1).contiguous()
    return image, {"keypoints": keypoints, "masks": masks, "boxes": boxes}


def _moved(out, image):
    """Per sample ``(B,)``: whether its image changed."""
    return (out - image).flatten(1).abs().amax(1) > 0


def test_p_zero_returns_the_inputs_themselves():
    image, extra = _batch(4)
    aug = FluidWarpAugment(p=0.0, generator=_gen(), **SETTINGS)
    one = image[0]  # unbatched
    assert aug(image) is image and aug(one) is one
    out = aug(image, **extra)
    assert isinstance(out, dict) and out["image"] is image
    assert all(out[k] is v for k, v in extra.items())
    assert random_fluid_warp(image, p=0.0, **SETTINGS) is image


def test_p_one_warps_every_sample_and_draws_nothing_for_it():
    image, extra = _batch(8)
    out = FluidWarpAugment(p=1.0, generator=_gen(3), **SETTINGS)(image, **extra)
    assert isinstance(out, dict) and bool(_moved(out["image"], image).all())
    assert bool(((out["keypoints"] - extra["keypoints"]).abs().flatten(1).amax(1) > 0).all())
    default = FluidWarpAugment(generator=_gen(3), **SETTINGS)(image, **extra)  # p=1 is the default
    assert isinstance(default, dict)
    for key, value in out.items():
        assert torch.equal(value, default[key]), key


@pytest.mark.parametrize("p", [0.25, 0.7])
def test_each_sample_of_a_batch_is_warped_with_probability_p(p):
    n = 200
    image, extra = _batch(n)
    out = FluidWarpAugment(p=p, generator=_gen(5), **SETTINGS)(image, **extra)
    assert isinstance(out, dict)
    moved = _moved(out["image"], image)
    # binomial: within 4 standard deviations of n p, for this seed and every reasonable one
    assert abs(int(moved.sum()) - n * p) < 4 * math.sqrt(n * p * (1 - p))
    kept = ~moved
    for key in ("keypoints", "masks", "boxes"):  # a sample's inputs follow its image, all or none
        assert torch.equal(out[key][kept], extra[key][kept]), key
        assert out[key].dtype == extra[key].dtype
    assert bool(((out["keypoints"] - extra["keypoints"])[moved].abs().flatten(1).amax(1) > 0).all())


def test_the_chosen_samples_are_rolled_out_together_and_reproduced_by_a_seed():
    image, _ = _batch(40)
    aug = FluidWarpAugment(p=0.5, generator=_gen(7), **SETTINGS)
    batches = []
    aug.simulator.register_forward_hook(lambda module, args, out: batches.append(out.velocities.shape[0]))
    first = aug(image)
    moved = _moved(first, image)
    assert batches == [int(moved.sum())]  # one roll-out, of the chosen samples only
    again = FluidWarpAugment(p=0.5, generator=_gen(7), **SETTINGS)(image)
    assert torch.equal(first, again)


def test_the_v2_transform_warps_about_p_of_its_calls_and_passes_the_others_through():
    t = RandomFluidWarp(p=0.4, generator=_gen(11), **SETTINGS)
    image = tv_tensors.Image(torch.rand(3, S, S, generator=_gen(2)))
    box = tv_tensors.BoundingBoxes([[3, 4, 11, 12]], format="XYXY", canvas_size=(S, S))
    calls, warped = 60, 0
    for _ in range(calls):
        sample = {"image": image, "boxes": box, "label": 3}
        out = t(sample)
        assert type(out["image"]) is tv_tensors.Image and out["label"] == 3
        if torch.equal(out["image"], image):
            assert out["image"] is image and out["boxes"] is box  # passed through, not copied
        else:
            warped += 1
    assert abs(warped - calls * 0.4) < 4 * math.sqrt(calls * 0.4 * 0.6)


def test_the_v2_transform_at_p_zero_in_a_pipeline():
    pipe = v2.Compose([RandomFluidWarp(p=0.0, **SETTINGS), v2.ToDtype(torch.float32, scale=True)])
    image = tv_tensors.Image((torch.rand(3, S, S, generator=_gen(4)) * 255).to(torch.uint8))
    out = pipe({"image": image, "label": 1})
    assert type(out["image"]) is tv_tensors.Image
    assert torch.equal(out["image"], v2.ToDtype(torch.float32, scale=True)(image))


@pytest.mark.parametrize("entry", [FluidWarpAugment, RandomFluidWarp])
def test_p_is_checked_named_and_shown(entry):
    for bad in (1.5, -0.1, float("nan")):
        with pytest.raises(ValueError, match="p must be in"):
            entry(p=bad)
    with pytest.raises(TypeError, match="p must be"):
        entry(p="0.5")
    assert entry(p=0.3).p == 0.3 and "p=0.3" in repr(entry(p=0.3))
    assert "p=" not in repr(entry())
