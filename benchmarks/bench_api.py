"""Time the public API's main jobs, for an A/B of two versions of the package (alternating processes).

Six jobs, each the median of ``--repeats`` calls after one warm-up, in one process:

* ``simulate``: ``FluidSimulator`` on 64 x 64 cells, 10 steps, batch 1, forward and backward;
* ``warp``: ``FluidWarp`` frames of a 600 x 600 RGB image, 64 x 64 cells, 10 steps, no autograd;
* ``fit_keyframes``: the paper's keyframe problem (``_common.flow_instance(0)``: 14 points that a flow carries
  5-10 px, 64 x 64 cells, 10 steps), float32, the default fit; and ``fit_keyframes_lbfgs``, the same with
  ``method="lbfgs"``, timed per evaluation (its evaluation count follows round-off, so a whole fit's time is not
  comparable across versions);
* ``fit_images``: ``fit_images`` of a 96 x 96 picture onto a shifted copy, 32 x 32 cells;
* ``morph``: the bundled astronaut onto the cat through their 23 marks, 10 frames rendered, natural method;
* ``augment``: ``FluidWarpAugment`` on a batch of 8 RGB 224 x 224 images.

Run it once per version and alternate, e.g. (a checkout of the old version in ``/tmp/old``)::

    for i in 1 2 3; do
      PYTHONPATH=/tmp/old python benchmarks/bench_api.py --json /tmp/old_$i.json
      python benchmarks/bench_api.py --json /tmp/new_$i.json
    done
    python benchmarks/bench_api.py --old /tmp/old_*.json --new /tmp/new_*.json

Every job uses only arguments that both sides of an A/B across the typed morph settings (#30) accept, with their
defaults.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable

import torch
from _common import FRAME, flow_instance

import torchfluidwarp as tfw


def _jobs() -> dict[str, Callable[[], int | None]]:
    g = torch.Generator().manual_seed(0)
    sim = tfw.FluidSimulator((64, 64))
    forces = 0.05 * torch.randn(1, 10, 2, 64, 64, generator=g)

    def simulate() -> None:
        f = forces.clone().requires_grad_()
        sim(f).velocities.square().sum().backward()

    warp = tfw.FluidWarp((64, 64), steps=10)
    image = torch.rand(1, 3, 600, 600, generator=g)
    stir = 0.2 * torch.randn(1, 10, 2, 64, 64, generator=g)

    def frames() -> None:
        with torch.no_grad():
            warp(image, stir)

    src, dst = (x[None] for x in flow_instance(0).tensors(torch.float32))

    def keyframes() -> None:
        tfw.fit_keyframes(src, [(10, dst)], grid=(64, 64), steps=10, image_size=FRAME, progress=False)

    def keyframes_lbfgs() -> int:
        fit = tfw.fit_keyframes(
            src, [(10, dst)], grid=(64, 64), steps=10, image_size=FRAME, method="lbfgs", max_iter=20, progress=False
        )
        return fit.evaluations

    yy, xx = torch.meshgrid(torch.linspace(-1, 1, 96), torch.linspace(-1, 1, 96), indexing="ij")
    blob = torch.exp(-((xx - 0.1) ** 2 + yy**2) / 0.1)[None, None].expand(1, 3, 96, 96).contiguous()
    moved = torch.roll(blob, shifts=(3, -4), dims=(-2, -1))

    def images() -> None:
        tfw.fit_images(blob, moved, grid=(32, 32), progress=False)

    from torchfluidwarp.data import load_sample, load_sample_points

    a, b = load_sample("astronaut"), load_sample("cat")
    pa, pb = load_sample_points("astronaut"), load_sample_points("cat")

    def morph() -> None:
        for _ in tfw.morph(a, b, pa, pb, frames=10, progress=False).iter_frames():
            pass

    from torchfluidwarp.augment import FluidWarpAugment

    aug = FluidWarpAugment(generator=torch.Generator().manual_seed(0))
    batch = torch.rand(8, 3, 224, 224, generator=g)

    def augment() -> None:
        aug(batch)

    return {
        "simulate": simulate,
        "warp": frames,
        "fit_keyframes": keyframes,
        "fit_keyframes_lbfgs": keyframes_lbfgs,
        "fit_images": images,
        "morph": morph,
        "augment": augment,
    }


def _run(repeats: int, only: list[str] | None) -> dict[str, float]:
    out = {}
    for name, job in _jobs().items():
        if only and name not in only:
            continue
        job()  # warm-up
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            evaluations = job()
            # per evaluation where the job says how many it made
            times.append((time.perf_counter() - start) / (evaluations or 1))
        out[name] = statistics.median(times)
        unit = "ms per evaluation" if evaluations else "ms"
        print(f"{name:20s} {out[name] * 1e3:9.1f} {unit} (median of {repeats})", file=sys.stderr)
    return out


def _compare(old: list[str], new: list[str]) -> None:
    def medians(paths: list[str]) -> dict[str, float]:
        runs = [json.loads(open(p).read())["seconds"] for p in paths]
        return {k: statistics.median(r[k] for r in runs) for k in runs[0]}

    a, b = medians(old), medians(new)
    print(f"{'job':20s} {'A (ms)':>9s} {'B (ms)':>9s} {'B/A':>6s}   (medians over {len(old)} and {len(new)} processes)")
    for k in a:
        print(f"{k:20s} {a[k] * 1e3:9.1f} {b[k] * 1e3:9.1f} {b[k] / a[k]:6.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per job (default 5)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--only", nargs="*", help="jobs to run (default all)")
    parser.add_argument("--json", help="write {'seconds': {job: median}} here")
    parser.add_argument("--old", nargs="+", metavar="JSON", help="A's files: with --new, print B/A and run nothing")
    parser.add_argument("--new", nargs="+", metavar="JSON", help="B's files")
    args = parser.parse_args()
    if args.old or args.new:
        _compare(args.old, args.new)
        return
    torch.set_num_threads(args.threads)
    seconds = _run(args.repeats, args.only)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"seconds": seconds, "package": tfw.__file__, "torch": torch.__version__}, f)


if __name__ == "__main__":
    main()
