"""Fluid image registration on a real pair: scikit-image's stereo motorcycle, scored against its disparity map.

``fit_images`` warps the right view onto the left one after the median disparity is cropped away; the fitted map
is scored against the true one pixel by pixel. Details: benchmarks/README.md; figures: docs/benchmarks.md,
"Registration on a real pair".
"""

from __future__ import annotations

import sys
import time

import numpy as np
import torch
import torch.nn.functional as F
from _common import finish, parser, start

from torchfluidwarp.control import fit_images
from torchfluidwarp.warp import identity_map, jacobian_determinant


def load(scale: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """Left, right (cropped by the median disparity), residual disparity (nan where unknown), the shift."""
    from skimage.data import stereo_motorcycle

    left, right, disp = stereo_motorcycle()
    disp = np.where(np.isfinite(disp), disp, np.nan).astype(np.float64)
    shift = int(round(float(np.nanmedian(disp))))
    W = left.shape[1]
    # left columns [shift, W) against right columns [0, W - shift): a pixel at crop column c sees its
    # match d - shift columns to the left in the right crop
    left_c = left[:, shift:]
    right_c = right[:, : W - shift]
    disp_c = disp[:, shift:] - shift

    def tensor(a: np.ndarray) -> torch.Tensor:
        t = torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)[None].double() / 255.0
        return F.interpolate(t, scale_factor=scale, mode="area")

    d = torch.from_numpy(disp_c)[None, None]
    valid = torch.isfinite(d)
    d_small = F.interpolate(torch.nan_to_num(d), scale_factor=scale, mode="area")
    v_small = F.interpolate(valid.double(), scale_factor=scale, mode="area") > 0.999  # wholly valid pixels only
    d_small = torch.where(v_small, d_small * scale, torch.nan)[0, 0]
    return tensor(left_c), tensor(right_c), d_small, shift


def score(coords: torch.Tensor, disp: torch.Tensor, margin: int) -> dict[str, float]:
    """Map errors against the true backward map ``(x - d, y)`` over valid pixels away from the borders."""
    H, W = disp.shape
    ident = identity_map((H, W), dtype=coords.dtype)[0]
    ex = (coords[0, ..., 0] - (ident[..., 0] - disp)).abs()
    ey = (coords[0, ..., 1] - ident[..., 1]).abs()
    keep = torch.isfinite(disp)
    keep[:margin] = keep[-margin:] = False
    keep[:, :margin] = keep[:, -margin:] = False
    return {
        "x_mean_px": float(ex[keep].mean()),
        "x_median_px": float(ex[keep].median()),
        "y_mean_px": float(ey[keep].mean()),
        "pixels": int(keep.sum()),
    }


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__)
    p.add_argument("--scale", type=float, default=0.5, help="working resolution (default 0.5: 250 px high)")
    args = p.parse_args(argv)
    info = start("bench_register_real", args.threads)
    left, right, disp, shift = load(args.scale)
    H, W = left.shape[-2:]
    margin = max(4, round(0.05 * min(H, W)))
    print(f"stereo motorcycle at {W}x{H} (scale {args.scale}); global shift taken out: {shift} px at full size")
    d = disp[torch.isfinite(disp)]
    print(f"residual disparity over {d.numel()} valid pixels: mean {float(d.mean()):.2f} px, |d| mean "
          f"{float(d.abs().mean()):.2f} px, range {float(d.min()):.1f} to {float(d.max()):.1f} px")  # fmt: skip
    before = score(identity_map((H, W), dtype=torch.float64), disp, margin)
    grid = (48, round(48 * W / H))
    print(f"\nfit_images: grid {grid[0]}x{grid[1]}, levels (12, 24, {max(grid)}), 8 steps, control 6x8, NCC loss")
    print(f"{'map':>28}  1 - NCC  x err mean px  x err median px  y err mean px  min det  evals  time s")
    print(f"{'identity (before)':>28}  {'':7}  {before['x_mean_px']:13.2f}  {before['x_median_px']:15.2f}  "
          f"{before['y_mean_px']:13.2f}")  # fmt: skip
    results = []
    for compressible in (False, True):
        t0 = time.perf_counter()
        fit = fit_images(right, left, loss="ncc", grid=grid, levels=(12, 24, max(grid)), steps=8, control=(6, 8),
                         max_iter=(30, 30, 30), compressible=compressible, progress=False)  # fmt: skip
        seconds = time.perf_counter() - t0
        with torch.no_grad():
            coords = fit.warp.maps(fit.forces, (H, W))[:, -1]
        after = score(coords, disp, margin)
        min_det = float(jacobian_determinant(coords).min())
        name = f"fluid fit, compressible={compressible}"
        print(f"{name:>28}  {fit.final_loss:7.4f}  {after['x_mean_px']:13.2f}  {after['x_median_px']:15.2f}  "
              f"{after['y_mean_px']:13.2f}  {min_det:7.3f}  {fit.evaluations:5d}  {seconds:6.1f}")  # fmt: skip
        folds = "no folds" if min_det > 0 else "FOLDS"
        print(f"{'':>28}  1 - NCC {fit.initial_loss:.4f} -> {fit.final_loss:.4f} "
              f"({fit.final_loss / fit.initial_loss:.1%}); x error {after['x_mean_px'] / before['x_mean_px']:.1%} of "
              f"before; {folds}; {after['pixels']} pixels scored")  # fmt: skip
        results.append(dict(compressible=compressible, after=after, initial_loss=fit.initial_loss,
                            final_loss=fit.final_loss, min_det=min_det, evaluations=fit.evaluations,
                            seconds=seconds))  # fmt: skip
    finish(info, {"size": [H, W], "shift": shift, "grid": grid, "before": before, "fits": results}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
