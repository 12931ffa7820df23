"""Decoding image files into arrays: the first frame, upright, as it shows (colour profiles, TIFF kinds, HEIF).

:func:`decode` is :func:`~torchfluidwarp.io.images.read_image`'s reader: imageio chooses the plugin by the file,
tifffile's samples are taken where they are the picture and Pillow's conversions elsewhere, and a HEIF photograph
(an iPhone's default) is read by the optional pillow-heif.
"""

from __future__ import annotations

import importlib.util
import io
import re
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
from imageio.plugins.pillow import PillowPlugin
from PIL import Image

from torchfluidwarp._checks import warn
from torchfluidwarp.errors import Hint, InputError
from torchfluidwarp.io._colour import in_srgb, lab_in_srgb, nclx_in_srgb
from torchfluidwarp.io._files import DECODE_ERRORS, first_line

_BOMB_PIXELS = re.compile(r"\((\d+) pixels\)")


def decode(uri: Path | bytes, source: str, max_pixels: int) -> np.ndarray:
    """The first frame of an encoded image, ``(H, W)`` or ``(H, W, C)``; its header is checked first, and a file of
    more frames (an animated GIF, WebP or PNG, a multi-page TIFF) warns that the others were left out."""
    argument = "data" if isinstance(uri, bytes) else "path"
    heif = _is_heif(uri, source)
    try:
        if heif:
            array, frames, shape = _heif_frame(uri, source, max_pixels)
        else:
            with iio.imopen(uri, "r") as file:
                shape = _header_size(file)
                too_large = shape[0] * shape[1] > max_pixels
                array, frames = (None, 0) if too_large else _first_frame(file, uri, source)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:  # the warning, when made an error
        match = _BOMB_PIXELS.search(str(exc))
        claimed = f"{int(match.group(1)):,} pixels" if match else "more pixels than Pillow accepts"
        raise InputError(
            f"cannot read {source}: its header claims {claimed}, more than Pillow decodes "
            f"(a possible decompression bomb; the limit here is max_pixels={max_pixels:,})",
            argument=argument,
        ) from None
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001  (decoders raise ZeroDivisionError, IndexError ... on corrupt files)
        raise _unreadable(source, argument, exc) from exc
    if array is None:
        raise InputError(
            f"cannot read {source}: its header claims {shape[1]} x {shape[0]} = {shape[0] * shape[1]:,} pixels, "
            f"more than max_pixels={max_pixels:,}",
            argument=argument,
            hint=Hint("pass a larger {setting} to read it", "max_pixels"),  # a caller without one says nothing
        )
    _check_pixels(array.shape, source, argument)
    if frames > 1:  # an animation or a multi-page file: say what was left out
        warn(
            f"{source} holds {frames} frames (an animation or a multi-page file): only its first was read; to use "
            f"another, save that frame as a picture of its own"
        )
    return array


def _unreadable(source: str, argument: str, exc: BaseException) -> InputError:
    """The error for a file that a decoder failed on, naming the file and the decoder's reason (imageio's "no
    plugin" in words: it quotes the file's name with unbalanced backticks)."""
    reason = first_line(exc)
    if reason.startswith("Could not find a backend to open"):
        reason = "no image format recognises its contents"
    return InputError(f"cannot read {source}: not a readable image ({reason})", argument=argument)


def _check_pixels(shape: tuple[int, ...], source: str, argument: str) -> None:
    """Refuse a picture of ``shape`` with no pixels (a header that says 0 pixels wide or high)."""
    if 0 in shape:
        raise InputError(f"cannot read {source}: it holds no pixels (shape {tuple(shape)})", argument=argument)


def _by_tifffile(file: object) -> bool:
    """Whether imageio opened the file with its tifffile plugin (tifffile is optional: without it, imageio reads
    TIFFs with Pillow, and importing the plugin would fail)."""
    return type(file).__module__ == "imageio.plugins.tifffile_v3"


def _by_pillow(uri: Path | bytes, source: str) -> np.ndarray:
    """The first frame of an image file, read by imageio's Pillow plugin (:func:`_pillow_frame`)."""
    with iio.imopen(uri, "r", plugin="pillow") as pillow:
        return _pillow_frame(pillow, pillow.metadata(index=0), source)


