"""Writing a morph's GIF: frames quantized ahead in threads against one at a time, and the rendering alone.

A morph is fitted once per pair (the bundled 512 x 512 pair with its points; and obama3 -> breakingbad of
``morph_quality_data.py``, 1434 x 2333 frames, its points found, as ``torchfluidwarp morph obama3.jpg
breakingbad.jpg`` does), then its 30 frames are streamed three ways, in turn, ``--repeats`` times: rendered only
(``iter_frames``, the floor of writing them), into a GIF with ``io.animation``'s defaults (``QUANTIZE_AHEAD``
frames quantized in threads while the next is rendered), and into a GIF with every frame quantized in turn
(``QUANTIZE_BYTES`` set to 1 byte for the run). ``--cli``: instead, the command line on a phone's 4032 x 3024 pair
(obama and biden of ``morph_quality_data.py`` enlarged to it, as JPEGs), ``torchfluidwarp morph A B -o out.gif``
with its defaults (frames shrunk to ``--max-size`` 1080) and with ``--max-size 0``, each a fresh process: wall
time and the GIF's size. Figures: docs/benchmarks.md, "A GIF's frames quantized while the next renders".
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

from _common import finish, log, parser, start, table
from morph_quality_data import photo_path
from PIL import Image

from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import animation, read_image, write_animation
from torchfluidwarp.morph import morph


def _pairs(quick: bool) -> dict[str, Any]:
    a, b = load_sample("astronaut"), load_sample("cat")
    pairs = {"bundled 512 x 512": (a, b, load_sample_points("astronaut"), load_sample_points("cat"))}
    if not quick:
        pairs["obama3 -> breakingbad (1434 x 2333)"] = (
            read_image(photo_path("obama3")),
            read_image(photo_path("breakingbad")),
            None,
            None,
        )
    return pairs


def _write(result: Any, folder: Path, ahead: bool) -> float:
    saved = animation.QUANTIZE_BYTES
    animation.QUANTIZE_BYTES = saved if ahead else 1
    try:
        t0 = time.perf_counter()
        write_animation(folder / "morph.gif", result.iter_frames(), overwrite=True)
        return time.perf_counter() - t0
    finally:
        animation.QUANTIZE_BYTES = saved


def _render(result: Any) -> float:
    t0 = time.perf_counter()
    for _ in result.iter_frames():
        pass
    return time.perf_counter() - t0


def phone_pair(folder: Path) -> tuple[Path, Path]:
    """Two 3024 x 4032 JPEGs (a phone's portrait): obama and biden enlarged (Lanczos), biden's top cropped."""
    a, b = folder / "phone_a.jpg", folder / "phone_b.jpg"
    Image.open(photo_path("obama")).resize((3024, 4032), Image.LANCZOS).save(a, quality=90)
    with Image.open(photo_path("biden")) as im:
        tall = im.resize((3024, round(im.height * 3024 / im.width)), Image.LANCZOS)
    tall.crop((0, 0, 3024, 4032)).save(b, quality=90)
    return a, b


def command_line(folder: Path) -> list[list[str]]:
    """``torchfluidwarp morph`` on :func:`phone_pair`, by default and with ``--max-size 0``: table rows."""
    a, b = phone_pair(folder)
    rows = []
    for label, extra in (("defaults (--max-size 1080)", []), ("--max-size 0", ["--max-size", "0"])):
        out = folder / "phone.gif"
        argv = [sys.executable, "-m", "torchfluidwarp.apps.cli", "morph", str(a), str(b), "-o", str(out)]
        log(f"torchfluidwarp morph phone_a.jpg phone_b.jpg -o phone.gif {' '.join(extra)}")
        t0 = time.perf_counter()
        done = subprocess.run([*argv, "--overwrite", *extra], capture_output=True, text=True, check=True)
        seconds = time.perf_counter() - t0
        with Image.open(out) as gif:
            size = f"{gif.width} x {gif.height}"
        rows.append([label, size, f"{out.stat().st_size / 1e6:.1f}", f"{seconds:.1f}"])
        print(done.stderr.strip().splitlines()[-1])  # the command's own line
    return rows


def main() -> None:
    p = parser(__doc__, quick="the bundled pair only, 1 repeat", threads=2)
    p.add_argument("--repeats", type=int, default=3, help="rounds of the three ways (default 3)")
    p.add_argument("--cli", action="store_true", help="the command line on a phone-size pair instead")
    args = p.parse_args()
    info = start("bench_gif", args.threads)
    if args.cli:
        with tempfile.TemporaryDirectory() as tmp:
            rows = command_line(Path(tmp))
        print("\ntorchfluidwarp morph on a 3024 x 4032 pair, 30 frames (each run a fresh process)")
        print(table(["run", "frames", "GIF MB", "wall s"], rows))
        finish(info, {"cli": rows}, args.json)
        return
    repeats = 1 if args.quick else args.repeats
    rows, out = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (a, b, pa, pb) in _pairs(args.quick).items():
            log(f"fitting {name}")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the morph's own notes (crossing marks, ...) are not measured here
                result = morph(a, b, pa, pb, frames=30, progress=False)
            times: dict[str, list[float]] = {"render only": [], "GIF, quantized ahead": [], "GIF, in turn": []}
            for k in range(repeats):
                log(f"  round {k + 1} of {repeats}")
                times["render only"].append(_render(result))
                times["GIF, quantized ahead"].append(_write(result, Path(tmp), ahead=True))
                times["GIF, in turn"].append(_write(result, Path(tmp), ahead=False))
            med = {way: statistics.median(t) for way, t in times.items()}
            out[name] = {"seconds": times, "median_s": med}
            for way, s in med.items():
                rows.append(
                    [name, way, f"{s:.2f}", f"{s / med['GIF, in turn']:.2f}x", f"{s / med['render only']:.2f}x"]
                )
    print(f"\n30 frames, median of {repeats} rounds, seconds")
    print(table(["pair", "way", "seconds", "/ in turn", "/ render only"], rows))
    finish(info, {"pairs": out, "quantize_ahead": animation.QUANTIZE_AHEAD}, args.json)


if __name__ == "__main__":
    main()
