"""Image files to and from ``(B, C, H, W)`` tensors, and the one antialiased resize.

Images are float tensors ``(B, C, H, W)`` with values in ``[0, 1]`` and ``C`` = 1 (gray), 3 (RGB) or
4 (RGBA). ``uint8`` appears only at the file boundary: writers clamp to ``[0, 1]`` and round to 8 bits.
"""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch
import torch.nn.functional as F
from imageio.config import known_extensions
from PIL import Image
from torch import Tensor

from torchfluidwarp._checks import (
    argument_of,
    check_int,
    check_memory,
    check_picture,
    check_size,
    check_tensor,
    compute_dtype,
    describe,
)
from torchfluidwarp.errors import InputError, InputTypeError
from torchfluidwarp.io._decode import decode, header_shape
from torchfluidwarp.io._files import (
    DECODE_ERRORS,
    PathLike,
    atomic_output,
    check_float_dtype,
    check_output_path,
    check_path,
    first_line,
    make_parents,
)

__all__ = [
    "read_image",
    "read_image_bytes",
    "write_image",
    "resize_image",
    "shrink_image",
    "shrunk_size",
    "premultiplied",
    "straight",
    "MAX_IMAGE_PIXELS",
]

# ITU-R BT.601 luma weights, the ones Pillow uses for RGB -> L.
_LUMA = (0.299, 0.587, 0.114)


MAX_IMAGE_PIXELS = 2**26
"""The most pixels (``H * W``) that :func:`read_image` and :func:`read_image_bytes` decode unless told otherwise
(``max_pixels``): 67,108,864, e.g. 8192 x 8192, or a 61-megapixel camera's 9504 x 6336. Such an image takes
about 1 GiB as a float32 RGBA tensor, and a quarter more while it is converted (its 8-bit pixels). A file whose
header claims more is refused before its pixels are decoded, so a few bytes that claim gigapixels (a
"decompression bomb") cost nothing. Pillow also refuses, whatever ``max_pixels`` says, more than twice
``PIL.Image.MAX_IMAGE_PIXELS`` (about 358 million), and warns above ``PIL.Image.MAX_IMAGE_PIXELS``."""


def read_image(
    path: PathLike,
    *,
    channels: int | None = None,
    dtype: torch.dtype = torch.float32,
    max_pixels: int = MAX_IMAGE_PIXELS,
) -> Tensor:
    """Read an image file into a ``(1, C, H, W)`` tensor with values in ``[0, 1]``.

    8- and 16-bit images are scaled by their integer range; float images are clipped to ``[0, 1]``.
    A multi-frame file (an animated GIF, WebP or PNG, a multi-page TIFF) gives its first frame, with a warning.
    A TIFF keeps its 16-bit or float grey and colour; one stored as a palette, inverted grey, CMYK or separate
    colour planes is converted to the picture it shows (8 bits a channel). An 8-bit colour picture with an
    embedded colour profile other than sRGB (a phone's Display P3, a camera's Adobe RGB) is converted to sRGB, as
    colour-managed viewers show it, so that it mixes with other pictures in one colour space. CMYK images are
    converted to RGB, and palette images with a transparent colour to RGBA. A photograph whose EXIF orientation
    says it is stored turned (a phone's portrait) is turned upright, as viewers show it: ``H`` and ``W`` are those
    of the upright picture. A HEIC/HEIF photograph (an iPhone's default) is read with the optional pillow-heif
    package (``pip install 'torchfluidwarp[heic]'``), at 8 bits a channel.

    Args:
        path: the image file; any format imageio reads (PNG, JPEG, GIF, TIFF, WebP, ...), or HEIC.
        channels: ``None`` keeps the file's channels (gray gives 1, RGB 3, RGBA 4, gray+alpha 4);
            1 converts to gray (BT.601 luma, alpha dropped), 3 to RGB (gray repeated, alpha dropped),
            4 to RGBA (opaque alpha added where missing).
        dtype: a floating-point dtype for the result.
        max_pixels: the most pixels ``H * W`` to decode (:data:`MAX_IMAGE_PIXELS` by default); a file whose
            header claims more is refused before decoding.

    Returns:
        ``(1, C, H, W)`` tensor on the CPU.

    Raises:
        InputError: the file does not exist or is not a readable image, its header claims more than
            ``max_pixels`` pixels, or ``channels`` is not ``None``, 1, 3 or 4.
        InputTypeError: ``path`` is not a path, ``dtype`` is not floating point, or ``max_pixels`` not an int.

    Example:
        >>> import tempfile, torch
        >>> path = tempfile.mkdtemp() + "/gray.png"
        >>> _ = write_image(path, torch.full((1, 4, 6), 0.5))
        >>> read_image(path, channels=3).shape
        torch.Size([1, 3, 4, 6])
    """
    path, source = _image_file(path)
    _check_image_options(channels, dtype, max_pixels)
    return _tensor_from_array(decode(path, source, max_pixels), source, channels, dtype)


