"""Animations: ``(T, C, H, W)`` frames, or an iterable of ``(C, H, W)`` frames, streamed to an animated GIF,
an MP4 or a folder of PNGs, or written as an animated WebP, or encoded to bytes.

Frames are float tensors ``(T, C, H, W)``: ``T`` frames, values in ``[0, 1]``, ``C`` in 1, 3, 4. RGBA frames
stay RGBA where the format can hold it: PNG frames keep their alpha exactly, a GIF makes the pixels with alpha
below 0.5 transparent, a WebP keeps its alpha (lossless alpha, lossy colour). Every output is written to a
temporary sibling and moved into place only on success.
"""

from __future__ import annotations

import io
import itertools
import os
import struct
import tempfile
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, BinaryIO, Literal

import imageio.v3 as iio
import numpy as np
from PIL import GifImagePlugin, Image, features
from torch import Tensor

from torchfluidwarp._checks import check_int, check_real, check_tensor, describe
from torchfluidwarp.errors import InputError, InputTypeError
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
    "MAX_WEBP_BYTES",
    "AnimationFormat",
]

AnimationFormat = Literal["gif", "mp4", "webp"]

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
MAX_WEBP_BYTES = 2**30
"""The most raw frame bytes (``T * H * W * 4``, 8-bit RGBA) an animated WebP may hold. Pillow's WebP writer takes
all frames at once, so unlike the other formats a WebP is not streamed: its frames are held in memory until the
last one, and a longer or larger animation is refused (write a GIF or PNG frames instead)."""
TRANSPARENT = 255
"""The GIF palette index of transparent pixels (the colours are quantized to the other 255)."""
QUANTIZE_AHEAD = 2
"""GIF frames quantized at once, each in a thread of its own, while the next one is made: Pillow lets go of
Python's lock while it quantizes, so its median cut (about half a second for a 3-megapixel frame) overlaps the
rendering of the frames after it instead of adding to it."""
QUANTIZE_BYTES = 2**26
"""The most bytes of 8-bit RGB (``3 H W`` a frame) a GIF writer holds in the frames it quantizes ahead (64 MiB;
Pillow's working copies come on top): frames larger than a :data:`QUANTIZE_AHEAD`-th of it are quantized in
turn, so that a streamed 6000 x 6000 morph still holds one frame at a time."""


