"""Benchmark of keyframe control: the paper's morphing set-up, fitted with ``fit_keyframes``.

64x64 fluid, 10 steps, control 5x5 (500 parameters), 14 points, targets 5-10 px away (``_common.flow_instance``
seeds, and one random instance, seed 1000). Targets: mean error < 0.05 px and fit < 3 s; issue #20: median 0.25
s. Reports the fits (float64 and float32, ``method="auto"`` and ``"lbfgs"``), a gradient over a forward, the time
per evaluation against ``--controls``, the peak memory of a fit and the first fit of a fresh process against a
warm one (target <= 1.2x). Set-up and figures: docs/benchmarks.md, "Keyframe control".
"""

from __future__ import annotations

import math
import statistics
import sys
import time
from dataclasses import asdict
from typing import Any

import torch
from _common import (
    FRAME,
    Instance,
    as_child,
    finish,
    flow_instance,
    interleaved,
    log,
    median_ms,
    parser,
    random_instance,
    reset_peak,
    rows_table,
    run_child,
    start,
    status_kib,
    verdict,
    yes,
)

from torchfluidwarp.control import fit_keyframes, keyframe_loss

TARGET_MEAN_PX, TARGET_SECONDS, TARGET_MEDIAN_SECONDS = 0.05, 3.0, 0.25
PAPER_SECONDS = 300.0  # the figure for the paper, quoted, not measured
DTYPES = {"float64": torch.float64, "float32": torch.float32}
METHODS = ("auto", "lbfgs")
FIRST_FIT_PROCESSES = 5  # one process's first call varies with the machine's load: the median of 5 is read


def fit_kwargs(cfg: dict[str, Any], dtype: torch.dtype, control: tuple[int, int], method: str = "auto") -> dict:
    return dict(image_size=FRAME, grid=tuple(cfg["grid"]), steps=cfg["steps"], control=tuple(control),
                max_iter=cfg["max_iter"], tolerance=cfg["tolerance"], dtype=dtype, progress=False, method=method,
                viscosity=cfg["viscosity"], compressible=cfg["compressible"])  # fmt: skip


def tiny_fit(dtype: torch.dtype) -> Any:
    """A 3-iteration fit on an 8x8 fluid: loads every code path (autograd, L-BFGS, FFT and BLAS kernels)."""
    a, b = torch.tensor([[10.0, 10.0]]), torch.tensor([[12.0, 10.0]])
    return fit_keyframes(a, b, image_size=(24, 24), grid=8, steps=2, control=(3, 3), max_iter=3, dtype=dtype,
                         progress=False)  # fmt: skip


def run_fit(inst: Instance, dtype: str, cfg: dict, control: tuple[int, int], method: str) -> tuple[dict, Any]:
    src, tgt = inst.tensors(DTYPES[dtype])
    cpu0 = time.process_time()
    fit = fit_keyframes(src, tgt, **fit_kwargs(cfg, DTYPES[dtype], control, method))
    run = dict(seconds=fit.seconds, cpu=time.process_time() - cpu0, evals=fit.evaluations, forwards=fit.forwards,
               mean=float(fit.error.mean()), max=float(fit.error.max()), converged=fit.converged,
               reached=fit.reached)  # fmt: skip
    return run, fit


def summarise(inst: Instance, dtype: str, method: str, control: tuple[int, int], steps: int, runs: list) -> dict:
    """Medians over the repeats; ms/eval divides by L-BFGS' evaluations only (the start's roll-outs excluded)."""
    med = {k: statistics.median(r[k] for r in runs) for k in ("seconds", "cpu", "evals", "forwards")}
    first = runs[0]
    same = all((r["evals"], r["forwards"], r["mean"], r["reached"]) == (first["evals"], first["forwards"],
               first["mean"], first["reached"]) for r in runs)  # fmt: skip
    ev = med["evals"]
    return dict(instance=inst.name, kind=inst.kind, dtype=dtype, method=method, control=f"{control[0]}x{control[1]}",
                params=2 * steps * control[0] * control[1], **med, mean=first["mean"], max=first["max"],
                ms_eval=med["seconds"] / ev * 1e3 if ev else math.nan, cpu_ms_eval=med["cpu"] / ev * 1e3 if ev else
                math.nan, converged=yes(first["converged"]), reached=yes(first["reached"]), same=yes(same),
                ok_mean=verdict(first["mean"] < TARGET_MEAN_PX), ok_time=verdict(med["seconds"] < TARGET_SECONDS),
                seconds_all=[r["seconds"] for r in runs])  # fmt: skip


