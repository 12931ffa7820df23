"""Benchmark of the warp layer as a real-time animation loop: frames per second and where each frame's time goes.

The set-up is indirect control: a few oscillating :class:`~torchfluidwarp.warp.forces.Brushes` stir a 64x64 fluid
that warps an RGB float32 image, without grad (``torch.no_grad()``). One animation frame is one fluid step, one
advance of the backward coordinate map at the image's resolution, and one resampling of the source image
through that map. Everything goes through the public API:

* **end to end**: :meth:`FluidWarp.iter_frames` consumed frame by frame (it rolls the fluid out first, then
  advances the map and resamples one frame per ``next``). Frames per second = ``T`` new frames over the wall
  time of the whole loop (frame 0, the input itself, is not counted). It runs twice: as shipped (the next
  sampling grid is prefetched in a worker thread) and with ``prefetch=False`` (everything in the calling
  thread), side by side in every repeat.
* **the split** (ms per frame):

  (a) fluid step: :meth:`FluidWarp.rollout` over ``T`` steps (brush forces included), divided by ``T``;
  (b) map advance: each ``next`` of :func:`iter_backward_maps` over the roll-out's velocities (the back-trace
      displacement at the image's resolution, then the composition ``g_{t+1}(x) = g_t(x - d_t(x))``);
  (c) resampling: the image sampled through each map, timed around that call alone, in the same loop as (b).
      ``iter_frames`` calls the private ``_warp_image``, which skips the input checks of the public
      :func:`warp_image` (its finiteness checks read the whole image and map every call). So (c) times
      ``_warp_image``, as the loop runs it, and the public :func:`warp_image` is timed on the same maps too.

  Of (b), the back-trace displacement alone (the private ``torchfluidwarp.warp.layer._displacement``, called once per
  step on the same velocities) is timed separately; the rest of (b) is the composition.

* **the floor** (issue #20): torch's ``grid_sample`` alone, once per frame, on the last frame's sampling grid,
  against :meth:`FluidWarp.forward` (all ``T + 1`` frames in one tensor) and ``iter_frames`` per frame, in the
  same repeats; the script prints each path's ratio to it (target: at most 2.5x at 600x600).

Target (from the issue): at least 60 frames per second end to end for a 600x600 image on a 64x64 fluid.

Each repeat runs (a), (b) + (c) and the end-to-end loop back to back, for every thread count in turn, so that
other load on the machine affects all alike; each figure is the median over the repeats. A last, untimed pass
under ``torch.profiler`` lists the operators of one end-to-end loop per image size. Run
``python benchmarks/bench_warp.py --help`` for the options.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import asdict, dataclass
from typing import Any

import torch
from _common import describe_load, machine, machine_load, source_fingerprint, table, verdict, write_json
from torch import Tensor

from torchfluidwarp.core.grid import pixel_to_normalized
from torchfluidwarp.warp import Brushes, FluidWarp, identity_map, iter_backward_maps, warp_image

SEED = 1234
FLUID = (64, 64)
TARGET_SIZE = (600, 600)
TARGET_FPS = 60.0
# brush strength in fluid cells per time unit^2, turned into pixels for each image so that every image sees
# the same flow (peak velocity about 0.5 cells per step, a visible but gentle swirl)
BRUSH_CELLS = 0.15
BRUSH_FREQUENCY = 0.05  # oscillations per time unit: a period of 20 steps


def make_brushes(size: tuple[int, int]) -> Brushes:
    """Three oscillating brushes placed at fixed fractions of the image (same flow in cells for any size)."""
    H, W = size
    centers = [[0.30 * W, 0.35 * H], [0.70 * W, 0.55 * H], [0.45 * W, 0.80 * H]]
    directions = [[1.0, 0.3], [-0.2, 1.0], [1.0, -1.0]]
    return Brushes(
        centers,
        directions,
        radius=0.12 * min(H, W),
        amplitude=BRUSH_CELLS * H / FLUID[0],
        frequency=BRUSH_FREQUENCY,
        phase=[0.0, 2.1, 4.2],
    )


def make_image(size: tuple[int, int]) -> Tensor:
    """A smooth random RGB float32 image ``(1, 3, H, W)`` in ``[0, 1]`` (content does not change the cost)."""
    gen = torch.Generator().manual_seed(SEED)
    coarse = torch.rand(1, 3, 16, 16, generator=gen)
    return torch.nn.functional.interpolate(coarse, size=size, mode="bilinear", align_corners=False)


# ----------------------------------------------------------------------------------------------- timing


PIECES = ("fluid", "maps", "resample", "public_resample", "displacement", "end_to_end", "serial", "floor", "forward")


def _clock() -> tuple[float, float]:
    """Wall time and this process's CPU time (all its threads), seconds."""
    return time.perf_counter(), time.process_time()


