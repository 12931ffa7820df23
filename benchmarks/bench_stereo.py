"""Dense correspondence on a real stereo pair, scored against its true disparity: what a morph aligns unmarked.

scikit-image's stereo motorcycle at full size (741 x 500), the views as they are (the median disparity, about 40 px,
is not cropped away): A is the right view and B the left one, so a morph's last map (output pixel -> A's pixel)
should be ``(x - d(x), y)``, ``d`` the left view's disparity. Rows: no motion; ``morph(A, B,
match=Matching("pixels"))`` with ``--settings`` (row ``fluid``) and each ``--config`` (as in
``bench_morph_quality.py``); the thin-plate-spline and Delaunay morphs through the points the pixels place
(``auto_points(A, B, match="pixels")``, what the morph is given); ``fit_images`` with its defaults; scikit-image's
TV-L1 and OpenCV's DIS flow (``PRESET_MEDIUM``, when ``cv2`` imports) on the grey pair; and the true map, the floor
of the ghosting figures. Definitions: benchmarks/README.md.
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from _common import finish, fmt, log, parser, settings_arg, start, table
from bench_morph_quality import Pair, config_arg, covered, picture_ghost, run_method, sheet_frames, write_sheet
from torch import Tensor

from torchfluidwarp.control import fit_images
from torchfluidwarp.correspond import auto_points
from torchfluidwarp.metrics import folded_pixels, image_ghosting
from torchfluidwarp.warp import identity_map, warp_image

MARGIN = 0.05
"""The fraction of the shorter side left out of the end-point error along every edge."""


def load_stereo(scale: float = 1.0) -> tuple[Tensor, Tensor, Tensor]:
    """``(A, B, disparity)``: the right and the left view ``(1, 3, H, W)`` float32 in ``[0, 1]`` and the left
    view's disparity ``(H, W)`` float64 in pixels (NaN where unknown): left pixel ``(x, y)`` shows in the right view
    at ``(x - d, y)``. ``scale < 1`` area-averages all three (a disparity where any part is unknown is unknown)."""
    from skimage.data import stereo_motorcycle

    left, right, disp = stereo_motorcycle()

    def tensor(x: np.ndarray) -> Tensor:
        t = torch.from_numpy(np.ascontiguousarray(x)).permute(2, 0, 1)[None].float() / 255
        return t if scale == 1 else F.interpolate(t, scale_factor=scale, mode="area")

    d = torch.from_numpy(np.where(np.isfinite(disp), disp, np.nan)).double()[None, None]
    if scale != 1:
        known = F.interpolate(d.isfinite().double(), scale_factor=scale, mode="area") > 1 - 1e-9
        d = torch.where(known, F.interpolate(torch.nan_to_num(d), scale_factor=scale, mode="area") * scale, torch.nan)
    return tensor(right), tensor(left), d[0, 0]


def true_map(disp: Tensor) -> Tensor:
    """``(H, W, 2)`` float64: where each of B's pixels shows in A, ``(x - d, y)`` (NaN where ``d`` is)."""
    ident = identity_map(tuple(disp.shape), dtype=torch.float64)[0]
    return torch.stack([ident[..., 0] - disp, ident[..., 1]], dim=-1)


def scored(disp: Tensor) -> Tensor:
    """``(H, W)`` bool: the pixels with a known disparity, :data:`MARGIN` of the shorter side from every edge."""
    m = max(1, round(MARGIN * min(disp.shape)))
    keep = disp.isfinite()
    keep[:m] = keep[-m:] = False
    keep[:, :m] = keep[:, -m:] = False
    return keep


def grey(image: Tensor) -> np.ndarray:
    """``(1, 3, H, W)`` in ``[0, 1]`` as ``(H, W)`` float64: ITU-R 601 luma, OpenCV's ``COLOR_RGB2GRAY``."""
    w = image.new_tensor([0.299, 0.587, 0.114]).view(1, 3, 1, 1)
    return (image * w).sum(1)[0].double().numpy()


