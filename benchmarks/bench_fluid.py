"""Benchmark of the fluid core: ms per step and its scaling, the backward's overhead, the adjoint's memory.

Float32 on CPU through ``FluidSimulator``: (1) ms per step forward and forward + backward on 64^2, 256^2, 1024^2,
with and without viscosity, and the per-cell cost of the largest grid over the second (target: within 2x);
(2) forward + backward over forward at 64^2, 10 steps (target: <= 3x); (3) peak RSS growth (``VmHWM`` reset at a
baseline) and bytes saved for backward of a 256^2 backward with a viscosity field, each in a fresh process: the
implicit adjoint against autograd through unrolled plain CG (whole on ``--unrolled-steps``; on all 50 steps with
its saved tensors counted and dropped, a lower bound on its peak; target: >= 10x), and the adjoint at a 100x
tighter tolerance (target: unchanged). Set-up and figures: docs/benchmarks.md, "Fluid core".
"""

from __future__ import annotations

import gc
import resource
import statistics
import sys
import time
import warnings
import weakref
from typing import Any

import torch
import torch.nn.functional as F
from _common import as_child, finish, log, parser, peak_mib, pyplot, rows_table, run_child, save_figure, start, verdict
from torch import Tensor

from torchfluidwarp import CGConfig, FluidSimulator
from torchfluidwarp.core import ConvergenceWarning

SEED = 1234
N_POINTS = 256
FORCE_AMPLITUDE = 0.05  # cells per time unit^2: a gentle stir that stays stable with dt = 1 over 50 steps
CONSTANT_VISCOSITY = 0.5  # cells^2 per time unit


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


def _maxrss_kib() -> float:
    return float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)  # KiB on Linux


