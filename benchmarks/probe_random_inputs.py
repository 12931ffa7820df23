"""Robustness probe: the fits and the morph on random problems, hard and unreasonable ones included.

Not a timing benchmark: each case draws a random problem from ``--seed``, runs ``fit_keyframes`` (``fit``:
``auto`` against ``lbfgs``), ``morph`` or ``fit_images`` on it, prints a line and counts the outcomes by flag
(``EXC``, ``REFUSED``, ``BLEWUP``, ``NAN``/``NONFINITE``, ``RANGE``, ``SHAPE``, ``FIRST``, ``SLOW``, ``WORSE``,
``FOLD``; see benchmarks/README.md). Figures: docs/benchmarks.md, "Hard and unreasonable problems".
"""

from __future__ import annotations

import argparse
import collections
import math
import sys
import time
import traceback
import warnings
from collections.abc import Callable

import torch
import torch.nn.functional as F

from torchfluidwarp import fit_images, fit_keyframes, morph
from torchfluidwarp.errors import FlowBlewUp, InputError, InputTypeError
from torchfluidwarp.morph import Blending, NaturalSettings, PaperSettings


class Draw:
    """Random draws from one seeded generator, so that case ``k`` of a seed is the same problem every run."""

    def __init__(self, seed: int) -> None:
        self.g = torch.Generator().manual_seed(seed)

    def u(self) -> float:
        return float(torch.rand(1, generator=self.g))

    def i(self, lo: int, hi: int) -> int:
        return int(torch.randint(lo, hi, (1,), generator=self.g))

    def pick(self, options: list):
        return options[self.i(0, len(options))]

    def rand(self, *shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=self.g)

    def randn(self, *shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=self.g)


Case = tuple[str, Callable[[], tuple[str, str]]]  # what was drawn, and the run: (flags, what came out)


