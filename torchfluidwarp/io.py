"""Reading and writing images, landmark points and animations.

Conventions:

* Images are float tensors ``(B, C, H, W)`` with values in ``[0, 1]`` and ``C`` = 1 (gray), 3 (RGB) or
  4 (RGBA). ``uint8`` appears only at the file boundary: writers clamp to ``[0, 1]`` and round to 8 bits.
* Points are float tensors ``(M, 2)`` in ``(x, y)`` order, in pixel coordinates with pixel centres at
  integers (see :mod:`torchfluidwarp.core.grid`).
* Animations are float tensors ``(T, C, H, W)``: ``T`` frames, values in ``[0, 1]``.
* Every writer writes to a temporary sibling of its output and moves it into place with ``os.replace``,
  so a failure never leaves a half-written file behind.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO, Literal

import imageio.v3 as iio
import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image
from torch import Tensor

from torchfluidwarp._checks import check_int, check_positive, check_tensor, describe

__all__ = [
    "read_image",
    "read_image_bytes",
    "write_image",
    "resize_image",
    "shrink_image",
    "read_points",
    "write_points",
    "check_point_counts",
    "write_animation",
    "encode_animation",
]

PathLike = str | os.PathLike[str]
AnimationFormat = Literal["gif", "mp4"]

POINT_SUFFIXES = (".pts", ".json", ".csv")
FFMPEG_HINT = "MP4 output needs imageio-ffmpeg: pip install 'torchfluidwarp[video]'"

# Decoders raise all of these for files that are not (complete) images; Pillow uses SyntaxError for
# broken PNG chunks and imageio an OSError when no plugin recognises the data.
_DECODE_ERRORS = (OSError, ValueError, RuntimeError, SyntaxError, EOFError)

# ITU-R BT.601 luma weights, the ones Pillow uses for RGB -> L.
_LUMA = (0.299, 0.587, 0.114)


# ---------------------------------------------------------------------------------------------- images


def read_image(path: PathLike, *, channels: int | None = None, dtype: torch.dtype = torch.float32) -> Tensor:
    """Read an image file into a ``(1, C, H, W)`` tensor with values in ``[0, 1]``.

    8- and 16-bit images are scaled by their integer range; float images are clipped to ``[0, 1]``.
    A multi-frame file (GIF, TIFF) gives its first frame.

    Args:
        path: the image file; any format imageio reads (PNG, JPEG, GIF, TIFF, ...).
        channels: ``None`` keeps the file's channels (gray gives 1, RGB 3, RGBA 4, gray+alpha 4);
            1 converts to gray (BT.601 luma, alpha dropped), 3 to RGB (gray repeated, alpha dropped),
            4 to RGBA (opaque alpha added where missing).
        dtype: a floating-point dtype for the result.

    Returns:
        ``(1, C, H, W)`` tensor on the CPU.

    Raises:
        ValueError: the file does not exist or is not a readable image, or ``channels`` is not
            ``None``, 1, 3 or 4.
        TypeError: ``dtype`` is not floating point.

    Example:
        >>> import tempfile, torch
        >>> path = tempfile.mkdtemp() + "/gray.png"
        >>> _ = write_image(path, torch.full((1, 4, 6), 0.5))
        >>> read_image(path, channels=3).shape
        torch.Size([1, 3, 4, 6])
    """
    _check_image_options(channels, dtype)
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"cannot read image {str(path)!r}: no such file")
    try:
        array = iio.imread(path, index=0)
    except _DECODE_ERRORS as exc:
        raise ValueError(f"cannot read image {str(path)!r}: not a readable image ({_first_line(exc)})") from exc
    return _tensor_from_array(array, f"image {str(path)!r}", channels, dtype)


def read_image_bytes(data: bytes, *, channels: int | None = None, dtype: torch.dtype = torch.float32) -> Tensor:
    """Decode an encoded image (the bytes of a PNG, JPEG, ... file, e.g. an upload).

    Args:
        data: the encoded file contents.
        channels: as in :func:`read_image`.
        dtype: as in :func:`read_image`.

    Returns:
        ``(1, C, H, W)`` tensor with values in ``[0, 1]``.

    Raises:
        TypeError: ``data`` is not bytes-like, or ``dtype`` is not floating point.
        ValueError: ``data`` is not a readable image, or ``channels`` is invalid.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f"data must be bytes, got {describe(data)}")
    _check_image_options(channels, dtype)
    source = f"image bytes ({len(data)} bytes)"
    try:
        array = iio.imread(bytes(data), index=0)
    except _DECODE_ERRORS as exc:
        raise ValueError(f"cannot read {source}: not a readable image ({_first_line(exc)})") from exc
    return _tensor_from_array(array, source, channels, dtype)


