"""The ``torchfluidwarp`` command line: a thin layer over the public API.

Subcommands:

* ``animate``: warp a photo with oscillating brushes and viscosity regions (the paper's indirect control) and
  write a GIF, an MP4 or a folder of PNG frames. The settings come from options or a JSON file (its format is
  in :mod:`torchfluidwarp.apps.animate` and in ``torchfluidwarp animate --help``).
* ``morph``: morph image A into image B along corresponding points (:func:`torchfluidwarp.morph.morph`,
  in :mod:`torchfluidwarp.apps.cli_morph`), found from the pictures when no point files are given; or through
  several images (:mod:`torchfluidwarp.apps.cli_sequence`).
* ``average``: the mean of several images, each warped to the mean shape (:func:`torchfluidwarp.morph.average`).
* ``demo``: the morph of the bundled samples (astronaut into cat), written to ``morph.gif``.
* ``studio``: the local web page (:mod:`torchfluidwarp.apps.studio`, the ``[studio]`` extra).

Exit status (:mod:`torchfluidwarp.errors` says whose fault each error is):

* 0 on success;
* 2 for bad input, with a one-line message on stderr: a missing or unreadable file, a bad option or config, an
  existing output without ``--overwrite``, MP4 without imageio-ffmpeg, any
  :class:`~torchfluidwarp.errors.InputError` of the library (naming the option that set the argument at fault);
* 3 when the flow blows up (:class:`~torchfluidwarp.errors.FlowBlewUp`), with its one line saying what to change;
* 1 for anything else, a bug in torchfluidwarp: the traceback, then a line saying so;
* 130 when interrupted (Ctrl-C), 143 when terminated (SIGTERM).

Outputs are written atomically, so a failed, interrupted or terminated run leaves nothing half-written.

The arguments are checked in two passes. :func:`main` first checks what it can without the library, which imports
torch (seconds): the input files named on the command line exist, the output's suffix is one it can write and it
does not exist without ``--overwrite``, ``--brush`` and ``--stiff`` hold the right count of numbers. Only then does
it import the library, parse every option and run the command. This module imports neither torch nor the
library's modules when it is imported.

Example:
    >>> build_parser().parse_args(["animate", "cat.png", "-o", "cat.gif", "--grid", "32"]).grid
    [32]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from torchfluidwarp._version import __version__
from torchfluidwarp.apps.cli_args import (
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_TERMINATED,
    FPS,
    NON_NEGATIVE,
    ONE_IMAGE,
    POSITIVE,
    PROG,
    Clock,
    Terminated,
    add_limit_options,
    check_disk_space,
    check_image_output,
    check_output,
    check_work,
    clock_of,
    command_run,
    count,
    fail,
    flags,
    numbers,
    progress_bar,
    report,
)
from torchfluidwarp.errors import InputError

if TYPE_CHECKING:
    from torchfluidwarp.apps.animate import AnimationConfig

__all__ = ["build_parser", "main"]

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
    from torchfluidwarp.apps.cli_morph import add_demo, add_morph  # these import the library (and torch)
    from torchfluidwarp.apps.cli_sequence import add_average

    parser = _Parser(prog=PROG, description="Warp and morph images with a simulated 2-D fluid.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    _add_animate(commands)
    add_demo(commands)
    add_morph(commands)
    add_average(commands)
    _add_studio(commands)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line.

    Args:
        argv: the arguments after the program name (default ``sys.argv[1:]``).

    Returns:
        The exit status: 0 on success, 2 for bad input and 3 for a flow that blew up (a one-line message on
        stderr), 1 for a bug (with its traceback), 130 when interrupted, 143 when terminated (SIGTERM).
    """
    clock = Clock()  # the run's wall time, from here
    argv = sys.argv[1:] if argv is None else list(argv)
    early = _check_early(argv)  # before the library (and torch) is imported
    if early is not None:
        return early
    with clock.part("start"):
        parser = build_parser()
        try:
            args = parser.parse_args(argv)
        except SystemExit as exc:  # --help, --version and usage errors: return their status instead of exiting
            return exc.code if isinstance(exc.code, int) else (EXIT_OK if exc.code is None else EXIT_BAD_INPUT)
    args.clock = clock
    args.options = _options(parser, args.command)  # the command's flags by the library setting each sets
    with command_run(args.command, args.options):  # SIGTERM as Ctrl-C; a warning in one line, in the flags' words
        try:
            return args.handler(args)
        except Terminated:
            print(f"{PROG}: terminated", file=sys.stderr)
            return EXIT_TERMINATED
        except KeyboardInterrupt:
            print(f"{PROG}: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        except Exception as exc:  # the one place that says whose fault an error is (cli_args.report)
            return report(args.command, exc, _options(parser, args.command))


def _options(parser: argparse.ArgumentParser, command: str) -> Mapping[str, argparse.Action]:
    """The options of ``command``'s subparser, by the library argument each sets (:func:`cli_args.flags`)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return flags(action.choices[command])
    return {}


# ---------------------------------------------------------------------------------------- the early checks

_INPUTS = {
    "animate": {"IMAGE": "image", "--config": "config"},
    "morph": {"IMAGE": "image", "--points-a": "points", "--points-b": "points", "--points": "points"}
    | {"--held-out-a": "points", "--held-out-b": "points", "--pairs": "pairs file"},
    "average": {"IMAGE": "image", "--points": "points"},
    "demo": {},
}
"""By command, what its files are: the positional ``IMAGE`` arguments and the options whose values are input files,
as the library's read errors call them (``cannot read image 'a.png': no such file``)."""
_LISTS = ("--points",)  # options with nargs="+"
_OUTPUTS = ("-o", "--output", "--out")
_NUMBERS = {"--brush": (7, 8), "--stiff": (4, 4)}  # animate's: how many comma-separated numbers each takes
_VALUES = ("--frame", "--region")  # morph's and demo's other options with one value that the checks look at
_FLAGS = ("--overwrite", "--no-limit")  # options without a value that the checks look at
_CHANGING = ("--overwrite", "--pairs", "--frame", "--output")  # an abbreviation of these stops the early checks


def _check_early(argv: Sequence[str]) -> int | None:
    """Check what :func:`main` can without importing the library: the files named, the output and the numbers of
    ``--brush`` and ``--stiff``. Returns the exit status of a refusal (its line printed), or ``None`` to go on.

    Only what is certain is refused: the positional images before any option this does not know, the values of
    the options in ``_INPUTS``, the output of ``-o``. After an option it does not know, no more positional
    arguments are taken (an option's value could look like one). ``--help`` anywhere, ``--``, or an abbreviation
    of an option that changes the checks leave it all to the full parser.
    """
    if not argv or argv[0] not in _INPUTS:
        return None
    command, rest = argv[0], list(argv[1:])
    inputs = _INPUTS[command]
    known = {
        *inputs,
        *_OUTPUTS,
        *(_NUMBERS if command == "animate" else ()),
        *(_VALUES if command in ("morph", "demo") else ()),
    }
    positional: list[str] = []
    given: dict[str, list[str]] = {}
    i, leading = 0, True
    while i < len(rest):
        token = rest[i]
        i += 1
        if token in ("--", "-h", "--help"):
            return None
        if not token.startswith("-") or _is_number(token):
            if leading:
                positional.append(token)
            continue
        name, value = token, None
        if token.startswith("--") and "=" in token:
            name, _, value = token.partition("=")
        elif token.startswith("-o") and len(token) > 2 and not token.startswith("--"):
            name, value = "-o", token[2:]
        if name in _FLAGS:
            given[name] = []
            continue
        if name not in known:
            if _abbreviates(name, _CHANGING):
                return None
            leading = False  # what follows may be this option's values
            continue
        values = [] if value is None else [value]
        while value is None and i < len(rest) and (not rest[i].startswith("-") or _is_number(rest[i])):
            values.append(rest[i])
            i += 1
            if name not in _LISTS:
                break
        given.setdefault(name, []).extend(values)
    try:
        _check_files(command, positional, given)
        _check_numbers(given)
    except InputError as exc:
        return fail(command, exc)
    except argparse.ArgumentTypeError as exc:
        print(f"{PROG} {command}: error: {exc} (see --help)", file=sys.stderr)
        return EXIT_BAD_INPUT
    return None


def _check_files(command: str, positional: list[str], given: dict[str, list[str]]) -> None:
    inputs = _INPUTS[command]
    if "IMAGE" in inputs and "--pairs" not in given:
        named = [("IMAGE", path) for path in positional[: 1 if command == "animate" else None]]
    else:
        named = []
    named += [(option, path) for option in inputs if option != "IMAGE" for path in given.get(option, [])]
    for option, path in named:
        target = Path(path)
        if target.is_dir():
            raise InputError(f"cannot read {inputs[option]} {path!r}: it is a folder, not a file")
        if not target.is_file():
            raise InputError(f"cannot read {inputs[option]} {path!r}: no such file")
    outputs = [path for option in _OUTPUTS for path in given.get(option, [])]
    if not outputs or "--pairs" in given:
        return
    overwrite = "--overwrite" in given
    if command == "average" or "--frame" in given:
        check_image_output(outputs[-1], overwrite)
    else:
        check_output(outputs[-1], overwrite, one_image=ONE_IMAGE if command in ("morph", "demo") else "")


def _check_numbers(given: dict[str, list[str]]) -> None:
    """``--brush`` and ``--stiff`` hold numbers, as many as they take (as ``numbers()`` parses them later)."""
    for option, (least, most) in _NUMBERS.items():
        for text in given.get(option, []):
            try:
                values = [float(v) for v in text.split(",")]
            except ValueError:
                raise argparse.ArgumentTypeError(
                    f"argument {option}: expected comma-separated numbers, got {text!r}"
                ) from None
            if not least <= len(values) <= most:
                wanted = f"{least} or {most}" if least < most else f"{most}"
                raise argparse.ArgumentTypeError(
                    f"argument {option}: {option[2:]} needs {wanted} values, got {len(values)} in {text!r}"
                )


def _abbreviates(name: str, options: Sequence[str]) -> bool:
    """Whether ``name`` is a shortened ``--option`` (argparse accepts a unique prefix) of one of ``options``."""
    return name.startswith("--") and len(name) > 2 and any(o.startswith(name) and o != name for o in options)


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


# ----------------------------------------------------------------------------------------------- animate


def _add_animate(commands: argparse._SubParsersAction) -> None:
    from torchfluidwarp.apps.animate import brush_from_values, region_from_values

    p = commands.add_parser(
        "animate",
        help="animate a photo with oscillating brushes (GIF, WebP, MP4 or PNG frames)",
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
        help="output: OUT.gif, OUT.webp, OUT.mp4 (needs imageio-ffmpeg) or a frames folder (ending in '/' or "
        "without suffix)",
    )
    p.add_argument("--config", metavar="JSON", help="animation settings file (format below)")
    p.add_argument(
        "--brush",
        metavar="X,Y,DX,DY,RADIUS,FREQ,AMP[,PHASE]",
        type=numbers(brush_from_values, "brush"),
        action="append",
        help="an oscillating brush: centre (px), push direction, Gaussian radius (px), frequency "
        "(cycles per time unit, 0 = steady), amplitude (px/time^2), phase (radians); repeatable",
    )
    p.add_argument(
        "--stiff",
        metavar="X,Y,RADIUS,VALUE",
        type=numbers(region_from_values, "region"),
        action="append",
        help="a viscosity region: centre (px), radius (px), added viscosity (cells^2/time); repeatable",
    )
    p.add_argument(
        "--viscosity",
        metavar="BASE",
        type=NON_NEGATIVE,
        help="background viscosity (cells^2/time, default 0)",
    )
    p.add_argument(
        "--grid",
        metavar="N",
        nargs="+",
        type=count(2),
        help="fluid grid: 'H W' cells, or N for N x N (default: 64 cells along the image's longer side)",
    )
    p.add_argument("--steps", type=count(1), help="fluid steps; frames = steps + 1 (default 60)")
    p.add_argument("--dt", type=POSITIVE, help="time step in time units (default 1.0)")
    p.add_argument("--fps", type=FPS, help="output frames per second, 0.01 to 1000 (default 20)")
    p.add_argument(
        "--max-size",
        metavar="PX",
        type=count(0),
        default=800,
        help="downscale the photo so its longer side is at most PX pixels, for speed (0 = keep; "
        "default 800); brush positions stay in the original's pixels",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    add_limit_options(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(handler=_cmd_animate)


def _merge(config: AnimationConfig, args: argparse.Namespace) -> AnimationConfig:
    """The file's settings with the command line's on top."""
    viscosity = config.viscosity
    if args.stiff:
        viscosity = dataclasses.replace(viscosity, regions=tuple(args.stiff))
    if args.viscosity is not None:
        viscosity = dataclasses.replace(viscosity, base=args.viscosity)
    grid = config.grid
    if args.grid is not None:
        if len(args.grid) > 2:
            raise InputError(f"--grid takes 1 or 2 integers (N, or H W), got {len(args.grid)}: {args.grid}")
        grid = (args.grid[0], args.grid[-1])
    return dataclasses.replace(
        config,
        brushes=tuple(args.brush) if args.brush else config.brushes,
        viscosity=viscosity,
        grid=grid,
        steps=config.steps if args.steps is None else args.steps,
        dt=config.dt if args.dt is None else args.dt,
        fps=config.fps if args.fps is None else args.fps,
    )


def _cmd_animate(args: argparse.Namespace) -> int:
    """``animate``; its errors are reported by :func:`main` (one line for the user's, the traceback for a bug)."""
    from torchfluidwarp.apps import animate
    from torchfluidwarp.io import read_image, write_animation

    clock = clock_of(args)
    with clock.part("load"):
        config = _merge(animate.load_config(args.config) if args.config else animate.AnimationConfig(), args)
        if not config.brushes:
            raise InputError('nothing to animate: give at least one --brush (or "brushes" in --config)')
        check_output(args.output, args.overwrite)
        image = read_image(args.image)
    frames = animate.animate_frames(config, image, max_size=args.max_size)
    with clock.part("frames"):
        first = next(frames)  # the (resized) photo: its size is known before the fluid runs
    (H, W), (h, w) = image.shape[-2:], first.shape[-2:]
    check_disk_space(args.output, config.steps + 1, h, w, first.shape[0])
    check_work(args, args.output, config.steps + 1, first.shape)
    if (h, w) != (H, W) and not args.quiet:  # said before the frames, as morph says it
        print(
            f"{PROG} animate: frames written at {w} x {h} px: the photo's {W} x {H} shrunk to --max-size "
            f"{args.max_size} (the brushes' positions stay in the photo's pixels); --max-size 0 keeps its size",
            file=sys.stderr,
        )
    stream = progress_bar(itertools.chain([first], frames), config.steps + 1, "animate", args.quiet)
    with clock.part("frames"):
        path = write_animation(args.output, stream, fps=config.fps, overwrite=args.overwrite)
    if not args.quiet:
        print(f"{PROG} animate: {config.steps + 1} frames of {w} x {h} px, {clock.summary()}", file=sys.stderr)
    print(path)  # even with --quiet: it is the command's result, for scripts
    return EXIT_OK


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
    return fail("studio", "the studio needs its extra: pip install 'torchfluidwarp[studio]'")


if __name__ == "__main__":
    raise SystemExit(main())
