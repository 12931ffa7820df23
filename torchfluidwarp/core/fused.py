"""Fused Triton kernels for the semi-Lagrangian back-trace on CUDA: one kernel forward, one adjoint kernel backward.

On a GPU a fluid step is bound by kernel launches, not arithmetic (issue #33): the torch path of the velocity's
self-advection (:meth:`~torchfluidwarp.core.staggered.StaggeredGrid.advect_velocity`) is 16 operators
forward and about 40 backward, each a launch. Here each of the two operators the library runs per step is
one kernel, inside a ``torch.autograd.Function`` whose backward is one hand-written adjoint kernel:

* :func:`advect_velocity`: the whole self-advection of a staggered velocity. Per interior face, the midpoint
  back-trace through both components, the clamp into the box, and the face's own component read at the foot;
  walls and padding are written as zero.
* :func:`backtrace`: the clamped midpoint back-trace of points ``(B, N, 2)``, which the texture-coordinate maps
  run once per step and the points' carry once per sub-step (a forward sub-step of length ``h`` is the back-trace
  over ``-h``).

Each kernel reads the velocity as :meth:`~torchfluidwarp.core.staggered.StaggeredGrid.extend` lays it out for
``grid_sample`` (bilinear, border padding, ``align_corners=True``), from the staggered tensor itself: a read of
``u``'s padding row or ``v``'s padding column is redirected to the row / column before it. Its results are the
torch path's to rounding, and its gradients too (the same clamps pass no gradient where a position is clamped).
The adjoint kernels scatter the velocity's gradient with atomic adds: its sum of many terms can differ from the
torch path's in the last bits, and from run to run.

:class:`~torchfluidwarp.core.staggered.StaggeredGrid` dispatches here (its ``fused`` setting): by default when
the tensors are float32 or float64 on a CUDA device, Triton imports and the environment variable
``TORCHFLUIDWARP_FUSED`` is not ``0``. The torch path stays the reference and the CPU path. The kernels also run
on CPU tensors under Triton's interpreter (``TRITON_INTERPRET=1`` set before Triton is imported), which is how
the tests check them without a GPU (``tests/core/test_fused.py``).

Conventions: staggered velocities ``(B, 2, h + 1, w + 1)`` in cells per time unit (layout in
:mod:`torchfluidwarp.core.staggered`); points ``(B, N, 2)`` ``(x, y)`` in fluid cells, cell centres at integers;
``dt`` in time units. Like the torch kernels they replace, these check nothing: their inputs were checked at
the public boundary.
"""

from __future__ import annotations

import os
import struct
from typing import Any

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from torchfluidwarp._checks import describe
from torchfluidwarp.errors import InputError

try:
    import triton
    import triton.language as tl
except ImportError:  # torch's CPU wheels ship no Triton: nothing here runs, and the torch path needs none of it
    triton = None  # type: ignore[assignment]


__all__ = ["ENVIRONMENT", "usable", "advect_velocity", "backtrace"]

ENVIRONMENT = "TORCHFLUIDWARP_FUSED"
"""The environment variable that turns the default dispatch to these kernels off (``0``); read at every call."""

BLOCK = 256
"""Faces or points per Triton program."""

_DTYPES = (torch.float32, torch.float64)


def usable(*tensors: Tensor) -> bool:
    """Whether a call on ``tensors`` runs the fused kernels by default: Triton imports, :data:`ENVIRONMENT` is not
    ``"0"``, and the tensors share one CUDA device and one dtype, float32 or float64.

    Example:
        >>> usable(torch.zeros(1, 2, 5, 5))  # a CPU tensor takes the torch path
        False
    """
    first = tensors[0]
    return (
        triton is not None
        and os.environ.get(ENVIRONMENT, "1") != "0"
        and first.is_cuda
        and first.dtype in _DTYPES
        and all(t.device == first.device and t.dtype == first.dtype for t in tensors)
    )


