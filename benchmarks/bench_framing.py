"""Whole photographs framed unlike each other (issue #31): a head-and-shoulders portrait against a group photograph,
a landscape still against a portrait, morphed with no points given (``morph(A, B)``: the faces matcher).

The matcher appends border points to the face landmarks. Two rules pair them, on the same landmarks:

* ``own frames``: A's border with B's own border (what the matcher did before ``border_pairs``): each picture's
  frame pinned onto the other's, wherever the faces are;
* ``border_pairs`` (the default): B's own border point where the landmarks' similarity sends A's within a tenth of
  B's longer side, else where it sends A's (left out when that is outside B).

Both morphs run with ``morph()``'s defaults and its placement (the crop of B on A's canvas centred on the median of
B's points). Figures: crossing pairs among the points (``morph.marks.crossing_pairs``); the fluid's own travel at the
face landmarks, after the pre-alignment (median, canvas pixels): the non-rigid motion the flow has to make; the
landmarks' mean end error, and whether ``morph()`` warned that they lie closer together than the fluid's cells
(``morph.marks.warn_coarse_grid``); the folded map pixels over 5 rendered frames; and where B's face is at the end:
the share of B's landmarks on the canvas, under this placement and under the old one (the crop centred on the
picture). ``--settings`` passes ``NaturalSettings`` fields (``'{"grid": 120}'``), ``--variants`` one pairing.
"""

from __future__ import annotations

import json
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from _common import finish, fmt, log, parser, start, table
from morph_quality_data import photo_path

from torchfluidwarp.control import apply_alignment
from torchfluidwarp.correspond.auto import border_points, find_points, usable_pairs
from torchfluidwarp.io import read_image, write_image
from torchfluidwarp.morph import NaturalSettings, morph
from torchfluidwarp.morph.marks import crossing_pairs
from torchfluidwarp.morph.morphing import placement

PAIRS = (
    ("biden", "t1"),  # 970 x 2204 standing portrait -> 1280 x 886 group of six (the largest face, at the left edge)
    ("t1", "biden"),
    ("obama3", "breakingbad"),  # 1434 x 2333 portrait -> 1920 x 1080 still of two men in a car
    ("breakingbad", "einstein"),  # landscape still -> 817 x 1024 grey speech photograph, a small face
    ("einstein", "obama2"),  # -> 626 x 1200 narrow portrait
    ("t1", "hopper"),  # group -> 512 x 600 portrait: zooms in
    ("obama3", "obama2"),  # a small face in a tall room -> a large one: zooms in
)
TIMES = (0.0, 0.25, 0.5, 0.75, 1.0)


def on_canvas(place: torch.Tensor, points: torch.Tensor, canvas: tuple[int, int]) -> float:
    """The share of ``points`` ``(M, 2)`` that ``place`` ``(3, 3)`` puts on a canvas of ``canvas`` ``(H, W)``."""
    q = apply_alignment(place, points.double())
    H, W = canvas
    inside = (q[:, 0] >= -0.5) & (q[:, 0] <= W - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] <= H - 0.5)
    return float(inside.double().mean())


def own_frames(a: torch.Tensor, b: torch.Tensor, pa: torch.Tensor, pb: torch.Tensor) -> tuple[Any, Any]:
    """The landmarks with each picture's own border appended (the old pairing), unusable pairs left out."""
    size_a, size_b = (a.shape[-2], a.shape[-1]), (b.shape[-2], b.shape[-1])
    qa = torch.cat([pa, border_points(size_a, dtype=pa.dtype)])
    qb = torch.cat([pb, border_points(size_b, dtype=pb.dtype)])
    keep = usable_pairs(qa, qb, size_a, size_b)
    return qa[keep], qb[keep]


def measure(
    a: torch.Tensor, b: torch.Tensor, pa: torch.Tensor, pb: torch.Tensor, faces: int, settings: NaturalSettings
) -> dict[str, Any]:
    """Morph ``a`` into ``b`` through ``pa``, ``pb`` (their first ``faces`` rows: the face landmarks)."""
    crossing = crossing_pairs(pa.double(), pb.double())
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        r = morph(a, b, pa, pb, settings=settings, progress=False)
    fit_s = time.perf_counter() - t0
    out = r.render(list(TIMES))
    seconds = time.perf_counter() - t0
    travel = (r.fit.trajectories[0, -1] - r.fit.trajectories[0, 0])[:faces].norm(dim=-1)
    canvas = (a.shape[-2], a.shape[-1])
    return {
        "points": int(pa.shape[0]),
        "crossing": int(crossing.shape[0]),
        "crossing_border": int((crossing >= faces).any(dim=1).sum()),
        "travel_px": float(travel.median()),
        "error_px": float(r.error[:faces].mean()),
        "folded": int(out.folded),
        "b_face_on_canvas": on_canvas(r.canvas_from_b, pb[:faces], canvas),
        "coarse_grid_warning": any("fluid cells apart" in str(w.message) for w in caught),
        "fit_s": fit_s,
        "seconds": seconds,
        "frames": out.frames,
    }


