"""The one guarded ``grid_sample`` (:mod:`torchfluidwarp.core.sampling`), and non-finite input at every public
entry point.

Each case puts one NaN or infinity into one tensor argument (or a time step) of a public entry point and
expects a ``ValueError`` that names that argument: never a crash, never a non-finite or garbage result.
"""

from __future__ import annotations

import pathlib
import re
from collections.abc import Callable
from typing import Any

import pytest
import torch
from torchvision import tv_tensors  # the [vision] extra, which [test] pulls in

import torchfluidwarp as tfw
from torchfluidwarp.augment.tensor import FluidWarpAugment as RandomFluidWarp
from torchfluidwarp.augment.transforms import RandomFluidWarp as RandomFluidWarpV2
from torchfluidwarp.control.images import fit_images
from torchfluidwarp.core import advection, sampling
from torchfluidwarp.core.staggered import StaggeredGrid
from torchfluidwarp.errors import FlowBlewUp
from torchfluidwarp.morph import NaturalSettings
from torchfluidwarp.warp import maps
from torchfluidwarp.warp.frames import identity_map

BAD = {"nan": float("nan"), "inf": float("inf"), "-inf": float("-inf")}
PACKAGE = pathlib.Path(tfw.__file__).parent


def test_sample_is_the_only_call_to_grid_sample():
    calls = {
        str(path.relative_to(PACKAGE)): len(re.findall(r"\bgrid_sample\(", path.read_text()))
        for path in PACKAGE.rglob("*.py")
    }
    assert {name: n for name, n in calls.items() if n} == {"core/sampling.py": 1}


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("align_corners", [False, True])
def test_sample_refuses_a_non_finite_grid_naming_what_was_sampled(bad: str, align_corners: bool):
    grid = torch.zeros(1, 3, 3, 2)
    grid[0, 1, 2, 0] = BAD[bad]
    with pytest.raises(ValueError, match=r"non-finite sampling positions \(NaN or inf\) from coords"):
        sampling.sample(torch.rand(1, 1, 4, 4), grid, align_corners=align_corners, check="coords")


def test_sample_matches_grid_sample_with_border_padding():
    g = torch.Generator().manual_seed(0)
    image = torch.rand(2, 3, 5, 7, generator=g, dtype=torch.float64)
    grid = 3 * torch.rand(2, 4, 6, 2, generator=g, dtype=torch.float64) - 1.5  # beyond [-1, 1]: the border
    for mode in ("bilinear", "bicubic", "nearest"):
        want = torch.nn.functional.grid_sample(image, grid, mode=mode, padding_mode="border", align_corners=False)
        got = sampling.sample(image, grid, mode=mode, align_corners=False, check="grid")
        torch.testing.assert_close(got, want, rtol=0, atol=0)


def test_sample_checks_nothing_when_told_the_grid_is_finite():
    # the per-sub-step paths pass check=None: no reduction, no error (their inputs were checked upstream)
    grid = torch.zeros(1, 1, 1, 2)
    out = sampling.sample(torch.ones(1, 1, 2, 2), grid, align_corners=True, check=None)
    assert out.item() == 1.0


# --- every public entry point, one bad value in one argument at a time ----------------------------------------

H = W = 12  # image pixels
G = 8  # fluid cells
T = 2  # steps


def _inputs() -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    forces = 0.05 * torch.randn(1, T, 2, G, G, generator=g)
    return {
        "image": torch.rand(1, 3, H, W, generator=g),
        "forces": forces,
        "points": 2 + 6 * torch.rand(1, 4, 2, generator=g),
        "velocity": tfw.FluidSimulator(G)(forces).velocities[:, -1],
        "velocities": tfw.FluidSimulator(G)(forces).velocities,
        "quantity": torch.rand(1, 2, G, G, generator=g),
        "coords": identity_map((H, W)) + 0.3,
        "viscosity": torch.full((1, 1, G, G), 0.1),
        "source": torch.tensor([[3.0, 4.0], [8.0, 7.0]]),
        "target": torch.tensor([[4.0, 4.5], [8.5, 6.0]]),
        "keypoints": torch.tensor([[[3.0, 4.0], [8.0, 7.0]]]),
        "boxes": torch.tensor([[[2.0, 2.0, 8.0, 9.0]]]),
        "masks": (torch.rand(1, 1, H, W, generator=g) > 0.5).float(),
        "source_image": torch.rand(1, 3, H, W, generator=g),
        "target_image": torch.rand(1, 3, H, W, generator=g),
        "image_a": torch.rand(3, H, W, generator=g),
        "image_b": torch.rand(3, H, W, generator=g),
        "points_a": torch.tensor([[3.0, 4.0], [8.0, 7.0], [5.0, 9.0]]),
        "points_b": torch.tensor([[3.5, 4.2], [7.6, 7.5], [5.3, 8.6]]),
    }