def one_repeat(warp: FluidWarp, brushes: Brushes, image: Tensor) -> dict[str, tuple[float, float]]:
    """One pass of every measurement: ``{piece: (wall s, CPU s)}`` summed over the ``T`` frames."""
    from torchfluidwarp.warp.layer import _displacement, _raster, _warp_image  # private: what iter_frames runs

    size = (image.shape[-2], image.shape[-1])
    T = warp.steps
    acc = {k: [0.0, 0.0] for k in PIECES}

    def add(key: str, a: tuple[float, float], b: tuple[float, float]) -> None:
        acc[key][0] += b[0] - a[0]
        acc[key][1] += b[1] - a[1]

    with torch.no_grad():
        # (a) the fluid alone
        c0 = _clock()
        vel = warp.rollout(brushes, size).velocities
        add("fluid", c0, _clock())
        # (b) and (c) in one loop, each timed around its own call; map 0 is the identity and, as in
        # iter_frames, is computed but not shown, so it is not counted
        gen = iter_backward_maps(vel, size, warp.dt)
        next(gen)
        for _ in range(T):
            c0 = _clock()
            m = next(gen)
            c1 = _clock()
            _warp_image(image, m, warp.mode)
            c2 = _clock()
            warp_image(image, m, warp.mode)
            c3 = _clock()
            add("maps", c0, c1)
            add("resample", c1, c2)
            add("public_resample", c2, c3)
        # the back-trace displacement inside (b), once per step, on the maps' working raster
        raster = _raster(size, *warp.grid.shape)
        c0 = _clock()
        for t in range(T):
            _displacement(vel[:, t], raster, warp.dt)
        add("displacement", c0, _clock())
        # end to end
        n = 0
        c0 = _clock()
        for _frame in warp.iter_frames(image, brushes):
            n += 1
        add("end_to_end", c0, _clock())
        # end to end with everything in the calling thread: what the worker thread's prefetch brings
        c0 = _clock()
        for _frame in warp.iter_frames(image, brushes, prefetch=False):
            pass
        add("serial", c0, _clock())
        # the floor: torch's grid_sample alone, T times, on the last map's normalised grid (what a frame needs)
        grid = pixel_to_normalized(m, size)
        c0 = _clock()
        for _ in range(T):
            torch.nn.functional.grid_sample(image, grid, padding_mode="border", align_corners=False)
        add("floor", c0, _clock())
        # FluidWarp.forward: all T + 1 frames in one tensor
        c0 = _clock()
        warp(image, brushes)
        add("forward", c0, _clock())
    if n != T + 1:
        raise RuntimeError(f"iter_frames yielded {n} frames, expected {T + 1}")
    return {k: (v[0], v[1]) for k, v in acc.items()}


@dataclass
class Row:
    """Medians at one image size and thread count, ms per frame (``*_cpu``: this process's CPU time)."""

    height: int
    width: int
    threads: int
    steps: int
    repeats: int
    fluid_ms: float
    maps_ms: float
    displacement_ms: float
    compose_ms: float
    resample_ms: float
    public_resample_ms: float
    sum_ms: float
    end_to_end_ms: float
    fps: float
    serial_fps: float
    fluid_cpu: float
    maps_cpu: float
    displacement_cpu: float
    compose_cpu: float
    resample_cpu: float
    public_resample_cpu: float
    sum_cpu: float
    end_to_end_cpu: float
    fps_cpu: float
    max_displacement_px: float
    floor_ms: float = 0.0
    forward_ms: float = 0.0


