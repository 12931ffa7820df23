"""What the ``morph`` and ``demo`` subcommands share after the points are known: the typed settings built from
the options (:func:`morph_settings`: the method's :class:`~torchfluidwarp.morph.NaturalSettings` or
:class:`~torchfluidwarp.morph.PaperSettings`; :func:`result_options`: :class:`~torchfluidwarp.morph.Timing` and
:class:`~torchfluidwarp.morph.Blending` from ``--motion``, ``--blend``, ``--region``, ``--background``), the
``--frame`` and ``--report`` options, the checks made before any work, and the writing of the animation, the
single frame and the quality report.

A morph of two images is a :class:`~torchfluidwarp.morph.MorphResult`, a sequence a
:class:`~torchfluidwarp.morph.MorphSequence`; both render ``frame(t)`` and stream ``iter_frames()``, so one writer
serves both.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import Any, TypeVar

from torch import Tensor

from torchfluidwarp.apps.batch import returning_memory, stream_frames
from torchfluidwarp.apps.cli_args import (
    FRACTION,
    NON_NEGATIVE,
    ONE_IMAGE,
    check_disk_space,
    check_image_output,
    check_output,
    count,
    is_animation_file,
    progress_bar,
    timing,
)
from torchfluidwarp.core.grid import SquareCells
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import read_image, shrunk_size, write_animation, write_image
from torchfluidwarp.morph import Blending, MorphResult, MorphSequence, MorphSettings, Timing
from torchfluidwarp.morph.settings import METHODS

Measures = TypeVar("Measures")

__all__ = [
    "add_result_options",
    "morph_settings",
    "max_memory",
    "result_options",
    "output_size",
    "shrink_to_max_size",
    "frame_shape",
    "check_result_output",
    "write_result",
    "write_measured",
    "write_report",
]


MAX_SIZE = 1080
"""Pixels: the longest side of an animation's frames (GIF, MP4, WebP) when neither ``--size`` nor ``--max-size``
says otherwise. A phone's 4032 x 3024 pair morphed at its own size made a 136.9 MB GIF in 99.1 s, against 13.4 MB
in 17.2 s at 1080 (``benchmarks/bench_gif.py --cli``, 2 CPU cores); a GIF is for a screen, and an MP4 of more
than about 9 megapixels exceeds what H.264's common levels play. A folder of PNG frames and ``--frame``'s image
keep the first image's size."""


def add_result_options(p: argparse.ArgumentParser) -> None:
    """``--motion``, ``--blend``, ``--region``, ``--region-margin``, ``--background``, ``--frame``, ``--size``,
    ``--max-size``, ``--report``."""
    p.add_argument(
        "--motion",
        metavar="SCHEDULE",
        type=timing,
        default="linear",
        help="how the shape progresses: linear (default), smooth, ease-in, ease-out, or control points "
        "t:progress,... such as 0:0,0.3:0.7,1:1 (the shape 70%% there at 30%% of the time)",
    )
    p.add_argument(
        "--blend",
        metavar="SCHEDULE",
        type=timing,
        default="linear",
        help="how the colour progresses (the cross-dissolve), as --motion; e.g. --motion ease-out --blend "
        "ease-in: the shape leads the colour",
    )
    p.add_argument(
        "--region",
        metavar="points|MASK_A,MASK_B",
        default=None,
        help="morph only a region: 'points' (the points' convex hull grown by --region-margin) or two gray mask "
        "images (white = morph) for A and B; outside it shows --background (default: the whole picture)",
    )
    p.add_argument(
        "--region-margin",
        metavar="F",
        type=NON_NEGATIVE,
        default=0.25,
        help="--region points: how far the region reaches beyond the hull, times the points' extent (default 0.25)",
    )
    p.add_argument(
        "--background",
        choices=("a", "b", "blend"),
        default="blend",
        help="with --region, what shows outside it: A's, B's or their cross-dissolve (default blend)",
    )
    p.add_argument(
        "--frame",
        metavar="T",
        type=FRACTION,
        default=None,
        help="write the single image at time T in [0, 1] to -o (an image file, e.g. --frame 0.5 -o mid.png: the "
        "middle image of a morph-attack set) instead of an animation",
    )
    p.add_argument(
        "--size",
        metavar="N",
        nargs="+",
        type=count(1),
        default=None,
        help="the frames' size in pixels: N (square) or H W (default: the first image's, for an animation at most "
        "--max-size); each picture is placed on them by one scale factor, the smallest that covers them, never "
        "stretched",
    )
    p.add_argument(
        "--max-size",
        metavar="PX",
        type=count(0),
        default=MAX_SIZE,
        help=f"an animation (GIF, MP4, WebP) of a larger first image is written with its longer side at PX pixels, "
        f"with a note (default {MAX_SIZE}; 0 keeps the first image's size); --size, PNG frames and --frame's "
        "image are never shrunk",
    )
    p.add_argument(
        "--report",
        metavar="JSON",
        help="also write the morph's quality report (torchfluidwarp.metrics.morph_report: folds per frame, point "
        "errors, ghosting, seam, path smoothness) to JSON; it measures all --frames frames (with --frame too, "
        "rendering them all), the ghosting at frame N // 2 (its t is the report's mid_t)",
    )


