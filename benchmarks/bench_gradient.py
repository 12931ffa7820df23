"""Benchmark of one keyframe gradient: what it costs over a forward, where that goes, three trials that did not help.

Issue #20: one gradient of the keyframe objective costs 2.6-3.3x a forward, where the adjoint's theory says about
2x. This script measures where the time goes, so that what is not inherent can be removed, and it keeps two
attempts at a faster keyframe fit that did not help, so that anyone can rerun them.

**Set-up.** The paper's keyframe problem exactly as ``bench_keyframes.py`` builds it: its flow instance of seed 0
(``flow_instance(0, 14, (64, 64), 10)``: 14 points in a 64x64-pixel frame, targets 5 to 10 px away, made by a
brush-driven flow), fitted by :func:`~torchfluidwarp.control.fit_keyframes` on a 64x64 fluid over 10 steps with
the paper's 500 control parameters (``control=(5, 5)``), tolerance 0.05 px, float32. Everything is measured at
the forces of that fit (as ``bench_keyframes.py``'s gradient measurement is), in float32, with ``--threads``
torch threads (default 1). Timings are medians of ``--repeats`` interleaved repeats, by ``time.perf_counter``.
The viscosity is zero, so the step's diffusion is the identity and costs nothing.

**Measurements.**

1. *Whole objective*: ``fit_keyframes``' objective reproduced (the roll-out's velocities
   ``fit.warp.rollout(fit.forces, (64, 64)).velocities``, the points carried through them by
   ``torchfluidwarp.warp.layer._carry``, and :func:`~torchfluidwarp.control.keyframe_loss`). One forward without
   grad, the same forward building autograd's graph, and the backward alone; the gradient (graph forward +
   backward) over the forward (target: at most 2x).
2. *Per stage*, summed over the 10 steps of the fitted roll-out, each stage alone on the inputs it sees there
   (recorded by re-running the simulator's step modules, and checked against the roll-out): the force (the
   ``ControlGrid`` forward and ``faces_from_cells``, one call for all steps, as the simulator makes it), the
   velocity's self-advection (``_advect_velocity`` on the velocity after the previous step plus ``dt`` times
   this step's force on the faces), the pressure projection (``project``), and carrying the 14 points through
   each step's velocity (``_advect_points``, channel-first, in fluid cells). Forward without grad against forward
   + backward of ``sum(output * R)`` for a fixed random ``R`` (per step; the steps' losses summed and
   backpropagated at once, as the roll-out's are: a backward per step would add ten starts of autograd's
   engine); per stage the ratio, and what it adds over 2x its forward. The objective's own figures are timed in
   the same repeats; what the stages do not cover (checks, stacking, the loss) is the rest.
3. *Kernels*: 5 gradients and 5 forwards under ``torch.profiler`` (CPU), each in its own session, interleaved,
   after a session that is thrown away (the first in a process pays the profiler's start-up and inflated the
   forward by half); the mean self CPU time per gradient (and per forward) grouped into ``grid_sample``'s
   forward reads (``aten::grid_sampler_2d``, with its dispatch wrapper ``aten::grid_sampler``), its backward
   kernel (``aten::grid_sampler_2d_backward``), matrix products and convolutions (``aten::mm``, ``bmm``,
   ``matmul``, ``_slow_conv2d*``: the pressure solve's DCTs and divergence, and the control grid's upsampling)
   and everything else; ``aten`` calls per gradient. The profiler inflates the times of small operators, so
   shares matter more than milliseconds. The last columns split the gradient's excess over 2x the forward by
   group: ``grid_sample``'s (the issue puts its CPU backward kernel at about 4x its forward read and calls that
   inherent; the ratio measured here is printed) against the rest. ``grid_sample``'s profiled excess is also
   set against the unprofiled excess of 1.

**Trials** (skipped with ``--no-trials``):

4. *Trial A: a hand-written adjoint of the self-advection.* A ``torch.autograd.Function`` whose forward runs the
   same reads without a graph and keeps their sampling grids and the clamp mask, and whose backward walks the
   three reads in reverse with ``torch.ops.aten.grid_sampler_2d_backward`` called directly, instead of the
   nodes autograd tapes (about 30 here). It is first checked against ``_advect_velocity`` (output and gradient within
   1e-5 on every step's fitted velocity), then both are timed, forward and forward + backward, interleaved, on
   each of the 10 steps' velocities. It was found no faster (1.04 ms against 1.04 ms forward + backward per step
   in the ad-hoc timing that first tried it): the three ``grid_sampler_2d_backward`` kernels stay, with a dozen
   indexing and element-wise operators around them, so what autograd's taping cost was not where the time went.
5. *Trial B: preconditioning L-BFGS by the linearised problem.* On flow instances 0 to 4 (``--trial-seeds``),
   the plain fit against L-BFGS in coordinates ``z`` with ``weight = M z``, where ``M = V S^-1 V^T + gamma
   (I - V V^T)``, ``gamma = 1 / median(S)``, from the SVD of the exact Jacobian ``J0`` (28 x 500, by
   ``torch.autograd.functional.jacobian``) of the carried points' final positions at zero forces. Both run
   :func:`~torchfluidwarp.control.optim.minimize` with ``fit_keyframes``' stop criterion (every point within
   0.05 px); ``fit_keyframes``' own evaluation count is shown as a check of the plain re-implementation.
   Reported: evaluations and seconds per instance for both, and the Jacobian's cost. It did not make the fit
   faster: in the run that recorded it, it needed about as many evaluations in all (fewer on some instances,
   more on others) and more time, before the Jacobian's cost of some 15 gradients per instance.

6. *Trial C: ``torch.compile``* (with ``--compile-trial``; off by default: it compiles for about half a minute
   and needs a C++ compiler). The self-advection compiled by inductor for the CPU against eager, forward and
   forward + backward on every step's velocity, and the first call's time, compilation included. The issue asks
   for ``torch.compile`` only where it helps without slowing the first call; the trial shows whether it helps at
   all.

7. *grid_sample's kernels alone* (always run, after 3.): on the three grids the self-advection of the roll-out's
   middle step reads with (every face, the midpoints, the feet), ``torch.grid_sampler_2d`` against its backward
   kernel asked for both gradients, the image's alone and the grid's alone; medians of interleaved repeats. It
   bounds what any rewrite around the kernel could win: the gradient were each backward kernel no dearer than
   its read.

Trial B is a fixed preconditioner. The quasi-Newton start that did make the fit faster
(:mod:`torchfluidwarp.control.newton`) learns its Jacobian as it goes; ``bench_keyframes.py`` measures it. This
script fits with ``method="lbfgs"``, so the forces it times gradients at are those of earlier runs.

Run ``python benchmarks/bench_gradient.py --help`` for the options.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, cast

import torch
import torch.nn.functional as F
from _common import (
    add_threads_argument,
    describe_load,
    machine,
    machine_load,
    source_fingerprint,
    table,
    verdict,
    write_json,
)
from bench_keyframes import flow_instance
from torch import Tensor
from torch.autograd.function import once_differentiable
from torch.func import functional_call
from torch.profiler import ProfilerActivity, profile

from torchfluidwarp.control import fit_keyframes, keyframe_loss
from torchfluidwarp.control.optim import minimize
from torchfluidwarp.core.advection import _advect_points, _advect_velocity, _clamp, _extend, _geo
from torchfluidwarp.core.fluid import faces_from_cells, project
from torchfluidwarp.core.grid import rescale_points
from torchfluidwarp.core.sampling import sample
from torchfluidwarp.warp import ControlGrid, FluidWarp
from torchfluidwarp.warp.layer import _carry
from torchfluidwarp.warp.maps import _cell_scale

FRAME = (64, 64)  # image size, pixels
GRID = (64, 64)  # fluid cells
STEPS = 10
POINTS = 14
CONTROL = (5, 5)
TOLERANCE = 0.05  # px
DT = 1.0
DTYPE = torch.float32
TARGET_RATIO = 2.0
EQUAL_WITHIN = 1e-5
# L-BFGS alone (not the quasi-Newton start of method="auto"): the forces at which gradients are timed are those of
# earlier runs, and trial B checks its plain re-implementation against fit_keyframes' evaluation count
FIT_KWARGS: dict[str, Any] = dict(
    image_size=FRAME,
    grid=GRID,
    steps=STEPS,
    control=CONTROL,
    tolerance=TOLERANCE,
    dtype=DTYPE,
    progress=False,
    method="lbfgs",
)

log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731


def median_ms(times: list[float]) -> float:
    return statistics.median(times) * 1e3


# ----------------------------------------------------------------------------------------------- the problem


@dataclass
class Problem:
    """The fitted keyframe problem: the fit's warp and forces, points ``(1, M, 2)`` px, and the objective's data."""

    warp: FluidWarp
    forces: ControlGrid
    source: Tensor
    target: Tensor
    weights: Tensor
    evaluations: int
    message: str

    def objective(self) -> Tensor:
        """``fit_keyframes``' objective: roll-out, points carried through it, keyframe loss (pixels^2)."""
        vel = self.warp.rollout(self.forces, FRAME).velocities
        paths = _carry(vel, self.source, FRAME, DT)  # (1, T + 1, M, 2) pixels
        return keyframe_loss(paths, [(STEPS, self.target)], self.weights)