def memory_child(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one memory configuration in this (fresh) process and return what it measured. ``count_only``: the
    tensors autograd saves are counted and dropped (no backward), a lower bound on the unrolled run's peak."""
    torch.set_num_threads(spec["threads"])
    rtol, unrolled, count_only = spec["rtol"], spec["backward"] == "unrolled", spec.get("count_only", False)

    def build(n: int, steps: int) -> tuple[FluidSimulator, Tensor, Tensor, Tensor]:
        gen = torch.Generator().manual_seed(SEED)
        forces, points = make_inputs(n, steps, gen)
        mu = viscosity_field(n, gen)
        cfg = CGConfig(rtol=rtol, max_iter=2000, precondition=False, backward="unrolled") if unrolled else CGConfig(
            rtol=rtol)  # fmt: skip
        return FluidSimulator((n, n), dt=1.0, viscosity=mu, pressure=cfg, diffusion=cfg), forces.requires_grad_(), \
            points, mu  # fmt: skip

    # warm-up on a tiny grid loads every code path (autograd engine, FFT and BLAS kernels) before the baseline
    sim, forces, points, _ = build(16, 2)
    loss_of(sim(forces, points)).backward()
    del sim, forces, points
    sim, forces, points, mu = build(spec["grid"], spec["steps"])
    gc.collect()
    base_now = peak_mib()  # VmRSS, with VmHWM reset to it (0 where the reset failed)
    base_maxrss = _maxrss_kib()
    saved_bytes, seen = 0, set()

    def pack(t: Tensor) -> Tensor | None:
        nonlocal saved_bytes
        key = t.untyped_storage().data_ptr()
        if key not in seen:  # kept tensors stay alive until backward, so pointers are unique
            seen.add(key)
            saved_bytes += t.untyped_storage().nbytes()
            if count_only:  # a dropped tensor's address may be reused, which real autograd would not do
                weakref.finalize(t if t._base is None else t._base, seen.discard, key)
        return None if count_only else t

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        t0 = time.perf_counter()
        with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
            out = sim(forces, points)
        t_fwd, t1 = time.perf_counter() - t0, time.perf_counter()
        if not count_only:
            loss_of(out).backward()
        t_bwd = time.perf_counter() - t1
    peak = peak_mib(base_now)
    result = {**spec, "saved_for_backward_mib": saved_bytes / 2**20, "forward_s": t_fwd,
              "viscosity_iters_per_step": statistics.mean(i for i, _ in out.iterations),
              "pressure_iters_per_step": statistics.mean(p for _, p in out.iterations)}  # fmt: skip
    if count_only:
        return {**result, "counted_peak_rss_growth_mib": peak}
    return {**result, "maxrss_growth_mib": (_maxrss_kib() - base_maxrss) / 1024, "peak_rss_growth_mib": peak,
            "baseline_rss_mib": base_now / 1024, "backward_s": t_bwd,
            "convergence_warnings": sum(issubclass(w.category, ConvergenceWarning) for w in caught),
            "grad_finite": bool(torch.isfinite(forces.grad).all() and torch.isfinite(mu.grad).all())}  # fmt: skip


def memory_benchmark(n: int, steps: int, short: int, rtol: float, tight: float, threads: int) -> dict[str, Any]:
    """Measurement 3: the adjoint against unrolled CG (whole on ``short`` steps, counted on ``steps``), and the
    adjoint at a ``tight`` times tighter tolerance; each configuration in its own process."""
    plan = {"adjoint": (steps, rtol, "implicit", False), "adjoint_tight": (steps, rtol / tight, "implicit", False),
            "adjoint_short": (short, rtol, "implicit", False), "unrolled": (short, rtol, "unrolled", False),
            "unrolled_counted_short": (short, rtol, "unrolled", True),
            "unrolled_counted": (steps, rtol, "unrolled", True)}  # fmt: skip
    runs = {}
    for name, (s, r, backward, count) in plan.items():
        log(f"  memory: {name}, {s} steps, rtol {r:g} ...")
        runs[name] = run_child(__file__, dict(grid=n, threads=threads, steps=s, rtol=r, backward=backward,
                                              count_only=count))  # fmt: skip
    summary: dict[str, Any] = dict(grid=n, steps=steps, short=short, rtol=rtol, tight_rtol=rtol / tight)
    if not any(r.get("failed") for r in runs.values()):
        ratio = lambda a, b, key, key_b=None: runs[a][key] / runs[b][key_b or key]  # noqa: E731
        summary.update(rss_ratio=ratio("unrolled", "adjoint_short", "peak_rss_growth_mib"),
                       saved_ratio=ratio("unrolled", "adjoint_short", "saved_for_backward_mib"),
                       tight_rss_ratio=ratio("adjoint_tight", "adjoint", "peak_rss_growth_mib"),
                       tight_saved_ratio=ratio("adjoint_tight", "adjoint", "saved_for_backward_mib"),
                       counted_saved_mib=runs["unrolled_counted"]["saved_for_backward_mib"],
                       counted_vs_adjoint_rss=ratio("unrolled_counted", "adjoint", "saved_for_backward_mib",
                                                    "peak_rss_growth_mib"),
                       counted_vs_adjoint_saved=ratio("unrolled_counted", "adjoint", "saved_for_backward_mib"),
                       count_check=ratio("unrolled_counted_short", "unrolled", "saved_for_backward_mib"))  # fmt: skip
    return {"summary": summary, "runs": runs}


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
    print(f"\nunrolled / adjoint on {s['short']} steps: peak RSS growth {s['rss_ratio']:.1f}x, saved for "
          f"backward {s['saved_ratio']:.1f}x (target: >= 10x) -> {verdict(met)}")  # fmt: skip
    # "unchanged": within 10% on RSS (allocator noise) and within 1% on the deterministic saved bytes
    met_t = abs(s["tight_rss_ratio"] - 1) <= 0.10 and abs(s["tight_saved_ratio"] - 1) <= 0.01
    print(f"adjoint rtol {s['tight_rtol']:g} / rtol {s['rtol']:g} on {s['steps']} steps: peak RSS growth "
          f"{s['tight_rss_ratio']:.2f}x, saved {s['tight_saved_ratio']:.2f}x (target: unchanged, within 10% RSS / 1% "
          f"saved) -> {verdict(met_t)}")  # fmt: skip
    c = runs["unrolled_counted"]
    print(f"unrolled on all {s['steps']} steps, saved tensors counted and dropped: {s['counted_saved_mib']:.1f} MiB "
          f"saved for backward ({c['forward_s']:.0f} s of forward, {c['viscosity_iters_per_step']:.1f} viscosity and "
          f"{c['pressure_iters_per_step']:.1f} pressure iterations per step): its peak is at least "
          f"{s['counted_vs_adjoint_rss']:.1f}x the adjoint's peak RSS growth ({s['counted_vs_adjoint_saved']:.1f}x"
          f" its saved bytes) (target: >= 10x) -> {verdict(s['counted_vs_adjoint_rss'] >= 10)}; the count, "
          f"checked on {s['short']} steps against the run that kept its tensors: {s['count_check']:.5f}x")  # fmt: skip


def plot_scaling(path: str, rows: list[dict[str, Any]], title: str) -> None:
    """ms per step against grid size, forward and forward + backward, log-log, written to ``path`` (PNG)."""
    fig, ax = pyplot().subplots(figsize=(6.4, 4.4), dpi=120)
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
    p = parser(__doc__, quick="grids 16^2 to 64^2, few steps and repeats; a 32^2 memory run", child=True)
    p.add_argument("--plot", metavar="PATH.png", help="also plot ms per step against grid size to PATH.png")
    p.add_argument("--unrolled-steps", type=int, default=3, help="steps of the whole unrolled-CG memory run (default "
                   "3: 50 steps would need some 100 GiB)")  # fmt: skip
    args = p.parse_args(argv)
    if as_child(args, memory_child):
        return 0
    # (grid, steps, repeats) of the timings; the backward overhead's grid; the memory runs' grid and steps
    plan, overhead_grid, mem = ([(16, 6, 3), (32, 4, 3), (64, 2, 2)], 16, (32, 6)) if args.quick else (
        [(64, 10, 7), (256, 5, 5), (1024, 3, 3)], 64, (256, 50))  # fmt: skip
    info = start("bench_fluid", args.threads, " [--quick]" if args.quick else "")
    rows = []
    for n, steps, reps in plan:
        for mu in (0.0, CONSTANT_VISCOSITY):
            log(f"  scaling: {n}^2, viscosity {mu:g}, {steps} steps x {reps} repeats ...")
            rows.append(time_grid(n, steps, mu, reps))
    report_scaling(rows, overhead_grid)
    if args.plot:
        plot_scaling(args.plot, rows, f"Fluid step, float32, {info['torch_threads']} thread(s), {info['cpu']}, "
                     f"{info['date'][:10]}")  # fmt: skip
    memory = memory_benchmark(*mem, args.unrolled_steps, rtol=1e-5, tight=100.0, threads=args.threads)
    report_memory(memory)
    finish(info, dict(args={k: v for k, v in vars(args).items() if k != "_child"}, scaling=rows, memory=memory),
           args.json)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
