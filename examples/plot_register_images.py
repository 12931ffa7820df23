"""
Registering two images with the fluid
=====================================

:func:`~torchfluidwarp.control.images.fit_images` finds the fluid forces that warp a source image onto a target:
L-BFGS on an image loss, gradients by the adjoint method, coarse to fine (small fluid grids and downsampled
images first). Its result is a warp like any other: it replays on the image, carries points, and never folds.

**The pair.** No two-frame sequence is bundled with the package, so the pair is made from the bundled
astronaut photo (downsampled to 128 x 128): the target is the photo under a known smooth deformation that is
*not* a fluid flow (a twirl about the face plus a gentle sinusoidal shear), with its brightness and contrast
changed (``0.8 * I + 0.1``). The loss is therefore ``"ncc"`` (1 - normalised cross-correlation), which does
not care about brightness and contrast. Because the deformation is known, the bundled face landmarks give a
ground truth: where each landmark truly went.
"""

# %%
# A pair with a known deformation
# -------------------------------
import math

import matplotlib.pyplot as plt
import torch
import torch.nn.functional as F

from torchfluidwarp.control import fit_images
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.warp import identity_map, warp_image

N = 128
photo = F.interpolate(
    load_sample("astronaut"), size=(N, N), mode="bilinear", antialias=True, align_corners=False
).double()  # (1, 3, N, N)
landmarks = ((load_sample_points("astronaut") + 0.5) * N / 512 - 0.5).double()  # (23, 2) pixels of the N-image


def true_backward(p: torch.Tensor) -> torch.Tensor:
    """Where the target at ``p`` ``(..., 2)`` reads the source: a twirl about the face and a shear (pixels)."""
    c = torch.tensor([66.0, 44.0], dtype=p.dtype)
    d = p - c
    angle = math.radians(18.0) * torch.exp(-(d**2).sum(-1) / (2 * 22.0**2))
    rot = torch.stack(
        [d[..., 0] * angle.cos() - d[..., 1] * angle.sin(), d[..., 0] * angle.sin() + d[..., 1] * angle.cos()], -1
    )
    shear = 2.0 * torch.stack([torch.sin(2 * math.pi * p[..., 1] / N), torch.sin(2 * math.pi * p[..., 0] / N)], -1)
    return c + rot + shear


def true_forward(q: torch.Tensor, iterations: int = 50) -> torch.Tensor:
    """Where a source point ``q`` went: solve ``true_backward(p) = q`` by fixed-point iteration."""
    p = q.clone()
    for _ in range(iterations):
        p = p - (true_backward(p) - q)
    return p


target = 0.8 * warp_image(photo, true_backward(identity_map((N, N), dtype=torch.float64))) + 0.1
landmarks_target = true_forward(landmarks)
print(
    f"landmarks move {float((landmarks_target - landmarks).norm(dim=-1).mean()):.2f} px on average "
    f"(at most {float((landmarks_target - landmarks).norm(dim=-1).max()):.2f} px)"
)

# %%
# The fit
# -------
# A 32 x 32 fluid at the finest level, after 8 x 8 and 16 x 16 (on 32 x 32 and 64 x 64 images), 8 steps, and a
# 5 x 5 control grid per step, in the paper's incompressible fluid: a twirl keeps every area.
fit = fit_images(
    photo,
    target,
    loss="ncc",
    compressible=False,
    grid=32,
    levels=(8, 16, 32),
    steps=8,
    control=(5, 5),
    max_iter=(20, 15, 25),
    progress=False,
)
print(fit.message)
for level in fit.levels:
    print(
        f"  {level.grid[0]:2d}x{level.grid[1]:<2d} fluid on {level.image_size[0]:3d}px images: loss "
        f"{level.initial_loss:.4f} -> {level.final_loss:.4f} in {level.evaluations} evaluations, "
        f"{level.seconds:.1f} s"
    )
with torch.no_grad():
    carried = fit.warp.carry_points(landmarks[None], fit.forces, (N, N))[0, -1]
before = (landmarks - landmarks_target).norm(dim=-1)
after = (carried - landmarks_target).norm(dim=-1)
print(
    f"NCC loss {fit.initial_loss:.4f} -> {fit.final_loss:.4f}; min Jacobian determinant "
    f"{float(fit.min_det.min()):.3f}; {fit.seconds:.1f} s"
)
print(
    f"landmark error {float(before.mean()):.2f} px -> {float(after.mean()):.2f} px (mean), "
    f"{float(before.max()):.2f} -> {float(after.max()):.2f} px (max)"
)


# %%
# Source, target, result
# ----------------------
# The difference images compare brightness-matched images (a least-squares gain and offset), since the
# target's brightness was changed on purpose.
def matched_difference(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    x, y = a.flatten(), b.flatten()
    gain = ((x - x.mean()) * (y - y.mean())).sum() / ((x - x.mean()) ** 2).sum()
    return (gain * (a - x.mean()) + y.mean() - b).abs().mean(1)[0]


def show(ax, image, title):
    ax.imshow(image[0].permute(1, 2, 0).clamp(0, 1).numpy())
    ax.set_title(title, fontsize=10)
    ax.set_axis_off()


fig, axes = plt.subplots(2, 3, figsize=(11, 7.6), layout="constrained")
show(axes[0, 0], photo, "source")
show(axes[0, 1], target, "target (deformed, 0.8 I + 0.1)")
show(axes[0, 2], fit.warped.detach(), "source warped by the fitted fluid")
axes[0, 1].scatter(*landmarks_target.T, s=14, c="tab:red", marker="x", label="true landmarks")
axes[0, 2].scatter(*landmarks_target.T, s=14, c="tab:red", marker="x", label="true landmarks")
axes[0, 2].scatter(*carried.T, s=10, c="yellow", edgecolors="k", linewidths=0.3, label="carried by the fit")
axes[0, 2].legend(loc="lower left", fontsize=8)
vmax = float(matched_difference(photo, target).max())
for ax, diff, title in [
    (axes[1, 0], matched_difference(photo, target), "|source - target| (matched)"),
    (axes[1, 1], matched_difference(fit.warped.detach(), target), "|warped - target| (matched)"),
]:
    ax.imshow(diff.numpy(), cmap="magma", vmin=0, vmax=vmax)
    ax.set_title(title, fontsize=10)
    ax.set_axis_off()
ax = axes[1, 2]
ax.plot(fit.loss_history, lw=1)
ends = [sum(lv.evaluations for lv in fit.levels[: i + 1]) for i in range(len(fit.levels))]
for e in ends[:-1]:
    ax.axvline(e, color="gray", lw=0.8, ls="--")
ax.set_yscale("log")
ax.set_xlabel("evaluation (dashed: next level)")
ax.set_ylabel("1 - NCC at that level")
plt.show()