def _augment_kwargs() -> dict[str, Any]:
    return {
        "radius": (4.0, 6.0),
        "steps": (2, 2),
        "grid": G,
        "strength": (0.01, 0.02),
        "generator": torch.Generator().manual_seed(0),
    }


def _warp() -> tfw.FluidWarp:
    return tfw.FluidWarp(G, T, image_size=(H, W))


Call = Callable[[dict[str, Any]], Any]

# entry point -> (its arguments, the call): each argument is corrupted in turn; an argument is its name, or
# (key in the inputs, name the error must give) where two entry points use one name for different things
ENTRY_POINTS: dict[str, tuple[list[str | tuple[str, str]], Call]] = {
    "FluidSimulator": (
        ["forces", "points", "velocity"],
        lambda a: tfw.FluidSimulator(G)(a["forces"], a["points"], a["velocity"]),
    ),
    "FluidSimulator(viscosity)": (
        ["viscosity"],
        lambda a: tfw.FluidSimulator(G, viscosity=a["viscosity"])(a["forces"]),
    ),
    "FluidWarp.forward": (["image", "forces"], lambda a: _warp()(a["image"], a["forces"])),
    "FluidWarp.forward(force module)": (["forces"], lambda a: _warp()(a["image"], lambda *_: a["forces"])),
    "FluidWarp.iter_frames": (["image", "forces"], lambda a: list(_warp().iter_frames(a["image"], a["forces"]))),
    "FluidWarp.maps": (["forces"], lambda a: _warp().maps(a["forces"])),
    "FluidWarp.forward_maps": (["forces"], lambda a: _warp().forward_maps(a["forces"])),
    "FluidWarp.carry_points": (["points", "forces"], lambda a: _warp().carry_points(a["points"], a["forces"])),
    "warp_image": (["image", "coords"], lambda a: tfw.warp_image(a["image"], a["coords"])),
    "advect": (["quantity", "velocity", "dt"], lambda a: advection.advect(a["quantity"], a["velocity"], a["dt"])),
    "advect_velocity": (["velocity", "dt"], lambda a: advection.advect_velocity(a["velocity"], a["dt"])),
    "advect_points": (
        ["points", "velocity", "dt"],
        lambda a: advection.advect_points(a["points"], a["velocity"], a["dt"]),
    ),
    "sample_velocity": (["velocity", "points"], lambda a: advection.sample_velocity(a["velocity"], a["points"])),
    "backward_maps": (["velocities", "dt"], lambda a: maps.backward_maps(a["velocities"], (H, W), a["dt"])),
    "iter_backward_maps": (
        ["velocities", "dt"],
        lambda a: list(maps.iter_backward_maps(a["velocities"], (H, W), a["dt"])),
    ),
    "maps_to_end": (["velocities", "dt"], lambda a: maps.maps_to_end(a["velocities"], (H, W), a["dt"])),
    "forward_maps": (["velocities", "dt"], lambda a: maps.forward_maps(a["velocities"], (H, W), a["dt"])),
    "jacobian_determinant": (["coords"], lambda a: tfw.jacobian_determinant(a["coords"])),
    "fit_keyframes": (
        ["source", "target"],
        lambda a: tfw.fit_keyframes(
            a["source"], a["target"], image_size=(H, W), grid=G, steps=T, max_iter=2, progress=False
        ),
    ),
    "RandomFluidWarp": (
        ["image", "keypoints", "boxes", "masks"],
        lambda a: RandomFluidWarp(
            radius=(4.0, 6.0), steps=(2, 2), grid=G, strength=(0.01, 0.02), generator=torch.Generator().manual_seed(0)
        )(a["image"], keypoints=a["keypoints"], boxes=a["boxes"], masks=a["masks"]),
    ),
    "morph": (
        ["image_a", "image_b", "points_a", "points_b"],
        lambda a: tfw.morph(
            a["image_a"],
            a["image_b"],
            a["points_a"],
            a["points_b"],
            frames=3,
            settings=NaturalSettings(steps=2, max_iter=2),
            progress=False,
        ),
    ),
    "fit_images": (
        [("source_image", "source"), ("target_image", "target")],
        lambda a: fit_images(
            a["source_image"], a["target_image"], grid=G, levels=None, steps=T, max_iter=2, progress=False
        ),
    ),
    "RandomFluidWarpV2(tensor)": (["image"], lambda a: RandomFluidWarpV2(**_augment_kwargs())(a["image"])),
    "RandomFluidWarpV2(Image)": (
        ["image"],
        lambda a: RandomFluidWarpV2(**_augment_kwargs())(tv_tensors.Image(a["image"][0])),
    ),
}

CASES = [
    pytest.param(entry, key, name, bad, id=f"{entry}-{name}-{bad}")
    for entry, (args, _) in ENTRY_POINTS.items()
    for key, name in ((a, a) if isinstance(a, str) else a for a in args)
    for bad in BAD
]


