"""Benchmark of the GPU path against the CPU of the same machine, in one run (issue #20).

Every device in ``--devices`` (default: ``cpu``, and ``cuda`` when ``torch.cuda.is_available()``) runs the same
three measurements, in float32, with its inputs made on the CPU and moved to it; each prints a table with one
column per device and, for every timed figure, a row of speed-ups over ``cpu``:

1. **Frames.** :class:`~torchfluidwarp.warp.layer.FluidWarp` on a 64x64 fluid, 60 steps, stirred by the three
   oscillating :class:`~torchfluidwarp.warp.forces.Brushes` of ``bench_warp.py`` (its ``make_brushes`` and
   ``make_image``), warping an RGB image of 600x600 and of 1920x1080, without grad. Timed, each over the
   ``T = 60`` new frames (frame 0, the input itself, is not counted):

   * :meth:`FluidWarp.forward`: all ``T + 1`` frames in one tensor;
   * :meth:`FluidWarp.iter_frames`, consumed frame by frame, as shipped (for frames over
     ``PREFETCH_PIXELS`` the next sampling grid is built in a worker thread) and with ``prefetch=False``;
   * two of a frame's pieces on their own: the fluid step (:meth:`FluidWarp.rollout` over ``T`` steps) and the
     backward map at the image's size (:func:`~torchfluidwarp.warp.maps.iter_backward_maps`), per frame;
   * the floor: ``torch.nn.functional.grid_sample`` of the image through a smooth grid of the frame's size
     (identity plus a few pixels of sine displacement; border padding, ``align_corners=False``), ``T`` times.

   Frames per second are ``T`` over the wall time; each path's ratio to the floor is printed too.
2. **Keyframe fit.** The paper set-up exactly as ``bench_keyframes.py`` builds it: its first flow instance
   (``flow_instance(0, 14, (64, 64), 10)``: 14 points in a 64x64-pixel frame, targets 5 to 10 px away) fitted
   by :func:`fit_keyframes` on a 64x64 fluid over 10 steps with ``control=(5, 5)`` (500 parameters),
   ``tolerance=0.05`` px, float32, the source and target points on the device. Reported: the wall time of the
   call, the quasi-Newton start's roll-outs and L-BFGS' evaluations (``fit_keyframes``' default
   ``method="auto"``), ms per evaluation, mean and max final error (px), and whether every point reached its
   target.
3. **Morph.** The bundled astronaut -> cat pair with its 23 points, resized to 1024x1024 (the points scaled by
   the same factors, pixel centres at integers: ``x' = (x + 0.5) W' / W - 0.5``), images and points on the
   device, morphed by :func:`torchfluidwarp.morph` with ``frames=30`` (its defaults otherwise). ``morph``
   returns once the fit is done and renders the frames on demand, so two times are taken: the call itself, and
   the call plus all 30 frames streamed through ``result.iter_frames()`` (the "whole morph"). The mean point
   error is ``result.fit.error.mean()``, in the last frame's pixels.

Timing: on CUDA, ``torch.cuda.synchronize()`` runs before every clock reading, so a time covers the work the
call queued, not only its launch. Each measurement is warmed up once per device before it is timed (frames: one
full repeat; fit: the same fit cut to 3 L-BFGS iterations; morph: the same pair at the same size with 2 frames
and 1 iteration), then runs ``--repeats`` times, the repeats interleaved over the devices so that a change of
load on the machine affects them alike; each figure is the median over the repeats. For CUDA the peak of
``torch.cuda.max_memory_allocated`` over the measurement is shown as well.

A failure on one device (an exception in its set-up or in any repeat) prints its traceback and drops that
device from that measurement only; the others, and the later measurements, still run. With ``--json PATH`` the
results so far are written after every measurement, so a run cut short keeps what it measured. ``--quick`` is a
smoke test: 64x64 and 96x128 images over 8 fluid steps, the fit on a 32x32 fluid over 5 steps, a 128x128 morph
of 5 frames. ``--only`` picks measurements. On CUDA a roll-out of at least ``GRAPH_MIN_STEPS`` steps replays its
step from a captured CUDA graph (:mod:`torchfluidwarp.core.graphs`); ``--no-cuda-graphs`` rolls it out step
by step instead, for comparison. Run ``PYTHONPATH=$PWD python benchmarks/bench_device.py --help`` for the
options.
"""

from __future__ import annotations

