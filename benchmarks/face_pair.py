"""A pair of real photographs of human faces for ``bench_morph.py --pair faces``, with their landmarks.

Two faces cropped from ``insightface`` 2.1's sample photo (fetched by ``morph_quality_data.py``, never
redistributed) and 41 mediapipe face-mesh landmarks each, ``data/face_pair_landmarks.json``; see
benchmarks/README.md. The detection code is in the history: ``git show 7d1a1c6:benchmarks/face_pair.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
import torch.nn.functional as F
from morph_quality_data import read_photo
from torch import Tensor

SIZE = 512
# face boxes (x, y, side) in t1.jpg's pixels, from mediapipe's full-range face detector (scores 0.81, 0.69)
FACES = {"a": (63, 290, 98), "b": (457, 294, 116)}
CROP_FACTOR = 2.0
LANDMARKS = Path(__file__).with_name("data") / "face_pair_landmarks.json"


def crops() -> dict[str, Tensor]:
    """The two face crops, ``(1, 3, 512, 512)`` float32 in ``[0, 1]``."""
    image = torch.from_numpy(read_photo("t1")).permute(2, 0, 1).float().div(255).unsqueeze(0)  # t1.jpg, 1280 x 886
    out = {}
    for key, (x, y, side) in FACES.items():
        cx, cy, half = x + side / 2, y + side / 2, CROP_FACTOR * side / 2
        x0, y0, x1, y1 = (round(v) for v in (cx - half, cy - half, cx + half, cy + half))
        crop = image[..., y0:y1, x0:x1]
        out[key] = F.interpolate(crop, size=(SIZE, SIZE), mode="bilinear", align_corners=False, antialias=True)
    return out


def load_face_pair() -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(image_a, image_b, points_a, points_b)``: ``(1, 3, 512, 512)`` x 2 and ``(41, 2)`` pixels x 2."""
    images = crops()
    marks = json.loads(LANDMARKS.read_text())
    pa, pb = (torch.tensor(marks[k], dtype=torch.float32) for k in ("a", "b"))
    return images["a"], images["b"], pa, pb