def write_animation(
    path: PathLike, frames: Tensor | Iterable[Tensor], *, fps: float = 10.0, overwrite: bool = False, loop: int = 0
) -> Path:
    """Write frames as a GIF, an MP4 or a folder of PNGs, atomically, one frame at a time.

    The output kind follows the path:

    * ``*.gif``: an animated GIF (Pillow's encoder). Each frame is shown for ``1 / fps`` seconds, rounded to
      the GIF's 10 ms steps; every frame is kept, repeated ones included, each with its own palette.
      RGBA frames give a transparent GIF: pixels with alpha below 0.5 (127 of 255) are transparent, the others
      opaque (a GIF has no partial transparency); each frame replaces the one before (disposal 2). All its frames
      share one fixed, dithered palette (a colour cube), so that every frame decodes in the first frame's mode
      and ``imageio.v3.imread(path, index=None)`` reads the file back as one array.
    * ``*.mp4``: H.264 through imageio-ffmpeg (needs the ``[video]`` extra). Odd sizes are
      padded by one edge row/column, as yuv420p needs even sizes.
    * ``*.webp``: an animated WebP (Pillow, where built with WebP: ``PIL.features.check("webp")``), lossy colour
      at quality 90 and lossless alpha. Its frames are held in memory until the last (Pillow's writer takes
      them all at once), at most :data:`MAX_WEBP_BYTES` as 8-bit RGBA.
    * a path ending in ``/``, an existing directory or a path without suffix: a folder of
      ``frame_0000.png``, ``frame_0001.png``, ... (all channels kept, alpha included).

    Gray frames are repeated to RGB for GIF, MP4 and WebP; MP4, which has no alpha, shows frames with alpha
    composited over black.

    Frames are encoded as they come, so an iterable (e.g. ``result.iter_frames()`` of a morph) is written in
    the memory of one frame whatever its length (a GIF's: of up to :data:`QUANTIZE_AHEAD` more 8-bit frames,
    within :data:`QUANTIZE_BYTES`, whose colours are chosen in threads while the next frame is made). The output
    goes to a temporary sibling that is moved into place only once the last frame is written; an error on the way
    (a bad frame, a full disk) removes it.

    Args:
        path: the output file or folder. Missing parent folders are created.
        frames: ``(T, C, H, W)`` float tensor with values in ``[0, 1]``, ``C`` in 1, 3, 4; or an iterable of
            ``(C, H, W)`` frames of one size (at least one).
        fps: frames per second, from :data:`MIN_FPS` (0.01) to :data:`MAX_FPS` (1000).
        overwrite: replace an existing output (a bool). Without it an existing file, or a non-empty folder,
            raises ``FileExistsError``. A folder is only replaced if it holds nothing but frames.
        loop: GIF repeat count, 0 to :data:`MAX_LOOP`; 0 loops forever.

    Returns:
        The path written.

    Raises:
        InputTypeError, InputError: bad ``path``, ``frames``, ``fps``, ``loop`` or ``overwrite``, or an unknown
            suffix. They are checked before anything is written (a tensor's frames all, an iterable's first
            one; a later bad frame of an iterable raises as it comes, and leaves nothing behind).
        FileExistsError: the output exists and ``overwrite`` is false.
        RuntimeError: MP4 output without imageio-ffmpeg installed, or WebP output from a Pillow without WebP.
    """
    target = check_output_path("path", path, folder_ok=True)
    as_folder = os.fspath(path).endswith(("/", os.sep)) or target.is_dir() or not target.suffix
    kind = "frames" if as_folder else _animation_format(target.suffix)
    fps = check_fps(fps)
    _check_loop(loop)
    if not isinstance(overwrite, bool):
        raise InputTypeError(f"overwrite must be a bool, got {describe(overwrite)}", argument="overwrite")
    data = _uint8_stream(frames)
    if kind == "mp4":
        _require_ffmpeg()
    if kind == "webp":
        _require_webp()
    check_overwrite(target, overwrite)
    make_parents("path", target)
    with atomic_output(target, folder=kind == "frames") as tmp:
        if kind == "frames":
            _write_pngs(tmp, data)
        elif kind == "gif":
            with open(tmp, "wb") as fp:
                _write_gif(fp, data, fps, loop)
        elif kind == "webp":
            with open(tmp, "wb") as fp:
                _write_webp(fp, data, fps, loop)
        else:
            _write_mp4(tmp, data, fps)
    return target


def encode_animation(
    frames: Tensor | Iterable[Tensor], fmt: AnimationFormat = "gif", *, fps: float = 10.0, loop: int = 0
) -> bytes:
    """Encode frames as GIF, MP4 or WebP bytes, e.g. to send from a web server without touching disk.

    Args:
        frames: ``(T, C, H, W)`` float tensor with values in ``[0, 1]``, ``C`` in 1, 3, 4, or an iterable of
            ``(C, H, W)`` frames (encoded as they come).
        fmt: ``"gif"``, ``"mp4"`` (needs imageio-ffmpeg and passes through a temporary file) or ``"webp"``
            (frames held in memory, see :func:`write_animation`).
        fps: frames per second, from :data:`MIN_FPS` (0.01) to :data:`MAX_FPS` (1000).
        loop: GIF repeat count, 0 to :data:`MAX_LOOP`; 0 loops forever.

    Returns:
        The encoded file contents, as :func:`write_animation` would write them.

    Raises:
        InputTypeError, InputError: bad ``frames``, ``fmt``, ``fps`` or ``loop``.
        RuntimeError: ``fmt="mp4"`` without imageio-ffmpeg installed, ``fmt="webp"`` without Pillow's WebP.

    Example:
        >>> import torch
        >>> encode_animation(torch.rand(3, 3, 8, 8), "gif")[:6]
        b'GIF89a'
    """
    if fmt not in ("gif", "mp4", "webp"):
        raise InputError(f"fmt must be 'gif', 'mp4' or 'webp', got {fmt!r}", argument="fmt")
    fps = check_fps(fps)
    _check_loop(loop)
    data = _uint8_stream(frames)
    if fmt in ("gif", "webp"):
        if fmt == "webp":
            _require_webp()
        buffer = io.BytesIO()
        (_write_gif if fmt == "gif" else _write_webp)(buffer, data, fps, loop)
        return buffer.getvalue()
    _require_ffmpeg()
    with tempfile.TemporaryDirectory() as folder:
        file = Path(folder) / "animation.mp4"
        _write_mp4(file, data, fps)
        return file.read_bytes()