def _pillow_frame(file: Any, meta: dict[str, Any], source: str) -> np.ndarray:
    """The first frame of a file open in imageio's Pillow plugin (its first frame's metadata ``meta``), in the mode
    :func:`_pillow_options` says, upright as its EXIF orientation says (:func:`_upright`), its colours in sRGB
    (:func:`~torchfluidwarp.io._colour.in_srgb`; CMYK inks through their profile where they have one). The
    orientation is read once the pixels are: Pillow turns a TIFF upright as it decodes it, and drops the tag."""
    icc = meta.get("icc_profile")
    inks = meta.get("mode") == "CMYK" and bool(icc)  # converted through its profile, not Pillow's plain formula
    array = file.read(index=0, rotate=False, **({} if inks else _pillow_options(meta)))
    array = _upright(array, file.metadata(index=0, exclude_applied=False).get("Orientation", 1))
    if meta.get("mode") == "LAB":  # a CIELab TIFF: its samples are L*, a*, b*, not red, green, blue
        return lab_in_srgb(array, source)
    return in_srgb(array, icc, source, "CMYK" if inks else "RGB") if icc else array


_UPRIGHT = {  # EXIF orientation -> the turn that shows the stored pixels ``(H, W, ...)`` upright
    2: lambda a: np.flip(a, 1),
    3: lambda a: np.rot90(a, 2),
    4: lambda a: np.flip(a, 0),
    5: lambda a: np.flip(np.rot90(a, 3), 1),
    6: lambda a: np.rot90(a, 3),
    7: lambda a: np.flip(np.rot90(a, 1), 1),
    8: lambda a: np.rot90(a, 1),
}


def _upright(array: np.ndarray, orientation: object) -> np.ndarray:
    """Pixels ``(H, W)`` or ``(H, W, C)`` stored with the EXIF ``orientation`` (1-8; anything else: as stored) as a
    viewer shows them: a phone's portrait is stored sideways with a tag that every viewer follows. (imageio's own
    ``rotate=True`` mirrors a palette picture's colour channels instead of its columns: it picks the axes by the
    stored mode's one band, after converting the pixels to RGB.)"""
    turn = _UPRIGHT.get(orientation) if isinstance(orientation, int) else None
    return array if turn is None else np.ascontiguousarray(turn(array))


def _header_size(file: Any) -> tuple[int, int]:
    """``(H, W)`` of an open imageio file's first frame, from its header (no pixels decoded). A TIFF says it in its
    tags: its page's shape puts the colour planes first where they are stored one after another."""
    if _by_tifffile(file):
        meta = file.metadata(index=0, page=0)
        if "ImageLength" in meta and "ImageWidth" in meta:
            return int(meta["ImageLength"]), int(meta["ImageWidth"])
    shape = file.properties(index=0).shape
    return (shape[0], shape[1]) if len(shape) >= 2 else (1, 1)


def _first_frame(file: Any, uri: Path | bytes, source: str) -> tuple[np.ndarray, int]:
    """The first frame (or page) of an open imageio ``file`` (opened from ``uri``), and how many the file holds.

    A TIFF is read by tifffile (16-bit and float colour kept), its first page alone (its first series is all its
    pages stacked). tifffile gives the stored samples as they are, so a TIFF whose samples are not plain grey or
    RGB pixels (a palette's indices, grey stored inverted, CMYK, colour planes stored one after another) is read by
    Pillow instead, which turns them into the picture they show (8 bits a channel); so is one whose compression
    tifffile cannot decode without the optional imagecodecs package (LZW, JPEG: common in scanners' and
    Photoshop's TIFFs). (imageio's annotations say
    ``index: int``; its plugins document ``...`` as "all of them", which is what is asked for here.)
    """
    reader: Any = file  # not narrowed by the checks below, for the reason above
    if _by_tifffile(file):
        pages = _tiff_pages(reader)
        meta = reader.metadata(index=0, page=0)
        if _plain_tiff(meta):
            try:
                array = reader.read(index=0, page=0)
                if int(meta.get("PhotometricInterpretation", 1)) == 0:  # stored inverted: 0 is white
                    array = np.iinfo(array.dtype).max - array
                icc = meta.get("InterColorProfile")
                return (in_srgb(array, icc, source) if isinstance(icc, bytes) else array), pages
            except DECODE_ERRORS as exc:  # LZW, JPEG ... need the optional imagecodecs: Pillow decodes those
                try:
                    return _by_pillow(uri, source), pages
                except DECODE_ERRORS:
                    raise exc from None
        return _by_pillow(uri, source), pages
    if isinstance(file, PillowPlugin):
        meta = reader.metadata(index=0)
        return _pillow_frame(file, meta, source), _pillow_frames(reader, meta)
    return reader.read(index=0), 1


