"""Morph quality on real photographs of faces, with held-out landmarks: the fluid morph against the classical ones.

Sixteen face crops (``morph_quality_data.py``) in a tune and a report half, each pair labelled ``frontal`` or
``turned`` (the head turns), and the bundled pair; the fluid ``morph()`` (``--settings``, more rows with
``--config``) against a thin-plate spline (``tps``) and a Delaunay piecewise-affine morph (``delaunay``) to the
average shape; the metrics are the library's (``torchfluidwarp.metrics``): held-out landmarks, which no method
sees, and the ghosting of the whole picture and of the face's pixels in the middle frame. ``bench_stereo.py``
scores the same rows against a known dense correspondence. Definitions: benchmarks/README.md; figures:
docs/benchmarks.md, "Quality on real photographs". Importable for tuning: ``load_pairs``, ``run_method``,
``evaluate``, ``summarize``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from _common import finish, fmt, log, morph_settings, parser, settings_arg, start, table
from matplotlib.tri import Triangulation
from morph_quality_data import FACES, SPLIT_FACES, load_faces, pair_kind, yaw_degrees
from scipy.spatial import ConvexHull, Delaunay
from torch import Tensor

from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.metrics import end_error, folded_pixels, ghosting, image_ghosting, seam_figure
from torchfluidwarp.morph import Matching, morph
from torchfluidwarp.warp import jacobian_determinant, warp_image

Split = Literal["tune", "report", "all"]
SPLITS: tuple[str, ...] = ("tune", "report")
BASELINES: tuple[str, ...] = ("tps", "delaunay")
SHEET_AT = (0.0, 0.25, 0.5, 0.75, 1.0)
SHEET_PX = 256


@dataclass(frozen=True)
class Pair:
    """Two images and their marked and held-out points, in each image's pixels (pixel centres at integers)."""

    name: str
    split: str  # "tune", "report" or "bundled"
    image_a: Tensor  # (1, 3, H, W) float32 in [0, 1]
    image_b: Tensor
    marked_a: Tensor | None  # (M, 2); None: the fluid's morph lets the pixels place the points (bench_stereo.py)
    marked_b: Tensor | None
    held_a: Tensor  # (K, 2)
    held_b: Tensor
    kind: str | None = None  # faces: "frontal", or "turned" when the yaws differ by more than TURNED_DEG
    yaw: tuple[float, float] | None = None  # faces: each one's yaw, degrees (morph_quality_data.yaw_degrees)
    landmarks: int | None = None  # faces: how many of the held-out points (the first) are iBUG landmarks; the rest
    # are the mesh's extra forehead, temple and cheek vertices


def hold_out(points: Tensor) -> tuple[Tensor, Tensor]:
    """``(marked, held)``: points ``i % 3 != 2`` and ``i % 3 == 2``."""
    held = torch.arange(points.shape[0]) % 3 == 2
    return points[~held], points[held]


def split_pairs(split: Split) -> list[tuple[str, str, str]]:
    """``(face_a, face_b, half)`` for every unordered pair of distinct faces within a half, in ``FACES`` order."""
    halves = SPLITS if split == "all" else (split,)
    out = []
    for half in halves:
        faces = SPLIT_FACES[half]
        out += [(a, b, half) for i, a in enumerate(faces) for b in faces[i + 1 :]]
    return out


def bundled_pair() -> Pair:
    a, b = load_sample("astronaut"), load_sample("cat")
    ma, ha = hold_out(load_sample_points("astronaut"))
    mb, hb = hold_out(load_sample_points("cat"))
    return Pair("astronaut_cat", "bundled", a, b, ma, mb, ha, hb)


