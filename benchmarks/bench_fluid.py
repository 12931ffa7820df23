"""Benchmark of the fluid core: speed, scaling, backward overhead and the adjoint's memory.

Three measurements, all float32 on CPU, all through the public API (:class:`torchfluidwarp.FluidSimulator`):

1. **Scaling**: ms per step forward (no grad) and forward + backward on square grids (64^2, 256^2, 1024^2),
   with a constant viscosity and with none; the CG iterations per step; the cost per cell (ns/cell/step);
   the per-cell cost of the largest grid against the second largest (target: within 2x).
2. **Backward overhead**: forward + backward time over forward time, 64^2 and 10 steps (target: <= 3x). Both
   come from the same interleaved repeats as (1).
3. **Memory**: peak memory of a 50-step backward on 256^2 with a viscosity *field* that requires grad, for the
   implicit adjoint against plain autograd through unrolled, unpreconditioned CG at the same tolerance
   (target: >= 10x less for the adjoint), and the adjoint again with a 100x tighter tolerance (target:
   unchanged). Each configuration runs in its own process and reports two measures:

   * peak RSS growth: the process's peak RSS after the backward minus its RSS at a baseline taken after
     imports, a warm-up on a tiny grid and building the inputs (everything the process holds at its peak: graph,
     CG temporaries, allocator slack). The peak is ``VmHWM`` from ``/proc/self/status``, reset at the baseline
     through ``/proc/self/clear_refs``. ``ru_maxrss`` growth is reported too, but it cannot be reset and a child
     started by ``exec`` inherits its parent's peak RSS into it, so it reads ~0 whenever the parent (which ran
     the 1024^2 timings) was larger than the child's whole run;
   * saved-for-backward bytes: the unique storages autograd saves for backward, summed by a
     ``torch.autograd.graph.saved_tensors_hooks`` pack hook (deterministic; closure-captured constants of the
     solves, such as the wall mask, are not counted).

   The unrolled run is given a memory and time budget. It starts on the full step count and checks itself after
   every step; if it would overrun, it stops, and both the adjoint and the unrolled run are repeated on the
   number of steps that fits, and the report says so. Then the unrolled forward runs once more on the full
   step count with a pack hook that *counts* what autograd saves for backward and drops it (the run stays
   small, and no backward is possible): autograd through the unrolled CG would hold all those bytes when its
   backward starts, so they are a lower bound on its peak memory, compared with the adjoint's whole measured
   peak RSS growth on the same steps.

Timings are medians of several repeats, forward and forward + backward interleaved so that other load on the
machine affects both alike. Run ``python benchmarks/bench_fluid.py --help`` for the options.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import resource
import statistics
import sys
import time
import warnings
import weakref
from typing import Any

import torch
import torch.nn.functional as F
from _common import finish, log, parser, reset_peak, rows_table, run_child, save_figure, start, status_kib, verdict
from torch import Tensor

from torchfluidwarp import CGConfig, FluidSimulator
from torchfluidwarp.core import ConvergenceWarning

SEED = 1234
N_POINTS = 256
FORCE_AMPLITUDE = 0.05  # cells per time unit^2: a gentle stir that stays stable with dt = 1 over 50 steps
CONSTANT_VISCOSITY = 0.5  # cells^2 per time unit


# ----------------------------------------------------------------------------------------------- inputs


def smooth_noise(h: int, w: int, channels: int, generator: torch.Generator) -> Tensor:
    """A smooth random field ``(1, channels, h, w)`` in ``[0, 1]``: 8x8 uniform noise, bicubically upsampled."""
    coarse = torch.rand(1, channels, 8, 8, generator=generator)
    return F.interpolate(coarse, size=(h, w), mode="bicubic", align_corners=True).clamp(0.0, 1.0)


def make_inputs(n: int, steps: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """A steady smooth force schedule ``(1, steps, 2, n, n)`` and ``(1, N_POINTS, 2)`` points in fluid cells."""
    force = FORCE_AMPLITUDE * (2.0 * smooth_noise(n, n, 2, generator) - 1.0)  # (1, 2, n, n)
    forces = force.unsqueeze(1).expand(1, steps, 2, n, n).contiguous()
    points = torch.rand(1, N_POINTS, 2, generator=generator) * (n - 1)
    return forces, points


def viscosity_field(n: int, generator: torch.Generator) -> Tensor:
    """``0.2 + 0.3 * smooth noise``, ``(1, 1, n, n)``, requiring grad."""
    return (0.2 + 0.3 * smooth_noise(n, n, 1, generator)).requires_grad_()


def loss_of(out: Any) -> Tensor:
    """Sum of the final velocities squared plus the final points."""
    return out.velocities[:, -1].pow(2).sum() + out.points[:, -1].sum()


# ----------------------------------------------------------------------------------------------- scaling


def time_grid(n: int, steps: int, viscosity: float, repeats: int) -> dict[str, Any]:
    """Median ms per step of a forward (no grad) and a forward + backward roll-out, interleaved."""
    gen = torch.Generator().manual_seed(SEED)
    forces, points = make_inputs(n, steps, gen)
    sim = FluidSimulator((n, n), dt=1.0, viscosity=viscosity)
    leaf = forces.clone().requires_grad_()

    def forward() -> Any:
        with torch.no_grad():
            return sim(forces, points)

    def forward_backward() -> None:
        leaf.grad = None
        loss_of(sim(leaf, points)).backward()

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        # warm-up on one step: fills the grid's geometry and transform caches, loads the kernels
        with torch.no_grad():
            sim(forces[:, :1], points)
        loss_of(sim(leaf[:, :1], points)).backward()
        fwd, fb = [], []
        out = None
        for _ in range(repeats):
            t0 = time.perf_counter()
            out = forward()
            fwd.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            forward_backward()
            fb.append(time.perf_counter() - t0)
    n_warn = sum(issubclass(w.category, ConvergenceWarning) for w in caught)
    f_ms = statistics.median(fwd) / steps * 1e3
    fb_ms = statistics.median(fb) / steps * 1e3
    return dict(grid=n, visc=viscosity, steps=steps, repeats=repeats, f=f_ms, fb=fb_ms, f_ns=f_ms * 1e6 / n**2,
                fb_ns=fb_ms * 1e6 / n**2, ratio=fb_ms / f_ms, visc_it=statistics.mean(i for i, _ in out.iterations),
                pres_it=statistics.mean(p for _, p in out.iterations), warn=n_warn)  # fmt: skip


# ----------------------------------------------------------------------------------------------- memory


def _maxrss_kib() -> float:
    return float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)  # KiB on Linux


class _OverBudget(Exception):
    pass


def memory_child(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one memory configuration in this (fresh) process and return what it measured."""
    torch.set_num_threads(spec["threads"])
    n, steps, rtol, backward = spec["grid"], spec["steps"], spec["rtol"], spec["backward"]

    def build(n: int, steps: int) -> tuple[FluidSimulator, Tensor, Tensor, Tensor]:
        gen = torch.Generator().manual_seed(SEED)
        forces, points = make_inputs(n, steps, gen)
        mu = viscosity_field(n, gen)
        if backward == "implicit":
            cfg = CGConfig(rtol=rtol)
        else:
            cfg = CGConfig(rtol=rtol, max_iter=spec["unrolled_max_iter"], precondition=False, backward="unrolled")
        sim = FluidSimulator((n, n), dt=1.0, viscosity=mu, pressure=cfg, diffusion=cfg)
        return sim, forces.requires_grad_(), points, mu

    # warm-up on a tiny grid loads every code path (autograd engine, FFT and BLAS kernels) before the baseline
    sim, forces, points, _ = build(16, 2)
    loss_of(sim(forces, points)).backward()
    del sim, forces, points
    sim, forces, points, mu = build(n, steps)
    gc.collect()
    hwm_reset = reset_peak()
    base_maxrss, base_now = _maxrss_kib(), status_kib("VmRSS")

    saved_bytes, seen = 0, set()
    count_only = spec.get("count_only", False)

    def pack(t: Tensor) -> Tensor | None:
        nonlocal saved_bytes
        storage = t.untyped_storage()
        key = storage.data_ptr()
        if key not in seen:  # kept tensors stay alive until backward, so pointers are unique
            seen.add(key)
            saved_bytes += storage.nbytes()
            if count_only:
                # the tensor is dropped below: once the computation frees it, its address may be reused by a
                # new tensor, which real autograd (holding the old one) would have placed elsewhere
                weakref.finalize(t if t._base is None else t._base, seen.discard, key)
        return None if count_only else t

    t_start = time.perf_counter()
    done = 0

    def check_budget(_module: Any, _inputs: Any, _output: Any) -> None:
        # after each step: would the whole roll-out (forward, then a backward) overrun the budget?
        nonlocal done
        done += 1
        if backward != "unrolled" or done == steps or count_only:
            return
        grow_gib = (status_kib("VmRSS") - base_now) / 2**20
        elapsed = time.perf_counter() - t_start
        if grow_gib / done * steps > spec["mem_budget_gib"] or elapsed / done * steps * 1.5 > spec["time_budget_s"]:
            raise _OverBudget(grow_gib, elapsed)

    sim.step.register_forward_hook(check_budget)
    result: dict[str, Any] = {**spec, "aborted": False}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        try:
            with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
                out = sim(forces, points)
        except _OverBudget as stop:
            grow_gib, elapsed = stop.args
            per_step_gib, per_step_s = grow_gib / done, elapsed / done
            fit = min(spec["mem_budget_gib"] / per_step_gib, spec["time_budget_s"] / (1.5 * per_step_s))
            result.update(
                aborted=True,
                steps_done=done,
                rss_growth_gib_at_abort=grow_gib,
                forward_s_at_abort=elapsed,
                saved_gib_at_abort=saved_bytes / 2**30,
                steps_that_fit=max(1, int(math.floor(fit))),
            )
            return result
        t_fwd = time.perf_counter() - t_start
        if count_only:
            result.update(
                saved_for_backward_mib=saved_bytes / 2**20,
                forward_s=t_fwd,
                counted_peak_rss_growth_mib=(status_kib("VmHWM") - base_now) / 1024 if hwm_reset else math.nan,
                pressure_iters_per_step=statistics.mean(p for _, p in out.iterations),
                viscosity_iters_per_step=statistics.mean(i for i, _ in out.iterations),
            )
            return result
        t0 = time.perf_counter()
        loss_of(out).backward()
        t_bwd = time.perf_counter() - t0
    result.update(
        maxrss_growth_mib=(_maxrss_kib() - base_maxrss) / 1024,
        peak_measure="VmHWM" if hwm_reset else "ru_maxrss",
        peak_rss_growth_mib=((status_kib("VmHWM") - base_now) if hwm_reset else (_maxrss_kib() - base_maxrss)) / 1024,
        baseline_rss_mib=base_now / 1024,
        baseline_maxrss_mib=base_maxrss / 1024,
        saved_for_backward_mib=saved_bytes / 2**20,
        forward_s=t_fwd,
        backward_s=t_bwd,
        viscosity_iters_per_step=statistics.mean(i for i, _ in out.iterations),
        pressure_iters_per_step=statistics.mean(p for _, p in out.iterations),
        convergence_warnings=sum(issubclass(w.category, ConvergenceWarning) for w in caught),
        grad_finite=bool(torch.isfinite(forces.grad).all() and torch.isfinite(mu.grad).all()),
    )
    return result