def time_gradient(inst: Instance, fits: dict[tuple[str, tuple[int, int]], Any], steps: int, repeats: int) -> list:
    """Forward (no grad) against forward + backward of the fit's objective, at each fit's own forces."""
    cases = {}
    for (dtype, control), fit in fits.items():
        src, tgt = (x[None] for x in inst.tensors(DTYPES[dtype]))
        params = [p for p in fit.forces.parameters() if p.requires_grad]

        def forward(fit=fit, src=src) -> None:
            with torch.no_grad():
                fit.warp.carry_points(src, fit.forces)

        def gradient(fit=fit, src=src, tgt=tgt, params=params) -> None:
            for p in params:
                p.grad = None
            keyframe_loss(fit.warp.carry_points(src, fit.forces), [(steps, tgt)]).backward()

        cases[(dtype, control, "f")], cases[(dtype, control, "g")] = forward, gradient
    times = interleaved(cases, repeats)  # type: ignore[arg-type]
    rows = []
    for dtype, control in fits:
        f, g = (times[(dtype, control, k)] for k in "fg")
        fw, gw, fc, gc = median_ms(t[0] for t in f), median_ms(t[0] for t in g), median_ms(t[1] for t in f), median_ms(
            t[1] for t in g)  # fmt: skip
        rows.append(dict(dtype=dtype, control=f"{control[0]}x{control[1]}", params=2 * steps * control[0] * control[1],
                         fwd=fw, grad=gw, ratio=gw / fw, fwd_cpu=fc, grad_cpu=gc, ratio_cpu=gc / fc,
                         ok=verdict(gw / fw <= 2.0)))  # fmt: skip
    return sorted(rows, key=lambda r: (r["dtype"], r["params"]))


def child(spec: dict[str, Any]) -> dict[str, Any]:
    """In a fresh process: the memory of one fit (``kind`` "memory") or the first fit against warm ones."""
    torch.set_num_threads(spec["threads"])
    dtype = DTYPES[spec["dtype"]]
    src, tgt = Instance(**spec["instance"]).tensors(dtype)
    kwargs = fit_kwargs(spec, dtype, spec["control"])
    if spec["kind"] == "first":
        walls, evals = [], []
        for _ in range(1 + spec["warm_repeats"]):
            t0 = time.perf_counter()
            evals.append(fit_keyframes(src, tgt, **kwargs).evaluations)
            walls.append(time.perf_counter() - t0)
        warm = statistics.median(walls[1:])
        return dict(first=walls[0], warm=warm, ratio=walls[0] / warm, evals="/".join(map(str, evals)),
                    dynamo=yes("torch._dynamo" in sys.modules))  # fmt: skip
    t0 = time.perf_counter()
    first_fit_s = tiny_fit(dtype).seconds  # the warm-up: the first call of this process
    first_call_s = time.perf_counter() - t0
    reset = reset_peak()
    base = status_kib("VmRSS")
    fit = fit_keyframes(src, tgt, **kwargs)
    peak = status_kib("VmHWM")
    return dict(dtype=spec["dtype"], measure="VmHWM" if reset else "VmHWM (not reset)", base=base / 1024,
                peak=peak / 1024, growth=(peak - base) / 1024, evals=fit.evaluations, seconds=fit.seconds,
                first_call=first_call_s, first_call_fit=first_fit_s)  # fmt: skip