def fitted_problem(seed: int) -> Problem:
    src, tgt = flow_instance(seed, POINTS, GRID, STEPS).tensors(DTYPE)
    fit = fit_keyframes(src, tgt, **FIT_KWARGS)
    weights = torch.ones(1, POINTS, dtype=DTYPE)  # fit_keyframes' default
    forces = cast(ControlGrid, fit.forces)  # its default force module
    return Problem(fit.warp, forces, src[None], tgt[None], weights, fit.evaluations, fit.message)


@dataclass
class Recorded:
    """What each stage sees in the fitted roll-out, per step: the velocity entering the self-advection, the
    advected velocity entering the projection, the step's velocity, and the points at its start ``(1, 2, M)``
    in fluid cells (channel-first)."""

    entering: list[Tensor]
    advected: list[Tensor]
    velocities: list[Tensor]
    points: list[Tensor]
    velocity_error: float
    points_error: float


@torch.no_grad()
def record(p: Problem) -> Recorded:
    """Re-run the simulator's step modules on the fitted forces, and check them against the roll-out."""
    warp, step = p.warp, p.warp.simulator.step
    h, w = warp.grid.shape
    mu = warp.simulator.current_viscosity(1, FRAME)
    on_faces = faces_from_cells(p.forces(warp.grid, STEPS, DT, FRAME).flatten(0, 1)).view(1, STEPS, 2, h + 1, w + 1)
    v = on_faces.new_zeros(1, 2, h + 1, w + 1)
    c = _cell_scale(FRAME, h, w, p.source)
    pts = rescale_points(p.source.transpose(1, 2), c)  # (1, 2, M) cells
    entering, advected, velocities, points = [], [], [], []
    for t in range(STEPS):
        entering.append(step.add_force(v, on_faces[:, t], staggered=True))
        advected.append(step.advect(entering[-1]))
        v, _ = step.diffuse(advected[-1], mu)  # zero viscosity: the identity
        v, _ = step.project(v)
        velocities.append(v)
        points.append(pts)
        pts = _advect_points(pts, v, DT)
    vel = warp.rollout(p.forces, FRAME).velocities
    paths = _carry(vel, p.source, FRAME, DT)
    mine = rescale_points(torch.stack([*points, pts], 1), c.unsqueeze(1), inverse=True).transpose(2, 3)
    return Recorded(
        entering,
        advected,
        velocities,
        points,
        velocity_error=float((torch.stack(velocities, 1) - vel).abs().max()),
        points_error=float((mine - paths).abs().max()),
    )


# ----------------------------------------------------------------------------------------------- 1. and 2.


@dataclass
class Stage:
    """One stage, timed alone: ``forward()`` (no grad) and ``gradient()`` (forward + backward)."""

    name: str
    forward: Callable[[], None]
    gradient: Callable[[], None]