def _ratio(a: float, b: float) -> float:
    return a / b if b > 0 else math.inf


def memory_benchmark(
    n: int,
    steps: int,
    rtol: float,
    tight_factor: float,
    threads: int,
    mem_budget_gib: float,
    time_budget_s: float,
    unrolled_max_iter: int,
    log: Any,
) -> dict[str, Any]:
    """Measurement 3: the adjoint against unrolled CG, and the adjoint at a tighter tolerance."""
    base = dict(
        grid=n,
        threads=threads,
        mem_budget_gib=mem_budget_gib,
        time_budget_s=time_budget_s,
        unrolled_max_iter=unrolled_max_iter,
    )
    runs: dict[str, Any] = {}
    log(f"  memory: adjoint, {steps} steps, rtol {rtol:g} ...")
    runs["adjoint"] = run_child(__file__, {**base, "steps": steps, "rtol": rtol, "backward": "implicit"})
    log(f"  memory: adjoint, {steps} steps, rtol {rtol / tight_factor:g} ...")
    runs["adjoint_tight"] = run_child(
        __file__, {**base, "steps": steps, "rtol": rtol / tight_factor, "backward": "implicit"}
    )
    log(f"  memory: unrolled unpreconditioned CG, {steps} steps, rtol {rtol:g} (with a budget check) ...")
    unrolled = run_child(__file__, {**base, "steps": steps, "rtol": rtol, "backward": "unrolled"})
    compare_steps = steps
    if unrolled.get("aborted"):
        runs["unrolled_attempt"] = unrolled
        compare_steps = unrolled["steps_that_fit"]
        log(f"  memory: the unrolled run would overrun its budget; both configs again on {compare_steps} steps ...")
        runs["adjoint_short"] = run_child(
            __file__, {**base, "steps": compare_steps, "rtol": rtol, "backward": "implicit"}
        )
        unrolled = run_child(__file__, {**base, "steps": compare_steps, "rtol": rtol, "backward": "unrolled"})
        log(f"  memory: unrolled on {compare_steps} steps again, counting what it saves (checks the count) ...")
        runs["unrolled_counted_short"] = run_child(
            __file__, {**base, "steps": compare_steps, "rtol": rtol, "backward": "unrolled", "count_only": True}
        )
        log(f"  memory: unrolled on all {steps} steps, counting what it saves (dropped, no backward) ...")
        runs["unrolled_counted"] = run_child(
            __file__, {**base, "steps": steps, "rtol": rtol, "backward": "unrolled", "count_only": True}
        )
    runs["unrolled"] = unrolled
    adjoint_cmp = runs.get("adjoint_short", runs["adjoint"])
    summary: dict[str, Any] = {
        "grid": n,
        "requested_steps": steps,
        "compared_steps": compare_steps,
        "rtol": rtol,
        "tight_rtol": rtol / tight_factor,
    }
    ok = not any(r.get("failed") for r in (adjoint_cmp, unrolled, runs["adjoint"], runs["adjoint_tight"]))
    if ok:
        tight, loose = runs["adjoint_tight"], runs["adjoint"]
        summary.update(
            rss_ratio=_ratio(unrolled["peak_rss_growth_mib"], adjoint_cmp["peak_rss_growth_mib"]),
            saved_ratio=_ratio(unrolled["saved_for_backward_mib"], adjoint_cmp["saved_for_backward_mib"]),
            tight_rss_ratio=_ratio(tight["peak_rss_growth_mib"], loose["peak_rss_growth_mib"]),
            tight_saved_ratio=_ratio(tight["saved_for_backward_mib"], loose["saved_for_backward_mib"]),
        )
        counted = runs.get("unrolled_counted")
        if counted is not None and not counted.get("failed"):
            summary.update(
                counted_saved_mib=counted["saved_for_backward_mib"],
                counted_vs_adjoint_rss=_ratio(counted["saved_for_backward_mib"], loose["peak_rss_growth_mib"]),
                counted_vs_adjoint_saved=_ratio(counted["saved_for_backward_mib"], loose["saved_for_backward_mib"]),
                count_check=_ratio(
                    runs["unrolled_counted_short"]["saved_for_backward_mib"], unrolled["saved_for_backward_mib"]
                ),
            )
    return {"summary": summary, "runs": runs}


