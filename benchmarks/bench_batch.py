"""Benchmark of batch morphing (#21): pairs per minute of ``morph --pairs`` with 1 and 2 processes, and whether
fitting independent problems together is faster than one after another.

(1) ``fit_keyframes`` on ``--joint`` of ``bench_keyframes.py``'s flow instances, one after another against
together (``(B, M, 2)`` points); (2) ``torchfluidwarp morph --pairs`` on ``--pairs`` jittered copies of the bundled
pair, in one process and under ``torchrun --nproc-per-node 2``. Figures: docs/benchmarks.md ("Batch throughput").
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from _common import describe_load, machine, machine_load, table

HERE = Path(__file__).resolve().parent


def joint_against_sequential(n: int, repeats: int) -> tuple[str, dict]:
    sys.path.insert(0, str(HERE))
    from _common import flow_instance

    from torchfluidwarp.control import fit_keyframes

    kwargs = dict(image_size=(64, 64), grid=(64, 64), steps=10, control=(5, 5), tolerance=0.05, progress=False)
    instances = [flow_instance(s, 14, (64, 64), 10).tensors(torch.float32) for s in range(n)]
    src = torch.stack([s for s, _ in instances])
    tgt = torch.stack([t for _, t in instances])
    fit_keyframes(src[0], tgt[0], **kwargs)  # warm-up
    seq_s, joint_s, seq_evals, joint_evals, seq_err, joint_err = [], [], [], [], 0.0, 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        fits = [fit_keyframes(s, t, **kwargs) for s, t in instances]
        seq_s.append(time.perf_counter() - t0)
        seq_evals = [f.evaluations for f in fits]
        seq_err = max(float(f.error.max()) for f in fits)
        t0 = time.perf_counter()
        joint = fit_keyframes(src, tgt, **kwargs)
        joint_s.append(time.perf_counter() - t0)
        joint_evals = [joint.evaluations]
        joint_err = float(joint.error.max())
    seq, jnt = statistics.median(seq_s), statistics.median(joint_s)
    text = "\n".join(
        [
            f"### Joint against sequential fits ({n} problems, medians of {repeats} interleaved repeats)",
            "",
            table(
                ["fits", "wall s", "evaluations", "max error px", "s per problem"],
                [
                    [
                        "one after another",
                        f"{seq:.3f}",
                        "+".join(map(str, seq_evals)),
                        f"{seq_err:.4f}",
                        f"{seq / n:.3f}",
                    ],
                    [f"together (B = {n})", f"{jnt:.3f}", str(joint_evals[0]), f"{joint_err:.4f}", f"{jnt / n:.3f}"],
                ],
            ),
            "",
            f"together / one after another: {jnt / seq:.2f}x the time",
        ]
    )
    return text, {"sequential_s": seq, "joint_s": jnt, "ratio": jnt / seq}


def make_pairs(folder: Path, n: int, size: int) -> Path:
    """``n`` pairs of the bundled samples at ``size x size`` with per-pair jittered points, and their CSV."""
    from torchfluidwarp.core.grid import rescale_points, scale_factor
    from torchfluidwarp.data import load_sample, load_sample_points
    from torchfluidwarp.io import write_image, write_points

    rows = ["image_a,image_b,points_a,points_b,name"]
    points = {}
    for name in ("astronaut", "cat"):
        image = load_sample(name)
        small = F.interpolate(image, size=(size, size), mode="bilinear", antialias=True, align_corners=False)
        write_image(folder / f"{name}.png", small[0].clamp(0, 1))
        scale = scale_factor(tuple(image.shape[-2:]), (size, size), dtype=torch.float64)
        points[name] = rescale_points(load_sample_points(name).double(), scale)
    for k in range(n):
        gen = torch.Generator().manual_seed(k)
        for name, pts in points.items():
            jittered = (pts + (torch.rand(pts.shape, generator=gen, dtype=torch.float64) * 4 - 2)).clamp(2, size - 3)
            write_points(folder / f"{name}{k}.json", jittered)
        rows.append(f"astronaut.png,cat.png,astronaut{k}.json,cat{k}.json,pair{k}")
    (folder / "pairs.csv").write_text("\n".join(rows) + "\n")
    return folder / "pairs.csv"


def throughput(pairs: Path, out: Path, frames: int, processes: int) -> dict:
    args = ["morph", "--pairs", str(pairs), "--out", str(out), "--frames", str(frames), "--quiet"]
    if processes == 1:
        cmd = [sys.executable, "-m", "torchfluidwarp.apps.cli", *args]
        env = dict(os.environ)
    else:
        cmd = [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nproc-per-node",
            str(processes),
            "-m",
            "torchfluidwarp.apps.cli",
            *args,
        ]
        env = {**os.environ, "CUDA_VISIBLE_DEVICES": ""}
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-3000:]}")
    with open(out / "summary.csv", newline="") as fp:
        summary = list(csv.DictReader(fp))
    morphed = [r for r in summary if r["status"] == "morphed"]
    return {
        "processes": processes,
        "wall_s": wall,
        "pairs": len(morphed),
        "pairs_per_min": 60 * len(morphed) / wall,
        "median_pair_s": statistics.median(float(r["seconds"]) for r in morphed),
        "max_error_px": max(float(r["error_max_px"]) for r in morphed),
        "command": " ".join(
            ["torchfluidwarp" if processes == 1 else "torchrun --nproc-per-node 2 -m torchfluidwarp.apps.cli", *args]
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=8, help="pairs in the CSV (default 8)")
    parser.add_argument("--size", type=int, default=256, help="side of the images, pixels (default 256)")
    parser.add_argument("--frames", type=int, default=30, help="frames per morph (default 30)")
    parser.add_argument("--joint", type=int, default=4, help="problems fitted together (default 4; 0 skips)")
    parser.add_argument("--repeats", type=int, default=3, help="repeats of the joint comparison (default 3)")
    args = parser.parse_args()
    info = machine()
    print(f"# {info['cpu']} ({info['cpu_count']} CPUs), torch {info['torch']}, {info['date']}")
    print(f"# at the start: {describe_load(machine_load())}")
    if args.joint:
        torch.set_num_threads(1)
        text, _ = joint_against_sequential(args.joint, args.repeats)
        print("\n" + text + " (1 torch thread)", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "in").mkdir()
        pairs = make_pairs(folder / "in", args.pairs, args.size)
        runs = [throughput(pairs, folder / f"out{p}", args.frames, p) for p in (1, 2)]
    print(f"\n### Throughput: {args.pairs} pairs of {args.size} x {args.size}, {args.frames} frames each, GIF\n")
    print(
        table(
            ["processes", "wall s", "pairs", "pairs/min", "median s a pair", "max landmark error px"],
            [
                [
                    str(r["processes"]),
                    f"{r['wall_s']:.1f}",
                    str(r["pairs"]),
                    f"{r['pairs_per_min']:.1f}",
                    f"{r['median_pair_s']:.1f}",
                    f"{r['max_error_px']:.3f}",
                ]
                for r in runs
            ],
        )
    )
    print(f"\n2 processes / 1: {runs[1]['pairs_per_min'] / runs[0]['pairs_per_min']:.2f}x the pairs per minute")
    for r in runs:
        print(f"#   {r['command']}")
    print(f"# at the end: {describe_load(machine_load())}")


if __name__ == "__main__":
    main()