def stages(p: Problem, rec: Recorded) -> list[Stage]:
    gen = torch.Generator().manual_seed(0)
    step = p.warp.simulator.step
    grid = p.warp.grid

    def leaf(x: Tensor, grad: bool = True) -> Tensor:
        return x.detach().clone().requires_grad_(grad)

    def cotangent(like: Tensor) -> Tensor:
        return torch.randn(like.shape, generator=gen, dtype=like.dtype)

    def force() -> Tensor:
        return faces_from_cells(p.forces(grid, STEPS, DT, FRAME).flatten(0, 1))

    def proj(x: Tensor) -> Tensor:
        return project(x, config=step.project.config, adjoint_config=step.project.adjoint_config)

    params = [q for q in p.forces.parameters() if q.requires_grad]
    r_force = cotangent(force().detach())
    entering = [leaf(x) for x in rec.entering]
    advected = [leaf(x) for x in rec.advected]
    velocities = [leaf(x) for x in rec.velocities]
    points = [leaf(x, t > 0) for t, x in enumerate(rec.points)]  # the sources need no gradient
    r_adv = [cotangent(x) for x in entering]
    r_proj = [cotangent(x) for x in advected]
    r_pts = [cotangent(x) for x in points]

    def per_step(name: str, fn: Callable[..., Tensor], inputs: list[tuple[Tensor, ...]], rs: list[Tensor]) -> Stage:
        def forward() -> None:
            with torch.no_grad():
                for args in inputs:
                    fn(*args)

        def gradient() -> None:
            # one backward for all steps, as in the roll-out (a backward per step would start autograd's engine
            # ten times)
            loss = 0.0
            for args, r in zip(inputs, rs):
                for x in args:
                    x.grad = None
                loss = loss + (fn(*args) * r).sum()
            loss.backward()  # type: ignore[union-attr]

        return Stage(name, forward, gradient)

    def force_forward() -> None:
        with torch.no_grad():
            force()

    def force_gradient() -> None:
        for q in params:
            q.grad = None
        (force() * r_force).sum().backward()

    return [
        Stage("force (ControlGrid + faces_from_cells)", force_forward, force_gradient),
        per_step(
            "self-advection (_advect_velocity)", lambda v: _advect_velocity(v, DT), [(v,) for v in entering], r_adv
        ),
        per_step("projection (project)", proj, [(v,) for v in advected], r_proj),
        per_step(
            f"carry {POINTS} points (_advect_points)",
            lambda x, v: _advect_points(x, v, DT),
            list(zip(points, velocities)),
            r_pts,
        ),
    ]


@dataclass
class ObjectiveRow:
    repeats: int
    forward_ms: float
    graph_forward_ms: float
    backward_ms: float
    gradient_ms: float
    graph_over_forward: float
    backward_over_forward: float
    ratio: float
    autograd_nodes: int


@dataclass
class StageRow:
    stage: str
    forward_ms: float
    gradient_ms: float
    ratio: float
    excess_ms: float  # gradient - 2 forward


def graph_nodes(t: Tensor) -> int:
    """Nodes of the autograd graph behind ``t`` (accumulators of leaves included)."""
    seen, todo = set(), [t.grad_fn]
    while todo:
        node = todo.pop()
        if node is None or node in seen:
            continue
        seen.add(node)
        todo.extend(n for n, _ in node.next_functions)
    return len(seen)


def time_objective_and_stages(p: Problem, rec: Recorded, repeats: int) -> tuple[ObjectiveRow, list[StageRow]]:
    """Sections 1 and 2 in the same interleaved repeats."""
    params = [q for q in p.forces.parameters() if q.requires_grad]
    st = stages(p, rec)

    def forward() -> None:
        with torch.no_grad():
            p.objective()

    forward()
    for q in params:
        q.grad = None
    loss = p.objective()
    nodes = graph_nodes(loss)
    loss.backward()  # warm-up
    for s in st:
        s.forward()
        s.gradient()
    f_t: list[float] = []
    g_t: list[float] = []
    b_t: list[float] = []
    sf_t: dict[str, list[float]] = {s.name: [] for s in st}
    sg_t: dict[str, list[float]] = {s.name: [] for s in st}
    for _ in range(repeats):
        t0 = time.perf_counter()
        forward()
        t1 = time.perf_counter()
        for q in params:
            q.grad = None
        loss = p.objective()
        t2 = time.perf_counter()
        loss.backward()
        t3 = time.perf_counter()
        f_t.append(t1 - t0)
        g_t.append(t2 - t1)
        b_t.append(t3 - t2)
        for s in st:
            t0 = time.perf_counter()
            s.forward()
            t1 = time.perf_counter()
            s.gradient()
            t2 = time.perf_counter()
            sf_t[s.name].append(t1 - t0)
            sg_t[s.name].append(t2 - t1)
    f, g, b = median_ms(f_t), median_ms(g_t), median_ms(b_t)
    grad = median_ms([x + y for x, y in zip(g_t, b_t)])
    obj = ObjectiveRow(repeats, f, g, b, grad, g / f, b / f, grad / f, nodes)
    rows = []
    for s in st:
        sf, sg = median_ms(sf_t[s.name]), median_ms(sg_t[s.name])
        rows.append(StageRow(s.name, sf, sg, sg / sf, sg - 2 * sf))
    return obj, rows


def report_objective(o: ObjectiveRow) -> str:
    return "\n".join(
        [
            f"1. Whole objective: one gradient against one forward (ms, medians of {o.repeats} interleaved repeats)",
            table(
                [
                    "forward (no grad)",
                    "forward with graph",
                    "backward",
                    "gradient",
                    "graph fwd / fwd",
                    "backward / fwd",
                    "gradient / fwd",
                    "autograd nodes",
                    f"target <= {TARGET_RATIO:g}x",
                ],
                [
                    [
                        f"{o.forward_ms:.2f}",
                        f"{o.graph_forward_ms:.2f}",
                        f"{o.backward_ms:.2f}",
                        f"{o.gradient_ms:.2f}",
                        f"{o.graph_over_forward:.2f}x",
                        f"{o.backward_over_forward:.2f}x",
                        f"{o.ratio:.2f}x",
                        str(o.autograd_nodes),
                        verdict(o.ratio <= TARGET_RATIO),
                    ]
                ],
            ),
            "gradient = forward with graph + backward (median of their sums)",
        ]
    )


def report_stages(o: ObjectiveRow, rows: list[StageRow]) -> str:
    def line(name: str, f: float, g: float) -> list[str]:
        ratio = f"{g / f:.2f}x" if f > 0 else ""
        return [name, f"{f:.2f}", f"{g:.2f}", f"{g - f:.2f}", ratio, f"{g - 2 * f:+.2f}", f"{g / grad:.0%}"]

    grad = o.gradient_ms
    sf, sg = sum(r.forward_ms for r in rows), sum(r.gradient_ms for r in rows)
    body = [line(r.stage, r.forward_ms, r.gradient_ms) for r in rows]
    body.append(line("sum of the stages", sf, sg))
    body.append(line("whole objective (1.)", o.forward_ms, grad))
    body.append(line("rest (objective - stages)", o.forward_ms - sf, grad - sg))
    return "\n".join(
        [
            f"2. Per stage, summed over the {STEPS} steps of the fitted roll-out, each alone on its recorded inputs "
            "(ms, same repeats as 1.)",
            table(
                ["stage", "fwd", "fwd+bwd", "bwd", "fwd+bwd / fwd", "fwd+bwd - 2 fwd", "share of the gradient"],
                body,
            ),
            "a stage's backward is that of sum(output * R), R fixed and random; 'rest' holds the roll-out's checks "
            "and stacking, the loss, and the gaps between stages",
        ]
    )