# ----------------------------------------------------------------------------------------------- report


def report_scaling(rows: list[dict[str, Any]], overhead_grid: int) -> None:
    print("\nScaling (float32, CPU; median ms per step; it = CG iterations per step, forward)")
    print(rows_table(rows, "grid {grid}^2 | visc {visc:g} | steps {steps} | reps {repeats} | fwd ms/step {f:.2f} | "
          "fwd+bwd ms/step {fb:.2f} | fwd ns/cell {f_ns:.1f} | f+b ns/cell {fb_ns:.1f} | f+b / fwd {ratio:.2f} | "
          "visc it {visc_it:g} | pres it {pres_it:g} | warn {warn}"))  # fmt: skip
    big, mid = sorted({r["grid"] for r in rows})[-1:-3:-1]
    at = {(r["grid"], r["visc"]): r for r in rows}
    passes = (("forward", "f_ns"), ("fwd+bwd", "fb_ns"))
    ratios = [dict(visc=mu, what=w, a=at[(big, mu)][k], b=at[(mid, mu)][k], r=at[(big, mu)][k] / at[(mid, mu)][k])
              for mu in sorted({r["visc"] for r in rows}) for w, k in passes]  # fmt: skip
    for r in ratios:
        r["ok"] = verdict(r["r"] <= 2.0)
    print(f"\nPer-cell cost {big}^2 / {mid}^2 (target: within 2x)")
    print(rows_table(ratios, f"visc {{visc:g}} | pass {{what}} | {big}^2 ns/cell {{a:.1f}} | {mid}^2 ns/cell "
          "{b:.1f} | ratio {r:.2f} | target {ok}"))  # fmt: skip
    over = [dict(r, tf=r["f"] * r["steps"], tfb=r["fb"] * r["steps"], ok=verdict(r["ratio"] <= 3.0)) for r in rows
            if r["grid"] == overhead_grid]  # fmt: skip
    print(f"\nBackward overhead at {overhead_grid}^2: (forward + backward) / forward (target: <= 3)")
    print(rows_table(over, "visc {visc:g} | steps {steps} | fwd ms {tf:.1f} | fwd+bwd ms {tfb:.1f} | ratio {ratio:.2f} "
          "| target {ok}"))  # fmt: skip


