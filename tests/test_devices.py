"""Device and dtype follow the inputs: the main paths on every available device, in float32 and float64, and no
tensor allocated in library code without a device.

The device list holds the CPU always and CUDA when ``torch.cuda.is_available()``: without CUDA its cases are not
generated at all (never skipped).
"""

from __future__ import annotations

import ast
import pathlib
from collections import Counter

import pytest
import torch

import torchfluidwarp as tfw
from torchfluidwarp.augment.tensor import FluidWarpAugment
from torchfluidwarp.control.images import fit_images
from torchfluidwarp.core.simulator import FluidSimulator
from torchfluidwarp.morph import NaturalSettings
from torchfluidwarp.warp.forces import Brushes, ViscosityBrushes
from torchfluidwarp.warp.frames import jacobian_determinant
from torchfluidwarp.warp.layer import FluidWarp
from torchfluidwarp.warp.maps import backward_maps, maps_to_end

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
DTYPES = [torch.float32, torch.float64]
PACKAGE = pathlib.Path(tfw.__file__).parent

CASES = [(d, t) for d in DEVICES for t in DTYPES]
on_every_device = pytest.mark.parametrize("device,dtype", CASES, ids=[f"{d}-{str(t)[6:]}" for d, t in CASES])


def _on(x: torch.Tensor, device: str, dtype: torch.dtype) -> None:
    assert x.device.type == device, f"on {x.device}, expected {device}"
    assert x.dtype == dtype, f"{x.dtype}, expected {dtype}"
    assert bool(torch.isfinite(x).all())


def _image(size: tuple[int, int], device: str, dtype: torch.dtype, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, 3, *size, generator=g, dtype=dtype).to(device)


def _forces(device: str, dtype: torch.dtype, steps: int = 3, grid: int = 12) -> torch.Tensor:
    forces = torch.zeros(1, steps, 2, grid, grid, dtype=dtype)
    forces[:, :, 0, 4:8, 4:8] = 0.3
    return forces.to(device)


@on_every_device
def test_simulate(device: str, dtype: torch.dtype):
    points = torch.tensor([[[5.0, 6.0], [7.5, 3.0]]], dtype=dtype, device=device)
    viscosity = torch.full((1, 1, 12, 12), 0.2, dtype=dtype, device=device)
    for mu in (0.0, 0.3, viscosity):
        out = FluidSimulator(12, viscosity=mu)(_forces(device, dtype), points=points)
        _on(out.velocities, device, dtype)
        assert out.points is not None
        _on(out.points, device, dtype)
        assert not torch.equal(out.points[:, -1], points)  # the flow moved them


@on_every_device
def test_warp_forward_and_iter_frames(device: str, dtype: torch.dtype):
    image = _image((30, 40), device, dtype)
    warp = FluidWarp(12, steps=3)
    frames = warp(image, _forces(device, dtype))
    _on(frames, device, dtype)
    streamed = torch.stack(list(warp.iter_frames(image, _forces(device, dtype))), dim=1)
    _on(streamed, device, dtype)
    torch.testing.assert_close(streamed, frames, rtol=0, atol=1e-4 if dtype == torch.float32 else 1e-10)
    points = torch.tensor([[[10.0, 12.0]]], dtype=dtype, device=device)
    _on(warp.carry_points(points, _forces(device, dtype), (30, 40)), device, dtype)


@on_every_device
def test_warp_with_force_and_viscosity_modules(device: str, dtype: torch.dtype):
    # modules hold parameters: .to() moves them, and the warp follows them and the image
    brushes = Brushes([[20.0, 15.0]], [[1.0, 0.0]], radius=6.0, amplitude=0.5, frequency=0.1).to(device, dtype)
    stiff = ViscosityBrushes([[10.0, 10.0]], radius=5.0, value=1.0).to(device, dtype)
    frames = FluidWarp(12, steps=3, viscosity=stiff)(_image((30, 40), device, dtype), brushes)
    _on(frames, device, dtype)


