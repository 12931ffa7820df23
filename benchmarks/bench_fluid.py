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
import os
import resource
import statistics
import subprocess
import sys
import time
import warnings
import weakref
from dataclasses import asdict, dataclass
from typing import Any

import torch
import torch.nn.functional as F
from _common import add_threads_argument, machine, reset_peak, save_figure, status_kib, table, verdict, write_json
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


@dataclass
class ScalingRow:
    """One grid and viscosity of measurement 1 (and 2)."""

    grid: int
    viscosity: float
    steps: int
    repeats: int
    forward_ms_per_step: float
    forward_backward_ms_per_step: float
    forward_ns_per_cell_step: float
    forward_backward_ns_per_cell_step: float
    backward_over_forward: float
    viscosity_iters_per_step: float
    pressure_iters_per_step: float
    convergence_warnings: int


def time_grid(n: int, steps: int, viscosity: float, repeats: int) -> ScalingRow:
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
    cells = n * n
    return ScalingRow(
        grid=n,
        viscosity=viscosity,
        steps=steps,
        repeats=repeats,
        forward_ms_per_step=f_ms,
        forward_backward_ms_per_step=fb_ms,
        forward_ns_per_cell_step=f_ms * 1e6 / cells,
        forward_backward_ns_per_cell_step=fb_ms * 1e6 / cells,
        backward_over_forward=fb_ms / f_ms,
        viscosity_iters_per_step=statistics.mean(i for i, _ in out.iterations),
        pressure_iters_per_step=statistics.mean(p for _, p in out.iterations),
        convergence_warnings=n_warn,
    )


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