import argparse
import gc
import math
import statistics
import sys
import time
import traceback
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import torch
import torch.nn.functional as F
from _common import describe_load, machine, machine_load, source_fingerprint, table, write_json
from bench_keyframes import FRAME as FIT_FRAME
from bench_keyframes import flow_instance
from bench_warp import FLUID, make_brushes, make_image
from torch import Tensor

from torchfluidwarp import FluidWarp, fit_keyframes, morph
from torchfluidwarp.core import graphs
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.warp import iter_backward_maps

SAMPLE_A, SAMPLE_B = "astronaut", "cat"
FIT_SEED, FIT_POINTS, FIT_CONTROL, FIT_TOLERANCE = 0, 14, (5, 5), 0.05
FLOOR_AMPLITUDE = 0.01  # the floor grid's displacement, in normalised units (0.5% of the frame's width)


@dataclass(frozen=True)
class Config:
    """Sizes of one run: the full set-up, or ``--quick``'s."""

    frame_sizes: tuple[tuple[int, int], ...]  # (H, W)
    frame_steps: int
    fit_grid: tuple[int, int]
    fit_steps: int
    morph_size: int
    morph_frames: int


FULL = Config(((600, 600), (1080, 1920)), 60, (64, 64), 10, 1024, 30)
QUICK = Config(((64, 64), (96, 128)), 8, (32, 32), 5, 128, 5)
SECTIONS = ("frames", "fit", "morph")

# ----------------------------------------------------------------------------------------------- timing


