"""A/B of one change to :meth:`FluidWarp.forward` (issue #20): how its output's new pages get mapped in.

Before (``15eff07``), a worker thread wrote one element per 4 KiB page of each frame's slot of the output while
the caller sampled the previous frame; now (``cbc73eb``) the output is zeroed up front, on all of torch's threads.
Both are run in one process, alternating, on the 600x600 set-up of ``bench_warp.py`` (its brushes and image, a
64x64 fluid, 60 frames, no grad), with the floor (one ``grid_sample`` of the frame through the last frame's map)
in the same repeats. The old ``forward`` is the file of ``15eff07`` (read with ``git show``), imported as a module
beside the installed package, so this script needs the repository's history.

Usage: ``python benchmarks/ab_forward_output.py 2,16`` (torch thread counts, measured in turn; default 1,2).
"""

from __future__ import annotations

import importlib.util
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

import torch
from bench_warp import FLUID, make_brushes, make_image

from torchfluidwarp.warp import FluidWarp

BEFORE = "15eff07"
SIZE, STEPS, REPEATS = (600, 600), 60, 9


def old_layer() -> object:
    root = pathlib.Path(__file__).resolve().parent.parent
    source = subprocess.run(
        ["git", "show", f"{BEFORE}:torchfluidwarp/warp/layer.py"], cwd=root, check=True, capture_output=True, text=True
    ).stdout
    path = pathlib.Path(tempfile.mkdtemp()) / "old_layer.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("old_layer", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main() -> None:
    threads = [int(t) for t in (sys.argv[1] if len(sys.argv) > 1 else "1,2").split(",")]
    old = old_layer()
    image, brushes = make_image(SIZE), make_brushes(SIZE)
    warps = {
        f"before ({BEFORE})": old.FluidWarp(FLUID, STEPS, image_size=SIZE),
        "now": FluidWarp(FLUID, STEPS, image_size=SIZE),
    }  # type: ignore[attr-defined]
    for n in threads:
        torch.set_num_threads(n)
        times: dict[str, list[float]] = {"floor": [], **{k: [] for k in warps}}
        with torch.no_grad():
            maps = warps["now"].maps(brushes, SIZE)
            grid = ((maps[:, -1] + 0.5) / torch.tensor([SIZE[1], SIZE[0]]) * 2 - 1).contiguous()
            for _ in range(REPEATS):
                t0 = time.perf_counter()
                for _ in range(STEPS):
                    torch.nn.functional.grid_sample(image, grid, padding_mode="border", align_corners=False)
                times["floor"].append((time.perf_counter() - t0) / STEPS * 1e3)
                for name, warp in warps.items():
                    t0 = time.perf_counter()
                    warp(image, brushes)
                    times[name].append((time.perf_counter() - t0) / STEPS * 1e3)
        floor = statistics.median(times["floor"])
        for name, ms in times.items():
            m = statistics.median(ms)
            runs = [round(x, 1) for x in ms]
            print(f"threads {n}: {name:16s} median {m:.2f} ms a frame, {m / floor:.2f}x the floor; {runs}")


if __name__ == "__main__":
    main()