def summarise(
    size: tuple[int, int], threads: int, steps: int, samples: list[dict[str, tuple[float, float]]], max_disp: float
) -> Row:
    def med(key: str, which: int) -> float:
        return statistics.median(s[key][which] for s in samples) / steps * 1e3

    w = {k: med(k, 0) for k in PIECES}
    c = {k: med(k, 1) for k in PIECES}
    return Row(
        height=size[0],
        width=size[1],
        threads=threads,
        steps=steps,
        repeats=len(samples),
        fluid_ms=w["fluid"],
        maps_ms=w["maps"],
        displacement_ms=w["displacement"],
        compose_ms=w["maps"] - w["displacement"],
        resample_ms=w["resample"],
        public_resample_ms=w["public_resample"],
        sum_ms=w["fluid"] + w["maps"] + w["resample"],
        end_to_end_ms=w["end_to_end"],
        fps=1e3 / w["end_to_end"],
        serial_fps=1e3 / w["serial"],
        fluid_cpu=c["fluid"],
        maps_cpu=c["maps"],
        displacement_cpu=c["displacement"],
        compose_cpu=c["maps"] - c["displacement"],
        resample_cpu=c["resample"],
        public_resample_cpu=c["public_resample"],
        sum_cpu=c["fluid"] + c["maps"] + c["resample"],
        end_to_end_cpu=c["end_to_end"],
        fps_cpu=1e3 / c["end_to_end"],
        max_displacement_px=max_disp,
        floor_ms=w["floor"],
        forward_ms=w["forward"],
    )


def max_displacement(warp: FluidWarp, brushes: Brushes, size: tuple[int, int]) -> float:
    """Largest distance, in pixels, between a pixel and where the last frame reads it from."""
    with torch.no_grad():
        vel = warp.rollout(brushes, size).velocities
        (last,) = iter_backward_maps(vel, size, warp.dt, times=[warp.steps])
    return float((last - identity_map(size)).norm(dim=-1).max())


def profile_ops(warp: FluidWarp, brushes: Brushes, image: Tensor, threads: int, top: int) -> list[dict[str, Any]]:
    """Operators of one end-to-end loop by self CPU time (untimed pass under ``torch.profiler``)."""
    from torch.profiler import ProfilerActivity, profile

    torch.set_num_threads(threads)
    with torch.no_grad(), profile(activities=[ProfilerActivity.CPU]) as prof:
        for _frame in warp.iter_frames(image, brushes):
            pass
    events = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)
    total = sum(e.self_cpu_time_total for e in events)
    return [
        {
            "op": e.key,
            "calls": e.count,
            "self_ms_per_frame": e.self_cpu_time_total / 1e3 / warp.steps,
            "share": e.self_cpu_time_total / total,
        }
        for e in events[:top]
    ]


# ----------------------------------------------------------------------------------------------- report


