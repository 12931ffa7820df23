"""The ``morph`` and ``demo`` subcommands: :func:`torchfluidwarp.morph.morph` from the command line.

``torchfluidwarp morph A B --points-a FA --points-b FB -o OUT`` reads the images and the point files, calls
:func:`~torchfluidwarp.morph.morph` with the typed settings built from the options
(:func:`~torchfluidwarp.apps.cli_morph_output.morph_settings`), and streams the frames to the output (written
atomically; memory does not grow with ``--frames``); ``demo`` does the same with the bundled samples (astronaut
into cat). Without point files the points are found from the pictures (``--match``: face landmarks, matched features or
the pixels; :func:`torchfluidwarp.correspond.find_points`), and ``--save-points`` writes them.
``torchfluidwarp morph A B C ... --points FA FB FC ...`` morphs through several images
(:mod:`torchfluidwarp.apps.cli_sequence`), and ``torchfluidwarp morph --pairs pairs.csv --out DIR/`` morphs a
list of pairs (:mod:`torchfluidwarp.apps.batch`). The timing, region and output options are in
:mod:`torchfluidwarp.apps.cli_morph_output`.

Exit status as in :mod:`torchfluidwarp.apps.cli`: 0 on success, 2 for bad input (also an output that would not
fit on its disk, a morph above ``--max-memory``, or frames projected to take longer than ``--max-minutes`` to
render and write, refused before any work; with ``--pairs``, the whole batch's frames); with ``--pairs``, 1 when
some pairs failed (listed in ``DIR/failures.csv``).
"""

from __future__ import annotations

import argparse
import sys
import warnings

import torch
from torch import Tensor

from torchfluidwarp.apps.batch import morph_pairs, planned_work
from torchfluidwarp.apps.cli_args import (
    EXIT_OK,
    FPS,
    NON_NEGATIVE,
    POSITIVE,
    PROG,
    add_face_index,
    add_limit_options,
    check_batch_work,
    check_work,
    clock_of,
    count,
    fail,
    setting_names,
)
from torchfluidwarp.apps.cli_morph_output import (
    add_result_options,
    check_result_output,
    frame_shape,
    max_memory,
    morph_settings,
    output_size,
    result_options,
    shrink_to_max_size,
    write_measured,
    write_report,
    write_result,
)
from torchfluidwarp.apps.cli_sequence import run_sequence
from torchfluidwarp.control import apply_alignment
from torchfluidwarp.correspond import FoundPoints, MatchNotice, find_points
from torchfluidwarp.correspond.auto import MATCH_MODES, TRUSTED_MATCHES
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import check_point_counts, read_image, read_points, write_points
from torchfluidwarp.metrics import report_frames
from torchfluidwarp.morph import morph
from torchfluidwarp.morph.marks import check_met, check_point_files

__all__ = ["add_morph", "add_demo", "EXIT_SOME_FAILED"]

EXIT_SOME_FAILED = 1
"""Exit status of ``morph --pairs`` when some pairs failed (the others were written)."""

# (flag, metavar, type, help) of the fields of the method's settings (NaturalSettings, PaperSettings) whose
# default is the method's: not given (None), the settings class's default stands
_MORPH_TUNING = (
    (
        "--grid",
        "N",
        count(4),
        "fluid grid of N x N cells' worth of square ones, N x N on a square picture (default: natural 80; paper "
        "64 x 64 rows and columns)",
    ),
    (
        "--compressible",
        "W",
        NON_NEGATIVE,
        "fraction of the divergent flow kept (0 = incompressible, 1 = no projection; default 1 for natural, "
        "0 for paper)",
    ),
    (
        "--straightness",
        "S",
        NON_NEGATIVE,
        "--method natural: weight on the fit's corrections to the points' straight-line velocities, pixels^2 of "
        "point error per (pixel per step)^2 (default 0: the marks are met)",
    ),
    (
        "--smoothness",
        "S",
        NON_NEGATIVE,
        "--method paper: weight on the flow's velocity-gradient energy, fluid cells^2 per pixel^2 of point error "
        "(default 5)",
    ),
    ("--max-iter", "N", count(1), "L-BFGS iterations (default 30 for natural, 100 for paper)"),
    ("--control", "K", count(2), "--method paper: control points per axis and step of the fitted forces (default 8)"),
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
)


