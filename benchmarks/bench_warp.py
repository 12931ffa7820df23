"""Benchmark of the warp layer as a real-time animation loop: frames per second and where each frame's time goes.

A 64x64 fluid stirred by ``_common.make_brushes`` warps an RGB float32 image without grad: ``iter_frames`` end to
end (target: >= 60 fps at 600x600), the split of a frame (fluid step, map advance and its back-trace,
resampling), and ``forward`` and ``iter_frames`` against the floor, one ``grid_sample`` a frame (issue #20:
<= 2.5x). Details: benchmarks/README.md; figures: docs/benchmarks.md, "Warp layer".
"""

from __future__ import annotations

import statistics
import sys
import time
from typing import Any

import torch
from _common import FLUID, finish, log, parser, pyplot, rows_table, save_figure, start, stirred, verdict
from torch import Tensor

from torchfluidwarp.core.grid import cell_scale, pixel_to_normalized, rescale_points
from torchfluidwarp.core.sampling import sample
from torchfluidwarp.core.staggered import StaggeredGrid
from torchfluidwarp.warp import FluidWarp, identity_map, iter_backward_maps, warp_image
from torchfluidwarp.warp.maps import TRACE_OVERSAMPLE

TARGET_SIZE, TARGET_FPS = (600, 600), 60.0
PIECES = ("fluid", "maps", "resample", "public", "backtrace", "end_to_end", "floor", "forward")


@torch.no_grad()
def one_repeat(warp: FluidWarp, brushes: Any, image: Tensor) -> dict[str, tuple[float, float]]:
    """One pass of every measurement: ``{piece: (wall s, CPU s)}`` summed over the ``T`` frames."""
    size, T = (image.shape[-2], image.shape[-1]), warp.steps
    acc = {k: [0.0, 0.0] for k in PIECES}
    clock = lambda: (time.perf_counter(), time.process_time())

    def timed(key: str, fn: Any, *args: Any) -> Any:
        c0 = clock()
        out = fn(*args)
        c1 = clock()
        acc[key][0] += c1[0] - c0[0]
        acc[key][1] += c1[1] - c0[1]
        return out

    vel = timed("fluid", lambda: warp.rollout(brushes, size).velocities)
    maps = iter_backward_maps(vel, size, warp.dt)
    next(maps)  # map 0 is the identity: not shown, not counted
    for _ in range(T):
        m = timed("maps", next, maps)
        grid = pixel_to_normalized(m, size)
        timed("resample", lambda: sample(image, grid, mode=warp.mode, align_corners=False, check=None))
        timed("public", warp_image, image, m, warp.mode)
    sg = StaggeredGrid(warp.grid)
    h, w = warp.grid.shape
    raster = (min(size[0], TRACE_OVERSAMPLE * h), min(size[1], TRACE_OVERSAMPLE * w))
    cells = rescale_points(identity_map(raster).reshape(1, -1, 2), cell_scale(raster, warp.grid))
    timed("backtrace", lambda: [sg.backtrace(sg.extend(vel[:, t]), cells, warp.dt) for t in range(T)])
    n = timed("end_to_end", lambda: sum(1 for _ in warp.iter_frames(image, brushes)))
    floor = lambda: torch.nn.functional.grid_sample(image, grid, padding_mode="border", align_corners=False)
    timed("floor", lambda: [floor() for _ in range(T)])
    timed("forward", warp, image, brushes)
    if n != T + 1:
        raise RuntimeError(f"iter_frames yielded {n} frames, expected {T + 1}")
    return {k: (v[0], v[1]) for k, v in acc.items()}


def summarise(size: tuple[int, int], threads: int, steps: int, samples: list[dict], max_disp: float) -> dict:
    w = {k: statistics.median(s[k][0] for s in samples) / steps * 1e3 for k in PIECES}
    c = {k + "_cpu": statistics.median(s[k][1] for s in samples) / steps * 1e3 for k in PIECES}
    return dict(image=f"{size[1]}x{size[0]}", size=size, threads=threads, steps=steps, repeats=len(samples), **w, **c,
                compose=w["maps"] - w["backtrace"], sum=w["fluid"] + w["maps"] + w["resample"],
                fps=1e3 / w["end_to_end"], fps_cpu=1e3 / c["end_to_end_cpu"],
                fwd_floor=w["forward"] / w["floor"], iter_floor=w["end_to_end"] / w["floor"],
                max_disp=max_disp)  # fmt: skip


