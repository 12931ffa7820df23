"""Benchmark of memory at scale (#21): peak RSS of the command line as the frame count and the image size grow.

Each configuration in a fresh process (``VmHWM`` reset after importing torch): ``torchfluidwarp demo --frames 30``
against ``--frames --long`` (target: within 10%), and a 6000 x 6000 pair, ``--frames 3`` (target: under 3 GB;
``--profile`` lists the operators that allocate most). Figures: docs/benchmarks.md, "Scale".
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import describe_load, machine, machine_load, table, verdict

HERE = Path(__file__).resolve().parent

CHILD = """
import json, sys, time
sys.path.insert(0, {here!r})
from _common import reset_peak, status_kib
reset_peak()
from torchfluidwarp.apps.cli import main
t0 = time.perf_counter()
rc = main(sys.argv[1:])
print(json.dumps({{"rc": rc, "seconds": time.perf_counter() - t0, "peak_kib": status_kib("VmHWM")}}))
"""

PROFILE = """
import sys, torch
from torch.profiler import ProfilerActivity, profile
from torchfluidwarp.io import read_image, read_points
from torchfluidwarp.morph import morph
a, b = read_image(sys.argv[1]), read_image(sys.argv[2])
pa, pb = read_points(sys.argv[3]), read_points(sys.argv[4])
result = morph(a, b, pa, pb, frames=3, max_memory=64 * 2**30)
with profile(activities=[ProfilerActivity.CPU], profile_memory=True) as prof:
    for frame in result.iter_frames(chunk=1):
        del frame
print(prof.key_averages().table(sort_by="self_cpu_memory_usage", row_limit=12))
"""


def run(argv: list[str]) -> dict:
    """``torchfluidwarp ARGV`` in a fresh process: its exit status, wall seconds and peak RSS (KiB).

    Each result is printed as it comes (a long run can be stopped and the figures so far are kept)."""
    out = subprocess.run(
        [sys.executable, "-c", CHILD.format(here=str(HERE)), *argv], capture_output=True, text=True, check=False
    )
    lines = [line for line in out.stdout.splitlines() if line.startswith("{")]
    if not lines:
        raise RuntimeError(f"torchfluidwarp {' '.join(argv)} failed:\n{out.stderr[-2000:]}")
    result = json.loads(lines[-1])
    if result["rc"] != 0:
        raise RuntimeError(f"torchfluidwarp {' '.join(argv)} exited {result['rc']}:\n{out.stderr[-2000:]}")
    print(f"# torchfluidwarp {' '.join(argv)}: {json.dumps(result)}", flush=True)
    return result


def large_pair(folder: Path, size: int) -> list[str]:
    """The bundled samples upscaled to ``size x size`` with their points; returns the ``morph`` arguments."""
    import torch.nn.functional as F

    from torchfluidwarp.core.grid import rescale_points, scale_factor
    from torchfluidwarp.data import load_sample, load_sample_points
    from torchfluidwarp.io import write_image, write_points

    paths = []
    for name in ("astronaut", "cat"):
        image = load_sample(name)
        big = F.interpolate(image, size=(size, size), mode="bicubic", align_corners=False).clamp(0, 1)
        write_image(folder / f"{name}.png", big[0])
        scale = scale_factor(tuple(image.shape[-2:]), (size, size), dtype=torch_float64())
        write_points(folder / f"{name}.json", rescale_points(load_sample_points(name).double(), scale))
        paths.append(folder / name)
        del big
    a, b = paths
    return [f"{a}.png", f"{b}.png", "--points-a", f"{a}.json", "--points-b", f"{b}.json"]


def torch_float64():
    import torch

    return torch.float64


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--long", type=int, default=3000, help="frames of the long demo (default 3000)")
    parser.add_argument("--size", type=int, default=6000, help="side of the large pair (default 6000)")
    parser.add_argument("--skip-large", action="store_true", help="only the 512 x 512 runs")
    parser.add_argument("--profile", action="store_true", help="profile the large morph's render")
    args = parser.parse_args()
    info = machine()
    print(f"# {info['cpu']} ({info['cpu_count']} CPUs, {info['torch_threads']} torch threads), torch {info['torch']}")
    print(f"# {describe_load(machine_load())}")
    rows, figures = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for frames in (30, args.long):
            argv = ["demo", "--frames", str(frames), "-o", str(folder / f"demo{frames}.gif"), "--quiet"]
            figures[frames] = r = run(argv)
            rows.append(
                [
                    "torchfluidwarp " + " ".join(argv[:3]),
                    f"{r['peak_kib'] / 2**20:.2f} GiB",
                    f"{r['seconds']:.1f} s",
                    f"{frames / r['seconds']:.1f}",
                ]
            )
        small, long = figures[30], figures[args.long]
        ratio = long["peak_kib"] / small["peak_kib"]
        rate = (args.long - 30) / max(long["seconds"] - small["seconds"], 1e-9)
        if not args.skip_large:
            (folder / "big").mkdir()
            pair = large_pair(folder / "big", args.size)
            argv = ["morph", *pair, "--frames", "3", "--max-memory", "64", "-o", str(folder / "big.gif"), "--quiet"]
            t0 = time.perf_counter()
            big = run(argv)
            rows.append(
                [
                    f"morph {args.size}x{args.size} --frames 3",
                    f"{big['peak_kib'] / 2**20:.2f} GiB",
                    f"{big['seconds']:.1f} s",
                    f"{3 / big['seconds']:.2f}",
                ]
            )
            print(f"# large pair written and morphed in {time.perf_counter() - t0:.0f} s")
            if args.profile:
                prof = subprocess.run(
                    [sys.executable, "-c", PROFILE, *pair[:2], pair[3], pair[5]], capture_output=True, text=True
                )
                print(prof.stdout or prof.stderr[-3000:])
    print(table(["command", "peak RSS", "wall", "frames/s"], rows))
    print(
        f"\n30 vs {args.long} frames: peak RSS ratio {ratio:.3f} "
        f"(target within 10%: {verdict(abs(ratio - 1) <= 0.10)}); marginal rate {rate:.1f} frames/s"
    )
    if not args.skip_large:
        print(
            f"{args.size} x {args.size}, 3 frames: {big['peak_kib'] / 2**20:.2f} GiB "
            f"(target < 3 GB: {verdict(big['peak_kib'] * 1024 < 3e9)})"
        )


if __name__ == "__main__":
    main()