def _add_morph_options(p: argparse.ArgumentParser, *, frames: int) -> None:
    p.add_argument(
        "-o",
        "--output",
        "--out",
        metavar="OUT",
        default=None,
        help="output (default morph.gif): OUT.gif (RGBA input: transparent where alpha < 0.5), OUT.mp4 (needs "
        "imageio-ffmpeg), OUT.webp (animated, RGBA) or a folder of PNG frames (a path ending in '/' or with no "
        "suffix; RGBA kept); with --frame an image file; with --pairs, the output folder",
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
    for flag, choices, text in _MORPH_CHOICES:
        p.add_argument(flag, choices=choices, default=choices[0], help=text)
    for flag, metavar, kind, text in _MORPH_TUNING:
        p.add_argument(flag, metavar=metavar, type=kind, default=None, help=text)
    p.add_argument(
        "--no-dense",
        action="store_true",
        help="--method natural: align only what was marked (skip the pixels' alignment between the marks)",
    )
    add_result_options(p)
    add_limit_options(p)
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")


def add_morph(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "morph",
        help="morph image A into image B along corresponding points (GIF, WebP, MP4 or PNG frames)",
        description="Morph A into B: fluid forces are fitted (adjoint gradients + L-BFGS) so that A's points reach "
        "B's at the keyframe; A is warped forward, B pulled back along the same flow, and the two are "
        'cross-dissolved. Point files: iBUG .pts, JSON ([[x, y], ...] or {"points": ...}) or CSV, '
        "pixels with pixel centres at integers.",
        epilog="examples:\n  torchfluidwarp morph a.png b.png --points-a a.pts --points-b b.pts -o morph.gif "
        "--frames 30\n  torchfluidwarp morph face1.jpg face2.jpg -o morph.gif --save-points p1.pts p2.pts\n"
        "  torchfluidwarp morph a.jpg b.jpg c.jpg --points a.pts b.pts c.pts -o seq.gif\n"
        "  torchfluidwarp morph a.jpg b.jpg --points a.pts b.pts --frame 0.5 -o mid.png --report report.json\n"
        "  torchfluidwarp morph --pairs pairs.csv --out morphs/",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "images",
        metavar="IMAGE",
        nargs="*",
        help="two images A B, or more: a sequence through them (each placed on the first's canvas by one "
        "scale factor, never stretched)",
    )
    p.add_argument("--points-a", metavar="FILE", help="A's points (.pts, .json or .csv)")
    p.add_argument("--points-b", metavar="FILE", help="B's points, same count and order")
    p.add_argument(
        "--points",
        metavar="FILE",
        nargs="+",
        help="one point file per image, in the images' order (the same points in the same order in each)",
    )
    p.add_argument(
        "--match",
        choices=MATCH_MODES,
        default="auto",
        help="with no point files, how to find the points: face landmarks (pip install "
        "'torchfluidwarp[faces]'), matched SIFT features, a lattice placed by the pixels, or faces when both "
        f"images show one and features otherwise, the pixels where fewer than {TRUSTED_MATCHES} features match "
        "(default)",
    )
    add_face_index(p, pair=True)
    p.add_argument(
        "--save-points",
        nargs=2,
        metavar=("A_FILE", "B_FILE"),
        help="write the points found (.pts, .json or .csv) to correct them and rerun with --points-a/-b",
    )
    p.add_argument(
        "--held-out-a",
        metavar="FILE",
        help="--report: points of A not given to the morph, whose error the report measures",
    )
    p.add_argument("--held-out-b", metavar="FILE", help="--report: the held-out points of B, same count and order")
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


def _run_morph(
    command: str,
    args: argparse.Namespace,
    image_a: Tensor,
    image_b: Tensor,
    points_a: Tensor,
    points_b: Tensor,
    placed: FoundPoints | None = None,
) -> int:
    """Morph, write the animation (or ``--frame``) and the report; the output was checked by the caller.

    The line printed at the end gives the run's wall time (from :func:`~torchfluidwarp.apps.cli.main`'s start),
    then its parts: ``start`` (the library's import and the arguments), ``load``, ``points``, ``fit`` (the call to
    :func:`~torchfluidwarp.morph.morph`), ``render and write`` (the frames are rendered as they are written);
    with ``--report``, ``render, write and report`` instead: the animation is written from the report's own pass
    over the frames, so each frame is rendered once (``--frame``: ``render, report and write``).
    """
    clock = clock_of(args)
    with clock.part("load"):  # the held-out points and --region's masks
        held = _held_out(args)
        timing, blending = result_options(args)
    progress = not args.quiet and sys.stderr.isatty()
    with clock.part("fit"):
        given = (points_a, points_b) if placed is None else (None, None)
        result = morph(
            image_a,
            image_b,
            *given,
            placed=placed,
            settings=morph_settings(args),
            frames=args.frames,
            timing=timing,
            blending=blending,
            progress=progress,
            max_memory=max_memory(args),
        )  # errors: see fail()
    if placed is None:  # the user's marks, every one let go: frames that follow none are not written
        check_met(result.error, result.let_go, result.targets)
    if not args.report:
        with clock.part("render and write"):
            path = write_result(result, args)
    else:
        # the animation is written from the report's own pass over the frames: each frame is rendered once
        with clock.part("render, write and report" if args.frame is None else "render, report and write"):
            if placed is not None:  # B's side where the morph aimed, B's pixels (the pixels may have moved it)
                points_b = apply_alignment(torch.linalg.inv(result.canvas_from_b), result.targets).to(points_b)
            measured = report_frames(result, image_a, image_b, points_a, points_b, held_out=held)
            report, path = write_measured(result, args, measured)
            print(f"report: {write_report(args.report, report)}", file=sys.stderr)
    if not args.quiet:
        print(f"{PROG} {command}: {result.error_summary()}, {clock.summary()}", file=sys.stderr)
    print(path)
    return EXIT_OK


def _held_out(args: argparse.Namespace) -> tuple[Tensor, Tensor] | None:
    """``--held-out-a/-b``'s points (both or neither, with ``--report``)."""
    a, b = getattr(args, "held_out_a", None), getattr(args, "held_out_b", None)  # demo has none
    if bool(a) != bool(b):
        raise InputError("give both --held-out-a and --held-out-b, or neither")
    if a and not args.report:
        raise InputError("--held-out-a/-b are measured by the report: add --report JSON")
    if not a or not b:
        return None
    pa, pb = read_points(a), read_points(b)
    check_point_counts(pa, pb, "--held-out-a", "--held-out-b")
    return pa, pb


def _run_pairs(args: argparse.Namespace) -> int:
    if args.images or args.points_a or args.points_b or args.points:
        raise InputError("--pairs takes the pairs from its CSV: give no images, --points-a/-b or --points")
    if args.frame is not None or args.report or args.save_points:
        raise InputError("--pairs writes each pair's animation: --frame, --report and --save-points do not apply")
    if args.region not in (None, "points"):
        raise InputError("--pairs takes --region points only (one pair of masks cannot serve every pair)")
    if not args.output:
        raise InputError("--pairs needs --out DIR/, the folder for the outputs")
    # the whole batch's work, before any pair is morphed: the pairs a rerun skips add none
    size = output_size(args)  # every pair's frames at --size, or A's shrunk to --max-size
    work = planned_work(
        args.pairs, args.output, fmt=args.format, overwrite=args.overwrite, max_size=args.max_size, size=size
    )
    check_batch_work(args, [(planned.output, planned.shape) for planned in work], args.frames, args.output)
    shrunk = sum(planned.shrunk for planned in work)
    if shrunk and not args.quiet:  # the pairs whose frames --max-size shrinks, said once
        print(
            f"{PROG} morph: {shrunk} of the {len(work)} pairs' animations are written with their longer side at "
            f"--max-size {args.max_size} (their point errors are in those pixels); --max-size 0 keeps their sizes",
            file=sys.stderr,
        )
    timing, blending = result_options(args)
    report = morph_pairs(
        args.pairs,
        args.output,
        fmt=args.format,
        fps=args.fps,
        overwrite=args.overwrite,
        progress=not args.quiet,
        settings=morph_settings(args),
        frames=args.frames,
        timing=timing,
        blending=blending,
        max_memory=max_memory(args),
        max_size=args.max_size,
        names=setting_names(args),  # the summary's warnings in the command line's words
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
        if len(args.images) < 2:
            return fail("morph", "give two images A B (or more, for a sequence), or --pairs CSV")
        if args.points and (args.points_a or args.points_b):
            return fail("morph", "give --points FILE... or --points-a/--points-b, not both")
        if bool(args.points_a) != bool(args.points_b):
            return fail("morph", "give both --points-a and --points-b, or neither (then --match finds them)")
        if args.points and len(args.points) != len(args.images):
            counts = f"{len(args.images)} images, {len(args.points)} files"
            return fail("morph", f"--points needs one file per image: {counts}")
        args.output = args.output or "morph.gif"
        if len(args.images) > 2:
            return run_sequence(args)
        clock = clock_of(args)
        with clock.part("load"):
            a, b = (read_image(path) for path in args.images)
        shrunk = shrink_to_max_size(args, a)
        check_result_output(args, args.frames, a)  # before the points are searched for
        check_work(args, args.output, 1 if args.frame is not None else args.frames, frame_shape(args, a))
        if shrunk and not args.quiet:
            print(f"{PROG} morph: {shrunk}", file=sys.stderr)
        files = args.points or ([args.points_a, args.points_b] if args.points_a else None)
        if files:
            if args.save_points:
                raise InputError("--save-points writes the points found: give no point files with it")
            with clock.part("points"):
                pa, pb = read_points(files[0]), read_points(files[1])
            check_point_counts(pa, pb, *(files if args.points else ("--points-a", "--points-b")))
            check_point_files(files, (pa, pb), (a, b))
        else:
            faces = args.face_index  # I, or (I, J)
            with clock.part("points"):  # the face model's log lines are kept off stderr by the library
                with warnings.catch_warnings():  # the reason is printed below, in the command line's words
                    warnings.simplefilter("ignore", MatchNotice)
                    found = find_points(a, b, match=args.match, face_index=faces, names=tuple(args.images))
            pa, pb = found.points_a, found.points_b
            if found.reason.notable and not args.quiet:  # a fall-back, or one face chosen among several
                words = {"match": "--match", "face_index": "--face-index I (or I,J for A and B)"}
                print(f"{PROG} morph: {found.reason.explain(words)}", file=sys.stderr)
            if args.save_points:
                for path, points in zip(args.save_points, (pa, pb)):
                    print(f"points: {write_points(path, points)}", file=sys.stderr)
        return _run_morph("morph", args, a, b, pa, pb, None if files else found)
    except (OSError, ImportError) as exc:  # a file of the user's, or the faces extra missing: one line
        return fail("morph", exc)  # every other error goes to cli.main, which says whose fault it is


def _cmd_demo(args: argparse.Namespace) -> int:
    try:
        args.output = args.output or "morph.gif"
        clock = clock_of(args)
        with clock.part("load"):
            a, b = load_sample("astronaut"), load_sample("cat")
        shrunk = shrink_to_max_size(args, a)
        check_result_output(args, args.frames, a)
        check_work(args, args.output, 1 if args.frame is not None else args.frames, frame_shape(args, a))
        if shrunk and not args.quiet:
            print(f"{PROG} demo: {shrunk}", file=sys.stderr)
        with clock.part("points"):
            pa, pb = load_sample_points("astronaut"), load_sample_points("cat")
        return _run_morph("demo", args, a, b, pa, pb)
    except OSError as exc:  # an output of the user's: one line
        return fail("demo", exc)  # every other error goes to cli.main, which says whose fault it is
