"""Benchmark of #23's sequences and averages at 512 x 512: the time of a 5-image sequence and of a 10-image average.

The bundled astronaut and cat and copies under mild known affine maps: ``morph_sequence`` over five images (fit
and total time) and ``average`` of ten (time, folded fraction, point error). Figures: docs/benchmarks.md, "Morph
features".
"""

from __future__ import annotations

import math
import sys
import time

import torch
import torch.nn.functional as F
from _common import finish, load_pair, parser, start

from torchfluidwarp.morph import average, morph_sequence


def affine_copy(image: torch.Tensor, points: torch.Tensor, angle: float, scale: float, shift: tuple[float, float]):
    """``image`` (1, C, H, W) under the map ``p -> R(angle) * scale * (p - c) + c + shift`` (pixels, c the centre),
    and ``points`` (M, 2) moved by it."""
    H, W = image.shape[-2:]
    c = torch.tensor([(W - 1) / 2, (H - 1) / 2], dtype=torch.float64)
    a = math.radians(angle)
    m = scale * torch.tensor([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]], dtype=torch.float64)
    t = torch.tensor(shift, dtype=torch.float64)
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    out = torch.stack([xs, ys], -1)  # output pixels y; read the source at m^-1 (y - c - t) + c
    src = (out - c - t) @ torch.linalg.inv(m).T + c
    grid = torch.stack([(src[..., 0] + 0.5) / W * 2 - 1, (src[..., 1] + 0.5) / H * 2 - 1], -1)
    warped = F.grid_sample(image, grid[None].float(), mode="bilinear", padding_mode="border", align_corners=False)
    moved = (points.double() - c) @ m.T + c + t
    return warped, moved.to(points.dtype)


MAPS = [(0.0, 1.0, (0.0, 0.0)), (1.0, 0.96, (4.0, -3.0)), (-1.0, 0.97, (-3.0, 4.0)), (0.5, 0.95, (-4.0, -4.0)),
        (-0.5, 0.96, (3.0, 3.0))]  # fmt: skip
"""(degrees, scale, shift in pixels) of each copy: mild, and they keep the cat's border points inside the picture."""


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="the images at 128x128, 6 frames, an average of 4", threads=None)
    p.add_argument("--frames", type=int, default=60, help="frames of the sequence (default 60)")
    args = p.parse_args(argv)
    size, frames = (128, 6) if args.quick else (None, args.frames)
    a, b, pa, pb = load_pair(size)
    samples = {"astronaut": (a, pa), "cat": (b, pb)}
    copies = {name: [affine_copy(img, pts, *m) for m in MAPS] for name, (img, pts) in samples.items()}
    info = start("bench_morph_features", args.threads, " [--quick]" if args.quick else "")
    side = a.shape[-1]
    order = [copies["astronaut"][0], copies["cat"][0], copies["astronaut"][1], copies["cat"][1], copies["astronaut"][2]]
    t0 = time.perf_counter()
    seq = morph_sequence([im for im, _ in order], [p for _, p in order], frames=frames, progress=False)
    fitted = time.perf_counter() - t0
    count = sum(1 for _ in seq.iter_frames())
    total = time.perf_counter() - t0
    print(f"sequence of 5 images at {side}x{side}, {count} frames: fit {fitted:.1f} s, total with frames {total:.1f} s")
    ten = (copies["astronaut"][:2] + copies["cat"][:2]) if args.quick else copies["astronaut"] + copies["cat"]
    t0 = time.perf_counter()
    mean = average([im for im, _ in ten], [p for _, p in ten], progress=False)
    seconds = time.perf_counter() - t0
    print(f"average of {len(ten)} images at {side}x{side}: {seconds:.1f} s, folded {mean.folded:.2e}, "
          f"mean point error {float(mean.errors.mean()):.2f} px")  # fmt: skip
    result = dict(sequence=dict(frames=count, fit_s=fitted, total_s=total), average=dict(
        images=len(ten), seconds=seconds, folded=mean.folded, error_px=float(mean.errors.mean())))  # fmt: skip
    finish(info, result, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