def tvl1_map(a: Tensor, b: Tensor) -> Tensor:
    """scikit-image's TV-L1 flow from B to A, with its defaults, as a map ``(H, W, 2)``."""
    from skimage.registration import optical_flow_tvl1

    v, u = optical_flow_tvl1(grey(b), grey(a))  # b(r, c) ~ a(r + v, c + u)
    return identity_map(tuple(a.shape[-2:]), dtype=torch.float64)[0] + torch.from_numpy(np.stack([u, v], -1))


def dis_map(a: Tensor, b: Tensor) -> Tensor | None:
    """OpenCV's DIS flow from B to A (``PRESET_MEDIUM``) as a map ``(H, W, 2)``; ``None`` without ``cv2``."""
    try:
        import cv2
    except ImportError:
        return None

    def u8(x: Tensor) -> np.ndarray:
        return np.ascontiguousarray((grey(x) * 255).round().astype(np.uint8))

    flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(u8(b), u8(a), None)  # (H, W, 2)
    return identity_map(tuple(a.shape[-2:]), dtype=torch.float64)[0] + torch.from_numpy(flow).double()


def fit_images_map(a: Tensor, b: Tensor) -> tuple[Tensor, dict[str, Any]]:
    """``fit_images(A, B)`` with its defaults: its last map ``(H, W, 2)`` and what it said."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = fit_images(a, b, progress=False)
    with torch.no_grad():
        last = fit.warp.maps(fit.forces, tuple(a.shape[-2:]))[0, -1]
    info = {"warnings": sorted({str(w.message) for w in caught}), "loss_ratio": fit.final_loss / fit.initial_loss}
    return last, info


def score(last: Tensor, truth: Tensor, keep: Tensor, a: Tensor, b: Tensor) -> dict[str, Any]:
    """The end-point error of a last map ``(H, W, 2)`` against ``truth`` over ``keep``, and the last frame's
    picture ghosting: A read through the map against B, where the map reads inside A."""
    last = last.detach().cpu().double()
    err = (last - truth).norm(dim=-1)[keep]
    dy = (last[..., 1] - truth[..., 1]).abs()[keep]
    warped = warp_image(a, last[None].float())
    ghost = image_ghosting(warped, b, covered(last, tuple(a.shape[-2:])))
    return dict(epe_mean=float(err.mean()), epe_median=float(err.median()), dy_mean=float(dy.mean()),
                last_ghost_px=ghost["median"], last_ghost=ghost, pixels=int(keep.sum()))  # fmt: skip


def stereo_table(rows: dict[str, dict[str, Any]]) -> str:
    none = rows["no motion"]["epe_mean"]
    out = []
    for label, r in rows.items():
        folded = "—" if r.get("folded") is None else str(r["folded"])  # no motion, the true map: no fit
        out.append([label, fmt(r["epe_mean"]), fmt(r["epe_median"]), fmt(r["dy_mean"]), f"{r['epe_mean'] / none:.2f}x",
                    fmt(r.get("mid_ghost_px")), fmt(r["last_ghost_px"]), folded,
                    str(len(r.get("warnings", [])))])  # fmt: skip
    heads = ["method", "end-point error (mean)", "end-point error (median)", "vertical error (mean)", "EPE / no motion"]
    return table([*heads, "middle picture ghost", "last picture ghost", "folded px", "warnings"], out, markdown=True)


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="half size, 5 frames, 10 fit iterations")
    p.add_argument("--frames", type=int, default=21, help="frames per morph (default 21)")
    p.add_argument("--settings", type=settings_arg, default={}, metavar="JSON", help="the fluid row's settings")
    p.add_argument("--config", type=config_arg, action="append", default=[], metavar="NAME=JSON",
                   help="another fluid row NAME with these settings (repeatable)")  # fmt: skip
    p.add_argument("--scale", type=float, default=1.0, help="working size (default 1: full size, 741 x 500)")
    p.add_argument("--sheets", metavar="DIR", help="write the pair's contact sheet into DIR")
    args = p.parse_args(argv)
    if args.quick:
        args.frames, args.scale = 5, 0.5
        args.settings = {**args.settings, "max_iter": 10}
    if args.frames < 2:
        p.error(f"--frames must be >= 2, got {args.frames}")
    info = start("bench_stereo", args.threads, " [--quick]" if args.quick else "", argv)
    a, b, disp = load_stereo(args.scale)
    H, W = disp.shape
    truth, keep = true_map(disp), scored(disp)
    d = disp[keep]
    print(f"stereo motorcycle {W} x {H}, A = right view, B = left view; {int(keep.sum())} pixels scored, disparity "
          f"{float(d.min()):.1f} to {float(d.max()):.1f} px, median {float(d.median()):.1f}")  # fmt: skip
    rows: dict[str, dict[str, Any]] = {}
    ident = identity_map((H, W), dtype=torch.float64)[0]
    rows["no motion"] = score(ident, truth, keep, a, b)
    rows["no motion"]["mid_ghost_px"] = rows["no motion"]["last_ghost_px"]  # a cross-dissolve of A and B as they are
    known = torch.where(truth.isfinite(), truth, ident)  # the true map, the identity where it is unknown
    rows["true map"] = {**score(known, truth, keep, a, b), "mid_ghost_px": None}
    sheet: dict[str, list[Tensor]] = {}
    t0 = time.perf_counter()
    pa, pb = auto_points(a, b, match="pixels")
    log(f"  the pixels placed {len(pa)} points ({time.perf_counter() - t0:.0f} s)")
    empty = torch.zeros(0, 2)
    marked = Pair("stereo_motorcycle", "stereo", a, b, pa.float(), pb.float(), empty, empty)
    unmarked = Pair("stereo_motorcycle", "stereo", a, b, None, None, empty, empty)
    morphs = [
        ("tps", "tps", {}, marked),
        ("delaunay", "delaunay", {}, marked),
        ("fluid", "fluid", args.settings, unmarked),
    ]
    morphs += [(label, "fluid", spec, unmarked) for label, spec in args.config]
    for label, method, spec, pair in morphs:
        res = run_method(method, pair, args.frames, spec)
        maps, maps_b = res.maps.detach().cpu(), res.maps_b.detach().cpu()
        mid = picture_ghost(res, a, b, args.frames // 2)
        folded = int(folded_pixels(maps).sum() + folded_pixels(maps_b).sum())
        rows[label] = {**score(maps[-1], truth, keep, a, b), "mid_ghost_px": mid["median"], "mid_ghost": mid,
                       "folded": folded, "warnings": res.info.get("warnings", []), "seconds": res.seconds}  # fmt: skip
        sheet[label] = sheet_frames(res)
        log(f"  {label}: EPE {fmt(rows[label]['epe_mean'])} px, ghost {fmt(mid['median'])} px, folded {folded}")
        del res
    last, fit_info = fit_images_map(a, b)
    rows["fit_images"] = {**score(last, truth, keep, a, b), "folded": int(folded_pixels(last).sum()), **fit_info}
    flows = {"TV-L1": tvl1_map(a, b), "DIS (medium)": dis_map(a, b)}
    for label, flow in flows.items():
        if flow is None:
            print(f"OpenCV (cv2) does not import: no {label} row")
        else:
            rows[label] = {**score(flow, truth, keep, a, b), "folded": int(folded_pixels(flow).sum())}
    print("\n## Stereo motorcycle: the last map against the true disparity\n\n" + stereo_table(rows))
    mid = args.frames // 2
    print(f"\nEnd-point error over {int(keep.sum())} pixels with a known disparity, {MARGIN:.0%} of the shorter "
          f"side from the edges; picture ghosts: medians (px) of metrics.image_ghosting in the middle frame ({mid}) "
          "and the last (A through the map against B).")  # fmt: skip
    if args.sheets:
        Path(args.sheets).mkdir(parents=True, exist_ok=True)
        write_sheet(Path(args.sheets) / "stereo_motorcycle.png", "stereo_motorcycle (A right, B left)", sheet)
        print(f"wrote {Path(args.sheets) / 'stereo_motorcycle.png'} (rows: {', '.join(sheet)})")
    settings = {"fluid": args.settings, **dict(args.config)}
    finish(info, {"size": [H, W], "frames": args.frames, "settings": settings, "rows": rows}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
