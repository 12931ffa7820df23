"""Face landmarks for morphing, from mediapipe's face detectors and face mesh (the optional ``faces`` extra).

A face is found in a whole photograph, at any framing, size, colour model and a tilt of up to 30 degrees or so,
in two stages (:func:`find_faces`):

1. **Where the faces are.** mediapipe's two face detectors (``mp.solutions.face_detection``) look at the whole
   picture, reduced to at most :data:`DETECTION_SIDE` pixels: the full-range model
   (``face_detection_full_range_sparse.tflite``, for faces down to a few percent of the picture) and the
   short-range model (``face_detection_short_range.tflite``), the latter also on the picture set in a grey
   margin (:data:`MARGIN`), so that a face that fills the frame is seen whole; the full-range model looks again
   at overlapping squares of the picture (:data:`TILES`), so that a group photo's small faces are seen at twice
   the size. Boxes of one face are merged.
2. **Its landmarks.** For each face, a square crop :data:`CROP_SCALE` times the face's box, turned so that the
   eyes are level and resampled to :data:`CROP` pixels (the resolution the mesh model works at), goes through
   the face mesh (``mp.solutions.face_mesh``, ``face_landmark.tflite``); its 468 points are mapped back to the
   picture's pixels. The mesh run on a whole uncropped portrait misses the face: its own detector is the
   short-range one at 128 x 128 pixels.

The wheel of mediapipe 0.10.14 bundles all three models, so nothing is downloaded at run time. Install it with
``pip install "torchfluidwarp[faces]"``; mediapipe is imported only when a face is looked for, never by
``import torchfluidwarp``. Its own log lines (TensorFlow Lite, absl, glog) are kept off stderr during the
library's calls only (:mod:`torchfluidwarp.correspond._quiet`).

Of the mesh's 468 points, :data:`FACE_LANDMARKS` keeps 63 that a morph needs, by group: the face outline
(every other point of the mesh's face oval, forehead to chin), the brows, the eyes (corners and lids), the nose
(bridge, tip, wings) and the lips (outer corners and outline, inner lips). Points are in pixels ``(x, y)``,
pixel centres at integers; mediapipe's normalised coordinates put 0 and 1 at the image's outer edges, so
``x_pixel = x * W - 0.5``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from types import ModuleType

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import check_int, warn
from torchfluidwarp.core.sampling import sample
from torchfluidwarp.correspond._image import rgb_uint8, single_image
from torchfluidwarp.correspond._quiet import native_logs_filtered
from torchfluidwarp.errors import InputError

__all__ = [
    "CROP",
    "CROP_SCALE",
    "DETECTION_SIDE",
    "FACE_LANDMARKS",
    "FACE_MESH_INDICES",
    "MARGIN",
    "MAX_FACES",
    "MIN_SCORE",
    "TILES",
    "Chosen",
    "Face",
    "NoFaceFound",
    "choose_face",
    "detect_face_points",
    "find_faces",
    "listing",
    "load_mediapipe",
]

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
DETECTION_SIDE = 1024
"""The longest side, in pixels, of the picture the detectors see (a larger one is reduced first: the detectors
work at 128 and 192 pixels, so more only costs time)."""
MARGIN = 0.5
"""The grey margin around the picture on the short-range detector's second look, per side, as a share of the
picture's longer side: a face that fills the picture then fills a third of it, as the model expects."""
TILES = 2
"""The full-range detector's second look: the picture in squares of ``1 / TILES`` of its longer side, each half a
square from the next. The model reads its input at 192 pixels, so a face a tenth of the picture across is 19
pixels to it in the whole picture, too few for faces turned or looking down, and twice that in a square."""
MIN_SCORE = 0.5
"""The detectors' least confidence for a face."""
CROP = 256
"""The side, in pixels, of the square crop the face mesh runs on."""
CROP_SCALE = 2.0
"""The crop's side over the side of the face's box (the detector's box runs from the brows to the chin): the
mesh's own detector then sees the whole head, at half the crop."""
_SAME_FACE = 0.3  # boxes overlapping more than this (intersection over union) are one face


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