def load_pairs(split: Split = "all", bundled: bool = True) -> list[Pair]:
    """The face pairs (``"<face a>_<face b>"``) of a half or of both (``"all"``), then ``"astronaut_cat"``."""
    if split not in ("tune", "report", "all"):
        raise ValueError(f"split must be 'tune', 'report' or 'all', got {split!r}")
    plan = split_pairs(split)
    faces = load_faces(sorted({f for a, b, _ in plan for f in (a, b)}, key=FACES.index))
    pairs = []
    for a, b, half in plan:
        fa, fb = faces[a], faces[b]
        ma, ha = hold_out(fa.ibug)
        mb, hb = hold_out(fb.ibug)
        held_a, held_b = torch.cat([ha, fa.extra]), torch.cat([hb, fb.extra])
        kind, yaw = pair_kind(fa.ibug, fb.ibug), (yaw_degrees(fa.ibug), yaw_degrees(fb.ibug))
        pairs.append(Pair(f"{a}_{b}", half, fa.image, fb.image, ma, mb, held_a, held_b, kind, yaw, len(ha)))
    if bundled:
        pairs.append(bundled_pair())
    return pairs


@dataclass
class MethodResult:
    """What a method returns; :func:`evaluate` reads ``frames``, ``maps``, ``maps_b`` and ``seconds``."""

    frames: Tensor  # (N, C, H, W)
    maps: Tensor  # (N, H, W, 2) output pixel -> A's pixel
    maps_b: Tensor  # (N, H, W, 2) output pixel -> B's pixel
    seconds: float  # wall time of the call
    info: dict[str, Any] = field(default_factory=dict)
    raw: Any = None  # the fluid's MorphResult


def pixel_grid(H: int, W: int, dtype: torch.dtype = torch.float64) -> Tensor:
    """``(H * W, 2)`` pixel centres ``(x, y)``, row by row."""
    y, x = torch.meshgrid(torch.arange(H, dtype=dtype), torch.arange(W, dtype=dtype), indexing="ij")
    return torch.stack([x, y], dim=-1).reshape(-1, 2)


def _tps_kernel(d2: Tensor) -> Tensor:
    """``U = r^2 log r^2`` from squared distances (0 at 0): twice the textbook ``r^2 log r``, the same spline."""
    return torch.xlogy(d2, d2)


def tps_fit(centres: Tensor, values: Tensor) -> tuple[Tensor, Tensor]:
    """The thin-plate spline ``f(centres_i) = values_i`` (Bookstein 1989), float64 ``(M, 2)`` and ``(M, D)``:
    ``(w (M, D), affine (3, D))``, ``f(p) = sum_i w_i U(|p - c_i|) + affine[0] + p @ affine[1:]``."""
    M = centres.shape[0]
    P = torch.cat([torch.ones(M, 1, dtype=centres.dtype), centres], dim=1)  # (M, 3)
    L = torch.zeros(M + 3, M + 3, dtype=centres.dtype)
    L[:M, :M] = _tps_kernel(torch.cdist(centres, centres).square())
    L[:M, M:], L[M:, :M] = P, P.T
    rhs = torch.cat([values, torch.zeros(3, values.shape[1], dtype=values.dtype)])
    sol = torch.linalg.solve(L, rhs)
    return sol[:M], sol[M:]


def tps_eval(centres: Tensor, w: Tensor, affine: Tensor, points: Tensor, chunk: int = 1 << 16) -> Tensor:
    """The spline of :func:`tps_fit` at ``points`` ``(P, 2)`` float64: ``(P, D)``."""
    out = points.new_empty(points.shape[0], w.shape[1])
    for i in range(0, points.shape[0], chunk):
        p = points[i : i + chunk]
        out[i : i + chunk] = _tps_kernel(torch.cdist(p, centres).square()) @ w + affine[0] + p @ affine[1:]
    return out


def _border_points(H: int, W: int) -> np.ndarray:
    """The image's corners and edge midpoints on its outer edges (pixel centres at integers): ``(8, 2)``."""
    x0, y0, x1, y1 = -0.5, -0.5, W - 0.5, H - 0.5
    xm, ym = (x0 + x1) / 2, (y0 + y1) / 2
    return np.array([[x0, y0], [xm, y0], [x1, y0], [x1, ym], [x1, y1], [xm, y1], [x0, y1], [x0, ym]])


