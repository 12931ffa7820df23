"""Colours as a viewer shows them: pictures whose colours an embedded ICC profile or a HEIF/AVIF ``nclx`` box
describes, converted to sRGB (the space every picture of a morph is mixed in) when they are read."""

from __future__ import annotations

import io
from typing import Any

import numpy as np
from PIL import Image

from torchfluidwarp._checks import warn
from torchfluidwarp.io._files import first_line

__all__ = ["in_srgb", "lab_in_srgb", "nclx_in_srgb", "SRGB_NAMES"]


def in_srgb(array: np.ndarray, icc: bytes, source: str, mode: str = "RGB") -> np.ndarray:
    """8-bit pixels ``(H, W, C)`` whose colours the embedded ICC profile ``icc`` describes, in sRGB, as every
    colour-managed viewer shows them: a phone's photograph in Display P3 or a camera's in Adobe RGB read as sRGB
    looks dull, and mixes with an sRGB picture in another colour space; a print shop's CMYK JPEG converted by the
    plain formula ``R = (1 - C)(1 - K)`` comes out garish. Relative colorimetric intent.

    ``mode`` ``"RGB"``: RGB or RGBA pixels (the alpha is kept); sRGB pixels, other layouts (grey, 16-bit) and
    profiles of other colour spaces are returned as they are. ``"CMYK"``: 4 inks (0 = none), returned as RGB. A
    profile that cannot be read or applied leaves RGB pixels as they are and converts inks by the plain formula,
    with a warning."""
    if mode == "RGB" and (array.dtype != np.uint8 or array.ndim != 3 or array.shape[-1] not in (3, 4)):
        return array
    try:
        from PIL import ImageCms  # in every Pillow wheel; a Pillow built without LittleCMS lacks it

        profile = ImageCms.ImageCmsProfile(io.BytesIO(icc))
        space = profile.profile.xcolor_space.strip()
        if mode == "RGB" and (space != "RGB" or _description(profile).strip().lower() in SRGB_NAMES):
            return array
        if space != mode:
            raise ValueError(f"a {space} profile for {mode} pixels")
        pixels = Image.fromarray(np.ascontiguousarray(array[..., :3] if mode == "RGB" else array), mode)
        srgb = ImageCms.profileToProfile(
            pixels, profile, ImageCms.createProfile("sRGB"), ImageCms.Intent.RELATIVE_COLORIMETRIC, "RGB"
        )
    except (ImportError, OSError, ValueError, TypeError) as exc:  # PyCMSError is an OSError
        instead = "its colours are read as sRGB" if mode == "RGB" else "its inks are converted by the plain formula"
        warn(f"the colour profile of {source} could not be applied ({first_line(exc)}): {instead}")
        return (
            array if mode == "RGB" else np.asarray(Image.fromarray(np.ascontiguousarray(array), "CMYK").convert("RGB"))
        )
    out = np.asarray(srgb)
    return out if mode == "CMYK" or array.shape[-1] == 3 else np.concatenate([out, array[..., 3:]], axis=-1)


def lab_in_srgb(array: np.ndarray, source: str) -> np.ndarray:
    """8-bit CIELab pixels ``(H, W, 3)`` as Pillow reads a CIELab TIFF (its mode ``LAB``: ``L*`` scaled to 0..255;
    a scanner's or a print workflow's export), in sRGB: read as RGB they would show ``L*`` as red and
    the two colour axes as green and blue. LittleCMS converts them from its D50 Lab space, relative colorimetric;
    where it cannot, the picture is refused (there is no plain formula worth showing), naming ``source``."""
    try:
        from PIL import ImageCms

        lab = Image.frombytes("LAB", (array.shape[1], array.shape[0]), np.ascontiguousarray(array[..., :3]).tobytes())
        transform = ImageCms.buildTransform(
            ImageCms.createProfile("LAB"), ImageCms.createProfile("sRGB"), "LAB", "RGB",
            renderingIntent=ImageCms.Intent.RELATIVE_COLORIMETRIC,
        )  # fmt: skip
        return np.asarray(ImageCms.applyTransform(lab, transform))
    except (ImportError, OSError, ValueError) as exc:
        reason = first_line(exc)
        raise ValueError(f"{source} is a CIELab picture whose colours could not be converted ({reason})") from exc


