"""
Morphing through several images, and the average of several
============================================================

:func:`~torchfluidwarp.morph.morph_sequence` chains two-image morphs ``0 -> 1 -> 2`` into one animation. The
frames are shared out in proportion to how far the points travel in each segment, so the points keep one speed
through every middle image, and each middle image appears exactly. :func:`~torchfluidwarp.morph.average` warps
every image to the mean shape of all the point sets, each by its own fold-free flow, and averages the results.

The images here are the bundled astronaut and cat at 128 x 128 and a zoomed crop of the astronaut (its points
moved by the same crop), with their 23 corresponding points.
"""

# %%
# Three images with the same 23 points
# ------------------------------------
import matplotlib.pyplot as plt
import torch

from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import resize_image
from torchfluidwarp.morph import NaturalSettings, average, morph_sequence

S = 128


def scaled(name: str) -> tuple[torch.Tensor, torch.Tensor]:
    """A bundled sample at S x S and its points (pixel centres at integers: x' = (x + 0.5) s - 0.5)."""
    return resize_image(load_sample(name), (S, S))[0], (load_sample_points(name) + 0.5) * (S / 512) - 0.5


def zoomed(image: torch.Tensor, points: torch.Tensor, box: tuple[int, int, int, int]):
    """The crop ``box = (x0, y0, x1, y1)`` of ``image`` resized back to S x S, and ``points`` moved with it."""
    x0, y0, x1, y1 = box
    crop = resize_image(image[None, :, y0:y1, x0:x1], (S, S))[0]
    scale = torch.tensor([S / (x1 - x0), S / (y1 - y0)])
    return crop, (points - torch.tensor([x0, y0]) + 0.5) * scale - 0.5


astronaut, cat = scaled("astronaut"), scaled("cat")
closer = zoomed(*astronaut, (6, 4, 118, 116))
images, points = [astronaut[0], cat[0], closer[0]], [astronaut[1], cat[1], closer[1]]

fast = NaturalSettings(grid=24, steps=6, max_iter=15)
sequence = morph_sequence(images, points, settings=fast, frames=9, progress=False)
frames = sequence.frames
print(f"{len(sequence)} frames, per segment {sequence.counts} (the joints shared)")

# %%
# The sequence
# ------------
# Each middle image appears exactly: the frame at the joint is the cat itself.
joint = sequence.counts[0] - 1
print(f"largest difference between the joint frame and the cat: {float((frames[joint] - images[1]).abs().max()):.2e}")
fig, axes = plt.subplots(1, len(frames), figsize=(1.6 * len(frames), 1.9))
for k, (ax, frame) in enumerate(zip(axes, frames)):
    ax.imshow(frame.permute(1, 2, 0).clamp(0, 1))
    ax.set_title("joint" if k == joint else f"{k}", fontsize=8)
    ax.axis("off")
fig.tight_layout()

# %%
# The average of the three images
# -------------------------------
# Each is warped to the mean shape (dots) by its own flow, and the three warps are averaged. ``folded`` is the
# fraction of map pixels that fold: 0 for a fold-free average.
mean = average(images, points, settings=fast)
print(f"mean point error {float(mean.errors.mean()):.2f} px, folded fraction {mean.folded:.1e}")
fig, axes = plt.subplots(1, 4, figsize=(8, 2.3))
for ax, picture, title in zip(axes, [*mean.warped, mean.image], ["astronaut", "cat", "zoomed", "average"]):
    ax.imshow(picture.permute(1, 2, 0).clamp(0, 1))
    ax.set_title(title, fontsize=9)
    ax.axis("off")
axes[-1].scatter(*mean.points.T, s=4, c="yellow")
fig.tight_layout()
plt.show()
