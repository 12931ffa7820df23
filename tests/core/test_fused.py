"""The fused Triton kernels (:mod:`torchfluidwarp.core.fused`) against the torch path: forward values, gradients
through their hand-written adjoints, and float64 gradchecks.

The kernels run compiled on a CUDA device and, without one, on CPU tensors under Triton's interpreter. The
interpreter has to be switched on before Triton is imported, so a normal run checks them in a subprocess:
:func:`test_the_kernels_under_the_triton_interpreter` runs this file again with ``TRITON_INTERPRET=1``, where the
cases below run on ``"cpu"`` (and the subprocess test is not defined). On a CUDA machine the normal run also runs
the cases compiled, on ``"cuda"``; elsewhere it does not collect them.
"""

from __future__ import annotations

import importlib.util
import inspect
import os
import pathlib
import re
import subprocess
import sys

import pytest
import torch
from conftest import gradcheck64

from torchfluidwarp.core.grid import FluidGrid, interior_mask
from torchfluidwarp.core.simulator import FluidSimulator
from torchfluidwarp.core.staggered import StaggeredGrid
from torchfluidwarp.errors import InputError

INTERPRETED = os.environ.get("TRITON_INTERPRET") == "1"
CUDA = torch.cuda.is_available()
ROOT = pathlib.Path(__file__).resolve().parents[2]

TRITON = importlib.util.find_spec("triton") is not None
DEVICES = ["cpu"] if INTERPRETED else ["cuda"] if CUDA and TRITON else []
"""Where this process runs the cases: the CPU under the interpreter, else a CUDA device, else nowhere."""
DTYPES = [torch.float64, torch.float32]
GRIDS = [(8, 8), (12, 16)]  # square, and wide: u and v differ in shape
TOL = {torch.float64: dict(rtol=1e-10, atol=1e-11), torch.float32: dict(rtol=1e-5, atol=5e-5)}
DT = 0.7  # not a float32 number: the float64 kernels must get all of it

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def on_device(case):
    """Run ``case`` on each device of :data:`DEVICES`; where there is none, pytest does not collect it."""
    case = pytest.mark.parametrize("device", DEVICES)(case)
    case.__test__ = bool(DEVICES)
    return case


def _velocity(grid, device, dtype, *, batch=2, scale=1.5, seed=0, walls=True):
    """A random staggered velocity ``(batch, 2, h + 1, w + 1)``; ``walls``: zero on the walls and the padding,
    otherwise random there too (which the kernels must read as the torch path does, or ignore)."""
    h, w = grid
    v = torch.randn(batch, 2, h + 1, w + 1, generator=torch.Generator().manual_seed(seed), dtype=dtype) * scale
    if walls:
        v = v * interior_mask(FluidGrid(h, w), dtype=dtype)
    return v.to(device)


def _points(grid, device, dtype, *, batch=2, n=40, seed=1):
    """``(batch, n, 2)`` points in cells, in the box and up to 1.5 cells beyond it."""
    h, w = grid
    box = torch.tensor([w + 3.0, h + 3.0], dtype=dtype)
    return (torch.rand(batch, n, 2, generator=torch.Generator().manual_seed(seed), dtype=dtype) * box - 2.0).to(device)


def _both(grid):
    """The torch path and the fused kernels on the same grid."""
    return StaggeredGrid(grid, fused=False), StaggeredGrid(grid, fused=True)


def _values_and_grads(fn, inputs, seed=2):
    """``fn(*inputs)`` and the gradients of ``<fn(*inputs), r>`` for a fixed random ``r``, for every input."""
    xs = [x.detach().clone().requires_grad_() for x in inputs]
    out = fn(*xs)
    r = torch.randn(out.shape, generator=torch.Generator().manual_seed(seed), dtype=out.dtype).to(out.device)
    grads = torch.autograd.grad((out * r).sum(), xs)
    return out.detach(), grads


def _assert_same(fn_ref, fn_fused, inputs, dtype):
    want, want_grads = _values_and_grads(fn_ref, inputs)
    got, got_grads = _values_and_grads(fn_fused, inputs)
    torch.testing.assert_close(got, want, **TOL[dtype])
    for g, w in zip(got_grads, want_grads):
        torch.testing.assert_close(g, w, **TOL[dtype])


# ---- the self-advection of the velocity: the step's kernel ----------------------------------------------------


@on_device
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("grid", GRIDS)
@pytest.mark.parametrize("walls", [True, False], ids=["zero-walls", "garbage-walls"])
def test_advect_velocity_matches_the_torch_path(device, dtype, grid, walls):
    ref, fused = _both(grid)
    v = _velocity(grid, device, dtype, walls=walls)
    _assert_same(lambda x: ref.advect_velocity(x, DT), lambda x: fused.advect_velocity(x, DT), [v], dtype)


