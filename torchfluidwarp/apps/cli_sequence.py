"""Morphing more than two images from the command line: ``morph`` through a sequence, and ``average``.

* ``torchfluidwarp morph A B C ... --points FA FB FC ... -o seq.gif`` morphs through the images in order
  (:func:`torchfluidwarp.morph.morph_sequence`): one animation of ``--frames`` frames whose points keep one speed
  through every middle image. ``--frame T`` writes the single image at ``T`` of the whole sequence, and
  ``--report`` a list of each segment's quality report.
* ``torchfluidwarp average IMG1 IMG2 ... --points F1 F2 ... -o mean.png`` writes the mean of the images, each
  warped to the mean shape of the points by its own fold-free flow (:func:`torchfluidwarp.morph.average`).

Without ``--points`` both use each image's face landmarks (:func:`torchfluidwarp.correspond.find_each_face`),
say so on stderr, and take ``--face-index I`` for the face to use where a photograph shows several.

Exit status as in :mod:`torchfluidwarp.apps.cli`: 0 on success, 2 for bad input, with one line on stderr.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Generator, Iterator
from contextlib import contextmanager
from typing import Any

from torch import Tensor

from torchfluidwarp.apps.cli_args import (
    EXIT_OK,
    NON_NEGATIVE,
    POSITIVE,
    PROG,
    add_face_index,
    check_image_output,
    check_work,
    clock_of,
    count,
    fail,
)
from torchfluidwarp.apps.cli_morph_output import (
    check_result_output,
    frame_shape,
    max_memory,
    morph_settings,
    result_options,
    shrink_to_max_size,
    write_measured,
    write_report,
    write_result,
)
from torchfluidwarp.correspond import FACE_MESH_INDICES, MatchNotice
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import check_point_counts, read_image, read_points, write_image, write_points
from torchfluidwarp.metrics import report_frames
from torchfluidwarp.morph import MorphSequence, average, morph_sequence
from torchfluidwarp.morph.marks import check_point_files

__all__ = ["run_sequence", "add_average"]


def _read_all(images: list[str], point_files: list[str] | None) -> tuple[list[Tensor], list[Tensor] | None]:
    """Every image and its points; every point file must have as many points as the first. Without point files,
    ``None``: the library finds each image's face landmarks (:func:`_faces_said`)."""
    pictures = [read_image(path) for path in images]
    if not point_files:
        return pictures, None
    if len(point_files) != len(images):
        raise InputError(f"--points needs one file per image: {len(images)} images, {len(point_files)} files")
    points = [read_points(path) for path in point_files]
    for path, p in zip(point_files[1:], points[1:]):
        check_point_counts(points[0], p, point_files[0], path)
    check_point_files(point_files, points, pictures)
    return pictures, points


@contextmanager
def _faces_said(command: str, args: argparse.Namespace, found: bool) -> Iterator[None]:
    """Around a call that finds each image's face landmarks (``found``): its note, in the command line's words
    (``--face-index I``), on stderr unless ``--quiet``."""
    caught: list[warnings.WarningMessage] = []
    done = False
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MatchNotice)
            yield
        done = True
    finally:  # the note first (the points came first), then the call's other warnings as they came, even on failure
        notes = [w.message.note for w in caught if isinstance(w.message, MatchNotice)]
        if done and found and not args.quiet:
            said = (
                notes[0].explain({"face_index": "--face-index I"})
                if notes
                else f"found the face landmarks ({len(FACE_MESH_INDICES)} points) of each of the "
                f"{len(args.images)} pictures"
            )
            print(f"{PROG} {command}: {said}; give --points FILE... to mark other features", file=sys.stderr)
        for w in caught:
            if not isinstance(w.message, MatchNotice):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def _measured(
    sequence: MorphSequence, pictures: list[Tensor], points: list[Tensor]
) -> Generator[Tensor, None, list[dict[str, Any]]]:
    """The sequence's frames, in order, from each segment's report pass; returns the segments' reports. A joint is
    the previous segment's last frame, so each later segment's first frame is measured but not yielded (as
    :meth:`~torchfluidwarp.morph.MorphSequence.iter_frames` leaves it out)."""
    reports = []
    for i, segment in enumerate(sequence.segments):
        frames = report_frames(segment, pictures[i], pictures[i + 1], points[i], points[i + 1])
        if i:
            next(frames)
        reports.append((yield from frames))
    return reports