def clock(device: torch.device) -> float:
    """Wall time in seconds, after the device has finished what was queued on it."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return time.perf_counter()


Runs = dict[str, dict[str, Any]]  # {device: {"runs": [figures per repeat], "error": str | None, ...}}


def interleaved(
    what: str,
    devices: list[torch.device],
    setup: Callable[[torch.device], Any],
    once: Callable[[Any], dict[str, Any]],
    repeats: int,
    log: Callable[[str], None],
) -> Runs:
    """Run ``setup(device)`` (inputs and warm-up) on every device, then ``repeats`` rounds of ``once(state)``
    over the devices in turn. A device whose set-up or repeat raises has its traceback printed and is dropped
    from this measurement; the others go on."""
    out: Runs = {str(d): {"runs": [], "error": None} for d in devices}
    states: dict[torch.device, Any] = {}

    def fail(d: torch.device, stage: str) -> None:
        print(f"\n{what}: {d} FAILED in {stage}:", file=sys.stderr, flush=True)
        traceback.print_exc()
        exc = sys.exc_info()[1]
        out[str(d)]["error"] = f"{stage}: {type(exc).__name__}: {exc}"
        states.pop(d, None)

    for d in devices:
        try:
            if d.type == "cuda":
                torch.cuda.reset_peak_memory_stats(d)
            log(f"  {what}: {d}, set-up and warm-up ...")
            states[d] = setup(d)
        except Exception:
            fail(d, "set-up")
    for rep in range(repeats):
        for d in devices:
            if d not in states:
                continue
            log(f"  {what}: {d}, repeat {rep + 1}/{repeats} ...")
            try:
                out[str(d)]["runs"].append(once(states[d]))
            except Exception:
                fail(d, f"repeat {rep + 1}")
    for d in devices:
        if d.type == "cuda":
            try:
                out[str(d)]["peak_mib"] = torch.cuda.max_memory_allocated(d) / 2**20
            except Exception:  # a broken CUDA context has already been reported
                pass
    states.clear()
    gc.collect()
    if any(d.type == "cuda" for d in devices):
        try:
            torch.cuda.empty_cache()
        except Exception:
            pass
    return out


def median(runs: list[dict[str, Any]], key: str) -> float:
    return statistics.median(r[key] for r in runs)


# ----------------------------------------------------------------------------------------------- 1. frames


def smooth_grid(size: tuple[int, int], device: torch.device) -> Tensor:
    """A smooth sampling grid ``(1, H, W, 2)``, normalised ``(x, y)`` (``align_corners=False``): the identity
    plus a gentle sine displacement, so that ``grid_sample`` interpolates as it does for a warped frame."""
    H, W = size
    ys = (2 * torch.arange(H, device=device, dtype=torch.float32) + 1) / H - 1
    xs = (2 * torch.arange(W, device=device, dtype=torch.float32) + 1) / W - 1
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")  # (H, W) each
    dx = FLOOR_AMPLITUDE * torch.sin(math.pi * gy) * torch.cos(2 * math.pi * gx)
    dy = FLOOR_AMPLITUDE * torch.sin(2 * math.pi * gx) * torch.cos(math.pi * gy)
    return torch.stack([gx + dx, gy + dy], dim=-1)[None]


@dataclass
class FrameState:
    device: torch.device
    warp: FluidWarp
    brushes: torch.nn.Module
    image: Tensor  # (1, 3, H, W)
    grid: Tensor  # (1, H, W, 2)


def frames_setup(size: tuple[int, int], steps: int) -> Callable[[torch.device], FrameState]:
    def setup(device: torch.device) -> FrameState:
        state = FrameState(
            device=device,
            warp=FluidWarp(FLUID, steps=steps, dt=1.0).to(device),
            brushes=make_brushes(size).to(device),
            image=make_image(size).to(device),
            grid=smooth_grid(size, device),
        )
        frames_once(state)  # warm-up: kernels, caches, the allocator
        return state

    return setup


def frames_once(s: FrameState) -> dict[str, Any]:
    """One repeat of the three paths: wall seconds over the ``T`` new frames of each."""
    T = s.warp.steps
    with torch.no_grad():
        t0 = clock(s.device)
        s.warp(s.image, s.brushes)
        t1 = clock(s.device)
        n = 0
        for _frame in s.warp.iter_frames(s.image, s.brushes):
            n += 1
        t2 = clock(s.device)
        for _ in range(T):
            F.grid_sample(s.image, s.grid, mode="bilinear", padding_mode="border", align_corners=False)
        t3 = clock(s.device)
        for _frame in s.warp.iter_frames(s.image, s.brushes, prefetch=False):
            pass
        t4 = clock(s.device)
        velocities = s.warp.rollout(s.brushes, tuple(s.image.shape[-2:])).velocities
        t5 = clock(s.device)
        for _map in iter_backward_maps(velocities, tuple(s.image.shape[-2:]), s.warp.dt):
            pass
        t6 = clock(s.device)
    if n != T + 1:
        raise RuntimeError(f"iter_frames yielded {n} frames, expected {T + 1}")
    return {
        "forward_s": t1 - t0,
        "iter_frames_s": t2 - t1,
        "floor_s": t3 - t2,
        "serial_s": t4 - t3,
        "rollout_s": t5 - t4,
        "maps_s": t6 - t5,
    }


def frames_summary(runs: list[dict[str, Any]], steps: int) -> dict[str, float]:
    fwd, it, floor, serial = (median(runs, k) for k in ("forward_s", "iter_frames_s", "floor_s", "serial_s"))
    return {
        "rollout_ms": median(runs, "rollout_s") / steps * 1e3,
        "maps_ms": median(runs, "maps_s") / steps * 1e3,
        "serial_fps": steps / serial,
        "serial_over_floor": serial / floor,
        "forward_fps": steps / fwd,
        "iter_frames_fps": steps / it,
        "floor_fps": steps / floor,
        "forward_ms": fwd / steps * 1e3,
        "iter_frames_ms": it / steps * 1e3,
        "floor_ms": floor / steps * 1e3,
        "forward_over_floor": fwd / floor,
        "iter_frames_over_floor": it / floor,
    }


# ----------------------------------------------------------------------------------------------- 2. keyframe fit


@dataclass
class FitState:
    device: torch.device
    source: Tensor  # (M, 2) pixels
    target: Tensor


def fit_call(s: FitState, cfg: Config, max_iter: int = 200) -> Any:
    return fit_keyframes(
        s.source,
        s.target,
        image_size=FIT_FRAME,
        grid=cfg.fit_grid,
        steps=cfg.fit_steps,
        control=FIT_CONTROL,
        max_iter=max_iter,
        tolerance=FIT_TOLERANCE,
        dtype=torch.float32,
        progress=False,
    )


def fit_setup(inst: Any, cfg: Config) -> Callable[[torch.device], FitState]:
    def setup(device: torch.device) -> FitState:
        src, tgt = inst.tensors(torch.float32)
        state = FitState(device, src.to(device), tgt.to(device))
        fit_call(state, cfg, max_iter=3)  # warm-up: the same shapes, a few iterations
        return state

    return setup


def fit_once(cfg: Config) -> Callable[[FitState], dict[str, Any]]:
    def once(s: FitState) -> dict[str, Any]:
        t0 = clock(s.device)
        fit = fit_call(s, cfg)
        wall = clock(s.device) - t0
        return {
            "wall_s": wall,
            "fit_seconds": fit.seconds,  # KeyframeFit's own figure (from the optimiser's start)
            "evaluations": fit.evaluations,
            "forwards": fit.forwards,  # the quasi-Newton start's roll-outs without autograd
            "mean_error_px": float(fit.error.mean()),
            "max_error_px": float(fit.error.max()),
            "reached": fit.reached,
            "converged": fit.converged,
        }

    return once


def fit_summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    wall = median(runs, "wall_s")
    evals = median(runs, "evaluations")
    return {
        "wall_s": wall,
        "fit_seconds": median(runs, "fit_seconds"),
        "evaluations": evals,
        "forwards": median(runs, "forwards"),
        "ms_per_evaluation": wall / evals * 1e3 if evals else math.nan,  # undefined when the start met the targets
        "mean_error_px": median(runs, "mean_error_px"),
        "max_error_px": median(runs, "max_error_px"),
        "reached": sum(bool(r["reached"]) for r in runs),
        "repeats": len(runs),
    }


# ----------------------------------------------------------------------------------------------- 3. morph


def load_pair(size: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The bundled pair ``(1, 3, size, size)`` x 2 and its points ``(M, 2)`` x 2, resized on the CPU."""
    a, b = load_sample(SAMPLE_A), load_sample(SAMPLE_B)
    pa, pb = load_sample_points(SAMPLE_A), load_sample_points(SAMPLE_B)
    H, W = a.shape[-2:]
    if (H, W) != (size, size):
        a, b = (
            F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False, antialias=True) for x in (a, b)
        )
        scale = torch.tensor([size / W, size / H])
        pa, pb = ((p + 0.5) * scale - 0.5 for p in (pa, pb))  # pixel centres stay at integers
    return a, b, pa, pb