def write_image(path: PathLike, image: Tensor) -> Path:
    """Write an image tensor to a file, atomically, as 8 bits per channel.

    Values are clamped to ``[0, 1]`` and rounded to ``uint8``; the format follows the suffix
    (``.png`` is lossless). An existing file is replaced.

    Args:
        path: the output file.
        image: ``(C, H, W)`` or ``(1, C, H, W)`` float tensor, ``C`` in 1, 3, 4.

    Returns:
        The path written.

    Raises:
        TypeError, ValueError: ``image`` is not a finite float tensor of one of those shapes.
    """
    check_tensor("image", image, ndim=(3, 4))
    if image.ndim == 4 and image.shape[0] != 1:
        raise ValueError(f"image must be (C, H, W) or (1, C, H, W), got shape {tuple(image.shape)}")
    array = _uint8_frames(image.reshape(1, *image.shape[-3:]), "image")[0]  # (H, W, C)
    path = Path(path)
    with _atomic_output(path) as tmp:
        iio.imwrite(tmp, array[..., 0] if array.shape[-1] == 1 else array)
    return path


def resize_image(image: Tensor, size: tuple[int, int]) -> Tensor:
    """Resize an image to ``size``: bilinear, antialiased when it shrinks.

    torch's antialiased bilinear (``F.interpolate(..., antialias=True)``): each output pixel averages the input
    under a triangle as wide as the scale factor, so fine detail is averaged away rather than aliased. Its
    weights are non-negative and sum to one: values stay within the input's range. (kornia's ``resize`` blurs
    with a Gaussian first and then samples; it is slower and aliases at mild factors: ``docs/design.rst``.)

    Conventions: ``align_corners=False``; pixel centres at integers, and the image's outer edges (``-0.5`` and
    ``H - 0.5``) map onto each other.

    Args:
        image: ``(B, C, H, W)`` floats.
        size: ``(H', W')`` in pixels.

    Returns:
        ``(B, C, H', W')``; ``image`` itself when it already has that size.

    Example:
        >>> resize_image(torch.ones(1, 3, 8, 6), (4, 3)).shape
        torch.Size([1, 3, 4, 3])
    """
    check_tensor("image", image, ndim=4, finite=False)
    if tuple(image.shape[-2:]) == tuple(size):
        return image
    return F.interpolate(image, size=size, mode="bilinear", align_corners=False, antialias=True)


def shrink_image(image: Tensor, longest: int) -> Tensor:
    """Downscale an image so that its longer side is at most ``longest`` pixels, keeping its aspect ratio.

    Each side is rounded, and kept at least 2 pixels; the result is :func:`resize_image`'s, clamped to
    ``[0, 1]`` (which only trims roundoff for an image in ``[0, 1]``).

    Args:
        image: ``(B, C, H, W)`` floats in ``[0, 1]``.
        longest: the longest side allowed, in pixels; 0 keeps every size.

    Returns:
        ``(B, C, H', W')``; ``image`` itself when it is small enough already.

    Example:
        >>> shrink_image(torch.ones(1, 3, 300, 200), 150).shape
        torch.Size([1, 3, 150, 100])
    """
    check_int("longest", longest, minimum=0)
    H, W = image.shape[-2:]
    if longest == 0 or max(H, W) <= longest:
        return image
    scale = longest / max(H, W)
    return resize_image(image, (max(2, round(H * scale)), max(2, round(W * scale)))).clamp(0, 1)


