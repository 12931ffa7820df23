"""
A quality report for a morph
============================

:func:`torchfluidwarp.metrics.morph_report` measures a morph in one pass over its frames, and is what
``torchfluidwarp morph ... --report report.json`` writes:

* folded pixels per frame, of A's and of B's maps (0 for a fold-free morph);
* the landmark error at the last frame, and of held-out points: corresponding points that were *not* given
  to the morph, a fairer test of the flow between the marks;
* ghosting in the middle frame: how far apart A's and B's copies of each point land there;
* the seam figure of a region morph;
* path smoothness: the distance between neighbouring frames, its total and its variance (a perceptual-path-
  length-style measure with no downloaded network): an even morph changes by the same amount every frame.

Here the astronaut morphs into the cat with 18 of its 23 points; the other 5 are held out.
"""

# %%
# The morph and its report
# ------------------------
import json

import matplotlib.pyplot as plt

from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import resize_image
from torchfluidwarp.metrics import morph_report
from torchfluidwarp.morph import NaturalSettings, Timing, morph

S = 128
a, b = (resize_image(load_sample(name), (S, S))[0] for name in ("astronaut", "cat"))
pa, pb = ((load_sample_points(name) + 0.5) * (S / 512) - 0.5 for name in ("astronaut", "cat"))
given, held = slice(0, 18), slice(18, None)

reports = {}
for motion in ("linear", "smooth"):
    result = morph(
        a, b, pa[given], pb[given], settings=NaturalSettings(grid=24, steps=6, max_iter=15), frames=9,
        timing=Timing(motion=motion), progress=False,
    )  # fmt: skip
    reports[motion] = morph_report(result, a, b, pa[given], pb[given], held_out=(pa[held], pb[held]))

report = reports["linear"]
print(json.dumps({key: report[key] for key in ("frames", "mid_frame", "folds", "seam")}))  # a part of the JSON
for motion, r in reports.items():
    print(
        f"{motion:>6}: end error {r['landmark_error_px']['mean']:.2f} px, held-out end error "
        f"{r['held_out']['end']['mean']:.2f} px, middle-frame ghosting {r['marked']['ghost']['mean']:.2f} px, "
        f"folded {r['folds']['total']} px, path total {r['path']['total']:.3f}, variance {r['path']['variance']:.2e}"
    )

# %%
# Path smoothness
# ---------------
# The distance between neighbouring frames: ``motion="linear"`` moves the points at one speed, so the frames
# change by similar amounts; ``"smooth"`` eases in and out, so the change is small at the ends and larger in
# the middle (a larger variance for the same path).
fig, ax = plt.subplots(figsize=(4.5, 3))
for motion, r in reports.items():
    ax.plot(range(1, len(r["path"]["distances"]) + 1), r["path"]["distances"], "o-", label=motion)
ax.set_xlabel("frame pair k-1, k")
ax.set_ylabel(f"{report['path']['kind']} distance")
ax.legend()
fig.tight_layout()
plt.show()
