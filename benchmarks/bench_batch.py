"""Benchmark of batch morphing (#21): pairs per minute of ``morph --pairs`` with 1 and 2 processes, and whether
fitting independent problems together is faster than one after another.

(1) ``fit_keyframes`` on ``--joint`` of ``bench_keyframes.py``'s flow instances, one after another against
together (``(B, M, 2)`` points); (2) ``torchfluidwarp morph --pairs`` on ``--pairs`` jittered copies of the bundled
pair, in one process and under ``torchrun --nproc-per-node 2``. Figures: docs/benchmarks.md ("Batch throughput").
"""

from __future__ import annotations

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
from _common import finish, flow_instance, parser, rows_table, start, write_samples

from torchfluidwarp.control import fit_keyframes


def joint_against_sequential(n: int, repeats: int) -> dict:
    """``n`` of the paper's flow instances (float32) fitted one after another and as one ``(n, M, 2)`` call."""
    kwargs = dict(image_size=(64, 64), grid=(64, 64), steps=10, control=(5, 5), tolerance=0.05, progress=False)
    instances = [flow_instance(s, 14, (64, 64), 10).tensors(torch.float32) for s in range(n)]
    src = torch.stack([s for s, _ in instances])
    tgt = torch.stack([t for _, t in instances])
    fit_keyframes(src[0], tgt[0], **kwargs)  # warm-up
    seq_s, joint_s = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fits = [fit_keyframes(s, t, **kwargs) for s, t in instances]
        seq_s.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        joint = fit_keyframes(src, tgt, **kwargs)
        joint_s.append(time.perf_counter() - t0)
    seq, jnt = statistics.median(seq_s), statistics.median(joint_s)
    rows = [dict(fits="one after another", s=seq, evals="+".join(str(f.evaluations) for f in fits),
                 err=max(float(f.error.max()) for f in fits)),
            dict(fits=f"together (B = {n})", s=jnt, evals=str(joint.evaluations),
                 err=float(joint.error.max()))]  # fmt: skip
    print(f"\n### Joint against sequential fits ({n} problems, medians of {repeats} interleaved repeats)\n")
    print(rows_table([dict(r, per=r["s"] / n) for r in rows], "fits {fits} | wall s {s:.3f} | evaluations {evals} | "
                     "max error px {err:.4f} | s per problem {per:.3f}"))  # fmt: skip
    print(f"\ntogether / one after another: {jnt / seq:.2f}x the time (1 torch thread)", flush=True)
    return {"sequential_s": seq, "joint_s": jnt, "ratio": jnt / seq}


def make_pairs(folder: Path, n: int, size: int) -> Path:
    """``n`` pairs of the bundled samples at ``size x size`` with per-pair jittered points, and their CSV."""
    from torchfluidwarp.io import write_points

    points = write_samples(folder, size)
    rows = ["image_a,image_b,points_a,points_b,name"]
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
    cli = ["-m", "torchfluidwarp.apps.cli", *args]
    if processes == 1:
        cmd, env = [sys.executable, *cli], dict(os.environ)
    else:
        cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", str(processes), *cli]
        env = {**os.environ, "CUDA_VISIBLE_DEVICES": ""}
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-3000:]}")
    with open(out / "summary.csv", newline="") as fp:
        morphed = [r for r in csv.DictReader(fp) if r["status"] == "morphed"]
    shown = "torchfluidwarp" if processes == 1 else "torchrun --nproc-per-node 2 -m torchfluidwarp.apps.cli"
    return dict(processes=processes, wall_s=wall, pairs=len(morphed), pairs_per_min=60 * len(morphed) / wall,
                median_pair_s=statistics.median(float(r["seconds"]) for r in morphed),
                max_error_px=max(float(r["error_max_px"]) for r in morphed),
                command=" ".join([shown, *args]))  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, threads=None)
    p.add_argument("--pairs", type=int, default=8, help="pairs in the CSV (default 8)")
    p.add_argument("--size", type=int, default=256, help="side of the images, pixels (default 256)")
    p.add_argument("--frames", type=int, default=30, help="frames per morph (default 30)")
    p.add_argument("--joint", type=int, default=4, help="problems fitted together (default 4; 0 skips)")
    p.add_argument("--repeats", type=int, default=3, help="repeats of the joint comparison (default 3)")
    args = p.parse_args(argv)
    info = start("bench_batch", args.threads)
    result: dict = {"args": vars(args)}
    if args.joint:
        torch.set_num_threads(1)
        result["joint"] = joint_against_sequential(args.joint, args.repeats)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "in").mkdir()
        pairs = make_pairs(folder / "in", args.pairs, args.size)
        runs = result["throughput"] = [throughput(pairs, folder / f"out{p}", args.frames, p) for p in (1, 2)]
    print(f"\n### Throughput: {args.pairs} pairs of {args.size} x {args.size}, {args.frames} frames each, GIF\n")
    print(rows_table(runs, "processes {processes} | wall s {wall_s:.1f} | pairs {pairs} | pairs/min "
                     "{pairs_per_min:.1f} | median s a pair {median_pair_s:.1f} | max landmark error px "
                     "{max_error_px:.3f}"))  # fmt: skip
    print(f"\n2 processes / 1: {runs[1]['pairs_per_min'] / runs[0]['pairs_per_min']:.2f}x the pairs per minute")
    for r in runs:
        print(f"#   {r['command']}")
    finish(info, result, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