def delaunay_maps(shape: Tensor, sources: list[Tensor], H: int, W: int) -> list[Tensor]:
    """Piecewise-affine backward maps: Delaunay triangles of ``shape`` ``(M, 2)`` plus the border points, each
    mapped affinely onto the same triangle of each ``sources[j]`` ``(M, 2)``. Returns ``(H, W, 2)`` float32 each."""
    border = _border_points(H, W)
    vertices = np.concatenate([shape.double().numpy(), border])
    tri = Delaunay(vertices)
    grid = pixel_grid(H, W).numpy()
    # matplotlib's trapezoid-map point location: 100 times faster than Delaunay.find_simplex here, same answer
    simplex = Triangulation(vertices[:, 0], vertices[:, 1], tri.simplices).get_trifinder()(grid[:, 0], grid[:, 1])
    if (simplex < 0).any():  # cannot happen: the border points' hull contains every pixel centre
        raise RuntimeError(f"{int((simplex < 0).sum())} pixels outside the triangulation")
    corners = np.concatenate([vertices[tri.simplices], np.ones((len(tri.simplices), 3, 1))], axis=2)  # (T, 3, 3)
    out = []
    for src in sources:
        verts = np.concatenate([src.double().numpy(), border])[tri.simplices]  # (T, 3, 2)
        affine = np.linalg.solve(corners, verts)  # (T, 3, 2): [x, y, 1] @ affine = source position
        a = affine[simplex]  # (HW, 3, 2)
        m = grid[:, :1] * a[:, 0] + grid[:, 1:] * a[:, 1] + a[:, 2]
        out.append(torch.from_numpy(m).float().view(H, W, 2))
    return out


def _dissolve(a: Tensor, b: Tensor, maps: Tensor, maps_b: Tensor) -> Tensor:
    n = maps.shape[0]
    s = torch.linspace(0, 1, n, dtype=a.dtype).view(-1, 1, 1, 1)
    return (1 - s) * warp_image(a.expand(n, -1, -1, -1), maps) + s * warp_image(b.expand(n, -1, -1, -1), maps_b)


def classical_maps(kind: str, pa: Tensor, pb: Tensor, H: int, W: int, frames: int) -> Iterator[tuple[float, ...]]:
    """``(s, map into A, map into B)`` at each frame's ``s = k / (frames - 1)``: the backward maps ``(H, W, 2)`` of
    the thin-plate-spline (``"tps"``, float64) or Delaunay (``"delaunay"``, float32) morph of the marks ``pa``,
    ``pb`` ``(M, 2)`` float64 to their average shape ``(1 - s) pa + s pb``."""
    grid = pixel_grid(H, W)
    for k in range(frames):
        s = k / (frames - 1)
        shape = (1 - s) * pa + s * pb
        if kind == "tps":
            w, affine = tps_fit(shape, torch.cat([pa, pb], dim=1))  # both maps share the kernel centres
            both = tps_eval(shape, w, affine, grid).view(H, W, 4)
            yield s, both[..., :2], both[..., 2:]
        else:
            yield s, *delaunay_maps(shape, [pa, pb], H, W)


def classical_morph(kind: Literal["tps", "delaunay"], pair: Pair, frames: int) -> MethodResult:
    """The thin-plate-spline or Delaunay morph to the average shape (see the module docstring)."""
    if pair.marked_a is None or pair.marked_b is None:
        raise ValueError(f"the {kind} morph needs marks; pair {pair.name!r} has none")
    t0 = time.perf_counter()
    H, W = pair.image_a.shape[-2:]
    both = [(a.float(), b.float()) for _, a, b in classical_maps(kind, pair.marked_a.double(),
                                                                 pair.marked_b.double(), H, W, frames)]  # fmt: skip
    maps_t, maps_b_t = torch.stack([a for a, _ in both]), torch.stack([b for _, b in both])
    out = _dissolve(pair.image_a, pair.image_b, maps_t, maps_b_t)
    return MethodResult(out, maps_t, maps_b_t, time.perf_counter() - t0)


