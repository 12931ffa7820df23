"""Batch morphing: a CSV of image pairs morphed one after another in one process, resumable, sharded by rank.

``torchfluidwarp morph --pairs pairs.csv --out DIR/`` calls :func:`morph_pairs`; Python code can call it too.
Each row of the CSV is ``image_a,image_b,points_a,points_b[,name]``; relative paths resolve against the CSV's
folder, blank lines and lines starting with ``#`` are skipped, and a first row ``image_a,image_b,...`` is a
header. ``name`` (default ``<A's stem>-<B's stem>``) names the output ``DIR/<name>.gif`` (or ``.mp4``, or a
folder ``DIR/<name>/`` of PNGs).

* Each output is written atomically (:func:`~torchfluidwarp.io.write_animation`), its frames streamed from
  :meth:`~torchfluidwarp.morph.result.MorphResult.iter_frames`, so memory does not grow with the frame count.
* A rerun skips the pairs whose output exists: a killed run resumes where it stopped (the temporary file a
  killed run left for the pair it was writing is removed when that pair's turn comes again).
* A bad row (a missing file, mismatched points, a morph that fails) goes to ``DIR/failures.csv`` (this run's
  failures: ``row,name,reason``) and the others go on.
* ``DIR/summary.csv`` has one row a pair: the landmark error over the marks met (``result.met_error``,
  pixels) and how many the morph let go so as not to fold (``result.let_go``), the fraction of folded map pixels
  (``result.folded``), the seconds it took and the warnings it raised; rows of earlier runs are kept.

Under ``torchrun`` (``RANK``/``WORLD_SIZE`` set) rank ``r`` of ``n`` takes the pairs ``r, r + n, r + 2n, ...``
and uses ``cuda:LOCAL_RANK`` when there are GPUs; rank 0 gathers the summaries and failures
(``torch.distributed``: gloo on CPU, nccl with GPUs). The outputs are the same whatever the world size. Ranks
given without ``torch.distributed`` (no process group, no ``MASTER_ADDR``) each write
``summary.rank<r>.csv`` and ``failures.rank<r>.csv`` instead.
"""

from __future__ import annotations

import csv
import ctypes
import dataclasses
import glob
import importlib.util
import os
import shutil
import sys
import time
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, NamedTuple

import torch
from torch import Tensor
from tqdm import tqdm

from torchfluidwarp._checks import check_instance, check_int, check_size
from torchfluidwarp.apps.cli_args import check_disk_space, first_line, worded
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import (
    FFMPEG_HINT,
    check_point_counts,
    image_shape,
    read_image,
    read_points,
    shrunk_size,
    write_animation,
)
from torchfluidwarp.morph import Blending, MorphSequence, MorphSettings, NaturalSettings, Timing, morph
from torchfluidwarp.morph.marks import check_met, check_point_files
from torchfluidwarp.morph.result import MorphResult

__all__ = [
    "PairRow",
    "BatchReport",
    "read_pairs",
    "morph_pairs",
    "planned_work",
    "PlannedOutput",
    "stream_frames",
    "returning_memory",
    "STREAM_BYTES",
]

STREAM_BYTES = 512 * 2**20
"""Bytes of frames (with their maps) rendered at once while streaming a morph: 8 frames, fewer when large."""

SUMMARY_FIELDS = (
    "name", "output", "status", "error_mean_px", "error_max_px", "let_go", "folded", "seconds", "warnings"
)  # fmt: skip
FAILURE_FIELDS = ("row", "name", "reason")
HEADER = ("image_a", "image_b", "points_a", "points_b")
OutputFormat = Literal["gif", "mp4", "png"]


@dataclass(frozen=True)
class PairRow:
    """One row of a pairs CSV: its line number, the output's name and the four paths (resolved)."""

    row: int
    name: str
    image_a: Path
    image_b: Path
    points_a: Path
    points_b: Path


@dataclass
class BatchReport:
    """What :func:`morph_pairs` did: the names morphed and skipped, the failures ``(row, name, reason)``."""

    morphed: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: list[tuple[int, str, str]] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """No pair failed."""
        return not self.failed


