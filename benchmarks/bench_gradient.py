"""Benchmark of one keyframe gradient: what it costs over a forward, and where that goes (issue #20).

At the forces ``fit_keyframes`` fits to ``_common.flow_instance(0)`` (float32): (1) the whole objective, gradient
over forward (target <= 2x); (2) per stage over the 10 steps (force, ``advect_velocity``, ``project``,
``advect_points``); (3) kernel groups under ``torch.profiler``; (4) ``grid_sample``'s kernels alone. Figures, and
those of the trials removed from this script: docs/benchmarks.md, "Why the fit's 0.25 s and the gradient's 2x
are blocked here".
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from typing import Any, cast

import torch
from _common import finish, flow_instance, interleaved, log, median_ms, medians_ms, parser, rows_table, start, verdict
from torch import Tensor
from torch.overrides import TorchFunctionMode
from torch.profiler import ProfilerActivity, profile

from torchfluidwarp.control import fit_keyframes, keyframe_loss
from torchfluidwarp.core.advection import advect_points, advect_velocity
from torchfluidwarp.core.fluid import faces_from_cells, project
from torchfluidwarp.core.grid import cell_scale, rescale_points
from torchfluidwarp.warp import ControlGrid

FRAME, GRID, STEPS, POINTS, DT, DTYPE = (64, 64), (64, 64), 10, 14, 1.0, torch.float32


class Problem:
    """The fitted keyframe problem: the fit's warp and forces, points ``(1, M, 2)`` px, the objective."""

    def __init__(self, seed: int) -> None:
        src, tgt = flow_instance(seed, POINTS, GRID, STEPS).tensors(DTYPE)
        fit = fit_keyframes(src, tgt, image_size=FRAME, grid=GRID, steps=STEPS, control=(5, 5), tolerance=0.05,
                            dtype=DTYPE, progress=False, method="lbfgs")  # fmt: skip
        self.warp, self.forces = fit.warp, cast(ControlGrid, fit.forces)
        self.source, self.target, self.message = src[None], tgt[None], fit.message
        self.params = [q for q in self.forces.parameters() if q.requires_grad]

    def objective(self) -> Tensor:
        """``fit_keyframes``' objective: roll-out, points carried through it, keyframe loss (pixels^2)."""
        return keyframe_loss(self.warp.carry_points(self.source, self.forces, FRAME), [(STEPS, self.target)])

    def forward(self) -> None:
        with torch.no_grad():
            self.objective()

    def gradient(self) -> None:
        for q in self.params:
            q.grad = None
        self.objective().backward()


@torch.no_grad()
def record(p: Problem) -> dict[str, Any]:
    """What each stage sees per step: the velocity entering the self-advection, the advected velocity, the step's
    velocity, and the points ``(1, M, 2)`` in cells at its start; checked against the roll-out."""
    warp, step = p.warp, p.warp.simulator.step
    h, w = warp.grid.shape
    mu = warp.simulator.current_viscosity(1, FRAME)
    on_faces = faces_from_cells(p.forces(warp.grid, STEPS, DT, FRAME).flatten(0, 1)).view(1, STEPS, 2, h + 1, w + 1)
    v = on_faces.new_zeros(1, 2, h + 1, w + 1)
    c = cell_scale(FRAME, warp.grid, dtype=DTYPE)
    pts = rescale_points(p.source, c)
    rec: dict[str, list[Tensor]] = {"entering": [], "advected": [], "velocities": [], "points": []}
    for t in range(STEPS):
        rec["entering"].append(step.add_force(v, on_faces[:, t], staggered=True))
        rec["advected"].append(step.advect(rec["entering"][-1]))
        v, _ = step.project(step.diffuse(rec["advected"][-1], mu)[0])
        rec["velocities"].append(v)
        rec["points"].append(pts)
        pts = advect_points(pts, v, DT)
    vel = warp.rollout(p.forces, FRAME).velocities
    paths = rescale_points(torch.stack([*rec["points"], pts], 1), c, inverse=True)
    errors = (float((torch.stack(rec["velocities"], 1) - vel).abs().max()),
              float((paths - p.warp.carry_points(p.source, p.forces, FRAME)).abs().max()))  # fmt: skip
    return {**rec, "errors": errors}