SRGB_NAMES = frozenset(
    {
        "srgb",
        "srgb built-in",
        "srgb iec61966-2.1",
        "srgb iec61966-2-1 black scaled",
        "srgb iec61966-2-1 no black scaling",
        "srgb2014",
        "srgb v4 icc preference perceptual intent beta",
        "srgb profile",
    }
)
"""The descriptions of the common sRGB profiles (lower case), whose pictures are read as stored; any other RGB
profile is applied (one named after sRGB that is not sRGB, such as "sRGB linear", is converted)."""


def _description(profile: Any) -> str:
    """An ICC profile's description (empty where it has none)."""
    return str(getattr(profile.profile, "profile_description", "") or "")


def nclx_in_srgb(array: np.ndarray, nclx: dict[str, Any], source: str, chunk: int = 1 << 20) -> np.ndarray:
    """8-bit RGB or RGBA pixels ``(H, W, 3 or 4)`` whose colours a HEIF ``nclx`` box describes (pillow-heif's
    ``info["nclx_profile"]``: the primaries' chromaticities, the transfer), in sRGB. An Android phone or a browser
    tags a wide-gamut picture this way instead of with an ICC profile: Display P3 (primaries 12), BT.2020 (9).

    BT.709 and unspecified primaries (1, 2) are sRGB's: the pixels are returned as they are. Other primaries with
    the sRGB transfer (13, or unspecified) are converted: sRGB's curve undone, the primaries' RGB to XYZ matrix (its
    white adapted to D65 by Bradford where it differs), sRGB's inverse, clipped to sRGB's gamut (relative
    colorimetric), sRGB's curve, rounded; ``chunk`` pixels at a time. Other transfers (an HDR picture's PQ or
    HLG, BT.709's) are left as stored, with a warning."""
    primaries, transfer = int(nclx.get("color_primaries", 2)), int(nclx.get("transfer_characteristics", 2))
    if primaries in (1, 2) or array.dtype != np.uint8 or array.ndim != 3 or array.shape[-1] not in (3, 4):
        return array
    if transfer not in (2, 13):
        warn(
            f"the colours of {source} are tagged with transfer characteristics {transfer} (an HDR or video curve), "
            f"which this reader does not convert: they are read as stored and may look off"
        )
        return array
    chromaticity = [(nclx[f"color_primary_{c}_x"], nclx[f"color_primary_{c}_y"]) for c in ("red", "green", "blue")]
    white = (nclx["color_primary_white_x"], nclx["color_primary_white_y"])
    matrix = np.linalg.solve(_rgb_to_xyz(_SRGB_PRIMARIES, _D65), _adapt(white, _D65) @ _rgb_to_xyz(chromaticity, white))
    flat = array.reshape(-1, array.shape[-1])
    out = np.empty((flat.shape[0], 3), np.uint8)
    for i in range(0, flat.shape[0], chunk):
        linear = _srgb_decode(flat[i : i + chunk, :3] / 255.0) @ matrix.T
        out[i : i + chunk] = np.rint(_srgb_encode(linear.clip(0, 1)) * 255)
    out = out.reshape(*array.shape[:-1], 3)
    return out if array.shape[-1] == 3 else np.concatenate([out, array[..., 3:]], axis=-1)


_D65 = (0.3127, 0.3290)
_SRGB_PRIMARIES = [(0.64, 0.33), (0.30, 0.60), (0.15, 0.06)]
_BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])


def _xyz(xy: tuple[float, float]) -> np.ndarray:
    """The XYZ of chromaticity ``(x, y)`` at ``Y = 1``."""
    x, y = xy
    return np.array([x / y, 1.0, (1 - x - y) / y])


def _rgb_to_xyz(primaries: list[tuple[float, float]], white: tuple[float, float]) -> np.ndarray:
    """``(3, 3)``: linear RGB with these primaries' chromaticities to XYZ, RGB ``(1, 1, 1)`` at ``white`` (Y = 1)."""
    columns = np.stack([_xyz(p) for p in primaries], 1)
    return columns * np.linalg.solve(columns, _xyz(white))


def _adapt(source: tuple[float, float], target: tuple[float, float]) -> np.ndarray:
    """``(3, 3)``: Bradford's adaptation of XYZ from white ``source`` to ``target`` (the identity if they agree)."""
    if np.allclose(source, target, atol=5e-4):
        return np.eye(3)
    gain = (_BRADFORD @ _xyz(target)) / (_BRADFORD @ _xyz(source))
    return np.linalg.solve(_BRADFORD, gain[:, None] * _BRADFORD)


def _srgb_decode(v: np.ndarray) -> np.ndarray:
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _srgb_encode(v: np.ndarray) -> np.ndarray:
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
