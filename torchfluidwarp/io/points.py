"""Landmark point files: ``.pts`` (iBUG), ``.json`` and ``.csv``, read to and written from ``(M, 2)`` tensors.

Points are float tensors ``(M, 2)`` in ``(x, y)`` order, in pixel coordinates with pixel centres at
integers (see :mod:`torchfluidwarp.core.grid`).
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from torchfluidwarp._checks import argument_of, check_int, check_tensor
from torchfluidwarp.errors import InputError
from torchfluidwarp.io._files import (
    PathLike,
    atomic_output,
    check_float_dtype,
    check_output_path,
    check_path,
    first_line,
    make_parents,
)

__all__ = ["read_points", "write_points", "check_point_counts", "POINT_SUFFIXES", "MAX_POINTS_BYTES"]

POINT_SUFFIXES = (".pts", ".json", ".csv")


MAX_POINTS_BYTES = 16 * 2**20
"""The largest points file :func:`read_points` reads unless told otherwise (``max_bytes``): 16 MiB, some
500,000 points as CSV. Landmark files hold tens to thousands of points; the limit bounds the parse time."""


def read_points(path: PathLike, *, dtype: torch.dtype = torch.float32, max_bytes: int = MAX_POINTS_BYTES) -> Tensor:
    """Read landmark points from a ``.pts``, ``.json`` or ``.csv`` file.

    Formats (chosen by the suffix):

    * ``.pts`` (iBUG): ``version: 1``, ``n_points: N``, ``{``, then N lines ``x y``, then ``}``.
    * ``.json``: ``[[x, y], ...]`` or ``{"points": [[x, y], ...]}``.
    * ``.csv``: one ``x,y`` row per point; or a header row that names its columns, ``x`` and ``y`` among them
      (``id,x,y``, ``label,y,x``, any case), and the rows under it.

    Conventions:
        Coordinates are returned exactly as written, as pixel coordinates with pixel centres at
        integers. Some tools write iBUG ``.pts`` files 1-based (the top-left pixel centre at
        ``(1, 1)``); no offset is applied here, so subtract 1 from such files yourself.

    Args:
        path: the points file.
        dtype: a floating-point dtype for the result; every value must fit it (``float16`` tops out at 65504).
        max_bytes: the largest file to read (:data:`MAX_POINTS_BYTES` by default).

    Returns:
        ``(M, 2)`` tensor of ``(x, y)`` pixel coordinates.

    Raises:
        InputError: the file is missing or larger than ``max_bytes``, its suffix is unknown, it is malformed
            (JSON nested deeper than a list of pairs included), a value is not finite in ``dtype``, or a
            ``.pts`` file's ``n_points`` disagrees with its point lines.
        InputTypeError: ``path`` is not a path, ``dtype`` is not a floating-point dtype, or ``max_bytes`` not an int.
    """
    path = check_path("path", path)
    check_float_dtype("dtype", dtype)
    check_int("max_bytes", max_bytes)
    suffix = _point_suffix(path)
    if path.is_dir():
        raise InputError(f"cannot read points {str(path)!r}: it is a folder, not a file", argument="path")
    if not path.is_file():
        raise InputError(f"cannot read points {str(path)!r}: no such file", argument="path")
    if (size := path.stat().st_size) > max_bytes:
        raise InputError(
            f"cannot read points {str(path)!r}: {size:,} bytes, more than max_bytes={max_bytes:,} "
            "(pass a larger max_bytes to read it)",
            argument="path",
        )
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark (a spreadsheet's "CSV UTF-8") is dropped
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read points {str(path)!r}: {first_line(exc)}", argument="path") from exc
    parse = {".pts": _parse_pts, ".json": _parse_json, ".csv": _parse_csv}[suffix]
    try:
        rows = parse(text)
    except ValueError as exc:  # the parsers below say what they could not parse with a ValueError
        raise InputError(f"malformed points file {str(path)!r}: {exc}", argument="path") from None
    points = torch.tensor(rows, dtype=torch.float64).reshape(-1, 2)
    if not bool(torch.isfinite(points).all()):
        raise InputError(
            f"malformed points file {str(path)!r}: contains non-finite values (NaN or inf)", argument="path"
        )
    converted = points.to(dtype)
    if not bool(torch.isfinite(converted).all()):
        largest = float(points.abs().max())
        raise InputError(
            f"points file {str(path)!r}: a value ({largest:g}) is out of the range of dtype {dtype}", argument="dtype"
        )
    return converted


def write_points(path: PathLike, points: Tensor) -> Path:
    """Write landmark points to a ``.pts``, ``.json`` or ``.csv`` file, atomically.

    The format follows the suffix as in :func:`read_points` (``.json`` is written as
    ``{"points": [[x, y], ...]}``, ``.csv`` with an ``x,y`` header). Each value is written with the
    fewest digits that read back to the same number in the tensor's dtype.

    Args:
        path: the output file; an existing file is replaced, an existing folder is not. Missing parent
            folders are created.
        points: ``(M, 2)`` float tensor of ``(x, y)`` pixel coordinates (bfloat16 is written as float32).

    Returns:
        The path written.

    Raises:
        InputTypeError, InputError: ``points`` is not a finite ``(M, 2)`` float tensor, ``path`` is not a path or
            is a folder, or the suffix is not ``.pts``, ``.json`` or ``.csv``.

    Example:
        >>> import tempfile, torch
        >>> path = tempfile.mkdtemp() + "/face.pts"
        >>> _ = write_points(path, torch.tensor([[10.5, 20.25], [30.0, 40.0]]))
        >>> read_points(path).tolist()
        [[10.5, 20.25], [30.0, 40.0]]
    """
    path = check_output_path("path", path)
    check_tensor("points", points, shape=(None, 2))
    suffix = _point_suffix(path)
    # numpy has no bfloat16; float32 holds each of its values exactly
    array = points.detach().cpu().to(torch.float32 if points.dtype == torch.bfloat16 else points.dtype).numpy()
    rows = [[_shortest(x), _shortest(y)] for x, y in array]
    if suffix == ".pts":
        lines = ["version: 1", f"n_points: {len(rows)}", "{", *(f"{x} {y}" for x, y in rows), "}"]
        text = "\n".join(lines) + "\n"
    elif suffix == ".json":
        text = json.dumps({"points": [[float(x), float(y)] for x, y in rows]}) + "\n"
    else:
        text = "x,y\n" + "".join(f"{x},{y}\n" for x, y in rows)
    make_parents("path", path)
    with atomic_output(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def check_point_counts(points_a: Tensor, points_b: Tensor, name_a: str = "points_a", name_b: str = "points_b") -> None:
    """Check that two point sets are ``(M, 2)`` tensors with the same ``M``.

    Args:
        points_a: ``(M, 2)`` points.
        points_b: ``(N, 2)`` points.
        name_a: how ``points_a`` is named in the error (e.g. a file name).
        name_b: how ``points_b`` is named in the error.

    Raises:
        InputTypeError, InputError: either is not a finite ``(M, 2)`` float tensor.
        InputError: ``M != N``; the message names both counts.

    Example:
        >>> import torch
        >>> check_point_counts(torch.zeros(3, 2), torch.zeros(2, 2), "src", "dst")
        Traceback (most recent call last):
        ...
        torchfluidwarp.errors.InputError: src has 3 points but dst has 2
    """
    check_tensor(name_a, points_a, shape=(None, 2))
    check_tensor(name_b, points_b, shape=(None, 2))
    if points_a.shape[0] != points_b.shape[0]:
        raise InputError(
            f"{name_a} has {points_a.shape[0]} points but {name_b} has {points_b.shape[0]}",
            argument=argument_of(name_b),
        )


def _point_suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in POINT_SUFFIXES:
        raise InputError(
            f"unknown points format for {str(path)!r}: suffix must be one of {', '.join(POINT_SUFFIXES)}",
            argument="path",
        )
    return suffix


def _shortest(value: np.floating) -> str:
    """The shortest decimal that reads back to ``value`` in its own dtype."""
    return np.format_float_positional(value, unique=True, trim="-")


def _parse_pair(fields: list[str], where: str) -> list[float]:
    if len(fields) != 2:
        raise ValueError(f"{where}: expected 2 values 'x y', got {len(fields)}")
    try:
        return [float(fields[0]), float(fields[1])]
    except ValueError:
        raise ValueError(f"{where}: not a number in {_shorten(repr(fields))}") from None


def _parse_pts(text: str) -> list[list[float]]:
    lines = [(n, line.strip()) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
    header: dict[str, str] = {}
    i = 0
    while i < len(lines) and lines[i][1] != "{":
        n, line = lines[i]
        key, sep, value = line.partition(":")
        if not sep:
            raise ValueError(f"line {n}: expected 'key: value' or '{{', got {_shorten(repr(line))}")
        header[key.strip().lower()] = value.strip()
        i += 1
    if i == len(lines):
        raise ValueError("no '{' opening the point list")
    try:
        expected = int(header["n_points"])
    except (KeyError, ValueError):
        raise ValueError(f"missing or invalid 'n_points' header, got {header.get('n_points')!r}") from None
    close = next((j for j in range(i + 1, len(lines)) if lines[j][1] == "}"), None)
    if close is None:
        raise ValueError("no '}' closing the point list")
    if close != len(lines) - 1:
        raise ValueError(f"line {lines[close + 1][0]}: unexpected text after '}}'")
    rows = [_parse_pair(line.split(), f"line {n}") for n, line in lines[i + 1 : close]]
    if len(rows) != expected:
        raise ValueError(f"header says n_points: {expected} but the file has {len(rows)} point lines")
    return rows


def _parse_json(text: str) -> list[list[float]]:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"invalid JSON: {exc}") from None
    except RecursionError:  # the decoder recurses once per level: a few bytes of "[[[[..." exhaust the stack
        raise ValueError('JSON nested too deeply; expected [[x, y], ...] or {"points": [[x, y], ...]}') from None
    if isinstance(data, dict):
        if "points" not in data:
            raise ValueError('expected a list [[x, y], ...] or an object {"points": [[x, y], ...]}')
        data = data["points"]
    if not isinstance(data, list):
        raise ValueError(f"expected a list of [x, y] pairs, got {type(data).__name__}")
    rows = []
    for k, item in enumerate(data):
        ok = isinstance(item, list) and len(item) == 2
        if not ok or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in item):
            raise ValueError(f"point {k}: expected [x, y] with two numbers, got {_shorten(repr(item))}")
        try:
            rows.append([float(item[0]), float(item[1])])
        except OverflowError:  # an integer literal beyond float64
            raise ValueError(f"point {k}: a value is too large for a float, in {_shorten(repr(item))}") from None
    return rows


def _shorten(text: str, limit: int = 60) -> str:
    """``text`` cut to about ``limit`` characters, for messages that quote a file's contents."""
    return text if len(text) <= limit else f"{text[: limit - 5]}...({len(text):,} characters)"


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def _parse_csv(text: str) -> list[list[float]]:
    """Rows ``x,y``; or, after a header row that names its columns, the columns named ``x`` and ``y`` (any case,
    in any place, among others such as an id or a label)."""
    rows: list[list[float]] = []
    columns: tuple[int, int] | None = None  # where x and y are, when a header names them
    width = 2  # the header's number of columns
    reader = csv.reader(io.StringIO(text))
    try:
        for n, fields in enumerate(reader, start=1):
            fields = [f.strip() for f in fields]
            if not any(fields):
                continue
            if not rows and columns is None and not any(_is_number(f) for f in fields):  # a header
                names = [f.lower() for f in fields]
                if names.count("x") != 1 or names.count("y") != 1:
                    got = _shorten(str(fields))
                    raise ValueError(f"line {n}: a header row must name the columns x and y once each, got {got}")
                columns, width = (names.index("x"), names.index("y")), len(names)
                continue
            if columns is not None:
                if len(fields) != width:
                    raise ValueError(f"line {n}: {len(fields)} fields under a header of {width} columns")
                fields = [fields[columns[0]], fields[columns[1]]]
            rows.append(_parse_pair(fields, f"line {n}"))
    except csv.Error as exc:  # e.g. a field longer than csv.field_size_limit()
        raise ValueError(f"line {reader.line_num}: {exc}") from None
    return rows