def advect_velocity(velocity: Tensor, dt: float) -> Tensor:
    """Self-advection of a staggered velocity in one kernel (the fused
    :meth:`~torchfluidwarp.core.staggered.StaggeredGrid.advect_velocity`).

    Args:
        velocity: ``(B, 2, h + 1, w + 1)`` staggered, cells per time unit.
        dt: time step (time units).

    Returns:
        ``(B, 2, h + 1, w + 1)``: each interior face's component read at the foot of its midpoint back-trace;
        zero on the walls and the padding. Differentiable in ``velocity`` (one adjoint kernel).
    """
    _check_launchable(velocity)
    return _AdvectVelocity.apply(velocity.contiguous(), float(dt))


def backtrace(velocity: Tensor, points: Tensor, dt: float) -> Tensor:
    """Where points came from ``dt`` ago, in one kernel (the fused
    :meth:`~torchfluidwarp.core.staggered.StaggeredGrid.backtrace`): the explicit midpoint rule, clamped into the
    box ``[-1/2, w - 1/2] x [-1/2, h - 1/2]``.

    Args:
        velocity: ``(B, 2, h + 1, w + 1)`` staggered, cells per time unit, or its extended layout ``(2B, 1, h + 1,
            w + 1)`` (:meth:`~torchfluidwarp.core.staggered.StaggeredGrid.extend`): the kernel reads the same
            values from either.
        points: ``(B, N, 2)`` ``(x, y)`` in cells, any strides.
        dt: time (time units); a negative ``dt`` carries the points forward.

    Returns:
        ``(B, N, 2)`` in cells. Differentiable in ``velocity`` and ``points`` (one adjoint kernel).
    """
    _check_launchable(velocity, points)
    staggered = velocity.reshape(points.shape[0], 2, *velocity.shape[-2:]).contiguous()
    return _Backtrace.apply(staggered, points, float(dt))


def _check_launchable(*tensors: Tensor) -> None:
    """Refuse what the kernels cannot run on, naming it: no Triton, CPU tensors outside the interpreter, dtypes."""
    if triton is None:
        raise ModuleNotFoundError(
            "the fused kernels need Triton (it ships with torch's CUDA wheels): pip install triton"
        )
    interpreted = os.environ.get("TRITON_INTERPRET") == "1"
    for t in tensors:
        if t.dtype != tensors[0].dtype or t.dtype not in _DTYPES:
            raise InputError(f"the fused kernels take float32 or float64 tensors of one dtype, got {describe(t)}")
        if not (t.is_cuda or interpreted):
            raise InputError(
                f"the fused kernels run on CUDA tensors (on the CPU only under Triton's interpreter, TRITON_INTERPRET=1"
                f" set before Triton is imported), got a {describe(t)} on {t.device}"
            )


def _halves(dt: float) -> tuple[float, float]:
    """``dt`` as two float32 values whose sum is ``dt`` to about 1e-14: Triton passes Python floats as float32,
    and the float64 kernels add the halves back (the float32 ones get ``float32(dt)``)."""
    hi = struct.unpack("f", struct.pack("f", dt))[0] if abs(dt) < 3e38 else dt
    return hi, dt - hi


# ---- the autograd Functions ---------------------------------------------------------------------------------


class _AdvectVelocity(torch.autograd.Function):
    """:func:`advect_velocity`; its backward is :func:`_advect_faces_adjoint`."""

    @staticmethod
    def forward(velocity: Tensor, dt: float) -> Tensor:
        B, _, H1, W1 = velocity.shape
        out = torch.empty_like(velocity)
        blocks = triton.cdiv(H1 * W1, BLOCK)
        _advect_faces[(2 * B * blocks,)](velocity, out, H1 - 1, W1 - 1, *_halves(dt), blocks, BLOCK=BLOCK)
        return out

    @staticmethod
    def setup_context(ctx: Any, inputs: tuple[Tensor, float], output: Tensor) -> None:
        velocity, ctx.dt = inputs
        ctx.save_for_backward(velocity)

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad_out: Tensor) -> tuple[Tensor | None, None]:
        (velocity,) = ctx.saved_tensors
        grad_velocity = None
        if ctx.needs_input_grad[0]:
            B, _, H1, W1 = velocity.shape
            grad_velocity = torch.zeros_like(velocity)
            blocks = triton.cdiv(H1 * W1, BLOCK)
            grid = (2 * B * blocks,)
            args = (velocity, grad_out.contiguous(), grad_velocity, H1 - 1, W1 - 1, *_halves(ctx.dt), blocks)
            _advect_faces_adjoint[grid](*args, BLOCK=BLOCK)
        return grad_velocity, None