def check_fps(fps: object) -> float:
    """Validate a frame rate for :func:`write_animation` and :func:`encode_animation` and return it as a float.

    Raises:
        InputTypeError: ``fps`` is not a real number.
        InputError: ``fps`` is not finite, or outside :data:`MIN_FPS` to :data:`MAX_FPS`.

    Example:
        >>> check_fps(25)
        25.0
    """
    value = check_real("fps", fps)
    if not MIN_FPS <= value <= MAX_FPS:
        raise InputError(f"fps must be from {MIN_FPS} to {MAX_FPS:g} frames per second, got {fps!r}", argument="fps")
    return value


def _check_loop(loop: object) -> None:
    if check_int("loop", loop, minimum=0) > MAX_LOOP:
        raise InputError(
            f"loop must be at most {MAX_LOOP} (a GIF's 16-bit repeat count; 0 loops forever), got {loop}",
            argument="loop",
        )


def _animation_format(suffix: str) -> str:
    kind = suffix.lower().lstrip(".")
    if kind not in ("gif", "mp4", "webp"):
        raise InputError(
            f"unknown animation suffix {suffix!r}: use .gif, .mp4, .webp, or a folder (a path ending in '/' or "
            "without suffix)",
            argument="path",
        )
    return kind


def _require_ffmpeg() -> None:
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        raise RuntimeError(FFMPEG_HINT) from None


def _require_webp() -> None:
    if not features.check("webp"):
        raise RuntimeError("WebP output needs a Pillow built with WebP support (PIL.features.check('webp') is False)")


def _uint8_stream(frames: Tensor | Iterable[Tensor]) -> Iterator[np.ndarray]:
    """Frames as ``(H, W, C)`` uint8 arrays of one size, one at a time; the first is checked before this returns.

    A tensor ``(T, C, H, W)`` is validated (and converted) whole; an iterable's ``(C, H, W)`` frames are
    validated one by one as ``frames[k]``, and each float frame is let go once converted, before the next one is
    asked for (a streamed morph renders it then: a 6000 x 6000 RGB frame is 432 MB as float32).
    """
    if isinstance(frames, Tensor):
        data = _uint8_frames(frames, "frames")
        return iter(data)
    if isinstance(frames, (str, bytes)) or not isinstance(frames, Iterable):
        raise InputTypeError(
            f"frames must be a (T, C, H, W) tensor or an iterable of (C, H, W) tensors, got {describe(frames)}",
            argument="frames",
        )
    source = iter(frames)
    first = next(source, None)
    if first is None:
        raise InputError("frames is empty: an animation needs at least one frame", argument="frames")
    head = _uint8_frame(first, 0, None)
    del first
    return itertools.chain([head], _uint8_rest(source, head.shape))


def _uint8_rest(source: Iterator[object], shape: tuple[int, ...]) -> Iterator[np.ndarray]:
    """``frames[1:]`` of :func:`_uint8_stream`, converted one at a time; no frame is held while the next one is
    made (a generator expression would keep its loop variable, the previous float frame, until then, and
    ``enumerate`` keeps its last item)."""
    k = 1
    for frame in source:
        out = _uint8_frame(frame, k, shape)
        del frame
        yield out
        del out
        k += 1


def _uint8_frame(frame: object, k: int, shape: tuple[int, ...] | None) -> np.ndarray:
    if not isinstance(frame, Tensor):
        raise InputTypeError(f"frames[{k}] must be a (C, H, W) tensor, got {describe(frame)}", argument="frames")
    check_tensor(f"frames[{k}]", frame, ndim=3)
    out = _uint8_frames(frame[None], f"frames[{k}]")[0]
    if shape is not None and out.shape != shape:
        raise InputError(
            f"frames[{k}] has shape {tuple(frame.shape)}, but frames[0] is {(shape[2], shape[0], shape[1])}; "
            "all frames of an animation have one size",
            argument="frames",
        )
    return out


def _write_pngs(folder: Path, frames: Iterator[np.ndarray]) -> None:
    """``frame_0000.png``, ... into ``folder``; past 10000 frames the names are widened at the end so they sort."""
    count = 0
    for frame in frames:
        iio.imwrite(folder / f"frame_{count:04d}.png", frame[..., 0] if frame.shape[-1] == 1 else frame)
        count += 1
        del frame  # not held while the next frame is made
    digits = len(str(count - 1))
    if digits > 4:
        for t in range(count):
            os.replace(folder / f"frame_{t:04d}.png", folder / f"frame_{t:0{digits}d}.png")


