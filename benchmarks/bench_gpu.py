"""Benchmark of the fused Triton kernels on a GPU (issue #33): a step and a frame at 1920x1080, fused and unfused,
against one grid_sample of the frame; augmentation at training scale against torchvision's ElasticTransform.

CUDA only: without a CUDA device it says so and exits (status 0). Float32, no grad. (1) ``FluidWarp`` on a 64x64
fluid stirred by ``bench_warp.py``'s brushes, at 1920x1080: ms and CUDA kernels (``torch.profiler``) per fluid step
(``FluidWarp.rollout`` over ``--steps`` steps), per frame of ``iter_frames`` and of ``forward``, with the fused
kernels (the default on CUDA) and without them (``TORCHFLUIDWARP_FUSED=0``), against the floor: one
``grid_sample`` of the frame. (2) ``bench_augment_scale.py``'s batches (default settings) on the GPU, 64 and 256
images of 224x224, with ``FluidWarpAugment`` fused and unfused: images per second; then ``bench_augment.py``'s
folds at matched displacement, the fluid's maps drawn on the GPU. Figures: docs/benchmarks.md, "GPU kernels (issue
#33)".
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import bench_augment_scale
import torch
import torch.nn.functional as F
from _common import FLUID, finish, interleaved, medians_ms, parser, rows_table, start, stirred
from bench_augment import SEED, bench_folds
from bench_device import smooth_grid
from torch.profiler import ProfilerActivity, profile

from torchfluidwarp.augment import FluidWarpAugment
from torchfluidwarp.core.fused import ENVIRONMENT


@contextmanager
def fused(on: bool) -> Iterator[None]:
    """The fused kernels on or off for the calls inside (the library reads the variable at every call)."""
    before = os.environ.get(ENVIRONMENT)
    os.environ[ENVIRONMENT] = "1" if on else "0"
    try:
        yield
    finally:
        if before is None:
            del os.environ[ENVIRONMENT]
        else:
            os.environ[ENVIRONMENT] = before


def with_kernels(fn: Callable[..., Any], on: bool) -> Callable[..., Any]:
    def run(*args: Any) -> Any:
        with fused(on):
            return fn(*args)

    return run


def kernels(fn: Callable[[], Any]) -> int:
    """CUDA kernels (and memory copies and fills) that one call of ``fn`` launches."""
    with profile(activities=[ProfilerActivity.CUDA]) as prof:
        fn()
        torch.cuda.synchronize()
    return sum(1 for e in prof.events() if e.device_type == torch.autograd.DeviceType.CUDA)


def bench_frames(size: tuple[int, int], steps: int, repeats: int) -> list[dict[str, Any]]:
    """ms and kernels per step and per frame, fused and unfused, and of the floor."""
    dev = torch.device("cuda")
    (warp, brushes, image), grid = stirred(size, steps, dev), smooth_grid(size, dev)
    paths: dict[str, Callable[[], Any]] = {
        "fluid step": lambda: warp.rollout(brushes, size),
        "frame of iter_frames": lambda: sum(1 for _ in warp.iter_frames(image, brushes)),
        "frame of forward": lambda: warp(image, brushes),
    }
    cases = {
        f"{k}, {mode}": with_kernels(fn, mode == "fused") for k, fn in paths.items() for mode in ("fused", "unfused")
    }
    cases["floor: one grid_sample of the frame"] = lambda: [
        F.grid_sample(image, grid, "bilinear", "border", False) for _ in range(steps)
    ]
    with torch.no_grad():
        ms = medians_ms(interleaved(cases, repeats, sync=torch.cuda.synchronize))
        launched = {k: kernels(fn) for k, fn in cases.items()}
    floor = ms["floor: one grid_sample of the frame"] / steps
    return [
        dict(path=k, ms=t / steps, kernels=launched[k] / steps, floor_ratio=t / steps / floor) for k, t in ms.items()
    ]


def bench_throughput(batch: int, size: int, repeats: int) -> list[dict[str, Any]]:
    """``bench_augment_scale.py``'s batch on the GPU (``FluidWarpAugment`` fused, the default there), and
    ``FluidWarpAugment`` unfused: images per second and the ratio to ElasticTransform per image."""
    unfused = with_kernels(FluidWarpAugment(generator=torch.Generator().manual_seed(SEED)), False)
    extra = {"FluidWarpAugment, batch in one call, unfused": unfused}
    return [dict(r, batch=batch) for r in bench_augment_scale.bench("cuda", batch, size, repeats, extra)]


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="a 192x108 frame over 4 steps, batches of 8, 4 draws, 2 repeats", threads=None)
    p.add_argument("--steps", type=int, default=30, help="fluid steps (frames) per timed call (default 30)")
    p.add_argument("--batches", type=int, nargs="+", default=[64, 256], help="augmentation batches (default 64 256)")
    p.add_argument("--repeats", type=int, default=5, help="interleaved timed repeats (default 5)")
    p.add_argument("--draws", type=int, default=64, help="draws per setting for the fold statistics (default 64)")
    args = p.parse_args(argv)
    if not torch.cuda.is_available():
        print("bench_gpu: no CUDA device here; this benchmark measures the GPU only (nothing was run)")
        return 0
    size, steps, batches = ((1080, 1920), args.steps, args.batches)
    if args.quick:
        size, steps, batches, args.draws, args.repeats = (108, 192), 4, [8], 4, 2
    info = start("bench_gpu", args.threads, " [--quick]" if args.quick else "")
    pr = torch.cuda.get_device_properties(0)
    print(f"cuda: {pr.name}, {pr.total_memory / 2**30:.0f} GiB, CUDA {torch.version.cuda}, torch {torch.__version__}")
    result: dict[str, Any] = {"args": vars(args), "device": pr.name}

    result["frames"] = bench_frames(size, steps, args.repeats)
    print(f"\n{size[1]}x{size[0]} RGB float32, {FLUID[0]}x{FLUID[1]} fluid, {steps} steps; medians of {args.repeats}")
    print(rows_table(result["frames"], "path {path} | ms per step or frame {ms:.3f} | kernels per step or frame "
                     "{kernels:.0f} | / floor {floor_ratio:.1f}x"))  # fmt: skip

    result["augment"] = [r for b in batches for r in bench_throughput(b, 224, args.repeats)]
    print(f"\nAugmentation, 224x224 float32 images; medians of {args.repeats}")
    print(rows_table(result["augment"], "batch {batch} | method {method} | ms per batch {ms_per_batch:.1f} | "
                     "images/s {images_per_s:.0f} | x ElasticTransform per image {ratio:.2f}"))  # fmt: skip

    print(f"\nFolds at matched displacement, 224x224, {args.draws} draws per setting, the fluid's drawn on the GPU")
    result["folds"] = bench_folds(224, args.draws, device="cuda")
    finish(info, result, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