class _Backtrace(torch.autograd.Function):
    """:func:`backtrace`; its backward is :func:`_backtrace_adjoint`."""

    @staticmethod
    def forward(velocity: Tensor, points: Tensor, dt: float) -> Tensor:
        B, N, _ = points.shape
        feet = torch.empty_like(points)  # the points' strides when they are dense (channel_first), else contiguous
        blocks = triton.cdiv(N, BLOCK)
        H1, W1 = velocity.shape[-2:]
        _backtrace[(B * blocks,)](
            velocity, points, feet, N, H1 - 1, W1 - 1, *points.stride(), *feet.stride(), *_halves(dt), blocks,
            BLOCK=BLOCK,
        )  # fmt: skip
        return feet

    @staticmethod
    def setup_context(ctx: Any, inputs: tuple[Tensor, Tensor, float], output: Tensor) -> None:
        velocity, points, ctx.dt = inputs
        ctx.save_for_backward(velocity, points)

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad_feet: Tensor) -> tuple[Tensor | None, Tensor | None, None]:
        velocity, points = ctx.saved_tensors
        want_velocity, want_points = ctx.needs_input_grad[:2]
        grad_velocity = grad_points = None
        if want_velocity or want_points:
            B, N, _ = points.shape
            H1, W1 = velocity.shape[-2:]
            grad_velocity = torch.zeros_like(velocity) if want_velocity else None
            grad_points = points.new_empty(B, N, 2) if want_points else None
            grad_feet = grad_feet.contiguous()
            blocks = triton.cdiv(N, BLOCK)
            _backtrace_adjoint[(B * blocks,)](
                velocity, points, grad_feet,
                velocity if grad_velocity is None else grad_velocity,  # never written without VELOCITY_GRAD
                grad_feet if grad_points is None else grad_points,  # never written without POINTS_GRAD
                N, H1 - 1, W1 - 1, *points.stride(), *_halves(ctx.dt), blocks,
                BLOCK=BLOCK, VELOCITY_GRAD=want_velocity, POINTS_GRAD=want_points,
            )  # fmt: skip
        return grad_velocity, grad_points, None


# ---- the kernels ----------------------------------------------------------------------------------------------


def _jit(fn: Any) -> Any:
    """``triton.jit`` (the function itself without Triton: then nothing launches it)."""
    return fn if triton is None else triton.jit(fn)


def _kernel(*sizes: str) -> Any:
    """``triton.jit`` for a launched kernel, compiled once for all values of its integer arguments ``sizes``
    (Triton would otherwise compile a variant for each of them that is 1 or a multiple of 16)."""
    return _jit if triton is None else triton.jit(do_not_specialize=sizes)


# A velocity plane is one component of one sample, (h + 1) x (w + 1) contiguous; a sample's two planes follow each
# other. Positions are in cells. Each program handles BLOCK faces of one plane, or BLOCK points of one sample.


@_jit
def _nodes(x, y, c, h, w):
    """Where component ``c`` (0: ``u``, 1: ``v``) is read at positions ``(x, y)``: the offsets of the four nodes
    in its plane (``00, 01, 10, 11`` = top left, top right, bottom left, bottom right), the weights ``fx, fy``
    towards the right and the bottom, and ``kx, ky``: whether a move along x / y moves the sample (not where
    border padding clamps the position, as ``grid_sample``'s gradient)."""
    ix = x + 0.5 * (1 - c)  # u's node (row r, column i) sits at (i - 1/2, r), v's at (i, r - 1/2)
    iy = y + 0.5 * c
    wf = w.to(ix.dtype)
    hf = h.to(ix.dtype)
    kx = (ix > 0) & (ix < wf)
    ky = (iy > 0) & (iy < hf)
    ix = tl.minimum(tl.maximum(ix, 0.0), wf)
    iy = tl.minimum(tl.maximum(iy, 0.0), hf)
    x0 = tl.floor(ix)
    y0 = tl.floor(iy)
    i0 = x0.to(tl.int32)
    j0 = y0.to(tl.int32)
    # a node beyond the last one has weight 0; reading the last one instead keeps the address valid
    i1 = tl.minimum(i0 + 1, w)
    j1 = tl.minimum(j0 + 1, h)
    # extend's layout: u's padding row repeats row h - 1, v's padding column repeats column w - 1
    j0 = tl.minimum(j0, h - 1 + c)
    j1 = tl.minimum(j1, h - 1 + c)
    i0 = tl.minimum(i0, w - c)
    i1 = tl.minimum(i1, w - c)
    row = w + 1
    return j0 * row + i0, j0 * row + i1, j1 * row + i0, j1 * row + i1, ix - x0, iy - y0, kx, ky