def _plain_tiff(meta: dict[str, Any]) -> bool:
    """Whether tifffile's samples of a TIFF page (its tags ``meta``) are the picture as a viewer shows it: grey or
    RGB (or integer grey stored inverted, which :func:`_first_frame` inverts), its samples interleaved, stored
    upright. Any other page is read by Pillow, which converts palettes and CMYK, and turns the picture upright."""
    photometric = int(meta.get("PhotometricInterpretation", 1))
    samples = int(meta.get("SamplesPerPixel", 1))
    inverted_ints = photometric == 0 and samples == 1 and int(meta.get("SampleFormat", 1)) in (1, 2)
    return (
        (photometric in _PLAIN_TIFF or inverted_ints)
        and (samples == 1 or int(meta.get("PlanarConfiguration", 1)) == 1)
        and int(meta.get("Orientation", 1)) == 1
    )


def _tiff_pages(reader: Any) -> int:
    """How many full pictures a TIFF holds: its pages, less reduced-resolution ones (thumbnails, pyramid levels:
    bit 0 of their NewSubfileType)."""
    pages = reader.properties(index=..., page=...).n_images or 1
    if pages == 1:
        return 1
    return sum(not int(reader.metadata(index=..., page=i).get("NewSubfileType", 0)) & 1 for i in range(pages))


def _pillow_frames(reader: Any, meta: dict[str, Any]) -> int:
    """How many frames a file open in imageio's Pillow plugin holds (its first frame's metadata ``meta``). A
    camera's JPEG often carries a preview or an HDR gain map as a second, smaller picture (Pillow opens it as an
    MPO): only pictures of the first one's size count."""
    frames = reader.properties(index=...).n_images or 1
    if frames == 1 or "mp" not in meta:
        return frames
    size = reader.properties(index=0).shape[:2]
    return sum(reader.properties(index=i).shape[:2] == size for i in range(frames))


_PLAIN_TIFF = (1, 2)
"""TIFF photometric interpretations whose samples tifffile gives as the picture: grey (black is zero) and RGB."""


def _pillow_options(meta: dict[str, Any]) -> dict[str, str]:
    """The mode in which Pillow reads a file (its first frame's metadata ``meta`` in imageio's Pillow plugin) where
    its raw values would be misread: CMYK (4 channels, not RGBA) as RGB, and a palette image with a transparent
    colour as RGBA (imageio would drop its alpha)."""
    mode = meta.get("mode")
    if mode == "CMYK":
        return {"mode": "RGB"}
    if mode == "PA" or (mode == "P" and "transparency" in meta):
        return {"mode": "RGBA"}
    return {}


HEIF_BRANDS = frozenset({b"heic", b"heix", b"heim", b"heis", b"hevc", b"hevx", b"mif1", b"msf1"})
"""The ``ftyp`` brands of HEIF files that Pillow does not read (HEVC-coded: an iPhone's photographs; AVIF, which
Pillow reads, is left to it)."""

HEIF_SUFFIXES = (".heic", ".heif", ".hif")

HEIF_NEEDED = (
    "a HEIC/HEIF photograph (an iPhone's default format) needs the pillow-heif package: pip install "
    "'torchfluidwarp[heic]' (or pillow-heif), or export it as JPEG"
)
"""What a HEIC file without pillow-heif is refused with."""


def _is_heif(uri: Path | bytes, source: str) -> bool:
    """Whether ``uri`` (a path or encoded bytes) is a HEIF file (:func:`_heif_brand`); one is refused, naming
    ``source``, where pillow-heif is not installed."""
    heif = _heif_brand(uri)
    if heif and importlib.util.find_spec("pillow_heif") is None:
        raise InputError(f"cannot read {source}: {HEIF_NEEDED}", argument="data" if isinstance(uri, bytes) else "path")
    return heif


def _heif_brand(uri: Path | bytes) -> bool:
    """Whether ``uri`` (a path or encoded bytes) is a HEIF file: by its suffix, or by its ``ftyp`` brand."""
    if isinstance(uri, Path):
        return uri.suffix.lower() in HEIF_SUFFIXES
    if uri[4:8] != b"ftyp":
        return False
    end = min(int.from_bytes(uri[:4], "big"), len(uri))
    brands = {uri[i : i + 4] for i in range(16, end - 3, 4)} | {uri[8:12]}
    return uri[8:12] in HEIF_BRANDS and not brands & {b"avif", b"avis"}  # AVIF (mif1 too) is Pillow's


