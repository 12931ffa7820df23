"""Benchmark of morphing: the time of a whole morph and its folds, the fluid morph against thin-plate splines.

The bundled pair at 512 x 512, float32 on CPU: ``morph()`` with
``NaturalSettings`` and ``PaperSettings``, each with ``inverse="flow"`` and ``"paper"`` (time, its split, peak RSS,
point errors), against kornia's thin-plate spline (``kornia``) and the textbook one (``standard``); folded pixels of
A's and B's backward maps. ``--images DIR`` writes middle frames. Figures: docs/benchmarks.md, "Time of a whole
30-frame 512 x 512 morph, and folds".
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path
from typing import Any

import torch
from _common import finish, load_pair, log, parser, peak_mib, rows_table, start, verdict
from kornia.geometry.transform import get_tps_transform, warp_image_tps, warp_points_tps
from torch import Tensor

from torchfluidwarp.io import write_image
from torchfluidwarp.morph import NaturalSettings, PaperSettings, morph
from torchfluidwarp.warp import identity_map, jacobian_determinant

FLUID = [("natural", "flow"), ("natural", "paper"), ("paper", "flow"), ("paper", "paper")]  # the default first
TPS = ("standard", "kornia")
TIME_TARGET_S, TIME_TARGET = 5.0, (30, 512)  # < 5 s for 30 frames at 512 x 512


def fold_stats(maps: Tensor) -> dict[str, Any]:
    """Jacobian determinants ``<= 0`` of backward maps ``(N, H, W, 2)``."""
    H, W = maps.shape[1:3]
    det = jacobian_determinant(maps)
    folded = det <= 0
    x, y = maps[..., 0], maps[..., 1]
    inside = (x >= -0.5) & (x <= W - 0.5) & (y >= -0.5) & (y <= H - 0.5)
    per_frame = folded.flatten(1).double().mean(1)
    return dict(
        fraction=float(folded.double().mean()),
        inside=float((folded & inside).sum() / inside.sum().clamp(min=1)),
        frames=int((per_frame > 0).sum()),
        worst=float(per_frame.max()),
        min_det=float(det.min()),
    )


# ----------------------------------------------------------------------------------------------- splines


def to_norm(points: Tensor, size: tuple[int, int], back: bool = False) -> Tensor:
    """Pixels (centres at integers) to kornia's ``align_corners=False`` frame, ``(2x + 1) / W - 1``; or back."""
    H, W = size
    scale = torch.tensor([2.0 / W, 2.0 / H], dtype=points.dtype)
    return (points + 1) / scale - 0.5 if back else points * scale + scale / 2 - 1


def standard_tps(dst: Tensor, src: Tensor) -> tuple[Tensor, Tensor]:
    """Textbook TPS weights ``(1, M, 2)``, ``(1, 3, 2)`` with ``f(dst_i) = src_i``, kernel ``r^2 log r`` centred at
    ``dst``, solved in float64, laid out as kornia's weights."""
    d, s = dst.double(), src.double()
    m = d.shape[1]
    r2 = (d[:, :, None] - d[:, None]).pow(2).sum(-1)
    k = torch.where(r2 > 0, 0.5 * r2 * r2.clamp(min=1e-300).log(), torch.zeros_like(r2))
    p = torch.cat([torch.ones_like(d[..., :1]), d], dim=-1)
    lhs = torch.cat([torch.cat([k, p], -1), torch.cat([p.transpose(1, 2), d.new_zeros(1, 3, 3)], -1)], 1)
    w = torch.linalg.solve(lhs, torch.cat([s, d.new_zeros(1, 3, 2)], 1))
    return w[:, :m].to(dst.dtype), w[:, m:].to(dst.dtype)


