"""Benchmark of augmentation and registration: cost per image, folds at comparable displacement, a fit.

Three measurements, float32 on CPU unless stated, through the public API:

1. **Cost per image** at 224 x 224 and 512 x 512 (RGB float): :class:`torchfluidwarp.augment.tensor.RandomFluidWarp`
   on a batch of ``--batch`` images (one draw and one fluid roll-out per sample, batched) and on single
   images, the torchvision v2 transform :class:`torchfluidwarp.augment.transforms.RandomFluidWarp` on single
   ``tv_tensors.Image`` s, and torchvision's ``v2.ElasticTransform`` (defaults: alpha 50, sigma 5) on single
   images, its baseline, in the same process. Medians of interleaved repeats, after a warm-up.
2. **Folds at comparable displacement**: the fraction of pixels whose backward map has a Jacobian
   determinant <= 0 (central differences, :func:`torchfluidwarp.warp.layer.jacobian_determinant`), and the mean
   displacement magnitude in pixels, over ``--draws`` draws at 224 x 224. ElasticTransform's map is
   ``identity + displacement`` in normalised coordinates (``make_params``' ``"displacement"``, ``(1, H, W, 2)``,
   ``x`` first; ``F.elastic`` adds it to an ``align_corners=False`` identity grid), so in pixels it reads the
   source at ``x + dx * W / 2``, ``y + dy * H / 2``. ElasticTransform is run at its defaults and with ``alpha``
   scaled so that its mean displacement matches each fluid setting's (displacement is linear in alpha), at
   sigma 5 (its default) and sigma 15 (smoother).
3. **Registration**: :func:`torchfluidwarp.control.images.fit_images` on the pair of
   ``examples/plot_register_images.py`` (the bundled astronaut at 128 x 128 against itself under a known twirl
   and shear, brightness ``0.8 I + 0.1``; loss ``"ncc"``; float64): loss before and after, time, evaluations,
   the smallest Jacobian determinant, and the error of the 23 bundled landmarks against where the known
   deformation took them.

Run ``python benchmarks/bench_augment.py --help`` for the options.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import statistics
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import torch
import torch.nn.functional as F
from _common import add_threads_argument
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


def interleaved_ms(fns: dict[str, Callable[[], Any]], repeats: int) -> dict[str, float]:
    """Median wall time (ms) of each callable, after a warm-up, over ``repeats`` rounds that call each in turn
    (so that load from other processes falls on all of them alike)."""
    times: dict[str, list[float]] = {name: [] for name in fns}
    for fn in fns.values():
        fn()
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    return {name: 1e3 * statistics.median(ts) for name, ts in times.items()}


def photo(size: int, batch: int = 1) -> Tensor:
    img = F.interpolate(
        load_sample("astronaut"), size=(size, size), mode="bilinear", antialias=True, align_corners=False
    )
    return img.expand(batch, -1, -1, -1).contiguous()


# ----------------------------------------------------------------------------------------------- cost


def bench_cost(sizes: list[int], batch: int, repeats: int) -> list[dict[str, Any]]:
    rows = []
    for n in sizes:
        single, many = photo(n), photo(n, batch)
        image = tv_tensors.Image(single[0])
        ours = RandomFluidWarp(generator=torch.Generator().manual_seed(SEED))
        ours_tv = RandomFluidWarpV2(generator=torch.Generator().manual_seed(SEED))
        elastic = v2.ElasticTransform()
        reps = repeats if n <= 256 else max(3, repeats // 2)
        with torch.no_grad():
            ms = interleaved_ms(
                {
                    "elastic": partial(elastic, image),
                    "single": partial(ours, single),
                    "batch": partial(ours, many),
                    "tv": partial(ours_tv, image),
                },
                reps,
            )
        row = {
            "size": n,
            "repeats": reps,
            "elastic_ms": ms["elastic"],
            "ours_single_ms": ms["single"],
            "ours_batch_ms": ms["batch"] / batch,
            "ours_tv_ms": ms["tv"],
        }
        row["single_ratio"] = row["ours_single_ms"] / row["elastic_ms"]
        row["batch_ratio"] = row["ours_batch_ms"] / row["elastic_ms"]
        rows.append(row)
        print(
            f"{n}x{n}: ElasticTransform {row['elastic_ms']:.1f} ms/image; RandomFluidWarp single "
            f"{row['ours_single_ms']:.1f} ms ({row['single_ratio']:.2f}x), batch of {batch} "
            f"{row['ours_batch_ms']:.1f} ms/image ({row['batch_ratio']:.2f}x), v2 transform "
            f"{row['ours_tv_ms']:.1f} ms",
            flush=True,
        )
    return rows


# ----------------------------------------------------------------------------------------------- folds


def map_stats(maps: Tensor) -> tuple[float, float, float]:
    """Mean displacement (px), fraction of pixels with det <= 0, and the smallest det of ``(B, H, W, 2)`` maps."""
    H, W = maps.shape[1:3]
    disp = (maps - identity_map((H, W), dtype=maps.dtype)).norm(dim=-1)
    det = jacobian_determinant(maps)
    return float(disp.mean()), float((det <= 0).double().mean()), float(det.min())


def elastic_maps(alpha: float, sigma: float, n: int, draws: int) -> Tensor:
    """Backward maps ``(draws, n, n, 2)`` in pixels of ElasticTransform's draws."""
    t = v2.ElasticTransform(alpha=alpha, sigma=sigma)
    probe = tv_tensors.Image(torch.zeros(1, n, n))
    scale = torch.tensor([n / 2, n / 2])  # normalised (align_corners=False) -> pixels: W / 2, H / 2
    disp = torch.cat([t.make_params([probe])["displacement"] for _ in range(draws)])  # (draws, n, n, 2)
    return identity_map((n, n)) + disp * scale