@on_every_device
def test_maps_and_jacobian(device: str, dtype: torch.dtype):
    velocities = FluidSimulator(12)(_forces(device, dtype)).velocities
    maps = backward_maps(velocities, (60, 70))  # larger than the raster: the upsampled path
    _on(maps, device, dtype)
    _on(maps_to_end(velocities, (60, 70), times=[0.0, 1.5]), device, dtype)
    _on(jacobian_determinant(maps[:, -1]), device, dtype)


@on_every_device
def test_fit_keyframes(device: str, dtype: torch.dtype):
    source = torch.tensor([[20.0, 20.0], [40.0, 30.0], [30.0, 45.0]], device=device)
    target = source + torch.tensor([3.0, -2.0], device=device)
    fit = tfw.fit_keyframes(
        source, target, image_size=(64, 64), grid=12, steps=3, max_iter=3, dtype=dtype, progress=False
    )
    for p in fit.forces.parameters():
        _on(p.detach(), device, dtype)
    _on(fit.points, device, dtype)
    _on(fit.trajectories, device, dtype)
    _on(fit.warp(_image((64, 64), device, dtype), fit.forces), device, dtype)


@on_every_device
def test_fit_images(device: str, dtype: torch.dtype):
    source = _image((32, 32), device, dtype, seed=1)
    target = torch.roll(source, shifts=1, dims=-1)
    fit = fit_images(source, target, grid=8, levels=None, steps=2, max_iter=2, dtype=dtype, progress=False)
    _on(fit.warped, device, dtype)
    _on(fit.min_det, device, dtype)


@on_every_device
def test_morph(device: str, dtype: torch.dtype):
    image_a, image_b = _image((32, 32), device, dtype, seed=2), _image((32, 32), device, dtype, seed=3)
    points_a = torch.tensor([[8.0, 8.0], [24.0, 8.0], [16.0, 24.0], [10.0, 20.0]], dtype=dtype, device=device)
    points_b = points_a + torch.tensor([1.0, 1.5], dtype=dtype, device=device)
    settings = NaturalSettings(steps=2, max_iter=2)
    result = tfw.morph(image_a, image_b, points_a, points_b, frames=3, settings=settings, progress=False)
    assert result.frames.shape[0] == 3
    for x in (result.frames, result.forward_frames, result.backward_frames, result.maps, result.maps_b):
        _on(x, device, dtype)


@on_every_device
def test_augment(device: str, dtype: torch.dtype):
    image = _image((32, 32), device, dtype, seed=4)
    keypoints = torch.tensor([[[10.0, 12.0], [20.0, 5.0]]], dtype=dtype, device=device)
    augment = FluidWarpAugment(radius=(6.0, 10.0), steps=(2, 3), grid=16, generator=torch.Generator().manual_seed(0))
    out = augment(image, keypoints=keypoints)
    assert isinstance(out, dict)
    _on(out["image"], device, dtype)
    _on(out["keypoints"], device, dtype)


# ---------------------------------------------------------------------------------------------------------------
# No allocation without a device in library code.

FACTORIES = {
    "zeros", "ones", "empty", "full", "arange", "linspace", "logspace", "eye", "tensor", "as_tensor",
    "rand", "randn", "randint", "randperm", "normal", "empty_strided", "scalar_tensor", "tril_indices",
    "triu_indices", "sparse_coo_tensor",
}  # fmt: skip
"""``torch.<factory>(...)`` calls that allocate; ``*_like`` and ``Tensor.new_*`` follow their tensor by design."""