def report_memory(mem: dict[str, Any]) -> None:
    s, runs = mem["summary"], mem["runs"]
    print(f"\nMemory of a backward, {s['grid']}^2, viscosity field requiring grad (each config in its own process)")
    if "unrolled_attempt" in runs:
        a = runs["unrolled_attempt"]
        print(f"NOTE: the unrolled run on {s['requested_steps']} steps was stopped by its budget after "
              f"{a['steps_done']} step(s) ({a['forward_s_at_abort']:.1f} s of forward, RSS +"
              f"{a['rss_growth_gib_at_abort']:.2f} GiB, {a['saved_gib_at_abort']:.2f} GiB saved for backward; budget "
              f"{a['mem_budget_gib']:g} GiB / {a['time_budget_s']:g} s), so adjoint and unrolled are compared on "
              f"{s['compared_steps']} steps; the tolerance check runs on {s['requested_steps']} steps.")  # fmt: skip
    names = {"adjoint_short": "adjoint (implicit)", "unrolled": "unrolled plain CG", "adjoint": "adjoint (implicit)",
             "adjoint_tight": "adjoint (implicit)"}  # fmt: skip
    rows = [dict(r, config=c) for k, c in names.items() if (r := runs.get(k)) and not r.get("failed")]
    print("peak RSS +MiB = VmHWM after the backward minus RSS at the baseline; ru_maxrss +MiB = the same with "
          "ru_maxrss (floored by the parent's RSS at launch)")  # fmt: skip
    print(rows_table(rows, "config {config} | steps {steps} | rtol {rtol:g} | peak RSS +MiB {peak_rss_growth_mib:.1f} |"
          " ru_maxrss +MiB {maxrss_growth_mib:.1f} | saved MiB {saved_for_backward_mib:.1f} | fwd s {forward_s:.1f} "
          "| bwd s {backward_s:.1f} | visc it {viscosity_iters_per_step:.1f} | pres it {pressure_iters_per_step:.1f}"
          " | warn {convergence_warnings}"))  # fmt: skip
    if "rss_ratio" not in s:
        print("a memory run failed; see the JSON for its stderr")
        return
    met = s["rss_ratio"] >= 10 and s["saved_ratio"] >= 10
    print(f"\nunrolled / adjoint on {s['compared_steps']} steps: peak RSS growth {s['rss_ratio']:.1f}x, saved for "
          f"backward {s['saved_ratio']:.1f}x (target: >= 10x) -> {verdict(met)}")  # fmt: skip
    # "unchanged": within 10% on RSS (allocator noise) and within 1% on the deterministic saved bytes
    met_t = abs(s["tight_rss_ratio"] - 1) <= 0.10 and abs(s["tight_saved_ratio"] - 1) <= 0.01
    print(f"adjoint rtol {s['tight_rtol']:g} / rtol {s['rtol']:g} on {s['requested_steps']} steps: peak RSS growth "
          f"{s['tight_rss_ratio']:.2f}x, saved {s['tight_saved_ratio']:.2f}x (target: unchanged, within 10% RSS / 1% "
          f"saved) -> {verdict(met_t)}")  # fmt: skip
    if "counted_saved_mib" in s:
        c = runs["unrolled_counted"]
        print(f"unrolled on all {s['requested_steps']} steps, saved tensors counted and dropped: "
              f"{s['counted_saved_mib']:.1f} MiB saved for backward ({c['forward_s']:.0f} s of forward, "
              f"{c['pressure_iters_per_step']:.1f} pressure iterations per step): its peak is at least "
              f"{s['counted_vs_adjoint_rss']:.1f}x the adjoint's peak RSS growth ({s['counted_vs_adjoint_saved']:.1f}x"
              f" its saved bytes) (target: >= 10x) -> {verdict(s['counted_vs_adjoint_rss'] >= 10)}; the count, "
              f"checked on {s['compared_steps']} steps against the run that kept its tensors: "
              f"{s['count_check']:.5f}x")  # fmt: skip


