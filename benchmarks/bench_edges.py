"""Clean edges (issue #31, item 4): does a picture's border show as a line, or is anything smeared beyond it, in
any frame of a morph? The fluid ``morph()`` against a thin-plate spline and a Delaunay morph of the same marks.

Pairs: the demo (astronaut -> cat, 512 x 512, as ``torchfluidwarp demo``), and pictures of different framing,
each placed on A's canvas by one scale factor (cover, the crop centred on its marks): a square A with a 3:2
landscape B (the cat -> the astronaut's upper third, 300 x 200), a square A with a 150 x 225 portrait B and a 2:3
portrait A with a 3:2 landscape B (faces of ``morph_quality_data.py``, 68 marks each; fetched on first use). The
classical morphs go to the average shape on the same canvas (B's marks placed on it) and dissolve with
``warp_image`` (edge pixels held beyond a picture). The figures are
``torchfluidwarp.metrics.edges.border_seam``'s, worst over the frames.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from _common import finish, fmt, log, parser, start, table
from bench_morph_quality import classical_maps
from torch import Tensor

from torchfluidwarp.control import apply_alignment
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import write_image
from torchfluidwarp.metrics.edges import border_seam
from torchfluidwarp.morph import morph
from torchfluidwarp.morph.morphing import placement
from torchfluidwarp.warp import warp_image

METHODS = ("fluid", "tps", "delaunay")
Pair = tuple[Tensor, Tensor, Tensor, Tensor]  # image A (1, 3, H, W), image B, marks of A (M, 2), marks of B


def reframe(image: Tensor, points: Tensor, box: tuple[int, int, int, int], size: tuple[int, int]) -> Pair:
    """``box = (x0, y0, w, h)`` of ``image`` resized to ``size = (w', h')`` (antialiased), with ``points`` moved
    along (pixel centres at integers)."""
    x0, y0, w, h = box
    out = F.interpolate(image[..., y0 : y0 + h, x0 : x0 + w], size=size[::-1], mode="bilinear", antialias=True)
    scale = points.new_tensor([size[0] / w, size[1] / h])
    return out.clamp(0, 1), (points - points.new_tensor([x0, y0]) + 0.5) * scale - 0.5  # type: ignore[return-value]


def bundled() -> dict[str, Callable[[], Pair]]:
    def demo() -> Pair:
        a, b = load_sample("astronaut"), load_sample("cat")
        return a, b, load_sample_points("astronaut"), load_sample_points("cat")

    def landscape() -> Pair:  # the astronaut's upper third (its marks are all there) as a 300 x 200 picture
        b, pb = reframe(load_sample("astronaut"), load_sample_points("astronaut"), (0, 0, 512, 341), (300, 200))
        return load_sample("cat"), b, load_sample_points("cat"), pb

    return {"demo (512^2 -> 512^2)": demo, "cat 512^2 -> landscape 300x200": landscape}


def faces() -> dict[str, Callable[[], Pair]]:
    from morph_quality_data import load_faces

    def portrait() -> Pair:
        f = load_faces(["t1-1", "obama"])
        b, pb = reframe(f["obama"].image, f["obama"].ibug, (85, 0, 342, 512), (150, 225))
        return f["t1-1"].image, b, f["t1-1"].ibug, pb

    def mixed() -> Pair:
        f = load_faces(["hopper", "biden"])
        a, pa = reframe(f["hopper"].image, f["hopper"].ibug, (85, 0, 342, 512), (342, 512))
        b, pb = reframe(f["biden"].image, f["biden"].ibug, (0, 85, 512, 342), (512, 342))
        return a, b, pa, pb

    return {"t1-1 512^2 -> portrait 150x225": portrait, "portrait 342x512 -> landscape 512x342": mixed}


def classical(kind: str, pair: Pair, frames: int) -> tuple[Tensor, Tensor, Tensor]:
    """A thin-plate-spline (``"tps"``) or Delaunay morph to the average shape on A's canvas: frames
    ``(N, 3, H, W)`` and the maps into A's and B's own pixels ``(N, H, W, 2)``."""
    a, b, pa, pb = pair
    H, W = a.shape[-2:]
    place_b, _ = placement((b.shape[-2], b.shape[-1]), (H, W), pb)  # as morph() places B: on its marks
    to_b = torch.linalg.inv(place_b)
    maps_a, maps_b, out = [], [], []
    for s, ma, mb in classical_maps(kind, pa.double(), apply_alignment(place_b, pb.double()), H, W, frames):
        mb = apply_alignment(to_b, mb.double())  # canvas pixels to B's own
        ma, mb = ma.float()[None], mb.float()[None]
        out.append((1 - s) * warp_image(a, ma) + s * warp_image(b, mb))
        maps_a.append(ma)
        maps_b.append(mb)
    return torch.cat(out), torch.cat(maps_a), torch.cat(maps_b)


def run(method: str, pair: Pair, frames: int) -> tuple[Tensor, Tensor, Tensor]:
    if method == "fluid":
        r = morph(*pair, frames=frames, progress=False)
        return r.frames, r.maps, r.maps_b
    return classical(method, pair, frames)


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="the two bundled pairs at 128 px, 8 frames")
    p.add_argument("--frames", type=int, default=30, help="frames per morph (default 30, as the demo)")
    p.add_argument("--no-faces", action="store_true", help="leave out the face pairs (they fetch their photos)")
    p.add_argument("--png", metavar="DIR", help="write every 4th frame of each morph (and the last) to DIR")
    args = p.parse_args(argv)
    pairs = bundled() if args.no_faces or args.quick else {**bundled(), **faces()}
    info = start("bench_edges", args.threads, " [--quick]" if args.quick else "", argv)
    frames = 8 if args.quick else args.frames
    rows: list[list[str]] = []
    records: list[dict[str, Any]] = []
    for name, load in pairs.items():
        pair = load()
        if args.quick:  # the canvas and both pictures at a quarter of their size
            a, b, pa, pb = pair
            small = lambda x: F.interpolate(x, scale_factor=0.25, mode="bilinear", antialias=True)  # noqa: E731
            pair = small(a), small(b), (pa + 0.5) / 4 - 0.5, (pb + 0.5) / 4 - 0.5
        a, b = pair[0], pair[1]
        sizes = (a.shape[-2], a.shape[-1]), (b.shape[-2], b.shape[-1])
        for method in METHODS:
            out, maps_a, maps_b = run(method, pair, frames)
            fig = border_seam(out, maps_a, maps_b, *sizes)
            worst = fig.worst()
            at = {k: int(v.nan_to_num(-1e9).argmax()) for k, v in (("a", fig.seam[:, 0]), ("b", fig.seam[:, 1]))}
            seams = [fmt(worst["seam_a"]), str(at["a"]), fmt(worst["seam_b"]), str(at["b"])]
            streaks = [fmt(worst["streak_a"]), fmt(worst["streak_b"]), f"{100 * worst['beyond_both']:.2f}%"]
            rows.append([name, method, *seams, *streaks])
            records.append({"pair": name, "method": method, **worst, "seam": fig.seam.tolist(),
                            "streak": fig.streak.tolist(), "beyond_both": fig.beyond_both.tolist()})  # fmt: skip
            log(f"  {name} {method}: {worst}")
            if args.png:
                slug = "".join(c if c.isalnum() else "_" for c in name)
                for k in [*range(0, frames, 4), frames - 1]:
                    write_image(Path(args.png) / f"{slug}_{method}_{k:02d}.png", out[k].clamp(0, 1))
    heads = ["pair", "method", "seam A", "at", "seam B", "at", "streak A", "streak B", "beyond both"]
    print(f"\n{frames} frames per morph; worst over the frames (the frame it is worst at)\n")
    print(table(heads, rows, markdown=True))
    finish(info, {"frames": frames, "morphs": records}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