def report(rows: list[Row], profiles: dict[str, list[dict[str, Any]]]) -> tuple[str, dict[str, Any]]:
    out = [
        f"Warp animation loop, {FLUID[0]}x{FLUID[1]} fluid, RGB float32, no grad; median ms per frame "
        "(a) fluid step, (b) map advance = back-trace displacement + composition, (c) resampling as iter_frames "
        "runs it (_warp_image); 'warp_image' = the public function on the same maps, input checks included"
    ]
    out.append(
        table(
            [
                "image",
                "threads",
                "frames",
                "reps",
                "(a) fluid",
                "(b) map",
                "(b) disp",
                "(b) compose",
                "(c) resample",
                "a+b+c",
                "end to end",
                "fps",
                "fps, prefetch=False",
                "warp_image",
                "max disp px",
            ],
            [
                [
                    f"{r.width}x{r.height}",
                    str(r.threads),
                    str(r.steps),
                    str(r.repeats),
                    f"{r.fluid_ms:.2f}",
                    f"{r.maps_ms:.2f}",
                    f"{r.displacement_ms:.2f}",
                    f"{r.compose_ms:.2f}",
                    f"{r.resample_ms:.2f}",
                    f"{r.sum_ms:.2f}",
                    f"{r.end_to_end_ms:.2f}",
                    f"{r.fps:.1f}",
                    f"{r.serial_fps:.1f}",
                    f"{r.public_resample_ms:.2f}",
                    f"{r.max_displacement_px:.1f}",
                ]
                for r in rows
            ],
        )
    )
    out.append(
        "\nThe same in CPU time of this process per frame (median; all its threads together). With 1 thread "
        "this is close to what the wall time would be on a core of its own, whatever else runs"
    )
    out.append(
        table(
            [
                "image",
                "threads",
                "(a) fluid",
                "(b) map",
                "(b) disp",
                "(b) compose",
                "(c) resample",
                "a+b+c",
                "end to end",
                "fps by CPU",
                "warp_image",
            ],
            [
                [
                    f"{r.width}x{r.height}",
                    str(r.threads),
                    f"{r.fluid_cpu:.2f}",
                    f"{r.maps_cpu:.2f}",
                    f"{r.displacement_cpu:.2f}",
                    f"{r.compose_cpu:.2f}",
                    f"{r.resample_cpu:.2f}",
                    f"{r.sum_cpu:.2f}",
                    f"{r.end_to_end_cpu:.2f}",
                    f"{r.fps_cpu:.1f}",
                    f"{r.public_resample_cpu:.2f}",
                ]
                for r in rows
            ],
        )
    )
    out.append("\nShare of the end-to-end frame time (each piece over the end-to-end median)")
    out.append(
        table(
            ["image", "threads", "(a) fluid", "(b) map", "(c) resample", "a+b+c / end to end", "largest"],
            [
                [
                    f"{r.width}x{r.height}",
                    str(r.threads),
                    f"{r.fluid_ms / r.end_to_end_ms:.0%}",
                    f"{r.maps_ms / r.end_to_end_ms:.0%}",
                    f"{r.resample_ms / r.end_to_end_ms:.0%}",
                    f"{r.sum_ms / r.end_to_end_ms:.2f}",
                    max(
                        [("(a) fluid", r.fluid_ms), ("(b) map", r.maps_ms), ("(c) resample", r.resample_ms)],
                        key=lambda kv: kv[1],
                    )[0],
                ]
                for r in rows
            ],
        )
    )
    out.append(
        "\nAgainst the floor, one grid_sample of the frame (torch's alone, on the last frame's grid, timed in the "
        "same repeats): ms per frame, and each path's ratio to it (target of issue #20: <= 2.5x)"
    )
    out.append(
        table(
            ["image", "threads", "floor ms", "forward ms", "forward / floor", "iter_frames ms", "iter_frames / floor"],
            [
                [
                    f"{r.width}x{r.height}",
                    str(r.threads),
                    f"{r.floor_ms:.2f}",
                    f"{r.forward_ms:.2f}",
                    f"{r.forward_ms / r.floor_ms:.2f}x",
                    f"{r.end_to_end_ms:.2f}",
                    f"{r.end_to_end_ms / r.floor_ms:.2f}x",
                ]
                for r in rows
            ],
        )
    )
    threads = sorted({r.threads for r in rows})
    if len(threads) > 1:
        t0 = threads[0]
        out.append(f"\nSpeed-up over {t0} thread(s) (median end-to-end ms per frame, same run)")
        sp_rows = []
        for r in rows:
            if r.threads == t0:
                continue
            base = next(b for b in rows if (b.height, b.width, b.threads) == (r.height, r.width, t0))
            sp_rows.append(
                [
                    f"{r.width}x{r.height}",
                    str(r.threads),
                    f"{base.end_to_end_ms / r.end_to_end_ms:.2f}",
                    f"{base.fluid_ms / r.fluid_ms:.2f}",
                    f"{base.maps_ms / r.maps_ms:.2f}",
                    f"{base.resample_ms / r.resample_ms:.2f}",
                ]
            )
        out.append(table(["image", "threads", "end to end", "(a) fluid", "(b) map", "(c) resample"], sp_rows))
    out.append(
        f"\nTarget: >= {TARGET_FPS:g} frames per second end to end at {TARGET_SIZE[1]}x{TARGET_SIZE[0]} "
        f"(i.e. <= {1e3 / TARGET_FPS:.2f} ms per frame)"
    )
    targets = []
    t_rows = []
    for r in rows:
        if (r.height, r.width) != TARGET_SIZE:
            continue
        met = r.fps >= TARGET_FPS
        pieces = {"fluid": r.fluid_ms, "map": r.maps_ms, "resample": r.resample_ms}
        top = max(pieces, key=pieces.__getitem__)
        # with one thread, CPU time is a load-independent estimate of the wall time on an idle core
        met_cpu = r.fps_cpu >= TARGET_FPS if r.threads == 1 else None
        targets.append(
            {
                "threads": r.threads,
                "fps": r.fps,
                "met": met,
                "dominant": top,
                "dominant_ms": pieces[top],
                "needed_speedup": TARGET_FPS / r.fps,
                "fps_cpu": r.fps_cpu,
                "met_by_cpu_time": met_cpu,
            }
        )
        t_rows.append(
            [
                str(r.threads),
                f"{r.fps:.1f}",
                f"{r.end_to_end_ms:.2f}",
                f"{TARGET_FPS / r.fps:.2f}x",
                f"{top} ({pieces[top]:.2f} ms)",
                verdict(met),
                "-" if met_cpu is None else f"{r.fps_cpu:.1f} fps: {verdict(met_cpu)}",
            ]
        )
    if t_rows:
        out.append(
            table(
                ["threads", "fps", "ms/frame", "speed-up needed", "largest piece", "target", "by CPU time (1 thread)"],
                t_rows,
            )
        )
    for label, ops in profiles.items():
        out.append(f"\nOperators of one end-to-end loop, {label} (torch.profiler, untimed pass; self CPU ms per frame)")
        out.append(
            table(
                ["op", "calls", "ms/frame", "share"],
                [[o["op"], str(o["calls"]), f"{o['self_ms_per_frame']:.2f}", f"{o['share']:.0%}"] for o in ops],
            )
        )
    return "\n".join(out), {"fps_600": targets}