def read_image_bytes(
    data: bytes,
    *,
    channels: int | None = None,
    dtype: torch.dtype = torch.float32,
    max_pixels: int = MAX_IMAGE_PIXELS,
    name: str | None = None,
) -> Tensor:
    """Decode an encoded image (the bytes of a PNG, JPEG, ... file, e.g. an upload).

    Args:
        data: the encoded file contents.
        channels: as in :func:`read_image`.
        dtype: as in :func:`read_image`.
        max_pixels: as in :func:`read_image`.
        name: what errors and warnings call the data (an upload's file name, as ``image 'name'``); by default
            ``image bytes (N bytes)``.

    Returns:
        ``(1, C, H, W)`` tensor with values in ``[0, 1]``.

    Raises:
        InputTypeError: ``data`` is not bytes-like, ``dtype`` is not floating point, or ``max_pixels`` not an int.
        InputError: ``data`` is not a readable image, claims more than ``max_pixels`` pixels, or ``channels``
            is invalid.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise InputTypeError(f"data must be bytes, got {describe(data)}", argument="data")
    _check_image_options(channels, dtype, max_pixels)
    if name is not None and not isinstance(name, str):
        raise InputTypeError(f"name must be a str or None, got {describe(name)}", argument="name")
    source = f"image bytes ({len(data)} bytes)" if name is None else f"image {name!r}"
    return _tensor_from_array(decode(bytes(data), source, max_pixels), source, channels, dtype, "data")


def write_image(path: PathLike, image: Tensor) -> Path:
    """Write an image tensor to a file, atomically, as 8 bits per channel.

    Values are clamped to ``[0, 1]`` and rounded to ``uint8``; the format follows the suffix
    (``.png`` is lossless). The image is encoded in memory first, so a format that cannot hold it (no
    known suffix, an alpha channel in a JPEG) is refused before anything is written. An existing file is
    replaced; an existing folder is not. Missing parent folders are created.

    Args:
        path: the output file.
        image: ``(C, H, W)`` or ``(1, C, H, W)`` float tensor, ``C`` in 1, 3, 4.

    Returns:
        The path written.

    Raises:
        InputTypeError, InputError: ``image`` is not a finite float tensor of one of those shapes; ``path`` is not
            a path, is a folder, or has a suffix whose format cannot hold the image.
    """
    target = check_output_path("path", path)
    check_picture("image", image, ndim=(3, 4))
    if image.ndim == 4 and image.shape[0] != 1:
        raise InputError(f"image must be (C, H, W) or (1, C, H, W), got shape {tuple(image.shape)}", argument="image")
    array = _uint8_frames(image.reshape(1, *image.shape[-3:]), "image")[0]  # (H, W, C)
    if not target.suffix:
        raise InputError(f"path {str(path)!r} has no suffix to choose an image format by (e.g. .png)", argument="path")
    cannot = f"cannot write image {str(path)!r} (suffix {target.suffix!r}, {array.shape[-1]} channels)"
    if target.suffix.lower() not in known_extensions:  # refused here: imageio would warn before it fails
        raise InputError(f"{cannot}: no image format has this suffix (e.g. use .png)", argument="path")
    try:
        encoded = iio.imwrite("<bytes>", array[..., 0] if array.shape[-1] == 1 else array, extension=target.suffix)
    except (*DECODE_ERRORS, KeyError, IndexError) as exc:
        known = target.suffix.lower() in Image.registered_extensions()
        why = first_line(exc) if known else "no image format has this suffix (e.g. use .png)"
        raise InputError(f"{cannot}: {why}", argument="path") from exc
    make_parents("path", target)
    with atomic_output(target) as tmp:
        tmp.write_bytes(encoded)
    return target


def premultiplied(image: Tensor) -> Tensor:
    """A picture with alpha, ``(B, 2, H, W)`` grey + alpha or ``(B, 4, H, W)`` RGBA (alpha last), with its colour
    multiplied by its alpha; 1 or 3 channels (no alpha) as it is.

    Resampling and blending premultiplied colour is what keeps the colour stored under transparent pixels (often
    black, or anything) from bleeding into its neighbours: a bilinear read between a transparent and an opaque
    pixel gives the opaque pixel's colour at half alpha, not half the hidden colour."""
    if image.shape[1] not in (2, 4):
        return image
    return torch.cat([image[:, :-1] * image[:, -1:], image[:, -1:]], 1)


