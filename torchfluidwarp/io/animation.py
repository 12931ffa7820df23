"""Animations: ``(T, C, H, W)`` frames streamed to an animated GIF, an MP4 or a folder of PNGs, or encoded to bytes.

Frames are float tensors ``(T, C, H, W)``: ``T`` frames, values in ``[0, 1]``, ``C`` in 1, 3, 4. Every output
is written to a temporary sibling and moved into place only on success.
"""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path
from typing import BinaryIO, Literal

import imageio.v3 as iio
import numpy as np
from PIL import Image
from torch import Tensor

from torchfluidwarp._checks import check_int, check_real, describe
from torchfluidwarp.io._files import PathLike, atomic_output, check_output_path, check_overwrite, make_parents
from torchfluidwarp.io.images import _uint8_frames

__all__ = [
    "write_animation",
    "encode_animation",
    "check_fps",
    "FFMPEG_HINT",
    "MIN_FPS",
    "MAX_FPS",
    "MAX_LOOP",
    "AnimationFormat",
]

AnimationFormat = Literal["gif", "mp4"]

FFMPEG_HINT = "MP4 output needs imageio-ffmpeg: pip install 'torchfluidwarp[video]'"

MIN_FPS = 0.01
"""The slowest frame rate :func:`write_animation` and :func:`encode_animation` accept: one frame per 100 s.
(A GIF delay is a 16-bit count of hundredths of a second, at most 655.35 s; ffmpeg refuses rates that round to
0.00.)"""
MAX_FPS = 1000.0
"""The fastest frame rate accepted. A GIF shows frames for whole hundredths of a second, at least 0.01 s, so
past 100 fps every GIF frame is shown for 0.01 s; MP4 keeps the rate."""
MAX_LOOP = 65535
"""The largest GIF repeat count (a 16-bit field)."""


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
        fps: frames per second, from :data:`MIN_FPS` (0.01) to :data:`MAX_FPS` (1000).
        overwrite: replace an existing output (a bool). Without it an existing file, or a non-empty folder,
            raises ``FileExistsError``. A folder is only replaced if it holds nothing but frames.
        loop: GIF repeat count, 0 to :data:`MAX_LOOP`; 0 loops forever.

    Returns:
        The path written.

    Raises:
        TypeError, ValueError: bad ``path``, ``frames``, ``fps``, ``loop`` or ``overwrite``, or an unknown
            suffix. They are checked before anything is written.
        FileExistsError: the output exists and ``overwrite`` is false.
        RuntimeError: MP4 output without imageio-ffmpeg installed.
    """
    target = check_output_path("path", path, folder_ok=True)
    as_folder = os.fspath(path).endswith(("/", os.sep)) or target.is_dir() or not target.suffix
    kind = "frames" if as_folder else _animation_format(target.suffix)
    fps = check_fps(fps)
    _check_loop(loop)
    if not isinstance(overwrite, bool):
        raise TypeError(f"overwrite must be a bool, got {describe(overwrite)}")
    data = _uint8_frames(frames, "frames")
    if kind == "mp4":
        _require_ffmpeg()
    check_overwrite(target, overwrite)
    make_parents("path", target)
    with atomic_output(target, folder=kind == "frames") as tmp:
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
        fps: frames per second, from :data:`MIN_FPS` (0.01) to :data:`MAX_FPS` (1000).
        loop: GIF repeat count, 0 to :data:`MAX_LOOP`; 0 loops forever.

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
    fps = check_fps(fps)
    _check_loop(loop)
    data = _uint8_frames(frames, "frames")
    if fmt == "gif":
        buffer = io.BytesIO()
        _write_gif(buffer, data, fps, loop)
        return buffer.getvalue()
    _require_ffmpeg()
    with tempfile.TemporaryDirectory() as folder:
        file = Path(folder) / "animation.mp4"
        _write_mp4(file, data, fps)
        return file.read_bytes()


def check_fps(fps: object) -> float:
    """Validate a frame rate for :func:`write_animation` and :func:`encode_animation` and return it as a float.

    Raises:
        TypeError: ``fps`` is not a real number.
        ValueError: ``fps`` is not finite, or outside :data:`MIN_FPS` to :data:`MAX_FPS`.

    Example:
        >>> check_fps(25)
        25.0
    """
    value = check_real("fps", fps)
    if not MIN_FPS <= value <= MAX_FPS:
        raise ValueError(f"fps must be from {MIN_FPS} to {MAX_FPS:g} frames per second, got {fps!r}")
    return value


def _check_loop(loop: object) -> None:
    if check_int("loop", loop, minimum=0) > MAX_LOOP:
        raise ValueError(f"loop must be at most {MAX_LOOP} (a GIF's 16-bit repeat count; 0 loops forever), got {loop}")


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
    if not file.is_file() or file.stat().st_size == 0:  # imageio does not always pass ffmpeg's failure on
        raise RuntimeError(f"ffmpeg wrote no video for {len(rgb)} frames of {w} x {h} at {fps:g} fps")


def _rgb(frames: np.ndarray) -> np.ndarray:
    """``(T, H, W, C)`` uint8 with ``C`` in 1, 3, 4 -> ``(T, H, W, 3)``."""
    if frames.shape[-1] == 1:
        return np.repeat(frames, 3, axis=-1)
    return np.ascontiguousarray(frames[..., :3])