def run_sequence(args: argparse.Namespace) -> int:
    """``morph A B C ... --points ...``: the sequence through the images, written as ``morph`` writes a morph.

    ``args`` are the ``morph`` subcommand's (:mod:`torchfluidwarp.apps.cli_morph`), with ``args.output`` set.
    """
    if not args.points and args.match not in (None, "auto", "faces"):
        raise InputError(
            f"a sequence of {len(args.images)} images takes --points FILE... (one per image), or finds each one's "
            f"face landmarks without them; --match {args.match} finds the points of two images only"
        )
    if args.save_points or args.held_out_a or args.held_out_b:
        raise InputError("--save-points and --held-out-a/-b apply to two images only")
    clock = clock_of(args)
    with clock.part("load"):
        pictures, points = _read_all(args.images, args.points)
    shrunk = shrink_to_max_size(args, pictures[0])
    if args.region not in (None, "points"):
        raise InputError("a sequence takes --region points only (a pair of masks is for two images)")
    settings = morph_settings(args)
    timing, blending = result_options(args)
    check_result_output(args, args.frames, pictures[0])
    check_work(args, args.output, 1 if args.frame is not None else args.frames, frame_shape(args, pictures[0]))
    if shrunk and not args.quiet:
        print(f"{PROG} morph: {shrunk}", file=sys.stderr)
    progress = not args.quiet and sys.stderr.isatty()
    if isinstance(args.face_index, tuple):
        raise InputError(
            f"--face-index {args.face_index[0]},{args.face_index[1]} names a face of A and of B, for two photos; "
            f"a morph through {len(args.images)} takes one index, the face of each photo that shows several"
        )
    with clock.part("fit"), _faces_said("morph", args, points is None):
        sequence = morph_sequence(
            pictures,
            points,
            face_index=args.face_index,
            names=args.images,
            settings=settings,
            frames=args.frames,
            timing=timing,
            blending=blending,
            progress=progress,
            max_memory=max_memory(args),
        )
    if not args.report:
        with clock.part("render and write"):
            path = write_result(sequence, args)
    else:  # the animation is written from the segments' report passes: each frame is rendered once
        with clock.part("render, write and report" if args.frame is None else "render, report and write"):
            reports, path = write_measured(sequence, args, _measured(sequence, pictures, sequence.points))
            print(f"report: {write_report(args.report, {'segments': reports})}", file=sys.stderr)
    if not args.quiet:
        errors = [segment.met_error for segment in sequence.segments]
        let_go = sum(int(segment.let_go.sum()) for segment in sequence.segments)
        print(
            f"{PROG} morph: {len(errors)} segments, mean point error per segment "
            + ", ".join(f"{float(e.mean()):.2f}" if e.numel() else "none met" for e in errors)
            + " px"
            + (f" over the marks met ({let_go} let go so as not to fold)" if let_go else "")
            + f", {clock.summary()}",
            file=sys.stderr,
        )
    print(path)
    return EXIT_OK


def add_average(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "average",
        help="the average of several images: each warped to the mean shape of the points, then averaged",
        description="Average images (faces, objects) that show the same points: the mean shape of the point "
        "sets is found (each set brought onto the first by a similarity, then averaged), every image is warped "
        "to it by its own fitted fold-free flow, and the warped images are averaged.",
        epilog="examples:\n  torchfluidwarp average f1.jpg f2.jpg f3.jpg -o mean.png   (faces: their landmarks are "
        "found)\n  torchfluidwarp average f1.jpg f2.jpg f3.jpg --points f1.pts f2.pts f3.pts -o mean.png",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "images",
        metavar="IMAGE",
        nargs="+",
        help="two or more images (each placed on the first's canvas by one scale factor, never stretched)",
    )
    p.add_argument(
        "--points",
        metavar="FILE",
        nargs="+",
        help="one point file per image, in order (default: each image's face landmarks, the largest face)",
    )
    p.add_argument("-o", "--output", metavar="OUT", default="average.png", help="the image (default average.png)")
    add_face_index(p, "without --points, ")
    p.add_argument("--save-points", metavar="FILE", help="write the mean shape (.pts, .json or .csv)")
    p.add_argument("--method", choices=("natural", "paper"), default="natural", help="as morph (default natural)")
    p.add_argument("--align", choices=("similarity", "affine", "none"), default="similarity", help="as morph")
    p.add_argument(
        "--grid", metavar="N", type=count(4), default=None, help="fluid grid of N x N square cells' worth, as morph"
    )
    p.add_argument("--steps", type=count(1), default=10, help="fluid steps (default 10)")
    p.add_argument("--compressible", metavar="W", type=NON_NEGATIVE, default=None, help="as morph")
    p.add_argument("--straightness", metavar="S", type=NON_NEGATIVE, default=None, help="--method natural: as morph")
    p.add_argument("--smoothness", metavar="S", type=NON_NEGATIVE, default=None, help="--method paper: as morph")
    p.add_argument("--max-iter", metavar="N", type=count(1), default=None, help="L-BFGS iterations, as morph")
    p.add_argument("--max-memory", metavar="GIB", type=POSITIVE, default=None, help="as morph (default 8)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.add_argument("-q", "--quiet", action="store_true", help="no summary line")
    p.set_defaults(handler=_cmd_average)


def _cmd_average(args: argparse.Namespace) -> int:
    clock = clock_of(args)
    try:
        if len(args.images) < 2:
            return fail("average", f"give two or more images, got {len(args.images)}")
        check_image_output(args.output, args.overwrite)
        with clock.part("load"):
            pictures, points = _read_all(args.images, args.points)
        settings = morph_settings(args)
        with clock.part("points, fit and render"), _faces_said("average", args, points is None):
            result = average(
                pictures,
                points,
                face_index=args.face_index,
                names=args.images,
                settings=settings,
                max_memory=max_memory(args),
            )
        path = write_image(args.output, result.image)
        if args.save_points:
            print(f"points: {write_points(args.save_points, result.points)}", file=sys.stderr)
        if not args.quiet:
            print(
                f"{PROG} average: {len(pictures)} images, {result.error_summary()}, folded fraction "
                f"{result.folded:.2g}, {clock.summary()}",
                file=sys.stderr,
            )
    except (OSError, ImportError) as exc:  # a file of the user's, or the faces extra missing: one line
        return fail("average", exc)  # every other error goes to cli.main, which says whose fault it is
    print(path)
    return EXIT_OK