ALLOWED: dict[tuple[str, str, str], str] = {
    # (module, enclosing function, factory): why the call needs no device
    ("core/linalg.py", "_ImplicitSolve.forward", "tensor"): (
        "a host-side CG iteration counter, read back with int(): on the device it would cost a sync per solve"
    ),
    ("warp/forces.py", "Brushes.__init__", "as_tensor"): (
        "a module's parameters from user values: a tensor keeps its device, a list starts on the CPU as torch.nn's "
        "parameters do, and .to() moves the module"
    ),
    ("warp/forces.py", "ViscosityBrushes.__init__", "as_tensor"): (
        "a module's parameters from user values: a tensor keeps its device, a list starts on the CPU as torch.nn's "
        "parameters do, and .to() moves the module"
    ),
    ("io/images.py", "_uint8_frames", "empty"): "CPU-only file encoding: frames go to an encoder on the host",
    ("io/points.py", "read_points", "tensor"): "CPU-only file decoding: points parsed from text",
    # the apps turn parsed user input (JSON, form fields, point files) into tensors; they run the library on
    # the CPU, and the library moves what it is given to its images' device
    ("apps/animate/config.py", "AnimationConfig.rescaled", "tensor"): "parsed config values, CPU by design",
    ("apps/animate/config.py", "AnimationConfig.rescaled.pos", "tensor"): "parsed config values, CPU by design",
    ("apps/studio/inputs.py", "points", "tensor"): "points parsed from the page, CPU by design",
    ("apps/studio/previews.py", "_to_size", "tensor"): "the studio runs on the CPU",
    # metadata for the caller, on the CPU like the other host-side scalars
    ("metrics/path.py", "PathTally.distances", "tensor"): "per-frame distances gathered as floats, metadata",
    ("morph/sequence.py", "average", "tensor"): "per-image point errors gathered as floats, metadata",
    # mediapipe's landmarks arrive as Python floats on the host; the caller moves them to the image's device
    ("correspond/faces.py", "_crop", "tensor"): "the crop's similarity for mediapipe's input, CPU by design",
    ("correspond/faces.py", "_crop", "arange"): "the crop's sampling lattice for mediapipe's input, CPU by design",
    ("correspond/faces.py", "_mesh_in_crop", "tensor"): "mediapipe's landmarks, CPU by design",
    ("morph/morphing.py", "placement", "eye"): "a 3 x 3 placement on the host; morph moves it to the images' device",
    ("morph/result.py", "MorphResult.times", "tensor"): "the frames' times, metadata for the caller",
}


def _bare_factory_calls(node: ast.AST, scope: tuple[str, ...] = ()) -> list[tuple[str, str]]:
    """``(enclosing function, factory)`` for each ``torch.<factory>(...)`` call without ``device=`` under ``node``."""
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
        scope = (*scope, node.name)
    found = []
    if isinstance(node, ast.Call):
        f = node.func
        if (
            isinstance(f, ast.Attribute)
            and isinstance(f.value, ast.Name)
            and f.value.id == "torch"
            and f.attr in FACTORIES
            and not any(k.arg == "device" for k in node.keywords)
        ):
            found.append((".".join(scope) or "<module>", f.attr))
    for child in ast.iter_child_nodes(node):
        found += _bare_factory_calls(child, scope)
    return found


def _allocations_without_device() -> Counter[tuple[str, str, str]]:
    return Counter(
        (str(path.relative_to(PACKAGE)), function, factory)
        for path in sorted(PACKAGE.rglob("*.py"))
        for function, factory in _bare_factory_calls(ast.parse(path.read_text()))
    )


@pytest.fixture(scope="module")
def allocations() -> Counter[tuple[str, str, str]]:
    return _allocations_without_device()


def test_library_code_allocates_nothing_without_a_device(allocations):
    unexplained = sorted(k for k in allocations if k not in ALLOWED)
    assert not unexplained, (
        "torch factory calls without device= (pass device=..., or use *_like / Tensor.new_*): "
        + ", ".join(f"{m}: {fn}: torch.{c}" for m, fn, c in unexplained)
    )


def test_every_allow_list_entry_is_still_needed_and_has_a_reason(allocations):
    stale = sorted(k for k in ALLOWED if k not in allocations)
    assert not stale, f"allow-list entries that match no call any more (remove them): {stale}"
    assert all(reason.strip() for reason in ALLOWED.values())


def test_the_check_flags_bare_factories_and_passes_device_following_forms():
    code = """
def f(x):
    a = torch.zeros(3)
    b = torch.tensor([1.0], dtype=x.dtype)
    c = torch.zeros(3, device=x.device)
    d = torch.zeros_like(x) + x.new_zeros(3) + x.new_tensor([1.0])
"""
    assert sorted(_bare_factory_calls(ast.parse(code))) == [("f", "tensor"), ("f", "zeros")]