@dataclass(frozen=True, eq=False)  # compared by identity: its mesh is a tensor
class Face:
    """One face found in a picture.

    Attributes:
        mesh: ``(468, 2)`` float64 points of mediapipe's face mesh, pixels ``(x, y)`` of the picture, pixel
            centres at integers, on the CPU.
        score: the face detector's confidence, in ``[0, 1]``.
        angle: the tilt of the line through the eyes, degrees, clockwise on the screen (``y`` points down).
    """

    mesh: Tensor
    score: float
    angle: float

    @property
    def box(self) -> tuple[float, float, float, float]:
        """``(x, y, width, height)`` of the mesh's bounding box, pixels (``x, y``: its top-left corner)."""
        low, high = self.mesh.amin(0), self.mesh.amax(0)
        return float(low[0]), float(low[1]), float(high[0] - low[0]), float(high[1] - low[1])

    @property
    def area(self) -> float:
        """The box's area, square pixels: what "the largest face" means."""
        return self.box[2] * self.box[3]

    def __str__(self) -> str:
        x, y, w, h = self.box
        return f"{w:.0f} x {h:.0f} px at ({x:.0f}, {y:.0f})"


@dataclass(frozen=True)
class _Box:
    """A detector's face box in the picture's pixels, with the centres of the two eyes."""

    x: float
    y: float
    width: float
    height: float
    score: float
    eyes: tuple[tuple[float, float], tuple[float, float]]

    def iou(self, other: _Box) -> float:
        w = min(self.x + self.width, other.x + other.width) - max(self.x, other.x)
        h = min(self.y + self.height, other.y + other.height) - max(self.y, other.y)
        inter = max(w, 0.0) * max(h, 0.0)
        return inter / (self.width * self.height + other.width * other.height - inter)


@contextmanager
def _quiet() -> Iterator[None]:
    """The face model's calls: its native log lines dropped, protobuf's deprecation warning ignored."""
    with native_logs_filtered(), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"SymbolDatabase\.GetPrototype\(\) is deprecated")
        yield


def _reduced(image: Tensor, side: int) -> Tensor:
    """``image`` reduced (antialiased) so that its longer side is at most ``side`` pixels."""
    H, W = image.shape[-2:]
    scale = side / max(H, W)
    if scale >= 1:
        return image
    size = (max(1, round(H * scale)), max(1, round(W * scale)))
    return F.interpolate(image.float(), size=size, mode="bilinear", antialias=True, align_corners=False)


def _detect(detector, rgb, offset: tuple[float, float], scale: float) -> list[_Box]:
    """A detector's boxes on ``rgb`` ``(h, w, 3)``, in picture pixels: ``picture = offset + scale * rgb``."""
    h, w = rgb.shape[:2]
    found = detector.process(rgb).detections or []
    boxes = []
    for d in found:
        r = d.location_data.relative_bounding_box
        if r.width <= 0 or r.height <= 0:
            continue
        k = d.location_data.relative_keypoints  # 0 and 1: the eyes

        def px(u: float, v: float) -> tuple[float, float]:
            return offset[0] + scale * (u * w - 0.5), offset[1] + scale * (v * h - 0.5)

        x, y = px(r.xmin, r.ymin)
        eyes = (px(k[0].x, k[0].y), px(k[1].x, k[1].y))
        boxes.append(_Box(x, y, scale * r.width * w, scale * r.height * h, float(d.score[0]), eyes))
    return boxes


def _starts(n: int, side: int) -> list[int]:
    """Where squares of ``side`` pixels start along ``n`` pixels, half a square apart, the last at the end."""
    count = 1 + max(0, math.ceil((n - side) / (side / 2)))
    return [min(n - side, round(i * side / 2)) for i in range(count)]


def _face_boxes(mp: ModuleType, image: Tensor) -> list[_Box]:
    """The faces' boxes in ``image`` ``(1, C, H, W)``, best score first, one per face."""
    H, W = image.shape[-2:]
    small = _reduced(image, DETECTION_SIDE)
    scale = W / small.shape[-1]  # picture pixels per detection pixel (the same along y, up to rounding)
    rgb = rgb_uint8(small)
    pad = round(MARGIN * max(rgb.shape[:2]))
    padded = (
        F.pad(torch.from_numpy(rgb).permute(2, 0, 1), (pad, pad, pad, pad), value=128).permute(1, 2, 0).contiguous()
    ).numpy()
    centre = (scale - 1) / 2  # pixel centres: picture x = scale * (x_small + 0.5) - 0.5
    h, w = rgb.shape[:2]
    side = math.ceil(max(h, w) / TILES)
    th, tw = min(h, side), min(w, side)
    detector = mp.solutions.face_detection.FaceDetection  # opened once per model: an opening costs about 3 looks
    with detector(model_selection=1, min_detection_confidence=MIN_SCORE) as full:
        boxes = _detect(full, rgb, (centre, centre), scale)
        for y0 in _starts(h, th):
            for x0 in _starts(w, tw):
                tile = np.ascontiguousarray(rgb[y0 : y0 + th, x0 : x0 + tw])
                boxes += _detect(full, tile, (centre + scale * x0, centre + scale * y0), scale)
    with detector(model_selection=0, min_detection_confidence=MIN_SCORE) as short:
        boxes += _detect(short, rgb, (centre, centre), scale)
        boxes += _detect(short, padded, (centre - scale * pad, centre - scale * pad), scale)
    kept: list[_Box] = []
    for box in sorted(boxes, key=lambda b: b.score, reverse=True):
        if all(box.iou(other) <= _SAME_FACE for other in kept):
            kept.append(box)
    return kept


