"""
A breathing cat
===============

The frog's throat of the paper, re-made on the bundled cat: the cat's muzzle swells and relaxes like a slow
breath while its eyes stay still.

An incompressible fluid cannot inflate a region: a purely radial push is a pressure gradient, and the pressure
projection removes it. So the "breath" is a strain: two brushes beside the nose push outwards while two above
and below it push inwards, and all four oscillate together. The muzzle widens as it flattens, then returns.
A viscosity bump on each eye makes the fluid there nearly rigid, so the eyes are carried along without
deforming.
"""

# %%
# The image, its landmarks and the brushes
# ----------------------------------------
# The 512 x 512 sample is halved to 256 x 256 (smaller GIF, faster render); its landmarks follow, keeping
# the pixel-centre convention (``(x, y)``, pixel centres at integers). Landmarks 1 and 4 are the eye centres
# and 7 the nose tip (see ``torchfluidwarp.data.POINT_LABELS``). Positions and radii below are pixels of the
# halved image.
import math

import torch
import torch.nn.functional as F

from torchfluidwarp import CGConfig
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import write_animation
from torchfluidwarp.warp import Brushes, FluidWarp, ViscosityBrushes

scale = 0.5
image = F.interpolate(load_sample("cat"), scale_factor=scale, mode="bilinear", antialias=True)  # (1, 3, 256, 256)
points = (load_sample_points("cat") + 0.5) * scale - 0.5  # (23, 2) pixels
eyes, nose = points[[1, 4]], points[7]

steps = 48  # 49 frames: two breaths at 20 frames per second
centre = nose + torch.tensor([0.0, -2.5])  # the middle of the muzzle
offsets = torch.tensor([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])  # right, left, below, above
outwards = torch.tensor([1.0, 1.0, -1.0, -1.0])  # sideways out, vertically in: area is conserved
forces = Brushes(
    centers=centre + 25.0 * offsets,
    directions=offsets * outwards[:, None],
    radius=12.5,  # pixels
    amplitude=0.4,  # pixels per time unit^2: about amplitude / (2 pi f)^2 = 6 px of swing
    frequency=2 / steps,  # cycles per time unit
    # A cosine push starts the velocity as a sine, which averages to zero, so the muzzle comes back instead
    # of creeping away (a sine push would add a steady drift).
    phase=math.pi / 2,
)

# %%
# The eyes: a viscosity bump (fluid cells^2 per time unit) on each, over a little background viscosity that
# damps the flow between breaths. The variable viscosity is solved by conjugate gradients; a loose tolerance
# is plenty for pictures.
viscosity = ViscosityBrushes(centers=eyes, radius=22.0, value=5.0, base=0.5)
warp = FluidWarp(grid=(64, 64), steps=steps, dt=1.0, viscosity=viscosity, diffusion=CGConfig(rtol=1e-3))

# %%
# Render the frames one at a time and write the GIF
# -------------------------------------------------
with torch.no_grad():
    frames = torch.cat(list(warp.iter_frames(image, forces)))  # (steps + 1, 3, 256, 256)
path = write_animation("animate_breathing.gif", frames, fps=20, overwrite=True)
print(f"wrote {path} ({frames.shape[0]} frames)")

# %%
# A few frames: rest, breathing out, rest, breathing out again
# ------------------------------------------------------------
try:
    import matplotlib.pyplot as plt
except ImportError:  # the GIF is the result; the figure is for the gallery
    plt = None

if plt is not None:
    shown = [0, steps // 8, steps // 4, 3 * steps // 8]
    fig, axes = plt.subplots(1, len(shown), figsize=(3 * len(shown), 3.2))
    for ax, t in zip(axes, shown):
        ax.imshow(frames[t, :, 100:256, 65:221].permute(1, 2, 0).numpy())
        ax.set_title(f"frame {t}")
        ax.axis("off")
    fig.tight_layout()
    plt.show()