@_jit
def _sample(plane, x, y, c, h, w, mask):
    """Component ``c`` (its ``plane``) at positions ``(x, y)``, bilinearly."""
    o00, o01, o10, o11, fx, fy, kx, ky = _nodes(x, y, c, h, w)
    v00 = tl.load(plane + o00, mask=mask, other=0.0)
    v01 = tl.load(plane + o01, mask=mask, other=0.0)
    v10 = tl.load(plane + o10, mask=mask, other=0.0)
    v11 = tl.load(plane + o11, mask=mask, other=0.0)
    return (1 - fy) * ((1 - fx) * v00 + fx * v01) + fy * ((1 - fx) * v10 + fx * v11)


@_jit
def _sample_adjoint(plane, grad_plane, x, y, c, h, w, g, mask, SCATTER: tl.constexpr):
    """The adjoint of :func:`_sample` for the gradient ``g`` of its result: adds ``g`` times each node's weight to
    ``grad_plane`` (when ``SCATTER``) and returns ``g`` times the sample's derivatives along x and y."""
    o00, o01, o10, o11, fx, fy, kx, ky = _nodes(x, y, c, h, w)
    v00 = tl.load(plane + o00, mask=mask, other=0.0)
    v01 = tl.load(plane + o01, mask=mask, other=0.0)
    v10 = tl.load(plane + o10, mask=mask, other=0.0)
    v11 = tl.load(plane + o11, mask=mask, other=0.0)
    if SCATTER:  # many faces or points read the same node: atomics
        tl.atomic_add(grad_plane + o00, g * (1 - fx) * (1 - fy), mask=mask, sem="relaxed")
        tl.atomic_add(grad_plane + o01, g * fx * (1 - fy), mask=mask, sem="relaxed")
        tl.atomic_add(grad_plane + o10, g * (1 - fx) * fy, mask=mask, sem="relaxed")
        tl.atomic_add(grad_plane + o11, g * fx * fy, mask=mask, sem="relaxed")
    gx = tl.where(kx, g * ((1 - fy) * (v01 - v00) + fy * (v11 - v10)), 0.0)
    gy = tl.where(ky, g * ((1 - fx) * (v10 - v00) + fx * (v11 - v01)), 0.0)
    return gx, gy


@_jit
def _trace(velocity, size, px, py, h, w, dt, mask):
    """The midpoint back-trace of points ``(px, py)`` through a sample's ``velocity`` (its two planes of ``size``):
    the midpoint ``m = p - dt/2 v(p)`` and the unclamped foot ``q = p - dt v(m)``."""
    half = 0.5 * dt
    mx = px - half * _sample(velocity, px, py, 0, h, w, mask)
    my = py - half * _sample(velocity + size, px, py, 1, h, w, mask)
    qx = px - dt * _sample(velocity, mx, my, 0, h, w, mask)
    qy = py - dt * _sample(velocity + size, mx, my, 1, h, w, mask)
    return mx, my, qx, qy


@_jit
def _clamp_slope(q, n):
    """The derivative of the clamp of ``q`` into ``[-1/2, n - 1/2]`` as the torch path's ``torch.clamp`` with tensor
    bounds takes it: 1 inside, 0 outside, 1/2 on a bound (a tie, split with the bound). Points the carry clamped
    onto a wall sit there exactly."""
    inside = (q > -0.5) & (q < n - 0.5)
    tie = (q == -0.5) | (q == n - 0.5)
    return tl.where(inside, 1.0, tl.where(tie, 0.5, 0.0))