SETTING_OPTIONS = ("grid", "steps", "control", "compressible", "straightness", "smoothness", "max_iter")
"""The options that set a field of the method's settings of the same name (``--max-iter``: ``max_iter``); ``None``
(not given) leaves the method's default. ``--grid N`` gives N x N cells' worth of square ones
(:class:`~torchfluidwarp.core.grid.SquareCells`: N x N on a square picture, never stretched with the picture).
``--align`` and ``--inverse`` set theirs too."""


def morph_settings(args: argparse.Namespace) -> MorphSettings:
    """The method's settings (:class:`~torchfluidwarp.morph.NaturalSettings` or
    :class:`~torchfluidwarp.morph.PaperSettings`, by ``--method``) from whichever of its options a command has.

    Raises:
        ValueError: an option given that the method has no field for (``--control`` or ``--smoothness`` with
            ``--method natural``, ``--straightness`` with ``--method paper``), naming the method it belongs to.
    """
    method = getattr(args, "method", "natural")
    cls = METHODS[method]
    fields = {f.name for f in dataclasses.fields(cls)}
    values: dict[str, Any] = {}
    for name in SETTING_OPTIONS:
        value = getattr(args, name, None)
        if value is None:
            continue
        if name not in fields:
            owner = next(m for m, other in METHODS.items() if name in {f.name for f in dataclasses.fields(other)})
            raise InputError(f"--{name.replace('_', '-')} applies to --method {owner}, not --method {method}")
        values[name] = SquareCells(value * value) if name == "grid" else value
    if getattr(args, "no_dense", False):
        if "dense" not in fields:
            raise InputError(f"--no-dense applies to --method natural, not --method {method}")
        values["dense"] = None
    if hasattr(args, "align"):
        values["align"] = None if args.align == "none" else args.align
    if hasattr(args, "inverse"):
        values["inverse"] = args.inverse
    return cls(**values)


def max_memory(args: argparse.Namespace) -> float | None:
    """``--max-memory`` (GiB) in bytes, or ``None`` (the library's default) when not given."""
    gib = getattr(args, "max_memory", None)
    return None if gib is None else gib * 2**30


def output_size(args: argparse.Namespace) -> tuple[int, int] | None:
    """``--size``: ``(H, W)`` pixels, or ``None`` (the first image's size)."""
    size = getattr(args, "size", None)
    if size is None:
        return None
    if len(size) > 2:
        raise InputError(f"--size takes 1 or 2 integers (N, or H W), got {len(size)}: {' '.join(map(str, size))}")
    return size[0], size[-1]


