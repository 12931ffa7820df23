"""
A laugh
=======

The paper's laughing face, re-made on the astronaut: four groups of vertical oscillators, on the two mouth
corners and the two cheeks, bounce her smile up and down.

The mouth corners and the cheeks move in opposite phase: when the corners rise the cheeks drop, and the
other way round. The fluid is incompressible, so what goes up somewhere must come down nearby; pushing
neighbours in opposite phase keeps each swirl small and the rest of the face calm. Phases other than 0 and
pi would make the pushes' velocity average to something non-zero, and the face would slowly creep away.
"""

# %%
# Crop the face
# -------------
# As in the nose example: a 256 x 256 square around the face, so the 64 x 64 fluid has 4-pixel cells.
# Landmarks 10 and 12 are the mouth corners, 15 and 16 the cheeks level with the mouth.
import math

import torch

from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import write_animation
from torchfluidwarp.warp import Brushes, FluidWarp, SumForces

x0, y0, size = 96, 0, 256
image = load_sample("astronaut")[:, :, y0 : y0 + size, x0 : x0 + size]  # (1, 3, 256, 256)
points = load_sample_points("astronaut") - torch.tensor([x0, y0], dtype=torch.float32)

# %%
# Four groups of vertical oscillators
# -----------------------------------
# Each group is its own :class:`~torchfluidwarp.warp.forces.Brushes` (one brush each here, but a group can hold
# several), and :class:`~torchfluidwarp.warp.forces.SumForces` adds them up. All push up (``direction (0, -1)``,
# y points down) at ``frequency`` cycles per time unit; a group's phase (radians) sets when.
steps = 40  # 41 frames: four laughs at 20 frames per second
frequency = 4 / steps
groups = {  # name: (landmark, phase)
    "left mouth corner": (10, 0.0),
    "right mouth corner": (12, 0.0),
    "left cheek": (15, math.pi),
    "right cheek": (16, math.pi),
}
forces = SumForces(
    *[
        Brushes(
            centers=points[index][None],  # (1, 2) pixels
            directions=[[0.0, -1.0]],
            radius=12.0,  # pixels
            amplitude=4.5,  # pixels per time unit^2: a swing of a few pixels at this frequency
            frequency=frequency,
            phase=math.pi / 2 + phase,  # a cosine push: the velocity averages to zero
        )
        for index, phase in groups.values()
    ]
)
# A uniform viscosity (cells^2 per time unit) damps the swirls between laughs.
warp = FluidWarp(grid=(64, 64), steps=steps, dt=1.0, viscosity=2.0)

# %%
# Render and write the GIF
# ------------------------
with torch.no_grad():
    frames = torch.cat(list(warp.iter_frames(image, forces)))  # (steps + 1, 3, 256, 256)
path = write_animation("animate_laugh.gif", frames, fps=20, overwrite=True)
print(f"wrote {path} ({frames.shape[0]} frames)")

# %%
# One laugh, frame by frame
# -------------------------
try:
    import matplotlib.pyplot as plt
except ImportError:  # the GIF is the result; the figure is for the gallery
    plt = None

if plt is not None:
    period = round(1 / frequency)
    shown = [0, period // 4, period // 2, 3 * period // 4]
    fig, axes = plt.subplots(1, len(shown), figsize=(3 * len(shown), 3.2))
    for ax, t in zip(axes, shown):
        ax.imshow(frames[t, :, 70:190, 68:188].permute(1, 2, 0).numpy())
        ax.set_title(f"frame {t}")
        ax.axis("off")
    fig.tight_layout()
    plt.show()