@_jit
def _trace_adjoint(velocity, grad_velocity, size, px, py, h, w, dt, gx, gy, mask, SCATTER: tl.constexpr):
    """The adjoint of the clamped back-trace for the gradient ``(gx, gy)`` of the feet: adds the velocity's gradient
    to ``grad_velocity`` (when ``SCATTER``) and returns the gradient of the points ``(px, py)``."""
    mx, my, qx, qy = _trace(velocity, size, px, py, h, w, dt, mask)
    gqx = gx * _clamp_slope(qx, w)
    gqy = gy * _clamp_slope(qy, h)
    # q = p - dt v(m): v(m)'s gradient is -dt gq
    gmx_u, gmy_u = _sample_adjoint(velocity, grad_velocity, mx, my, 0, h, w, -dt * gqx, mask, SCATTER)
    gmx_v, gmy_v = _sample_adjoint(velocity + size, grad_velocity + size, mx, my, 1, h, w, -dt * gqy, mask, SCATTER)
    gmx = gmx_u + gmx_v
    gmy = gmy_u + gmy_v
    # m = p - dt/2 v(p): v(p)'s gradient is -dt/2 gm
    gpx_u, gpy_u = _sample_adjoint(velocity, grad_velocity, px, py, 0, h, w, -0.5 * dt * gmx, mask, SCATTER)
    gpx_v, gpy_v = _sample_adjoint(
        velocity + size, grad_velocity + size, px, py, 1, h, w, -0.5 * dt * gmy, mask, SCATTER
    )
    return gqx + gmx + gpx_u + gpx_v, gqy + gmy + gpy_u + gpy_v


@_jit
def _faces(blocks, h, w, BLOCK: tl.constexpr):
    """This program's plane (``2 b + c``), its component ``c``, the flat indices ``k`` of its nodes, which of
    them are in the plane, which are interior faces, and their positions ``(px, py)``."""
    pid = tl.program_id(0)
    plane = pid // blocks
    c = plane % 2
    k = (pid % blocks) * BLOCK + tl.arange(0, BLOCK)
    row = k // (w + 1)
    col = k % (w + 1)
    inside = k < (h + 1) * (w + 1)
    # u's interior faces: rows 0..h-1, columns 1..w-1; v's: rows 1..h-1, columns 0..w-1
    face = inside & (row >= c) & (row < h) & (col >= 1 - c) & (col < w)
    return plane, c, k, inside, face, col - 0.5 * (1 - c), row - 0.5 * c


@_kernel("h", "w", "blocks")
def _advect_faces(velocity, out, h, w, dt_hi, dt_lo, blocks, BLOCK: tl.constexpr):
    """Forward of :func:`advect_velocity`: one program per ``BLOCK`` nodes of one plane of ``out``."""
    dtype = velocity.dtype.element_ty
    dt = tl.cast(dt_hi, dtype) + tl.cast(dt_lo, dtype)
    size = (h + 1) * (w + 1)
    plane, c, k, inside, face, px, py = _faces(blocks, h, w, BLOCK)
    px = px.to(dtype)
    py = py.to(dtype)
    sample = velocity + (plane - c).to(tl.int64) * size  # this sample's u plane; its v plane follows
    _, _, qx, qy = _trace(sample, size, px, py, h, w, dt, face)
    fx = tl.minimum(tl.maximum(qx, -0.5), w - 0.5)
    fy = tl.minimum(tl.maximum(qy, -0.5), h - 0.5)
    value = _sample(sample + c * size, fx, fy, c, h, w, face)
    tl.store(out + plane.to(tl.int64) * size + k, tl.where(face, value, 0.0), mask=inside)