def sheet(frames: torch.Tensor, height: int = 360) -> torch.Tensor:
    """``frames`` ``(n, C, H, W)`` side by side at ``height`` pixels, ``(C, height, n w)``."""
    small = torch.nn.functional.interpolate(
        frames.float(), size=(height, round(height * frames.shape[-1] / frames.shape[-2])), antialias=True,
        mode="bilinear",
    )  # fmt: skip
    return torch.cat(list(small.clamp(0, 1)), -1)


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, threads=2)
    p.add_argument("--sheets", metavar="DIR", help="write each morph's 5 frames side by side to DIR")
    p.add_argument("--pairs", help="comma-separated A_B names (default: all)")
    p.add_argument("--settings", default="{}", help="NaturalSettings fields as JSON, e.g. '{\"grid\": 120}'")
    p.add_argument("--variants", default="own frames,border_pairs", help="comma-separated, of the two (default: both)")
    args = p.parse_args(argv)
    info = start("bench_framing", args.threads, "", argv)
    chosen = PAIRS if not args.pairs else [tuple(x.split("_", 1)) for x in args.pairs.split(",")]
    settings = NaturalSettings(**json.loads(args.settings))
    rows, records = [], []
    for name_a, name_b in chosen:
        a, b = (read_image(photo_path(n)) for n in (name_a, name_b))
        found = find_points(a, b, match="faces", border=None)
        faces = int(found.points_a.shape[0])
        default = find_points(a, b, match="faces")
        variants = {
            "own frames": own_frames(a, b, found.points_a, found.points_b),
            "border_pairs": (default.points_a, default.points_b),
        }
        variants = {k: v for k, v in variants.items() if k in args.variants.split(",")}
        size_a, size_b = (a.shape[-2], a.shape[-1]), (b.shape[-2], b.shape[-1])
        centred = on_canvas(placement(size_b, size_a)[0], found.points_b, size_a)
        pair = f"{name_a} {size_a[1]}x{size_a[0]} -> {name_b} {size_b[1]}x{size_b[0]}"
        for variant, (pa, pb) in variants.items():
            m = measure(a, b, pa, pb, faces, settings)
            frames = m.pop("frames")
            log(f"  {pair} {variant}: {m}")
            on = f"{100 * m['b_face_on_canvas']:.0f}% ({100 * centred:.0f}%)"
            crossing = f"{m['crossing']} ({m['crossing_border']})"
            warned = "yes" if m["coarse_grid_warning"] else ""
            figures = [fmt(m["travel_px"]), fmt(m["error_px"]), warned, str(m["folded"]), on, fmt(m["seconds"], 1)]
            rows.append([pair, variant, str(m["points"]), crossing, *figures])
            records.append({"pair": pair, "variant": variant, "faces": faces, "centred_on_canvas": centred, **m})
            if args.sheets:
                slug = "".join(c if c.isalnum() else "_" for c in f"{name_a}_{name_b}_{variant}")
                write_image(Path(args.sheets) / f"{slug}.png", sheet(frames))
    heads = ["pair (W x H)", "border", "points", "crossing (with border)", "fluid travel px", "end error px",
             "coarse-grid warning", "folded px", "B's face on canvas (centred crop)", "s"]  # fmt: skip
    print(
        f"\n{args.settings} (NaturalSettings fields; {{}}: the defaults), frames at t = {', '.join(map(str, TIMES))}; "
        "medians and means over the face landmarks\n"
    )
    print(table(heads, rows, markdown=True))
    travel = {
        v: float(np.median([r["travel_px"] for r in records if r["variant"] == v]))
        for v in ("own frames", "border_pairs")
        if any(r["variant"] == v for r in records)
    }
    print(f"\nmedian fluid travel over pairs: {travel}")
    finish(info, {"morphs": records}, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
