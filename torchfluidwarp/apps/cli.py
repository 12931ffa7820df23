"""The ``torchfluidwarp`` command line: a thin layer over the public API.

Subcommands:

* ``animate``: warp a photo with oscillating brushes and viscosity regions (the paper's indirect control) and
  write a GIF, an MP4 or a folder of PNG frames. The settings come from options or a JSON file (its format is
  in :mod:`torchfluidwarp.apps.animate` and in ``torchfluidwarp animate --help``).
* ``morph``: morph image A into image B along corresponding points (:func:`torchfluidwarp.morph.morphing.morph`).
* ``demo``: the morph of the bundled samples (astronaut into cat), written to ``morph.gif``.
* ``studio``: the local web page (:mod:`torchfluidwarp.apps.studio`, the ``[studio]`` extra).

Exit status: 0 on success, 2 for bad input (a missing or unreadable image, a bad option or config, an existing
output without ``--overwrite``, MP4 without imageio-ffmpeg), with a one-line message on stderr; 130 when
interrupted. Outputs are written atomically, so a failed or interrupted run leaves nothing half-written.

Example:
    >>> build_parser().parse_args(["animate", "cat.png", "-o", "cat.gif", "--grid", "32"]).grid
    [32]
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

import torch
from torch import Tensor
from tqdm import tqdm

from torchfluidwarp._version import __version__
from torchfluidwarp.apps.animate import (
    AnimationConfig,
    BrushSpec,
    RegionSpec,
    auto_grid,
    brush_from_values,
    build_forces,
    build_viscosity,
    load_config,
    region_from_values,
)
from torchfluidwarp.io import FFMPEG_HINT, read_image, shrink_image, write_animation
from torchfluidwarp.warp.forces import Brushes
from torchfluidwarp.warp.layer import FluidWarp

__all__ = ["build_parser", "main"]

PROG = "torchfluidwarp"
EXIT_OK, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 2, 130

ANIMATE_EPILOG = """\
config file (--config), every key optional, unknown keys are an error:
  {"brushes": [{"position": [x, y], "direction": [dx, dy], "radius": r,
                "frequency": f, "amplitude": a, "phase": p}],
   "viscosity": {"base": 0.0,
                 "regions": [{"position": [x, y], "radius": r, "value": v}],
                 "mask": "stiff.png", "stiff": 5.0, "soft": 0.0},
   "grid": [64, 64], "steps": 60, "dt": 1.0, "fps": 20}

  Positions and radii are pixels of the input image (x right, y down, pixel centres at
  integers). amplitude: peak acceleration in px/time^2 (an oscillating brush moves the
  image by about amplitude / (2 pi frequency)^2 px); frequency: cycles per time unit
  (0 = steady push); phase: radians. Phase 1.57 (pi/2) swings the image back and forth
  around where it started; other phases also make it creep along the push. A brush
  needs position, direction, radius and amplitude. Viscosity (fluid cells^2 per time unit) is base + a Gaussian bump per
  region + soft..stiff from a gray mask image (1 = stiff, same size as the image,
  path relative to the JSON file). Options given on the command line replace the
  file's values (--brush replaces all its brushes, --stiff all its regions).

examples:
  torchfluidwarp animate cat.png -o cat.gif --brush 282,400,1,1,40,0.05,0.6,1.57 \
      --stiff 125,190,45,5 --stiff 367,227,45,5
  torchfluidwarp animate face.jpg -o out.mp4 --config laugh.json --steps 80
