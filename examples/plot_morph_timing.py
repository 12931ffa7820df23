"""
Timing a morph: the shape leads the colour
==========================================

A morph has two schedules (:mod:`torchfluidwarp.morph.timing`): ``motion`` for the shape (how far along the
fluid's path each frame is) and ``blend`` for the colour (the cross-dissolve's weight of image B). Each is an
easing name (``"linear"``, ``"smooth"``, ``"ease-in"``, ``"ease-out"``) or a few control points
``[(t, progress), ...]``. With ``timing=Timing(motion="ease-out", blend="ease-in")`` the features arrive before their
colours change, as FantaMorph's separate shape and colour curves do.

``result.frame(t)`` renders any ``t`` in ``[0, 1]``, not only the frames' own times; ``frame(0)`` is image A and
``frame(1)`` image B.
"""

# %%
# Two schedules
# -------------
import matplotlib.pyplot as plt
import torch

from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import resize_image
from torchfluidwarp.morph import NaturalSettings, Timing, morph
from torchfluidwarp.morph.timing import schedule

S = 128
a, b = (resize_image(load_sample(name), (S, S))[0] for name in ("astronaut", "cat"))
pa, pb = ((load_sample_points(name) + 0.5) * (S / 512) - 0.5 for name in ("astronaut", "cat"))
fast = dict(settings=NaturalSettings(grid=24, steps=6, max_iter=15), progress=False)

shape_first = [(0, 0), (0.3, 0.7), (1, 1)]  # 70% of the shape change in the first 30% of the time
settings = {
    "linear": Timing(motion="linear", blend="linear"),
    "shape leads": Timing(motion=shape_first, blend="ease-in"),
}
ts = torch.linspace(0, 1, 101).tolist()
fig, ax = plt.subplots(figsize=(4, 3))
ax.plot(ts, [schedule("motion", shape_first)(t) for t in ts], label="motion (shape): 0:0, 0.3:0.7, 1:1")
ax.plot(ts, [schedule("blend", "ease-in")(t) for t in ts], label="blend (colour): ease-in")
ax.plot(ts, ts, "k:", lw=0.8, label="linear")
ax.set_xlabel("t")
ax.set_ylabel("progress")
ax.legend(fontsize=7)
fig.tight_layout()

# %%
# The frames at t = 0, 0.25, 0.5, 0.75, 1
# ---------------------------------------
# One fit per setting; ``frame(t)`` renders each time on demand. At ``t = 0.25`` the "shape leads" morph
# already has the cat's outline in the astronaut's colours.
times = [0.0, 0.25, 0.5, 0.75, 1.0]
fig, axes = plt.subplots(2, len(times), figsize=(1.8 * len(times), 4))
for row, (name, timing) in zip(axes, settings.items()):
    result = morph(a, b, pa, pb, frames=5, timing=timing, **fast)
    for ax, t in zip(row, times):
        ax.imshow(result.frame(t).permute(1, 2, 0).clamp(0, 1))
        ax.set_title(f"{name}, t={t:g}", fontsize=7)
        ax.axis("off")
    ends = float((result.frame(0.0) - a).abs().max()), float((result.frame(1.0) - b).abs().max())
    print(f"{name}: frame(0) is A to {ends[0]:.1e}, frame(1) is B to {ends[1]:.1e}")
fig.tight_layout()
plt.show()
