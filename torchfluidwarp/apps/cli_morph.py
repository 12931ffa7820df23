"""The ``morph`` and ``demo`` subcommands: :func:`torchfluidwarp.morph.morph` from the command line.

``torchfluidwarp morph A B --points-a FA --points-b FB -o OUT`` reads the images and the point files, calls
:func:`~torchfluidwarp.morph.morph` with the options, and writes the frames atomically; ``demo`` does the same
with the bundled samples (astronaut into cat). Exit status as in :mod:`torchfluidwarp.apps.cli`.
"""

from __future__ import annotations

import argparse
import sys

from torch import Tensor

from torchfluidwarp.apps.cli_args import EXIT_OK, NON_NEGATIVE, POSITIVE, PROG, check_output, count, fail
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import check_point_counts, read_image, read_points, write_animation
from torchfluidwarp.morph import morph

__all__ = ["add_morph", "add_demo"]

# (flag, metavar, type, help) of the morph's numeric options whose default is the method's: morph() picks it
_MORPH_TUNING = (
    ("--grid", "N", count(4), "fluid grid N x N cells (default 80 for natural, 64 for paper)"),
    (
        "--compressible",
        "W",
        NON_NEGATIVE,
        "fraction of the divergent flow kept (0 = incompressible, 1 = no projection; default 1 for natural, "
        "0 for paper)",
    ),
    (
        "--smoothness",
        "S",
        NON_NEGATIVE,
        "how strongly the fit keeps the flow calm (default 3 for natural, 5 for paper; see morph())",
    ),
    ("--max-iter", "N", count(1), "L-BFGS iterations (default 30 for natural, 100 for paper)"),
)
# (flag, choices (the first is the default), help)
_MORPH_CHOICES = (
    (
        "--method",
        ("natural", "paper"),
        "natural (default: straight paths, a thin-plate spline between the points, compressible) or the "
        "paper's incompressible keyframe fit",
    ),
    ("--align", ("similarity", "affine", "none"), "global pre-alignment from the points (default similarity)"),
    (
        "--inverse",
        ("flow", "paper"),
        "how image B is pulled back: along the same flow (default) or the paper's stepwise fits",
    ),
    ("--blend", ("linear", "smooth"), "cross-dissolve schedule (default linear)"),
)


def _add_morph_options(p: argparse.ArgumentParser, *, frames: int) -> None:
    p.add_argument(
        "-o",
        "--output",
        metavar="OUT",
        default=None,
        help="output: OUT.gif, OUT.mp4 (needs imageio-ffmpeg) or a frames folder (ending in '/')",
    )
    p.add_argument("--frames", type=count(2), default=frames, help=f"frames (default {frames})")
    p.add_argument("--fps", type=POSITIVE, default=15.0, help="frames per second (default 15)")
    p.add_argument("--steps", type=count(1), default=10, help="fluid steps (default 10)")
    p.add_argument(
        "--control",
        metavar="K",
        type=count(2),
        default=8,
        help="--method paper: control points per axis and step of the fitted forces (default 8)",
    )
    for flag, choices, text in _MORPH_CHOICES:
        p.add_argument(flag, choices=choices, default=choices[0], help=text)
    for flag, metavar, kind, text in _MORPH_TUNING:
        p.add_argument(flag, metavar=metavar, type=kind, default=None, help=text)
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")


def add_morph(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "morph",
        help="morph image A into image B along corresponding points (GIF, MP4 or PNG frames)",
        description="Morph A into B: fluid forces are fitted (adjoint gradients + L-BFGS) so that A's points reach "
        "B's at the keyframe; A is warped forward, B pulled back along the same flow, and the two are "
        'cross-dissolved. Point files: iBUG .pts, JSON ([[x, y], ...] or {"points": ...}) or CSV, '
        "pixels with pixel centres at integers.",
        epilog="example:\n  torchfluidwarp morph a.png b.png --points-a a.pts --points-b b.pts -o morph.gif "
        "--frames 30",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("image_a", metavar="A", help="source image")
    p.add_argument("image_b", metavar="B", help="target image (resized to A's size if needed)")
    p.add_argument("--points-a", required=True, metavar="FILE", help="A's points (.pts, .json or .csv)")
    p.add_argument("--points-b", required=True, metavar="FILE", help="B's points, same count and order")
    _add_morph_options(p, frames=30)
    p.set_defaults(handler=_cmd_morph)


def add_demo(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "demo",
        help="morph the bundled astronaut into the bundled cat: writes morph.gif",
        description="Morph the bundled public-domain samples (a photo of an astronaut into a "
        "photo of a cat, 23 corresponding points each) and write morph.gif.",
    )
    _add_morph_options(p, frames=30)
    p.set_defaults(handler=_cmd_demo)


def _run_morph(
    command: str, args: argparse.Namespace, image_a: Tensor, image_b: Tensor, points_a: Tensor, points_b: Tensor
) -> int:
    check_output(args.output, args.overwrite)
    progress = not args.quiet and sys.stderr.isatty()
    result = morph(
        image_a,
        image_b,
        points_a,
        points_b,
        frames=args.frames,
        method=args.method,
        grid=args.grid,
        steps=args.steps,
        control=args.control,
        align=None if args.align == "none" else args.align,
        inverse=args.inverse,
        blend=args.blend,
        compressible=args.compressible,
        smoothness=args.smoothness,
        max_iter=args.max_iter,
        progress=progress,
    )
    path = write_animation(args.output, result.frames, fps=args.fps, overwrite=args.overwrite)
    if not args.quiet:
        err = result.fit.error
        print(
            f"{PROG} {command}: mean point error {float(err.mean()):.2f} px (max {float(err.max()):.2f}), "
            f"{result.seconds['total']:.1f} s",
            file=sys.stderr,
        )
    print(path)
    return EXIT_OK


def _cmd_morph(args: argparse.Namespace) -> int:
    try:
        args.output = args.output or "morph.gif"
        a, b = read_image(args.image_a), read_image(args.image_b)
        pa, pb = read_points(args.points_a), read_points(args.points_b)
        check_point_counts(pa, pb, "--points-a", "--points-b")
        return _run_morph("morph", args, a, b, pa, pb)
    except (ValueError, TypeError, OSError) as exc:
        return fail("morph", exc)


def _cmd_demo(args: argparse.Namespace) -> int:
    try:
        args.output = args.output or "morph.gif"
        return _run_morph(
            "demo",
            args,
            load_sample("astronaut"),
            load_sample("cat"),
            load_sample_points("astronaut"),
            load_sample_points("cat"),
        )
    except (ValueError, TypeError, OSError) as exc:
        return fail("demo", exc)