def straight(image: Tensor) -> Tensor:
    """The inverse of :func:`premultiplied`: the colour divided by the alpha where it is above 0 (0 where it is
    not: a fully transparent pixel has no colour to recover); 1 or 3 channels as it is."""
    if image.shape[1] not in (2, 4):
        return image
    alpha = image[:, -1:]
    seen = alpha > 0
    colour = torch.where(seen, image[:, :-1] / torch.where(seen, alpha, torch.ones_like(alpha)), 0.0)
    return torch.cat([colour, alpha], 1)


def resize_image(image: Tensor, size: tuple[int, int], *, max_memory: float | None = None) -> Tensor:
    """Resize an image to ``size``: bilinear, antialiased when it shrinks.

    torch's antialiased bilinear (``F.interpolate(..., antialias=True)``): each output pixel averages the input
    under a triangle as wide as the scale factor, so fine detail is averaged away rather than aliased. Its
    weights are non-negative and sum to one: values stay within the input's range. (kornia's ``resize`` blurs
    with a Gaussian first and then samples; it is slower and aliases at mild factors: ``docs/design.rst``.)

    Conventions: ``align_corners=False``; pixel centres at integers, and the image's outer edges (``-0.5`` and
    ``H - 0.5``) map onto each other. Every channel is resized alike, whatever it holds: a caller that knows its
    picture has alpha resizes it premultiplied (:func:`premultiplied`, :func:`straight`), as the morph does.

    Args:
        image: ``(B, C, H, W)`` floats, ``C``, ``H``, ``W`` >= 1; float16 and bfloat16 are resized in float32
            and returned in their own dtype.
        size: ``(H', W')`` in pixels, each >= 1 (an int means a square).
        max_memory: the most bytes the result may take (:data:`torchfluidwarp._checks.MAX_BYTES`, 8 GiB, by
            default); a larger request is refused before any work.

    Returns:
        ``(B, C, H', W')``; ``image`` itself when it already has that size.

    Raises:
        InputTypeError, InputError: ``image`` is not a 4-D float tensor with non-empty ``C, H, W``, or ``size`` is
            not a pair of ints >= 1; the result would exceed ``max_memory``.

    Example:
        >>> resize_image(torch.ones(1, 3, 8, 6), (4, 3)).shape
        torch.Size([1, 3, 4, 3])
    """
    check_tensor("image", image, ndim=4)  # NaN or inf would smear over the neighbours
    size = check_size("size", size)
    if min(image.shape[1:]) < 1:
        raise InputError(f"image must have C, H and W >= 1, got shape {tuple(image.shape)}", argument="image")
    if tuple(image.shape[-2:]) == size:
        return image
    work = compute_dtype(image.dtype)  # float16 and bfloat16 in float32: torch's CPU antialiased kernel has neither
    nbytes = image.shape[0] * image.shape[1] * size[0] * size[1] * (work.itemsize + image.dtype.itemsize)
    check_memory(f"resize_image to {size[0]} x {size[1]}", nbytes, max_memory, "max_memory")
    out = F.interpolate(image.to(work), size=size, mode="bilinear", align_corners=False, antialias=True)
    return out.to(image.dtype)


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
    check_tensor("image", image, ndim=4)  # as resize_image: NaN or inf is refused, shrunk or not
    size = (image.shape[-2], image.shape[-1])
    smaller = shrunk_size(size, longest)
    return image if smaller == size else resize_image(image, smaller).clamp(0, 1)


def image_shape(path: PathLike) -> tuple[int, int, int]:
    """``(C, H, W)`` of the tensor :func:`read_image` returns for ``path`` (with ``channels=None``), from the
    file's header: no pixels are decoded, so a large photograph costs milliseconds. Upright as :func:`read_image`
    turns it (EXIF orientation); palette, CMYK and grey + alpha counted as it converts them.

    Raises:
        InputError: the file does not exist, is a folder, or its header cannot be read (the error says why; a
            HEIC file without pillow-heif names the package).
        InputTypeError: ``path`` is not a path.

    Example:
        >>> import tempfile, torch
        >>> path = tempfile.mkdtemp() + "/grey.png"
        >>> _ = write_image(path, torch.full((1, 4, 6), 0.5))
        >>> image_shape(path)
        (1, 4, 6)
    """
    path, source = _image_file(path)
    return header_shape(path, source)


def _image_file(path: PathLike) -> tuple[Path, str]:
    """``path`` checked to be an existing file, and how errors name it (``"image 'a.png'"``)."""
    path = check_path("path", path)
    if path.is_dir():
        raise InputError(f"cannot read image {str(path)!r}: it is a folder, not a file", argument="path")
    if not path.is_file():
        raise InputError(f"cannot read image {str(path)!r}: no such file", argument="path")
    return path, f"image {str(path)!r}"