def run_method(name: str, pair: Pair, frames: int = 21, spec: dict[str, Any] | None = None) -> MethodResult:
    """Morph a pair by ``"fluid"`` (:func:`torchfluidwarp.morph.morph` with the settings ``spec``, a dict for
    :func:`_common.morph_settings`; ``match=Matching("pixels")`` where the pair has no marks), ``"tps"`` or
    ``"delaunay"``. The fluid's warnings go to ``info["warnings"]``."""
    if name in BASELINES:
        return classical_morph(name, pair, frames)  # type: ignore[arg-type]
    settings = morph_settings(spec)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        match = Matching("pixels") if pair.marked_a is None else Matching()
        res = morph(pair.image_a, pair.image_b, pair.marked_a, pair.marked_b, settings=settings, frames=frames,
                    match=match, progress=False)  # fmt: skip
        maps, maps_b, out = res.maps, res.maps_b, res.frames
        seconds = time.perf_counter() - t0
    info = {"warnings": sorted({str(w.message) for w in caught}), "error_px": float(res.error.double().mean()),
            "fit_error_box_px": float(res.fit.error.double().mean()), "phases_s": dict(res.seconds)}  # fmt: skip
    return MethodResult(out, maps, maps_b, seconds, info, raw=res)


def _stats(d: Tensor, ok: Tensor) -> dict[str, Any]:
    v = d[ok] if ok.any() else torch.full((1,), float("nan"))
    per_point = [round(float(x), 3) if bool(o) else None for x, o in zip(d, ok)]
    return dict(mean=float(v.mean()), median=float(v.median()), max=float(v.max()), located=int(ok.sum()),
                of=int(ok.numel()), per_point=per_point)  # fmt: skip


def covered(map1: Tensor, size: tuple[int, ...]) -> Tensor:
    """``(H, W)`` bool: where a backward map ``(H, W, 2)`` reads inside a picture of ``size`` ``(h, w)`` (its outer
    edges at ``-0.5`` and ``w - 0.5``, ``h - 0.5``)."""
    x, y = map1[..., 0], map1[..., 1]
    return (x >= -0.5) & (x <= size[1] - 0.5) & (y >= -0.5) & (y <= size[0] - 0.5)


def frame_pictures(result: Any, image_a: Tensor, image_b: Tensor, k: int) -> tuple[Tensor, Tensor, Tensor]:
    """Frame ``k`` of a morph as ``(warped A, warped B, covered)``: ``(1, C, H, W)`` each and ``(H, W)`` bool
    (both maps read inside their picture). A ``MorphResult`` (or a :class:`MethodResult` holding one) renders the
    frame as it shows it (``render``: ``forward``, ``backward``); any other result's pictures are read through its
    ``maps`` and ``maps_b`` by :func:`~torchfluidwarp.warp.warp_image`."""
    fluid = result if getattr(result, "raw", None) is None else result.raw
    if hasattr(fluid, "render"):
        n = len(fluid)
        shown = fluid.render([1.0 if k == n - 1 else k / (n - 1)])
        warped_a, warped_b, map_a, map_b = shown.forward, shown.backward, shown.maps_a[0], shown.maps_b[0]
    else:
        map_a, map_b = result.maps[k], result.maps_b[k]
        warped_a, warped_b = warp_image(image_a, map_a[None]), warp_image(image_b, map_b[None])
    valid = covered(map_a.cpu(), image_a.shape[-2:]) & covered(map_b.cpu(), image_b.shape[-2:])
    return warped_a.detach().cpu().float(), warped_b.detach().cpu().float(), valid