def _corrupt(value: Any, bad: float) -> Any:
    if isinstance(value, torch.Tensor):
        value = value.clone()
        value.view(-1)[value.numel() // 2] = bad  # one element, mid-tensor
        return value
    return bad


@pytest.mark.parametrize("entry,key,name,bad", CASES)
def test_entry_point_refuses_non_finite_input_naming_the_argument(entry: str, key: str, name: str, bad: str):
    _, call = ENTRY_POINTS[entry]
    inputs: dict[str, Any] = {**_inputs(), "dt": 1.0}
    call(inputs)  # the clean call works: the failure below is the bad value's
    inputs[key] = _corrupt(inputs[key], BAD[bad])
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        call(inputs)


@pytest.mark.parametrize("bad", BAD)
def test_a_flow_that_blows_up_inside_is_refused_before_sampling(bad: str):
    # the per-sub-step sampling is unchecked; the sub-step count reads the velocity's strain on the host anyway,
    # so a non-finite velocity that got past the boundary (here: straight into the unchecked kernel) is refused
    velocity = torch.zeros(1, 2, G + 1, G + 1)
    velocity[0, 0, 3, 3] = BAD[bad]
    with pytest.raises(FlowBlewUp, match="non-finite velocity"):
        StaggeredGrid.of(velocity).carry(velocity, torch.full((1, 3, 2), 4.0), 1.0)


@pytest.mark.parametrize("entry", ["forward", "iter_frames", "carry_points"])
def test_fluid_warp_refuses_a_batch_mismatch_naming_both(entry: str):
    a = _inputs()
    forces = a["forces"].expand(3, -1, -1, -1, -1)
    image, points = a["image"].expand(2, -1, -1, -1), a["points"].expand(2, -1, -1)
    call: dict[str, Callable[[], Any]] = {
        "forward": lambda: _warp()(image, forces),
        "iter_frames": lambda: list(_warp().iter_frames(image, forces)),
        "carry_points": lambda: _warp().carry_points(points, forces),
    }
    with pytest.raises(ValueError, match=r"forces have batch 3, but (image|points) has batch 2"):
        call[entry]()


def test_fluid_warp_shares_a_batch_of_one_force_schedule():
    a = _inputs()
    image = torch.cat([a["image"], a["image"].flip(-1)])
    frames = _warp()(image, a["forces"])
    torch.testing.assert_close(frames[1], _warp()(image[1:], a["forces"])[0])


@pytest.mark.parametrize("layout", ["contiguous", "channels-first"])
def test_a_lone_picture_sampled_in_bands_is_sampled_exactly(monkeypatch: pytest.MonkeyPatch, layout: str):
    # 4 threads: the 300 x 301 output is read as bands of the picture; every value and the grid's gradient are
    # grid_sample's own, bit for bit
    monkeypatch.setattr(torch, "get_num_threads", lambda: 4)
    g = torch.Generator().manual_seed(1)
    image = torch.rand(1, 3, 40, 50, generator=g)
    grid = 2.4 * torch.rand(1, 300, 301, 2, generator=g) - 1.2
    if layout == "channels-first":
        grid = grid.permute(0, 3, 1, 2).contiguous().permute(0, 2, 3, 1)
    assert sampling._bands(image, grid) == 4
    for mode in ("bilinear", "bicubic", "nearest"):
        want = torch.nn.functional.grid_sample(image, grid, mode=mode, padding_mode="border", align_corners=False)
        got = sampling.sample(image, grid, mode=mode, align_corners=False, check=None)
        torch.testing.assert_close(got, want, rtol=0, atol=0)
    leaf = grid.detach().requires_grad_()
    sampling.sample(image, leaf, align_corners=True, check=None).square().sum().backward()
    want_grad = torch.autograd.grad(
        torch.nn.functional.grid_sample(image, leaf, padding_mode="border", align_corners=True).square().sum(), leaf
    )[0]
    torch.testing.assert_close(leaf.grad, want_grad, rtol=0, atol=0)


def test_bands_only_for_a_lone_cpu_picture_with_enough_points(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(torch, "get_num_threads", lambda: 4)
    grid = torch.zeros(1, 300, 301, 2)
    assert sampling._bands(torch.zeros(1, 1, 4, 4), grid) == 4
    assert sampling._bands(torch.zeros(2, 1, 4, 4), grid.expand(2, -1, -1, -1)) == 1  # a batch uses the threads
    assert sampling._bands(torch.zeros(1, 1, 4, 4), torch.zeros(1, 1, 68, 2)) == 1  # too few points to share
    assert sampling._bands(torch.zeros(1, 1, 4, 4), torch.zeros(1, 1, 3 * sampling.GRAIN, 2)) == 3  # a divisor
    assert sampling._bands(torch.zeros(1, 1, 4, 4, requires_grad=True), grid) == 1  # its gradient: one copy
    with torch.no_grad():
        assert sampling._bands(torch.zeros(1, 1, 4, 4, requires_grad=True), grid) == 4
