"""
Keyframe control: fitting points and their trajectories
=======================================================

Mark points on a photo and say where each must be at a keyframe;
:func:`~torchfluidwarp.control.keyframes.fit_keyframes` finds the fluid forces that take them there (L-BFGS on the
paper's objective, gradients by the adjoint method). The fit returns the points' whole trajectories and a
warp that replays the forces on the image.

Here eight landmarks of the bundled astronaut photo are moved: the face tilts and one mouth corner rises.
"""

# %%
# Points and targets
# ------------------
# The bundled landmarks are in the 512 x 512 photo's pixels. A 192 x 192 crop around the face keeps the fluid
# busy where the points are; cropping shifts every pixel coordinate by the crop's corner.
import math

import matplotlib.pyplot as plt
import torch

from torchfluidwarp.control import fit_keyframes
from torchfluidwarp.data import POINT_LABELS, load_sample, load_sample_points
from torchfluidwarp.io import write_animation

top, left, size = 10, 128, 192
photo = load_sample("astronaut")[..., top : top + size, left : left + size]  # (1, 3, 192, 192)
landmarks = load_sample_points("astronaut") - torch.tensor([left, top])  # (23, 2) pixels of the crop

# The face tilts by 15 degrees about the nose tip, as a whole, and the right mouth corner rises a further
# 6 pixels: a smirk. Rotating a region is something an incompressible fluid does easily (a vortex); see the
# user guide for what happens when targets ask a region to grow or shrink.
index = [1, 4, 18, 19, 7, 10, 12, 14]  # eyes, brows, nose tip, mouth corners, chin
source = landmarks[index].double()  # (8, 2) pixels (x, y)
angle = torch.tensor(math.radians(15.0), dtype=torch.float64)
rotation = torch.stack([torch.stack([angle.cos(), -angle.sin()]), torch.stack([angle.sin(), angle.cos()])])
pivot = landmarks[7].double()
target = (source - pivot) @ rotation.T + pivot
target[index.index(12), 1] -= 6.0  # the right mouth corner, as seen in the image, goes up (y points down)
for i, p, q in zip(index, source, target):
    print(f"{POINT_LABELS[i]:35s} ({p[0]:6.1f}, {p[1]:6.1f}) -> ({q[0]:6.1f}, {q[1]:6.1f})")

# %%
# The fit
# -------
# A 64 x 64 fluid, 10 steps, and a 5 x 5 control grid per step: the paper's 500 parameters. The fit stops
# once every point is within ``tolerance`` pixels of its target. It starts with quasi-Newton steps, each a
# roll-out without gradients, and runs L-BFGS with adjoint gradients only if those stall.
fit = fit_keyframes(
    source, target, image_size=(size, size), grid=(64, 64), steps=10, control=(5, 5), tolerance=0.05, progress=False
)
print(fit.message)
print(f"{fit.forwards} roll-outs and {fit.evaluations} objective + gradient evaluations in {fit.seconds:.2f} s")

# %%
# Trajectories over the image
# ---------------------------
# ``fit.trajectories`` is ``(B, T + 1, M, 2)``: every point at every step, in pixels. The right panel is the
# last frame of the fitted warp, ``fit.animate(photo)``.
with torch.no_grad():
    frames = fit.animate(photo)[0]  # (T + 1, 3, H, W)
paths = fit.trajectories[0].detach()  # (T + 1, M, 2)

fig, axes = plt.subplots(1, 2, figsize=(11, 6.2), layout="constrained")
for ax, frame, title in [
    (axes[0], frames[0], "source, with the fitted trajectories"),
    (axes[1], frames[-1], f"frame {len(frames) - 1}: the keyframe"),
]:
    ax.imshow(frame.permute(1, 2, 0).clamp(0, 1).numpy())
    ax.set_title(title)
    ax.set_axis_off()
for m in range(paths.shape[1]):
    axes[0].plot(paths[:, m, 0], paths[:, m, 1], ".-", color="yellow", lw=1.5, ms=4)
axes[0].scatter(*source.T, s=30, c="white", edgecolors="k", zorder=3, label="source points")
for ax in axes:
    ax.scatter(*target.T, s=60, c="tab:red", marker="x", zorder=4, label="targets")
axes[1].scatter(
    *fit.points[0].detach().T,
    s=12,
    c="yellow",
    edgecolors="k",
    linewidths=0.4,
    zorder=5,
    label="points carried by the fluid",
)
axes[0].legend(loc="lower left", fontsize=9)
axes[1].legend(loc="lower left", fontsize=9)
plt.show()

# %%
# Replaying the warp
# ------------------
# The fitted forces replay on the photo (or on any image of its size) as an animation.
write_animation("keyframes.gif", frames, fps=8, overwrite=True)