def picture_ghost(result: Any, image_a: Tensor, image_b: Tensor, k: int) -> dict[str, Any]:
    """:func:`~torchfluidwarp.metrics.image_ghosting` of frame ``k`` of a morph (see :func:`frame_pictures`)."""
    return image_ghosting(*frame_pictures(result, image_a, image_b, k))


def halfway_hull(pair: Pair, size: tuple[int, ...]) -> Tensor:
    """``(H, W)`` bool: the convex hull of the pair's points, marked and held out, at their average position (the
    middle frame's shape): the face, where the whole picture's ghosting is about the face alone."""
    from matplotlib.path import Path as Polygon

    if pair.marked_a is None or pair.marked_b is None:
        raise ValueError(f"pair {pair.name!r} has no marks to take the hull of")
    mean = 0.5 * (torch.cat([pair.marked_a, pair.held_a]) + torch.cat([pair.marked_b, pair.held_b])).double()
    hull = mean[ConvexHull(mean.numpy()).vertices].numpy()
    inside = Polygon(hull).contains_points(pixel_grid(size[0], size[1]).numpy())
    return torch.from_numpy(inside).view(size[0], size[1])


def _median(ghost: dict[str, Any]) -> float:
    return float("nan") if ghost["median"] is None else ghost["median"]


def evaluate(result: Any, pair: Pair) -> dict[str, Any]:
    """The metrics (see benchmarks/README.md) of a morph of ``pair``: anything with ``maps`` and ``maps_b``
    ``(N, H, W, 2)`` (a :class:`MethodResult` or a ``MorphResult``); px, the details under ``"points"`` and
    ``"image_ghost"`` and ``"face_ghost"``."""
    maps, maps_b = result.maps.detach().cpu().float(), result.maps_b.detach().cpu().float()
    n, H, W = maps.shape[:3]
    mid = n // 2
    warped_a, warped_b, valid = frame_pictures(result, pair.image_a, pair.image_b, mid)
    image_ghost = image_ghosting(warped_a, warped_b, valid)
    face_ghost = image_ghosting(warped_a, warped_b, valid & halfway_hull(pair, (H, W)))
    last_a, mid_a, mid_b = maps[n - 1 :], maps[mid : mid + 1], maps_b[mid : mid + 1]
    points: dict[str, dict[str, Any]] = {}
    landmarks: dict[str, dict[str, Any]] = {}  # the iBUG landmarks among the held-out points, as #32 defines them
    for kind, pa, pb in (("held", pair.held_a, pair.held_b), ("marked", pair.marked_a, pair.marked_b)):
        for figure, (d, ok) in (("end", end_error(last_a, pa, pb)), ("ghost", ghosting(mid_a, mid_b, pa, pb))):
            points[f"{kind}_{figure}"] = _stats(d, ok)
            if kind == "held" and pair.landmarks is not None:  # the first held-out points, read off the same run
                landmarks[figure] = _stats(d[: pair.landmarks], ok[: pair.landmarks])
    folded_a, folded_b = int(folded_pixels(maps).sum()), int(folded_pixels(maps_b).sum())
    # of those, the ones where a picture shows: the map reads inside its picture
    seen = sum(int(((jacobian_determinant(m) <= 0) & covered(m, img.shape[-2:])).sum())
               for m, img in ((maps, pair.image_a), (maps_b, pair.image_b)))  # fmt: skip
    seconds = getattr(result, "seconds", None)
    if isinstance(seconds, dict):
        seconds = seconds.get("total")
    return dict(pair=pair.name, split=pair.split, kind=pair.kind, frames=n, held_end_px=points["held_end"]["mean"],
                held_ghost_px=points["held_ghost"]["median"], marked_ghost_px=points["marked_ghost"]["median"],
                landmark_end_px=landmarks.get("end", {}).get("mean"),
                landmark_ghost_px=landmarks.get("ghost", {}).get("median"),
                image_ghost_px=_median(image_ghost), face_ghost_px=_median(face_ghost), image_ghost=image_ghost,
                face_ghost=face_ghost,
                marked_end_px=points["marked_end"]["mean"], folded=folded_a + folded_b, folded_a=folded_a,
                folded_b=folded_b, folded_seen=seen, folded_fraction=(folded_a + folded_b) / (2 * n * H * W),
                seam=max(seam_figure(maps[mid]), seam_figure(maps_b[mid])),
                seconds=None if seconds is None else float(seconds),
                not_located=sum(p["of"] - p["located"] for p in points.values()), points=points,
                landmarks=landmarks)  # fmt: skip


