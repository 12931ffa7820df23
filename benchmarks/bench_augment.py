"""Benchmark of augmentation and registration: cost per image, folds at comparable displacement, a fit.

Float32 on CPU: (1) the cost per image of ``RandomFluidWarp`` (tensor-level, batched and single; and the
torchvision v2 transform) against torchvision's ``v2.ElasticTransform``; (2) the fraction of folded pixels and
the mean displacement over ``--draws`` draws, ElasticTransform at its defaults and at the fluid's displacement;
(3) ``fit_images`` on the pair of ``examples/plot_register_images.py``. Set-up and figures: docs/benchmarks.md,
"Augmentation and registration".
"""

from __future__ import annotations

import math
import sys
from functools import partial
from typing import Any

import torch
import torch.nn.functional as F
from _common import finish, interleaved, medians_ms, parser, rows_table, start
from torch import Tensor
from torchvision import tv_tensors
from torchvision.transforms import v2

from torchfluidwarp.augment import FluidWarpAugment as RandomFluidWarp
from torchfluidwarp.augment import fluid_warp_map
from torchfluidwarp.augment.transforms import RandomFluidWarp as RandomFluidWarpV2
from torchfluidwarp.control import fit_images
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.warp import identity_map, jacobian_determinant, warp_image

SEED = 1234
SETTINGS: dict[str, dict[str, Any]] = {
    "default": {},
    "strong": {"count": (2, 4), "strength": (0.4, 0.7), "radius": (24.0, 48.0), "steps": (6, 8)},
    "strongest": {"count": 4, "strength": 1.0, "radius": (32.0, 64.0), "steps": 8},  # at the fold bound
}


def photo(size: int, batch: int = 1) -> Tensor:
    img = F.interpolate(load_sample("astronaut"), size=(size, size), mode="bilinear", antialias=True,
                        align_corners=False)  # fmt: skip
    return img.expand(batch, -1, -1, -1).contiguous()