@_kernel("h", "w", "blocks")
def _advect_faces_adjoint(velocity, grad_out, grad_velocity, h, w, dt_hi, dt_lo, blocks, BLOCK: tl.constexpr):
    """Backward of :func:`advect_velocity`: each interior face scatters its gradient through its own read at the
    foot and through the back-trace. Walls and padding were written as constants and pass nothing."""
    dtype = velocity.dtype.element_ty
    dt = tl.cast(dt_hi, dtype) + tl.cast(dt_lo, dtype)
    size = (h + 1) * (w + 1)
    plane, c, k, inside, face, px, py = _faces(blocks, h, w, BLOCK)
    px = px.to(dtype)
    py = py.to(dtype)
    g = tl.load(grad_out + plane.to(tl.int64) * size + k, mask=face, other=0.0)
    offset = (plane - c).to(tl.int64) * size
    sample = velocity + offset
    grad_sample = grad_velocity + offset
    _, _, qx, qy = _trace(sample, size, px, py, h, w, dt, face)
    fx = tl.minimum(tl.maximum(qx, -0.5), w - 0.5)
    fy = tl.minimum(tl.maximum(qy, -0.5), h - 0.5)
    gfx, gfy = _sample_adjoint(sample + c * size, grad_sample + c * size, fx, fy, c, h, w, g, face, True)
    _trace_adjoint(sample, grad_sample, size, px, py, h, w, dt, gfx, gfy, face, True)


@_jit
def _points(points, n, ps_b, ps_n, ps_c, blocks, BLOCK: tl.constexpr):
    """This program's sample ``b``, the indices ``k`` of its ``BLOCK`` points, which of them exist, and their
    positions ``(px, py)``, read through the strides ``ps_*`` of ``points`` ``(B, N, 2)``."""
    pid = tl.program_id(0)
    b = (pid // blocks).to(tl.int64)
    k = ((pid % blocks) * BLOCK + tl.arange(0, BLOCK)).to(tl.int64)
    inside = k < n
    p = points + b * ps_b + k * ps_n
    return b, k, inside, tl.load(p, mask=inside, other=0.0), tl.load(p + ps_c, mask=inside, other=0.0)


@_kernel("n", "h", "w", "ps_b", "ps_n", "ps_c", "fs_b", "fs_n", "fs_c", "blocks")
def _backtrace(
    velocity, points, feet, n, h, w, ps_b, ps_n, ps_c, fs_b, fs_n, fs_c, dt_hi, dt_lo, blocks, BLOCK: tl.constexpr
):
    """Forward of :func:`backtrace`: one program per ``BLOCK`` points of one sample."""
    dtype = velocity.dtype.element_ty
    dt = tl.cast(dt_hi, dtype) + tl.cast(dt_lo, dtype)
    size = (h + 1) * (w + 1)
    b, k, inside, px, py = _points(points, n, ps_b, ps_n, ps_c, blocks, BLOCK)
    _, _, qx, qy = _trace(velocity + b * 2 * size, size, px, py, h, w, dt, inside)
    f = feet + b * fs_b + k * fs_n
    tl.store(f, tl.minimum(tl.maximum(qx, -0.5), w - 0.5), mask=inside)
    tl.store(f + fs_c, tl.minimum(tl.maximum(qy, -0.5), h - 0.5), mask=inside)


@_kernel("n", "h", "w", "ps_b", "ps_n", "ps_c", "blocks")
def _backtrace_adjoint(
    velocity, points, grad_feet, grad_velocity, grad_points, n, h, w, ps_b, ps_n, ps_c, dt_hi, dt_lo, blocks,
    BLOCK: tl.constexpr, VELOCITY_GRAD: tl.constexpr, POINTS_GRAD: tl.constexpr,
):  # fmt: skip
    """Backward of :func:`backtrace`; ``grad_feet`` and ``grad_points`` are contiguous ``(B, N, 2)``."""
    dtype = velocity.dtype.element_ty
    dt = tl.cast(dt_hi, dtype) + tl.cast(dt_lo, dtype)
    size = (h + 1) * (w + 1)
    b, k, inside, px, py = _points(points, n, ps_b, ps_n, ps_c, blocks, BLOCK)
    g = grad_feet + (b * n + k) * 2
    gx = tl.load(g, mask=inside, other=0.0)
    gy = tl.load(g + 1, mask=inside, other=0.0)
    offset = b * 2 * size
    gpx, gpy = _trace_adjoint(
        velocity + offset, grad_velocity + offset, size, px, py, h, w, dt, gx, gy, inside, VELOCITY_GRAD
    )
    if POINTS_GRAD:
        tl.store(grad_points + (b * n + k) * 2, gpx, mask=inside)
        tl.store(grad_points + (b * n + k) * 2 + 1, gpy, mask=inside)