def _check_image_options(channels: int | None, dtype: torch.dtype) -> None:
    if channels is not None and channels not in (1, 3, 4):
        raise ValueError(f"channels must be None, 1, 3 or 4, got {channels!r}")
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise TypeError(f"dtype must be a floating-point torch.dtype, got {describe(dtype)}")


def _tensor_from_array(array: np.ndarray, source: str, channels: int | None, dtype: torch.dtype) -> Tensor:
    """``(H, W)`` or ``(H, W, C)`` decoded pixels -> ``(1, C', H, W)`` in ``[0, 1]``."""
    if array.ndim == 2:
        array = array[..., None]
    if array.ndim != 3 or not 1 <= array.shape[-1] <= 4:
        raise ValueError(f"cannot read {source}: unsupported pixel layout {array.shape}")
    if array.dtype == np.bool_:
        values = array.astype(np.float64)
    elif np.issubdtype(array.dtype, np.integer):
        values = array.astype(np.float64) / np.iinfo(array.dtype).max
    else:
        values = np.clip(np.nan_to_num(array.astype(np.float64)), 0.0, 1.0)
    image = torch.from_numpy(values).permute(2, 0, 1).unsqueeze(0)  # (1, C, H, W)
    if image.shape[1] == 2:  # gray + alpha: keep the alpha, as RGBA
        image = torch.cat([image[:, :1].expand(-1, 3, -1, -1), image[:, 1:]], dim=1)
    return _convert_channels(image, channels).to(dtype).contiguous()


def _convert_channels(image: Tensor, channels: int | None) -> Tensor:
    """``(B, C, H, W)`` with ``C`` in 1, 3, 4 -> ``(B, channels, H, W)``."""
    c = image.shape[1]
    if channels is None or channels == c:
        return image
    color = image[:, :3] if c >= 3 else image[:, :1]
    if channels == 1:
        weights = torch.tensor(_LUMA, dtype=image.dtype, device=image.device).view(1, 3, 1, 1)
        return color if c == 1 else (color * weights).sum(dim=1, keepdim=True)
    rgb = color.expand(-1, 3, -1, -1)
    if channels == 3:
        return rgb
    alpha = image[:, 3:] if c == 4 else torch.ones_like(image[:, :1])
    return torch.cat([rgb, alpha], dim=1)


_CONVERT_BYTES = 64 * 2**20
"""Frames are converted to uint8 in chunks of about this many bytes of float64, not all at once (300 frames
of 1920 x 1080 RGB would take 15 GB as float64)."""