def shrunk_size(size: tuple[int, int], longest: int) -> tuple[int, int]:
    """``size`` ``(H, W)`` pixels shrunk by one factor so that its longer side is at most ``longest`` (0: kept),
    each side rounded and at least 2 pixels: what :func:`shrink_image` resizes to.

    Example:
        >>> shrunk_size((4032, 3024), 1080)
        (1080, 810)
    """
    check_int("longest", longest, minimum=0)
    H, W = size
    if longest == 0 or max(H, W) <= longest:
        return H, W
    scale = longest / max(H, W)
    return max(2, round(H * scale)), max(2, round(W * scale))


def _check_image_options(channels: int | None, dtype: torch.dtype, max_pixels: int) -> None:
    if channels is not None and (
        isinstance(channels, bool) or not isinstance(channels, int) or channels not in (1, 3, 4)
    ):
        raise InputError(f"channels must be None, 1, 3 or 4, got {channels!r}", argument="channels")
    check_float_dtype("dtype", dtype)
    check_int("max_pixels", max_pixels)


def _tensor_from_array(
    array: np.ndarray, source: str, channels: int | None, dtype: torch.dtype, argument: str = "path"
) -> Tensor:
    """``(H, W)`` or ``(H, W, C)`` decoded pixels -> ``(1, C', H, W)`` in ``[0, 1]``; ``argument`` names where
    they came from in errors (``"path"`` or ``"data"``)."""
    if array.ndim == 2:
        array = array[..., None]
    if array.ndim != 3 or not 1 <= array.shape[-1] <= 4:
        raise InputError(f"cannot read {source}: unsupported pixel layout {array.shape}", argument=argument)
    if array.shape[-1] == 2:  # gray + alpha: keep the alpha, as RGBA (repeated in the file's dtype, not in floats)
        array = array[..., [0, 0, 0, 1]]
    # One pass from the decoded (H, W, C) pixels, in the file's dtype (a 6000 x 6000 RGB photo: 108 MB as uint8),
    # into the result's (C, H, W) floats, then scaled in place: the floats are the only full-size copy made, in
    # the working dtype (float32 unless float64 is asked for), never float64 on the way.
    work = np.float64 if dtype == torch.float64 else np.float32
    values = np.empty((array.shape[2], array.shape[0], array.shape[1]), dtype=work)  # (C, H, W)
    with np.errstate(over="ignore", invalid="ignore"):  # float64 past float32's range: inf, clipped below
        np.copyto(values, array.transpose(2, 0, 1), casting="unsafe")
    if np.issubdtype(array.dtype, np.integer):
        values /= work(np.iinfo(array.dtype).max)
    elif array.dtype != np.bool_:  # float pixels clipped to [0, 1], in place: fmax takes NaN to 0, as -inf
        np.fmax(values, 0.0, out=values)
        np.fmin(values, 1.0, out=values)
    image = torch.from_numpy(values).unsqueeze(0)  # (1, C, H, W)
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
of 1920 x 1080 RGB would take 15 GB as float64, one 6000 x 6000 RGB frame 0.86 GB): whole frames when they
are small, bands of rows of one frame when they are large."""


def _uint8_frames(frames: Tensor, name: str) -> np.ndarray:
    """``(T, C, H, W)`` floats in ``[0, 1]`` -> ``(T, H, W, C)`` uint8, after validating them."""
    check_tensor(name, frames, ndim=4)
    t, c, h, w = frames.shape
    if c not in (1, 3, 4) or min(t, h, w) < 1:
        raise InputError(
            f"{name} must have C in 1, 3, 4 and non-empty T, H, W; got shape {tuple(frames.shape)}",
            argument=argument_of(name),
        )
    out = torch.empty(t, h, w, c, dtype=torch.uint8)
    chunk = max(1, _CONVERT_BYTES // (8 * c * h * w))  # frames per float64 chunk: memory stays bounded
    rows = h if chunk > 1 else max(1, _CONVERT_BYTES // (8 * c * w))  # rows per chunk of one large frame
    for i in range(0, t, chunk):
        for r in range(0, h, rows):
            part = frames[i : i + chunk, :, r : r + rows].detach().to("cpu", torch.float64, copy=True)  # not in place
            part = part.clamp_(0.0, 1.0).mul_(255.0).round_()
            out[i : i + chunk, r : r + rows] = part.to(torch.uint8).permute(0, 2, 3, 1)
    return out.numpy()