def stages(p: Problem, rec: dict[str, Any]) -> dict[str, Callable[[], None]]:
    """``{"<stage> f": forward, "<stage> g": forward + backward}`` for the four stages."""
    gen = torch.Generator().manual_seed(0)
    step = p.warp.simulator.step
    leaf = lambda x, grad=True: x.detach().clone().requires_grad_(grad)
    cotangent = lambda x: torch.randn(x.shape, generator=gen, dtype=x.dtype)
    force = lambda: faces_from_cells(p.forces(p.warp.grid, STEPS, DT, FRAME).flatten(0, 1))
    proj = lambda x: project(x, config=step.project.config, adjoint_config=step.project.adjoint_config)
    per_step = {
        "self-advection (advect_velocity)": (lambda v: advect_velocity(v, DT), [(leaf(v),) for v in rec["entering"]]),
        "projection (project)": (proj, [(leaf(v),) for v in rec["advected"]]),
        f"carry {POINTS} points (advect_points)": (
            lambda x, v: advect_points(x, v, DT),
            [(leaf(x, t > 0), leaf(v)) for t, (x, v) in enumerate(zip(rec["points"], rec["velocities"]))],
        ),
    }
    r_force = cotangent(force().detach())
    out: dict[str, Callable[[], None]] = {}

    def force_gradient() -> None:
        for q in p.params:
            q.grad = None
        (force() * r_force).sum().backward()

    out["force (ControlGrid + faces_from_cells) f"] = lambda: torch.no_grad()(force)()
    out["force (ControlGrid + faces_from_cells) g"] = force_gradient
    for name, (fn, inputs) in per_step.items():
        with torch.no_grad():
            rs = [cotangent(fn(*args)) for args in inputs]

        def forward(fn=fn, inputs=inputs) -> None:
            with torch.no_grad():
                for args in inputs:
                    fn(*args)

        def gradient(fn=fn, inputs=inputs, rs=rs) -> None:
            loss = sum((fn(*args) * r).sum() for args, r in zip(inputs, rs))  # one backward, as in the roll-out
            loss.backward()  # type: ignore[union-attr]

        out[name + " f"], out[name + " g"] = forward, gradient
    return out


GROUPS = ("grid_sample forward reads", "grid_sample backward kernel", "matrix products and convolutions", "rest")


def group_of(key: str) -> str:
    if key in ("aten::grid_sampler_2d", "aten::grid_sampler"):
        return GROUPS[0]
    if key == "aten::grid_sampler_2d_backward":
        return GROUPS[1]
    if key in ("aten::mm", "aten::bmm", "aten::matmul") or key.startswith("aten::_slow_conv2d"):
        return GROUPS[2]
    return GROUPS[3]


def profile_kernels(p: Problem, n: int) -> list[dict[str, Any]]:
    """Mean self CPU ms and ``aten`` calls per forward and per gradient, by group, each call profiled alone."""
    acc = {(k, g): [0.0, 0.0] for k in "fg" for g in GROUPS}
    for i in range(n + 1):  # the first session pays the profiler's start-up: thrown away
        for k, fn in (("f", p.forward), ("g", p.gradient)):
            with profile(activities=[ProfilerActivity.CPU]) as prof:
                fn()
            for evt in prof.key_averages() if i else []:
                a = acc[(k, group_of(evt.key))]
                a[0] += evt.self_cpu_time_total / 1e3 / n
                a[1] += (evt.count if evt.key.startswith("aten::") else 0) / n
    rows = [dict(group=g, f=acc[("f", g)][0], fc=acc[("f", g)][1], g=acc[("g", g)][0], gc=acc[("g", g)][1])
            for g in GROUPS]  # fmt: skip
    rows.append({"group": "total", **{k: sum(r[k] for r in rows) for k in ("f", "fc", "g", "gc")}})
    for r in rows:
        r.update(fs=r["f"] / rows[-1]["f"], gs=r["g"] / rows[-1]["g"], excess=r["g"] - 2 * r["f"])
    return rows