HEADLINE = ("held_end_px", "held_ghost_px", "marked_ghost_px", "image_ghost_px", "face_ghost_px", "marked_end_px",
            "seam", "seconds", "landmark_end_px", "landmark_ghost_px")  # fmt: skip


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians over pairs of :func:`evaluate`'s figures; folds as the pairs that fold and the worst fraction."""
    out: dict[str, Any] = {"pairs": len(rows)}
    for key in (*HEADLINE, "folded_fraction"):
        values = [r[key] for r in rows if r[key] is not None and r[key] == r[key]]
        out[key] = statistics.median(values) if values else float("nan")
    out["pairs_folding"] = sum(r["folded"] > 0 for r in rows)
    out["pairs_folding_seen"] = sum(r.get("folded_seen", r["folded"]) > 0 for r in rows)
    out["folded_fraction_max"] = max((r["folded_fraction"] for r in rows), default=float("nan"))
    out["folded_max"] = max((r["folded"] for r in rows), default=0)
    return out


def pair_table(records: list[dict[str, Any]], labels: list[str]) -> str:
    rows = []
    for rec in records:
        for label in labels:
            r = rec["methods"][label]
            folded = "0" if r["folded"] == 0 else f"{r['folded']} ({100 * r['folded_fraction']:.3g}%)"
            kind = "—" if rec["yaw"] is None else f"{rec['kind']} ({abs(rec['yaw'][0] - rec['yaw'][1]):.0f}°)"
            rows.append([rec["pair"], kind, label, fmt(r["held_end_px"]) + ("*" if r["not_located"] else ""),
                         *(fmt(r[k]) for k in HEADLINE[1:6]), folded, fmt(r["seam"], 3),
                         fmt(r["seconds"])])  # fmt: skip
    heads = ["pair", "kind (yaw apart)", "method", "held-out end (mean)", "held-out ghost (median)"]
    heads += ["marked ghost (median)", "picture ghost (median)", "face picture ghost (median)", "marked end (mean)"]
    heads += ["folded px", "seam", "time s"]
    return table(heads, rows, markdown=True)


def median_table(summary: dict[str, dict[str, Any]], labels: list[str]) -> str:
    ref = summary.get("tps")

    def ratio(s: dict[str, Any], key: str) -> str:  # "—" where the spline's figure is missing, 0 or NaN
        return "—" if ref is None or not ref[key] or ref[key] != ref[key] else f"{s[key] / ref[key]:.2f}x"

    rows = [[label, *(fmt(s[k]) for k in HEADLINE[:6]),
             f"{s['pairs_folding']}/{s['pairs']} ({s['pairs_folding_seen']})",
             f"{100 * s['folded_fraction_max']:.3g}%", fmt(s["seam"], 3), fmt(s["seconds"]),
             *(ratio(s, k) for k in ("held_end_px", "held_ghost_px", "image_ghost_px", "face_ghost_px", "seam")),
             fmt(s["landmark_end_px"]), fmt(s["landmark_ghost_px"]),
             *(ratio(s, k) for k in ("landmark_end_px", "landmark_ghost_px"))]
            for label, s in ((label, summary[label]) for label in labels)]  # fmt: skip
    heads = ["method", "held-out end", "held-out ghost", "marked ghost", "picture ghost", "face picture ghost"]
    heads += ["marked end", "pairs folding (where a picture shows)", "worst folded", "seam", "time s"]
    heads += ["held-out end / tps"]
    heads += ["held-out ghost / tps", "picture ghost / tps", "face picture ghost / tps", "seam / tps"]
    heads += ["held-out landmarks' end", "held-out landmarks' ghost", "landmarks' end / tps", "landmarks' ghost / tps"]
    return table(heads, rows, markdown=True)


