"""
Morphing a region: backgrounds and pasting back into the photo
==============================================================

``morph(..., blending=Blending(region="points"))`` limits the morph to the points' convex hull grown by
``region_margin`` (:func:`~torchfluidwarp.morph.regions.hull_mask`); outside it the frame shows ``background``:
A's (``"a"``), B's (``"b"``) or their cross-dissolve (``"blend"``), mixed over a soft ramp so that no seam shows.
A region can also be a pair of masks ``(mask_a, mask_b)``, one per image.

:func:`~torchfluidwarp.morph.regions.paste_back` puts a morphed frame back into the full-size photograph it was
cut from: morph a small crop around the face, and paste the result into the large picture.
"""

# %%
# The middle frame with each background
# -------------------------------------
import matplotlib.pyplot as plt
import torch

from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import resize_image
from torchfluidwarp.morph import Blending, NaturalSettings, hull_mask, morph, paste_back

S = 128
a, b = (resize_image(load_sample(name), (S, S))[0] for name in ("astronaut", "cat"))
# the 14 points of the eyes, nose and mouth (the others reach the cat's picture edges)
pa, pb = ((load_sample_points(name)[:14] + 0.5) * (S / 512) - 0.5 for name in ("astronaut", "cat"))
fast = dict(settings=NaturalSettings(grid=24, steps=6, max_iter=15), progress=False)

middles = {}
for background in ("a", "b", "blend"):
    blending = Blending(region="points", region_margin=0.1, background=background)
    result = morph(a, b, pa, pb, frames=3, blending=blending, **fast)
    middles[background] = result.frame(0.5)
mask = hull_mask(pa, (S, S), margin=0.1)

fig, axes = plt.subplots(1, 4, figsize=(9, 2.5))
axes[0].imshow(mask, cmap="gray")
axes[0].set_title("A's region", fontsize=9)
for ax, (background, frame) in zip(axes[1:], middles.items()):
    ax.imshow(frame.permute(1, 2, 0).clamp(0, 1))
    ax.set_title(f'background="{background}"', fontsize=9)
for ax in axes:
    ax.axis("off")
fig.tight_layout()

# %%
# Outside the region the frame is the background
# ----------------------------------------------
# The region travels from A's hull to B's with the morph; away from both (outside the hull of all the points,
# grown by the same margin) the middle frame with ``background="a"`` is A, to a few hundredths where the
# ramp of the travelling region reaches past the hulls.
outside = hull_mask(torch.cat([pa, pb]), (S, S), margin=0.1) == 0
difference = float((middles["a"] - a)[:, outside].abs().max())
print(f"background='a': largest difference from A outside the region {difference:.1e}")

# %%
# Paste a morphed crop back into the large photo
# ----------------------------------------------
# The astronaut at 192 x 192; the 96 x 96 box around her face is cut out, morphed towards the cat's face (the
# cat brought to the crop's size), and the middle frame pasted back, faded in over 6 pixels at the box's edge.
# ``paste_back`` of frame 0 gives the photo back.
big = resize_image(load_sample("astronaut"), (192, 192))[0]
box = (48, 8, 144, 104)  # x0, y0, x1, y1 in the large photo's pixels
x0, y0, x1, y1 = box
crop = big[:, y0:y1, x0:x1]
crop_points = (load_sample_points("astronaut") + 0.5) * (192 / 512) - 0.5 - torch.tensor([x0, y0])
keep = ((crop_points >= 0) & (crop_points <= 95)).all(1)  # the points inside the box
cat96 = resize_image(load_sample("cat"), (96, 96))[0]
cat_points = (load_sample_points("cat") + 0.5) * (96 / 512) - 0.5
result = morph(crop, cat96, crop_points[keep], cat_points[keep], frames=3, **fast)
pasted = paste_back(result.frame(0.5), big, box, band=6.0)
again = paste_back(result.frame(0.0), big, box, band=6.0)
print(f"paste_back of frame 0: largest difference from the photo {float((again - big).abs().max()):.1e}")

fig, axes = plt.subplots(1, 2, figsize=(6, 3.2))
for ax, picture, title in zip(axes, (big, pasted), ("photo", "middle frame pasted back")):
    ax.imshow(picture.permute(1, 2, 0).clamp(0, 1))
    ax.set_title(title, fontsize=9)
    ax.axis("off")
axes[1].add_patch(plt.Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, ec="yellow", lw=0.8))
fig.tight_layout()
plt.show()