def shrink_to_max_size(args: argparse.Namespace, image: Tensor) -> str | None:
    """``--max-size``: with no ``--size``, an animation file (``-o`` ending in .gif, .mp4 or .webp; not ``--frame``'s
    image, not a folder of PNG frames) of a first picture ``image`` ``(1, C, H, W)`` whose longer side passes
    ``--max-size`` gets ``args.size`` set to the picture's size shrunk to it
    (:func:`~torchfluidwarp.io.images.shrunk_size`). Returns the note that says so, for the command to print once
    its output is checked, or ``None`` when nothing is shrunk."""
    limit = getattr(args, "max_size", 0)
    if args.size is not None or args.frame is not None or not limit or not is_animation_file(os.fspath(args.output)):
        return None
    H, W = image.shape[-2], image.shape[-1]
    h, w = shrunk_size((H, W), limit)
    if (h, w) == (H, W):
        return None
    args.size = [h, w]
    return (
        f"frames written at {w} x {h} px: the first image's {W} x {H} shrunk to --max-size {limit} (the point errors "
        f"printed are in these pixels); --size {H} {W} (or --max-size 0) writes them at its size"
    )


def frame_shape(args: argparse.Namespace, image: Tensor) -> tuple[int, int, int]:
    """``(C, H, W)`` of the frames a morph of ``image`` ``(1, C, H, W)`` (its first picture) writes: ``--size`` or
    the picture's size."""
    size = output_size(args)
    H, W = (image.shape[-2], image.shape[-1]) if size is None else size
    return image.shape[1], H, W


def result_options(args: argparse.Namespace) -> tuple[Timing, Blending]:
    """The morph's :class:`~torchfluidwarp.morph.Timing` and :class:`~torchfluidwarp.morph.Blending` from the
    options (region masks are read here)."""
    timing = Timing(motion=args.motion, blend=args.blend)
    size = output_size(args)
    if args.region is None:
        return timing, Blending(size=size)
    if args.region == "points":
        region: Any = "points"
    else:
        files = args.region.split(",")
        if len(files) != 2 or not all(files):
            raise InputError(f"--region takes 'points' or MASK_A,MASK_B (two image files), got {args.region!r}")
        region = tuple(read_image(f, channels=1)[0, 0] for f in files)
    return timing, Blending(region=region, region_margin=args.region_margin, background=args.background, size=size)


def check_result_output(args: argparse.Namespace, frames: int, image: Tensor) -> None:
    """Refuse, before any work, an output that could not be written: the animation's, or ``--frame``'s image."""
    if args.frame is not None:
        check_image_output(args.output, args.overwrite)
    else:
        check_output(args.output, args.overwrite, one_image=ONE_IMAGE)
        channels, height, width = frame_shape(args, image)
        check_disk_space(args.output, frames, height, width, channels)
    if args.report and Path(args.report).exists() and not args.overwrite:
        raise InputError(f"--report {args.report!r} already exists; pass --overwrite to replace it")


def write_result(
    result: MorphResult | MorphSequence, args: argparse.Namespace, frames: Iterator[Tensor] | None = None
) -> Path:
    """Write ``--frame``'s image, or stream every frame to the animation ``-o`` (``frames``: the result's frames
    ``(C, H, W)`` as another pass over them renders them); returns the path written."""
    if args.frame is not None:
        return write_image(args.output, result.frame(args.frame))
    frames = returning_memory(stream_frames(result) if frames is None else frames)
    frames = progress_bar(frames, len(result), "frames", args.quiet)
    return write_animation(args.output, frames, fps=args.fps, overwrite=args.overwrite)


def write_measured(
    result: MorphResult | MorphSequence, args: argparse.Namespace, measured: Generator[Tensor, None, Measures]
) -> tuple[Measures, Path]:
    """:func:`write_result`, and the end of ``measured``: a report's pass over the same frames
    (:func:`~torchfluidwarp.metrics.report.report_frames`). The animation is written from that pass, so each frame
    is rendered once; ``--frame`` writes its image after it. Returns what the pass returned, and the path written."""
    done: list[Measures] = []

    def frames() -> Iterator[Tensor]:
        done.append((yield from measured))

    stream = frames()
    path = None if args.frame is not None else write_result(result, args, stream)
    for _ in stream:  # the rest of the pass: all of it for --frame
        pass
    return done[0], write_result(result, args) if path is None else path


def write_report(path: str, report: dict[str, Any]) -> Path:
    """Write ``report`` as JSON (strict: no NaN or infinity) to ``path``, atomically; returns the path."""
    text = json.dumps(report, indent=1, allow_nan=False)
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.tmp")
    try:
        tmp.write_text(text + "\n", encoding="utf-8")
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    return target
