"""Benchmark of memory at scale (#21): peak RSS of the command line as the frame count and the image size grow.

Each configuration in a fresh process (``VmHWM`` reset after importing torch): ``torchfluidwarp demo --frames 30``
against ``--frames --long`` (target: within 10%). The 6000 x 6000 pair it also ran (at ``d33a341``) is
``bench_memory.py``'s now. Figures: docs/benchmarks.md, "Scale".
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from _common import finish, parser, start, table, verdict

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


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, threads=None)
    p.add_argument("--long", type=int, default=3000, help="frames of the long demo (default 3000)")
    args = p.parse_args(argv)
    info = start("bench_scale", args.threads)
    rows, figures = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for frames in (30, args.long):
            argv = ["demo", "--frames", str(frames), "-o", str(folder / f"demo{frames}.gif"), "--quiet"]
            r = figures[frames] = run(argv)
            rows.append([f"torchfluidwarp {' '.join(argv[:3])}", f"{r['peak_kib'] / 2**20:.2f} GiB",
                         f"{r['seconds']:.1f} s", f"{frames / r['seconds']:.1f}"])  # fmt: skip
    print(table(["command", "peak RSS", "wall", "frames/s"], rows))
    small, long = figures[30], figures[args.long]
    ratio = long["peak_kib"] / small["peak_kib"]
    rate = (args.long - 30) / max(long["seconds"] - small["seconds"], 1e-9)
    print(f"\n30 vs {args.long} frames: peak RSS ratio {ratio:.3f} (target within 10%: "
          f"{verdict(abs(ratio - 1) <= 0.10)}); marginal rate {rate:.1f} frames/s")  # fmt: skip
    finish(info, {"args": vars(args), "runs": {str(k): v for k, v in figures.items()}}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