def run_child(spec: dict[str, Any]) -> dict[str, Any]:
    """Run :func:`memory_child` in a fresh interpreter, so that its ``ru_maxrss`` is its own."""
    proc = subprocess.run(
        [sys.executable, os.path.abspath(__file__), "--_child", json.dumps(spec)], capture_output=True, text=True
    )
    if proc.returncode != 0:
        return {**spec, "failed": True, "returncode": proc.returncode, "stderr_tail": proc.stderr[-2000:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


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
    runs["adjoint"] = run_child({**base, "steps": steps, "rtol": rtol, "backward": "implicit"})
    log(f"  memory: adjoint, {steps} steps, rtol {rtol / tight_factor:g} ...")
    runs["adjoint_tight"] = run_child({**base, "steps": steps, "rtol": rtol / tight_factor, "backward": "implicit"})
    log(f"  memory: unrolled unpreconditioned CG, {steps} steps, rtol {rtol:g} (with a budget check) ...")
    unrolled = run_child({**base, "steps": steps, "rtol": rtol, "backward": "unrolled"})
    compare_steps = steps
    if unrolled.get("aborted"):
        runs["unrolled_attempt"] = unrolled
        compare_steps = unrolled["steps_that_fit"]
        log(f"  memory: the unrolled run would overrun its budget; both configs again on {compare_steps} steps ...")
        runs["adjoint_short"] = run_child({**base, "steps": compare_steps, "rtol": rtol, "backward": "implicit"})
        unrolled = run_child({**base, "steps": compare_steps, "rtol": rtol, "backward": "unrolled"})
        log(f"  memory: unrolled on {compare_steps} steps again, counting what it saves (checks the count) ...")
        runs["unrolled_counted_short"] = run_child(
            {**base, "steps": compare_steps, "rtol": rtol, "backward": "unrolled", "count_only": True}
        )
        log(f"  memory: unrolled on all {steps} steps, counting what it saves (dropped, no backward) ...")
        runs["unrolled_counted"] = run_child(
            {**base, "steps": steps, "rtol": rtol, "backward": "unrolled", "count_only": True}
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


def report_scaling(rows: list[ScalingRow], overhead_grid: int) -> tuple[str, dict[str, Any]]:
    out = ["Scaling (float32, CPU; median ms per step; iterations = CG iterations per step, forward)"]
    out.append(
        table(
            [
                "grid",
                "visc",
                "steps",
                "reps",
                "fwd ms/step",
                "fwd+bwd ms/step",
                "fwd ns/cell",
                "f+b ns/cell",
                "f+b / fwd",
                "visc it",
                "pres it",
                "warn",
            ],
            [
                [
                    f"{r.grid}^2",
                    f"{r.viscosity:g}",
                    str(r.steps),
                    str(r.repeats),
                    f"{r.forward_ms_per_step:.2f}",
                    f"{r.forward_backward_ms_per_step:.2f}",
                    f"{r.forward_ns_per_cell_step:.1f}",
                    f"{r.forward_backward_ns_per_cell_step:.1f}",
                    f"{r.backward_over_forward:.2f}",
                    f"{r.viscosity_iters_per_step:g}",
                    f"{r.pressure_iters_per_step:g}",
                    str(r.convergence_warnings),
                ]
                for r in rows
            ],
        )
    )
    grids = sorted({r.grid for r in rows})
    big, mid = grids[-1], grids[-2]
    targets: dict[str, Any] = {"per_cell": [], "overhead": []}
    out.append(f"\nPer-cell cost {big}^2 / {mid}^2 (target: within 2x, i.e. <= 2)")
    ratio_rows = []
    for mu in sorted({r.viscosity for r in rows}):
        rb = next(r for r in rows if r.grid == big and r.viscosity == mu)
        rm = next(r for r in rows if r.grid == mid and r.viscosity == mu)
        for what, a, b in [
            ("forward", rb.forward_ns_per_cell_step, rm.forward_ns_per_cell_step),
            ("fwd+bwd", rb.forward_backward_ns_per_cell_step, rm.forward_backward_ns_per_cell_step),
        ]:
            ratio = a / b
            targets["per_cell"].append({"viscosity": mu, "pass": what, "ratio": ratio, "met": ratio <= 2.0})
            ratio_rows.append([f"{mu:g}", what, f"{a:.1f}", f"{b:.1f}", f"{ratio:.2f}", verdict(ratio <= 2.0)])
    out.append(table(["visc", "pass", f"{big}^2 ns/cell", f"{mid}^2 ns/cell", "ratio", "target"], ratio_rows))
    out.append(f"\nBackward overhead at {overhead_grid}^2: (forward + backward) / forward (target: <= 3)")
    oh_rows = []
    for r in rows:
        if r.grid == overhead_grid:
            met = r.backward_over_forward <= 3.0
            targets["overhead"].append(
                {"viscosity": r.viscosity, "steps": r.steps, "ratio": r.backward_over_forward, "met": met}
            )
            oh_rows.append(
                [
                    f"{r.viscosity:g}",
                    str(r.steps),
                    f"{r.forward_ms_per_step * r.steps:.1f}",
                    f"{r.forward_backward_ms_per_step * r.steps:.1f}",
                    f"{r.backward_over_forward:.2f}",
                    verdict(met),
                ]
            )
    out.append(table(["visc", "steps", "fwd ms", "fwd+bwd ms", "ratio", "target"], oh_rows))
    return "\n".join(out), targets


def report_memory(mem: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    s, runs = mem["summary"], mem["runs"]
    out = [f"Memory of a backward, {s['grid']}^2, viscosity field requiring grad (each config in its own process)"]
    if "unrolled_attempt" in runs:
        a = runs["unrolled_attempt"]
        out.append(
            f"NOTE: the unrolled run on {s['requested_steps']} steps was stopped by its budget after "
            f"{a['steps_done']} step(s) ({a['forward_s_at_abort']:.1f} s of forward, RSS +"
            f"{a['rss_growth_gib_at_abort']:.2f} GiB, {a['saved_gib_at_abort']:.2f} GiB saved for backward; budget "
            f"{a['mem_budget_gib']:g} GiB / {a['time_budget_s']:g} s), so adjoint and unrolled are compared on "
            f"{s['compared_steps']} steps; the tolerance check runs on {s['requested_steps']} steps."
        )
    measure = {r.get("peak_measure") for r in runs.values() if "peak_measure" in r}
    out.append(
        f"peak RSS +MiB = {'/'.join(sorted(measure))} after the backward minus RSS at the baseline; "
        "ru_maxrss +MiB = the same with ru_maxrss (floored by the parent's RSS at launch, see the module doc)"
    )
    rows = []
    order = [
        ("adjoint_short", "adjoint (implicit)"),
        ("unrolled", "unrolled plain CG"),
        ("adjoint", "adjoint (implicit)"),
        ("adjoint_tight", "adjoint (implicit)"),
    ]
    for key, label in order:
        r = runs.get(key)
        if r is None:
            continue
        if r.get("failed"):
            rows.append(
                [label, str(r["steps"]), f"{r['rtol']:g}", "FAILED", f"rc {r['returncode']}", "", "", "", "", "", ""]
            )
            continue
        rows.append(
            [
                label,
                str(r["steps"]),
                f"{r['rtol']:g}",
                f"{r['peak_rss_growth_mib']:.1f}",
                f"{r['maxrss_growth_mib']:.1f}",
                f"{r['saved_for_backward_mib']:.1f}",
                f"{r['forward_s']:.1f}",
                f"{r['backward_s']:.1f}",
                f"{r['viscosity_iters_per_step']:.1f}",
                f"{r['pressure_iters_per_step']:.1f}",
                str(r["convergence_warnings"]),
            ]
        )
    out.append(
        table(
            [
                "config",
                "steps",
                "rtol",
                "peak RSS +MiB",
                "ru_maxrss +MiB",
                "saved MiB",
                "fwd s",
                "bwd s",
                "visc it",
                "pres it",
                "warn",
            ],
            rows,
        )
    )
    targets: dict[str, Any] = {}
    if "rss_ratio" in s:
        met = s["rss_ratio"] >= 10 and s["saved_ratio"] >= 10
        targets["adjoint_vs_unrolled"] = {
            "rss_ratio": s["rss_ratio"],
            "saved_ratio": s["saved_ratio"],
            "met": met,
            "steps": s["compared_steps"],
        }
        out.append(
            f"\nunrolled / adjoint on {s['compared_steps']} steps: peak RSS growth {s['rss_ratio']:.1f}x, "
            f"saved for backward {s['saved_ratio']:.1f}x (target: >= 10x) -> {verdict(met)}"
        )
        # "unchanged": within 10% on RSS (allocator noise) and within 1% on the deterministic saved bytes
        met_t = abs(s["tight_rss_ratio"] - 1) <= 0.10 and abs(s["tight_saved_ratio"] - 1) <= 0.01
        targets["tight_tolerance"] = {
            "rss_ratio": s["tight_rss_ratio"],
            "saved_ratio": s["tight_saved_ratio"],
            "met": met_t,
        }
        out.append(
            f"adjoint rtol {s['tight_rtol']:g} / rtol {s['rtol']:g} on {s['requested_steps']} steps: peak RSS "
            f"growth {s['tight_rss_ratio']:.2f}x, saved {s['tight_saved_ratio']:.2f}x (target: unchanged, "
            f"within 10% RSS / 1% saved) -> {verdict(met_t)}"
        )
        if "counted_saved_mib" in s:
            c = runs["unrolled_counted"]
            met_c = s["counted_vs_adjoint_rss"] >= 10
            targets["adjoint_vs_unrolled_full_steps"] = {
                "unrolled_saved_mib_lower_bound": s["counted_saved_mib"],
                "ratio_lower_bound": s["counted_vs_adjoint_rss"],
                "met": met_c,
                "steps": s["requested_steps"],
            }
            out.append(
                f"unrolled on all {s['requested_steps']} steps, saved tensors counted and dropped: "
                f"{s['counted_saved_mib']:.1f} MiB saved for backward ({c['forward_s']:.0f} s of forward, "
                f"{c['pressure_iters_per_step']:.1f} pressure iterations per step); autograd would hold all of it "
                f"when its backward starts, so its peak is at least {s['counted_vs_adjoint_rss']:.1f}x the "
                f"adjoint's peak RSS growth ({s['counted_vs_adjoint_saved']:.1f}x its saved bytes) "
                f"(target: >= 10x) -> {verdict(met_c)}; the count, checked on {s['compared_steps']} steps against the "
                f"run that kept its tensors: {s['count_check']:.5f}x"
            )
    else:
        out.append("a memory run failed; see the JSON for its stderr")
    return "\n".join(out), targets


def plot_scaling(path: str, rows: list[ScalingRow], title: str) -> None:
    """ms per step against grid size, forward and forward + backward, log-log, written to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=120)
    for mu, color in zip(sorted({r.viscosity for r in rows}), ["#1b9e77", "#d95f02", "#7570b3"]):
        rs = sorted((r for r in rows if r.viscosity == mu), key=lambda r: r.grid)
        n = [r.grid for r in rs]
        ax.plot(n, [r.forward_ms_per_step for r in rs], "o-", color=color, label=f"forward, viscosity {mu:g}")
        ax.plot(
            n,
            [r.forward_backward_ms_per_step for r in rs],
            "s--",
            color=color,
            label=f"forward + backward, viscosity {mu:g}",
        )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xticks(sorted({r.grid for r in rows}), [f"{g}^2" for g in sorted({r.grid for r in rows})])
    ax.set_xlabel("grid (cells)")
    ax.set_ylabel("ms per step (median)")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


# ----------------------------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="smoke mode: small grids, few steps and repeats")
    parser.add_argument("--json", metavar="PATH", help="also write the results as JSON to PATH")
    parser.add_argument("--plot", metavar="PATH.png", help="also plot ms per step against grid size to PATH.png")
    add_threads_argument(parser)
    parser.add_argument(
        "--mem-budget-gib",
        type=float,
        default=8.0,
        help="projected peak RSS growth above which the unrolled memory run is shortened",
    )
    parser.add_argument(
        "--time-budget-s",
        type=float,
        default=150.0,
        help="projected run time above which the unrolled memory run is shortened",
    )
    parser.add_argument("--memory-only", action="store_true", help="skip the timings; run only the memory part")
    parser.add_argument("--_child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.threads < 1:
        parser.error(f"--threads must be >= 1, got {args.threads}")
    if args._child:
        print(json.dumps(memory_child(json.loads(args._child))))
        return 0

    torch.set_num_threads(args.threads)
    if args.quick:
        plan = [(16, 6, 3), (32, 4, 3), (64, 2, 2)]  # (grid, steps, repeats)
        overhead_grid, mem = 16, dict(n=32, steps=6, mem_budget_gib=1.0, time_budget_s=20.0)
    else:
        plan = [(64, 10, 7), (256, 5, 5), (1024, 3, 3)]
        overhead_grid, mem = (
            64,
            dict(n=256, steps=50, mem_budget_gib=args.mem_budget_gib, time_budget_s=args.time_budget_s),
        )
    info = machine()
    print(
        f"bench_fluid: {info['cpu']}, {info['cpu_count']} CPUs, torch {info['torch']} with "
        f"{info['torch_threads']} thread(s), Python {info['python']}, {info['date']}"
        + (" [--quick]" if args.quick else ""),
        flush=True,
    )
    log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731

    t0 = time.perf_counter()
    rows = []
    for n, steps, reps in [] if args.memory_only else plan:
        for mu in (0.0, CONSTANT_VISCOSITY):
            log(f"  scaling: {n}^2, viscosity {mu:g}, {steps} steps x {reps} repeats ...")
            rows.append(time_grid(n, steps, mu, reps))
    text_s, targets_s = report_scaling(rows, overhead_grid) if rows else ("", {})
    print("\n" + text_s, flush=True)
    if args.plot and rows:
        title = f"Fluid step, float32, {info['torch_threads']} thread(s), {info['cpu']}, {info['date'][:10]}"
        plot_scaling(args.plot, rows, title)
        print(f"plot written to {args.plot}", flush=True)

    memory = memory_benchmark(
        mem["n"],
        mem["steps"],
        rtol=1e-5,
        tight_factor=100.0,
        threads=args.threads,
        mem_budget_gib=mem["mem_budget_gib"],
        time_budget_s=mem["time_budget_s"],
        unrolled_max_iter=2000,
        log=log,
    )
    text_m, targets_m = report_memory(memory)
    print("\n" + text_m)
    total = time.perf_counter() - t0
    print(f"\ntotal {total:.0f} s")

    if args.json:
        result = {
            "machine": info,
            "args": {k: v for k, v in vars(args).items() if k != "_child"},
            "scaling": [asdict(r) for r in rows],
            "memory": memory,
            "targets": {**targets_s, **targets_m},
            "total_s": total,
        }
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
