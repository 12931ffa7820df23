"""Automatic correspondences (issue #22): held-out error of matched features on known maps, face landmarks
against hand marks, and how many features pairs of one scene and pairs of unrelated pictures match (what
``correspond.auto.TRUSTED_MATCHES`` is set from).

B is the bundled astronaut read through a known map ``phi``, so a match ``(a, b)`` errs by ``|phi(b) - a|``;
``detect_face_points`` is scored against her 23 hand marks (needs ``torchfluidwarp[faces]``). Figures:
docs/benchmarks.md, "Automatic correspondences".
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from _common import describe_load, machine, machine_load, table
from morph_quality_data import read_photo

from torchfluidwarp.correspond import match_features
from torchfluidwarp.correspond.auto import TRUSTED_MATCHES
from torchfluidwarp.data import POINT_LABELS, load_sample, load_sample_points
from torchfluidwarp.warp import identity_map, warp_image

# the known maps are those of the tests (tests/correspond/test_features.py), so one definition serves both
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "correspond"))
from test_features import MAPS, SIZE  # noqa: E402

# the hand-marked labels whose face-mesh counterparts sit at the same feature (index into the 63 points is
# found as the nearest detected point: this measures how close the detector comes, not a fixed pairing)
FACE_LABELS = [label for label in POINT_LABELS if any(k in label for k in ("eye", "nose", "mouth", "lip", "chin"))]


def _tensor(image: np.ndarray) -> torch.Tensor:
    """``(1, 3, H, W)`` float32 in ``[0, 1]`` from an ``(H, W)`` or ``(H, W, C)`` array (uint8, or float in [0, 1])."""
    x = np.asarray(image, dtype=np.float32)
    x = x / 255 if x.max() > 1.5 else x
    x = np.repeat(x[..., None], 3, axis=2) if x.ndim == 2 else x[..., :3]
    return torch.from_numpy(np.ascontiguousarray(x)).permute(2, 0, 1)[None]


def chance_pairs() -> dict[str, list[tuple[str, torch.Tensor, torch.Tensor]]]:
    """Pairs of one scene (a stereo pair, crops, a zoom, a rotation, an affine map, a photograph at half size) and
    pairs of pictures of different scenes (a person against a cat, different people, unrelated objects, and one
    man in two photographs taken apart): scikit-image's sample pictures and the photographs of
    ``morph_quality_data.py``."""
    import skimage.data as sd
    import skimage.transform as st

    left, right, _ = sd.stereo_motorcycle()
    ast, cof, cat, rock, cam = sd.astronaut(), sd.coffee(), sd.chelsea(), sd.rocket(), sd.camera()
    obama = _tensor(read_photo("obama"))
    affine = st.AffineTransform(scale=(1.1, 0.95), rotation=0.05, translation=(-20, 10))
    photo = {name: _tensor(read_photo(name)) for name in ("obama2", "obama3", "biden", "einstein", "breakingbad")}
    return {
        "one scene": [
            ("stereo motorcycle", _tensor(left), _tensor(right)),
            ("astronaut, turned 12 degrees", _tensor(ast), _tensor(st.rotate(ast, 12))),
            (
                "astronaut, cropped and zoomed 1.2x",
                _tensor(ast),
                _tensor(st.rescale(ast[64:448, 64:448], 1.2, channel_axis=-1)),
            ),
            ("coffee, cropped, 1.3x brighter", _tensor(cof), _tensor(np.clip(cof[40:, 60:] / 255 * 1.3, 0, 1))),
            ("cat, affine map", _tensor(cat), _tensor(st.warp(cat, affine))),
            ("rocket, cropped", _tensor(rock), _tensor(rock[50:, 100:])),
            ("obama, at half size", obama, F.interpolate(obama, scale_factor=0.5, mode="area")),
        ],
        "unrelated": [
            ("astronaut / cat", _tensor(ast), _tensor(cat)),
            ("coffee / cat", _tensor(cof), _tensor(cat)),
            ("rocket / camera man", _tensor(rock), _tensor(cam)),
            ("obama2 / cat", photo["obama2"], _tensor(cat)),
            ("biden / cat", photo["biden"], _tensor(cat)),
            ("einstein / astronaut", photo["einstein"], _tensor(ast)),
            ("obama / cat", obama, _tensor(cat)),
            ("obama / biden", obama, photo["biden"]),
            ("obama2 / obama3", photo["obama2"], photo["obama3"]),
            ("breakingbad / einstein", photo["breakingbad"], photo["einstein"]),
            ("coffee / rocket", _tensor(cof), _tensor(rock)),
            ("camera man / astronaut", _tensor(cam), _tensor(ast)),
        ],
    }


def chance_matches() -> None:
    """How many features ``match_features`` keeps on each pair of :func:`chance_pairs`."""
    rows, counts = [], {}
    for kind, pairs in chance_pairs().items():
        for name, a, b in pairs:
            n = len(match_features(a, b)[0])
            counts.setdefault(kind, []).append(n)
            rows.append([kind, name, f"{a.shape[-1]} x {a.shape[-2]}", f"{b.shape[-1]} x {b.shape[-2]}", str(n)])
    print("features matched (match_features' defaults) on pairs of one scene and of unrelated pictures")
    print(table(["pairs", "pair", "A", "B", "matches"], rows))
    for kind, n in counts.items():
        print(f"{kind}: {len(n)} pairs, {min(n)} to {max(n)} matches")
    print(f"correspond.auto.TRUSTED_MATCHES = {TRUSTED_MATCHES}")


def main() -> None:
    print(machine())
    a = load_sample("astronaut").reshape(1, 3, SIZE, SIZE)
    rows = []
    for name, phi in MAPS.items():
        b = warp_image(a, phi(identity_map((SIZE, SIZE), dtype=torch.float64)).float())
        t0 = time.perf_counter()
        pa, pb = match_features(a[0], b[0])
        seconds = time.perf_counter() - t0
        err = (phi(pb.double()) - pa.double()).norm(dim=-1)
        q = torch.quantile(err, torch.tensor([0.5, 0.9], dtype=err.dtype)).tolist()
        rows.append([name, str(len(err)), f"{q[0]:.2f}", f"{q[1]:.2f}", f"{float(err.max()):.2f}", f"{seconds:.1f}"])
    print("feature matches against the known map (A's pixels)")
    print(table(["map", "matches", "median px", "p90 px", "worst px", "seconds"], rows))
    try:
        from torchfluidwarp.correspond import detect_face_points

        found = detect_face_points(a[0], name="astronaut")
    except ImportError as exc:
        print(f"faces: skipped ({exc})")
    else:
        marks = load_sample_points("astronaut")
        chosen = [POINT_LABELS.index(label) for label in FACE_LABELS]
        d = torch.cdist(marks[chosen].double(), found.double()).min(dim=1).values
        print(
            f"face landmarks: {len(found)} points; distance from each of {len(chosen)} hand marks "
            f"({', '.join(FACE_LABELS)}) to the nearest: median {float(d.median()):.2f} px, "
            f"mean {float(d.mean()):.2f} px, max {float(d.max()):.2f} px"
        )
    chance_matches()
    print(describe_load(machine_load()))


if __name__ == "__main__":
    main()