def stream_frames(result: MorphResult | MorphSequence) -> Iterator[Tensor]:
    """A morph's (or a sequence's) frames ``(C, H, W)``, rendered a few at a time so that at most
    :data:`STREAM_BYTES` are held."""
    first = result.segments[0] if isinstance(result, MorphSequence) else result
    return result.iter_frames(chunk=max(1, min(8, STREAM_BYTES // first.bytes_per_frame())))


def returning_memory(frames: Iterator[Tensor]) -> Iterator[Tensor]:
    """``frames`` as they come, each followed by handing the C heap's free memory back to the system (glibc's
    ``malloc_trim``; nothing where the C library has none).

    Rendering a large frame frees temporaries of tens of MB, which glibc keeps in its heap once its dynamic mmap
    threshold has risen: a 6000 x 6000 morph grew by 1.6 GiB over three frames although it held no more. The
    command line streams its animations through this, a process-wide choice that the library leaves to the
    application. (It used to fix glibc's mmap threshold at 1 MiB instead, which made every larger block a fresh
    mapping: the fit and the frames of an 817 x 1024 morph took twice as long.)"""
    trim = _malloc_trim()
    if trim is not None:  # what the fit freed, before the first frame is rendered
        trim(0)
    for frame in frames:
        yield frame
        if trim is not None:
            trim(0)


def _malloc_trim() -> Any:
    """glibc's ``malloc_trim(pad)``, or ``None`` where the C library is not glibc."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return None


def read_pairs(path: str | os.PathLike[str]) -> tuple[list[PairRow], list[tuple[int, str, str]]]:
    """Read a pairs CSV: the good rows, and the bad ones as ``(row, name, reason)``.

    A row is bad when it has not 4 or 5 fields, an empty or path-like name, or a name an earlier row has.
    Files are not opened here (a missing one fails when its pair's turn comes).

    Raises:
        OSError: the CSV cannot be read.
    """
    csv_path = Path(path)
    base = csv_path.parent
    rows: list[PairRow] = []
    bad: list[tuple[int, str, str]] = []
    seen: dict[str, int] = {}
    with open(csv_path, newline="", encoding="utf-8") as fp:
        for line, fields in enumerate(csv.reader(fp), 1):
            fields = [f.strip() for f in fields]
            if not any(fields) or fields[0].startswith("#"):
                continue
            if not rows and not bad and tuple(f.lower() for f in fields[:4]) == HEADER:
                continue
            if len(fields) not in (4, 5) or not all(fields[:4]):
                bad.append((line, "", f"expected image_a,image_b,points_a,points_b[,name], got {len(fields)} fields"))
                continue
            a, b, pa, pb = (base / f for f in fields[:4])
            name = fields[4] if len(fields) == 5 and fields[4] else f"{a.stem}-{b.stem}"
            if Path(name).name != name or name in (".", ".."):
                bad.append((line, name, f"name {name!r} must be a plain file name (no folders)"))
            elif name in seen:
                bad.append((line, name, f"name {name!r} is already used by row {seen[name]}"))
            else:
                seen[name] = line
                rows.append(PairRow(line, name, a, b, pa, pb))
    return rows, bad


def morph_pairs(
    pairs: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    fmt: OutputFormat = "gif",
    fps: float = 15.0,
    overwrite: bool = False,
    progress: bool = True,
    rank: int | None = None,
    world_size: int | None = None,
    settings: MorphSettings = NaturalSettings(),
    frames: int = 30,
    timing: Timing = Timing(),
    blending: Blending = Blending(),
    max_memory: float | None = None,
    max_size: int = 0,
    names: Mapping[str, str] | None = None,
) -> BatchReport:
    """Morph every pair of the CSV ``pairs`` into the folder ``out``, one after another.

    Args:
        pairs: the pairs CSV (format in the module docstring).
        out: the output folder (created if missing); it receives the outputs, ``summary.csv`` and
            ``failures.csv``.
        fmt: ``"gif"``, ``"mp4"`` (imageio-ffmpeg) or ``"png"`` (a folder of frames per pair).
        fps: frames per second of the outputs.
        overwrite: redo pairs whose output exists (by default they are skipped, which resumes a killed run).
        progress: a progress bar counting pairs.
        rank, world_size: this process's share, pairs ``rank, rank + world_size, ...``; by default from the
            ``RANK`` and ``WORLD_SIZE`` variables that ``torchrun`` sets (0 and 1 without them).
        settings, frames, timing, blending, max_memory: :func:`~torchfluidwarp.morph.morph`'s, for every pair
            (``blending.region`` may be ``"points"`` or ``None``: one pair of masks cannot serve every pair).
        max_size: without ``blending.size``, each pair's GIF or MP4 is written with its image A's size shrunk so
            that its longer side is at most this many pixels (:func:`~torchfluidwarp.io.shrunk_size`; 0 keeps
            it, as do PNG frames).
        names: how the summary's ``warnings`` column names the settings a warning's advice names (an
            :class:`~torchfluidwarp.errors.AdvisedWarning`'s :class:`~torchfluidwarp.errors.Hint`): the command line
            passes its flags (``{"straightness": "--straightness S"}``); by default Python's.

    Returns:
        This process's :class:`BatchReport` (with several ranks, its ``failed`` lists every rank's failures).

    Raises:
        OSError: the CSV cannot be read or ``out`` cannot be made.
        ValueError: a bad ``fmt``, ``rank`` or ``world_size``; ``"mp4"`` without imageio-ffmpeg.
    """
    if fmt not in ("gif", "mp4", "png"):
        raise InputError(f"fmt must be 'gif', 'mp4' or 'png', got {fmt!r}")
    check_instance("blending", blending, Blending)
    if blending.region not in (None, "points"):
        raise InputError(
            "blending.region must be 'points' or None for a batch: one pair of masks cannot serve every pair"
        )
    check_int("max_size", max_size, minimum=0)
    options = _MorphOptions(settings, frames, timing, blending, max_memory, _animation_limit(fmt, max_size), names)
    if fmt == "mp4" and importlib.util.find_spec("imageio_ffmpeg") is None:
        raise InputError(FFMPEG_HINT)
    rank, world_size = _ranks(rank, world_size)
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    rows, bad = read_pairs(pairs)
    gather = world_size > 1 and _distributed()
    suffix = f".rank{rank}" if world_size > 1 and not gather else ""
    summary_path = folder / f"summary{suffix}.csv"
    summary = {r["name"]: r for r in _read_csv(summary_path)}
    report = BatchReport(failed=list(bad) if rank == 0 else [])
    device = _device()
    plan = _plan(rows, folder, fmt, overwrite, rank, world_size)
    bar = tqdm(plan, unit="pair", desc="pairs" if world_size == 1 else f"pairs (rank {rank})", disable=not progress)
    for pair, target, done in bar:
        if done:
            report.skipped.append(pair.name)
            summary.setdefault(pair.name, {"name": pair.name, "output": target, "status": "exists"})
            continue
        for stale in folder.glob(_temporary_pattern(Path(target), fmt)):  # a killed run's half-written output
            _remove(stale)
        try:
            summary[pair.name] = _morph_pair(pair, target, fps, overwrite, device, options)
        except (KeyboardInterrupt, SystemExit):
            raise
        except Exception as exc:  # noqa: BLE001  (one bad pair must not stop the others)
            report.failed.append((pair.row, pair.name, f"{type(exc).__name__}: {first_line(exc)}"))
            continue
        report.morphed.append(pair.name)
        if not gather:  # a killed run keeps the summary of the pairs it finished
            _write_csv(summary_path, SUMMARY_FIELDS, summary.values())
    if gather:
        summary, report.failed = _gather(summary, report.failed)
    if rank == 0 or not gather:
        listed = {r.name for r in rows}
        ordered = [summary[r.name] for r in rows if r.name in summary]
        ordered += [v for k, v in summary.items() if k not in listed]  # earlier runs' other rows
        _write_csv(summary_path, SUMMARY_FIELDS, ordered)
        report.failed.sort()
        failures = (dict(zip(FAILURE_FIELDS, f)) for f in report.failed)
        _write_csv(folder / f"failures{suffix}.csv", FAILURE_FIELDS, failures)
    return report


class PlannedOutput(NamedTuple):
    """One output :func:`morph_pairs` would write (:func:`planned_work`).

    Attributes:
        output: its path (a GIF or MP4 file, or a folder of PNG frames ending in ``/``).
        shape: its frames' ``(C, H, W)``: image A's channels, at ``size`` or A's size shrunk to ``max_size``.
        shrunk: whether ``max_size`` shrank A's size (``shape`` is then smaller than A).
    """

    output: str
    shape: tuple[int, int, int]
    shrunk: bool


def planned_work(
    pairs: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    fmt: OutputFormat = "gif",
    overwrite: bool = False,
    rank: int | None = None,
    world_size: int | None = None,
    max_size: int = 0,
    size: tuple[int, int] | None = None,
) -> list[PlannedOutput]:
    """What :func:`morph_pairs` with the same arguments would write: a :class:`PlannedOutput` for each pair it
    would morph, its frames' shape read from image A's file header (no pixels are decoded), at ``size``
    (``blending.size``) or shrunk to ``max_size`` as :func:`morph_pairs` does.

    This process's share of the CSV's good rows, less those a rerun skips (their output exists and not
    ``overwrite``), less those whose image A cannot be read (they fail when their turn comes, with the reason).
    Nothing is written: the command line checks the batch's work with it before any pair is morphed.

    Raises:
        OSError: the CSV cannot be read.
        ValueError: a bad ``rank``, ``world_size``, ``max_size`` or ``size``.
    """
    check_int("max_size", max_size, minimum=0)
    if size is not None:
        size = check_size("size", size)
    rank, world_size = _ranks(rank, world_size)
    rows, _ = read_pairs(pairs)
    work = []
    for pair, target, done in _plan(rows, Path(out), fmt, overwrite, rank, world_size):
        shape = None if done else _frame_shape(pair.image_a)
        if shape is not None:
            frames = _frames_size(shape[1:], size, _animation_limit(fmt, max_size))
            work.append(PlannedOutput(target, (shape[0], *frames), size is None and frames != shape[1:]))
    return work


def _animation_limit(fmt: str, max_size: int) -> int:
    """The ``max_size`` that applies to a batch's outputs: GIFs and MP4s are shrunk, PNG frames keep A's size."""
    return 0 if fmt == "png" else max_size


def _frames_size(size_a: tuple[int, int], size: tuple[int, int] | None, max_size: int) -> tuple[int, int]:
    """A pair's frames' ``(H, W)``: ``size`` (``blending.size``) when given, else A's ``size_a`` shrunk so that its
    longer side is at most ``max_size`` (0: kept)."""
    return shrunk_size(size_a, max_size) if size is None else size


def _ranks(rank: int | None, world_size: int | None) -> tuple[int, int]:
    """``rank`` and ``world_size``, by default from ``torchrun``'s ``RANK`` and ``WORLD_SIZE`` (0 and 1 without)."""
    rank = int(os.environ.get("RANK", 0)) if rank is None else rank
    world_size = int(os.environ.get("WORLD_SIZE", 1)) if world_size is None else world_size
    if not 0 <= rank < world_size:
        raise InputError(f"rank must be in [0, world_size), got rank={rank}, world_size={world_size}")
    return rank, world_size


def _plan(
    rows: list[PairRow], folder: Path, fmt: str, overwrite: bool, rank: int, world_size: int
) -> list[tuple[PairRow, str, bool]]:
    """This rank's pairs ``rank, rank + world_size, ...``, each with its output and whether it is done (its output
    exists and not ``overwrite``: a rerun skips it)."""
    plan = []
    for pair in rows[rank::world_size]:
        target = f"{folder / pair.name}{'/' if fmt == 'png' else '.' + fmt}"
        plan.append((pair, target, not overwrite and _exists(Path(target))))
    return plan


def _frame_shape(path: Path) -> tuple[int, int, int] | None:
    """``(C, H, W)`` of the image file at ``path`` from its header, or ``None`` when it cannot be read (its pair
    fails when its turn comes, with the reason)."""
    try:
        return image_shape(path)
    except InputError:
        return None


@dataclass(frozen=True)
class _MorphOptions:
    """:func:`~torchfluidwarp.morph.morph`'s settings for every pair of a batch."""

    settings: MorphSettings
    frames: int
    timing: Timing
    blending: Blending
    max_memory: float | None
    max_size: int  # 0: image A's size (PNG frames, or not asked)
    names: Mapping[str, str] | None  # the settings' names in the warnings' advice (the command line's flags)


def _morph_pair(
    pair: PairRow, target: str, fps: float, overwrite: bool, device: torch.device, options: _MorphOptions
) -> dict[str, Any]:
    """Morph one pair into ``target`` (atomically) and return its summary row."""
    t0 = time.perf_counter()
    a = read_image(pair.image_a).to(device)
    b = read_image(pair.image_b).to(device)
    pa, pb = read_points(pair.points_a), read_points(pair.points_b)
    check_point_counts(pa, pb, "points_a", "points_b")
    check_point_files((pair.points_a, pair.points_b), (pa, pb), (a, b))  # named by their files
    blending = options.blending
    size = None if blending.size is None else check_size("blending.size", blending.size)
    height, width = _frames_size((a.shape[-2], a.shape[-1]), size, options.max_size)
    if blending.size is None and (height, width) != tuple(a.shape[-2:]):  # its longer side at max_size
        blending = dataclasses.replace(blending, size=(height, width))
    check_disk_space(target, options.frames, height, width, a.shape[1])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = morph(
            a,
            b,
            pa.to(device),
            pb.to(device),
            settings=options.settings,
            frames=options.frames,
            timing=options.timing,
            blending=blending,
            progress=False,
            max_memory=options.max_memory,
        )
        check_met(result.error, result.let_go, result.targets)  # no mark met: a failed row, nothing written
        write_animation(target, returning_memory(stream_frames(result)), fps=fps, overwrite=overwrite)
    err = result.met_error  # those let go so as not to fold are counted apart
    err = err if err.numel() else result.error.new_full((1,), float("nan"))
    return {
        "name": pair.name,
        "output": target,
        "status": "morphed",
        "error_mean_px": f"{float(err.mean()):.4f}",
        "error_max_px": f"{float(err.max()):.4f}",
        "let_go": str(int(result.let_go.sum())),
        "folded": f"{result.folded:.6g}",
        "seconds": f"{time.perf_counter() - t0:.2f}",
        "warnings": " | ".join(first_line(worded(w.message, options.names)) for w in caught),
    }


def _device() -> torch.device:
    if torch.cuda.is_available():
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))
    return torch.device("cpu")


def _distributed() -> bool:
    """Whether the ranks can talk: a ``torch.distributed`` group exists, or ``torchrun``'s rendezvous is set."""
    import torch.distributed as dist

    return dist.is_available() and (dist.is_initialized() or "MASTER_ADDR" in os.environ)


def _gather(
    summary: dict[str, dict[str, Any]], failed: list[tuple[int, str, str]]
) -> tuple[dict[str, dict[str, Any]], list[tuple[int, str, str]]]:
    """Every rank's summary rows and failures, on every rank (``torch.distributed``, started here if needed)."""
    import torch.distributed as dist

    started = not dist.is_initialized()
    if started:
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    try:
        parts: list[Any] = [None] * dist.get_world_size()
        dist.all_gather_object(parts, (summary, failed))
    finally:
        if started:
            dist.destroy_process_group()
    merged: dict[str, dict[str, Any]] = {}
    failures: list[tuple[int, str, str]] = []
    for part_summary, part_failed in parts:
        for name, row in part_summary.items():
            if name not in merged or row.get("status") == "morphed":
                merged[name] = row
        failures += [tuple(f) for f in part_failed]
    return merged, failures


def _temporary_pattern(target: Path, fmt: str) -> str:
    """The glob of the temporary names :func:`~torchfluidwarp.io.write_animation` gives ``target`` while it writes
    (``.<name>.<8 hex digits>.tmp<suffix>``), for this pair only."""
    return f".{glob.escape(target.name)}.{'?' * 8}.tmp{'' if fmt == 'png' else '.' + fmt}"


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _exists(target: Path) -> bool:
    return any(target.iterdir()) if target.is_dir() else target.exists()


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as fp:
        return [row for row in csv.DictReader(fp) if row.get("name")]


def _write_csv(path: Path, fields: tuple[str, ...], rows: Any) -> None:
    """Write ``rows`` (dicts) as CSV atomically: a temporary sibling moved into place."""
    tmp = path.with_name(f".{path.name}.tmp")  # one writer per file: a killed run's leftover is overwritten
    try:
        with open(tmp, "w", newline="", encoding="utf-8") as fp:
            writer = csv.DictWriter(fp, fields, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
