"""Sample images and landmark points bundled with the package, for examples and tests.

Samples (512 x 512 RGB PNGs; sources and licences in ``LICENSES.md`` beside this file):

* ``"astronaut"``: the NASA portrait of Eileen Collins (public domain).
* ``"cat"``: Chelsea the cat's face (CC0), cropped and resized.

Each sample has an iBUG ``.pts`` file of :data:`POINT_LABELS`'s 23 face landmarks, in that order, in
pixel coordinates with pixel centres at integers. The points of two samples correspond one to one,
so they can drive a morph from one face to the other. "Left" and "right" are as seen in the image.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Literal

import torch
from torch import Tensor

from torchfluidwarp.errors import InputError
from torchfluidwarp.io import read_image, read_points

__all__ = ["SAMPLES", "POINT_LABELS", "sample_path", "load_sample", "load_sample_points"]

SAMPLES: tuple[str, ...] = ("astronaut", "cat")

POINT_LABELS: tuple[str, ...] = (
    "left eye, outer corner",
    "left eye, centre",
    "left eye, inner corner",
    "right eye, inner corner",
    "right eye, centre",
    "right eye, outer corner",
    "nose bridge, between the eyes",
    "nose tip",
    "left nostril",
    "right nostril",
    "left mouth corner",
    "upper lip, centre",
    "right mouth corner",
    "lower lip, centre",
    "chin",
    "left cheek, level with the mouth",
    "right cheek, level with the mouth",
    "forehead, centre (hairline)",
    "above the left eye (brow)",
    "above the right eye (brow)",
    "top of the head",
    "head outline, upper left",
    "head outline, upper right (cat: right ear)",
)


def sample_path(name: str, kind: Literal["image", "points"] = "image") -> Path:
    """The file of a bundled sample.

    Args:
        name: one of :data:`SAMPLES`.
        kind: ``"image"`` for the ``.png``, ``"points"`` for the ``.pts`` landmarks.

    Returns:
        The path of the file inside the installed package.

    Raises:
        ValueError: unknown ``name`` (the message lists the available ones) or ``kind``.

    Example:
        >>> sample_path("cat").name
        'cat.png'
    """
    if name not in SAMPLES:
        raise InputError(f"unknown sample {name!r}; available samples: {', '.join(SAMPLES)}")
    suffix = {"image": ".png", "points": ".pts"}.get(kind)
    if suffix is None:
        raise InputError(f"kind must be 'image' or 'points', got {kind!r}")
    resource = resources.files(__name__) / f"{name}{suffix}"
    if not isinstance(resource, Path):  # only a zipped install gives something else
        raise RuntimeError(f"sample {name!r} is not a file on disk ({resource!r}); install the package unzipped")
    return resource


def load_sample(name: str, channels: int = 3, dtype: torch.dtype = torch.float32) -> Tensor:
    """Load a bundled sample image.

    Args:
        name: one of :data:`SAMPLES`.
        channels: 1 (gray), 3 (RGB) or 4 (RGBA), as in :func:`~torchfluidwarp.io.images.read_image`.
        dtype: a floating-point dtype.

    Returns:
        ``(1, channels, 512, 512)`` tensor with values in ``[0, 1]``.

    Raises:
        ValueError: unknown ``name`` or invalid ``channels``.

    Example:
        >>> load_sample("astronaut").shape
        torch.Size([1, 3, 512, 512])
    """
    return read_image(sample_path(name), channels=channels, dtype=dtype)


def load_sample_points(name: str, dtype: torch.dtype = torch.float32) -> Tensor:
    """Load a bundled sample's landmarks (see :data:`POINT_LABELS` for their order).

    Args:
        name: one of :data:`SAMPLES`.
        dtype: a floating-point dtype.

    Returns:
        ``(23, 2)`` tensor of ``(x, y)`` pixel coordinates (pixel centres at integers).

    Raises:
        ValueError: unknown ``name``.

    Example:
        >>> load_sample_points("cat").shape
        torch.Size([23, 2])
    """
    return read_points(sample_path(name, "points"), dtype=dtype)