def _thumb(frame: Tensor, size: tuple[int, int]) -> np.ndarray:
    small = torch.nn.functional.interpolate(
        frame[None].float(), size=size, mode="bilinear", align_corners=False, antialias=True
    )
    return (small[0, :3].clamp(0, 1).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)


def sheet_frames(result: MethodResult) -> list[Tensor]:
    """The frames of a morph nearest ``SHEET_AT``, ``(C, H, W)`` each, for :func:`write_sheet`."""
    n = result.frames.shape[0]
    return [result.frames[round(s * (n - 1))].detach().cpu() for s in SHEET_AT]


def write_sheet(path: Path, pair: str, rows: dict[str, list[Tensor]]) -> None:
    """A contact sheet: one row per method (labelled at the left), columns at ``SHEET_AT``; thumbnails
    ``SHEET_PX`` high, as wide as the frames' aspect ratio says."""
    from PIL import Image, ImageDraw

    H, W = next(iter(rows.values()))[0].shape[-2:]
    th, tw = SHEET_PX, round(SHEET_PX * W / H)
    label_w, head_h, gap = 110, 22, 4
    cols = len(SHEET_AT)
    sheet = Image.new("RGB", (label_w + cols * (tw + gap), head_h + len(rows) * (th + gap)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    draw.text((4, 4), pair, fill=(0, 0, 0))
    for j, s in enumerate(SHEET_AT):
        draw.text((label_w + j * (tw + gap) + tw // 2 - 16, 4), f"s = {s:g}", fill=(0, 0, 0))
    for i, (label, frames) in enumerate(rows.items()):
        top = head_h + i * (th + gap)
        draw.text((4, top + th // 2 - 6), label[:16], fill=(0, 0, 0))
        for j, frame in enumerate(frames):
            sheet.paste(Image.fromarray(_thumb(frame, (th, tw))), (label_w + j * (tw + gap), top))
    tmp = path.with_suffix(".tmp.png")
    sheet.save(tmp)
    os.replace(tmp, path)


def config_arg(text: str) -> tuple[str, dict[str, Any]]:
    name, sep, spec = text.partition("=")
    if not sep or not name or name in BASELINES:
        raise argparse.ArgumentTypeError(f"expected NAME=JSON with NAME not in {BASELINES}, got {text!r}")
    return name, settings_arg(spec)


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="the bundled pair alone (no download), 5 frames, 10 fit iterations, tps and fluid")
    p.add_argument("--split", choices=("tune", "report", "all"), default="all", help="face pairs (default all)")
    p.add_argument("--frames", type=int, default=21, help="frames per morph (default 21)")
    p.add_argument("--methods", default="tps,delaunay,fluid", help="comma-separated rows: tps, delaunay, fluid")
    p.add_argument("--settings", type=settings_arg, default={}, metavar="JSON",
                   help='the fluid row\'s settings: {"method": "natural" or "paper", and its fields}')  # fmt: skip
    p.add_argument("--config", type=config_arg, action="append", default=[], metavar="NAME=JSON",
                   help="another fluid row NAME with these settings (repeatable)")  # fmt: skip
    p.add_argument("--pairs", help="comma-separated pair names to keep (e.g. t1-1_t1-3,astronaut_cat)")
    p.add_argument("--no-bundled", action="store_true", help="leave out the bundled astronaut -> cat pair")
    p.add_argument("--sheets", metavar="DIR", help="write a contact sheet per pair into DIR")
    args = p.parse_args(argv)
    if args.quick:
        args.frames, args.methods = 5, "tps,fluid"
        args.settings = {**args.settings, "max_iter": 10}
    if args.frames < 2:
        p.error(f"--frames must be >= 2, got {args.frames}")
    rows: dict[str, tuple[str, dict[str, Any]]] = {}
    for name in filter(None, args.methods.split(",")):
        if name not in (*BASELINES, "fluid"):
            p.error(f"--methods: unknown method {name!r} (tps, delaunay, fluid)")
        rows[name] = (name, args.settings if name == "fluid" else {})
    rows.update((name, ("fluid", spec)) for name, spec in args.config)
    labels = list(rows)
    pairs = [bundled_pair()] if args.quick else load_pairs(args.split, bundled=not args.no_bundled)
    if args.pairs:
        keep = set(args.pairs.split(","))
        if keep - {pair.name for pair in pairs}:
            p.error(f"--pairs: not in split {args.split!r}: {sorted(keep - {pair.name for pair in pairs})}")
        pairs = [pair for pair in pairs if pair.name in keep]
    info = start("bench_morph_quality", args.threads, " [--quick]" if args.quick else "", argv)
    described = ", ".join(f"{label} = {method} {spec}" for label, (method, spec) in rows.items())
    print(f"{len(pairs)} pairs, {args.frames} frames; rows: {described}")
    if args.sheets:
        Path(args.sheets).mkdir(parents=True, exist_ok=True)
    records = []
    for pair in pairs:
        rec: dict[str, Any] = {"pair": pair.name, "split": pair.split, "kind": pair.kind, "yaw": pair.yaw}
        rec["methods"] = {}
        sheet_rows: dict[str, list[Tensor]] = {}
        for label, (method, spec) in rows.items():
            res = run_method(method, pair, args.frames, spec)
            m = rec["methods"][label] = {**evaluate(res, pair), "info": res.info}
            sheet_rows[label] = sheet_frames(res)
            ghost = " / ".join(
                fmt(m[k]) for k in ("held_ghost_px", "marked_ghost_px", "image_ghost_px", "face_ghost_px")
            )
            log(f"  {pair.name} {label}: held-out {fmt(m['held_end_px'])} px, ghost (held-out / marked / picture / "
                f"face) {ghost} px, folded {m['folded']}, seam {fmt(m['seam'], 3)}, {res.seconds:.2f} s")  # fmt: skip
        if args.sheets:
            write_sheet(Path(args.sheets) / f"{pair.name}.png", pair.name, sheet_rows)
        records.append(rec)
    groups: dict[str, list[dict[str, Any]]] = {}
    for half in (*SPLITS, "bundled"):
        groups[half] = [r for r in records if r["split"] == half]
        if half in SPLITS:  # and by kind, where a half has both
            for kind in ("frontal", "turned"):
                groups[f"{half}, {kind}"] = [r for r in groups[half] if r["kind"] == kind]
    summaries = {half: {label: summarize([r["methods"][label] for r in recs]) for label in labels}
                 for half, recs in groups.items() if recs}  # fmt: skip
    print("\n## Per pair\n\n" + pair_table(records, labels))
    print("\n(*: some points were not located in a frame; see the JSON.) Ghosting at frame", args.frames // 2)
    for half, summary in summaries.items():
        names = ", ".join(r["pair"] for r in groups[half])
        print(f"\n## Medians, {half} ({len(groups[half])} pairs: {names})\n\n" + median_table(summary, labels))
    if args.sheets:
        print(f"wrote {len(records)} contact sheets to {args.sheets} (rows: {', '.join(labels)})")
    result = {"frames": args.frames, "rows": {k: {"method": m, "settings": spec} for k, (m, spec) in rows.items()}}
    finish(info, {**result, "pairs": records, "medians": summaries}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