def bench_cost(sizes: list[int], batch: int, repeats: int) -> list[dict[str, Any]]:
    """ms per image of each augmentation, medians of interleaved repeats (half as many at 512)."""
    rows = []
    for n in sizes:
        single, many = photo(n), photo(n, batch)
        image = tv_tensors.Image(single[0])
        ours = RandomFluidWarp(generator=torch.Generator().manual_seed(SEED))
        ours_tv = RandomFluidWarpV2(generator=torch.Generator().manual_seed(SEED))
        reps = repeats if n <= 256 else max(3, repeats // 2)
        cases = {"elastic": partial(v2.ElasticTransform(), image), "single": partial(ours, single),
                 "batch": partial(ours, many), "tv": partial(ours_tv, image)}  # fmt: skip
        with torch.no_grad():
            ms = medians_ms(interleaved(cases, reps))
        row = dict(size=n, repeats=reps, elastic_ms=ms["elastic"], ours_single_ms=ms["single"],
                   ours_batch_ms=ms["batch"] / batch, ours_tv_ms=ms["tv"])  # fmt: skip
        row.update(single_ratio=row["ours_single_ms"] / row["elastic_ms"],
                   batch_ratio=row["ours_batch_ms"] / row["elastic_ms"])  # fmt: skip
        rows.append(row)
    print(rows_table(rows, f"size {{size}} | ElasticTransform ms/image {{elastic_ms:.1f}} | RandomFluidWarp single ms "
          f"{{ours_single_ms:.1f}} | single / elastic {{single_ratio:.2f}}x | batch of {batch} ms/image "
          "{ours_batch_ms:.1f} | batch / elastic {batch_ratio:.2f}x | v2 transform ms {ours_tv_ms:.1f}"))  # fmt: skip
    return rows


def map_stats(maps: Tensor) -> tuple[float, float, float]:
    """Mean displacement (px), fraction of pixels with det <= 0, and the smallest det of ``(B, H, W, 2)`` maps."""
    H, W = maps.shape[1:3]
    disp = (maps - identity_map((H, W), dtype=maps.dtype)).norm(dim=-1)
    det = jacobian_determinant(maps)
    return float(disp.mean()), float((det <= 0).double().mean()), float(det.min())


def elastic_maps(alpha: float, sigma: float, n: int, draws: int) -> Tensor:
    """Backward maps ``(draws, n, n, 2)`` in pixels of ElasticTransform's draws: its ``"displacement"`` is added
    to an ``align_corners=False`` identity grid in normalised coordinates, ``x`` first."""
    t = v2.ElasticTransform(alpha=alpha, sigma=sigma)
    probe = tv_tensors.Image(torch.zeros(1, n, n))
    disp = torch.cat([t.make_params([probe])["displacement"] for _ in range(draws)])  # (draws, n, n, 2)
    return identity_map((n, n)) + disp * torch.tensor([n / 2, n / 2])


def bench_folds(n: int, draws: int, device: str | None = None) -> list[dict[str, Any]]:
    """Folds and mean displacement of each fluid setting (drawn on ``device``), and of ElasticTransform at its
    defaults and at alphas that match each setting's displacement (linear in alpha) at sigma 5 and 15."""
    torch.manual_seed(SEED)  # ElasticTransform draws from torch's global RNG
    unit = {s: map_stats(elastic_maps(1.0, s, n, draws))[0] for s in (5.0, 15.0)}  # mean px per unit alpha
    stats = lambda method, setting, maps, retried="": dict(zip(("mean_disp", "folded", "min_det"), map_stats(maps)),
                                                           method=method, setting=setting, retried=retried)  # fmt: skip
    rows = [stats("ElasticTransform", "defaults: alpha 50, sigma 5", elastic_maps(50.0, 5.0, n, draws))]
    for name, kw in SETTINGS.items():
        draw = RandomFluidWarp(generator=torch.Generator().manual_seed(SEED), **kw)
        params = draw.make_params(draws, (n, n), device=device)
        retried = f"{float((params.force_scale < 1).double().mean()):.1%}"
        desc = ", ".join(f"{k} {v}" for k, v in kw.items()) or "defaults"
        rows.append(fluid := stats("RandomFluidWarp", desc, fluid_warp_map(params).cpu(), retried))
        for sigma in (5.0, 15.0):
            alpha = fluid["mean_disp"] / unit[sigma]
            setting = f"alpha {alpha:.1f}, sigma {sigma:g} (matches '{name}')"
            rows.append(stats("ElasticTransform", setting, elastic_maps(alpha, sigma, n, draws)))
    print(rows_table(rows, "method {method} | setting {setting} | mean displacement px {mean_disp:.2f} | folded "
          "{folded:.4%} | min det {min_det:.3f} | re-rolled at half force {retried}"))  # fmt: skip
    return rows


def registration_pair(n: int = 128) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The pair of ``examples/plot_register_images.py``: source, target, landmarks and where they truly went."""
    src = photo(n).double()
    marks = ((load_sample_points("astronaut") + 0.5) * n / 512 - 0.5).double()

    def backward(p: Tensor) -> Tensor:
        c = torch.tensor([66.0, 44.0], dtype=p.dtype) * n / 128
        d = p - c
        angle = math.radians(18.0) * torch.exp(-(d**2).sum(-1) / (2 * (22.0 * n / 128) ** 2))
        rot = torch.stack([d[..., 0] * angle.cos() - d[..., 1] * angle.sin(),
                           d[..., 0] * angle.sin() + d[..., 1] * angle.cos()], -1)  # fmt: skip
        shear = 2.0 * torch.stack([torch.sin(2 * math.pi * p[..., 1] / n), torch.sin(2 * math.pi * p[..., 0] / n)], -1)
        return c + rot + shear

    moved = marks.clone()
    for _ in range(50):  # forward map by fixed-point iteration on the backward one
        moved = moved - (backward(moved) - marks)
    tgt = 0.8 * warp_image(src, backward(identity_map((n, n), dtype=torch.float64))) + 0.1
    return src, tgt, marks, moved


def bench_registration(max_iter: tuple[int, ...]) -> dict[str, Any]:
    src, tgt, marks, truth = registration_pair()
    torch.optim.LBFGS([torch.zeros(1, requires_grad=True)])  # the first LBFGS in a process imports torch._dynamo
    fit = fit_images(src, tgt, loss="ncc", compressible=False, grid=32, levels=(8, 16, 32), steps=8, control=(5, 5),
                     max_iter=max_iter, progress=False)  # fmt: skip
    with torch.no_grad():
        err = (fit.warp.carry_points(marks[None], fit.forces, tuple(src.shape[-2:]))[0, -1] - truth).norm(dim=-1)
    row = dict(initial_loss=fit.initial_loss, final_loss=fit.final_loss, seconds=fit.seconds,
               evaluations=fit.evaluations, min_det=float(fit.min_det.min()), max_iter=list(max_iter),
               landmarks_before=float((marks - truth).norm(dim=-1).mean()), landmarks_after=float(err.mean()),
               landmarks_after_max=float(err.max()))  # fmt: skip
    print(f"fit_images: 1 - NCC {row['initial_loss']:.4f} -> {row['final_loss']:.4f} "
          f"({row['final_loss'] / row['initial_loss']:.1%}) in {row['seconds']:.1f} s, {row['evaluations']} "
          f"evaluations, min det {row['min_det']:.3f}; landmark error {row['landmarks_before']:.2f} -> "
          f"{row['landmarks_after']:.2f} px mean ({row['landmarks_after_max']:.2f} px max)", flush=True)  # fmt: skip
    return row


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="3 repeats, 4 draws, 5 iterations a level")
    p.add_argument("--batch", type=int, default=8, help="batch size of the batched RandomFluidWarp timing")
    p.add_argument("--repeats", type=int, default=10, help="timing repeats at 224 (half at 512)")
    p.add_argument("--draws", type=int, default=32, help="draws per setting for the fold statistics")
    p.add_argument("--only", choices=["cost", "folds", "registration"], action="append",
                   help="run only this part (repeatable; default: all three)")  # fmt: skip
    args = p.parse_args(argv)
    parts = set(args.only or ["cost", "folds", "registration"])
    if args.quick:
        args.repeats, args.draws = 3, 4
    info = start("bench_augment", args.threads, " [--quick]" if args.quick else "")
    results: dict[str, Any] = {"args": vars(args)}
    if "cost" in parts:
        results["cost"] = bench_cost([224, 512], args.batch, args.repeats)
    if "folds" in parts:
        results["folds"] = bench_folds(224, args.draws)
    if "registration" in parts:
        results["registration"] = bench_registration((5, 5, 5) if args.quick else (20, 15, 25))
    finish(info, results, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