@on_device
def test_advect_velocity_writes_zero_on_the_walls_and_the_padding(device):
    _, fused = _both((8, 8))
    v = _velocity((8, 8), device, torch.float64, walls=False)
    out = fused.advect_velocity(v, DT)
    mask = interior_mask(FluidGrid(8, 8), dtype=torch.float64).to(device)
    assert not (out * (1 - mask)).any()


# ---- the back-trace of points, and the carry it gives --------------------------------------------------------


@on_device
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("grid", GRIDS)
@pytest.mark.parametrize("dt", [DT, -0.45])
def test_backtrace_matches_the_torch_path_for_velocity_and_points(device, dtype, grid, dt):
    ref, fused = _both(grid)
    v, p = _velocity(grid, device, dtype), _points(grid, device, dtype)

    def run(layout):
        return lambda v, p: layout.backtrace(layout.extend(v), p, dt)

    _assert_same(run(ref), run(fused), [v, p], dtype)


@on_device
def test_backtrace_reads_any_point_layout_and_the_staggered_tensor_itself(device):
    ref, fused = _both((8, 8))
    v = _velocity((8, 8), device, torch.float64)
    want = ref.backtrace(ref.extend(v), _points((8, 8), device, torch.float64), DT)
    cells = _points((8, 8), device, torch.float64, batch=1).expand(2, -1, -1)  # stride 0 along the batch
    channel_first = _points((8, 8), device, torch.float64).transpose(1, 2).contiguous().transpose(1, 2)
    from torchfluidwarp.core import fused as kernels

    for points in (cells, channel_first):
        got = kernels.backtrace(v, points, DT)  # the staggered velocity, not its extension
        torch.testing.assert_close(got, ref.backtrace(ref.extend(v), points, DT), **TOL[torch.float64])
    torch.testing.assert_close(kernels.backtrace(fused.extend(v), channel_first, DT), want, **TOL[torch.float64])


@on_device
def test_points_on_the_walls_and_corners_match(device):
    # the carry clamps points onto the walls, where they then sit exactly: the clamp's gradient there is a tie
    grid = (8, 8)
    ref, fused = _both(grid)
    v = _velocity(grid, device, torch.float64)
    on_walls = [[-0.5, 3.3], [7.5, 4.2], [5.3, -0.5], [6.1, 7.5], [-0.5, -0.5], [7.5, 7.5], [2.0, 3.0], [4.5, 0.5]]
    p = torch.tensor([on_walls, on_walls[::-1]], dtype=torch.float64, device=device)

    def run(layout):
        return lambda v, p: layout.backtrace(layout.extend(v), p, -0.3)

    _assert_same(run(ref), run(fused), [v, p], torch.float64)


@on_device
@pytest.mark.parametrize("dtype", DTYPES)
def test_trajectories_through_several_substeps_match(device, dtype):
    grid = (8, 8)
    ref, fused = _both(grid)
    velocities = torch.stack([_velocity(grid, device, dtype, scale=0.3, seed=s) for s in range(2)], dim=1)
    points = _points(grid, device, dtype, n=20)  # some beyond the walls: carried along them, clamped onto them
    assert ref.substeps(ref.extend(velocities[:, 0]), 1.0) > 1  # the carry takes several sub-steps a step

    def run(layout):
        return lambda v, p: layout.trajectories(v, p, 1.0)

    _assert_same(run(ref), run(fused), [velocities, points], dtype)


@on_device
@pytest.mark.parametrize("dtype", DTYPES)
def test_advect_of_a_cell_field_matches(device, dtype):
    grid = (8, 8)
    ref, fused = _both(grid)
    v = _velocity(grid, device, dtype)
    q = torch.randn(2, 3, *grid, generator=torch.Generator().manual_seed(5), dtype=dtype).to(device)
    _assert_same(lambda q, v: ref.advect(q, v, DT), lambda q, v: fused.advect(q, v, DT), [q, v], dtype)


@on_device
@pytest.mark.parametrize("dtype", DTYPES)
def test_a_rollout_with_points_and_its_gradient_match(device, dtype):
    grid = (12, 16)
    forces = torch.randn(2, 3, 2, *grid, generator=torch.Generator().manual_seed(3), dtype=dtype).to(device) * 0.3
    points = _points(grid, device, dtype, n=10)

    def run(fused):
        sim = FluidSimulator(grid, viscosity=0.1).to(device)
        sim.layout.fused = fused  # the step modules share the simulator's layout

        def fn(f, p):
            out = sim(f, points=p)
            return torch.cat([out.velocities.flatten(1), out.points.flatten(1)], dim=1)

        return fn

    _assert_same(run(False), run(True), [forces, points], dtype)


# ---- gradcheck: the adjoint kernels against finite differences, float64 --------------------------------------


@on_device
def test_advect_velocity_gradcheck(device):
    # fast mode (one random projection of the Jacobian): its every row is an interpreted adjoint launch, twice
    _, fused = _both((3, 4))
    v = _velocity((3, 4), device, torch.float64, scale=0.8, seed=7, walls=False)
    assert gradcheck64(lambda x: fused.advect_velocity(x, DT), v, fast_mode=True)


