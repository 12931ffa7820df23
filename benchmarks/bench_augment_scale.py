"""Benchmark of augmentation at scale (#21): images per second for a batch of 64 images of 224 x 224.

The same batch (the bundled astronaut, resized to 224 x 224, RGB float32, ``--batch`` copies) goes through:

* ``FluidWarpAugment`` (:class:`torchfluidwarp.augment.tensor.FluidWarpAugment`) on the whole batch in one call:
  one independent draw per sample, one batched fluid roll-out (how a collated batch is augmented on its device);
* ``RandomFluidWarp`` (the torchvision v2 transform) on each image in turn (how a ``DataLoader`` worker
  augments its samples), one draw per image;
* torchvision's ``v2.ElasticTransform()`` (defaults: alpha 50, sigma 5) on each image in turn: per-sample warps,
  like the two above; the baseline of the ratios;
* ``v2.ElasticTransform()`` on the whole batch in one call: torchvision treats a batched tensor as one sample,
  so all 64 images share **one** warp. Cheaper, but not per-sample augmentation; shown for reference.

Timings are medians over rounds that call each method in turn (so that load from other processes falls on all
of them alike), after a warm-up; the ratios are images per second over ElasticTransform's per image, from the
same run. On CUDA (when ``torch.cuda.is_available()``) the same methods run again on the GPU, synchronised
around each call. The machine (``_common.machine``) and its load before and after are printed.

Usage::

    python benchmarks/bench_augment_scale.py                    # CPU, 1 thread, 3 rounds (about 2 minutes)
    python benchmarks/bench_augment_scale.py --threads 2 --repeats 5 --json out.json
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import torch
from _common import add_threads_argument, describe_load, machine, machine_load, table, write_json
from bench_augment import SEED, interleaved_ms, photo
from torchvision import tv_tensors
from torchvision.transforms import v2

from torchfluidwarp.augment import FluidWarpAugment
from torchfluidwarp.augment.transforms import RandomFluidWarp


def methods(batch: torch.Tensor) -> dict[str, Callable[[], Any]]:
    """The four ways of warping ``batch`` ``(B, C, H, W)``, each a callable that warps all of it once."""
    tensor_level = FluidWarpAugment(generator=torch.Generator().manual_seed(SEED))
    transform = RandomFluidWarp(generator=torch.Generator().manual_seed(SEED))
    elastic = v2.ElasticTransform()
    images = [tv_tensors.Image(x) for x in batch]
    sync = torch.cuda.synchronize if batch.is_cuda else (lambda: None)

    def timed(fn: Callable[[], Any]) -> Callable[[], Any]:
        def run() -> Any:
            out = fn()
            sync()
            return out

        return run

    return {
        "FluidWarpAugment, batch in one call": timed(lambda: tensor_level(batch)),
        "RandomFluidWarp (v2), per image": timed(lambda: [transform(x) for x in images]),
        "ElasticTransform, per image": timed(lambda: [elastic(x) for x in images]),
        "ElasticTransform, batch in one call (one shared warp)": timed(lambda: elastic(batch)),
    }


BASELINE = "ElasticTransform, per image"


def bench(device: str, batch: int, size: int, repeats: int) -> list[dict[str, Any]]:
    images = photo(size, batch).to(device)
    with torch.no_grad():
        ms = interleaved_ms(methods(images), repeats)
    base = batch / (ms[BASELINE] / 1e3)
    rows = []
    for name, t in ms.items():
        rate = batch / (t / 1e3)
        rows.append({"device": device, "method": name, "ms_per_batch": t, "images_per_s": rate, "ratio": rate / base})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_threads_argument(parser)
    parser.add_argument("--batch", type=int, default=64, help="images per batch (default 64)")
    parser.add_argument("--size", type=int, default=224, help="image side in pixels (default 224)")
    parser.add_argument("--repeats", type=int, default=3, help="timed rounds after the warm-up (default 3)")
    parser.add_argument("--json", help="also write the results to this file")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    info, load = machine(), machine_load()
    print(
        f"machine: {info['cpu']} ({info['cpu_count']} CPUs), torch {info['torch']}, {info['torch_threads']} thread(s)"
    )
    print(f"before: {describe_load(load)}")
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    if len(devices) == 1:
        print("CUDA: not available on this machine; CPU only")
    start = time.perf_counter()
    rows = []
    for device in devices:
        rows += bench(device, args.batch, args.size, args.repeats)
    after = machine_load()
    print(
        table(
            ["device", "method", "ms per batch", "images/s", "x ElasticTransform per image"],
            [
                [r["device"], r["method"], f"{r['ms_per_batch']:.0f}", f"{r['images_per_s']:.1f}", f"{r['ratio']:.2f}"]
                for r in rows
            ],
        )
    )
    print(
        f"batch of {args.batch} images of {args.size} x {args.size}, float32; medians of {args.repeats} interleaved "
        f"rounds after a warm-up; {time.perf_counter() - start:.0f} s"
    )
    print(f"after: {describe_load(after)}")
    if args.json:
        write_json(
            args.json, {"machine": info, "load_before": load, "load_after": after, "args": vars(args), "rows": rows}
        )


if __name__ == "__main__":
    main()