def fit_case(d: Draw) -> Case:
    H, W, g, gw = d.i(24, 120), d.i(24, 120), d.i(8, 40), d.i(8, 40)
    steps, k, M, B = d.i(1, 12), (d.i(2, 7), d.i(2, 7)), d.i(1, 20), d.i(1, 3)
    scale = d.u() * 0.3 * min(H, W)
    hi = torch.tensor([W - 1.0, H - 1.0])
    src = d.rand(B, M, 2) * hi
    tgt = torch.minimum((src + scale * d.randn(B, M, 2)).clamp(min=0), hi)
    visc, comp = d.pick([0.0, 0.0, 0.05, 0.5]), d.pick([False, False, True, 0.5])
    dtype = d.pick([torch.float32, torch.float64])
    two = d.u() < 0.3 and steps >= 2
    target = [(steps // 2, (src + tgt) / 2), (steps, tgt)] if two else tgt
    if B == 1:
        src, target = src[0], ([(t, p[0]) for t, p in target] if two else tgt[0])
    desc = f"img {H}x{W} grid {g}x{gw} T={steps} K={k} M={M} B={B} scale={scale:.1f} visc={visc} comp={comp}"
    desc += f" {str(dtype)[6:]} keyframes={2 if two else 1}"

    def run() -> tuple[str, str]:
        res = {}
        kwargs = dict(image_size=(H, W), grid=(g, gw), steps=steps, control=k, viscosity=visc, compressible=comp,
                      dtype=dtype, progress=False, max_iter=200)  # fmt: skip
        for method in ("auto", "lbfgs"):
            t0 = time.perf_counter()
            fit = fit_keyframes(src, target, method=method, **kwargs)
            err = max(float(e.max()) for _, e in fit.keyframe_errors)
            res[method] = (err, time.perf_counter() - t0, fit.forwards, fit.evaluations)
        (ea, ta, fw, ev), (el, tl, _, evl) = res["auto"], res["lbfgs"]
        flag = "NAN" if not math.isfinite(ea) else "WORSE" if ea > max(1.5 * el, el + 0.05) else "ok"
        auto = f"auto {ea:.4f} px in {ta:.2f} s ({fw} roll-outs + {ev} evals)"
        return flag, f"{auto}; lbfgs {el:.4f} px in {tl:.2f} s ({evl} evals)"

    return desc, run


def morph_case(d: Draw) -> Case:
    H, W = d.i(32, 160), d.i(32, 160)
    Hb, Wb = (H, W) if d.u() < 0.6 else (d.i(32, 160), d.i(32, 160))
    C = d.pick([1, 3, 3, 4])
    A, B = d.rand(C, H, W), d.rand(C, Hb, Wb)
    M = d.i(3, 30)
    pa = d.rand(M, 2) * torch.tensor([W - 1.0, H - 1.0])
    kind = d.pick(["small", "large", "rotate", "shuffle", "scale"])
    base = pa * torch.tensor([(Wb - 1) / (W - 1), (Hb - 1) / (H - 1)])
    if kind == "small":
        pb = base + 3 * d.randn(M, 2)
    elif kind == "large":
        pb = base + 0.2 * min(Hb, Wb) * d.randn(M, 2)
    elif kind == "rotate":
        th, c = (d.u() - 0.5) * 2.5, torch.tensor([Wb / 2, Hb / 2])
        R = torch.tensor([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        pb = (base - c) @ R.T * 0.7 + c
    elif kind == "shuffle":
        pb = base[torch.randperm(M, generator=d.g)]
    else:
        pb = (base - base.mean(0)) * (0.3 + d.u()) + base.mean(0)
    pb = torch.minimum(pb.clamp(min=0), torch.tensor([Wb - 1.0, Hb - 1.0]))
    # the draws in the order of the old keyword arguments, so that a seed draws the same problems as before
    frames = d.i(2, 8)
    kind_of = NaturalSettings if d.u() < 0.7 else PaperSettings
    fields: dict = {}
    region = None
    if d.u() < 0.3:
        fields["align"] = d.pick([None, "affine", "similarity"])
    if d.u() < 0.2:
        region = "points"
    if d.u() < 0.2:
        fields["compressible"] = d.pick([True, False, 0.5])
    if d.u() < 0.2:
        fields["inverse"] = "paper"
    if d.u() < 0.3:
        fields["grid"] = d.i(8, 48)
    if d.u() < 0.3:
        fields["steps"] = d.i(1, 12)
    if d.u() < 0.2:
        A, B = A.double(), B.double()
    opts: dict = dict(frames=frames, progress=False, blending=Blending(region=region))
    desc = f"A {tuple(A.shape)} B {tuple(B.shape)} {str(A.dtype)[6:]} M={M} {kind} {kind_of.__name__}({fields})"
    desc += f" frames={opts['frames']}" + (" region=points" if region else "")

    def run() -> tuple[str, str]:
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            frames = morph(A, B, pa, pb, settings=kind_of(**fields), **opts).frames
        seconds = time.perf_counter() - t0
        flags = []
        if not torch.isfinite(frames).all():
            flags.append("NONFINITE")
        elif frames.min() < -1e-4 or frames.max() > 1 + 1e-4:
            flags.append("RANGE")
        if frames.shape[0] != opts["frames"] or tuple(frames.shape[-2:]) != (H, W):
            flags.append("SHAPE")
        if region is None and float((frames[0] - A.to(frames.dtype)).abs().max()) > 1e-3:
            flags.append("FIRST")
        if seconds > 20:
            flags.append("SLOW")
        said = sorted({str(w.message).split(":")[0][:50] for w in caught})
        return " ".join(flags) or "ok", f"{seconds:.1f} s; warnings: {said}"

    return desc, run


def images_case(d: Draw) -> Case:
    H, W, C = d.i(16, 96), d.i(16, 96), d.pick([1, 3])
    kind = d.pick(["smooth", "noise", "const", "shift", "blobs"])

    def smooth() -> torch.Tensor:
        return F.interpolate(d.rand(1, C, 6, 6), size=(H, W), mode="bicubic", align_corners=False).clamp(0, 1)

    if kind == "noise":
        A, B = d.rand(1, C, H, W), d.rand(1, C, H, W)
    elif kind == "const":
        A, B = torch.full((1, C, H, W), d.u()), torch.full((1, C, H, W), d.u())
    else:
        A = smooth()
        B = {"shift": lambda: torch.roll(A, (d.i(-4, 5), d.i(-4, 5)), (-2, -1)), "blobs": smooth}.get(
            kind, lambda: A.flip(-1)
        )()
    opts: dict = dict(progress=False, loss=d.pick(["mse", "ncc", "ssim", "lncc"]))
    if d.u() < 0.4:
        opts["levels"] = None
    if d.u() < 0.3:
        opts["grid"] = d.i(8, 40)
    if d.u() < 0.3:
        opts["steps"] = d.i(1, 8)
    if d.u() < 0.3:
        opts["max_iter"] = d.i(1, 30)
    if d.u() < 0.2:
        opts["compressible"] = True
    if d.u() < 0.2:
        opts["viscosity"] = 0.5
    if d.u() < 0.2:
        opts["regularization"] = 1e-3
    if d.u() < 0.2:
        opts["dtype"] = torch.float32
    if d.u() < 0.2:
        M, hi = d.i(1, 6), torch.tensor([W - 1.0, H - 1.0])
        p = d.rand(M, 2) * hi
        opts["points"] = (p, torch.minimum((p + 3 * d.randn(M, 2)).clamp(min=0), hi))
    shown = {k: ("(src, tgt)" if k == "points" else v) for k, v in opts.items()}
    desc = f"{tuple(A.shape)} {kind} {shown}"

    def run() -> tuple[str, str]:
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # the fold warning: judged below from min_det
            fit = fit_images(A, B, **opts)
        flags = []
        if not torch.isfinite(fit.warped).all():
            flags.append("NONFINITE")
        if fit.final_loss > fit.initial_loss * 1.0001 + 1e-9:
            flags.append("WORSE")
        if not bool((fit.min_det > 0).all()):
            flags.append("FOLD")
        detail = f"{time.perf_counter() - t0:.1f} s; loss {fit.initial_loss:.4g} -> {fit.final_loss:.4g}"
        return " ".join(flags) or "ok", f"{detail}; min det {float(fit.min_det.min()):.3f}"

    return desc, run


CASES: dict[str, Callable[[Draw], Case]] = {"fit": fit_case, "morph": morph_case, "images": images_case}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=sorted(CASES), help="which function to probe")
    parser.add_argument("--seed", type=int, default=0, help="the problems' seed (default 0)")
    parser.add_argument("--cases", type=int, default=30, help="how many problems (default 30)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    parser.add_argument("--quick", action="store_true", help="smoke run: 3 cases")
    args = parser.parse_args(argv)
    args.cases = 3 if args.quick else args.cases
    torch.set_num_threads(args.threads)
    draw, counts = Draw(args.seed), collections.Counter[str]()
    for case in range(args.cases):
        desc, run = CASES[args.what](draw)  # drawn first: a failing case leaves the next ones as they were
        try:
            flag, text = run()
        except (InputError, InputTypeError) as exc:  # a refusal: its message should name the argument
            flag, text = "REFUSED", str(exc)[:300]
        except FlowBlewUp as exc:  # the flow blew up: its message should say what to change
            flag, text = "BLEWUP", str(exc)[:300]
        except Exception as exc:  # noqa: BLE001 - any other exception is what this probe looks for
            flag, text = "EXC", f"{type(exc).__name__}: {str(exc)[:300]}\n{traceback.format_exc()[-800:]}"
        for word in flag.split():
            counts[word] += 1
        print(f"{flag:8s} case {case}: {desc}\n    {text}", flush=True)
    outcomes = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
    print(f"\n{args.what}, seed {args.seed}, {args.cases} cases: {outcomes}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
