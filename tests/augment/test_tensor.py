import importlib
import math
import warnings

import kornia.augmentation as K
import pytest
import torch
from torch import nn

from torchfluidwarp import augment
from torchfluidwarp.augment import (
    MAX_SHEAR,
    MIN_DET,
    FluidWarpAugment,
    FluidWarpParams,
    brush_forces,
    carry_points,
    fluid_warp_map,
    min_quad_determinant,
    raster_map,
)
from torchfluidwarp.augment import tensor as augment_tensor
from torchfluidwarp.warp.frames import identity_map, jacobian_determinant, warp_image
from torchfluidwarp.warp.layer import FluidWarp

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def _seeded(seed=0, **kwargs):
    return FluidWarpAugment(generator=torch.Generator().manual_seed(seed), **kwargs)


def _strongest(count=4, steps=8, radius=16.0, dt=1.0):
    """The largest strength the module accepts for these settings."""
    return MAX_SHEAR * radius / (count * steps * dt**2 * max(1.0, steps / 4))


def test_reproducible_with_a_generator_and_the_global_rng_untouched():
    image = torch.rand(3, 3, 48, 40, generator=torch.Generator().manual_seed(5))
    state = torch.get_rng_state()
    a, b, c = _seeded(7, grid=16)(image), _seeded(7, grid=16)(image), _seeded(8, grid=16)(image)
    assert torch.equal(torch.get_rng_state(), state)
    assert torch.equal(a, b)
    assert not torch.allclose(a, c)
    assert not torch.allclose(a, image)


def test_one_draw_per_call_serves_every_input():
    image = torch.rand(2, 1, 40, 40, generator=torch.Generator().manual_seed(1))
    out = _seeded(3, grid=16)(image, masks=image)  # the same tensor as image and as mask
    alone = _seeded(3, grid=16)(image)
    assert torch.equal(out["image"], alone)
    coords = fluid_warp_map(_seeded(3, grid=16).make_params(2, (40, 40)))
    assert torch.equal(out["masks"], warp_image(image, coords, "nearest"))
    assert torch.equal(out["image"], warp_image(image, coords))


def test_keypoints_land_on_the_dots_they_marked():
    H = W = 96
    ys, xs = torch.meshgrid(torch.arange(12.0, 90.0, 13.0), torch.arange(12.0, 90.0, 13.0), indexing="ij")
    jitter = torch.rand(xs.numel(), 2, generator=torch.Generator().manual_seed(2)) - 0.5
    pts = (torch.stack([xs, ys], -1).reshape(-1, 2) + jitter).to(torch.float64)  # (M, 2)
    grid = identity_map((H, W), dtype=torch.float64)[0]  # (H, W, 2)
    dots = torch.exp(-((grid[:, :, None] - pts) ** 2).sum(-1) / 2.0).sum(-1)  # sigma = 1 px
    image = dots.expand(2, 1, H, W)
    aug = _seeded(4, count=(3, 4), strength=(0.2, 0.3), radius=(16.0, 24.0), steps=(6, 8), grid=24)
    out = aug(image, keypoints=pts.expand(2, -1, -1))
    moved, warped = out["keypoints"], out["image"]
    assert (moved - pts).norm(dim=-1).max() > 2.0  # the test means something: dots moved
    r = 4
    off = torch.arange(-r, r + 1, dtype=torch.float64)
    for b in range(2):
        for p in moved[b]:
            cx, cy = int(p[0].round()), int(p[1].round())
            win = warped[b, 0, cy - r : cy + r + 1, cx - r : cx + r + 1]
            centroid = torch.stack([(win.sum(0) * (cx + off)).sum(), (win.sum(1) * (cy + off)).sum()]) / win.sum()
            assert (centroid - p).norm() < 0.5, f"dot at {centroid.tolist()}, keypoint at {p.tolist()}"


def test_keypoints_are_carry_points_through_the_same_flow():
    aug = _seeded(0, count=2, strength=0.4, radius=20.0, steps=5, grid=16)
    params = aug.make_params(2, (64, 80))
    pts = torch.tensor([[[10.0, 12.0], [40.0, 30.0], [70.0, 50.0]]]).expand(2, -1, -1)
    forces = brush_forces(
        params.centers, params.directions, params.amplitude, params.radius, grid=16, image_size=(64, 80), steps=5
    )
    expected = FluidWarp(16, 5).carry_points(pts, forces, (64, 80))[:, -1]
    assert torch.equal(params.force_scale, torch.ones(2))
    torch.testing.assert_close(carry_points(params, pts), expected)


