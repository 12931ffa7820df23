"""The ``morph`` and ``demo`` subcommands: :func:`torchfluidwarp.morph.morph` from the command line.

``torchfluidwarp morph A B --points-a FA --points-b FB -o OUT`` reads the images and the point files, calls
:func:`~torchfluidwarp.morph.morph` with the options, and streams the frames to the output (written atomically;
memory does not grow with ``--frames``); ``demo`` does the same with the bundled samples (astronaut into cat).
``torchfluidwarp morph --pairs pairs.csv --out DIR/`` morphs a list of pairs (:mod:`torchfluidwarp.apps.batch`).

Exit status as in :mod:`torchfluidwarp.apps.cli`: 0 on success, 2 for bad input (also an output that would not
fit on its disk, or a morph above ``--max-memory``, refused before any work); with ``--pairs``, 1 when some
pairs failed (listed in ``DIR/failures.csv``).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from torch import Tensor

from torchfluidwarp.apps.batch import morph_pairs, stream_frames
from torchfluidwarp.apps.cli_args import (
    EXIT_OK,
    FPS,
    NON_NEGATIVE,
    POSITIVE,
    PROG,
    check_disk_space,
    check_output,
    count,
    fail,
    progress_bar,
)
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import check_point_counts, read_image, read_points, write_animation
from torchfluidwarp.morph import morph

__all__ = ["add_morph", "add_demo", "EXIT_SOME_FAILED"]

EXIT_SOME_FAILED = 1
"""Exit status of ``morph --pairs`` when some pairs failed (the others were written)."""

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
        "--out",
        metavar="OUT",
        default=None,
        help="output: OUT.gif, OUT.mp4 (needs imageio-ffmpeg) or a frames folder (ending in '/'); with --pairs, "
        "the output folder",
    )
    p.add_argument("--frames", type=count(2), default=frames, help=f"frames (default {frames})")
    p.add_argument("--fps", type=FPS, default=15.0, help="frames per second, 0.01 to 1000 (default 15)")
    p.add_argument(
        "--max-memory",
        metavar="GIB",
        type=POSITIVE,
        default=None,
        help="memory the morph may set out to hold, in GiB (default 8); larger requests are refused before work",
    )
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
        "--frames 30\n  torchfluidwarp morph --pairs pairs.csv --out morphs/",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("image_a", metavar="A", nargs="?", help="source image")
    p.add_argument("image_b", metavar="B", nargs="?", help="target image (resized to A's size if needed)")
    p.add_argument("--points-a", metavar="FILE", help="A's points (.pts, .json or .csv)")
    p.add_argument("--points-b", metavar="FILE", help="B's points, same count and order")
    p.add_argument(
        "--pairs",
        metavar="CSV",
        help="morph every row image_a,image_b,points_a,points_b[,name] of CSV (paths relative to its folder) "
        "into the folder --out; a rerun skips finished pairs; see torchfluidwarp.apps.batch",
    )
    p.add_argument(
        "--format", choices=("gif", "mp4", "png"), default="gif", help="--pairs: each pair's output (default gif)"
    )
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


def _morph_options(args: argparse.Namespace) -> dict[str, Any]:
    """:func:`~torchfluidwarp.morph.morph`'s keyword arguments from the command line's options."""
    return dict(
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
        max_memory=None if args.max_memory is None else args.max_memory * 2**30,
    )


def _run_morph(
    command: str, args: argparse.Namespace, image_a: Tensor, image_b: Tensor, points_a: Tensor, points_b: Tensor
) -> int:
    check_output(args.output, args.overwrite)
    check_disk_space(args.output, args.frames, image_a.shape[-2], image_a.shape[-1], image_a.shape[1])
    progress = not args.quiet and sys.stderr.isatty()
    try:
        result = morph(image_a, image_b, points_a, points_b, progress=progress, **_morph_options(args))
    except ValueError as exc:  # name the command line's option, not the library's argument
        raise ValueError(str(exc).replace("morph(max_memory=...)", "--max-memory GIB")) from None
    frames = progress_bar(stream_frames(result), len(result), "frames", args.quiet)
    path = write_animation(args.output, frames, fps=args.fps, overwrite=args.overwrite)
    if not args.quiet:
        err = result.fit.error
        print(
            f"{PROG} {command}: mean point error {float(err.mean()):.2f} px (max {float(err.max()):.2f}), "
            f"{result.seconds['total']:.1f} s",
            file=sys.stderr,
        )
    print(path)
    return EXIT_OK


def _run_pairs(args: argparse.Namespace) -> int:
    if args.image_a or args.image_b or args.points_a or args.points_b:
        raise ValueError("--pairs takes the pairs from its CSV: give no A, B, --points-a or --points-b")
    if not args.output:
        raise ValueError("--pairs needs --out DIR/, the folder for the outputs")
    report = morph_pairs(
        args.pairs,
        args.output,
        fmt=args.format,
        fps=args.fps,
        overwrite=args.overwrite,
        progress=not args.quiet,
        **_morph_options(args),
    )
    print(  # even with --quiet, as the failures below: the command's result
        f"{PROG} morph: {len(report.morphed)} morphed, {len(report.skipped)} skipped (done before), "
        f"{len(report.failed)} failed",
        file=sys.stderr,
    )
    for row, name, reason in report.failed:
        print(f"{PROG} morph: row {row} ({name or '?'}) failed: {reason}", file=sys.stderr)
    print(args.output)
    return EXIT_OK if report.ok else EXIT_SOME_FAILED


def _cmd_morph(args: argparse.Namespace) -> int:
    try:
        if args.pairs:
            return _run_pairs(args)
        missing = [
            flag
            for flag, value in (
                ("A", args.image_a),
                ("B", args.image_b),
                ("--points-a", args.points_a),
                ("--points-b", args.points_b),
            )
            if not value
        ]
        if missing:
            return fail("morph", f"missing {', '.join(missing)} (or give --pairs CSV)")
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
