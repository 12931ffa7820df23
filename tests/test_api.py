"""The public surface: a small top level, one ``RandomFluidWarp``, one home per name (no deprecation shims), and
torchvision imported by ``augment.transforms`` only; imports that point one way through the layers."""

from __future__ import annotations

import ast
import pathlib
import subprocess
import sys
import warnings

import pytest
import torch

import torchfluidwarp as tfw
from torchfluidwarp import augment, errors
from torchfluidwarp.augment.tensor import FluidWarpAugment, random_fluid_warp

PACKAGE = pathlib.Path(tfw.__file__).parent


def test_the_top_level_is_small_and_every_name_resolves():
    assert len([n for n in tfw.__all__ if not n.startswith("__")]) <= 16  # __version__ aside
    for name in ["FluidWarp", "FluidSimulator", "fit_keyframes", "fit_images", "morph", "RandomFluidWarp"]:
        assert name in tfw.__all__
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the top-level names warn about nothing
        for name in tfw.__all__:
            assert getattr(tfw, name) is not None
    assert set(tfw.__all__) <= set(dir(tfw))
    # what dir() (and so tab completion) offers: the public names and the subpackages, not the module's imports
    assert set(dir(tfw)) == set(tfw.__all__) | {"core", "warp", "control", "correspond", "morph", "metrics",
                                                 "augment", "io", "data", "apps"}  # fmt: skip


def test_the_top_level_random_fluid_warp_is_the_v2_transform():
    from torchvision.transforms import v2

    assert issubclass(tfw.RandomFluidWarp, v2.Transform)
    assert tfw.RandomFluidWarp.__module__ == "torchfluidwarp.augment.transforms"


# names the top level used to export (``_MOVED``, deleted in #30): they have one home now
FORMER_TOP_LEVEL = ["advect", "project", "divergence", "Brushes", "ControlGrid", "identity_map", "keyframe_loss"]


@pytest.mark.parametrize("name", FORMER_TOP_LEVEL)
def test_a_former_top_level_name_is_not_there(name):
    assert name not in tfw.__all__
    with pytest.raises(AttributeError, match=name):
        getattr(tfw, name)


def test_the_top_level_exports_the_errors_from_their_home():
    assert tfw.InputError is errors.InputError and tfw.FlowBlewUp is errors.FlowBlewUp
    assert {"InputError", "FlowBlewUp"} <= set(tfw.__all__)
    assert issubclass(tfw.InputError, ValueError)
    assert issubclass(tfw.FlowBlewUp, ArithmeticError) and not issubclass(tfw.FlowBlewUp, ValueError)


def test_an_unknown_top_level_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_name"):
        tfw.no_such_name  # noqa: B018


@pytest.mark.parametrize("name", ["RandomFluidWarp", "RandomFluidWarpV2"])
def test_the_old_augment_aliases_are_gone(name):
    assert name not in augment.__all__
    with pytest.raises(AttributeError, match=name):
        getattr(augment, name)


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
    assert users == {"augment/transforms.py"}
    assert "torchfluidwarp.augment.transforms" not in _imports(PACKAGE / "augment" / "tensor.py")
    assert "torchfluidwarp.augment.tensor" in _imports(PACKAGE / "augment" / "transforms.py")


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


# The layers, bottom up. A module may import its own subpackage and any lower layer, never a higher one.
# ``errors`` (the exceptions), ``_checks`` (the one validation layer, which raises them), ``io`` (files) and
# ``data`` (samples) sit below the pipeline.
LAYERS = {"errors": 0, "_version": 0, "_checks": 1, "io": 2, "data": 3, "core": 4, "warp": 5, "control": 6}
LAYERS |= {"correspond": 7, "morph": 8, "augment": 8, "metrics": 8, "apps": 9, "__main__": 10}  # python -m


def _layer_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_point_down_the_layers(path: pathlib.Path):
    relative = path.relative_to(PACKAGE)
    if relative.parts == ("__init__.py",):
        return  # the top level gathers names from every layer
    own = relative.parts[0].removesuffix(".py")
    assert own in LAYERS, f"{relative} is in no layer: add its folder to LAYERS"
    for module in _imports(path):
        if module.startswith("torchfluidwarp."):
            other = _layer_of(module)
            assert other in LAYERS, f"{relative} imports {module}, which is in no layer"
            assert other == own or LAYERS[other] < LAYERS[own], f"{relative} ({own}) imports upward: {module}"
        if own in ("morph", "augment"):
            other_client = "augment" if own == "morph" else "morph"
            assert not module.startswith(f"torchfluidwarp.{other_client}"), f"{relative} imports {module}"


def test_importing_the_package_imports_neither_torchvision_nor_the_studio():
    code = (
        "import sys, torchfluidwarp; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('torchvision', 'starlette', 'uvicorn', 'matplotlib')"
        " or m.startswith('torchfluidwarp.apps')]; print(bad); sys.exit(bool(bad))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stdout + done.stderr


def test_importing_the_package_or_the_command_line_imports_no_torch():
    # the names load on first use (PEP 562), so the command line checks its arguments before torch is imported
    code = (
        "import sys, torchfluidwarp, torchfluidwarp.apps.cli; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('torch', 'numpy', 'PIL')]; "
        "print(bad); sys.exit(bool(bad))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stdout + done.stderr


def test_morph_is_the_package_and_calls_the_function_whichever_is_imported_first():
    # ``morph`` is the function users call and the package of its settings: the package, callable, serves both,
    # so that ``import torchfluidwarp.morph as m`` and ``import torchfluidwarp.morph.fit`` reach the package (a
    # function at the top level hid it: "cannot import name 'fit' from 'morph'")
    code = (
        "import inspect, torchfluidwarp as t; import torchfluidwarp.morph.settings; "
        "import torchfluidwarp.morph as m; import torchfluidwarp.morph.fit as f; "
        "from torchfluidwarp import morph; "
        "assert morph is m is t.morph and callable(m) and m.NaturalSettings and f.fit_natural, m; "
        "assert 'points_a' in inspect.signature(morph).parameters; "
        "import pickle, copy, functools; assert pickle.loads(pickle.dumps(morph)) is morph is copy.deepcopy(m); "
        "assert pickle.loads(pickle.dumps(functools.partial(morph, frames=3))).func is morph; "
        "assert t.io.read_image and t.core.FluidGrid is t.FluidGrid"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