def _cube_palette() -> Image.Image:
    """The fixed palette of transparent GIFs: a 6 x 7 x 6 colour cube (252 colours, green finest: the eye's most
    sensitive channel) and 3 more greys, 255 colours in all; index :data:`TRANSPARENT` is left for transparency."""
    levels = {n: [round(255 * i / (n - 1)) for i in range(n)] for n in (6, 7)}
    colours = [(r, g, b) for r in levels[6] for g in levels[7] for b in levels[6]]
    colours += [(64, 64, 64), (128, 128, 128), (192, 192, 192), (0, 0, 0)]  # the last: the transparent index
    palette = Image.new("P", (1, 1))
    palette.putpalette([v for c in colours for v in c])
    return palette


def _write_gif(fp: BinaryIO, frames: Iterator[np.ndarray], fps: float, loop: int) -> None:
    """Encode ``(H, W, C)`` uint8 frames as an animated GIF into a binary file object, one frame at a time.

    Every frame of a file has one mode, that of the first frame: opaque colour, or colour with transparency.

    * Opaque frames (grey or RGB) are quantized each on its own (median cut, 256 colours, no dithering) and
      written whole with their own colour table, so no frame is merged with the one before it (Pillow's
      multi-frame writer keeps every frame until the end, and drops repeated ones).
    * RGBA frames all use one global palette, :func:`_cube_palette` (dithered), with index :data:`TRANSPARENT`
      where ``alpha < 128`` in every frame, and each replaces the one before (disposal 2). A streamed file cannot
      choose one palette for frames it has not seen, and a frame with its own colour table is decoded by Pillow
      (hence imageio) in another mode than the first frame of a transparent GIF, so that
      ``imageio.v3.imread(path, index=None)`` could not stack the frames.

    Up to :data:`QUANTIZE_AHEAD` frames are quantized in threads while the next one is made (within
    :data:`QUANTIZE_BYTES`), and written in order: at most that many frames and the one being made are held.
    """
    delay_ms = max(10, 10 * round(100.0 / fps))  # GIF delays count hundredths of a second
    first = next(frames, None)
    if first is None:
        return
    h, w = first.shape[:2]
    cube: Image.Image | None = None
    if first.shape[-1] == 4:
        cube = _cube_palette()
        table = bytes(cube.getpalette() or [])[:768].ljust(768, b"\0")
        fp.write(b"GIF89a" + struct.pack("<HHBBB", w, h, 0xF7, 0, 0) + table)  # a 256-colour global table
        extra: dict[str, Any] = {"include_color_table": False, "transparency": TRANSPARENT, "disposal": 2}
    else:
        fp.write(b"GIF89a" + struct.pack("<HHBBB", w, h, 0, 0, 0))  # no global colour table
        extra = {"include_color_table": True}
    fp.write(b"!\xff\x0bNETSCAPE2.0\x03\x01" + struct.pack("<H", loop) + b"\x00")
    ahead = QUANTIZE_AHEAD if QUANTIZE_AHEAD * 3 * h * w <= QUANTIZE_BYTES else 0
    stream = itertools.chain([first], frames)
    del first  # held by the stream until it is quantized, not while the frames after it are made
    for quantized in _quantized(stream, cube, ahead):
        fp.writelines(GifImagePlugin.getdata(quantized, duration=delay_ms, **extra))
        del quantized  # not held while the next frame is made
    fp.write(b";")


def _quantize(frame: np.ndarray, cube: Image.Image | None) -> Image.Image:
    """One GIF frame's palette image: :func:`_transparent` in ``cube``'s colours, or its own 256 (median cut)."""
    rgb = _rgb(frame)
    if cube is not None:
        return _transparent(rgb, frame[..., 3], cube)
    return Image.fromarray(rgb).quantize(colors=256)


