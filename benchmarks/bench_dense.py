"""The pixels' alignment between the marks (``NaturalSettings.dense``) on known deformations, and what it costs.

Each pair is a bundled photograph ``A`` (astronaut, cat) at ``--size`` pixels and ``B(x) = g A(x + u(x)) + o``:
``u`` is a sum of 10 Gaussian bumps (seeded, up to 6 px in each component, 1/12 of the picture wide), and
``g, o`` change the brightness and contrast (``-0.7, 0.9`` inverts it). The marks are 9 points of a lattice,
either "clustered" in the middle third (like a face's marks: the bumps lie around them) or "spread" over the
picture (the bumps lie between them); the held-out points are a 12 x 12 lattice. The figure is the mean distance,
in the last frame, between where the morph reads A for a held-out point of B (``result.maps[-1]``) and the truth
``x + u(x)``, against no motion at all and the marks alone (``dense=None``). Then the time of a 30-frame
512 x 512 morph of the bundled pair (call and frames) with and without the pixels' alignment (``--threads``,
default 2).
"""

from __future__ import annotations

import sys
import time

import torch
import torch.nn.functional as F
from _common import finish, log, parser, start, table
from torch import Tensor

from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.morph import morph
from torchfluidwarp.morph.settings import NaturalSettings
from torchfluidwarp.warp import warp_image


def _grid(values: list[float]) -> Tensor:
    v = torch.tensor(values, dtype=torch.float64)
    return torch.stack(torch.meshgrid(v, v, indexing="xy"), -1).reshape(-1, 2)


def _read(field: Tensor, points: Tensor) -> Tensor:
    """``field`` ``(H, W, 2)`` read bilinearly at pixels ``points`` ``(N, 2)``."""
    H, W = field.shape[:2]
    g = torch.stack([(2 * points[:, 0] + 1) / W - 1, (2 * points[:, 1] + 1) / H - 1], -1).view(1, 1, -1, 2)
    out = F.grid_sample(field.permute(2, 0, 1)[None].double(), g, padding_mode="border", align_corners=False)
    return out[0, :, 0].T


def known_pair(name: str, size: int, seed: int, marks: str, tone: tuple[float, float]) -> dict[str, Tensor]:
    a = F.interpolate(load_sample(name), size=(size, size), mode="bilinear", antialias=True, align_corners=False)
    gen = torch.Generator().manual_seed(seed)
    axis = torch.arange(size, dtype=torch.float64)
    yy, xx = torch.meshgrid(axis, axis, indexing="ij")
    u = torch.zeros(size, size, 2, dtype=torch.float64)
    for _ in range(10):
        cx, cy = (0.1 + 0.8 * torch.rand(2, generator=gen, dtype=torch.float64)) * size
        amp = (torch.rand(2, generator=gen, dtype=torch.float64) - 0.5) * 2 * 6.0  # px, each component
        u += torch.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * (size / 12) ** 2))[..., None] * amp
    coords = (torch.stack([xx, yy], -1) + u)[None]  # B at x reads A at x + u(x)
    b = tone[0] * warp_image(a.double(), coords).float() + tone[1]
    s = size / 96
    lattice = [12.0, 48.0, 84.0] if marks == "spread" else [36.0, 48.0, 60.0]
    pb = _grid([v * s for v in lattice])
    held = _grid([(4 + 8 * i) * s for i in range(12)])
    return {"a": a, "b": b, "pa": pb + _read(u, pb), "pb": pb, "ha": held + _read(u, held), "hb": held}


def held_error(pair: dict[str, Tensor], dense: bool) -> tuple[float, int, float]:
    settings = NaturalSettings() if dense else NaturalSettings(dense=None)
    t0 = time.perf_counter()
    r = morph(pair["a"], pair["b"], pair["pa"], pair["pb"], settings=settings, frames=5, progress=False)
    seconds = time.perf_counter() - t0
    err = (_read(r.maps[-1], pair["hb"]) - pair["ha"]).norm(dim=1).mean()
    return float(err), int(r.folded), seconds


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="one pair of each kind at 128 px, no timing", threads=2)
    p.add_argument("--size", type=int, default=256, help="pictures' side in pixels (default 256)")
    args = p.parse_args(argv)
    size = 128 if args.quick else args.size
    info = start("bench_dense", args.threads, " [--quick]" if args.quick else "")
    tones = {"same": (0.8, 0.1), "contrast": (0.5, 0.3), "inverted": (-0.7, 0.9)}
    rows, results = [], []
    for name in ("astronaut",) if args.quick else ("astronaut", "cat"):
        for marks in ("clustered", "spread"):
            for tone in ("same",) if args.quick else tuple(tones):
                pair = known_pair(name, size, seed=1, marks=marks, tone=tones[tone])
                none = float((pair["ha"] - pair["hb"]).norm(dim=1).mean())
                spline, folded_s, _ = held_error(pair, dense=False)
                dense, folded_d, seconds = held_error(pair, dense=True)
                log(f"  {name} {marks} {tone}: none {none:.2f}, alone {spline:.2f}, pixels {dense:.2f} px")
                rows.append([name, marks, tone, f"{none:.2f}", f"{spline:.2f}", f"{dense:.2f}", f"{dense / none:.2f}x",
                             f"{folded_s} / {folded_d}"])  # fmt: skip
                results.append({"name": name, "marks": marks, "tone": tone, "none": none, "spline": spline,
                                "dense": dense, "folded": [folded_s, folded_d], "seconds": seconds})  # fmt: skip
    head = ["picture", "marks", "tone", "no motion", "marks alone", "with pixels", "ratio"]
    head.append("folded px (alone / pixels)")
    print(f"\nheld-out end error, px ({size} x {size}, 12 x 12 held-out points)\n")
    print(table(head, rows, markdown=True))
    timing = {}
    if not args.quick:
        a, b = load_sample("astronaut"), load_sample("cat")
        pa, pb = load_sample_points("astronaut"), load_sample_points("cat")
        for label, settings in (("marks alone", NaturalSettings(dense=None)), ("with pixels", NaturalSettings())):
            best = []
            for _ in range(2):
                t0 = time.perf_counter()
                r = morph(a, b, pa, pb, settings=settings, frames=30, progress=False)
                t1 = time.perf_counter()
                for _frame in r.iter_frames():
                    pass
                best.append((t1 - t0, time.perf_counter() - t1))
            call, frames = min(best, key=sum)
            timing[label] = dict(call=call, frames=frames, total=call + frames)
            print(f"30-frame 512 x 512 morph, {label}: call {call:.2f} s + frames {frames:.2f} s = "
                  f"{call + frames:.2f} s")  # fmt: skip
    finish(info, {"size": size, "pairs": results, "timing": timing}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