def parse_control(text: str) -> tuple[int, int]:
    ky, kx = (int(v) for v in text.lower().split("x"))
    return ky, kx


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="32x32 fluid, 5 steps, 6 points, 2 flow seeds, one repeat", child=True)
    p.add_argument("--seeds", type=int, help="number of flow instances (default 5; --quick 2)")
    p.add_argument("--repeats", type=int, help="repeats of each fit (default 3; --quick 1)")
    p.add_argument("--grad-repeats", type=int, help="repeats of the gradient timing (default 9; --quick 3)")
    p.add_argument("--tolerance", type=float, default=0.05, help="px: stop once every point is within it")
    p.add_argument("--max-iter", type=int, default=200, help="L-BFGS iterations at most (default 200)")
    p.add_argument("--controls", type=parse_control, nargs="+", default=[(3, 3), (5, 5), (8, 8)],
                   help="control grids of the parameter-count sweep (default 3x3 5x5 8x8)")  # fmt: skip
    p.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS), help="fit_keyframes methods")
    p.add_argument("--viscosity", type=float, default=0.0, help="the fits' viscosity (default 0, the paper's)")
    p.add_argument("--compressible", type=float, default=0.0, help="the fits' compressible weight (default 0)")
    args = p.parse_args(argv)
    if as_child(args, child):
        return 0
    q = args.quick
    cfg = dict(grid=(32, 32) if q else (64, 64), steps=5 if q else 10, points=6 if q else 14,
               seeds=args.seeds or (2 if q else 5), repeats=args.repeats or (1 if q else 3),
               grad_repeats=args.grad_repeats or (3 if q else 9), tolerance=args.tolerance, max_iter=args.max_iter,
               viscosity=args.viscosity, compressible=args.compressible)  # fmt: skip
    control, steps = (5, 5), cfg["steps"]
    info = start("bench_keyframes", args.threads, " [--quick]" if q else "")
    print(f"set-up: {cfg['grid'][0]}x{cfg['grid'][1]} fluid, {steps} steps, {cfg['points']} points in a "
          f"{FRAME[1]}x{FRAME[0]} px frame, control 5x5 ({2 * steps * 25} parameters), tolerance "
          f"{cfg['tolerance']:g} px, max_iter {cfg['max_iter']}, viscosity {cfg['viscosity']:g}, compressible "
          f"{cfg['compressible']:g}")  # fmt: skip

    log("  instances ...")
    instances = [flow_instance(s, cfg["points"], cfg["grid"], steps) for s in range(cfg["seeds"])]
    instances.append(random_instance(1000, cfg["points"]))
    print("\nProblem instances (px; displacement = |target - source|)")
    described = [dict(name=i.name, n=len(i.source), scale=i.brush_scale or 0.0, attempts=i.attempts, **i.describe())
                 for i in instances]  # fmt: skip
    print(rows_table(described, "instance {name} | points {n} | min disp {min_disp:.2f} | max disp {max_disp:.2f} | "
          "min spacing {min_spacing:.2f} | target min wall dist {min_wall:.2f} | brush scale {scale:.3f} | "
          "attempts {attempts}"))  # fmt: skip
    for dtype in DTYPES.values():
        tiny_fit(dtype)  # warm-up

    # 1. the fits, interleaved over instances, dtypes and methods
    runs: dict[tuple[str, str, str], list[dict]] = {}
    fits: dict[tuple[str, tuple[int, int]], Any] = {}
    for rep in range(cfg["repeats"]):
        for inst in instances:
            for dtype in DTYPES:
                for method in args.methods:
                    log(f"  fit {inst.name}, {dtype}, {method}, repeat {rep + 1}/{cfg['repeats']} ...")
                    run, fit = run_fit(inst, dtype, cfg, control, method)
                    runs.setdefault((inst.name, dtype, method), []).append(run)
                    if inst is instances[0] and (method == "lbfgs" or (dtype, control) not in fits):
                        fits[(dtype, control)] = fit
    rows = [summarise(i, d, m, control, steps, runs[(i.name, d, m)]) for i in instances for d in DTYPES
            for m in args.methods]  # fmt: skip
    spec = ("instance {instance} | dtype {dtype} | method {method} | forwards {forwards:g} | evals {evals:g} | "
            "fit s {seconds:.2f} | CPU s {cpu:.2f} | ms/eval {ms_eval:.1f} | CPU ms/eval {cpu_ms_eval:.1f} | "
            "mean err px {mean:.4f} | max err px {max:.4f} | converged {converged} | reached {reached} | "
            "same each rep {same}")  # fmt: skip
    print(f"\nFits, control 5x5, tolerance {cfg['tolerance']:g} px; medians over {cfg['repeats']} repeats; auto = the "
          "quasi-Newton start (forwards: roll-outs without autograd), then L-BFGS (evals) if it stalls")  # fmt: skip
    print("\nReachable instances (targets made by a flow)")
    flow = [r for r in rows if r["kind"] == "flow"]
    print(rows_table(flow, spec + " | mean < 0.05 {ok_mean} | < 3 s {ok_time}"))
    print("\nRandom-direction instance (may be partly unreachable; no target)")
    print(rows_table([r for r in rows if r["kind"] != "flow"], spec))
    summary = []
    for method in args.methods:
        for dtype in DTYPES:
            rs = [r for r in flow if r["dtype"] == dtype and r["method"] == method]
            s, c = [r["seconds"] for r in rs], [r["cpu"] for r in rs]
            med = statistics.median(s)
            summary.append(dict(dtype=dtype, method=method, n=len(rs), worst=max(r["mean"] for r in rs),
                                ok_mean=verdict(all(r["mean"] < TARGET_MEAN_PX for r in rs)), s_min=min(s), s_med=med,
                                s_max=max(s), under=f"{sum(x < TARGET_SECONDS for x in s)}/{len(rs)}",
                                c_min=min(c), c_med=statistics.median(c), c_max=max(c),
                                ok_median=verdict(med <= TARGET_MEDIAN_SECONDS),
                                forwards=statistics.median(r["forwards"] for r in rs),
                                evals=statistics.median(r["evals"] for r in rs),
                                ms_eval=statistics.median(r["ms_eval"] for r in rs),
                                paper=PAPER_SECONDS / med))  # fmt: skip
    print("\nSummary over the reachable instances (CPU time, with 1 thread, estimates the wall time on a core of "
          "its own)")  # fmt: skip
    print(rows_table(summary, "dtype {dtype} | method {method} | instances {n} | worst mean err {worst:.4f} | "
          "mean < 0.05 px {ok_mean} | fit s min/med/max {s_min:.2f} / {s_med:.3f} / {s_max:.2f} | fits < 3 s "
          "{under} | CPU s min/med/max {c_min:.2f} / {c_med:.2f} / {c_max:.2f} | median <= 0.25 s (#20) "
          "{ok_median} | median forwards {forwards:g} | median evals {evals:g} | med ms/eval {ms_eval:.1f} | "
          "vs 5 min (quoted) {paper:.0f}x"))  # fmt: skip
    for dtype in DTYPES:
        pair = {r["method"]: r["s_med"] for r in summary if r["dtype"] == dtype}
        if len(pair) == 2:
            print(f"{dtype}: median fit lbfgs / auto {pair['lbfgs'] / pair['auto']:.2f}x")

    # 3. parameter count (float64, L-BFGS alone), interleaved; its fits also feed 2.
    sweep: dict[tuple[int, int], list[dict]] = {c: [] for c in args.controls}
    for rep in range(cfg["repeats"]):
        for c in args.controls:
            log(f"  fit {instances[0].name}, float64, control {c[0]}x{c[1]}, repeat {rep + 1} ...")
            run, fit = run_fit(instances[0], "float64", cfg, c, "lbfgs")
            sweep[c].append(run)
            fits.setdefault(("float64", c), fit)
    sweep_rows = [summarise(instances[0], "float64", "lbfgs", c, steps, sweep[c]) for c in args.controls]

    # 2. gradient over forward
    log("  gradient / forward ...")
    grad_rows = time_gradient(instances[0], fits, steps, cfg["grad_repeats"])
    print(f"\nCost of a gradient: forward (no grad) against forward + backward of the objective at the fitted "
          f"forces of {instances[0].name}; medians of {cfg['grad_repeats']} interleaved repeats")  # fmt: skip
    print(rows_table(grad_rows, "dtype {dtype} | control {control} | params {params} | forward ms {fwd:.1f} | "
          "gradient ms {grad:.1f} | grad / fwd {ratio:.2f} | CPU fwd ms {fwd_cpu:.1f} | CPU grad ms {grad_cpu:.1f} "
          "| CPU grad / fwd {ratio_cpu:.2f} | expected ~1-2x {ok}"))  # fmt: skip
    grads = {r["control"]: r for r in grad_rows if r["dtype"] == "float64"}
    base = sweep_rows[0]
    for r in sweep_rows:
        g = grads.get(r["control"], {})
        r.update(vs=r["cpu_ms_eval"] / base["cpu_ms_eval"], gms=g.get("grad", math.nan), gcpu=g.get("grad_cpu", 0.0))
    print(f"\nParameter count: {instances[0].name}, float64, L-BFGS, each control grid, interleaved")
    print(rows_table(sweep_rows, "control {control} | params {params} | evals {evals:g} | fit s {seconds:.2f} | "
          "ms/eval {ms_eval:.1f} | CPU ms/eval {cpu_ms_eval:.1f} | CPU ms/eval vs first {vs:.2f} | gradient ms "
          "{gms:.1f} | CPU gradient ms {gcpu:.1f} | mean err px {mean:.4f} | reached {reached}"))  # fmt: skip
    big = sweep_rows[-1]
    g_growth = big["gcpu"] / base["gcpu"] if base["gcpu"] else math.nan
    met = big["vs"] <= 1.25 and (math.isnan(g_growth) or g_growth <= 1.25)
    print(f"{big['params']} / {base['params']} parameters: CPU ms per evaluation {big['vs']:.2f}x, CPU ms per "
          f"gradient {g_growth:.2f}x; target: does not grow (within 25% in CPU time) -> {verdict(met)}")  # fmt: skip

    # 4. and 5. in fresh processes
    keys = ("grid", "steps", "max_iter", "tolerance", "viscosity", "compressible")
    spec_child = dict(threads=args.threads, instance=asdict(instances[0]), control=control, **{k: cfg[k] for k in keys})
    log("  memory ...")
    mem = [run_child(__file__, {**spec_child, "kind": "memory", "dtype": d}) for d in DTYPES]
    print("\nPeak memory of a fit (a fresh process each; growth = VmHWM after the fit - VmRSS at the baseline); "
          "1st call = the warm-up, the process's first fit_keyframes call: wall time, KeyframeFit.seconds")  # fmt: skip
    ok = [m for m in mem if not m.get("failed")]
    print(rows_table(ok, "dtype {dtype} | evals {evals} | fit s {seconds:.2f} | baseline RSS MiB {base:.1f} | peak "
          "RSS MiB {peak:.1f} | peak RSS growth MiB {growth:.1f} | 1st call wall s {first_call:.2f} | 1st call fit "
          "s {first_call_fit:.2f}") if ok else "failed")  # fmt: skip
    log("  first fit of a process ...")
    first = [run_child(__file__, {**spec_child, "kind": "first", "dtype": "float32", "warm_repeats": 3})
             for _ in range(FIRST_FIT_PROCESSES)]  # fmt: skip
    ok = [dict(k=k + 1, **r) for k, r in enumerate(first) if not r.get("failed")]
    print(f"\nFirst fit of a process (float32) against the same fit warm, in {len(first)} fresh processes")
    if ok:
        print(rows_table(ok, "process {k} | first fit s {first:.3f} | warm fit s (median of 3) {warm:.3f} | "
              "first / warm {ratio:.2f}x | evaluations {evals} | torch._dynamo imported {dynamo}"))  # fmt: skip
        ratio = statistics.median(r["ratio"] for r in ok)
        print(f"median first / warm {ratio:.2f}x; target <= 1.2x: "
              f"{verdict(ratio <= 1.2 and all(r['dynamo'] == 'no' for r in ok))}")  # fmt: skip
    else:
        print(f"failed: {first[0].get('stderr_tail', '')}")
    result = dict(config=cfg, instances=[asdict(i) for i in instances], fits=rows, summary=summary,
                  gradient=grad_rows, controls=sweep_rows, memory=mem, first_fit=first)  # fmt: skip
    finish(info, result, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