@pytest.mark.parametrize("size, grid", [((64, 64), 16), ((224, 224), 32)])
def test_stacked_brushes_at_the_strongest_setting_do_not_fold(size, grid):
    # worst case: every brush of a sample on one spot, pushing the same way, at the bound
    count, steps, radius = 4, 8, 16.0
    strength = _strongest(count, steps, radius)
    B = 4
    g = torch.Generator().manual_seed(3)
    centers = (0.2 + 0.6 * torch.rand(B, 1, 2, generator=g)).mul(torch.tensor([size[1] - 1.0, size[0] - 1.0]))
    angle = 2 * math.pi * torch.rand(B, 1, generator=g)
    directions = torch.stack([angle.cos(), angle.sin()], -1)
    forces = brush_forces(
        centers.expand(B, count, 2),
        directions.expand(B, count, 2),
        torch.full((B, count), strength),
        torch.full((B, count), radius),
        grid=grid,
        image_size=size,
        steps=steps,
    )
    with torch.no_grad():
        vel = FluidWarp(grid, steps).rollout(forces, size).velocities
    coarse = raster_map(vel, size, 1.0)
    params = FluidWarpParams(
        vel,
        torch.full((B,), steps),
        1.0,
        centers,
        directions,
        torch.zeros(B, count),
        torch.full((B, count), radius),
        torch.ones(B),
        size,
        coarse,
        min_quad_determinant(coarse, size),
    )
    maps = fluid_warp_map(params)
    disp = (maps - identity_map(size)).norm(dim=-1)
    assert disp.amax() > 10.0  # a strong push
    assert jacobian_determinant(maps).amin() > 0
    assert params.min_det.amin() >= MIN_DET  # the bound alone suffices here: the fold check would not act


def test_module_at_its_strongest_setting_never_folds():
    aug = _seeded(1, count=4, strength=_strongest(), radius=16.0, steps=8, grid=32)
    params = aug.make_params(8, (128, 128))
    assert jacobian_determinant(fluid_warp_map(params)).amin() > 0


def test_a_map_that_would_fold_is_drawn_again_at_half_force():
    # wide brushes (0.6 of the image) pass the bound but can fold near the walls: the check catches them
    aug = _seeded(0, count=4, strength=_strongest(4, 2, 40.0), radius=40.0, steps=2, grid=32)
    params = aug.make_params(16, (64, 64))
    assert (params.force_scale < 1).any()
    assert params.min_det.amin() >= MIN_DET
    assert jacobian_determinant(fluid_warp_map(params)).amin() > 0


def test_folded_map_is_detected():
    ident = identity_map((8, 8))
    flipped = ident.clone()
    flipped[..., 0] = 7 - flipped[..., 0]
    assert min_quad_determinant(ident, (8, 8)).item() == pytest.approx(1.0)
    assert min_quad_determinant(flipped, (8, 8)).item() == pytest.approx(-1.0)


def test_masks_stay_binary_and_labels_keep_their_values():
    g = torch.Generator().manual_seed(0)
    binary = torch.rand(2, 1, 48, 48, generator=g) > 0.6
    labels = torch.randint(0, 5, (2, 1, 48, 48), generator=g) * 10
    image = torch.rand(2, 3, 48, 48, generator=g)
    out = _seeded(2, grid=16)(image, masks=torch.cat([binary.float(), labels.float()], 1))
    assert set(out["masks"][:, 0].unique().tolist()) <= {0.0, 1.0}
    assert set(out["masks"][:, 1].unique().tolist()) <= {0.0, 10.0, 20.0, 30.0, 40.0}
    out = _seeded(2, grid=16)(image, masks=binary)
    assert out["masks"].dtype == torch.bool and out["masks"].shape == binary.shape


def test_boxes_contain_their_carried_keypoints():
    g = torch.Generator().manual_seed(1)
    B, N, M = 3, 5, 12
    lo = torch.rand(B, N, 2, generator=g) * 40 + 2
    size = 10 + torch.rand(B, N, 2, generator=g) * 20
    boxes = torch.cat([lo, lo + size], -1)  # (B, N, 4) inside 72 x 72
    inner = lo[:, :, None] + torch.rand(B, N, M, 2, generator=g) * size[:, :, None]  # points in each box
    aug = _seeded(6, count=(2, 4), strength=(0.2, 0.35), radius=(12.0, 20.0), steps=(6, 8), grid=24)
    out = aug(torch.rand(B, 1, 72, 72, generator=g), keypoints=inner.reshape(B, -1, 2), boxes=boxes)
    pts = out["keypoints"].view(B, N, M, 2)
    bx = out["boxes"][:, :, None]
    assert (pts - inner).norm(dim=-1).amax() > 1.0
    assert ((pts >= bx[..., :2]) & (pts <= bx[..., 2:])).all()
    assert (out["boxes"][..., :2] >= -0.5).all() and (out["boxes"][..., 2:] <= 71.5).all()