def _crop(image: Tensor, centre: tuple[float, float], side: float, angle: float) -> tuple[Tensor, Tensor]:
    """A square of ``side`` pixels about ``centre``, turned by ``angle`` radians, resampled to :data:`CROP` pixels.

    Returns:
        the crop ``(1, C, CROP, CROP)`` (grey where it leaves the picture), and the ``(3, 2)`` affine map ``A``
        from crop pixels to picture pixels: ``p = q @ A[:2] + A[2]``.
    """
    H, W = image.shape[-2:]
    k = side / CROP  # picture pixels per crop pixel
    c, s = math.cos(angle), math.sin(angle)
    q0 = (CROP - 1) / 2
    # p = centre + k R (q - q0), with R's columns the crop's axes in the picture
    A = torch.tensor([[k * c, k * s], [-k * s, k * c], [0.0, 0.0]], dtype=torch.float64)
    A[2] = torch.tensor(centre, dtype=torch.float64) - q0 * (A[0] + A[1])
    # read only the part of the picture the crop covers, reduced to about the crop's resolution first
    reach = side / 2 * math.sqrt(2) + 2
    x0, x1 = max(0, math.floor(centre[0] - reach)), min(W, math.ceil(centre[0] + reach) + 1)
    y0, y1 = max(0, math.floor(centre[1] - reach)), min(H, math.ceil(centre[1] + reach) + 1)
    region = image[..., y0:y1, x0:x1].float()
    if k > 1.5:
        size = (max(1, round((y1 - y0) / k)), max(1, round((x1 - x0) / k)))
        region = F.interpolate(region, size=size, mode="bilinear", antialias=True, align_corners=False)
    sy, sx = region.shape[-2] / (y1 - y0), region.shape[-1] / (x1 - x0)
    region = F.pad(region, (1, 1, 1, 1), value=0.5)  # grey beyond the picture (the sampler repeats the border)
    q = torch.stack(torch.meshgrid(torch.arange(CROP), torch.arange(CROP), indexing="xy"), -1)
    p = q.to(torch.float64) @ A[:2] + A[2]  # (CROP, CROP, 2) picture pixels
    p = (p - torch.tensor([x0, y0]) + 0.5) * torch.tensor([sx, sy]) - 0.5 + 1  # pixels of the padded region
    grid = (p + 0.5) / torch.tensor([region.shape[-1], region.shape[-2]]) * 2 - 1
    grid = grid.unsqueeze(0).to(device=region.device, dtype=region.dtype)  # (1, CROP, CROP, 2), finite
    crop = sample(region, grid, align_corners=False, check=None)
    return crop, A


def _mesh_in_crop(mesh_model, crop: Tensor) -> Tensor | None:
    """The mesh ``(468, 2)`` (crop pixels, float64) of the face nearest the crop's centre, or ``None``."""
    found = mesh_model.process(rgb_uint8(crop)).multi_face_landmarks or []
    meshes = [torch.tensor([[p.x, p.y] for p in f.landmark], dtype=torch.float64) * CROP - 0.5 for f in found]
    if not meshes:
        return None
    centre = (CROP - 1) / 2
    return min(meshes, key=lambda m: float((m.mean(0) - centre).norm()))


