"""Benchmark of augmentation at scale (#21): images per second for a batch of 64 images of 224 x 224.

``FluidWarpAugment`` on the whole batch, ``RandomFluidWarp`` and ``v2.ElasticTransform()`` on each image in turn
(the baseline of the ratios), and ``ElasticTransform`` on the whole batch (one warp shared by all: for reference);
medians of interleaved rounds; again on CUDA when there is one. Figures: docs/benchmarks.md, "Augmentation at
scale".
"""

from __future__ import annotations

import sys
from functools import partial
from typing import Any

import torch
from _common import finish, interleaved, medians_ms, parser, rows_table, start
from bench_augment import SEED, photo
from torchvision import tv_tensors
from torchvision.transforms import v2

from torchfluidwarp.augment import FluidWarpAugment
from torchfluidwarp.augment.transforms import RandomFluidWarp

BASELINE = "ElasticTransform, per image"


def bench(device: str, batch: int, size: int, repeats: int, extra: dict | None = None) -> list[dict[str, Any]]:
    """The four ways of warping a batch, and any ``extra`` ``{label: fn(images)}``, each timed on all of it: ms per
    batch, images/s, ratio to the baseline."""
    images = photo(size, batch).to(device)
    tensor_level = FluidWarpAugment(generator=torch.Generator().manual_seed(SEED))
    transform = RandomFluidWarp(generator=torch.Generator().manual_seed(SEED))
    elastic = v2.ElasticTransform()
    singles = [tv_tensors.Image(x) for x in images]
    cases = {"FluidWarpAugment, batch in one call": lambda: tensor_level(images),
             "RandomFluidWarp (v2), per image": lambda: [transform(x) for x in singles],
             BASELINE: lambda: [elastic(x) for x in singles],
             "ElasticTransform, batch in one call (one shared warp)": lambda: elastic(images)}  # fmt: skip
    cases.update({label: partial(fn, images) for label, fn in (extra or {}).items()})
    with torch.no_grad():
        ms = medians_ms(interleaved(cases, repeats, sync=torch.cuda.synchronize if images.is_cuda else None))
    rate = {k: batch / (t / 1e3) for k, t in ms.items()}
    return [dict(device=device, method=k, ms_per_batch=t, images_per_s=rate[k], ratio=rate[k] / rate[BASELINE])
            for k, t in ms.items()]  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__)
    p.add_argument("--batch", type=int, default=64, help="images per batch (default 64)")
    p.add_argument("--size", type=int, default=224, help="image side in pixels (default 224)")
    p.add_argument("--repeats", type=int, default=3, help="timed rounds after the warm-up (default 3)")
    args = p.parse_args(argv)
    info = start("bench_augment_scale", args.threads)
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    rows = [r for device in devices for r in bench(device, args.batch, args.size, args.repeats)]
    print(rows_table(rows, "device {device} | method {method} | ms per batch {ms_per_batch:.0f} | images/s "
          "{images_per_s:.1f} | x ElasticTransform per image {ratio:.2f}"))  # fmt: skip
    print(f"batch of {args.batch} images of {args.size} x {args.size}, float32; medians of {args.repeats} interleaved "
          f"rounds after a warm-up; devices: {', '.join(devices)}")  # fmt: skip
    finish(info, {"args": vars(args), "rows": rows}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