def test_unbatched_integer_and_float64_inputs_follow_their_dtype():
    aug = _seeded(0, grid=16)
    img = (torch.rand(3, 40, 40, generator=torch.Generator().manual_seed(0)) * 255).to(torch.uint8)
    out = aug(img, keypoints=torch.tensor([[10.0, 20.0]]), boxes=torch.tensor([[5.0, 5.0, 20.0, 30.0]]))
    assert out["image"].dtype == torch.uint8 and out["image"].shape == (3, 40, 40)
    assert out["keypoints"].shape == (1, 2) and out["boxes"].shape == (1, 4)
    assert aug(torch.rand(2, 1, 32, 32, dtype=torch.float64)).dtype == torch.float64


def test_works_in_a_sequential_with_kornia():
    pipe = nn.Sequential(K.RandomHorizontalFlip(p=1.0), _seeded(0, grid=16))
    image = torch.rand(2, 3, 32, 32)
    assert pipe(image).shape == (2, 3, 32, 32)


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"strength": 10.0}, "strength"),
        ({"count": (3, 2)}, "count"),
        ({"radius": 0.0}, "radius"),
        ({"steps": (0, 4)}, "steps"),
        ({"strength": (-1.0, 0.1)}, "strength"),
        ({"count": 1.5}, "count"),
    ],
)
def test_bad_settings_are_refused_by_name(kwargs, word):
    with pytest.raises((ValueError, TypeError), match=word):
        FluidWarpAugment(**kwargs)


def test_mismatched_inputs_are_refused():
    aug = _seeded(0, grid=16)
    with pytest.raises(ValueError, match="keypoints"):
        aug(torch.rand(2, 1, 16, 16), keypoints=torch.zeros(3, 1, 2))
    with pytest.raises(ValueError, match="masks"):
        aug(torch.rand(2, 1, 16, 16), masks=torch.zeros(2, 1, 8, 8))
    with pytest.raises(ValueError, match="boxes"):
        aug(torch.rand(1, 1, 16, 16), boxes=torch.zeros(1, 2, 3))


@pytest.mark.parametrize(
    "name,home",
    [
        *[(n, "settings") for n in ["MAX_SHEAR", "RangeArg"]],
        *[(n, "draw") for n in ["MIN_DET", "brush_forces", "min_quad_determinant", "raster_map"]],
        *[(n, "carry") for n in ["fluid_warp_map", "carry_points", "carry_boxes", "box_outline", "polygon_outline"]],
    ],
)
def test_a_name_moved_out_of_tensor_has_one_home(name, home):
    module = importlib.import_module(f"torchfluidwarp.augment.{home}")
    assert not hasattr(augment_tensor, name)
    assert getattr(augment, name, getattr(module, name)) is getattr(module, name)
    with pytest.raises(AttributeError, match="no_such_name"):
        augment_tensor.no_such_name  # noqa: B018


@pytest.mark.parametrize("name", ["RandomFluidWarp", "RandomFluidWarpV2"])
def test_the_old_aliases_of_the_augmentations_are_gone(name):
    with pytest.raises(AttributeError, match=name):
        getattr(augment, name)


def test_brushes_narrower_than_a_fluid_cell_warn_that_the_warp_is_faint():
    # a 910 x 1137 phone photograph on the default 32 x 32 cells: a cell is 36 px, wider than the default radius
    # (16 to 48 px, 32 on average); the fluid smooths such pushes away, and the warp is faint: it says so
    image = torch.rand(1, 3, 1137, 910, generator=torch.Generator().manual_seed(0))
    augment = FluidWarpAugment(count=1, steps=4, generator=torch.Generator().manual_seed(1))
    with pytest.warns(RuntimeWarning, match=r"radius, 32 px on average, is under a fluid cell \(35.5 px on a 910 x"):
        augment(image)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the same at 512 px (16 px cells), or radii of a cell, say nothing
        augment(image[..., :512, :512])
        FluidWarpAugment(count=1, steps=4, radius=(30.0, 50.0))(image)
