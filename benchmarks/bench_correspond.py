"""Automatic correspondences (issue #22): held-out error of matched features on known maps, and face landmarks
against hand marks.

B is the bundled astronaut read through a known map ``phi``, so a match ``(a, b)`` errs by ``|phi(b) - a|``;
``detect_face_points`` is scored against her 23 hand marks (needs ``torchfluidwarp[faces]``). Figures:
docs/benchmarks.md, "Automatic correspondences".
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch
from _common import describe_load, machine, machine_load, table

from torchfluidwarp.correspond import match_features
from torchfluidwarp.data import POINT_LABELS, load_sample, load_sample_points
from torchfluidwarp.warp import identity_map, warp_image

# the known maps are those of the tests (tests/correspond/test_features.py), so one definition serves both
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "correspond"))
from test_features import MAPS, SIZE  # noqa: E402

# the hand-marked labels whose face-mesh counterparts sit at the same feature (index into the 63 points is
# found as the nearest detected point: this measures how close the detector comes, not a fixed pairing)
FACE_LABELS = [label for label in POINT_LABELS if any(k in label for k in ("eye", "nose", "mouth", "lip", "chin"))]


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
    print(describe_load(machine_load()))


if __name__ == "__main__":
    main()