def _uint8_frames(frames: Tensor, name: str) -> np.ndarray:
    """``(T, C, H, W)`` floats in ``[0, 1]`` -> ``(T, H, W, C)`` uint8, after validating them."""
    check_tensor(name, frames, ndim=4)
    t, c, h, w = frames.shape
    if c not in (1, 3, 4) or min(t, h, w) < 1:
        raise ValueError(f"{name} must have C in 1, 3, 4 and non-empty T, H, W; got shape {tuple(frames.shape)}")
    out = torch.empty(t, h, w, c, dtype=torch.uint8)
    chunk = max(1, _CONVERT_BYTES // (8 * c * h * w))  # frames per float64 chunk: memory stays bounded
    for i in range(0, t, chunk):
        part = frames[i : i + chunk].detach().to("cpu", torch.float64).clamp(0.0, 1.0).mul(255.0).round()
        out[i : i + chunk] = part.to(torch.uint8).permute(0, 2, 3, 1)
    return out.numpy()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


# ---------------------------------------------------------------------------------------------- points


def read_points(path: PathLike, *, dtype: torch.dtype = torch.float32) -> Tensor:
    """Read landmark points from a ``.pts``, ``.json`` or ``.csv`` file.

    Formats (chosen by the suffix):

    * ``.pts`` (iBUG): ``version: 1``, ``n_points: N``, ``{``, then N lines ``x y``, then ``}``.
    * ``.json``: ``[[x, y], ...]`` or ``{"points": [[x, y], ...]}``.
    * ``.csv``: one ``x,y`` row per point, after an optional header row ``x,y``.

    Conventions:
        Coordinates are returned exactly as written, as pixel coordinates with pixel centres at
        integers. Some tools write iBUG ``.pts`` files 1-based (the top-left pixel centre at
        ``(1, 1)``); no offset is applied here, so subtract 1 from such files yourself.

    Args:
        path: the points file.
        dtype: a floating-point dtype for the result.

    Returns:
        ``(M, 2)`` tensor of ``(x, y)`` pixel coordinates.

    Raises:
        ValueError: the file is missing, its suffix is unknown, it is malformed, a value is not
            finite, or a ``.pts`` file's ``n_points`` disagrees with its point lines.
    """
    path = Path(path)
    suffix = _point_suffix(path)
    if not path.is_file():
        raise ValueError(f"cannot read points {str(path)!r}: no such file")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read points {str(path)!r}: {_first_line(exc)}") from exc
    parse = {".pts": _parse_pts, ".json": _parse_json, ".csv": _parse_csv}[suffix]
    try:
        rows = parse(text)
    except ValueError as exc:
        raise ValueError(f"malformed points file {str(path)!r}: {exc}") from None
    points = torch.tensor(rows, dtype=torch.float64).reshape(-1, 2)
    if not bool(torch.isfinite(points).all()):
        raise ValueError(f"malformed points file {str(path)!r}: contains non-finite values (NaN or inf)")
    return points.to(dtype)


def write_points(path: PathLike, points: Tensor) -> Path:
    """Write landmark points to a ``.pts``, ``.json`` or ``.csv`` file, atomically.

    The format follows the suffix as in :func:`read_points` (``.json`` is written as
    ``{"points": [[x, y], ...]}``, ``.csv`` with an ``x,y`` header). Each value is written with the
    fewest digits that read back to the same number in the tensor's dtype.

    Args:
        path: the output file; an existing file is replaced.
        points: ``(M, 2)`` float tensor of ``(x, y)`` pixel coordinates.

    Returns:
        The path written.

    Raises:
        TypeError, ValueError: ``points`` is not a finite ``(M, 2)`` float tensor, or the suffix is
            not ``.pts``, ``.json`` or ``.csv``.

    Example:
        >>> import tempfile, torch
        >>> path = tempfile.mkdtemp() + "/face.pts"
        >>> _ = write_points(path, torch.tensor([[10.5, 20.25], [30.0, 40.0]]))
        >>> read_points(path).tolist()
        [[10.5, 20.25], [30.0, 40.0]]
    """
    check_tensor("points", points, shape=(None, 2))
    path = Path(path)
    suffix = _point_suffix(path)
    array = points.detach().cpu().numpy()
    rows = [[_shortest(x), _shortest(y)] for x, y in array]
    if suffix == ".pts":
        lines = ["version: 1", f"n_points: {len(rows)}", "{", *(f"{x} {y}" for x, y in rows), "}"]
        text = "\n".join(lines) + "\n"
    elif suffix == ".json":
        text = json.dumps({"points": [[float(x), float(y)] for x, y in rows]}) + "\n"
    else:
        text = "x,y\n" + "".join(f"{x},{y}\n" for x, y in rows)
    with _atomic_output(path) as tmp:
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
        TypeError, ValueError: either is not a finite ``(M, 2)`` float tensor.
        ValueError: ``M != N``; the message names both counts.

    Example:
        >>> import torch
        >>> check_point_counts(torch.zeros(3, 2), torch.zeros(2, 2), "src", "dst")
        Traceback (most recent call last):
        ...
        ValueError: src has 3 points but dst has 2
    """
    check_tensor(name_a, points_a, shape=(None, 2))
    check_tensor(name_b, points_b, shape=(None, 2))
    if points_a.shape[0] != points_b.shape[0]:
        raise ValueError(f"{name_a} has {points_a.shape[0]} points but {name_b} has {points_b.shape[0]}")


def _point_suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in POINT_SUFFIXES:
        raise ValueError(f"unknown points format for {str(path)!r}: suffix must be one of {', '.join(POINT_SUFFIXES)}")
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
        raise ValueError(f"{where}: not a number in {fields!r}") from None


def _parse_pts(text: str) -> list[list[float]]:
    lines = [(n, line.strip()) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
    header: dict[str, str] = {}
    i = 0
    while i < len(lines) and lines[i][1] != "{":
        n, line = lines[i]
        key, sep, value = line.partition(":")
        if not sep:
            raise ValueError(f"line {n}: expected 'key: value' or '{{', got {line!r}")
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
            raise ValueError(f"point {k}: expected [x, y] with two numbers, got {item!r}")
        rows.append([float(item[0]), float(item[1])])
    return rows


def _parse_csv(text: str) -> list[list[float]]:
    rows: list[list[float]] = []
    for n, fields in enumerate(csv.reader(io.StringIO(text)), start=1):
        fields = [f.strip() for f in fields]
        if not any(fields):
            continue
        if not rows and [f.lower() for f in fields] == ["x", "y"]:
            continue
        rows.append(_parse_pair(fields, f"line {n}"))
    return rows


# ------------------------------------------------------------------------------------------ animations


def write_animation(
    path: PathLike, frames: Tensor, *, fps: float = 10.0, overwrite: bool = False, loop: int = 0
) -> Path:
    """Write frames as a GIF, an MP4 or a folder of PNGs, atomically.

    The output kind follows the path:

    * ``*.gif``: an animated GIF (Pillow). Each frame is shown for ``1 / fps`` seconds, rounded to
      the GIF's 10 ms steps; every frame is kept, repeated ones included.
    * ``*.mp4``: H.264 through imageio's ffmpeg plugin (needs the ``[video]`` extra). Odd sizes are
      padded by one edge row/column, as yuv420p needs even sizes.
    * a path ending in ``/``, an existing directory or a path without suffix: a folder of
      ``frame_0000.png``, ``frame_0001.png``, ... (all channels kept).

    GIF and MP4 are RGB: gray frames are repeated to RGB and an alpha channel is dropped.

    Args:
        path: the output file or folder. Missing parent folders are created.
        frames: ``(T, C, H, W)`` float tensor with values in ``[0, 1]``, ``C`` in 1, 3, 4.
        fps: frames per second (> 0).
        overwrite: replace an existing output. Without it an existing file, or a non-empty folder,
            raises ``FileExistsError``. A folder is only replaced if it holds nothing but frames.
        loop: GIF repeat count; 0 loops forever.

    Returns:
        The path written.

    Raises:
        TypeError, ValueError: bad ``frames``, ``fps`` or ``loop``, or an unknown suffix.
        FileExistsError: the output exists and ``overwrite`` is false.
        RuntimeError: MP4 output without imageio-ffmpeg installed.
    """
    target = Path(path)
    as_folder = os.fspath(path).endswith(("/", os.sep)) or target.is_dir() or not target.suffix
    kind = "frames" if as_folder else _animation_format(target.suffix)
    data = _uint8_frames(frames, "frames")
    fps = check_positive("fps", fps)
    check_int("loop", loop, minimum=0)
    if kind == "mp4":
        _require_ffmpeg()
    _check_overwrite(target, overwrite)
    target.parent.mkdir(parents=True, exist_ok=True)
    with _atomic_output(target, folder=kind == "frames") as tmp:
        if kind == "frames":
            digits = max(4, len(str(len(data) - 1)))
            for t, frame in enumerate(data):
                iio.imwrite(tmp / f"frame_{t:0{digits}d}.png", frame[..., 0] if frame.shape[-1] == 1 else frame)
        elif kind == "gif":
            with open(tmp, "wb") as fp:
                _write_gif(fp, data, fps, loop)
        else:
            _write_mp4(tmp, data, fps)
    return target


def encode_animation(frames: Tensor, fmt: AnimationFormat = "gif", *, fps: float = 10.0, loop: int = 0) -> bytes:
    """Encode frames as GIF or MP4 bytes, e.g. to send from a web server without touching disk.

    Args:
        frames: ``(T, C, H, W)`` float tensor with values in ``[0, 1]``, ``C`` in 1, 3, 4.
        fmt: ``"gif"`` or ``"mp4"`` (MP4 needs imageio-ffmpeg and passes through a temporary file).
        fps: frames per second (> 0).
        loop: GIF repeat count; 0 loops forever.

    Returns:
        The encoded file contents, as :func:`write_animation` would write them.

    Raises:
        TypeError, ValueError: bad ``frames``, ``fmt``, ``fps`` or ``loop``.
        RuntimeError: ``fmt="mp4"`` without imageio-ffmpeg installed.

    Example:
        >>> import torch
        >>> encode_animation(torch.rand(3, 3, 8, 8), "gif")[:6]
        b'GIF89a'
    """
    if fmt not in ("gif", "mp4"):
        raise ValueError(f"fmt must be 'gif' or 'mp4', got {fmt!r}")
    data = _uint8_frames(frames, "frames")
    fps = check_positive("fps", fps)
    check_int("loop", loop, minimum=0)
    if fmt == "gif":
        buffer = io.BytesIO()
        _write_gif(buffer, data, fps, loop)
        return buffer.getvalue()
    _require_ffmpeg()
    with tempfile.TemporaryDirectory() as folder:
        file = Path(folder) / "animation.mp4"
        _write_mp4(file, data, fps)
        return file.read_bytes()


def _animation_format(suffix: str) -> str:
    kind = suffix.lower().lstrip(".")
    if kind not in ("gif", "mp4"):
        raise ValueError(
            f"unknown animation suffix {suffix!r}: use .gif, .mp4, or a folder (a path ending in '/' or without suffix)"
        )
    return kind


def _require_ffmpeg() -> None:
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        raise RuntimeError(FFMPEG_HINT) from None


def _write_gif(fp: BinaryIO, frames: np.ndarray, fps: float, loop: int) -> None:
    """Encode ``(T, H, W, C)`` uint8 frames as an animated GIF into a binary file object."""
    images = _gif_palette_frames(_rgb(frames))
    duration_ms = max(10, 10 * round(100.0 / fps))  # GIF delays count hundredths of a second
    images[0].save(
        fp, format="GIF", save_all=True, append_images=images[1:], duration=duration_ms, loop=loop, optimize=False
    )


def _gif_palette_frames(frames: np.ndarray) -> list[Image.Image]:
    """Quantize ``(T, H, W, 3)`` uint8 frames to palette images that Pillow keeps one for one.

    Pillow's GIF writer silently drops a frame that looks the same as the one before it (adding its
    delay to that one), whatever ``optimize`` says, so repeated frames (a pause) would change the
    frame count. Pillow compares palette indices when two frames share a palette, so each palette
    keeps its last entry (255) as a copy of the colour of pixel ``(0, 0)``: a repeated frame reuses
    the previous frame's palette and indices with pixel ``(0, 0)`` switched between the two
    same-coloured entries. The data differ, the picture does not.
    """
    images = []
    previous: tuple[np.ndarray, np.ndarray, int] | None = None  # (indices (H, W), palette (256, 3), twin)
    for rgb in frames:
        quantized = Image.fromarray(rgb).quantize(colors=255)  # median cut, no dithering
        indices = np.array(quantized, dtype=np.uint8)
        used = np.asarray((quantized.getpalette() or [])[: 3 * 255], dtype=np.uint8).reshape(-1, 3)
        palette = np.zeros((256, 3), dtype=np.uint8)
        palette[: len(used)] = used
        twin = int(indices[0, 0])
        palette[255] = palette[twin]
        if previous is not None and np.array_equal(palette[indices], previous[1][previous[0]]):
            indices, palette, twin = previous[0].copy(), previous[1], previous[2]
            indices[0, 0] = twin if indices[0, 0] == 255 else 255
        previous = (indices, palette, twin)
        image = Image.frombytes("P", (indices.shape[1], indices.shape[0]), indices.tobytes())
        image.putpalette(palette.tobytes())
        images.append(image)
    return images


def _write_mp4(file: Path, frames: np.ndarray, fps: float) -> None:
    """Encode ``(T, H, W, C)`` uint8 frames as H.264 (yuv420p) into ``file``."""
    rgb = _rgb(frames)
    _, h, w, _ = rgb.shape
    rgb = np.pad(rgb, ((0, 0), (0, h % 2), (0, w % 2), (0, 0)), mode="edge")  # yuv420p needs even sizes
    # macro_block_size=1: the size is already even, so imageio must not rescale the frames.
    iio.imwrite(file, rgb, extension=".mp4", plugin="FFMPEG", fps=fps, codec="libx264", macro_block_size=1)


def _rgb(frames: np.ndarray) -> np.ndarray:
    """``(T, H, W, C)`` uint8 with ``C`` in 1, 3, 4 -> ``(T, H, W, 3)``."""
    if frames.shape[-1] == 1:
        return np.repeat(frames, 3, axis=-1)
    return np.ascontiguousarray(frames[..., :3])


# ------------------------------------------------------------------------------------- atomic outputs


def _check_overwrite(target: Path, overwrite: bool) -> None:
    """Refuse to replace existing output unless asked; never replace a folder of other files."""
    if not (target.exists() or target.is_symlink()):
        return
    if target.is_dir() and not target.is_symlink():
        contents = list(target.iterdir())
        if not contents:
            return
        foreign = [p.name for p in contents if not (p.name.startswith("frame_") and p.suffix == ".png")]
        if foreign:
            raise FileExistsError(
                f"output folder {str(target)!r} holds files other than frames (e.g. {foreign[0]!r}); "
                "refusing to replace it"
            )
    if not overwrite:
        raise FileExistsError(f"output {str(target)!r} already exists; pass overwrite=True to replace it")


@contextlib.contextmanager
def _atomic_output(target: Path, *, folder: bool = False) -> Iterator[Path]:
    """Yield a temporary sibling of ``target`` to write; move it onto ``target`` only on success.

    The temporary name starts with a dot and keeps ``target``'s suffix, so writers that choose the
    format by extension still work. On any error it is removed and the error re-raised.
    """
    tmp = target.with_name(f".{target.name}.{uuid.uuid4().hex[:8]}.tmp{'' if folder else target.suffix}")
    if folder:
        tmp.mkdir()
    try:
        yield tmp
        _replace(tmp, target)
    except BaseException:
        _remove(tmp)
        raise


def _replace(tmp: Path, target: Path) -> None:
    """``os.replace`` that also replaces a folder, or a file by a folder (moving the old one aside first)."""
    if not (tmp.is_dir() or target.is_dir()) or not (target.exists() or target.is_symlink()):
        os.replace(tmp, target)
        return
    old = target.with_name(f".{target.name}.{uuid.uuid4().hex[:8]}.old")
    os.replace(target, old)
    try:
        os.replace(tmp, target)
    except BaseException:
        os.replace(old, target)
        raise
    _remove(old)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)
