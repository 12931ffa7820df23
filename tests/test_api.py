"""The public surface: a small top level, one ``RandomFluidWarp``, deprecation shims for the names that moved,
and torchvision imported by ``augment_tv`` only."""

from __future__ import annotations

import ast
import importlib
import pathlib
import warnings

import pytest
import torch

import torchfluidwarp as tfw
from torchfluidwarp import augment
from torchfluidwarp.augment import FluidWarpAugment, random_fluid_warp

PACKAGE = pathlib.Path(tfw.__file__).parent


def test_the_top_level_is_small_and_every_name_resolves():
    assert len(tfw.__all__) <= 16
    for name in ["FluidWarp", "FluidSimulator", "fit_keyframes", "fit_images", "morph", "RandomFluidWarp"]:
        assert name in tfw.__all__
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the top-level names warn about nothing
        for name in tfw.__all__:
            assert getattr(tfw, name) is not None
    assert set(tfw.__all__) <= set(dir(tfw))


def test_the_top_level_random_fluid_warp_is_the_v2_transform():
    from torchvision.transforms import v2

    assert issubclass(tfw.RandomFluidWarp, v2.Transform)
    assert tfw.RandomFluidWarp.__module__ == "torchfluidwarp.augment_tv"


@pytest.mark.parametrize("name", sorted(tfw._MOVED))
def test_a_moved_top_level_name_warns_and_names_its_module(name):
    module = tfw._MOVED[name]
    with pytest.warns(DeprecationWarning, match=rf"from {module} import {name}"):
        value = getattr(tfw, name)
    assert value is getattr(importlib.import_module(module), name)
    assert name not in tfw.__all__


def test_an_unknown_top_level_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_name"):
        tfw.no_such_name  # noqa: B018


def test_the_old_tensor_level_name_warns_and_is_the_renamed_module():
    with pytest.warns(DeprecationWarning, match=r"torchfluidwarp\.augment\.FluidWarpAugment"):
        from torchfluidwarp.augment import RandomFluidWarp
    assert RandomFluidWarp is FluidWarpAugment
    assert "RandomFluidWarp" not in augment.__all__


def test_the_old_lazy_v2_alias_warns_and_is_the_transform():
    with pytest.warns(DeprecationWarning, match=r"torchfluidwarp\.RandomFluidWarp"):
        value = augment.RandomFluidWarpV2
    assert value is tfw.RandomFluidWarp


def _imports(path: pathlib.Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def test_only_augment_tv_imports_torchvision_and_augment_never_imports_it():
    users = {
        str(path.relative_to(PACKAGE))
        for path in PACKAGE.rglob("*.py")
        if any(m == "torchvision" or m.startswith("torchvision.") for m in _imports(path))
    }
    assert users == {"augment_tv.py"}
    assert "torchfluidwarp.augment_tv" not in _imports(PACKAGE / "augment.py")
    assert "torchfluidwarp.augment" in _imports(PACKAGE / "augment_tv.py")


def test_random_fluid_warp_is_the_module_in_one_call():
    image = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(1))
    points = torch.tensor([[[10.0, 12.0]], [[20.0, 5.0]]])
    settings = {"radius": (8.0, 12.0), "steps": (2, 4), "grid": 16}
    got = random_fluid_warp(image, keypoints=points, generator=torch.Generator().manual_seed(0), **settings)
    want = FluidWarpAugment(generator=torch.Generator().manual_seed(0), **settings)(image, keypoints=points)
    assert isinstance(got, dict) and isinstance(want, dict)
    for key in ("image", "keypoints"):
        torch.testing.assert_close(got[key], want[key], rtol=0, atol=0)
    assert not torch.equal(got["image"], image)