# ----------------------------------------------------------------------------------------------- main


def parse_threads(text: str) -> list[int]:
    try:
        values = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--threads must be a comma-separated list of integers, got {text!r}"
        ) from None
    if not values or any(v < 1 for v in values):
        raise argparse.ArgumentTypeError(f"--threads must list integers >= 1, got {text!r}")
    return values


def parse_sizes(text: str) -> list[tuple[int, int]]:
    try:
        sizes = [tuple(int(v) for v in item.lower().split("x")) for item in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"sizes are written HxW[,HxW...], e.g. 600x600, got {text!r}") from None
    if any(len(s) != 2 or min(s) < 8 for s in sizes):
        raise argparse.ArgumentTypeError(f"each size needs H and W >= 8, got {text!r}")
    return sizes  # type: ignore[return-value]


def plot_fps(path: str, rows: list[Row], subtitle: str) -> None:
    """Frames per second (end to end) and the split per frame against image size, one line per thread count."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 4.2), dpi=120)
    for n in sorted({r.threads for r in rows}):
        rs = sorted((r for r in rows if r.threads == n), key=lambda r: r.height * r.width)
        mp = [r.height * r.width / 1e6 for r in rs]
        ax.plot(mp, [r.fps for r in rs], "o-", label=f"{n} thread(s)")
        for r, x in zip(rs, mp):
            ax.annotate(f"{r.width}x{r.height}", (x, r.fps), fontsize=7, xytext=(3, 3), textcoords="offset points")
        if n == min(r.threads for r in rows):
            for key, label in [("fluid_ms", "(a) fluid"), ("maps_ms", "(b) map"), ("resample_ms", "(c) resample")]:
                bx.plot(mp, [getattr(r, key) for r in rs], "o-", label=f"{label}, {n} thread(s)")
    ax.axhline(60, color="grey", ls="--", lw=1, label="target 60 fps")
    ax.set(xlabel="image size (megapixels)", ylabel="frames per second (end to end)", xscale="log", yscale="log")
    bx.set(xlabel="image size (megapixels)", ylabel="ms per frame", xscale="log", yscale="log")
    ax.legend(fontsize=8)
    bx.legend(fontsize=8)
    fig.suptitle(f"FluidWarp.iter_frames, 64x64 fluid, RGB float32 ({subtitle})", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="smoke mode: small images, few frames and repeats")
    parser.add_argument("--json", metavar="PATH", help="also write the results as JSON to PATH")
    parser.add_argument(
        "--threads",
        type=parse_threads,
        default=[1],
        help="torch CPU threads, or a comma-separated list measured in turn in every repeat, e.g. "
        "1,2 (default 1: on a small shared machine, multi-threaded kernels stall for a "
        "scheduler slice whenever another process holds a core)",
    )
    parser.add_argument("--frames", type=int, help="fluid steps T per loop (default 30; --quick 6)")
    parser.add_argument("--repeats", type=int, help="interleaved repeats (default 5; --quick 2)")
    parser.add_argument(
        "--sizes",
        type=parse_sizes,
        help="image sizes HxW, comma-separated (default 600x600,1080x1920; --quick 120x120,108x192)",
    )
    parser.add_argument("--plot", metavar="PATH.png", help="also plot frames per second against image size")
    args = parser.parse_args(argv)
    frames = args.frames or (6 if args.quick else 30)
    repeats = args.repeats or (2 if args.quick else 5)
    if frames < 1 or repeats < 1:
        parser.error(f"--frames and --repeats must be >= 1, got {frames} and {repeats}")
    sizes = args.sizes or ([(120, 120), (108, 192)] if args.quick else [TARGET_SIZE, (1080, 1920)])

    info = machine()
    info["threads"] = args.threads
    info["load_start"] = machine_load()
    info["sources_sha256"] = source_fingerprint()
    print(
        f"bench_warp: {info['cpu']}, {info['cpu_count']} CPUs, torch {info['torch']} with thread(s) "
        f"{','.join(map(str, args.threads))}, Python {info['python']}, {info['date']}"
        + (" [--quick]" if args.quick else ""),
        flush=True,
    )
    print(
        f"torchfluidwarp sources sha256 {info['sources_sha256']}; at the start: {describe_load(info['load_start'])}",
        flush=True,
    )
    log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731

    t_start = time.perf_counter()
    rows: list[Row] = []
    profiles: dict[str, list[dict[str, Any]]] = {}
    for size in sizes:
        warp = FluidWarp(FLUID, steps=frames, dt=1.0)
        brushes, image = make_brushes(size), make_image(size)
        torch.set_num_threads(args.threads[0])
        one_repeat(warp, brushes, image)  # warm-up: geometry caches, kernels, allocator
        max_disp = max_displacement(warp, brushes, size)
        samples: dict[int, list[dict[str, tuple[float, float]]]] = {n: [] for n in args.threads}
        for rep in range(repeats):
            for n in args.threads:
                log(f"  {size[1]}x{size[0]}: repeat {rep + 1}/{repeats}, {n} thread(s) ...")
                torch.set_num_threads(n)
                samples[n].append(one_repeat(warp, brushes, image))
        rows += [summarise(size, n, frames, samples[n], max_disp) for n in args.threads]
        profiles[f"{size[1]}x{size[0]}, {args.threads[0]} thread(s)"] = profile_ops(
            warp, brushes, image, args.threads[0], top=10
        )
    text, targets = report(rows, profiles)
    print("\n" + text)
    total = time.perf_counter() - t_start
    info["load_end"] = machine_load()
    print(f"\ntotal {total:.0f} s; at the end: {describe_load(info['load_end'])}")
    if source_fingerprint() != info["sources_sha256"]:
        info["sources_changed"] = True
        print(
            "WARNING: the torchfluidwarp sources changed during the run (this process kept the code it imported "
            "at the start; any subprocess imported the new code)"
        )

    if args.plot:
        plot_fps(args.plot, rows, f"{info['cpu']}, torch {info['torch']}, {info['date'][:10]}")
        print(f"plot written to {args.plot}")
    if args.json:
        result = {
            "machine": info,
            "args": vars(args),
            "fluid": FLUID,
            "brush_cells": BRUSH_CELLS,
            "brush_frequency": BRUSH_FREQUENCY,
            "rows": [asdict(r) for r in rows],
            "profiles": profiles,
            "targets": targets,
            "total_s": total,
        }
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
