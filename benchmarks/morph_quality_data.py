"""Real photographs of faces with held-out landmarks, for ``bench_morph_quality.py``.

The photos come from PyPI packages (``insightface`` 2.1's wheel: faces ``t1-1`` to ``t1-6``; ``face_recognition``
1.3.0's sdist: ``biden``, ``obama``, ``obama2``, ``obama3``), fetched with ``pip download --no-deps`` into
``$TORCHFLUIDWARP_BENCH_CACHE`` (default ``~/.cache/torchfluidwarp-bench``) and checked by SHA-256, plus the
bundled ``astronaut`` and matplotlib's ``hopper``. Each face is a square crop around mediapipe's face box,
resized to 512 x 512, with 68 iBUG-like and 12 extra landmarks committed in ``data/morph_quality_landmarks.json``;
the detection code is in the history: ``git show 7d1a1c6:benchmarks/morph_quality_data.py``.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tarfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

SIZE = 512
CROP_FACTOR = 2.0
LANDMARKS = Path(__file__).with_name("data") / "morph_quality_landmarks.json"


@dataclass(frozen=True)
class Archive:
    """A package release on PyPI that ships photographs."""

    requirement: str  # pinned, for pip download
    filename: str  # the archive pip saves
    sha256: str
    sdist: bool  # fetched with --no-binary :all:


@dataclass(frozen=True)
class Photo:
    archive: Archive
    member: str  # path inside the archive
    sha256: str


INSIGHTFACE = Archive(
    "insightface==2.1",
    "insightface-2.1-py3-none-any.whl",
    "dcd58ee79d99d689572477315f3149353afd65a36dc575f597cbb217a7bde399",
    sdist=False,
)
FACE_RECOGNITION = Archive(
    "face_recognition==1.3.0",
    "face_recognition-1.3.0.tar.gz",
    "5e5efdd1686aa566af0d3cc1313b131e4b197657a8ffd03669e6d3fad92705ec",
    sdist=True,
)
HOPPER_SHA256 = "a8ca6d734765703b09728ab47fe59f473d93ae3967fc24c7c0288c3c7adb7130"  # matplotlib 3.11.2
_FR = "face_recognition-1.3.0/tests/test_images/"
PHOTOS: dict[str, Photo] = {
    "t1": Photo(
        INSIGHTFACE,
        "insightface/data/images/t1.jpg",
        "47f682e945b659f93a9e490b9c9c4a2a864abe64dace9e1a2893845ddfd69489",
    ),
    "biden": Photo(
        FACE_RECOGNITION, _FR + "biden.jpg", "3c17508bb91554c637a2eabddfae790e5bb1caba93130814fc2ac50be9760c4c"
    ),
    "obama": Photo(
        FACE_RECOGNITION, _FR + "obama.jpg", "0930e3aa8cae5920329c0c8cbc6a2ab70f47b0e67b432875beaa95cbf7e741f6"
    ),
    "obama2": Photo(
        FACE_RECOGNITION, _FR + "obama2.jpg", "a7efcc907375274796f39646510704aa86672d59f6d5469d69af3c85590976a6"
    ),
    "obama3": Photo(
        FACE_RECOGNITION, _FR + "obama3.jpg", "76ac6bf97c36dc2da0ad16a537d6a5ac1b10f48d49aac29a0cca9a17cdbc3ca3"
    ),
}

# Every face that --detect writes. ``t1-2`` and ``t1-5`` are in near profile: the face mesh places their far side's
# jaw and brow points (hidden behind the nose) across the nose line, so their marks cross those of any frontal face
# (morph warns so), which no smooth morph can follow without folding; they are kept in the JSON but not used.
DETECTED: tuple[str, ...] = (
    *("t1-1", "t1-2", "t1-3", "t1-4", "t1-5", "t1-6"),
    *("astronaut", "hopper", "biden", "obama", "obama2", "obama3"),
)
# A pair belongs to a half when both its faces do, so no report face is seen while tuning; pairs across the
# halves are not used. The bundled pair's astronaut is a tune face.
SPLIT_FACES: dict[str, tuple[str, ...]] = {
    "tune": ("t1-1", "t1-3", "astronaut", "obama", "obama2"),
    "report": ("t1-4", "t1-6", "hopper", "biden", "obama3"),
}
FACES: tuple[str, ...] = tuple(f for f in DETECTED if f in SPLIT_FACES["tune"] + SPLIT_FACES["report"])


def cache_dir() -> Path:
    return Path(os.environ.get("TORCHFLUIDWARP_BENCH_CACHE", Path.home() / ".cache" / "torchfluidwarp-bench"))


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def fetch_archive(archive: Archive) -> Path:
    """The archive in the cache, downloaded by ``pip download --no-deps`` on first use and checked by SHA-256."""
    folder = cache_dir() / "pip"
    path = folder / archive.filename
    if not path.exists():
        folder.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--disable-pip-version-check", "-d", str(folder)]
        cmd += ["--no-binary", ":all:"] if archive.sdist else ["--only-binary", ":all:"]
        done = subprocess.run([*cmd, archive.requirement], capture_output=True, text=True)
        if done.returncode != 0 or not path.exists():
            raise RuntimeError(f"pip download {archive.requirement} failed:\n{done.stdout}{done.stderr}")
    digest = _sha256(path.read_bytes())
    if digest != archive.sha256:
        raise RuntimeError(f"{path} has SHA-256 {digest}, expected {archive.sha256}; delete it and retry")
    return path


def photo_path(name: str) -> Path:
    """A photograph of :data:`PHOTOS`, extracted from its archive into the cache and checked by SHA-256;
    ``"astronaut"``, the library's bundled sample; or ``"hopper"``, matplotlib's sample photo."""
    if name == "astronaut":
        from torchfluidwarp.data import sample_path

        return sample_path("astronaut")
    if name == "hopper":
        from matplotlib.cbook import get_sample_data

        path = Path(get_sample_data("grace_hopper.jpg", asfileobj=False))
        digest = _sha256(path.read_bytes())
        if digest != HOPPER_SHA256:
            raise RuntimeError(f"{path} has SHA-256 {digest}, expected {HOPPER_SHA256}")
        return path
    photo = PHOTOS[name]
    path = cache_dir() / Path(photo.member).name
    if not path.exists() or _sha256(path.read_bytes()) != photo.sha256:
        archive = fetch_archive(photo.archive)
        if archive.name.endswith(".whl"):
            with zipfile.ZipFile(archive) as z:
                data = z.read(photo.member)
        else:
            with tarfile.open(archive) as t:
                member = t.extractfile(photo.member)
                if member is None:
                    raise RuntimeError(f"{photo.member} is not a file in {archive}")
                data = member.read()
        digest = _sha256(data)
        if digest != photo.sha256:
            raise RuntimeError(f"{photo.member} in {archive} has SHA-256 {digest}, expected {photo.sha256}")
        path.write_bytes(data)
    return path


def read_photo(name: str) -> np.ndarray:
    """A photograph as ``(H, W, 3)`` uint8."""
    return iio.imread(photo_path(name))[..., :3]


def crop(image: np.ndarray, box: tuple[int, int, int]) -> Tensor:
    """The square ``box = (x0, y0, side)`` of ``image`` ``(H, W, 3)`` uint8, as ``(1, 3, 512, 512)`` float32 in
    ``[0, 1]``. A crop pixel ``p`` shows the photo's pixel ``(p + 0.5) * side / 512 - 0.5 + (x0, y0)``."""
    x0, y0, side = box
    t = torch.from_numpy(np.ascontiguousarray(image[y0 : y0 + side, x0 : x0 + side])).permute(2, 0, 1)
    t = t.float().div(255).unsqueeze(0)
    return F.interpolate(t, size=(SIZE, SIZE), mode="bilinear", align_corners=False, antialias=True).clamp(0, 1)


@dataclass(frozen=True)
class Face:
    """One face crop and its landmarks, in pixels of the crop (pixel centres at integers)."""

    name: str
    image: Tensor  # (1, 3, 512, 512) float32 in [0, 1]
    ibug: Tensor  # (68, 2)
    extra: Tensor  # (len(EXTRA), 2)


def load_landmarks() -> dict:
    return json.loads(LANDMARKS.read_text())


def load_faces(names: tuple[str, ...] | list[str] = FACES) -> dict[str, Face]:
    """The face crops and their committed landmarks; only the photos are fetched."""
    marks = load_landmarks()["faces"]
    photos: dict[str, np.ndarray] = {}
    out = {}
    for name in names:
        entry = marks[name]
        if entry["photo"] not in photos:
            photos[entry["photo"]] = read_photo(entry["photo"])
        out[name] = Face(
            name=name,
            image=crop(photos[entry["photo"]], tuple(entry["box"])),
            ibug=torch.tensor(entry["ibug68"], dtype=torch.float32),
            extra=torch.tensor(entry["extra"], dtype=torch.float32),
        )
    return out