def bench_folds(n: int, draws: int) -> list[dict[str, Any]]:
    rows = []
    torch.manual_seed(SEED)  # ElasticTransform draws from torch's global RNG
    unit = {s: map_stats(elastic_maps(1.0, s, n, draws))[0] for s in (5.0, 15.0)}  # mean px per unit alpha
    mean, folded, det = map_stats(elastic_maps(50.0, 5.0, n, draws))
    rows.append(
        {
            "method": "ElasticTransform",
            "setting": "defaults: alpha 50, sigma 5",
            "mean_disp": mean,
            "folded": folded,
            "min_det": det,
            "retried": None,
        }
    )
    for name, kw in SETTINGS.items():
        aug = RandomFluidWarp(generator=torch.Generator().manual_seed(SEED), **kw)
        params = aug.make_params(draws, (n, n))
        mean, folded, det = map_stats(fluid_warp_map(params))
        retried = float((params.force_scale < 1).double().mean())
        desc = ", ".join(f"{k} {v}" for k, v in kw.items()) or "defaults"
        rows.append(
            {
                "method": "RandomFluidWarp",
                "setting": desc,
                "mean_disp": mean,
                "folded": folded,
                "min_det": det,
                "retried": retried,
            }
        )
        target = mean
        for sigma in (5.0, 15.0):
            alpha = target / unit[sigma]
            m, f, d = map_stats(elastic_maps(alpha, sigma, n, draws))
            rows.append(
                {
                    "method": "ElasticTransform",
                    "setting": f"alpha {alpha:.1f}, sigma {sigma:g} (matches '{name}')",
                    "mean_disp": m,
                    "folded": f,
                    "min_det": d,
                    "retried": None,
                }
            )
    for r in rows:
        extra = "" if r["retried"] is None else f", re-rolled at half force: {r['retried']:.1%} of samples"
        print(
            f"{r['method']:17s} {r['setting']:62s} mean displacement {r['mean_disp']:6.2f} px, folded "
            f"{r['folded']:.4%}, min det {r['min_det']:.3f}{extra}",
            flush=True,
        )
    return rows


# ----------------------------------------------------------------------------------------------- registration


def registration_pair(n: int = 128) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The pair of ``examples/plot_register_images.py``: source, target, landmarks and where they truly went."""
    src = photo(n).double()
    marks = ((load_sample_points("astronaut") + 0.5) * n / 512 - 0.5).double()

    def backward(p: Tensor) -> Tensor:
        c = torch.tensor([66.0, 44.0], dtype=p.dtype) * n / 128
        d = p - c
        angle = math.radians(18.0) * torch.exp(-(d**2).sum(-1) / (2 * (22.0 * n / 128) ** 2))
        rot = torch.stack(
            [d[..., 0] * angle.cos() - d[..., 1] * angle.sin(), d[..., 0] * angle.sin() + d[..., 1] * angle.cos()], -1
        )
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
    fit = fit_images(
        src, tgt, loss="ncc", grid=32, levels=(8, 16, 32), steps=8, control=(5, 5), max_iter=max_iter, progress=False
    )
    with torch.no_grad():
        carried = fit.warp.carry_points(marks[None], fit.forces, tuple(src.shape[-2:]))[0, -1]
    row = {
        "initial_loss": fit.initial_loss,
        "final_loss": fit.final_loss,
        "seconds": fit.seconds,
        "evaluations": fit.evaluations,
        "min_det": float(fit.min_det.min()),
        "landmarks_before": float((marks - truth).norm(dim=-1).mean()),
        "landmarks_after": float((carried - truth).norm(dim=-1).mean()),
        "landmarks_after_max": float((carried - truth).norm(dim=-1).max()),
        "max_iter": list(max_iter),
    }
    print(
        f"fit_images: 1 - NCC {row['initial_loss']:.4f} -> {row['final_loss']:.4f} "
        f"({row['final_loss'] / row['initial_loss']:.1%}) in {row['seconds']:.1f} s, {row['evaluations']} "
        f"evaluations, min det {row['min_det']:.3f}; landmark error {row['landmarks_before']:.2f} -> "
        f"{row['landmarks_after']:.2f} px mean ({row['landmarks_after_max']:.2f} px max)",
        flush=True,
    )
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_threads_argument(parser)
    parser.add_argument("--batch", type=int, default=8, help="batch size of the batched RandomFluidWarp timing")
    parser.add_argument("--repeats", type=int, default=10, help="timing repeats at 224 (half at 512)")
    parser.add_argument("--draws", type=int, default=32, help="draws per setting for the fold statistics")
    parser.add_argument("--quick", action="store_true", help="a smoke run: fewer repeats, draws and iterations")
    parser.add_argument("--json", help="also write the results to this file")
    parser.add_argument(
        "--only",
        choices=["cost", "folds", "registration"],
        action="append",
        help="run only this part (repeatable; default: all three)",
    )
    args = parser.parse_args()
    parts = set(args.only or ["cost", "folds", "registration"])
    torch.set_num_threads(args.threads)
    if args.quick:
        args.repeats, args.draws = 3, 4
    machine = platform.processor() or platform.machine()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} thread(s), {machine}")
    start = time.perf_counter()
    results = {
        "date": datetime.date.today().isoformat(),
        "threads": args.threads,
        "batch": args.batch,
    }
    if "cost" in parts:
        results["cost"] = bench_cost([224, 512], args.batch, args.repeats)
    if "folds" in parts:
        results["folds"] = bench_folds(224, args.draws)
    if "registration" in parts:
        results["registration"] = bench_registration((5, 5, 5) if args.quick else (20, 15, 25))
    results["seconds"] = time.perf_counter() - start
    print(f"total {results['seconds']:.0f} s")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