# ----------------------------------------------------------------------------------------------- 3. kernels

GROUPS = [
    "grid_sample forward reads",
    "grid_sample backward kernel",
    "matrix products and convolutions",
    "everything else",
]


def group_of(key: str) -> str:
    if key in ("aten::grid_sampler_2d", "aten::grid_sampler"):
        return GROUPS[0]
    if key == "aten::grid_sampler_2d_backward":
        return GROUPS[1]
    if key in ("aten::mm", "aten::bmm", "aten::matmul") or key.startswith("aten::_slow_conv2d"):
        return GROUPS[2]
    return GROUPS[3]


@dataclass
class KernelRow:
    group: str
    forward_ms: float
    forward_share: float
    forward_calls: float
    gradient_ms: float
    gradient_share: float
    gradient_calls: float
    excess_ms: float  # gradient - 2 forward


def profile_groups(fn: Callable[[], None], acc: dict[str, list[float]]) -> None:
    """Add the self CPU ms and ``aten`` calls of one call of ``fn``, profiled on its own, to ``acc`` by group."""
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        fn()
    for evt in prof.key_averages():
        into = acc[group_of(evt.key)]
        into[0] += evt.self_cpu_time_total / 1e3
        into[1] += evt.count if evt.key.startswith("aten::") else 0


def profile_kernels(p: Problem, n: int) -> list[KernelRow]:
    """``n`` forwards and ``n`` gradients, each in its own profiler session, interleaved, after a session that
    is thrown away (the first one in a process pays the profiler's start-up)."""
    params = [q for q in p.forces.parameters() if q.requires_grad]

    def forward() -> None:
        with torch.no_grad():
            p.objective()

    def gradient() -> None:
        for q in params:
            q.grad = None
        p.objective().backward()

    fwd = {g: [0.0, 0.0] for g in GROUPS}
    grad = {g: [0.0, 0.0] for g in GROUPS}
    profile_groups(forward, {g: [0.0, 0.0] for g in GROUPS})  # warm-up
    for _ in range(n):
        profile_groups(forward, fwd)
        profile_groups(gradient, grad)
    for acc in (fwd, grad):
        for g in GROUPS:
            acc[g] = [x / n for x in acc[g]]
    f_total, g_total = sum(v[0] for v in fwd.values()), sum(v[0] for v in grad.values())
    rows = [
        KernelRow(
            g,
            fwd[g][0],
            fwd[g][0] / f_total,
            fwd[g][1],
            grad[g][0],
            grad[g][0] / g_total,
            grad[g][1],
            grad[g][0] - 2 * fwd[g][0],
        )
        for g in GROUPS
    ]
    rows.append(
        KernelRow(
            "total",
            f_total,
            1.0,
            sum(v[1] for v in fwd.values()),
            g_total,
            1.0,
            sum(v[1] for v in grad.values()),
            g_total - 2 * f_total,
        )
    )
    return rows


def report_kernels(rows: list[KernelRow], n: int, o: ObjectiveRow) -> str:
    total = rows[-1]
    wall_excess = o.gradient_ms - 2 * o.forward_ms
    body = [
        [
            r.group,
            f"{r.forward_ms:.2f}",
            f"{r.forward_share:.0%}",
            f"{r.forward_calls:.0f}",
            f"{r.gradient_ms:.2f}",
            f"{r.gradient_share:.0%}",
            f"{r.gradient_calls:.0f}",
            f"{r.excess_ms:+.2f}",
            f"{r.excess_ms / total.excess_ms:.0%}" if total.excess_ms else "",
        ]
        for r in rows
    ]
    gs = rows[0].excess_ms + rows[1].excess_ms
    return "\n".join(
        [
            f"3. Kernels: self CPU time per forward and per gradient, means of {n} of each under torch.profiler, "
            "one per session, interleaved (PROFILED times, inflated by the profiler's per-operator overhead: read "
            "the shares)",
            table(
                [
                    "group",
                    "fwd ms",
                    "fwd share",
                    "fwd aten calls",
                    "gradient ms",
                    "gradient share",
                    "gradient aten calls",
                    "gradient - 2 fwd ms",
                    "share of the excess",
                ],
                body,
            ),
            f"profiled gradient / forward {total.gradient_ms / total.forward_ms:.2f}x; of the gradient's excess over "
            f"2x the forward ({total.excess_ms:.2f} ms profiled), grid_sample (its backward kernel less the one "
            f"forward read it replaces) accounts for {gs:.2f} ms ({gs / total.excess_ms:.0%}), the rest for "
            f"{total.excess_ms - gs:.2f} ms ({1 - gs / total.excess_ms:.0%})",
            f"unprofiled (1.): the excess is {wall_excess:.2f} ms, and grid_sample's profiled excess would be "
            f"{gs / wall_excess:.0%} of it; grid_sampler_2d_backward / forward reads (profiled): "
            f"{rows[1].gradient_ms / rows[0].forward_ms:.2f}x",
            "grid_sample forward reads = aten::grid_sampler_2d and its dispatch wrapper aten::grid_sampler; matrix "
            "products = aten::mm, bmm, matmul, _slow_conv2d* (the pressure solve's DCTs and divergence, the control "
            "grid's upsampling)",
        ]
    )


# ----------------------------------------------------------------------------------------------- 4. trial A


