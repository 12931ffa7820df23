"""
Advecting texture coordinates, not pixels
=========================================

Stable Fluids moves a quantity with *semi-Lagrangian advection*: every sample is traced back along the
velocity and the quantity is read there by bilinear interpolation. Applied to the pixel values step after
step, every step averages neighbouring pixels once more, and after a few dozen steps the photo is blurred.

torchfluidwarp advects the image's *texture coordinates* instead: a backward map ``g_t`` that says, for each
output pixel, where to read in the original. The map is smooth, so resampling it costs nothing visible, and
the image is sampled **once** per frame, from the original (see :doc:`/concepts/texture-coordinates`).

This example stirs a photo for 50 steps and compares the two.
"""

# %%
# A stirred photo
# ---------------
# Two oscillating Gaussian brushes, a quarter period apart, stir a slightly viscous 64 x 64 fluid over a
# 256 x 256 photo. Positions and radii are in the photo's pixels, amplitudes in pixels per time unit squared,
# viscosity in fluid cells squared per time unit.
import matplotlib.pyplot as plt
import torch
import torch.nn.functional as F

from torchfluidwarp.data import load_sample
from torchfluidwarp.io import write_animation
from torchfluidwarp.warp import Brushes, FluidWarp, backward_maps, warp_image

photo = F.interpolate(load_sample("astronaut"), size=(256, 256), mode="area")  # (1, 3, 256, 256)
size = (256, 256)
steps = 50
brushes = Brushes(
    centers=[[118.0, 75.0], [118.0, 75.0]],
    directions=[[1.0, 0.0], [0.0, 1.0]],
    radius=35.0,
    amplitude=0.4,
    frequency=0.04,
    phase=[0.0, 1.5708],  # a quarter period apart: the push turns in a circle
)
warp = FluidWarp(grid=(64, 64), steps=steps, viscosity=0.5, image_size=size)
with torch.no_grad():  # nothing is fitted here: no autograd graph needed
    velocities = warp.rollout(brushes).velocities  # (1, 50, 2, 65, 65) staggered, fluid cells per time unit

# %%
# Advecting the pixels
# --------------------
# Each step's own backward map (``x - dt v(x)``, traced back at the image's resolution) resamples the
# *previous frame*: 50 bilinear resamplings in a row.
advected_pixels = photo
for t in range(steps):
    one_step = backward_maps(velocities[:, t : t + 1], size)[:, 1]  # (1, H, W, 2), pixels
    advected_pixels = warp_image(advected_pixels, one_step)

# %%
# Advecting the coordinates
# -------------------------
# The maps are advected instead (``g_{t+1}(x) = g_t(x - dt v_t(x))``) and the original photo is sampled once
# through the last one. This is what :class:`~torchfluidwarp.warp.layer.FluidWarp` does for every frame.
maps = backward_maps(velocities, size)  # (1, 51, H, W, 2)
advected_coords = warp_image(photo, maps[:, -1])
shift = (maps[:, -1] - maps[:, 0]).norm(dim=-1)  # (1, H, W): how far each output pixel reads from home
print(f"largest displacement after {steps} steps: {float(shift.max()):.1f} px")


def sharpness(image: torch.Tensor) -> float:
    """Mean absolute difference between horizontal neighbours: falls as an image blurs."""
    return float((image[..., 1:] - image[..., :-1]).abs().mean())


print(f"sharpness of the photo:              {sharpness(photo):.4f}")
print(f"after 50 steps, advecting pixels:    {sharpness(advected_pixels):.4f}")
print(f"after 50 steps, advecting the map:   {sharpness(advected_coords):.4f}")
print(f"mean difference between the two:     {float((advected_pixels - advected_coords).abs().mean()):.4f}")

# %%
# Side by side
# ------------
# Same flow, same 50 steps. The bottom row zooms into the face. The right column differs from the photo
# only by where its pixels come from.
crop = (slice(15, 135), slice(58, 178))
panels = [
    ("the photo", photo),
    (f"advecting pixels (sharpness {sharpness(advected_pixels):.3f})", advected_pixels),
    (f"advecting coordinates (sharpness {sharpness(advected_coords):.3f})", advected_coords),
]
fig, axes = plt.subplots(2, 3, figsize=(10.5, 7.2), layout="constrained")
for col, (title, image) in enumerate(panels):
    rgb = image[0].permute(1, 2, 0).clamp(0, 1).numpy()
    axes[0, col].imshow(rgb)
    axes[0, col].set_title(title, fontsize=10)
    axes[1, col].imshow(rgb[crop])
for ax in axes.flat:
    ax.set_axis_off()
fig.suptitle("50 steps of the same fluid on a 256 x 256 photo (64 x 64 fluid)")
plt.show()

# %%
# The animation
# -------------
# Every second frame of the coordinate-advected warp, written with :func:`torchfluidwarp.io.write_animation`
# (the documentation shows the GIFs that examples write).
frames = torch.cat([warp_image(photo, maps[:, t]) for t in range(0, steps + 1, 2)])  # (26, 3, H, W)
write_animation("stirred_photo.gif", frames, fps=12, overwrite=True)
