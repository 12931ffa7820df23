"""
Morphing without point files: features and faces
================================================

``morph(image_a, image_b)`` with no points finds them itself (:func:`torchfluidwarp.correspond.auto_points`),
as ``torchfluidwarp morph a.jpg b.jpg -o out.gif`` does:

* ``match="features"``: SIFT features matched both ways, checked by RANSAC (kornia; nothing downloaded);
* ``match="faces"``: 63 face landmarks (mediapipe's bundled face mesh, the ``faces`` extra);
* ``match="pixels"``: a lattice of points placed by a flow fitted to the pixels;
* ``match="auto"`` (default): faces when both pictures show one, features otherwise, the pixels where fewer than 8
  features match.

Border points (the corners and edge midpoints) are added so that the picture's frame stays put. Here image B is
the bundled astronaut under a known mild map (a 4 degree turn, 5% smaller, a small shift), so the points found
can be checked against where the map sends them.
"""

# %%
# A copy of the astronaut under a known map
# -----------------------------------------
import math

import matplotlib.pyplot as plt
import torch
import torch.nn.functional as F

from torchfluidwarp.correspond import auto_points
from torchfluidwarp.data import load_sample
from torchfluidwarp.io import resize_image
from torchfluidwarp.morph import Matching, NaturalSettings, morph

S = 160
a = resize_image(load_sample("astronaut"), (S, S))[0]
angle, scale, shift = math.radians(4.0), 0.95, torch.tensor([4.0, -3.0])
centre = torch.tensor([(S - 1) / 2, (S - 1) / 2])
m = scale * torch.tensor([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])


def known_map(points: torch.Tensor) -> torch.Tensor:
    """Where the map sends A's pixels ``(x, y)``: a turn and a shrink about the centre, then a shift."""
    return (points - centre) @ m.T + centre + shift


ys, xs = torch.meshgrid(torch.arange(S, dtype=torch.float32), torch.arange(S, dtype=torch.float32), indexing="ij")
source = (torch.stack([xs, ys], -1) - centre - shift) @ torch.linalg.inv(m).T + centre  # B's pixel reads A here
grid = (source + 0.5) / S * 2 - 1  # grid_sample's coordinates (align_corners=False)
b = F.grid_sample(a[None], grid[None], padding_mode="border", align_corners=False)[0]

# %%
# Features
# --------
pa, pb = auto_points(a, b, match="features")
inner = ((pa > 8) & (pa < S - 9)).all(1)  # the matches, not the border points
error = (known_map(pa[inner]) - pb[inner]).norm(dim=1)
print(f"{int(inner.sum())} feature matches, median error against the known map {float(error.median()):.2f} px")

fast = NaturalSettings(grid=24, steps=6, max_iter=15)
result = morph(a, b, settings=fast, frames=3, match=Matching("features"), progress=False)
print(f"the morph reaches B's points to {float(result.error.mean()):.2f} px on average")

fig, axes = plt.subplots(1, 3, figsize=(9, 3.2))
for ax, picture, points, title in ((axes[0], a, pa, "A"), (axes[2], b, pb, "B")):
    ax.imshow(picture.permute(1, 2, 0))
    ax.scatter(*points.T, s=5, c="yellow")
    ax.set_title(f"{title}: {len(points)} points", fontsize=9)
axes[1].imshow(result.frame(0.5).permute(1, 2, 0).clamp(0, 1))
axes[1].set_title("middle frame", fontsize=9)
for ax in axes:
    ax.axis("off")
fig.tight_layout()

# %%
# Faces
# -----
# With the faces extra installed, ``match="faces"`` places 63 landmarks on each face: eyebrows, eyes, nose,
# lips and the face's outline.
fa, fb = auto_points(a, b, match="faces")
face = ((fa > 8) & (fa < S - 9)).all(1)
error = (known_map(fa[face]) - fb[face]).norm(dim=1)
print(f"{int(face.sum())} face landmarks, median error against the known map {float(error.median()):.2f} px")
fig, axes = plt.subplots(1, 2, figsize=(6, 3.2))
for ax, picture, points, title in ((axes[0], a, fa, "A"), (axes[1], b, fb, "B")):
    ax.imshow(picture.permute(1, 2, 0))
    ax.scatter(*points.T, s=4, c="cyan")
    ax.set_title(f"{title}: face landmarks and border points", fontsize=9)
    ax.axis("off")
fig.tight_layout()
plt.show()
