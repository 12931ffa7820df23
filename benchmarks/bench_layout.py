"""A/B of a change to the package's shape: the main public paths timed on ``--base`` and on this checkout.

Checks out ``--base`` into a temporary git worktree and times the same public top-level calls in fresh
subprocesses alternating between the two trees; prints medians and new / old. The workloads use only arguments
that every version since the flat layout accepts; ``--only TEXT`` times those whose name holds ``TEXT`` (the
30-frame 512^2 morph of issue #32: ``--only "30 frames"``), ``--skip TEXT`` leaves them out, and ``--new COMMIT``
times a commit instead of the checkout. The 128^2 morph is the marks alone in every tree (since #32 the default
also aligns the pixels; the 30-frame morph keeps each tree's default). Figures: docs/benchmarks.md, "Package
layout: no cost" (issue #18), "One shape: no cost" (issue #30) and "A 30-frame morph" (issue #32).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import subprocess
import sys
import tempfile

from _common import describe_load, machine, machine_load, table

ROOT = pathlib.Path(__file__).resolve().parents[1]

WORKLOADS = r"""
import json, sys, time, warnings
import torch
warnings.simplefilter("ignore")
torch.set_num_threads(int(sys.argv[1]))
only, skip = sys.argv[2], sys.argv[3]
import torchfluidwarp as tfw
from torchfluidwarp.data import load_sample, load_sample_points

def timed(fn, repeats=3):
    fn()  # warm-up
    best = []
    for _ in range(repeats):
        t = time.perf_counter(); fn(); best.append(time.perf_counter() - t)
    return min(best)

g = torch.Generator().manual_seed(0)
out = {}
def bench(name, fn, repeats=3):
    if only in name and not (skip and skip in name):
        out[name] = timed(fn, repeats)
sim = tfw.FluidSimulator(64)
forces = 0.05 * torch.randn(1, 60, 2, 64, 64, generator=g)
bench("simulate 60 steps 64^2", lambda: sim(forces))
warp = tfw.FluidWarp(64, 20)
image = torch.rand(1, 3, 256, 256, generator=g)
wf = 0.05 * torch.randn(1, 20, 2, 64, 64, generator=g)
bench("FluidWarp 256^2 x 20 steps", lambda: warp(image, wf))
warp10 = tfw.FluidWarp(64, 10)
image600 = torch.rand(1, 3, 600, 600, generator=g)
wf10 = 0.2 * torch.randn(1, 10, 2, 64, 64, generator=g)
with torch.no_grad():
    bench("FluidWarp 600^2 x 10 steps", lambda: warp10(image600, wf10))
src = torch.rand(14, 2, generator=g) * 40 + 12
tgt = src + torch.randn(14, 2, generator=g) * 3
bench("fit_keyframes paper set-up",
    lambda: tfw.fit_keyframes(src, tgt, steps=10, grid=64, image_size=(64, 64), progress=False), repeats=2
)
yy, xx = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
blob = lambda cx, cy: torch.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / 60.0)[None, None]
bench("fit_images 64^2",
    lambda: tfw.fit_images(
        blob(28, 30), blob(34, 32), loss="mse", compressible=False, grid=16, levels=(8, 16), steps=4, max_iter=15,
        progress=False,
    ),
    repeats=2,
)
a, b = load_sample("astronaut"), load_sample("cat")
pa, pb = load_sample_points("astronaut"), load_sample_points("cat")
def small(im, p):
    im = im.reshape(1, -1, *im.shape[-2:])
    scale = torch.tensor([128 / im.shape[-1], 128 / im.shape[-2]])
    out = torch.nn.functional.interpolate(im, size=(128, 128), mode="bilinear", antialias=True)[0]
    return out, ((p + 0.5) * scale - 0.5).clamp(0, 127)
a128, pa128 = small(a, pa)
b128, pb128 = small(b, pb)
import dataclasses
try:  # trees since #32 align the pixels by default: not here
    from torchfluidwarp.morph import NaturalSettings as natural
except ImportError:
    natural = None
dense = natural is not None and "dense" in {f.name for f in dataclasses.fields(natural)}
marks = {"settings": natural(dense=None)} if dense else {}
bench("morph 128^2 x 10 frames (marks alone)",
    lambda: tfw.morph(a128, b128, pa128, pb128, frames=10, progress=False, **marks), repeats=2
)
from torchfluidwarp.augment import FluidWarpAugment
aug = FluidWarpAugment(generator=torch.Generator().manual_seed(1))
batch = torch.rand(8, 3, 64, 64, generator=g)
bench("augment 8 x 64^2", lambda: aug(batch))
def stream(frames):
    r = tfw.morph(a, b, pa, pb, frames=frames, progress=False)
    for _ in r.iter_frames():
        pass
bench("morph 512^2 x 30 frames, streamed", lambda: stream(30), repeats=1)
print(json.dumps(out))
"""


def run(tree: pathlib.Path, threads: int, only: str = "", skip: str = "") -> dict[str, float]:
    env = {"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin", "OMP_NUM_THREADS": str(threads), "MPLBACKEND": "Agg"}
    done = subprocess.run(
        [sys.executable, "-c", WORKLOADS, str(threads), only, skip],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode:
        raise SystemExit(f"workloads failed in {tree}:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--base", default="2e9f7a8", help="the commit to compare against (default: the flat layout)")
    parser.add_argument("--repeats", type=int, default=5, help="subprocess pairs (old, new) to alternate")
    parser.add_argument("--threads", type=int, default=2, help="torch threads of each subprocess (default 2)")
    parser.add_argument("--only", default="", help="time only the workloads whose name holds this text")
    parser.add_argument("--skip", default="", help="leave out the workloads whose name holds this text")
    parser.add_argument("--new", default=None, help="a commit to time instead of this checkout (default: the checkout)")
    args = parser.parse_args()
    print(machine())
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"old": pathlib.Path(tmp) / "old", "new": ROOT if args.new is None else pathlib.Path(tmp) / "new"}
        made = [(trees[k], c) for k, c in (("old", args.base), ("new", args.new)) if c is not None]
        for tree, commit in made:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), commit], check=True)
        try:
            runs: dict[str, list[dict[str, float]]] = {"old": [], "new": []}
            for i in range(args.repeats):
                for name, tree in trees.items():
                    runs[name].append(run(tree, args.threads, args.only, args.skip))
                    print(f"pair {i + 1}/{args.repeats} {name} done", flush=True)
        finally:
            for tree, _ in made:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)
    rows = []
    for key in runs["old"][0]:
        o = statistics.median(r[key] for r in runs["old"])
        n = statistics.median(r[key] for r in runs["new"])
        rows.append([key, f"{1000 * o:.1f}", f"{1000 * n:.1f}", f"{n / o:.2f}"])
    new = "this checkout" if args.new is None else args.new
    print(f"base {args.base} vs {new}, {args.threads} threads, median of {args.repeats} subprocesses each (ms)")
    print(table(["workload", f"old ({args.base})", f"new ({new})", "new / old"], rows))
    print(describe_load(machine_load()))


if __name__ == "__main__":
    main()