@torch.no_grad()
def max_displacement(warp: FluidWarp, brushes: Any, size: tuple[int, int]) -> float:
    """Largest distance, in pixels, between a pixel and where the last frame reads it from."""
    (last,) = iter_backward_maps(warp.rollout(brushes, size).velocities, size, warp.dt, times=[warp.steps])
    return float((last - identity_map(size)).norm(dim=-1).max())


@torch.no_grad()
def profile_ops(warp: FluidWarp, brushes: Any, image: Tensor, top: int = 10) -> list[dict[str, Any]]:
    """Operators of one end-to-end loop by self CPU time (untimed pass under ``torch.profiler``)."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        sum(1 for _ in warp.iter_frames(image, brushes))
    events = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)
    total = sum(e.self_cpu_time_total for e in events)
    return [dict(op=e.key, calls=e.count, ms=e.self_cpu_time_total / 1e3 / warp.steps,
                 share=e.self_cpu_time_total / total) for e in events[:top]]  # fmt: skip


def plot_fps(path: str, rows: list[dict], subtitle: str) -> None:
    """Frames per second (end to end) and the split per frame against image size, one line per thread count."""
    fig, (ax, bx) = pyplot().subplots(1, 2, figsize=(10, 4.2), dpi=120)
    for n in sorted({r["threads"] for r in rows}):
        rs = sorted((r for r in rows if r["threads"] == n), key=lambda r: r["size"][0] * r["size"][1])
        mp = [r["size"][0] * r["size"][1] / 1e6 for r in rs]
        ax.plot(mp, [r["fps"] for r in rs], "o-", label=f"{n} thread(s)")
        for r, x in zip(rs, mp):
            ax.annotate(r["image"], (x, r["fps"]), fontsize=7, xytext=(3, 3), textcoords="offset points")
        if n == min(r["threads"] for r in rows):
            for key, label in [("fluid", "(a) fluid"), ("maps", "(b) map"), ("resample", "(c) resample")]:
                bx.plot(mp, [r[key] for r in rs], "o-", label=f"{label}, {n} thread(s)")
    ax.axhline(TARGET_FPS, color="grey", ls="--", lw=1, label="target 60 fps")
    ax.set(xlabel="image size (megapixels)", ylabel="frames per second (end to end)", xscale="log", yscale="log")
    bx.set(xlabel="image size (megapixels)", ylabel="ms per frame", xscale="log", yscale="log")
    ax.legend(fontsize=8)
    bx.legend(fontsize=8)
    fig.suptitle(f"FluidWarp.iter_frames, 64x64 fluid, RGB float32 ({subtitle})", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="120x120 and 192x108 images, 6 frames, 2 repeats", threads=False)
    p.add_argument("--threads", type=lambda s: [int(t) for t in s.split(",")], default=[1],
                   help="torch threads, or a comma-separated list, measured in turn each repeat")  # fmt: skip
    p.add_argument("--frames", type=int, help="fluid steps T per loop (default 30; --quick 6)")
    p.add_argument("--repeats", type=int, help="interleaved repeats (default 5; --quick 2)")
    p.add_argument("--sizes", type=lambda s: [tuple(int(v) for v in x.split("x")) for x in s.split(",")],
                   help="image sizes HxW, comma-separated (default 600x600,1080x1920)")  # fmt: skip
    p.add_argument("--plot", metavar="PATH.png", help="also plot frames per second against image size")
    args = p.parse_args(argv)
    frames, repeats = args.frames or (6 if args.quick else 30), args.repeats or (2 if args.quick else 5)
    sizes = args.sizes or ([(120, 120), (108, 192)] if args.quick else [TARGET_SIZE, (1080, 1920)])
    info = start("bench_warp", args.threads[0], f" (threads {args.threads})" + (" [--quick]" if args.quick else ""))
    rows: list[dict] = []
    profiles: dict[str, list] = {}
    for size in sizes:
        warp, brushes, image = stirred(size, frames)
        torch.set_num_threads(args.threads[0])
        one_repeat(warp, brushes, image)  # warm-up
        samples: dict[int, list] = {n: [] for n in args.threads}
        for rep in range(repeats):
            for n in args.threads:
                log(f"  {size[1]}x{size[0]}: repeat {rep + 1}/{repeats}, {n} thread(s) ...")
                torch.set_num_threads(n)
                samples[n].append(one_repeat(warp, brushes, image))
        max_disp = max_displacement(warp, brushes, size)
        rows += [summarise(size, n, frames, samples[n], max_disp) for n in args.threads]
        torch.set_num_threads(args.threads[0])
        profiles[f"{size[1]}x{size[0]}, {args.threads[0]} thread(s)"] = profile_ops(warp, brushes, image)
    print(f"\nWarp animation loop, {FLUID[0]}x{FLUID[1]} fluid, RGB float32, no grad; median ms per frame: (a) fluid "
          "step, (b) map advance = back-trace + composition, (c) resampling as iter_frames runs it; warp_image = "
          "the public function on the same maps, input checks included")  # fmt: skip
    print(rows_table(rows, "image {image} | threads {threads} | frames {steps} | reps {repeats} | (a) fluid "
          "{fluid:.2f} | (b) map {maps:.2f} | (b) back-trace {backtrace:.2f} | (b) compose {compose:.2f} | (c) "
          "resample {resample:.2f} | a+b+c {sum:.2f} | end to end {end_to_end:.2f} | fps {fps:.1f} | warp_image "
          "{public:.2f} | max disp px {max_disp:.1f}"))  # fmt: skip
    print("\nThe same in this process's CPU time per frame (all its threads)")
    print(rows_table(rows, "image {image} | threads {threads} | (a) fluid {fluid_cpu:.2f} | (b) map {maps_cpu:.2f} "
          "| (c) resample {resample_cpu:.2f} | end to end {end_to_end_cpu:.2f} | fps by CPU {fps_cpu:.1f} | "
          "warp_image {public_cpu:.2f}"))  # fmt: skip
    print("\nAgainst the floor, one grid_sample of the frame in the same repeats (target of issue #20: <= 2.5x)")
    print(rows_table(rows, "image {image} | threads {threads} | floor ms {floor:.2f} | forward ms {forward:.2f} | "
          "forward / floor {fwd_floor:.2f}x | iter_frames ms {end_to_end:.2f} | iter_frames / floor "
          "{iter_floor:.2f}x"))  # fmt: skip
    base = {r["image"]: r for r in rows if r["threads"] == args.threads[0]}
    for r in rows:
        b = base[r["image"]]
        r.update(sp=b["end_to_end"] / r["end_to_end"], sp_a=b["fluid"] / r["fluid"], sp_b=b["maps"] / r["maps"],
                 sp_c=b["resample"] / r["resample"], met=verdict(r["fps"] >= TARGET_FPS))  # fmt: skip
    if len(args.threads) > 1:
        print(f"\nSpeed-up over {args.threads[0]} thread(s), same run")
        print(rows_table(rows, "image {image} | threads {threads} | end to end {sp:.2f} | (a) fluid {sp_a:.2f} | "
              "(b) map {sp_b:.2f} | (c) resample {sp_c:.2f}"))  # fmt: skip
    target = [r for r in rows if tuple(r["size"]) == TARGET_SIZE]
    if target:
        print(f"\nTarget: >= {TARGET_FPS:g} frames per second end to end at 600x600")
        print(rows_table(target, "threads {threads} | fps {fps:.1f} | ms/frame {end_to_end:.2f} | target {met} | "
              "fps by CPU time {fps_cpu:.1f}"))  # fmt: skip
    for label, ops in profiles.items():
        print(f"\nOperators of one end-to-end loop, {label} (torch.profiler, untimed; self CPU ms per frame)")
        print(rows_table(ops, "op {op} | calls {calls} | ms/frame {ms:.2f} | share {share:.0%}"))
    if args.plot:
        plot_fps(args.plot, rows, f"{info['cpu']}, torch {info['torch']}, {info['date'][:10]}")
    finish(info, dict(args=vars(args), fluid=FLUID, rows=rows, profiles=profiles), args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
