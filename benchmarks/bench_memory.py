"""Peak memory of a 6000 x 6000 morph through the command line (#31, item 8: within 3 GB).

Makes a pair of photographs (the bundled astronaut and cat upscaled to ``--size``, with seeded noise, as JPEGs) and
their points, then measures, each in a fresh process, the peak resident set (``VmHWM``, the whole process as
``/usr/bin/time -v`` reports it, torch's import included): importing torch alone (the floor), decoding the two
files (:func:`torchfluidwarp.io.read_image`), and ``torchfluidwarp morph A B --points-a --points-b --frames N -o
OUT`` for each output format asked for. Figures: docs/benchmarks.md, "Any size".
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import finish, log, parser, start, table, verdict

TARGET = 3e9  # bytes: the 3 GB

# each child prints its own peak as its last line: VmHWM of a fresh process (exec starts a new address space)
PEAK = "print(next(line.split()[1] for line in open('/proc/self/status') if line.startswith('VmHWM:')))"
CHILDREN = {
    "import torch": "import torch\n" + PEAK,
    "decode A and B": "import sys\nfrom torchfluidwarp.io import read_image\n"
    "images = [read_image(path) for path in sys.argv[1:3]]\n" + PEAK,
    "morph": "import sys\nfrom torchfluidwarp.apps.cli import main\nrc = main(sys.argv[1:])\n"
    "assert rc == 0, rc\n" + PEAK,
}


def make_pair(folder: Path, size: int, seed: int = 0) -> list[str]:
    """The bundled astronaut and cat resized to ``size x size`` (bicubic) with uniform noise of +-8 levels (a
    camera's grain: JPEG cannot squeeze the upscaled smoothness away), as JPEGs of quality 90, and their points
    scaled (pixel centres at integers); returns the paths ``[A, B, points A, points B]``."""
    import numpy as np
    from PIL import Image

    from torchfluidwarp.data import load_sample, load_sample_points
    from torchfluidwarp.io import write_points

    rng = np.random.default_rng(seed)
    paths = []
    for name in ("astronaut", "cat"):
        pixels = (load_sample(name)[0].permute(1, 2, 0) * 255).round().byte().numpy()  # (H, W, 3)
        small = Image.fromarray(pixels)
        big = np.asarray(small.resize((size, size), Image.Resampling.BICUBIC)).astype(np.int16)
        big += rng.integers(-8, 9, size=big.shape, dtype=np.int16)
        Image.fromarray(big.clip(0, 255).astype(np.uint8)).save(folder / f"{name}.jpg", quality=90)
        del big
        scale = size / small.width
        write_points(folder / f"{name}.pts", (load_sample_points(name).double() + 0.5) * scale - 0.5)
        paths.append(str(folder / f"{name}.jpg"))
    return [*paths, str(folder / "astronaut.pts"), str(folder / "cat.pts")]


def peak(child: str, argv: list[str]) -> dict[str, float]:
    """Run ``child`` in a fresh interpreter with ``argv``; its peak RSS (bytes) and wall seconds."""
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", CHILDREN[child], *argv], capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if out.returncode != 0:
        raise RuntimeError(f"{child} {' '.join(argv)} failed ({out.returncode}):\n{out.stderr[-3000:]}")
    return {"peak_bytes": 1024 * float(out.stdout.split()[-1]), "seconds": seconds}


def main() -> None:
    p = parser(__doc__, quick="a 1500 x 1500 pair, 3 frames", threads=None)
    p.add_argument("--size", type=int, default=6000, help="side of the pair, pixels (default 6000)")
    p.add_argument("--frames", type=int, default=5, help="frames of each morph (default 5)")
    p.add_argument(
        "--formats", default="gif", help="outputs, comma-separated from gif, mp4, png (PNG frames; default gif)"
    )
    args = p.parse_args()
    size, frames = (1500, 3) if args.quick else (args.size, args.frames)
    info = start("bench_memory", args.threads)
    rows, result = [], {"size": size, "frames": frames, "runs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        log(f"writing the {size} x {size} pair")
        a, b, pa, pb = make_pair(folder, size)
        runs = [("import torch", "import torch", []), ("decode A and B", "decode A and B", [a, b])]
        for fmt in args.formats.split(","):
            out = str(folder / ("frames/" if fmt == "png" else f"morph.{fmt}"))
            argv = ["morph", a, b, "--points-a", pa, "--points-b", pb, "--frames", str(frames), "-o", out, "-q"]
            argv += ["--max-size", "0"]  # the frames at the pictures' own 6000 x 6000, as the GIF's default is not
            runs.append((f"morph -o {Path(out).name}{'/' if fmt == 'png' else ''}", "morph", argv))
        for label, child, argv in runs:
            log(f"{label} ...")
            r = result["runs"][label] = peak(child, argv)
            log(f"{label}: {r['peak_bytes'] / 1e9:.2f} GB in {r['seconds']:.0f} s")
            gb, gib = r["peak_bytes"] / 1e9, r["peak_bytes"] / 2**30
            rows.append([label, f"{gb:.2f} GB", f"{gib:.2f} GiB", f"{r['seconds']:.0f}"])
    print(f"\n{size} x {size} JPEG pair, --frames {frames}; peak RSS of each fresh process (VmHWM, torch included):")
    print(table(["run", "peak RSS", "", "wall s"], rows))
    worst = max(r["peak_bytes"] for k, r in result["runs"].items() if k.startswith("morph"))
    print(f"\nlargest morph: {worst / 1e9:.2f} GB (target within {TARGET / 1e9:g} GB: {verdict(worst <= TARGET)})")
    finish(info, result, args.json)


if __name__ == "__main__":
    main()