def tps_spline(kind: str, dst: Tensor, src: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Kernel centres and weights of the backward map ``dst -> src`` (normalised) that ``warp_image_tps`` takes."""
    if kind == "kornia":
        return (src, *get_tps_transform(dst, src))
    return (dst, *standard_tps(dst, src))


def tps_splines(kind: str, pa: Tensor, pb: Tensor, size: tuple[int, int], frames: int) -> list[tuple[Any, Any, float]]:
    na, nb = to_norm(pa, size)[None], to_norm(pb, size)[None]
    out = []
    for k in range(frames):
        u = k / (frames - 1)
        nk = (1 - u) * na + u * nb
        out.append((tps_spline(kind, nk, na), tps_spline(kind, nk, nb), u))
    return out


def tps_morph(kind: str, a: Tensor, b: Tensor, pa: Tensor, pb: Tensor, frames: int) -> Tensor:
    """The spline morph ``(N, C, H, W)``, the timed path: kornia renders every frame."""
    opts = dict(align_corners=False, padding_mode="border")
    out = [
        torch.lerp(warp_image_tps(a, *sa, **opts), warp_image_tps(b, *sb, **opts), u)
        for sa, sb, u in tps_splines(kind, pa, pb, a.shape[-2:], frames)
    ]
    res = torch.cat(out)
    res[0], res[-1] = a[0], b[0]  # as the fluid morph: the endpoints are the inputs
    return res


def tps_maps(kind: str, pa: Tensor, pb: Tensor, size: tuple[int, int], frames: int) -> tuple[Tensor, Tensor]:
    """The spline morph's backward maps of A and B ``(N, H, W, 2)``, pixels: what ``warp_image_tps`` samples."""
    H, W = size
    grid = to_norm(identity_map(size).reshape(1, -1, 2), size)
    maps = [
        [to_norm(warp_points_tps(grid, *s), size, back=True).view(H, W, 2) for s in (sa, sb)]
        for sa, sb, _ in tps_splines(kind, pa, pb, size, frames)
    ]
    return torch.stack([m[0] for m in maps]), torch.stack([m[1] for m in maps])


# ----------------------------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="the pair at 128x128, 6 frames, 15 fit iterations, 1 repeat", threads=1)
    p.add_argument("--images", metavar="DIR", help="write the middle frames as PNGs into DIR")
    p.add_argument("--repeats", type=int, help="timing repeats (default 3; 1 with --quick)")
    p.add_argument("--frames", type=int, help="frames per morph (default 30; 6 with --quick)")
    p.add_argument("--max-iter", type=int, help="L-BFGS iterations of each fit (default: the settings'; 15 quick)")
    args = p.parse_args(argv)
    size, frames, repeats, max_iter = (128, 6, 1, 15) if args.quick else (None, 30, 3, None)
    frames, repeats = args.frames or frames, args.repeats or repeats
    max_iter = args.max_iter or max_iter
    if frames < 3 or repeats < 1 or (max_iter is not None and max_iter < 1):
        p.error("--frames must be >= 3, --repeats and --max-iter >= 1")
    a, b, pa, pb = load_pair(size)
    size = a.shape[-1]
    info = start("bench_morph", args.threads, " [--quick]" if args.quick else "")
    print(f"the bundled pair, {size}x{size}, {pa.shape[0]} points; {frames} frames, {repeats} repeat(s)")
    extra = {} if max_iter is None else {"max_iter": max_iter}
    settings = {
        (method, inverse): (NaturalSettings if method == "natural" else PaperSettings)(inverse=inverse, **extra)
        for method, inverse in FLUID
    }
    for kind in TPS:
        tps_morph(kind, a, b, pa, pb, 3)  # warm-up
    times: dict[Any, dict[str, list[float]]] = {k: {} for k in [*FLUID, *TPS]}
    rows: dict[Any, dict[str, Any]] = {}
    mids: dict[str, Tensor] = {}
    prefix = "morph"
    for rep in range(repeats):
        for cfg in FLUID:
            log(f"  repeat {rep + 1}/{repeats}: {cfg} ...")
            base = peak_mib()
            t0 = time.perf_counter()
            res = morph(a, b, pa, pb, settings=settings[cfg], frames=frames, progress=False)
            res.frames  # noqa: B018 - renders every frame
            wall = time.perf_counter() - t0
            for k, v in {"wall": wall, **res.seconds}.items():
                times[cfg].setdefault(k, []).append(v)
            if rep == 0:
                rows[cfg] = dict(
                    name=f"fluid {cfg[0]}, inverse {cfg[1]}", evals=res.fit.evaluations, rss=peak_mib(base),
                    fit_err=float(res.fit.error.mean()), fit_max=float(res.fit.error.max()),
                    err=float(res.error.mean()), err_max=float(res.error.max()), message=res.message,
                    a=fold_stats(res.maps), b=fold_stats(res.maps_b),
                )  # fmt: skip
                if cfg[0] == "natural":
                    mids[f"{prefix}_mid_fluid_{cfg[1]}.png"] = res.frames[frames // 2].clone()
            del res
        for kind in TPS:
            log(f"  repeat {rep + 1}/{repeats}: TPS {kind} ...")
            base = peak_mib()
            t0 = time.perf_counter()
            out = tps_morph(kind, a, b, pa, pb, frames)
            times[kind].setdefault("wall", []).append(time.perf_counter() - t0)
            if rep == 0:
                maps_a, maps_b = tps_maps(kind, pa, pb, (size, size), frames)
                rows[kind] = dict(name=f"TPS {kind}", rss=peak_mib(base), a=fold_stats(maps_a), b=fold_stats(maps_b))
                if kind == "kornia":
                    mids[f"{prefix}_mid_tps.png"] = out[frames // 2].clone()
    for k, row in rows.items():
        med = {s: statistics.median(v) for s, v in times[k].items()}
        fluid = "fit" in med
        row.update(
            total=f"{med['wall']:.2f}", total_s=med["wall"], repeats=" ".join(f"{x:.2f}" for x in times[k]["wall"]),
            fit=f"{med['fit']:.2f}" if fluid else "-", inverse=f"{med['inverse']:.2f}" if fluid else "-",
            render=f"{med.get('render', med['wall']):.2f}", evals=row.get("evals", "-"),
            ms_eval=f"{1e3 * med['fit'] / max(row['evals'], 1):.0f}" if fluid else "-",
            **{f"{side}_{s}": v for side in "ab" for s, v in row[side].items()},
        )  # fmt: skip
    print("\nTime of a whole morph, s (medians over the repeats; the fluid's split as result.seconds reports it)")
    spec = "morph {name} | total s {total} | fit s {fit} | inverse s {inverse} | render s {render} | fit evals {evals}"
    print(
        rows_table(list(rows.values()), spec + " | ms/eval {ms_eval} | peak RSS +MiB {rss:.0f} | repeats s {repeats}")
    )
    base = rows[FLUID[0]]["total_s"]
    ratios = ", ".join(f"{r['name']} {r['total_s'] / base:.3f}x" for k, r in rows.items() if k != FLUID[0])
    print(f"ratios to {rows[FLUID[0]]['name']}: {ratios}")
    print("\nFolds: Jacobian determinant <= 0 of the backward maps, all frames (inside: where the map reads inside)")
    spec = "morph {name} | A folded {a_fraction:.3%} | A inside {a_inside:.3%} | A frames {a_frames} | A worst frame "
    spec += "{a_worst:.3%} | A min det {a_min_det:.3g} | B folded {b_fraction:.3%} | B inside {b_inside:.3%} | "
    print(rows_table(list(rows.values()), spec + "B frames {b_frames} | B min det {b_min_det:.3g}"))
    print("\nPoint errors, px: in the fluid box's frame (result.fit.error) and in the frames' pixels (result.error)")
    spec = "morph {name} | fit.error mean {fit_err:.2f} | max {fit_max:.2f} | error mean {err:.2f} | max {err_max:.2f}"
    print(rows_table([rows[c] for c in FLUID], spec))
    for cfg in FLUID:
        print(f"  {rows[cfg]['name']}: {rows[cfg].pop('message')}")
    targets: dict[str, Any] = {}
    judged = (frames, size) == TIME_TARGET
    for cfg in FLUID:
        r = rows[cfg]
        met = r["total_s"] < TIME_TARGET_S if judged and cfg[1] == "flow" else None
        targets[f"time {r['name']}"], targets[f"folds {r['name']}"] = met, r["a_fraction"] == 0
        if cfg[1] == "flow":
            print(f"{r['name']}: {frames}-frame {size}x{size} morph {r['total_s']:.2f} s (target < {TIME_TARGET_S:g} s "
                  f"at {TIME_TARGET}) -> {verdict(met) if judged else 'not judged (other size)'}")  # fmt: skip
        print(f"{r['name']}: A's maps fold on {r['a_fraction']:.3%} (target 0) -> {verdict(r['a_fraction'] == 0)}")
    if args.images:
        Path(args.images).mkdir(parents=True, exist_ok=True)
        for name, image in mids.items():
            print(f"wrote {write_image(Path(args.images) / name, image)}")
    for r in rows.values():
        del r["a"], r["b"]
    finish(info, {"args": vars(args), "size": size, "frames": frames, "rows": list(rows.values()), "targets": targets},
           args.json)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