def plot_scaling(path: str, rows: list[dict[str, Any]], title: str) -> None:
    """ms per step against grid size, forward and forward + backward, log-log, written to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=120)
    grids = sorted({r["grid"] for r in rows})
    for mu, color in zip(sorted({r["visc"] for r in rows}), ["#1b9e77", "#d95f02", "#7570b3"]):
        rs = sorted((r for r in rows if r["visc"] == mu), key=lambda r: r["grid"])
        n = [r["grid"] for r in rs]
        ax.plot(n, [r["f"] for r in rs], "o-", color=color, label=f"forward, viscosity {mu:g}")
        ax.plot(n, [r["fb"] for r in rs], "s--", color=color, label=f"forward + backward, viscosity {mu:g}")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xticks(grids, [f"{g}^2" for g in grids])
    ax.set(xlabel="grid (cells)", ylabel="ms per step (median)")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="grids 16^2 to 64^2, few steps and repeats; a 32^2 memory run")
    p.add_argument("--plot", metavar="PATH.png", help="also plot ms per step against grid size to PATH.png")
    p.add_argument("--mem-budget-gib", type=float, default=8.0, help="projected peak RSS growth above which the "
                   "unrolled memory run is shortened")  # fmt: skip
    p.add_argument("--time-budget-s", type=float, default=150.0, help="projected run time above which the unrolled "
                   "memory run is shortened")  # fmt: skip
    p.add_argument("--memory-only", action="store_true", help="skip the timings; run only the memory part")
    p.add_argument("--_child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args._child:
        print(json.dumps(memory_child(json.loads(args._child))))
        return 0
    if args.quick:
        plan = [(16, 6, 3), (32, 4, 3), (64, 2, 2)]  # (grid, steps, repeats)
        overhead_grid, mem = 16, dict(n=32, steps=6, mem_budget_gib=1.0, time_budget_s=20.0)
    else:
        plan = [(64, 10, 7), (256, 5, 5), (1024, 3, 3)]
        overhead_grid, mem = 64, dict(n=256, steps=50, mem_budget_gib=args.mem_budget_gib,
                                      time_budget_s=args.time_budget_s)  # fmt: skip
    info = start("bench_fluid", args.threads, " [--quick]" if args.quick else "")
    rows = []
    for n, steps, reps in [] if args.memory_only else plan:
        for mu in (0.0, CONSTANT_VISCOSITY):
            log(f"  scaling: {n}^2, viscosity {mu:g}, {steps} steps x {reps} repeats ...")
            rows.append(time_grid(n, steps, mu, reps))
    if rows:
        report_scaling(rows, overhead_grid)
    if args.plot and rows:
        plot_scaling(args.plot, rows, f"Fluid step, float32, {info['torch_threads']} thread(s), {info['cpu']}, "
                     f"{info['date'][:10]}")  # fmt: skip
    memory = memory_benchmark(mem["n"], mem["steps"], rtol=1e-5, tight_factor=100.0, threads=args.threads,
                              mem_budget_gib=mem["mem_budget_gib"], time_budget_s=mem["time_budget_s"],
                              unrolled_max_iter=2000, log=log)  # fmt: skip
    report_memory(memory)
    finish(info, dict(args={k: v for k, v in vars(args).items() if k != "_child"}, scaling=rows, memory=memory),
           args.json)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
