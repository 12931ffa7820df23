"""Benchmark of the GPU path against the CPU of the same machine, in one run (issue #20).

Every device in ``--devices``, float32: (1) ``FluidWarp`` frames at 600x600 and 1920x1080 (``forward``,
``iter_frames``, the fluid step, the backward map) against the floor, one
``grid_sample`` a frame; (2) the paper's keyframe fit; (3) a 30-frame 1024x1024 morph. Medians of ``--repeats``
interleaved over the devices, speed-ups over ``cpu``, peak GPU memory. Figures: docs/benchmarks.md, "The GPU
(H100) against the CPU of the same machine".
"""

from __future__ import annotations

import gc
import math
import statistics
import sys
import time
import traceback
import warnings
from collections.abc import Callable
from typing import Any

import torch
import torch.nn.functional as F
from _common import (
    FLUID,
    FRAME,
    finish,
    flow_instance,
    load_pair,
    log,
    parser,
    start,
    stirred,
    table,
    write_json,
)

from torchfluidwarp import fit_keyframes, morph
from torchfluidwarp.core import graphs
from torchfluidwarp.warp import iter_backward_maps

FULL = dict(frame_sizes=((600, 600), (1080, 1920)), frame_steps=60, fit_grid=(64, 64), fit_steps=10, morph_size=1024,
            morph_frames=30)  # fmt: skip
QUICK = dict(frame_sizes=((64, 64), (96, 128)), frame_steps=8, fit_grid=(32, 32), fit_steps=5, morph_size=128,
             morph_frames=5)  # fmt: skip
Runs = dict[str, dict[str, Any]]  # {device: {"runs": [figures per repeat], "error": str | None, "peak_mib": ...}}


def clock(device: torch.device) -> float:
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return time.perf_counter()


def on_devices(what: str, devices: list, setup: Callable, once: Callable, repeats: int) -> Runs:
    """``setup(device)`` (inputs and warm-up) on every device, then ``repeats`` rounds of ``once(device, state)``
    over the devices in turn; a device that raises is reported and dropped from this measurement."""
    out: Runs = {str(d): {"runs": [], "error": None} for d in devices}
    states: dict[Any, Any] = {}
    for rep in range(-1, repeats):
        for d in devices:
            if rep >= 0 and d not in states:
                continue
            try:
                log(f"  {what}: {d}, " + ("set-up and warm-up" if rep < 0 else f"repeat {rep + 1}/{repeats}") + " ...")
                if rep < 0:
                    if d.type == "cuda":
                        torch.cuda.reset_peak_memory_stats(d)
                    states[d] = setup(d)
                else:
                    out[str(d)]["runs"].append(once(d, states[d]))
            except Exception as exc:
                print(f"\n{what}: {d} FAILED:", file=sys.stderr, flush=True)
                traceback.print_exc()
                out[str(d)]["error"] = f"{type(exc).__name__}: {exc}"
                states.pop(d, None)
    for d in devices:
        if d.type == "cuda" and d in states:
            out[str(d)]["peak_mib"] = torch.cuda.max_memory_allocated(d) / 2**20
    states.clear()
    gc.collect()
    return out


def smooth_grid(size: tuple[int, int], device: torch.device, amplitude: float = 0.01) -> torch.Tensor:
    """A smooth sampling grid ``(1, H, W, 2)`` (normalised, ``align_corners=False``): identity plus a sine."""
    H, W = size
    ys = (2 * torch.arange(H, device=device, dtype=torch.float32) + 1) / H - 1
    xs = (2 * torch.arange(W, device=device, dtype=torch.float32) + 1) / W - 1
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    dx = amplitude * torch.sin(math.pi * gy) * torch.cos(2 * math.pi * gx)
    dy = amplitude * torch.sin(2 * math.pi * gx) * torch.cos(math.pi * gy)
    return torch.stack([gx + dx, gy + dy], dim=-1)[None]


def frames_once(d: torch.device, s: dict[str, Any]) -> dict[str, float]:
    """One repeat of every path: wall seconds over the ``T`` new frames of each."""
    warp, image, brushes, T = s["warp"], s["image"], s["brushes"], s["warp"].steps
    size = tuple(image.shape[-2:])
    steps: dict[str, Callable[[], Any]] = {
        "forward": lambda: warp(image, brushes),
        "iter_frames": lambda: sum(1 for _ in warp.iter_frames(image, brushes)),
        "floor": lambda: [F.grid_sample(image, s["grid"], "bilinear", "border", False) for _ in range(T)],
        "rollout": lambda: s.__setitem__("vel", warp.rollout(brushes, size).velocities),
        "maps": lambda: sum(1 for _ in iter_backward_maps(s["vel"], size, warp.dt)),
    }  # fmt: skip
    out = {}
    with torch.no_grad():
        for k, fn in steps.items():
            t0 = clock(d)
            fn()
            out[k] = clock(d) - t0
    return out