def _read(extended: Tensor, points: Tensor, geo: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
    """Each velocity component at its own channel-first points ``(B, 2 components, 2, N)`` (or ``(B, 1, 2, N)``
    for both at the same points) from the extended layout ``(2B, 1, h + 1, w + 1)``: ``(B, 2, N)``, and the
    ``grid_sample`` grid ``(2B, N, 1, 2)`` that read them."""
    B, _, _, N = points.shape
    grid = torch.addcmul(geo["t2"], points, geo["s2"]).transpose(2, 3).reshape(2 * B, N, 1, 2)
    return sample(extended, grid, align_corners=True, check=None).view(B, 2, N), grid


def _vjp(extended: Tensor, grid: Tensor, grad: Tensor, positions: bool) -> tuple[Tensor, Tensor]:
    # grid_sample's own backward kernel; interpolation 0 = bilinear, padding 1 = border: those of sample()
    B, _, N = grad.shape
    return torch.ops.aten.grid_sampler_2d_backward(
        grad.reshape(2 * B, 1, N, 1), extended, grid, 0, 1, True, [True, positions]
    )


def _read_vjp(extended: Tensor, grid: Tensor, grad: Tensor, geo: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
    """Adjoint of :func:`_read`: ``grad`` ``(B, 2, N)`` -> the gradient of the extended layout
    ``(2B, 1, h + 1, w + 1)`` and that of each component's sampling position ``(B, 2 components, 2, N)``, in
    fluid cells."""
    d_ext, d_grid = _vjp(extended, grid, grad, positions=True)
    B, _, N = grad.shape
    return d_ext, d_grid.view(B, 2, N, 2).transpose(2, 3) * geo["s2"]


def _fused_forward(velocity: Tensor, dt: float) -> tuple[Tensor, tuple[Tensor, ...]]:
    """``_advect_velocity``'s operations, and what the adjoint needs: the extended velocity, the three reads'
    grids and the clamp mask of the feet."""
    B, h, w = velocity.shape[0], velocity.shape[-2] - 1, velocity.shape[-1] - 1
    geo = _geo(h, w, velocity)
    ext = _extend(velocity)  # (2B, 1, h + 1, w + 1)
    faces = geo["faces"].expand(B, -1, -1)  # (B, 2, N) every interior face
    v1, g1 = _read(ext, faces.unsqueeze(1), geo)
    mid = faces - (0.5 * dt) * v1
    v2, g2 = _read(ext, mid.unsqueeze(1), geo)
    raw = faces - dt * v2
    feet = _clamp(raw, geo)
    inside = feet == raw  # the clamp passes the gradient where it did not move the foot
    nu, nv = h * (w - 1), (h - 1) * w
    n = max(nu, nv)
    feet_u, feet_v = feet[..., :nu], feet[..., nu:]
    if nu != nv:
        feet_u, feet_v = (F.pad(f, (0, n - f.shape[-1]), mode="replicate") for f in (feet_u, feet_v))
    sampled, g3 = _read(ext, torch.stack([feet_u, feet_v], dim=1), geo)  # (B, 2, n)
    values = torch.cat([sampled[:, 0, :nu], sampled[:, 1, :nv]], dim=1)
    out = values.new_zeros(B, 2 * (h + 1) * (w + 1)).index_copy(1, geo["face_index"], values)
    return out.view(B, 2, h + 1, w + 1), (ext, g1, g2, g3, inside)


class FusedSelfAdvection(torch.autograd.Function):
    """Self-advection of a staggered velocity ``(B, 2, h + 1, w + 1)`` with a hand-written backward: the
    adjoint of the semi-Lagrangian step (McNamara et al. 2004), one ``grid_sampler_2d_backward`` per forward read
    in reverse order, then one scatter of the extended layout back onto the faces. The forward's intermediates
    are extra, non-differentiable outputs, the way ``setup_context`` sees them."""

    @staticmethod
    def forward(velocity: Tensor, dt: float) -> tuple[Tensor, ...]:  # type: ignore[override]
        out, saved = _fused_forward(velocity, dt)
        return (out, *saved)

    @staticmethod
    def setup_context(ctx: Any, inputs: tuple[Tensor, float], output: tuple[Tensor, ...]) -> None:
        ctx.mark_non_differentiable(*output[1:])
        ctx.set_materialize_grads(False)
        ctx.save_for_backward(*output[1:])
        ctx.dt, ctx.shape = inputs[1], inputs[0].shape

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad_out: Tensor | None, *_: Any) -> tuple[Tensor | None, None]:
        if grad_out is None or not ctx.needs_input_grad[0]:
            return None, None
        ext, g1, g2, g3, inside = ctx.saved_tensors
        dt, shape = ctx.dt, ctx.shape
        B, h, w = shape[0], shape[-2] - 1, shape[-1] - 1
        geo = _geo(h, w, grad_out)
        nu, nv = h * (w - 1), (h - 1) * w
        n = max(nu, nv)
        g_values = grad_out.reshape(B, -1).index_select(1, geo["face_index"])
        g_sampled = torch.stack([F.pad(g_values[:, :nu], (0, n - nu)), F.pad(g_values[:, nu:], (0, n - nv))], 1)
        d_ext, d_feet = _read_vjp(ext, g3, g_sampled, geo)  # d_feet (B, 2, 2, n)
        d_raw = torch.cat([d_feet[:, 0, :, :nu], d_feet[:, 1, :, :nv]], dim=-1) * inside  # (B, 2, N)
        e2, d_mid = _read_vjp(ext, g2, d_raw.mul_(-dt), geo)  # raw = faces - dt v(mid)
        # mid = faces - dt/2 v(faces): the faces are constants, so only the velocity's gradient
        e1, _ = _vjp(ext, g1, d_mid.sum(1).mul_(-0.5 * dt), positions=False)
        d_ext = d_ext.add_(e2).add_(e1).reshape(B, -1)
        grad_velocity = d_ext.new_zeros(B, shape[1] * shape[2] * shape[3])
        grad_velocity.index_add_(1, geo["extend_index"], d_ext)  # the adjoint of _extend's gather
        return grad_velocity.view(shape), None


def fused_self_advection(velocity: Tensor, dt: float) -> Tensor:
    if torch.is_grad_enabled() and velocity.requires_grad:
        return FusedSelfAdvection.apply(velocity, dt)[0]
    return _fused_forward(velocity, dt)[0]


@dataclass
class TrialARow:
    step: int
    output_diff: float
    gradient_diff: float
    autograd_forward_ms: float
    fused_forward_ms: float
    autograd_gradient_ms: float
    fused_gradient_ms: float
    ratio: float  # fused / autograd, forward + backward


def trial_a(rec: Recorded, repeats: int) -> tuple[list[TrialARow], tuple[int, int]]:
    gen = torch.Generator().manual_seed(1)
    inputs = [x.detach().clone().requires_grad_() for x in rec.entering]
    rs = [torch.randn(x.shape, generator=gen, dtype=x.dtype) for x in inputs]
    impls = {"autograd": lambda v: _advect_velocity(v, DT), "fused": lambda v: fused_self_advection(v, DT)}
    diffs = []
    for v, r in zip(inputs, rs):
        outs, grads = [], []
        for fn in impls.values():
            out = fn(v)
            outs.append(out.detach())
            grads.append(torch.autograd.grad((out * r).sum(), v)[0])
        diffs.append((float((outs[0] - outs[1]).abs().max()), float((grads[0] - grads[1]).abs().max())))
    nodes = (graph_nodes(impls["autograd"](inputs[0])), graph_nodes(impls["fused"](inputs[0])))
    worst = max(max(d) for d in diffs)
    if not worst <= EQUAL_WITHIN:
        raise RuntimeError(f"trial A: the fused self-advection differs from _advect_velocity by {worst:.3g}")

    times = {(t, k, m): [] for t in range(STEPS) for k in impls for m in ("fwd", "grad")}
    for _ in range(repeats + 1):  # the first round warms up
        for t, (v, r) in enumerate(zip(inputs, rs)):
            for k, fn in impls.items():
                t0 = time.perf_counter()
                with torch.no_grad():
                    fn(v)
                t1 = time.perf_counter()
                v.grad = None
                (fn(v) * r).sum().backward()
                t2 = time.perf_counter()
                times[(t, k, "fwd")].append(t1 - t0)
                times[(t, k, "grad")].append(t2 - t1)
    rows = []
    for t in range(STEPS):
        m = {key[1:]: median_ms(v[1:]) for key, v in times.items() if key[0] == t}
        rows.append(
            TrialARow(
                t,
                *diffs[t],
                m[("autograd", "fwd")],
                m[("fused", "fwd")],
                m[("autograd", "grad")],
                m[("fused", "grad")],
                m[("fused", "grad")] / m[("autograd", "grad")],
            )
        )
    return rows, nodes


def report_trial_a(rows: list[TrialARow], nodes: tuple[int, int], repeats: int) -> str:
    body = [
        [
            str(r.step),
            f"{r.output_diff:.1e}",
            f"{r.gradient_diff:.1e}",
            f"{r.autograd_forward_ms:.3f}",
            f"{r.fused_forward_ms:.3f}",
            f"{r.autograd_gradient_ms:.3f}",
            f"{r.fused_gradient_ms:.3f}",
            f"{r.ratio:.2f}x",
        ]
        for r in rows
    ]
    sums = [sum(getattr(r, f) for r in rows) for f in ("autograd_forward_ms", "fused_forward_ms")]
    sums += [sum(getattr(r, f) for r in rows) for f in ("autograd_gradient_ms", "fused_gradient_ms")]
    body.append(
        [
            "sum",
            f"{max(r.output_diff for r in rows):.1e}",
            f"{max(r.gradient_diff for r in rows):.1e}",
            *(f"{s:.3f}" for s in sums),
            f"{sums[3] / sums[2]:.2f}x",
        ]
    )
    return "\n".join(
        [
            "4. Trial A: hand-written adjoint of the self-advection against autograd through _advect_velocity, on "
            f"each step's fitted velocity (ms, medians of {repeats} interleaved repeats)",
            table(
                [
                    "step",
                    "max |out diff|",
                    "max |grad diff|",
                    "autograd fwd",
                    "fused fwd",
                    "autograd fwd+bwd",
                    "fused fwd+bwd",
                    "fused / autograd (fwd+bwd)",
                ],
                body,
            ),
            f"equal within {EQUAL_WITHIN:g} (float32): checked; autograd nodes behind one output (the input's "
            f"accumulator included): {nodes[0]} taped by autograd, {nodes[1]} with the Function; the fused forward "
            "without grad also computes the clamp mask that its backward keeps",
        ]
    )


# ----------------------------------------------------------------------------------------------- 5. trial B


@dataclass
class TrialBRow:
    seed: int
    fit_keyframes_evaluations: int
    plain_evaluations: int
    plain_seconds: float
    plain_max_error: float
    precond_evaluations: int
    precond_seconds: float
    precond_max_error: float
    jacobian_seconds: float
    singular_values: tuple[float, float, float]  # min, median, max


def trial_b_fit(p: Problem, M: Tensor | None) -> tuple[int, float, float]:
    """L-BFGS on the control grid's weight ``M z`` (``z`` itself without ``M``) from zero, with ``fit_keyframes``'
    stop criterion: evaluations, seconds and the final max error (px)."""
    shape = p.forces.weight.shape
    z = torch.zeros(shape.numel(), dtype=DTYPE, requires_grad=True)
    last: dict[str, Tensor] = {}

    def objective() -> Tensor:
        weight = z if M is None else M @ z
        forces = functional_call(p.forces, {"weight": weight.view(shape)}, (p.warp.grid, STEPS, DT, FRAME))
        paths = _carry(p.warp.rollout(forces, FRAME).velocities, p.source, FRAME, DT)
        last["paths"] = paths.detach()
        return keyframe_loss(paths, [(STEPS, p.target)], p.weights)

    def error() -> float:
        return float((last["paths"][:, STEPS] - p.target).norm(dim=-1).max())

    result = minimize(objective, [z], max_iter=200, stop=lambda _loss: error() <= TOLERANCE)
    with torch.no_grad():
        objective()  # the restored best iterate
    return result.evaluations, result.seconds, error()


def preconditioner(p: Problem) -> tuple[Tensor, float, Tensor]:
    """``M = V S^-1 V^T + gamma (I - V V^T)`` from the SVD of ``J0``, the Jacobian of the final points (px) in the
    weight at zero; the seconds the Jacobian and SVD took, and the singular values."""
    shape = p.forces.weight.shape

    def final_points(weight: Tensor) -> Tensor:
        forces = functional_call(p.forces, {"weight": weight.view(shape)}, (p.warp.grid, STEPS, DT, FRAME))
        return _carry(p.warp.rollout(forces, FRAME).velocities, p.source, FRAME, DT)[:, STEPS].flatten()

    t0 = time.perf_counter()
    J = torch.autograd.functional.jacobian(final_points, torch.zeros(shape.numel(), dtype=DTYPE))  # (2M, 500)
    _, S, Vh = torch.linalg.svd(J, full_matrices=False)
    seconds = time.perf_counter() - t0
    V = Vh.T  # (500, 2M)
    gamma = 1.0 / S.median()
    M = V @ torch.diag(1.0 / S) @ V.T + gamma * (torch.eye(shape.numel(), dtype=DTYPE) - V @ V.T)
    return M, seconds, S


def trial_b(seeds: int) -> list[TrialBRow]:
    rows = []
    for seed in range(seeds):
        log(f"  trial B: flow seed {seed} ...")
        p = fitted_problem(seed)
        plain = trial_b_fit(p, None)
        M, jac_s, S = preconditioner(p)
        pre = trial_b_fit(p, M)
        rows.append(
            TrialBRow(
                seed,
                p.evaluations,
                *plain,
                *pre,
                jac_s,
                (float(S.min()), float(S.median()), float(S.max())),
            )
        )
    return rows


def report_trial_b(rows: list[TrialBRow], gradient_ms: float) -> str:
    def cells(name: str, fk: int, pe: int, ps: float, qe: int, qs: float, js: float) -> list[str]:
        return [
            name,
            str(fk),
            str(pe),
            f"{ps:.2f}",
            f"{ps / pe * 1e3:.1f}",
            str(qe),
            f"{qs:.2f}",
            f"{qs / qe * 1e3:.1f}",
            f"{js:.2f}",
        ]

    body = []
    for r in rows:
        body.append(
            cells(
                f"flow seed {r.seed}",
                r.fit_keyframes_evaluations,
                r.plain_evaluations,
                r.plain_seconds,
                r.precond_evaluations,
                r.precond_seconds,
                r.jacobian_seconds,
            )
            + [
                f"{r.plain_max_error:.3f} / {r.precond_max_error:.3f}",
                f"{r.singular_values[2] / r.singular_values[0]:.0f}",
            ]
        )
    body.append(
        cells(
            "sum",
            sum(r.fit_keyframes_evaluations for r in rows),
            sum(r.plain_evaluations for r in rows),
            sum(r.plain_seconds for r in rows),
            sum(r.precond_evaluations for r in rows),
            sum(r.precond_seconds for r in rows),
            sum(r.jacobian_seconds for r in rows),
        )
        + ["", ""]
    )
    jac = statistics.median(r.jacobian_seconds for r in rows)
    return "\n".join(
        [
            "5. Trial B: L-BFGS preconditioned by the linearised problem (weight = M z from the SVD of J0) against "
            f"the plain fit; stop when every point is within {TOLERANCE:g} px",
            table(
                [
                    "instance",
                    "fit_keyframes evals",
                    "plain evals",
                    "plain s",
                    "plain ms/eval",
                    "precond evals",
                    "precond s",
                    "precond ms/eval",
                    "J0 + SVD s",
                    "max err px plain / precond",
                    "cond(J0)",
                ],
                body,
            ),
            f"J0 (28 x 500 by autograd.functional.jacobian, one forward and 28 backwards) and its SVD: median "
            f"{jac:.2f} s, about {jac * 1e3 / gradient_ms:.0f} gradients of the objective (1.); 'precond s' excludes "
            "it; seconds are minimize's, from after the optimiser is built",
        ]
    )


# ----------------------------------------------------------------------------------------------- 6. trial C


def trial_c(rec: Recorded, repeats: int) -> dict[str, float]:
    """``torch.compile`` (inductor, CPU) of ``_advect_velocity``: its first call (compilation included) and the
    medians, over every step's velocity, of forward and forward + backward against eager."""
    gen = torch.Generator().manual_seed(2)
    inputs = [x.detach().clone().requires_grad_() for x in rec.entering]
    rs = [torch.randn(x.shape, generator=gen, dtype=x.dtype) for x in inputs]
    # a cache of its own, empty: the first call compiles as it would in a user's first run
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = tempfile.mkdtemp(prefix="bench_gradient_inductor_")
    compiled = torch.compile(_advect_velocity)
    t0 = time.perf_counter()
    (compiled(inputs[0], DT) * rs[0]).sum().backward()
    first_s = time.perf_counter() - t0
    impls = {"eager": _advect_velocity, "compiled": compiled}
    times: dict[tuple[str, str], list[float]] = {(k, m): [] for k in impls for m in ("fwd", "grad")}
    for _ in range(repeats + 1):  # the first round warms up (and compiles the no-grad graph)
        for v, r in zip(inputs, rs):
            for k, fn in impls.items():
                t1 = time.perf_counter()
                with torch.no_grad():
                    fn(v, DT)
                t2 = time.perf_counter()
                v.grad = None
                (fn(v, DT) * r).sum().backward()
                t3 = time.perf_counter()
                times[(k, "fwd")].append(t2 - t1)
                times[(k, "grad")].append(t3 - t2)
    m = {f"{k}_{w}_ms": median_ms(v[STEPS:]) for (k, w), v in times.items()}
    return {"first_call_s": first_s, **m}


def report_trial_c(c: dict[str, float], repeats: int) -> str:
    head = (
        "6. Trial C: torch.compile (inductor, CPU) of the self-advection against eager, per step (ms, medians over "
        f"the 10 steps' velocities and {repeats} interleaved repeats)"
    )
    row = [
        f"{c['first_call_s']:.1f}",
        f"{c['eager_fwd_ms']:.3f}",
        f"{c['compiled_fwd_ms']:.3f}",
        f"{c['eager_grad_ms']:.3f}",
        f"{c['compiled_grad_ms']:.3f}",
        f"{c['compiled_grad_ms'] / c['eager_grad_ms']:.2f}x",
    ]
    cols = [
        "first call s (compiling)",
        "eager fwd",
        "compiled fwd",
        "eager fwd+bwd",
        "compiled fwd+bwd",
        "compiled / eager",
    ]
    return head + "\n" + table(cols, [row])


# ----------------------------------------------------------------------------------------------- main


# ----------------------------------------------------------------------------------------------- 7. grid_sample


@dataclass
class ReadRow:
    """One of the self-advection's three ``grid_sample`` reads, its kernels timed alone (us, medians)."""

    read: str
    points: int
    forward_us: float
    backward_both_us: float
    backward_input_us: float
    backward_grid_us: float


def grid_sample_kernels(rec: Recorded, repeats: int) -> list[ReadRow]:
    """Time ``grid_sampler_2d`` and its backward kernel, asked for both gradients, the image's alone and the
    grid's alone, on the three grids the self-advection of the roll-out's middle step reads with (the faces,
    the midpoints, the feet); interleaved repeats."""
    velocity = rec.entering[len(rec.entering) // 2]
    _, (ext, *grids, _) = _fused_forward(velocity, DT)
    names = ("faces (grid constant)", "midpoints", "feet")
    grad = [torch.randn(ext.shape[0], 1, g.shape[1], 1, dtype=ext.dtype) for g in grids]
    back = torch.ops.aten.grid_sampler_2d_backward
    calls = {
        "forward": lambda i: torch.grid_sampler_2d(ext, grids[i], 0, 1, True),
        "both": lambda i: back(grad[i], ext, grids[i], 0, 1, True, [True, True]),
        "input": lambda i: back(grad[i], ext, grids[i], 0, 1, True, [True, False]),
        "grid": lambda i: back(grad[i], ext, grids[i], 0, 1, True, [False, True]),
    }
    times: dict[tuple[str, int], list[float]] = {}
    for _ in range(repeats):
        for i in range(len(grids)):
            for key, fn in calls.items():
                fn(i)  # warm
                t0 = time.perf_counter()
                for _ in range(20):
                    fn(i)
                times.setdefault((key, i), []).append((time.perf_counter() - t0) / 20 * 1e6)
    return [
        ReadRow(names[i], int(grids[i].shape[1]), *(statistics.median(times[(k, i)]) for k in calls))
        for i in range(len(grids))
    ]


def report_grid_sample(rows: list[ReadRow], o: ObjectiveRow) -> str:
    head = ["read", "points", "forward us", "backward us", "/ forward", "image grad only us", "grid grad only us"]
    body = [
        [
            r.read,
            str(r.points),
            f"{r.forward_us:.1f}",
            f"{r.backward_both_us:.1f}",
            f"{r.backward_both_us / r.forward_us:.2f}x",
            f"{r.backward_input_us:.1f}",
            f"{r.backward_grid_us:.1f}",
        ]
        for r in rows
    ]
    fwd = sum(r.forward_us for r in rows) * STEPS / 1e3
    bwd = sum(r.backward_both_us for r in rows) * STEPS / 1e3
    return "\n".join(
        [
            "7. grid_sample's kernels on the self-advection's three reads of the roll-out's middle step (the extended "
            "velocity, 2 images of the fluid's nodes), each timed alone, us, medians",
            table(head, body),
            f"over the {STEPS} steps: forward reads {fwd:.2f} ms, backward kernels {bwd:.2f} ms, against a whole "
            f"forward of {o.forward_ms:.2f} ms and a gradient of {o.gradient_ms:.2f} ms; were each backward kernel "
            f"no dearer than its read, the gradient would be {(o.gradient_ms - bwd + fwd) / o.forward_ms:.2f}x the "
            "forward. Columns 6-7: the backward kernel asked for one of its two gradients only.",
        ]
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--json", metavar="PATH", help="also write the results as JSON to PATH")
    add_threads_argument(parser)
    parser.add_argument("--repeats", type=int, default=40, help="interleaved repeats of 1., 2. and 4. (default 40)")
    parser.add_argument("--profiled", type=int, default=5, help="gradients and forwards profiled in 3. (default 5)")
    parser.add_argument("--trial-seeds", type=int, default=5, help="flow instances of trial B (default 5)")
    parser.add_argument("--no-trials", action="store_true", help="skip the trials (4. and 5.)")
    parser.add_argument(
        "--compile-trial",
        action="store_true",
        help="also run trial C, torch.compile of the self-advection (about 30 s of compiling; needs a C++ compiler)",
    )
    args = parser.parse_args(argv)
    if min(args.threads, args.repeats, args.profiled, args.trial_seeds) < 1:
        parser.error("--threads, --repeats, --profiled and --trial-seeds must be >= 1")
    torch.set_num_threads(args.threads)

    info = machine()
    info["load_start"] = machine_load()
    info["sources_sha256"] = source_fingerprint()
    print(
        f"bench_gradient: {info['cpu']}, {info['cpu_count']} CPUs, torch {info['torch']} with "
        f"{info['torch_threads']} thread(s), Python {info['python']}, {info['date']}",
        flush=True,
    )
    print(
        f"torchfluidwarp sources sha256 {info['sources_sha256']}; at the start: {describe_load(info['load_start'])}",
        flush=True,
    )
    t_start = time.perf_counter()
    log("  fit of flow seed 0 ...")
    p = fitted_problem(0)
    rec = record(p)
    print(
        f"set-up: flow seed 0, {GRID[0]}x{GRID[1]} fluid, {STEPS} steps, {POINTS} points in a {FRAME[1]}x{FRAME[0]} "
        f"px frame, control {CONTROL[0]}x{CONTROL[1]} ({2 * STEPS * CONTROL[0] * CONTROL[1]} parameters), float32; "
        f"the fit {p.message}",
        flush=True,
    )
    print(
        f"recorded stage inputs against the roll-out: velocities within {rec.velocity_error:.1e}, points within "
        f"{rec.points_error:.1e} px",
        flush=True,
    )

    log("  1. and 2. ...")
    obj, stage_rows = time_objective_and_stages(p, rec, args.repeats)
    print("\n" + report_objective(obj), flush=True)
    print("\n" + report_stages(obj, stage_rows), flush=True)
    log("  3. ...")
    kernel_rows = profile_kernels(p, args.profiled)
    print("\n" + report_kernels(kernel_rows, args.profiled, obj), flush=True)

    log("  7. grid_sample's kernels ...")
    read_rows = grid_sample_kernels(rec, max(5, args.repeats // 4))
    print("\n" + report_grid_sample(read_rows, obj), flush=True)

    result: dict[str, Any] = {
        "machine": info,
        "args": vars(args),
        "fit": {"evaluations": p.evaluations, "message": p.message},
        "recorded": {"velocity_error": rec.velocity_error, "points_error": rec.points_error},
        "objective": asdict(obj),
        "stages": [asdict(r) for r in stage_rows],
        "kernels": [asdict(r) for r in kernel_rows],
        "grid_sample": [asdict(r) for r in read_rows],
    }
    if not args.no_trials:
        log("  4. trial A ...")
        a_rows, nodes = trial_a(rec, args.repeats)
        print("\n" + report_trial_a(a_rows, nodes, args.repeats), flush=True)
        b_rows = trial_b(args.trial_seeds)
        print("\n" + report_trial_b(b_rows, obj.gradient_ms), flush=True)
        result["trial_a"] = {"rows": [asdict(r) for r in a_rows], "autograd_nodes": nodes}
        result["trial_b"] = [asdict(r) for r in b_rows]
    if args.compile_trial:
        log("  6. trial C (compiling) ...")
        c = trial_c(rec, args.repeats)
        print("\n" + report_trial_c(c, args.repeats), flush=True)
        result["trial_c"] = c

    total = time.perf_counter() - t_start
    info["load_end"] = machine_load()
    print(f"\ntotal {total:.0f} s; at the end: {describe_load(info['load_end'])}")
    result["total_s"] = total
    if args.json:
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