"""


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line on stderr (exit status 2)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``torchfluidwarp`` argument parser, with one subparser per subcommand.

    Each subparser stores its handler as ``handler`` (a function ``(argparse.Namespace) -> int`` returning the
    exit status), so a subcommand is added or replaced by one ``_add_*`` function and one ``_cmd_*`` function.
    """
    parser = _Parser(prog=PROG, description="Warp and morph images with a simulated 2-D incompressible fluid.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    _add_animate(commands)
    _add_demo(commands)
    _add_morph(commands)
    _add_studio(commands)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line.

    Args:
        argv: the arguments after the program name (default ``sys.argv[1:]``).

    Returns:
        The exit status: 0 on success, 2 for bad input (a one-line message on stderr), 130 when interrupted.
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors: return their status instead of exiting
        return exc.code if isinstance(exc.code, int) else (EXIT_OK if exc.code is None else EXIT_BAD_INPUT)
    try:
        return args.handler(args)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def _fail(command: str, message: object) -> int:
    text = str(message).strip().splitlines()
    print(f"{PROG} {command}: error: {text[0] if text else type(message).__name__}", file=sys.stderr)
    return EXIT_BAD_INPUT


# ----------------------------------------------------------------------------------------------- animate


def _numbers(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _brush(text: str) -> BrushSpec:
    try:
        return brush_from_values(_numbers(text), "brush")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{exc} in {text!r}") from None


def _region(text: str) -> RegionSpec:
    try:
        return region_from_values(_numbers(text), "region")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{exc} in {text!r}") from None


def _bounded(kind: Callable[[str], float], minimum: float, strict: bool) -> Callable[[str], float]:
    bound = f"> {minimum:g}" if strict else f">= {minimum:g}"

    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {'an integer' if kind is int else 'a number'} {bound}, got {text!r}"
            ) from None
        if not (value > minimum if strict else value >= minimum) or value != value or value == float("inf"):
            raise argparse.ArgumentTypeError(f"must be {bound}, got {text!r}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in some messages
    return parse


def _add_animate(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "animate",
        help="animate a photo with oscillating brushes (GIF, MP4 or PNG frames)",
        description="Animate a photo: oscillating Gaussian brushes stir a 2-D incompressible fluid that carries "
        "the image's texture coordinates; viscosity regions keep parts of it rigid.",
        epilog=ANIMATE_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("image", metavar="IMAGE", help="the photo to animate (PNG, JPEG, ...)")
    p.add_argument(
        "-o",
        "--output",
        metavar="OUT",
        required=True,
        help="output: OUT.gif, OUT.mp4 (needs imageio-ffmpeg) or a frames folder (ending in '/' or without suffix)",
    )
    p.add_argument("--config", metavar="JSON", help="animation settings file (format below)")
    p.add_argument(
        "--brush",
        metavar="X,Y,DX,DY,RADIUS,FREQ,AMP[,PHASE]",
        type=_brush,
        action="append",
        help="an oscillating brush: centre (px), push direction, Gaussian radius (px), frequency "
        "(cycles per time unit, 0 = steady), amplitude (px/time^2), phase (radians); repeatable",
    )
    p.add_argument(
        "--stiff",
        metavar="X,Y,RADIUS,VALUE",
        type=_region,
        action="append",
        help="a viscosity region: centre (px), radius (px), added viscosity (cells^2/time); repeatable",
    )
    p.add_argument(
        "--viscosity",
        metavar="BASE",
        type=_bounded(float, 0.0, strict=False),
        help="background viscosity (cells^2/time, default 0)",
    )
    p.add_argument(
        "--grid",
        metavar="N",
        nargs="+",
        type=_bounded(int, 2, strict=False),
        help="fluid grid: 'H W' cells, or N for N x N (default: 64 cells along the image's longer side)",
    )
    p.add_argument("--steps", type=_bounded(int, 1, strict=False), help="fluid steps; frames = steps + 1 (default 60)")
    p.add_argument("--dt", type=_bounded(float, 0.0, strict=True), help="time step in time units (default 1.0)")
    p.add_argument("--fps", type=_bounded(float, 0.0, strict=True), help="output frames per second (default 20)")
    p.add_argument(
        "--max-size",
        metavar="PX",
        type=_bounded(int, 0, strict=False),
        default=800,
        help="downscale the photo so its longer side is at most PX pixels, for speed (0 = keep; "
        "default 800); brush positions stay in the original's pixels",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(handler=_cmd_animate)


def _merge(config: AnimationConfig, args: argparse.Namespace) -> AnimationConfig:
    """The file's settings with the command line's on top."""
    viscosity = config.viscosity
    if args.stiff:
        viscosity = dataclasses.replace(viscosity, regions=tuple(args.stiff))
    if args.viscosity is not None:
        viscosity = dataclasses.replace(viscosity, base=args.viscosity)
    return dataclasses.replace(
        config,
        brushes=tuple(args.brush) if args.brush else config.brushes,
        viscosity=viscosity,
        steps=config.steps if args.steps is None else args.steps,
        dt=config.dt if args.dt is None else args.dt,
        fps=config.fps if args.fps is None else args.fps,
    )


def _grid(args: argparse.Namespace, config: AnimationConfig, size: tuple[int, int]) -> tuple[int, int]:
    if args.grid is None:
        return config.grid or auto_grid(size)
    if len(args.grid) == 1:
        return (args.grid[0], args.grid[0])
    if len(args.grid) == 2:
        return (args.grid[0], args.grid[1])
    raise ValueError(f"--grid takes 1 or 2 integers (N, or H W), got {len(args.grid)}: {args.grid}")


def _check_output(path: str, overwrite: bool) -> None:
    """Fail before rendering on what :func:`~torchfluidwarp.io.write_animation` would refuse after it."""
    target = Path(path)
    folder = path.endswith(("/", "\\")) or target.is_dir() or not target.suffix
    if not folder and target.suffix.lower() not in (".gif", ".mp4"):
        raise ValueError(f"-o {path!r}: unknown suffix {target.suffix!r}; use .gif, .mp4 or a folder ending in '/'")
    if not folder and target.suffix.lower() == ".mp4" and importlib.util.find_spec("imageio_ffmpeg") is None:
        raise ValueError(FFMPEG_HINT)
    exists = any(target.iterdir()) if target.is_dir() else target.exists() or target.is_symlink()
    if exists and not overwrite:
        raise ValueError(f"output {path!r} already exists; pass --overwrite to replace it")


def _render(warp: FluidWarp, image: Tensor, forces: Brushes, *, quiet: bool) -> Tensor:
    """All ``steps + 1`` frames ``(T + 1, C, H, W)``, with a progress bar on an interactive stderr."""
    frames = torch.empty(warp.steps + 1, *image.shape[1:], dtype=image.dtype)
    bar = tqdm(
        total=warp.steps + 1, unit="frame", desc="animate", leave=False, disable=quiet or not sys.stderr.isatty()
    )
    with torch.no_grad(), bar:
        for t, frame in enumerate(warp.iter_frames(image, forces)):
            frames[t] = frame[0]
            bar.update()
    return frames


def _cmd_animate(args: argparse.Namespace) -> int:
    try:
        config = _merge(load_config(args.config) if args.config else AnimationConfig(), args)
        if not config.brushes:
            raise ValueError('nothing to animate: give at least one --brush (or "brushes" in --config)')
        _check_output(args.output, args.overwrite)
        original = read_image(args.image)
        image = shrink_image(original, args.max_size)
        size = (image.shape[-2], image.shape[-1])
        config = config.rescaled(size[1] / original.shape[-1], size[0] / original.shape[-2])
        grid = _grid(args, config, size)
        viscosity = build_viscosity(config, grid, size, mask_size=(original.shape[-2], original.shape[-1]))
        warp = FluidWarp(grid, config.steps, config.dt, viscosity)
        frames = _render(warp, image, build_forces(config), quiet=args.quiet)
        path = write_animation(args.output, frames, fps=config.fps, overwrite=args.overwrite)
    except (ValueError, TypeError, OSError) as exc:  # FileExistsError and unwritable outputs are OSErrors
        return _fail("animate", exc)
    print(path)  # even with --quiet: it is the command's result, for scripts
    return EXIT_OK


# ------------------------------------------------------------------------------------------ morph and demo


def _add_morph_options(p: argparse.ArgumentParser, *, frames: int) -> None:
    p.add_argument(
        "-o",
        "--output",
        metavar="OUT",
        default=None,
        help="output: OUT.gif, OUT.mp4 (needs imageio-ffmpeg) or a frames folder (ending in '/')",
    )
    p.add_argument("--frames", type=_bounded(int, 2, strict=False), default=frames, help=f"frames (default {frames})")
    p.add_argument("--fps", type=_bounded(float, 0.0, strict=True), default=15.0, help="frames per second (default 15)")
    p.add_argument(
        "--method",
        choices=["natural", "paper"],
        default="natural",
        help="natural (default: straight paths, a thin-plate spline between the points, compressible) or the "
        "paper's incompressible keyframe fit",
    )
    p.add_argument(
        "--grid",
        metavar="N",
        type=_bounded(int, 4, strict=False),
        default=None,
        help="fluid grid N x N cells (default 80 for natural, 64 for paper)",
    )
    p.add_argument("--steps", type=_bounded(int, 1, strict=False), default=10, help="fluid steps (default 10)")
    p.add_argument(
        "--control",
        metavar="K",
        type=_bounded(int, 2, strict=False),
        default=8,
        help="--method paper: control points per axis and step of the fitted forces (default 8)",
    )
    p.add_argument(
        "--align",
        choices=["similarity", "affine", "none"],
        default="similarity",
        help="global pre-alignment from the points (default similarity)",
    )
    p.add_argument(
        "--inverse",
        choices=["flow", "paper"],
        default="flow",
        help="how image B is pulled back: along the same flow (default) or the paper's stepwise fits",
    )
    p.add_argument("--blend", choices=["linear", "smooth"], default="linear", help="cross-dissolve schedule")
    p.add_argument(
        "--compressible",
        metavar="W",
        type=_bounded(float, 0.0, strict=False),
        default=None,
        help="fraction of the divergent flow kept (0 = incompressible, 1 = no projection; default 1 for natural, "
        "0 for paper)",
    )
    p.add_argument(
        "--smoothness",
        metavar="S",
        type=_bounded(float, 0.0, strict=False),
        default=None,
        help="how strongly the fit keeps the flow calm (default 3 for natural, 5 for paper; see morph())",
    )
    p.add_argument(
        "--max-iter",
        type=_bounded(int, 1, strict=False),
        default=None,
        help="L-BFGS iterations (default 30 for natural, 100 for paper)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")


def _add_morph(commands: argparse._SubParsersAction) -> None:
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


def _add_demo(commands: argparse._SubParsersAction) -> None:
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
    from torchfluidwarp.morph.morphing import morph

    _check_output(args.output, args.overwrite)
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
    from torchfluidwarp.io import check_point_counts, read_points

    try:
        args.output = args.output or "morph.gif"
        a, b = read_image(args.image_a), read_image(args.image_b)
        pa, pb = read_points(args.points_a), read_points(args.points_b)
        check_point_counts(pa, pb, "--points-a", "--points-b")
        return _run_morph("morph", args, a, b, pa, pb)
    except (ValueError, TypeError, OSError) as exc:
        return _fail("morph", exc)


def _cmd_demo(args: argparse.Namespace) -> int:
    from torchfluidwarp.data import load_sample, load_sample_points

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
        return _fail("demo", exc)


# ------------------------------------------------------------------------------------------------ studio


def _add_studio(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "studio",
        help="the interactive web studio: click point pairs, watch the morph",
        description="Start the local studio page (127.0.0.1 by default) and open it in the browser.",
    )
    try:
        from torchfluidwarp.apps import studio
    except ImportError:
        p.set_defaults(handler=_cmd_studio_missing)
        return
    studio.add_arguments(p)
    p.set_defaults(handler=studio.run)


def _cmd_studio_missing(args: argparse.Namespace) -> int:
    return _fail("studio", "the studio needs its extra: pip install 'torchfluidwarp[studio]'")


if __name__ == "__main__":
    raise SystemExit(main())
