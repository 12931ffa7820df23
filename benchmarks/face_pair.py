"""A pair of real photographs of human faces for ``bench_morph.py --pair faces``, with their landmarks.

This machine reaches only package registries, so the photograph comes from one: ``insightface`` 2.1's wheel on
PyPI ships a group photo, ``insightface/data/images/t1.jpg`` (1280 x 886), as sample data. It is fetched once with
``pip download insightface==2.1 --no-deps`` through pip's configured index (``morph_quality_data.py``, which
checks the SHA-256 of the wheel and of the photo) into ``$TORCHFLUIDWARP_BENCH_CACHE`` (default
``~/.cache/torchfluidwarp-bench``) and never redistributed by this repository. Two faces are cropped from it, each
a square twice the side of the face box that mediapipe's face detector found, and resized to 512 x 512
(antialiased bilinear).

The landmarks in ``data/face_pair_landmarks.json`` (pixels of the 512 x 512 crops, pixel centres at integers)
are 41 points of mediapipe's 468-point face mesh (jaw line, brows, eye corners and lids, nose, lips), detected
on each crop by ``python benchmarks/face_pair.py --detect`` with ``mediapipe==0.10.14`` (the last release
whose wheel bundles the face-mesh model; install it with ``pip install --target DIR mediapipe==0.10.14`` and
put ``DIR`` on ``PYTHONPATH``). They were not edited by hand.

``python benchmarks/face_pair.py --show OUT.png`` writes the two crops side by side with their landmarks.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from morph_quality_data import read_photo
from torch import Tensor

SIZE = 512
# face boxes (x, y, side) in t1.jpg's pixels, from mediapipe's full-range face detector (scores 0.81, 0.69)
FACES = {"a": (63, 290, 98), "b": (457, 294, 116)}
CROP_FACTOR = 2.0
# mediapipe face-mesh indices: jaw line (17), brows (6), eyes (8), nose (4), lips (6)
MESH_POINTS = [
    *[234, 93, 132, 58, 172, 136, 150, 176, 152, 400, 379, 365, 397, 288, 361, 323, 454],
    *[70, 105, 107, 336, 334, 300],
    *[33, 133, 159, 145, 362, 263, 386, 374],
    *[168, 1, 98, 327],
    *[61, 291, 0, 17, 13, 14],
]
LANDMARKS = Path(__file__).with_name("data") / "face_pair_landmarks.json"


def photo() -> np.ndarray:
    """``t1.jpg`` as ``(886, 1280, 3)`` uint8, fetched and checked on first use."""
    return read_photo("t1")


def crops() -> dict[str, Tensor]:
    """The two face crops, ``(1, 3, 512, 512)`` float32 in ``[0, 1]``."""
    image = torch.from_numpy(photo()).permute(2, 0, 1).float().div(255).unsqueeze(0)
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


def detect() -> dict[str, list[list[float]]]:  # pragma: no cover - needs mediapipe 0.10.14
    import mediapipe as mp

    mesh = mp.solutions.face_mesh.FaceMesh(static_image_mode=True, max_num_faces=1)
    out = {}
    for key, img in crops().items():
        rgb = (img[0].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
        found = mesh.process(rgb).multi_face_landmarks
        if not found:
            raise RuntimeError(f"no face found in crop {key}")
        lm = found[0].landmark
        # mediapipe's normalised coordinates: 0 and 1 are the image's outer edges
        out[key] = [[round(lm[i].x * SIZE - 0.5, 2), round(lm[i].y * SIZE - 0.5, 2)] for i in MESH_POINTS]
    return out


def show(path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a, b, pa, pb = load_face_pair()
    fig, axes = plt.subplots(1, 2, figsize=(8, 4))
    for ax, img, p in zip(axes, (a, b), (pa, pb)):
        ax.imshow(img[0].permute(1, 2, 0))
        ax.scatter(p[:, 0], p[:, 1], s=8, c="yellow")
        for i, (x, y) in enumerate(p.tolist()):
            ax.annotate(str(i), (x, y), fontsize=5, color="cyan")
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--detect", action="store_true", help=f"detect the landmarks and write {LANDMARKS.name}")
    parser.add_argument("--show", metavar="OUT.png", help="draw the crops and their landmarks")
    args = parser.parse_args(argv)
    if args.detect:
        LANDMARKS.parent.mkdir(exist_ok=True)
        LANDMARKS.write_text(json.dumps(detect(), indent=1) + "\n")
        print(f"wrote {LANDMARKS}")
    if args.show:
        show(args.show)
        print(f"wrote {args.show}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
