"""Reading and writing images, landmark points and animations.

Conventions:

* Images are float tensors ``(B, C, H, W)`` with values in ``[0, 1]`` and ``C`` = 1 (gray), 3 (RGB) or
  4 (RGBA). ``uint8`` appears only at the file boundary: writers clamp to ``[0, 1]`` and round to 8 bits.
* Points are float tensors ``(M, 2)`` in ``(x, y)`` order, in pixel coordinates with pixel centres at
  integers (see :mod:`torchfluidwarp.core.grid`).
* Animations are float tensors ``(T, C, H, W)``: ``T`` frames, values in ``[0, 1]``.
* Every writer writes to a temporary sibling of its output and moves it into place with ``os.replace``,
  so a failure never leaves a half-written file behind.

Modules: :mod:`~torchfluidwarp.io.images` (image files, resizing), :mod:`~torchfluidwarp.io.points`
(``.pts``, ``.json``, ``.csv`` landmark files) and :mod:`~torchfluidwarp.io.animation` (GIF, MP4, PNG folders).
"""

from __future__ import annotations

from torchfluidwarp.io.animation import FFMPEG_HINT as FFMPEG_HINT
from torchfluidwarp.io.animation import MAX_FPS, MAX_LOOP, MIN_FPS, check_fps, encode_animation, write_animation
from torchfluidwarp.io.animation import AnimationFormat as AnimationFormat
from torchfluidwarp.io.images import (
    MAX_IMAGE_PIXELS,
    image_shape,
    premultiplied,
    read_image,
    read_image_bytes,
    resize_image,
    shrink_image,
    shrunk_size,
    straight,
    write_image,
)
from torchfluidwarp.io.points import MAX_POINTS_BYTES, check_point_counts, read_points, write_points
from torchfluidwarp.io.points import POINT_SUFFIXES as POINT_SUFFIXES

__all__ = [
    "read_image",
    "read_image_bytes",
    "image_shape",
    "write_image",
    "resize_image",
    "shrink_image",
    "premultiplied",
    "straight",
    "shrunk_size",
    "read_points",
    "write_points",
    "check_point_counts",
    "write_animation",
    "encode_animation",
    "check_fps",
    "MAX_IMAGE_PIXELS",
    "MAX_POINTS_BYTES",
    "MIN_FPS",
    "MAX_FPS",
    "MAX_LOOP",
]