@dataclass
class MorphState:
    device: torch.device
    inputs: tuple[Tensor, Tensor, Tensor, Tensor]


def morph_run(s: MorphState, frames: int, max_iter: int | None = None) -> dict[str, Any]:
    """One morph: the call, then every frame streamed; wall seconds of each, the mean point error, and the
    warnings it gave (a fold or crossing warning is part of the result, not noise to print every repeat)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = clock(s.device)
        res = morph(*s.inputs, frames=frames, max_iter=max_iter, progress=False)
        t1 = clock(s.device)
        n = sum(1 for _frame in res.iter_frames())
        t2 = clock(s.device)
    if n != frames:
        raise RuntimeError(f"result.iter_frames() yielded {n} frames, expected {frames}")
    return {
        "call_s": t1 - t0,
        "render_s": t2 - t1,
        "total_s": t2 - t0,
        "fit_evaluations": res.fit.evaluations,
        "mean_error_px": float(res.fit.error.mean()),
        "max_error_px": float(res.fit.error.max()),
        "warnings": list(dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught)),
    }


def morph_setup(pair: tuple[Tensor, Tensor, Tensor, Tensor]) -> Callable[[torch.device], MorphState]:
    def setup(device: torch.device) -> MorphState:
        a, b, pa, pb = (x.to(device) for x in pair)
        state = MorphState(device, (a, b, pa, pb))
        morph_run(state, frames=2, max_iter=1)  # warm-up: the same size, 2 frames, 1 iteration
        return state

    return setup


def morph_summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "call_s": median(runs, "call_s"),
        "render_s": median(runs, "render_s"),
        "total_s": median(runs, "total_s"),
        "fit_evaluations": median(runs, "fit_evaluations"),
        "mean_error_px": median(runs, "mean_error_px"),
        "max_error_px": median(runs, "max_error_px"),
        "repeats": len(runs),
    }


# ----------------------------------------------------------------------------------------------- report


Row = tuple[str, Callable[[dict[str, Any]], str]]


def device_table(
    runs: Runs, summaries: dict[str, dict[str, Any]], rows: list[Row], speedups: list[tuple[str, str, bool]]
) -> str:
    """One column per device. ``speedups``: ``(label, key, higher_is_better)`` rows of each device's figure
    over ``cpu``'s (> 1: faster than the CPU)."""
    names = list(runs)
    body = []
    for label, fmt in rows:
        body.append([label] + [fmt(summaries[n]) if n in summaries else "FAILED" for n in names])
    base = summaries.get("cpu")
    for label, key, higher in speedups:
        cells = []
        for n in names:
            if base is None or n not in summaries or n == "cpu":
                cells.append("-")
                continue
            v, b = summaries[n][key], base[key]
            cells.append(f"{(v / b if higher else b / v):.2f}x")
        body.append([f"speed-up over cpu: {label}"] + cells)
    body.append(["repeats"] + [str(len(runs[n]["runs"])) for n in names])
    if any("peak_mib" in runs[n] for n in names):
        body.append(
            ["peak GPU memory MiB"] + [f"{runs[n]['peak_mib']:.0f}" if "peak_mib" in runs[n] else "-" for n in names]
        )
    text = table(["", *names], body)
    for n in names:
        if runs[n]["error"]:
            text += f"\n{n} FAILED: {runs[n]['error'].splitlines()[0][:300]}"
    return text