def frames_rows(s: dict[str, float], T: int) -> dict[str, str]:
    return {
        "forward fps": f"{T / s['forward']:.1f}",
        "iter_frames fps": f"{T / s['iter_frames']:.1f}",
        "floor (grid_sample) fps": f"{T / s['floor']:.1f}",
        "floor ms/frame": f"{s['floor'] / T * 1e3:.3f}",
        "forward / floor": f"{s['forward'] / s['floor']:.2f}x",
        "iter_frames / floor": f"{s['iter_frames'] / s['floor']:.2f}x",
        "of a frame: fluid step ms": f"{s['rollout'] / T * 1e3:.3f}",
        "of a frame: backward map ms": f"{s['maps'] / T * 1e3:.3f}",
    }


def fit_once(d: torch.device, s: dict[str, Any], max_iter: int = 200) -> dict[str, Any]:
    t0 = clock(d)
    fit = fit_keyframes(*s["points"], image_size=FRAME, grid=s["grid"], steps=s["steps"], control=(5, 5),
                        max_iter=max_iter, tolerance=0.05, dtype=torch.float32, progress=False)  # fmt: skip
    return dict(wall=clock(d) - t0, seconds=fit.seconds, evals=fit.evaluations, forwards=fit.forwards,
                mean=float(fit.error.mean()), max=float(fit.error.max()), reached=float(fit.reached))  # fmt: skip


def fit_rows(s: dict[str, float], _: int) -> dict[str, str]:
    ms = s["wall"] / s["evals"] * 1e3 if s["evals"] else math.nan
    return {"fit s (wall, synchronised)": f"{s['wall']:.3f}", "KeyframeFit.seconds": f"{s['seconds']:.3f}",
            "roll-outs of the quasi-Newton start": f"{s['forwards']:g}", "L-BFGS evaluations": f"{s['evals']:g}",
            "ms per L-BFGS evaluation": f"{ms:.2f}", "mean final error px": f"{s['mean']:.4f}",
            "max final error px": f"{s['max']:.4f}", "reached (share of repeats)": f"{s['reached']:g}"}  # fmt: skip