class CatchGridSample(TorchFunctionMode):
    """Records the ``(image, grid)`` of every ``grid_sample`` call made under it."""

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[tuple[Tensor, Tensor, bool]] = []

    def __torch_function__(self, func: Any, types: Any, args: Any = (), kwargs: Any = None) -> Any:
        kwargs = kwargs or {}
        if func is torch.nn.functional.grid_sample:
            self.calls.append((args[0].detach(), args[1].detach(), bool(kwargs.get("align_corners"))))
        return func(*args, **kwargs)


def grid_sample_kernels(rec: dict[str, Any], repeats: int) -> list[dict[str, Any]]:
    """``grid_sampler_2d`` and its backward kernel (both gradients, the image's, the grid's), on the grids the
    self-advection of the middle step reads with; us, medians of interleaved repeats (20 calls each)."""
    with CatchGridSample() as catch, torch.no_grad():
        advect_velocity(rec["entering"][STEPS // 2], DT)
    back = torch.ops.aten.grid_sampler_2d_backward
    names = ("every face (constant grid)", "the midpoints", "the feet")
    rows = []
    for name, (img, grid, corners) in zip(names, catch.calls):
        g_out = torch.randn(img.shape[0], img.shape[1], *grid.shape[1:3], dtype=img.dtype)
        calls = {
            "fwd": lambda: torch.grid_sampler_2d(img, grid, 0, 1, corners),
            "both": lambda: back(g_out, img, grid, 0, 1, corners, [True, True]),
            "image": lambda: back(g_out, img, grid, 0, 1, corners, [True, False]),
            "grid": lambda: back(g_out, img, grid, 0, 1, corners, [False, True]),
        }
        times = interleaved({k: (lambda fn=fn: [fn() for _ in range(20)]) for k, fn in calls.items()}, repeats)
        us = {k: v / 20 * 1e3 for k, v in medians_ms(times).items()}
        rows.append(dict(read=name, points=grid.shape[1] * grid.shape[2], **us, ratio=us["both"] / us["fwd"]))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="5 repeats, 1 profiled call")
    p.add_argument("--repeats", type=int, default=40, help="interleaved repeats of 1., 2. and 4. (default 40)")
    p.add_argument("--profiled", type=int, default=5, help="gradients and forwards profiled in 3. (default 5)")
    args = p.parse_args(argv)
    if args.quick:
        args.repeats, args.profiled = 5, 1
    info = start("bench_gradient", args.threads)
    log("  fit of flow seed 0 ...")
    prob = Problem(0)
    rec = record(prob)
    print(f"set-up: flow seed 0, {GRID[0]}x{GRID[1]} fluid, {STEPS} steps, {POINTS} points, control 5x5 (500 "
          f"parameters), float32; the fit {prob.message}; recorded stage inputs against the roll-out: velocities "
          f"within {rec['errors'][0]:.1e}, points within {rec['errors'][1]:.1e} px")  # fmt: skip

    log("  1. and 2. ...")
    split: list[tuple[float, float]] = []  # the forward with autograd's graph, and its backward

    def graph_then_backward() -> None:
        for q in prob.params:
            q.grad = None
        t0 = time.perf_counter()
        loss = prob.objective()
        t1 = time.perf_counter()
        loss.backward()
        split.append((t1 - t0, time.perf_counter() - t1))

    cases = {"forward": prob.forward, "graph": graph_then_backward, **stages(prob, rec)}
    ms = medians_ms(interleaved(cases, args.repeats))
    split = split[1:]  # the warm-up
    f, g, b = ms["forward"], median_ms(s[0] for s in split), median_ms(s[1] for s in split)
    grad = median_ms(s[0] + s[1] for s in split)
    print(f"\n1. Whole objective, ms, medians of {args.repeats} interleaved repeats")
    obj = dict(f=f, g=g, b=b, grad=grad, ratio=grad / f, gf=g / f, bf=b / f, ok=verdict(grad / f <= 2.0))
    print(rows_table([obj], "forward (no grad) {f:.2f} | forward with graph {g:.2f} | backward {b:.2f} | gradient "
          "{grad:.2f} | graph fwd / fwd {gf:.2f}x | backward / fwd {bf:.2f}x | gradient / fwd {ratio:.2f}x | "
          "target <= 2x {ok}"))  # fmt: skip
    names = [k[:-2] for k in ms if k.endswith(" f")]
    rows = [dict(stage=n, f=ms[n + " f"], g=ms[n + " g"]) for n in names]
    rows.append(dict(stage="sum of the stages", f=sum(r["f"] for r in rows), g=sum(r["g"] for r in rows)))
    rows.append(dict(stage="whole objective (1.)", f=f, g=grad))
    rows.append(dict(stage="rest (objective - stages)", f=f - rows[-2]["f"], g=grad - rows[-2]["g"]))
    for r in rows:
        r.update(b=r["g"] - r["f"], ratio=r["g"] / r["f"] if r["f"] > 0 else float("nan"), ex=r["g"] - 2 * r["f"],
                 share=r["g"] / grad)  # fmt: skip
    print(f"\n2. Per stage, summed over the {STEPS} steps, each alone on its recorded inputs (ms, same repeats)")
    print(rows_table(rows, "stage {stage} | fwd {f:.2f} | fwd+bwd {g:.2f} | bwd {b:.2f} | fwd+bwd / fwd {ratio:.2f}x |"
          " fwd+bwd - 2 fwd {ex:+.2f} | share of the gradient {share:.0%}"))  # fmt: skip

    log("  3. ...")
    kernels = profile_kernels(prob, args.profiled)
    total = kernels[-1]
    gs = kernels[0]["excess"] + kernels[1]["excess"]
    print(f"\n3. Kernels: self CPU ms per forward and per gradient, means of {args.profiled} profiled calls each "
          "(PROFILED times: read the shares)")  # fmt: skip
    print(rows_table(kernels, "group {group} | fwd ms {f:.2f} | fwd share {fs:.0%} | fwd aten calls {fc:.0f} | "
          "gradient ms {g:.2f} | gradient share {gs:.0%} | gradient aten calls {gc:.0f} | gradient - 2 fwd ms "
          "{excess:+.2f}"))  # fmt: skip
    print(f"profiled gradient / forward {total['g'] / total['f']:.2f}x; of the gradient's excess over 2x the forward "
          f"({total['excess']:.2f} ms profiled), grid_sample accounts for {gs:.2f} ms ({gs / total['excess']:.0%}); "
          f"grid_sampler_2d_backward / forward reads {kernels[1]['g'] / kernels[0]['f']:.2f}x")  # fmt: skip

    log("  4. grid_sample's kernels ...")
    reads = grid_sample_kernels(rec, max(5, args.repeats // 4))
    print("\n4. grid_sample's kernels on the self-advection's three reads of the middle step, us, medians")
    print(rows_table(reads, "read {read} | points per image {points} | forward us {fwd:.1f} | backward us (both) "
          "{both:.1f} | / forward {ratio:.2f}x | image's gradient only us {image:.1f} | grid's only us "
          "{grid:.1f}"))  # fmt: skip
    fwd_ms = sum(r["fwd"] for r in reads) * STEPS / 1e3
    bwd_ms = sum(r["both"] for r in reads) * STEPS / 1e3
    bound = (grad - bwd_ms + fwd_ms) / f
    print(f"over the {STEPS} steps: reads {fwd_ms:.2f} ms, backward kernels {bwd_ms:.2f} ms; were each backward "
          f"kernel no dearer than its read, the gradient would be {bound:.2f}x the forward")  # fmt: skip
    result = dict(args=vars(args), objective=obj, stages=rows, kernels=kernels, grid_sample=reads,
                  recorded_errors=rec["errors"], median_read_us=statistics.median(r["fwd"] for r in reads))  # fmt: skip
    finish(info, result, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