def summarise(runs: Runs, summary: Callable[[list[dict[str, Any]]], dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {n: summary(r["runs"]) for n, r in runs.items() if r["error"] is None and r["runs"]}


def report_frames(size: tuple[int, int], steps: int, runs: Runs, summaries: dict[str, dict[str, Any]]) -> str:
    H, W = size
    head = (
        f"Frames: {W}x{H} RGB float32, {FLUID[0]}x{FLUID[1]} fluid, {steps} frames, no grad; median frames per "
        "second (T new frames over the wall time), ms per frame, and each path's ratio to the floor (one "
        "grid_sample of the image per frame)"
    )
    rows: list[Row] = [
        ("forward fps", lambda s: f"{s['forward_fps']:.1f}"),
        ("iter_frames fps", lambda s: f"{s['iter_frames_fps']:.1f}"),
        ("floor (grid_sample) fps", lambda s: f"{s['floor_fps']:.1f}"),
        ("forward ms/frame", lambda s: f"{s['forward_ms']:.3f}"),
        ("iter_frames ms/frame", lambda s: f"{s['iter_frames_ms']:.3f}"),
        ("floor ms/frame", lambda s: f"{s['floor_ms']:.3f}"),
        ("forward / floor", lambda s: f"{s['forward_over_floor']:.2f}x"),
        ("iter_frames / floor", lambda s: f"{s['iter_frames_over_floor']:.2f}x"),
        ("iter_frames(prefetch=False) fps", lambda s: f"{s['serial_fps']:.1f}"),
        ("iter_frames(prefetch=False) / floor", lambda s: f"{s['serial_over_floor']:.2f}x"),
        ("of a frame: fluid step ms", lambda s: f"{s['rollout_ms']:.3f}"),
        ("of a frame: backward map ms", lambda s: f"{s['maps_ms']:.3f}"),
    ]
    speedups = [
        ("forward", "forward_fps", True),
        ("iter_frames", "iter_frames_fps", True),
        ("floor", "floor_fps", True),
    ]
    return head + "\n" + device_table(runs, summaries, rows, speedups)


def report_fit(cfg: Config, runs: Runs, summaries: dict[str, dict[str, Any]]) -> str:
    params = 2 * cfg.fit_steps * FIT_CONTROL[0] * FIT_CONTROL[1]
    head = (
        f"Keyframe fit: flow instance seed {FIT_SEED}, {FIT_POINTS} points in a {FIT_FRAME[1]}x{FIT_FRAME[0]} px "
        f"frame, {cfg.fit_grid[0]}x{cfg.fit_grid[1]} fluid, {cfg.fit_steps} steps, control "
        f"{FIT_CONTROL[0]}x{FIT_CONTROL[1]} ({params} parameters), tolerance {FIT_TOLERANCE:g} px, float32; "
        "median wall time of the call"
    )
    rows: list[Row] = [
        ("fit s (wall, synchronised)", lambda s: f"{s['wall_s']:.3f}"),
        ("KeyframeFit.seconds", lambda s: f"{s['fit_seconds']:.3f}"),
        ("roll-outs of the quasi-Newton start", lambda s: f"{s['forwards']:g}"),
        ("L-BFGS evaluations", lambda s: f"{s['evaluations']:g}"),
        ("ms per L-BFGS evaluation", lambda s: f"{s['ms_per_evaluation']:.2f}"),
        ("mean final error px", lambda s: f"{s['mean_error_px']:.4f}"),
        ("max final error px", lambda s: f"{s['max_error_px']:.4f}"),
        ("reached", lambda s: f"{s['reached']}/{s['repeats']}"),
    ]
    speedups = [("fit s", "wall_s", False)]
    return head + "\n" + device_table(runs, summaries, rows, speedups)


def report_morph(cfg: Config, n_points: int, runs: Runs, summaries: dict[str, dict[str, Any]]) -> str:
    S = cfg.morph_size
    head = (
        f"Morph: {SAMPLE_A} -> {SAMPLE_B}, {S}x{S}, {n_points} points, {cfg.morph_frames} frames, morph()'s "
        "defaults; median wall seconds of the call (fit and inverse), of streaming every frame "
        "(result.iter_frames()), and of both (the whole morph)"
    )
    rows: list[Row] = [
        ("whole morph s (call + frames)", lambda s: f"{s['total_s']:.3f}"),
        ("morph() call s", lambda s: f"{s['call_s']:.3f}"),
        ("frames s", lambda s: f"{s['render_s']:.3f}"),
        ("fit evaluations", lambda s: f"{s['fit_evaluations']:g}"),
        ("mean point error px", lambda s: f"{s['mean_error_px']:.4f}"),
        ("max point error px", lambda s: f"{s['max_error_px']:.4f}"),
    ]
    speedups = [("whole morph", "total_s", False), ("morph() call", "call_s", False), ("frames", "render_s", False)]
    return head + "\n" + device_table(runs, summaries, rows, speedups)


# ----------------------------------------------------------------------------------------------- main


def parse_devices(values: list[str]) -> list[torch.device]:
    names = [v.strip() for item in values for v in item.split(",") if v.strip()]
    devices: list[torch.device] = []
    for name in names:
        try:
            d = torch.device(name)
        except RuntimeError:
            raise ValueError(f"not a torch device: {name!r}") from None
        if d.type not in ("cpu", "cuda"):
            raise ValueError(f"only cpu and cuda devices can be timed here (synchronised clocks), got {name!r}")
        if d.type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"{name!r} was asked for, but torch.cuda.is_available() is False")
        if d.type == "cuda" and d.index is not None and d.index >= torch.cuda.device_count():
            raise ValueError(f"{name!r}: only {torch.cuda.device_count()} CUDA device(s)")
        if d in devices:
            raise ValueError(f"device {name!r} is listed twice")
        devices.append(d)
    if not devices:
        raise ValueError("--devices lists no device")
    return devices


def cuda_info(device: torch.device) -> dict[str, Any]:
    props = torch.cuda.get_device_properties(device)
    return {
        "name": torch.cuda.get_device_name(device),
        "capability": f"{props.major}.{props.minor}",
        "memory_gib": props.total_memory / 2**30,
        "cuda": torch.version.cuda,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--devices",
        nargs="+",
        metavar="DEV",
        help="devices to measure, e.g. cpu cuda (or cpu,cuda:0); default: cpu, and cuda when available",
    )
    parser.add_argument("--repeats", type=int, default=3, help="interleaved timed repeats per device (default 3)")
    parser.add_argument(
        "--threads", type=int, help="torch CPU threads (default: torch's own default, which is printed)"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke mode: 64x64 and 96x128 images over 8 fluid steps, the fit on a 32x32 fluid over 5 steps, a "
        "128x128 morph of 5 frames",
    )
    parser.add_argument(
        "--json", metavar="PATH", help="also write the results as JSON to PATH (after every measurement)"
    )
    parser.add_argument(
        "--only",
        nargs="+",
        choices=SECTIONS,
        default=list(SECTIONS),
        help="measure only these (default: all of frames, fit, morph)",
    )
    parser.add_argument(
        "--no-cuda-graphs",
        action="store_true",
        help="roll the fluid out step by step on CUDA too (torchfluidwarp.core.graphs.GRAPH_MIN_STEPS raised "
        "out of reach), to compare with the default replay of a captured step",
    )
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    if args.threads is not None and args.threads < 1:
        parser.error(f"--threads must be >= 1, got {args.threads}")
    try:
        devices = parse_devices(args.devices or (["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"]))
    except ValueError as exc:
        parser.error(str(exc))
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    cfg = QUICK if args.quick else FULL
    if args.no_cuda_graphs:
        graphs.GRAPH_MIN_STEPS = sys.maxsize

    info = machine()
    info["threads_from"] = "--threads" if args.threads is not None else "torch's default"
    info["load_start"] = machine_load()
    info["sources_sha256"] = source_fingerprint()
    info["cuda"] = {}
    print(
        f"bench_device: {info['cpu']}, {info['cpu_count']} CPUs, torch {info['torch']} with "
        f"{info['torch_threads']} CPU thread(s) ({info['threads_from']}), Python {info['python']}, {info['date']}"
        + (" [--quick]" if args.quick else "")
        + (" [--no-cuda-graphs]" if args.no_cuda_graphs else ""),
        flush=True,
    )
    for d in devices:
        if d.type == "cuda":
            try:
                c = info["cuda"][str(d)] = cuda_info(d)
                print(
                    f"{d}: {c['name']}, compute capability {c['capability']}, {c['memory_gib']:.1f} GiB, "
                    f"CUDA {c['cuda']}",
                    flush=True,
                )
            except Exception:
                traceback.print_exc()
    print(
        f"devices: {', '.join(map(str, devices))}; {args.repeats} repeat(s); torchfluidwarp sources sha256 "
        f"{info['sources_sha256']}; at the start: {describe_load(info['load_start'])}",
        flush=True,
    )
    log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731

    result: dict[str, Any] = {
        "machine": info,
        "args": vars(args),
        "config": asdict(cfg),
        "frames": {},
        "fit": None,
        "morph": None,
    }

    def save() -> None:
        if args.json:
            write_json(args.json, result, default=str)

    save()
    failed: list[str] = []  # "<measurement> on <device>", or the measurement alone when its shared inputs failed

    def record(what: str, runs: Runs) -> None:
        failed.extend(f"{what} on {n}" for n, r in runs.items() if r["error"])
        save()

    def shared(what: str, make: Callable[[], Any]) -> Any:
        """Inputs that every device shares, built once on the CPU: a failure skips this measurement only."""
        try:
            return make()
        except Exception:
            print(f"\n{what} FAILED while building its inputs:", file=sys.stderr, flush=True)
            traceback.print_exc()
            failed.append(what)
            return None

    t_start = time.perf_counter()

    # 1. frames
    for size in cfg.frame_sizes if "frames" in args.only else []:
        what = f"frames {size[1]}x{size[0]}"
        runs = interleaved(what, devices, frames_setup(size, cfg.frame_steps), frames_once, args.repeats, log)
        summaries = summarise(runs, lambda r: frames_summary(r, cfg.frame_steps))
        print("\n" + report_frames(size, cfg.frame_steps, runs, summaries), flush=True)
        result["frames"][f"{size[1]}x{size[0]}"] = {"runs": runs, "summary": summaries}
        record(what, runs)

    # 2. keyframe fit
    inst = None
    if "fit" in args.only:
        log("  fit: building the flow instance ...")
        inst = shared("fit", lambda: flow_instance(FIT_SEED, FIT_POINTS, cfg.fit_grid, cfg.fit_steps))
    if inst is not None:
        runs = interleaved("fit", devices, fit_setup(inst, cfg), fit_once(cfg), args.repeats, log)
        summaries = summarise(runs, fit_summary)
        print("\n" + report_fit(cfg, runs, summaries), flush=True)
        result["fit"] = {"instance": asdict(inst), "runs": runs, "summary": summaries}
        record("fit", runs)

    # 3. morph
    pair = shared("morph", lambda: load_pair(cfg.morph_size)) if "morph" in args.only else None
    if pair is not None:
        once = lambda s: morph_run(s, cfg.morph_frames)  # noqa: E731
        runs = interleaved("morph", devices, morph_setup(pair), once, args.repeats, log)
        summaries = summarise(runs, morph_summary)
        print("\n" + report_morph(cfg, pair[2].shape[0], runs, summaries), flush=True)
        for name, r in runs.items():
            for text in dict.fromkeys(w for run in r["runs"] for w in run["warnings"]):
                print(f"{name} warned: {text[:300]}")
        result["morph"] = {"runs": runs, "summary": summaries}
        record("morph", runs)

    total = time.perf_counter() - t_start
    info["load_end"] = machine_load()
    result["total_s"] = total
    print(f"\ntotal {total:.0f} s; at the end: {describe_load(info['load_end'])}")
    if source_fingerprint() != info["sources_sha256"]:
        info["sources_changed"] = True
        print("WARNING: the torchfluidwarp sources changed during the run (this process kept the code it imported)")
    save()
    if failed:
        print(f"FAILED: {', '.join(failed)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