def find_faces(image: Tensor) -> list[Face]:
    """Every face in a photograph, with its 468 mesh points, largest first.

    Args:
        image: ``(C, H, W)`` or ``(1, C, H, W)`` float image in ``[0, 1]``, ``C`` = 1, 3 (RGB) or 4 (alpha
            ignored); any size from about 100 pixels up.

    Returns:
        the faces found (:class:`Face`), by the area of their box, largest first; empty when there is none.

    Raises:
        ImportError: mediapipe is not installed (the message says ``pip install "torchfluidwarp[faces]"``).

    Example:
        >>> from torchfluidwarp.data import load_sample
        >>> faces = find_faces(load_sample("astronaut"))
        >>> len(faces), faces[0].mesh.shape  # str(faces[0]): '93 x 106 px at (178, 69)'
        (1, torch.Size([468, 2]))
    """
    x = single_image("image", image).detach()
    mp = load_mediapipe()
    faces: list[Face] = []
    with _quiet():
        boxes = _face_boxes(mp, x)
        if not boxes:
            return []
        with mp.solutions.face_mesh.FaceMesh(
            static_image_mode=True, max_num_faces=2, refine_landmarks=False, min_detection_confidence=MIN_SCORE
        ) as mesh_model:
            for box in boxes[:MAX_FACES]:
                (ax, ay), (bx, by) = box.eyes
                angle = math.atan2(by - ay, bx - ax)
                centre = (box.x + box.width / 2, box.y + box.height / 2)
                crop, A = _crop(x, centre, CROP_SCALE * max(box.width, box.height), angle)
                mesh = _mesh_in_crop(mesh_model, crop)
                if mesh is not None:
                    faces.append(Face(mesh @ A[:2] + A[2], box.score, math.degrees(angle)))
    # two boxes of one face (one per detector) that the overlap test kept apart give one mesh twice
    unique: list[Face] = []
    for face in sorted(faces, key=lambda f: f.score, reverse=True):
        size = math.sqrt(face.area)
        if all(float((face.mesh.mean(0) - other.mesh.mean(0)).norm()) > 0.3 * size for other in unique):
            unique.append(face)
    return sorted(unique, key=lambda f: f.area, reverse=True)


def listing(faces: list[Face]) -> str:
    """``"0: 97 x 117 px at (176, 71); 1: 40 x 48 px at (300, 60)"``: the faces by their index."""
    return "; ".join(f"{i}: {face}" for i, face in enumerate(faces))


@dataclass(frozen=True, eq=False)
class Chosen:
    """The face that :func:`choose_face` picked, and what it was picked from."""

    face: Face
    index: int
    others: list[Face]  # every face found, largest first (the chosen one among them)

    @property
    def count(self) -> int:
        return len(self.others)


def choose_face(faces: list[Face], face_index: int | None, name: str, size: tuple[int, int]) -> Chosen:
    """The face ``face_index`` (``None``: the largest) of those :func:`find_faces` found in the picture ``name``.

    Raises:
        NoFaceFound: ``faces`` is empty (the message names ``name`` and its size ``(H, W)``).
        InputError: ``face_index`` beyond the faces found (the message lists them).
    """
    if not faces:
        raise NoFaceFound(f"no face found in {name} ({size[1]} x {size[0]} pixels)", argument="image")
    index = 0 if face_index is None else face_index
    if index >= len(faces):
        raise InputError(
            f"face_index={index}, but {name} has {len(faces)} face(s) (0 to {len(faces) - 1}): {listing(faces)}",
            argument="face_index",
        )
    return Chosen(faces[index], index, faces)


def detect_face_points(image: Tensor, *, face_index: int | None = None, name: str = "image") -> Tensor:
    """The :data:`FACE_LANDMARKS` of one face in a photograph (:func:`find_faces`).

    Args:
        image: ``(C, H, W)`` or ``(1, C, H, W)`` float image in ``[0, 1]``, ``C`` = 1, 3 (RGB) or 4 (alpha
            ignored). A whole portrait, a group photo or a tight crop, of any size.
        face_index: which face, counted by size, largest first (0 = the largest). ``None``: the largest,
            with a warning when there are several.
        name: what to call the image in messages (a file name, say).

    Returns:
        ``(63, 2)`` points ``(x, y)`` in pixels, pixel centres at integers, in :data:`FACE_MESH_INDICES`'s
        order, with the image's dtype and device.

    Raises:
        ImportError: mediapipe is not installed (the message says ``pip install "torchfluidwarp[faces]"``).
        NoFaceFound: no face found in the image (an ``InputError``, so a ``ValueError``; the message names
            ``name`` and its size in pixels).
        InputError: ``face_index`` beyond the faces found (the message lists them: size and place of each).

    Warns:
        UserWarning: several faces and ``face_index=None``: lists them, and says how to pick another.

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
    face = choose_face(find_faces(x), face_index, name, (x.shape[-2], x.shape[-1]))
    if face_index is None and face.count > 1:
        warn(
            f"found {face.count} faces in {name} ({listing(face.others)}); using the largest. Pass face_index=i "
            f"(0 = largest, {face.count - 1} = smallest) to choose another",
            UserWarning,
        )
    return face.face.mesh[list(FACE_MESH_INDICES)].to(device=x.device, dtype=x.dtype)
