import dataclasses
import inspect

import pytest
import torch

from torchfluidwarp.augment import MAX_SHEAR, FluidWarpSettings, draw_fluid_warp, fluid_warp_map, random_fluid_warp
from torchfluidwarp.augment.settings import make_settings
from torchfluidwarp.augment.tensor import FluidWarpAugment
from torchfluidwarp.augment.transforms import RandomFluidWarp
from torchfluidwarp.core.grid import FluidGrid
from torchfluidwarp.warp.frames import identity_map

FIELDS = [f.name for f in dataclasses.fields(FluidWarpSettings)]
SETTINGS = {"count": (1, 2), "strength": 0.2, "radius": (10.0, 14.0), "steps": (2, 3), "grid": 12, "dt": 1.0}


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def _gen(seed=0):
    return torch.Generator().manual_seed(seed)


def test_settings_are_normalised_once():
    s = FluidWarpSettings(2, [0.1, 0.3], 8, steps=3, grid=(12, 16), dt=2, viscosity=0)
    assert s.count == (2, 2) and s.strength == (0.1, 0.3) and s.radius == (8.0, 8.0) and s.steps == (3, 3)
    assert s.grid == FluidGrid(12, 16) and isinstance(s.dt, float) and s.viscosity == 0.0
    assert dataclasses.replace(s) == s  # normalising normalised values changes nothing
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.dt = 3.0  # type: ignore[misc]


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"dt": 0.0}, "dt"),
        ({"viscosity": -1.0}, "viscosity"),
        ({"edge_points": 1}, "edge_points"),
        ({"max_retries": -1}, "max_retries"),
        ({"grid": 1}, "grid"),
        ({"radius": (8.0, float("nan"))}, "radius"),
        ({"steps": (2, 3.0)}, "steps"),
    ],
)
def test_bad_settings_are_refused_by_name(kwargs, word):
    with pytest.raises((ValueError, TypeError), match=word):
        FluidWarpSettings(**kwargs)


def test_the_fold_bound_is_the_documented_stretch():
    count, steps, radius, dt = 3, 8, 20.0, 1.0
    strongest = MAX_SHEAR * radius / (count * steps * dt**2 * max(1.0, steps / 4))
    at = FluidWarpSettings(count=count, strength=strongest, radius=radius, steps=steps, dt=dt)
    assert at.stretch == pytest.approx(MAX_SHEAR, rel=1e-12)
    with pytest.raises(ValueError, match="strength"):
        FluidWarpSettings(count=count, strength=strongest * 1.001, radius=radius, steps=steps, dt=dt)


def test_make_settings_builds_or_replaces():
    base = FluidWarpSettings(**SETTINGS)
    assert make_settings(None, **SETTINGS) == base
    assert make_settings(base) is base
    assert make_settings(base, dt=0.5) == dataclasses.replace(base, dt=0.5)
    with pytest.raises(TypeError, match="strenght"):
        make_settings(None, strenght=0.2)
    with pytest.raises(TypeError, match="positional"):
        make_settings(base, (1, 2))
    with pytest.raises(TypeError, match="settings"):
        make_settings({"dt": 1.0})  # type: ignore[arg-type]


@pytest.mark.parametrize("entry", [FluidWarpAugment, random_fluid_warp, RandomFluidWarp])
def test_every_entry_point_shows_the_settings_in_its_signature(entry):
    params = inspect.signature(entry).parameters
    assert set(FIELDS) <= set(params) and {"settings", "generator"} <= set(params)
    assert not any(p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD) for p in params.values())


def test_the_module_reads_its_settings_as_attributes():
    aug = FluidWarpAugment((1, 2), 0.2, grid=12)
    for name in FIELDS:
        assert getattr(aug, name) == getattr(aug.settings, name)
    with pytest.raises(AttributeError, match="no_such"):
        aug.no_such  # noqa: B018


def test_ready_settings_give_the_same_warp_as_keywords():
    image = torch.rand(2, 1, 24, 32, generator=_gen(1))
    points = torch.tensor([[[5.0, 6.0]], [[20.0, 10.0]]])
    settings = FluidWarpSettings(**SETTINGS)
    by_name = FluidWarpAugment(generator=_gen(), **SETTINGS)(image, keypoints=points)
    ready = FluidWarpAugment(settings=settings, generator=_gen())(image, keypoints=points)
    once = random_fluid_warp(image, keypoints=points, settings=settings, generator=_gen())
    assert isinstance(by_name, dict) and isinstance(ready, dict) and isinstance(once, dict)
    for key in ("image", "keypoints"):
        assert torch.equal(by_name[key], ready[key]) and torch.equal(by_name[key], once[key])
    v2 = RandomFluidWarp(settings=settings, generator=_gen())(image[0])
    assert torch.equal(v2, RandomFluidWarp(generator=_gen(), **SETTINGS)(image[0]))


def test_the_module_draws_through_draw_fluid_warp():
    settings = FluidWarpSettings(**SETTINGS)
    a = FluidWarpAugment(settings=settings, generator=_gen(3)).make_params(3, (20, 28))
    b = draw_fluid_warp(settings, 3, (20, 28), generator=_gen(3))
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        assert torch.equal(x, y) if isinstance(x, torch.Tensor) else x == y


@pytest.mark.parametrize("size", [(20, 28), (96, 80)])
def test_a_warp_without_force_is_the_identity(size):
    # at (96, 80) the map is composed on a coarser raster and resized: the identity must survive both
    settings = FluidWarpSettings(**{**SETTINGS, "strength": 0.0})
    params = draw_fluid_warp(settings, 2, size, generator=_gen())
    assert torch.equal(fluid_warp_map(params), identity_map(size).expand(2, -1, -1, -1))
    image = torch.rand(2, 3, *size, generator=_gen(2))
    out = FluidWarpAugment(settings=settings, generator=_gen())(image, keypoints=torch.tensor([[[3.0, 4.0]]] * 2))
    assert isinstance(out, dict)
    torch.testing.assert_close(out["image"], image, atol=1e-5, rtol=0)
    torch.testing.assert_close(out["keypoints"], torch.tensor([[[3.0, 4.0]]] * 2), atol=1e-4, rtol=0)