def _quantized(frames: Iterator[np.ndarray], cube: Image.Image | None, ahead: int) -> Iterator[Image.Image]:
    """:func:`_quantize` of each frame, in order, up to ``ahead`` of them at once in threads (0: in turn)."""
    if ahead < 1:
        for frame in frames:  # not enumerate(frames): it would keep the last frame while the next one is made
            out = _quantize(frame, cube)
            del frame
            yield out
            del out
        return
    with ThreadPoolExecutor(max_workers=ahead, thread_name_prefix="gif") as pool:
        pending: deque[Future[Image.Image]] = deque()
        try:
            for frame in frames:
                pending.append(pool.submit(_quantize, frame, cube))
                del frame
                if len(pending) >= ahead:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:  # a frame that failed to be made, or a writer that stopped: the pool waits for those running
            for future in pending:
                future.cancel()  # a frame not yet started (none while the pool has a worker per frame ahead)


def _transparent(rgb: np.ndarray, alpha: np.ndarray, palette: Image.Image) -> Image.Image:
    """A palette image of ``rgb`` in ``palette``'s colours (dithered), with index :data:`TRANSPARENT` where
    ``alpha < 128``."""
    quantized = Image.fromarray(rgb).quantize(palette=palette, dither=Image.Dither.FLOYDSTEINBERG)
    indices = np.asarray(quantized).copy()
    indices[alpha < 128] = TRANSPARENT
    out = Image.fromarray(indices, "P")
    out.putpalette(palette.getpalette() or [])
    return out


def _write_webp(fp: BinaryIO, frames: Iterator[np.ndarray], fps: float, loop: int) -> None:
    """Encode ``(H, W, C)`` uint8 frames as an animated WebP, holding them until the last (at most
    :data:`MAX_WEBP_BYTES` as RGBA)."""
    images: list[Image.Image] = []
    held = 0
    for frame in frames:
        held += frame.shape[0] * frame.shape[1] * 4
        if held > MAX_WEBP_BYTES:
            raise InputError(
                f"an animated WebP holds its frames in memory, and these pass {MAX_WEBP_BYTES / 2**30:g} GiB "
                f"(MAX_WEBP_BYTES) at frame {len(images)}; write a .gif or a folder of PNG frames instead",
                argument="frames",
            )
        rgb = _rgb(frame)
        images.append(Image.fromarray(np.dstack([rgb, frame[..., 3]]) if frame.shape[-1] == 4 else rgb))
    duration = max(1, round(1000.0 / fps))
    images[0].save(fp, format="WEBP", save_all=True, append_images=images[1:], duration=duration, loop=loop, quality=90)


def _write_mp4(file: Path, frames: Iterator[np.ndarray], fps: float) -> None:
    """Encode ``(H, W, C)`` uint8 frames as H.264 (yuv420p) into ``file``, one frame at a time."""
    import imageio_ffmpeg

    writer = None
    count, w, h = 0, 0, 0
    try:
        for frame in frames:
            rgb = _rgb(_over_black(frame))
            h, w = rgb.shape[:2]
            rgb = np.pad(rgb, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")  # yuv420p needs even sizes
            if writer is None:
                # macro_block_size=1: the size is already even, so ffmpeg must not rescale the frames.
                writer = imageio_ffmpeg.write_frames(
                    str(file), (rgb.shape[1], rgb.shape[0]), fps=fps, codec="libx264", macro_block_size=1, quality=5
                )
                writer.send(None)
            writer.send(np.ascontiguousarray(rgb))
            count += 1
            del frame, rgb  # not held while the next frame is made
    finally:
        if writer is not None:
            writer.close()
    if not file.is_file() or file.stat().st_size == 0:  # ffmpeg does not always pass its failure on
        raise RuntimeError(f"ffmpeg wrote no video for {count} frames of {w} x {h} at {fps:g} fps")


def _over_black(frame: np.ndarray) -> np.ndarray:
    """``(H, W, C)`` uint8 with alpha (``C`` 2 or 4) composited over black, for a format without alpha (MP4):
    a transparent pixel shows black whatever colour it stores (a morph's frames store none under alpha 0, its
    first and last frames the pictures' own); other frames as they are."""
    if frame.shape[-1] not in (2, 4):
        return frame
    alpha = frame[..., -1:].astype(np.uint16)
    return ((frame[..., :-1].astype(np.uint16) * alpha + 127) // 255).astype(np.uint8)


def _rgb(frame: np.ndarray) -> np.ndarray:
    """``(H, W, C)`` uint8 with ``C`` in 1, 3, 4 -> ``(H, W, 3)``."""
    if frame.shape[-1] == 1:
        return np.repeat(frame, 3, axis=-1)
    return np.ascontiguousarray(frame[..., :3])
