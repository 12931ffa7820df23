"""
A wiggling nose
===============

The astronaut's nose and upper lip oscillate diagonally, up-right and back, driven by one oscillating brush.

One brush is enough: the fluid is incompressible, so the push spreads smoothly into a swirl around the nose
and the rest of the face follows it gently instead of being smeared. The fluid carries the image's texture
coordinates, so every frame is sampled from the original photo and never blurs.
"""

# %%
# Crop the face
# -------------
# The face covers a small part of the 512 x 512 portrait, so we keep a 256 x 256 square around it; a 64 x 64
# fluid then has 4-pixel cells. The landmarks move with the crop (``(x, y)`` in pixels, pixel centres at
# integers); 7 is the nose tip and 11 the centre of the upper lip.
import math

import torch

from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import write_animation
from torchfluidwarp.warp import Brushes, FluidWarp

x0, y0, size = 96, 0, 256
image = load_sample("astronaut")[:, :, y0 : y0 + size, x0 : x0 + size]  # (1, 3, 256, 256)
points = load_sample_points("astronaut") - torch.tensor([x0, y0], dtype=torch.float32)

# %%
# One diagonal brush between the nose tip and the upper lip
# ---------------------------------------------------------
steps = 40  # 41 frames: two wiggles at 20 frames per second
forces = Brushes(
    centers=((points[7] + points[11]) / 2)[None],  # (1, 2) pixels
    directions=[[1.0, -1.0]],  # up and to the right (y points down)
    radius=14.0,  # pixels
    amplitude=1.2,  # pixels per time unit^2
    frequency=2 / steps,  # cycles per time unit
    # A cosine push makes a velocity that averages to zero: the nose swings out and back to where it started
    # (a sine push would add a steady drift).
    phase=math.pi / 2,
)
# A little viscosity (cells^2 per time unit) damps the swirl, so each wiggle ends where it began and the GIF
# loops cleanly. A uniform viscosity costs one fast solve per step.
warp = FluidWarp(grid=(64, 64), steps=steps, dt=1.0, viscosity=1.0)

# %%
# Render and write the GIF
# ------------------------
with torch.no_grad():
    frames = torch.cat(list(warp.iter_frames(image, forces)))  # (steps + 1, 3, 256, 256)
path = write_animation("animate_nose.gif", frames, fps=20, overwrite=True)
print(f"wrote {path} ({frames.shape[0]} frames)")

# %%
# A few frames: at rest, swung out, back, swung out again
# --------------------------------------------------------
try:
    import matplotlib.pyplot as plt
except ImportError:  # the GIF is the result; the figure is for the gallery
    plt = None

if plt is not None:
    shown = [0, steps // 8, steps // 4, 3 * steps // 8]
    fig, axes = plt.subplots(1, len(shown), figsize=(3 * len(shown), 3.2))
    for ax, t in zip(axes, shown):
        ax.imshow(frames[t, :, 70:190, 68:188].permute(1, 2, 0).numpy())
        ax.set_title(f"frame {t}")
        ax.axis("off")
    fig.tight_layout()
    plt.show()
