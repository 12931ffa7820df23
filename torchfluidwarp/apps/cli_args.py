"""What the command line's subcommands share: exit codes, the one-line error, argument types, the output check,
the run's clock and the limits on its work.

This module is imported before torch (:func:`torchfluidwarp.apps.cli.main` checks the arguments and files
first, so that a missing file is reported at once): what it needs from the library or from Pillow and tqdm, its
functions import when they are called.

Argument types parse the text, then validate the value with :mod:`torchfluidwarp._checks` (the library's one
validation layer), so a bad option reads ``argument --steps: the value must be >= 1, got 0``.

Exit codes follow the library's errors (:mod:`torchfluidwarp.errors`): :data:`EXIT_BAD_INPUT` (2) with one line
for the user's input (an :class:`~torchfluidwarp.errors.InputError` or
:class:`~torchfluidwarp.errors.InputTypeError`, a bad option, an ``OSError`` on the user's files),
:data:`EXIT_FLOW_BLEW_UP` (3) with one line for a :class:`~torchfluidwarp.errors.FlowBlewUp`, and
:data:`EXIT_BUG` (1) with the traceback for anything else (:func:`report`).

Example:
    >>> count(2)("16"), POSITIVE("0.5")
    (16, 0.5)
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import shutil
import signal
import sys
import threading
import time
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from types import FrameType
from typing import Any, TypeVar

from torchfluidwarp.errors import AdvisedWarning, FlowBlewUp, InputError, InputTypeError

__all__ = [
    "PROG",
    "EXIT_OK",
    "EXIT_BUG",
    "EXIT_BAD_INPUT",
    "EXIT_FLOW_BLEW_UP",
    "EXIT_INTERRUPTED",
    "EXIT_TERMINATED",
    "Terminated",
    "USER_ERRORS",
    "fail",
    "report",
    "flags",
    "first_line",
    "checked",
    "count",
    "numbers",
    "POSITIVE",
    "NON_NEGATIVE",
    "FPS",
    "FRACTION",
    "timing",
    "check_output",
    "check_image_output",
    "check_disk_space",
    "output_bytes",
    "progress_bar",
    "Clock",
    "SECONDS_PER_MEGAPIXEL",
    "MAX_MINUTES",
    "add_limit_options",
    "add_face_index",
    "face_index_pair",
    "setting_names",
    "worded",
    "work_seconds",
    "check_work",
    "check_batch_work",
    "command_run",
]

PROG = "torchfluidwarp"
EXIT_OK, EXIT_BUG, EXIT_BAD_INPUT, EXIT_FLOW_BLEW_UP, EXIT_INTERRUPTED = 0, 1, 2, 3, 130
EXIT_TERMINATED = 128 + 15
"""Exit status after SIGTERM (the shell's convention for a process ended by signal 15)."""

USER_ERRORS = (InputError, InputTypeError, OSError)
"""The errors that are the user's to fix (exit 2, one line): the library's input errors and ``OSError`` on the
user's files (missing, unreadable, an existing output, a full disk). Not a plain ``ValueError`` or ``TypeError``:
from inside the library, those are bugs."""

T = TypeVar("T")


def _library(module: str, name: str) -> Callable[..., Any]:
    """``module.name``, imported at its first call (the library's modules import torch)."""

    def call(*args: Any, **kwargs: Any) -> Any:
        return getattr(importlib.import_module(module), name)(*args, **kwargs)

    call.__name__ = name
    return call


check_int = _library("torchfluidwarp._checks", "check_int")
check_positive = _library("torchfluidwarp._checks", "check_positive")
check_fraction = _library("torchfluidwarp._checks", "check_fraction")
check_fps = _library("torchfluidwarp.io", "check_fps")


def first_line(message: object) -> str:
    """The first line of a message or an exception's text (the exception's type name when it has none)."""
    text = str(message).strip().splitlines()
    return text[0] if text else type(message).__name__


def flags(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    """A command's options by the name of the library argument they set (their ``dest``: ``"max_memory"`` for
    ``--max-memory``), to put the library's errors in the command line's terms. Positional arguments are left
    out: a library argument called ``image`` is not necessarily the user's ``IMAGE``."""
    return {action.dest: action for action in parser._actions if action.option_strings}


def _flag(action: argparse.Action) -> str:
    """``--max-memory``: the option's first long spelling."""
    return next((s for s in action.option_strings if s.startswith("--")), action.option_strings[0])


def _usage(action: argparse.Action) -> str:
    """``--max-memory GIB``: the option as it is typed, with its metavar when it has one."""
    return f"{_flag(action)} {action.metavar}" if isinstance(action.metavar, str) else _flag(action)


def setting_names(args: argparse.Namespace) -> dict[str, str]:
    """The command line's name of each library setting the running command's options set (``{"max_memory":
    "--max-memory GIB"}``): :func:`torchfluidwarp.apps.cli.main` puts the options on ``args``; ``{}`` without
    them (a handler called directly)."""
    return _names(getattr(args, "options", {}) or {})


def _names(options: Mapping[str, argparse.Action]) -> dict[str, str]:
    """The command line's name of each library setting its ``options`` set (``{"max_memory": "--max-memory
    GIB"}``), for a :class:`~torchfluidwarp.errors.Hint`."""
    return {name: _usage(action) for name, action in options.items()}


def worded(message: Warning | str, names: Mapping[str, str] | None) -> Warning | str:
    """A warning as a command says it: an :class:`~torchfluidwarp.errors.AdvisedWarning`'s advice with the
    settings called by ``names`` (:func:`setting_names`); any other warning, or any with ``names=None``, as it is
    (its advice in Python's names)."""
    return message.explain(names) if names is not None and isinstance(message, AdvisedWarning) else message


def fail(command: str, message: object, options: Mapping[str, argparse.Action] | None = None) -> int:
    """Print ``torchfluidwarp COMMAND: error: <first line of message>`` on stderr and return the exit status.

    Args:
        command: the subcommand, for the message.
        message: the error's text, or the exception.
        options: the command's :func:`flags`. An exception's ``argument`` that one of them sets is named by its
            flag (``argument --max-iter: max_iter must be >= 1, got 0``), and its hint
            (:class:`~torchfluidwarp.errors.Hint`) names the flag that changes the setting, or gives the advice
            for a setting the command line does not have.

    Returns:
        :data:`EXIT_FLOW_BLEW_UP` for a :class:`~torchfluidwarp.errors.FlowBlewUp`, else :data:`EXIT_BAD_INPUT`.
    """
    options = options or {}
    if isinstance(message, (InputError, InputTypeError, FlowBlewUp)):
        text = first_line(message.explain(_names(options)))
        if message.argument is not None and message.argument in options:
            text = f"argument {_flag(options[message.argument])}: {text}"
    else:
        text = first_line(message)
    print(f"{PROG} {command}: error: {text}", file=sys.stderr)
    return EXIT_FLOW_BLEW_UP if isinstance(message, FlowBlewUp) else EXIT_BAD_INPUT


def report(command: str, error: Exception, options: Mapping[str, argparse.Action] | None = None) -> int:
    """Report an error that ended ``command`` and return its exit status.

    The user's errors (:data:`USER_ERRORS`) and a :class:`~torchfluidwarp.errors.FlowBlewUp` are one line
    (:func:`fail`). Anything else is a bug in torchfluidwarp: its traceback on stderr, then a line saying so, and
    :data:`EXIT_BUG`.
    """
    if isinstance(error, (*USER_ERRORS, FlowBlewUp)):
        return fail(command, error, options)
    traceback.print_exception(type(error), error, error.__traceback__, file=sys.stderr)
    print(
        f"{PROG} {command}: internal error ({type(error).__name__}): a bug in torchfluidwarp, not in your input; "
        "please report it with the traceback above",
        file=sys.stderr,
    )
    return EXIT_BUG


def checked(kind: Callable[[str], Any], check: Callable[..., T], **bounds: Any) -> Callable[[str], T]:
    """An argparse ``type``: ``kind(text)``, then ``check("the value", value, **bounds)`` from ``_checks``."""

    def parse(text: str) -> T:
        try:
            value = kind(text)
        except ValueError:
            noun = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"expected {noun}, got {text!r}") from None
        try:
            return check("the value", value, **bounds)
        except (InputError, InputTypeError) as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = getattr(kind, "__name__", "value")  # argparse names the type in some messages
    return parse


def count(minimum: int) -> Callable[[str], int]:
    """An argparse ``type``: an integer ``>= minimum``."""
    return checked(int, check_int, minimum=minimum)


POSITIVE: Callable[[str], float] = checked(float, check_positive)
"""An argparse ``type``: a finite number ``> 0``."""
NON_NEGATIVE: Callable[[str], float] = checked(float, check_positive, allow_zero=True)
"""An argparse ``type``: a finite number ``>= 0``."""
FPS: Callable[[str], float] = checked(float, lambda name, value: check_fps(value))
"""An argparse ``type``: a frame rate :func:`~torchfluidwarp.io.check_fps` accepts (0.01 to 1000)."""
FRACTION: Callable[[str], float] = checked(float, check_fraction)
"""An argparse ``type``: a number in ``[0, 1]`` (a morph's time ``t``)."""


def timing(text: str) -> str | list[tuple[float, float]]:
    """An argparse ``type``: a schedule of :mod:`torchfluidwarp.morph.timing`, an easing name (``linear``,
    ``smooth``, ``ease-in``, ``ease-out``) or control points ``t:progress,...`` such as ``0:0,0.3:0.7,1:1``.

    Example:
        >>> timing("0:0,0.3:0.7,1:1")
        [(0.0, 0.0), (0.3, 0.7), (1.0, 1.0)]
    """
    value: str | list[tuple[float, float]] = text
    if ":" in text:
        try:
            value = [(float(t), float(v)) for t, v in (pair.split(":") for pair in text.split(","))]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an easing name or t:progress,... pairs, got {text!r}") from None
    from torchfluidwarp.morph.timing import schedule

    try:
        schedule("the schedule", value)
    except (TypeError, ValueError) as exc:  # argparse makes these a usage error anyway: keep their message
        raise argparse.ArgumentTypeError(str(exc)) from None
    return value


def numbers(build: Callable[[Sequence[float], str], T], where: str) -> Callable[[str], T]:
    """An argparse ``type``: comma-separated numbers passed to ``build(values, where)``, e.g. a brush."""

    def parse(text: str) -> T:
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
        try:
            return build(values, where)
        except ValueError as exc:  # argparse makes it a usage error anyway: keep its message
            raise argparse.ArgumentTypeError(f"{exc} in {text!r}") from None

    parse.__name__ = where
    return parse


ANIMATION_SUFFIXES = (".gif", ".mp4", ".webp")
"""The file suffixes of an animation output (a path ending in ``/``, or without a suffix, is a folder of PNGs)."""

ONE_IMAGE = "--frame T (--frame 0.5: the middle image)"
"""How ``morph`` and ``demo`` write a single image instead of an animation, said when ``-o`` names an image."""


def check_output(path: str, overwrite: bool, one_image: str = "") -> None:
    """Fail before rendering on what :func:`~torchfluidwarp.io.write_animation` would refuse after it.

    ``one_image``: how the command writes a single image instead (``"--frame T"``), said when ``path`` names an
    image file (``mid.png``).

    Raises:
        InputError: an unknown suffix, MP4 without imageio-ffmpeg, or an existing output without ``overwrite``.
    """
    from PIL import Image

    target = Path(path)
    folder = _is_folder(path)
    if not folder and target.suffix.lower() not in ANIMATION_SUFFIXES:
        image = one_image and target.suffix.lower() in Image.registered_extensions()
        raise InputError(
            f"-o {path!r}: unknown suffix {target.suffix!r}; use .gif, .mp4, .webp or a folder ending in '/'"
            + (
                f" for the animation, or add {one_image} to write the single image at time T to {path!r}"
                if image
                else ""
            )
        )
    if not folder and target.suffix.lower() == ".mp4" and importlib.util.find_spec("imageio_ffmpeg") is None:
        from torchfluidwarp.io import FFMPEG_HINT

        raise InputError(FFMPEG_HINT)
    exists = any(target.iterdir()) if target.is_dir() else target.exists() or target.is_symlink()
    if exists and not overwrite:
        raise InputError(f"output {path!r} already exists; pass --overwrite to replace it")


def check_image_output(path: str, overwrite: bool) -> None:
    """Fail before any work on an image output (``--frame``, ``average``) that could not be written.

    Raises:
        InputError: a suffix no image format has, or an existing output without ``overwrite``.
    """
    from PIL import Image

    target = Path(path)
    Image.init()
    if target.suffix.lower() not in Image.registered_extensions():
        raise InputError(f"-o {path!r}: an image needs a suffix such as .png or .jpg, got {target.suffix!r}")
    if (target.exists() or target.is_symlink()) and not overwrite:
        raise InputError(f"output {path!r} already exists; pass --overwrite to replace it")


def _is_folder(path: str) -> bool:
    target = Path(path)
    return path.endswith(("/", "\\")) or target.is_dir() or not target.suffix


def is_animation_file(path: str) -> bool:
    """Whether ``-o path`` is an animation file (:data:`ANIMATION_SUFFIXES`), not a folder of PNG frames."""
    return not _is_folder(path) and Path(path).suffix.lower() in ANIMATION_SUFFIXES


def output_bytes(path: str, frames: int, height: int, width: int, channels: int) -> float:
    """About how many bytes an animation of ``frames`` frames ``(channels, height, width)`` takes at ``path``.

    A GIF holds about a byte a pixel (8-bit palette indices, which LZW rarely shrinks for photos), a folder of
    PNGs at most ``channels`` bytes a pixel, an H.264 MP4 about 0.3 (generous for its default quality), a WebP at
    quality 90 about 1 (lossy colour, lossless alpha).
    """
    suffix = "" if _is_folder(path) else Path(path).suffix.lower()
    per_pixel = {".gif": 1.0, ".mp4": 0.3, ".webp": 1.0}.get(suffix, float(channels))
    return frames * (height * width * per_pixel + 1024)


def check_disk_space(path: str, frames: int, height: int, width: int, channels: int) -> None:
    """Refuse, before any work, an animation that would not fit in the free space of ``path``'s folder.

    Raises:
        InputError: the estimate (:func:`output_bytes`) is above the free space, with both in the message.
    """
    from torchfluidwarp._checks import format_bytes

    need = output_bytes(path, frames, height, width, channels)
    folder = Path(path).absolute()
    while not folder.exists():
        folder = folder.parent
    if folder.is_file():
        folder = folder.parent
    free = shutil.disk_usage(folder).free
    if need > free:
        raise InputError(
            f"output {path!r} would need about {format_bytes(need)} ({frames} frames of {width}x{height}), "
            f"above the {format_bytes(free)} free in {str(folder)!r}; ask for fewer or smaller frames, "
            "or write elsewhere"
        )


def progress_bar(frames: Iterable[T], total: int, desc: str, quiet: bool) -> Iterator[T]:
    """``frames`` with a tqdm bar on stderr (none with ``quiet`` or when stderr is not a terminal)."""
    from tqdm import tqdm

    with tqdm(total=total, unit="frame", desc=desc, leave=False, disable=quiet or not sys.stderr.isatty()) as bar:
        for frame in frames:
            yield frame
            bar.update()


class Clock:
    """The wall time of one run of a command, and its parts, for the line a command prints when it is done.

    :func:`torchfluidwarp.apps.cli.main` starts it as the run starts, times its own ``start`` (importing the
    library and parsing the arguments) and hands it to the command as ``args.clock``; the command times its
    parts (``load``, ``points``, ``fit``, ``render and write``, ``report``). What no part covers (the checks in
    between) is small, so the parts add up to the total.

    Example:
        >>> clock = Clock()
        >>> with clock.part("load"):
        ...     pass
        >>> list(clock.parts)
        ['load']
    """

    def __init__(self) -> None:
        self.started = time.perf_counter()
        self.parts: dict[str, float] = {}
        """Seconds spent in each part, in the order the parts first ran."""

    @contextlib.contextmanager
    def part(self, name: str) -> Iterator[None]:
        """Time the block as part ``name`` (added to what ``name`` already holds), even when it raises."""
        begin = time.perf_counter()
        try:
            yield
        finally:
            self.parts[name] = self.parts.get(name, 0.0) + time.perf_counter() - begin

    def total(self) -> float:
        """Seconds since the run started."""
        return time.perf_counter() - self.started

    def summary(self) -> str:
        """``'12.3 s (start 2.0 s, load 0.1 s, fit 4.6 s, render and write 5.5 s)'``: the total, then the parts."""
        parts = ", ".join(f"{name} {seconds:.1f} s" for name, seconds in self.parts.items())
        return f"{self.total():.1f} s" + (f" ({parts})" if parts else "")


def clock_of(args: argparse.Namespace) -> Clock:
    """The run's :class:`Clock` (``args.clock``, set by :func:`~torchfluidwarp.apps.cli.main`), or a new one
    for a command called without it."""
    clock = getattr(args, "clock", None)
    return clock if isinstance(clock, Clock) else Clock()


# ------------------------------------------------------------------------------------------ limits on work

SECONDS_PER_MEGAPIXEL = {"gif": 0.2, "other": 0.05}
"""The least time a frame takes to render and write, in seconds per megapixel of frame, by output format: a GIF's
encoding alone (Pillow's palette quantisation) takes 0.67 s per megapixel on the 2-core machine of
``docs/benchmarks.md``, a WebP's 0.10 and an MP4's 0.16, and rendering comes on top. The figures are a third of
those or less, so that a run refused by :func:`check_work` would take longer than its estimate on any machine:
the estimate says "at least"."""

MAX_MINUTES = 10.0
"""The longest projected render a command starts without ``--max-minutes`` or ``--no-limit``, in minutes."""


def add_face_index(p: argparse.ArgumentParser, when: str = "", pair: bool = False) -> None:
    """``--face-index I``: which face of a photograph that shows several the points are found on (``when`` says
    when it applies, as a prefix of its help). With ``pair``, ``--face-index I,J`` chooses in A and in B
    separately (one word, so that the option may stand before the image files), as
    :func:`~torchfluidwarp.correspond.auto.find_points` takes them."""
    p.add_argument(
        "--face-index",
        type=face_index_pair if pair else count(0),
        default=None,
        metavar="I" + ("[,J]" if pair else ""),
        help=f"{when}which face when a photo shows several: 0 = the largest (the default, with a note), 1 = the next"
        + ("; I,J: face I of A and face J of B" if pair else ""),
    )


def face_index_pair(text: str) -> int | tuple[int, int]:
    """An argparse ``type``: ``I`` (an index >= 0) or ``I,J`` (two)."""
    parts = text.split(",")
    if len(parts) > 2:
        raise argparse.ArgumentTypeError(f"expected I or I,J (integers >= 0), got {text!r}")
    values = [count(0)(part.strip()) for part in parts]
    return values[0] if len(values) == 1 else (values[0], values[1])


def add_limit_options(p: argparse.ArgumentParser) -> None:
    """``--max-minutes`` and ``--no-limit``: how long a run's frames may be projected to take (:func:`check_work`)."""
    p.add_argument(
        "--max-minutes",
        metavar="MIN",
        type=POSITIVE,
        default=MAX_MINUTES,
        help=f"refuse, before any work, frames projected to take longer than MIN minutes to render and write "
        f"(default {MAX_MINUTES:g}; the projection is a lower bound from the frame size and count)",
    )
    p.add_argument("--no-limit", action="store_true", help="start however long the frames are projected to take")


def _duration(seconds: float) -> str:
    """``'45 s'``, ``'12 min'``, ``'16.2 h'``, ``'3.5 days'``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 90 * 60:
        return f"{seconds / 60:.0f} min"
    if seconds < 48 * 3600:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


def work_seconds(path: str, frames: int, shape: Sequence[int]) -> float:
    """The least time ``frames`` frames of ``shape`` ``(..., C, H, W)`` take to render and write at ``path``, in
    seconds: ``frames`` times the megapixels of a frame times :data:`SECONDS_PER_MEGAPIXEL` for the output's format
    (a lower bound).

    Example:
        >>> work_seconds("out.gif", 100, (3, 1000, 1000))
        20.0
    """
    height, width = (int(n) for n in shape[-2:])
    suffix = "" if _is_folder(path) else Path(path).suffix.lower()
    rate = SECONDS_PER_MEGAPIXEL["gif" if suffix == ".gif" else "other"]
    return frames * height * width / 1e6 * rate


def _work_limit(args: argparse.Namespace) -> float | None:
    """``--max-minutes`` (:data:`MAX_MINUTES` when the command has none), or ``None`` with ``--no-limit``."""
    if getattr(args, "no_limit", False):
        return None
    return float(getattr(args, "max_minutes", None) or MAX_MINUTES)


def _too_much_work(what: str, seconds: float, limit: float, size: float, where: str, fewer: str) -> InputError:
    """The refusal of work projected to take ``seconds`` (above ``limit`` minutes) and ``size`` bytes at ``where``."""
    from torchfluidwarp._checks import format_bytes

    return InputError(
        f"{what} would take at least {_duration(seconds)} to render and write (and about {format_bytes(size)} at "
        f"{where!r}), above the limit of {limit:g} min; ask for {fewer}, or allow it with --max-minutes "
        f"{max(1, int(seconds / 60) + 1)} (or --no-limit)"
    )


def check_work(args: argparse.Namespace, path: str, frames: int, shape: Sequence[int]) -> None:
    """Refuse, before any work, frames projected to take longer than ``--max-minutes`` to render and write.

    The projection is :func:`work_seconds` for ``frames`` frames of ``shape`` ``(..., C, H, W)`` at ``path``.
    ``--no-limit`` skips the check; a command without ``--max-minutes`` is checked against :data:`MAX_MINUTES`.

    Raises:
        InputError: the projection is above the limit; the message gives it, the output's size
            (:func:`output_bytes`), and the flags that allow the run.
    """
    limit = _work_limit(args)
    if limit is None:
        return
    seconds = work_seconds(path, frames, shape)
    if seconds > limit * 60:
        channels, height, width = (int(n) for n in shape[-3:])
        size = output_bytes(path, frames, height, width, channels)
        raise _too_much_work(
            f"{frames} frames of {width}x{height}", seconds, limit, size, path, "fewer or smaller frames"
        )


def check_batch_work(
    args: argparse.Namespace, outputs: Sequence[tuple[str, Sequence[int]]], frames: int, folder: str
) -> None:
    """Refuse, before any work, a batch whose frames are projected to take longer than ``--max-minutes`` in all.

    The projection is the sum of :func:`work_seconds` over ``outputs``, one ``(path, shape)`` per animation of
    ``frames`` frames of ``shape`` ``(..., C, H, W)``, written at ``path`` in ``folder``. ``--no-limit`` skips the
    check; a command without ``--max-minutes`` is checked against :data:`MAX_MINUTES`.

    Raises:
        InputError: the projection is above the limit; the message gives it, the outputs' size
            (:func:`output_bytes`), and the flags that allow the run.
    """
    limit = _work_limit(args)
    if limit is None:
        return
    seconds = sum(work_seconds(path, frames, shape) for path, shape in outputs)
    if seconds > limit * 60:
        size = sum(output_bytes(path, frames, int(s[-2]), int(s[-1]), int(s[-3])) for path, s in outputs)
        raise _too_much_work(
            f"{len(outputs)} pairs of {frames} frames each",
            seconds,
            limit,
            size,
            folder,
            "fewer pairs or fewer or smaller frames",
        )


# --------------------------------------------------------------------------------------------- the run


class Terminated(KeyboardInterrupt):
    """SIGTERM during a command: raised where the run is, like Ctrl-C's ``KeyboardInterrupt``, so that what
    cleans up after an interrupt (the atomic outputs of :mod:`torchfluidwarp.io`) cleans up after it too."""


def _terminate(signum: int, frame: FrameType | None) -> None:
    raise Terminated


def _show_warning(command: str, options: Mapping[str, argparse.Action]) -> Callable[..., None]:
    """A ``warnings.showwarning`` that prints the warning as the command's one line, without a source line, an
    :class:`~torchfluidwarp.errors.AdvisedWarning`'s advice naming the command's flags (``options``, as
    :func:`flags` gives them)."""

    names = _names(options)

    def show(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: Any = None,
        line: str | None = None,
    ) -> None:
        text = first_line(worded(message, names))
        print(f"{PROG} {command}: warning: {text}", file=sys.stderr if file is None else file)

    return show


@contextlib.contextmanager
def command_run(command: str, options: Mapping[str, argparse.Action] | None = None) -> Iterator[None]:
    """The setting of one command's run: SIGTERM raises :class:`Terminated` (as SIGINT raises
    ``KeyboardInterrupt``), and warnings print as one line, ``torchfluidwarp COMMAND: warning: ...``, without
    the library's source line, their advice in the command's flags (``options``, as :func:`flags` gives them).
    Both are restored when the run ends; SIGTERM is left alone outside the main thread (where no handler can be
    set)."""
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminate) if main else None
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning(command, options or {})
            yield
    finally:
        if main:
            signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)