def morph_once(d: torch.device, s: dict[str, Any], frames: int | None = None) -> dict:
    frames = frames or s["frames"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = clock(d)
        res = morph(*s["inputs"], frames=frames, progress=False)
        t1 = clock(d)
        n = sum(1 for _ in res.iter_frames())
        t2 = clock(d)
    if n != frames:
        raise RuntimeError(f"result.iter_frames() yielded {n} frames, expected {frames}")
    s["warnings"] = {f"{w.category.__name__}: {w.message}"[:300] for w in caught}
    return dict(total=t2 - t0, call=t1 - t0, render=t2 - t1, evals=res.fit.evaluations,
                mean=float(res.error.mean()), max=float(res.error.max()))  # fmt: skip


def morph_rows(s: dict[str, float], _: int) -> dict[str, str]:
    return {"whole morph s (call + frames)": f"{s['total']:.3f}", "morph() call s": f"{s['call']:.3f}",
            "frames s": f"{s['render']:.3f}", "fit evaluations": f"{s['evals']:g}",
            "mean point error px (frames)": f"{s['mean']:.4f}", "max px": f"{s['max']:.4f}"}  # fmt: skip


def device_table(runs: Runs, rows: Callable, n: int, speedups: dict[str, tuple[str, bool]]) -> str:
    """One column per device; ``speedups``: ``{label: (key, higher is better)}`` rows over ``cpu``'s figure."""
    med = {d: {k: statistics.median(x[k] for x in r["runs"]) for k in r["runs"][0]} for d, r in runs.items()
           if r["runs"] and not r["error"]}  # fmt: skip
    names = list(runs)
    cells = {d: rows(m, n) for d, m in med.items()}
    body = [[k] + [cells[d][k] if d in cells else "FAILED" for d in names] for k in next(iter(cells.values()), {})]
    for label, (key, higher) in speedups.items():
        b = med.get("cpu", {}).get(key)
        sp = [(med[d][key] / b if higher else b / med[d][key]) if b and d in med and d != "cpu" else None
              for d in names]  # fmt: skip
        body.append([f"speed-up over cpu: {label}"] + ["-" if x is None else f"{x:.2f}x" for x in sp])
    body.append(["repeats"] + [str(len(runs[d]["runs"])) for d in names])
    body.append(["peak GPU memory MiB"] + [f"{runs[d].get('peak_mib', math.nan):.0f}" for d in names])
    errors = "".join(f"\n{d} FAILED: {r['error'][:300]}" for d, r in runs.items() if r["error"])
    return table(["", *names], body) + errors


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="64x64 and 96x128 images over 8 steps, a 32x32 fit over 5 steps, a 128x128 morph of "
               "5 frames", threads=None)  # fmt: skip
    p.add_argument("--devices", nargs="+", help="devices, e.g. cpu cuda (default: cpu, and cuda when available)")
    p.add_argument("--repeats", type=int, default=3, help="interleaved timed repeats per device (default 3)")
    p.add_argument("--only", nargs="+", choices=("frames", "fit", "morph"), default=["frames", "fit", "morph"])
    p.add_argument("--no-cuda-graphs", action="store_true", help="roll the fluid out step by step on CUDA too")
    args = p.parse_args(argv)
    devices = [torch.device(d) for d in args.devices or (["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"])]
    cfg = QUICK if args.quick else FULL
    if args.no_cuda_graphs:
        graphs.GRAPH_MIN_STEPS = sys.maxsize
    info = start("bench_device", args.threads, " [--quick]" * args.quick + " [--no-cuda-graphs]" * args.no_cuda_graphs)
    for d in devices:
        if d.type == "cuda":
            pr = torch.cuda.get_device_properties(d)
            print(f"{d}: {pr.name}, compute capability {pr.major}.{pr.minor}, {pr.total_memory / 2**30:.1f} GiB, "
                  f"CUDA {torch.version.cuda}")  # fmt: skip
    result: dict[str, Any] = dict(args=vars(args), config=cfg, frames={})
    save = lambda: args.json and write_json(args.json, {"machine": info, **result})
    failed: list[str] = []
    T = cfg["frame_steps"]
    for size in cfg["frame_sizes"] if "frames" in args.only else []:

        def setup(d: torch.device, size: tuple[int, int] = size) -> dict[str, Any]:
            s = dict(zip(("warp", "brushes", "image"), stirred(size, T, d)), grid=smooth_grid(size, d))
            frames_once(d, s)
            return s

        runs = on_devices(f"frames {size[1]}x{size[0]}", devices, setup, frames_once, args.repeats)
        failed += [f"frames on {d}" for d, r in runs.items() if r["error"]]
        print(f"\nFrames: {size[1]}x{size[0]} RGB float32, {FLUID[0]}x{FLUID[1]} fluid, {T} frames, no grad; medians")
        speed = {"forward": ("forward", False), "iter_frames": ("iter_frames", False), "floor": ("floor", False)}
        print(device_table(runs, frames_rows, T, speed))
        result["frames"][f"{size[1]}x{size[0]}"] = runs
        save()
    if "fit" in args.only:
        inst = flow_instance(0, 14, cfg["fit_grid"], cfg["fit_steps"])

        def fit_setup(d: torch.device) -> dict[str, Any]:
            s = dict(points=[x.to(d) for x in inst.tensors(torch.float32)], grid=cfg["fit_grid"],
                     steps=cfg["fit_steps"])  # fmt: skip
            fit_once(d, s, max_iter=3)
            return s

        runs = on_devices("fit", devices, fit_setup, fit_once, args.repeats)
        failed += [f"fit on {d}" for d, r in runs.items() if r["error"]]
        print(f"\nKeyframe fit: flow seed 0, 14 points, {cfg['fit_grid'][0]}x{cfg['fit_grid'][1]} fluid, "
              f"{cfg['fit_steps']} steps, control 5x5, tolerance 0.05 px, float32; median wall time")  # fmt: skip
        print(device_table(runs, fit_rows, 0, {"fit s": ("wall", False)}))
        result["fit"] = runs
        save()
    if "morph" in args.only:
        pair, S, n = load_pair(cfg["morph_size"]), cfg["morph_size"], cfg["morph_frames"]

        def morph_setup(d: torch.device) -> dict[str, Any]:
            s = dict(inputs=[x.to(d) for x in pair], frames=n)
            morph_once(d, s, frames=2)  # warm-up: the same size, 2 frames
            states.append(s)
            return s

        states: list[dict] = []
        runs = on_devices("morph", devices, morph_setup, morph_once, args.repeats)
        failed += [f"morph on {d}" for d, r in runs.items() if r["error"]]
        print(f"\nMorph: astronaut -> cat, {S}x{S}, {len(pair[2])} points, {n} frames, morph()'s defaults; medians")
        speed = {"whole morph": ("total", False), "morph() call": ("call", False), "frames": ("render", False)}
        print(device_table(runs, morph_rows, 0, speed))
        for text in {w for s in states for w in s.get("warnings", ())}:
            print(f"warned: {text}")
        result["morph"] = runs
    finish(info, result, args.json)
    if failed:
        print(f"FAILED: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