@on_device
@pytest.mark.parametrize("dt", [DT, -0.45])
def test_backtrace_gradcheck(device, dt):
    _, fused = _both((2, 3))
    v = _velocity((2, 3), device, torch.float64, batch=1, scale=0.8, seed=8)
    p = _points((2, 3), device, torch.float64, batch=1, n=4, seed=9)
    assert gradcheck64(lambda v, p: fused.backtrace(fused.extend(v), p, dt), v, p)


@on_device
def test_only_the_gradients_asked_for_are_computed(device):
    from torchfluidwarp.core import fused

    ref, _ = _both((8, 8))
    v = _velocity((8, 8), device, torch.float64).requires_grad_()
    p = _points((8, 8), device, torch.float64)
    (gv,) = torch.autograd.grad(fused.backtrace(v, p, DT).sum(), [v])  # the points' gradient is not computed
    (want,) = torch.autograd.grad(ref.backtrace(ref.extend(v), p, DT).sum(), [v])
    torch.testing.assert_close(gv, want, **TOL[torch.float64])
    pr = p.clone().requires_grad_()
    (gp,) = torch.autograd.grad(fused.backtrace(v.detach(), pr, DT).sum(), [pr])  # nor the velocity's
    (want,) = torch.autograd.grad(ref.backtrace(ref.extend(v.detach()), pr, DT).sum(), [pr])
    torch.testing.assert_close(gp, want, **TOL[torch.float64])


# ---- the dispatch, and the interpreter run -------------------------------------------------------------------

if not INTERPRETED:

    def test_the_kernels_under_the_triton_interpreter():
        pytest.importorskip("triton")  # ships with torch's CUDA wheels; the [test] extra's torch brings it
        env = {**os.environ, "TRITON_INTERPRET": "1"}
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(pathlib.Path(__file__))]
        done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600, check=False)
        report = done.stdout[-6000:] + done.stderr[-3000:]
        assert done.returncode == 0, report
        passed = re.search(r"(\d+) passed", done.stdout)
        assert passed and int(passed.group(1)) >= 20 and "skipped" not in done.stdout, report

    @pytest.mark.parametrize("dtype", ["fp32", "fp64"])
    def test_the_kernels_compile_for_a_gpu_without_one(dtype):
        # the interpreter runs the kernels' Python, not Triton's code generation: compile each launched kernel to a
        # cubin for sm_90 (Triton's own compiler and ptxas; no device needed), with Triton 3.x's compile API
        triton = pytest.importorskip("triton")
        from triton.backends.compiler import GPUTarget
        from triton.compiler import ASTSource

        from torchfluidwarp.core import fused

        flags = {"BLOCK": fused.BLOCK, "VELOCITY_GRAD": True, "POINTS_GRAD": True}
        for kernel in (fused._advect_faces, fused._advect_faces_adjoint, fused._backtrace, fused._backtrace_adjoint):
            names = list(inspect.signature(kernel.fn).parameters)
            kind = {"dt_hi": "fp32", "dt_lo": "fp32", **dict.fromkeys(["n", "h", "w", "blocks"], "i32")}
            kind |= {name: "i32" for name in names if name[:3] in ("ps_", "fs_")}
            signature = {name: "constexpr" if name in flags else kind.get(name, f"*{dtype}") for name in names}
            constants = {(names.index(name),): flags[name] for name in names if name in flags}
            compiled = triton.compile(ASTSource(kernel, signature, constants), target=GPUTarget("cuda", 90, 32))
            assert compiled.asm["cubin"], kernel.fn.__name__

    def test_cpu_tensors_take_the_torch_path_and_forcing_the_kernels_needs_the_interpreter():
        from torchfluidwarp.core import fused

        v = _velocity((4, 4), "cpu", torch.float32)
        assert not fused.usable(v) and StaggeredGrid((4, 4))._fused_kernels(v) is None
        assert StaggeredGrid((4, 4), fused=True)._fused_kernels(v) is fused
        assert StaggeredGrid((4, 4), fused=False)._fused_kernels(v) is None
        # forced onto CPU tensors outside the interpreter (or without Triton): refused, saying what is missing
        error, text = (InputError, "TRITON_INTERPRET") if TRITON else (ModuleNotFoundError, "Triton")
        with pytest.raises(error, match=text):
            fused.advect_velocity(v, 1.0)

    def test_the_cpu_path_never_imports_triton():
        code = (
            "import sys, torch; from torchfluidwarp.core.simulator import FluidSimulator; "
            "f = torch.zeros(1, 2, 2, 8, 8); f[:, :, 0, 3:5, 3:5] = 0.3; "
            "FluidSimulator(8)(f, points=torch.tensor([[[3.0, 4.0]]])); "
            "sys.exit('triton' in sys.modules)"
        )
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
        assert done.returncode == 0, done.stdout + done.stderr