def _heif_frame(uri: Path | bytes, source: str, max_pixels: int) -> tuple[np.ndarray | None, int, tuple[int, int]]:
    """A HEIF file's primary picture read by pillow-heif (upright: libheif applies the file's rotation and mirror),
    its colours in sRGB (by its ICC profile or its ``nclx`` box: :mod:`~torchfluidwarp.io._colour`), 10- and
    12-bit pictures at 8 bits; how many pictures it holds; and its ``(H, W)``. ``None`` instead of the pixels
    where ``(H, W)`` passes ``max_pixels`` (nothing decoded)."""
    heif = _open_heif(uri)
    width, height = heif.size
    if width * height > max_pixels:
        return None, len(heif), (height, width)
    picture = heif.to_pillow()
    array = np.asarray(
        picture.convert("RGBA" if "A" in picture.mode else "RGB") if picture.mode not in _HEIF_MODES else picture
    )
    icc, nclx = picture.info.get("icc_profile"), picture.info.get("nclx_profile")
    if icc:
        array = in_srgb(array, icc, source)
    elif nclx:  # an Android phone's or a browser's tag instead of a profile
        array = nclx_in_srgb(array, nclx, source)
    return array, len(heif), (height, width)


def _open_heif(uri: Path | bytes) -> Any:
    """``uri`` opened by pillow-heif (the optional extra "heic", checked by :func:`_is_heif`); nothing decoded."""
    import pillow_heif

    return pillow_heif.open_heif(uri if isinstance(uri, Path) else io.BytesIO(uri))


_HEIF_MODES = ("L", "RGB", "RGBA", "I;16", "I;16L")
"""pillow-heif's picture modes that convert to arrays as they are; others (BGR, LA) are converted to RGB(A)."""


def header_shape(uri: Path | bytes, source: str) -> tuple[int, int, int]:
    """``(C, H, W)`` of the picture :func:`decode` gives (before any ``channels`` conversion), from the file's
    header alone: no pixels decoded. Upright (EXIF orientation), palette, CMYK and grey + alpha counted as
    :func:`decode` converts them.

    Raises:
        InputError: a file that cannot be read, holds no pixels, or is a HEIC without pillow-heif (``source`` names
            it in the message).
    """
    argument = "data" if isinstance(uri, bytes) else "path"
    heif = _is_heif(uri, source)
    try:
        channels, height, width = _heif_shape(uri) if heif else _imageio_shape(uri)
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001  (decoders raise ZeroDivisionError, IndexError ... on corrupt files)
        raise _unreadable(source, argument, exc) from exc
    _check_pixels((channels, height, width), source, argument)
    return channels, height, width


def _heif_shape(uri: Path | bytes) -> tuple[int, int, int]:
    """:func:`header_shape` of a HEIF file."""
    heif = _open_heif(uri)
    (width, height), mode = heif.size, heif.mode
    return (4 if "A" in mode else 1 if mode in ("L", "I;16", "I;16L") else 3), height, width


def _imageio_shape(uri: Path | bytes) -> tuple[int, int, int]:
    """:func:`header_shape` of a file that imageio opens."""
    with iio.imopen(uri, "r") as file:
        height, width = _header_size(file)
        reader: Any = file
        if _by_tifffile(file):  # min-is-white: grey; a palette, CMYK: RGB (Pillow converts them); else samples
            meta = reader.metadata(index=0, page=0)
            photometric = int(meta.get("PhotometricInterpretation", 1))
            channels = {0: 1, 3: 3, 5: 3}.get(photometric, int(meta.get("SamplesPerPixel", 1)))
            turned = int(meta.get("Orientation", 1)) in (5, 6, 7, 8)  # Pillow reads it upright (_plain_tiff)
        else:
            shape = reader.properties(index=0).shape
            channels = shape[2] if len(shape) == 3 else 1
            turned = False
            if isinstance(file, PillowPlugin):
                meta = reader.metadata(index=0, exclude_applied=False)
                channels = {"RGB": 3, "RGBA": 4}.get(str(_pillow_options(meta).get("mode")), channels)
                turned = meta.get("Orientation") in (5, 6, 7, 8)
    if turned:  # stored turned a quarter: read upright
        height, width = width, height
    return (4 if channels == 2 else channels), height, width
