"""Face landmarks for morphing, from mediapipe's face mesh (the optional ``faces`` extra).

The detector is mediapipe 0.10.14's face mesh (``mp.solutions.face_mesh``): its wheel bundles the face detector
and the 468-point mesh model (``face_detection_short_range.tflite``, ``face_landmark.tflite``), so nothing is
downloaded at run time. Install it with ``pip install "torchfluidwarp[faces]"``; mediapipe is imported only when
a face is detected, never by ``import torchfluidwarp``.

Of the mesh's 468 points, :data:`FACE_LANDMARKS` keeps 63 that a morph needs, by group: the face outline
(every other point of the mesh's face oval, forehead to chin), the brows, the eyes (corners and lids), the nose
(bridge, tip, wings) and the lips (outer corners and outline, inner lips). Points are in pixels ``(x, y)``,
pixel centres at integers; mediapipe's normalised coordinates put 0 and 1 at the image's outer edges, so
``x_pixel = x * W - 0.5``.
"""

from __future__ import annotations

import warnings
from types import ModuleType

import torch
from torch import Tensor

from torchfluidwarp._checks import check_int
from torchfluidwarp.correspond._image import rgb_uint8, single_image
from torchfluidwarp.errors import InputError

__all__ = ["FACE_LANDMARKS", "FACE_MESH_INDICES", "MAX_FACES", "NoFaceFound", "detect_face_points", "load_mediapipe"]

# mediapipe face-mesh indices, by group; "left"/"right" as seen in the image
FACE_LANDMARKS: dict[str, tuple[int, ...]] = {
    # every other point of mediapipe's FACEMESH_FACE_OVAL, clockwise from the top of the forehead (10) via the
    # right side of the image (454), the chin (152) and the left side (234)
    "outline": (10, 297, 284, 389, 454, 361, 397, 379, 400, 152, 176, 150, 172, 132, 234, 162, 54, 67),
    "brows": (70, 63, 105, 66, 107, 336, 296, 334, 293, 300),
    "eyes": (33, 160, 158, 133, 153, 144, 362, 385, 387, 263, 373, 380),
    "nose": (168, 6, 197, 1, 2, 98, 327),
    "lips": (61, 40, 37, 0, 267, 270, 291, 321, 314, 17, 84, 91, 78, 13, 308, 14),
}
FACE_MESH_INDICES: tuple[int, ...] = tuple(i for group in FACE_LANDMARKS.values() for i in group)
MAX_FACES = 8  # faces looked for in one image


class NoFaceFound(InputError):
    """:func:`detect_face_points` found no face in the image (an :class:`~torchfluidwarp.errors.InputError`), so
    that :func:`~torchfluidwarp.correspond.auto_points` can tell it from the other refusals and match features."""


INSTALL_HINT = 'face landmarks need mediapipe 0.10.14: pip install "torchfluidwarp[faces]"'


def load_mediapipe() -> ModuleType:
    """Import mediapipe, or raise an ImportError that says how to install it."""
    try:
        import mediapipe
    except ImportError as exc:  # also when sys.modules["mediapipe"] is None
        raise ImportError(INSTALL_HINT) from exc
    if not hasattr(mediapipe, "solutions"):
        raise ImportError(f"mediapipe {getattr(mediapipe, '__version__', '?')} has no face mesh; {INSTALL_HINT}")
    return mediapipe


def _mesh_points(image: Tensor) -> list[Tensor]:
    """Every face's 468 mesh points ``(468, 2)`` in pixels (float64, on the CPU), in mediapipe's order."""
    mp = load_mediapipe()
    H, W = image.shape[-2:]
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"SymbolDatabase\.GetPrototype\(\) is deprecated")
        with mp.solutions.face_mesh.FaceMesh(
            static_image_mode=True, max_num_faces=MAX_FACES, refine_landmarks=False
        ) as mesh:
            found = mesh.process(rgb_uint8(image)).multi_face_landmarks or []
    out = []
    for face in found:
        xy = torch.tensor([[p.x, p.y] for p in face.landmark], dtype=torch.float64)
        out.append(xy * torch.tensor([W, H], dtype=torch.float64) - 0.5)
    return out


def _area(points: Tensor) -> float:
    span = points.amax(0) - points.amin(0)
    return float(span[0] * span[1])


def detect_face_points(image: Tensor, *, face_index: int | None = None, name: str = "image") -> Tensor:
    """The :data:`FACE_LANDMARKS` of one face in a photograph.

    Args:
        image: ``(C, H, W)`` or ``(1, C, H, W)`` float image in ``[0, 1]``, ``C`` = 1, 3 (RGB) or 4 (alpha
            ignored).
        face_index: which face, counted by size, largest first (0 = the largest). ``None``: the largest,
            with a warning when there are several.
        name: what to call the image in messages (a file name, say).

    Returns:
        ``(63, 2)`` points ``(x, y)`` in pixels, pixel centres at integers, in :data:`FACE_MESH_INDICES`'s
        order, with the image's dtype and device.

    Raises:
        ImportError: mediapipe is not installed (the message says ``pip install "torchfluidwarp[faces]"``).
        NoFaceFound: no face found in the image (an ``InputError``, so a ``ValueError``; the message names
            ``name``).
        InputError: ``face_index`` beyond the faces found.

    Warns:
        UserWarning: several faces and ``face_index=None``: says how many, and how to pick another.

    Conventions:
        ``(x, y)`` order, pixels, pixel centres at integers (the library's convention). "Left" and "right"
        in :data:`FACE_LANDMARKS` are as seen in the image.

    Example:
        >>> from torchfluidwarp.data import load_sample
        >>> detect_face_points(load_sample("astronaut"), name="astronaut").shape
        torch.Size([63, 2])
    """
    x = single_image("image", image)
    if face_index is not None:
        face_index = check_int("face_index", face_index, minimum=0)
    faces = sorted(_mesh_points(x), key=_area, reverse=True)
    if not faces:
        raise NoFaceFound(f"no face found in {name} ({x.shape[-1]} x {x.shape[-2]} pixels)", argument="image")
    if face_index is None:
        if len(faces) > 1:
            warnings.warn(
                f"found {len(faces)} faces in {name}; using the largest. Pass face_index=i (0 = largest, "
                f"{len(faces) - 1} = smallest) to choose another",
                UserWarning,
                stacklevel=2,
            )
        face_index = 0
    if face_index >= len(faces):
        raise InputError(
            f"face_index={face_index}, but {name} has {len(faces)} face(s) (0 to {len(faces) - 1})",
            argument="face_index",
        )
    points = faces[face_index][list(FACE_MESH_INDICES)]
    return points.to(device=x.device, dtype=x.dtype)
