"""
Incompressibility: a fluid warp never folds
===========================================

The fluid is incompressible: after every step its velocity is projected onto divergence-free fields, so the
flow preserves area. A warp made of such steps has a Jacobian determinant of (nearly) 1 everywhere. It can
stretch and shear a region but never squash it to nothing, and it never folds the image over itself.

A thin-plate spline (TPS) fitted to the same point pairs interpolates the displacements without any such
constraint. When the targets twist far from the sources, it compresses some regions, expands others, and
can fold (determinant ``<= 0``).

Both warps below move the same 16 points: an inner ring of 8 is turned by 100 degrees, an outer ring of 8
stays put.
"""

# %%
# The point pairs
# ---------------
import math

import matplotlib.pyplot as plt
import torch
from kornia.geometry.transform import get_tps_transform, warp_points_tps
from matplotlib.colors import TwoSlopeNorm

from torchfluidwarp.control import fit_keyframes
from torchfluidwarp.warp import identity_map, jacobian_determinant, warp_image

H = W = 128
size = (H, W)
centre = torch.tensor([63.5, 63.5])


def ring(radius: float, count: int, turn: float = 0.0) -> torch.Tensor:
    angles = torch.arange(count, dtype=torch.float64) * (2 * math.pi / count) + turn
    return centre + radius * torch.stack([angles.cos(), angles.sin()], dim=-1)  # (count, 2) pixels


turn = math.radians(100)
source = torch.cat([ring(22.0, 8), ring(50.0, 8)])  # (16, 2) pixels (x, y)
target = torch.cat([ring(22.0, 8, turn), ring(50.0, 8)])

# %%
# The fluid warp
# --------------
# :func:`~torchfluidwarp.control.keyframes.fit_keyframes` finds forces that carry each source point to its target in 10
# fluid steps; the fitted warp's last backward map says where each output pixel reads in the source.
fit = fit_keyframes(
    source,
    target,
    image_size=size,
    grid=(32, 32),
    steps=10,
    control=(5, 5),
    regularization=1.0,
    tolerance=0.1,
    progress=False,
)
print(fit.message)
with torch.no_grad():
    fluid_map = fit.warp.maps(fit.forces)[:, -1].float()  # (1, H, W, 2), pixels

# %%
# The thin-plate spline
# ---------------------
# kornia's TPS works in normalised coordinates and, like every backward warp, maps output positions to
# source positions: it is fitted from the targets to the sources (``get_tps_transform(targets, sources)``; in
# kornia's convention the kernels then sit at the second argument). ``warp_points_tps`` evaluates it at every
# pixel centre; it is what ``warp_image_tps`` does before sampling, and keeping the map lets both warps be
# sampled and measured the same way.
pixels = identity_map(size).reshape(1, -1, 2).double()  # (1, H * W, 2)
scale = torch.tensor([2.0 / W, 2.0 / H], dtype=torch.float64)


def normalise(p: torch.Tensor) -> torch.Tensor:  # pixels -> [-1, 1], align_corners=False
    return (p + 0.5) * scale - 1


kernel_weights, affine_weights = get_tps_transform(normalise(target)[None], normalise(source)[None])
tps_norm = warp_points_tps(normalise(pixels), normalise(source)[None], kernel_weights, affine_weights)
tps_map = ((tps_norm + 1) / scale - 0.5).reshape(1, H, W, 2).float()  # back to pixels

# %%
# Jacobian determinants
# ---------------------
# :func:`~torchfluidwarp.warp.frames.jacobian_determinant` by central differences. A backward map's determinant is the
# inverse of the area change: above 1 where the warp squeezes the source, below 1 where it spreads it, and
# ``<= 0`` where it folds.
dets = {"fluid warp": jacobian_determinant(fluid_map)[0], "thin-plate spline": jacobian_determinant(tps_map)[0]}
for name, det in dets.items():
    print(
        f"{name:18s} det in [{float(det.min()):.3f}, {float(det.max()):.3f}], "
        f"within 5% of 1: {float(((det - 1).abs() < 0.05).float().mean()):.1%}, "
        f"folded: {float((det <= 0).float().mean()):.2%}"
    )

# %%
# Side by side
# ------------
# A checkerboard warped by each map, and each map's determinant (colour bar centred at 1, black contour at 0).
yy, xx = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
checker = (((xx // 8) + (yy // 8)) % 2).float()
checker = torch.stack([0.25 + 0.6 * checker, 0.35 + 0.4 * checker, 0.9 - 0.5 * checker])[None]  # (1, 3, H, W)
maps = {"fluid warp": fluid_map, "thin-plate spline": tps_map}
dot = dict(s=14, edgecolors="k", linewidths=0.5)
norm = TwoSlopeNorm(vmin=-1.0, vcenter=1.0, vmax=3.0)
fig, axes = plt.subplots(2, 2, figsize=(9, 9.2), layout="constrained")
for col, name in enumerate(maps):
    warped = warp_image(checker, maps[name])[0].permute(1, 2, 0).clamp(0, 1)
    det = dets[name]
    axes[0, col].imshow(warped.numpy())
    axes[0, col].scatter(*source.T, c="white", **dot, label="sources")
    axes[0, col].scatter(*target.T, c="tab:red", marker="X", s=40, edgecolors="k", linewidths=0.5, label="targets")
    axes[0, col].set_title(name)
    im = axes[1, col].imshow(det.numpy(), cmap="RdBu_r", norm=norm)
    if float(det.min()) <= 0:
        axes[1, col].contour(det.numpy(), levels=[0.0], colors="k", linewidths=1.2)
    axes[1, col].set_title(
        f"det in [{float(det.min()):.2f}, {float(det.max()):.2f}], folded {float((det <= 0).float().mean()):.1%}",
        fontsize=10,
    )
for ax in axes.flat:
    ax.set_axis_off()
axes[0, 0].legend(loc="lower left", fontsize=8)
fig.colorbar(im, ax=axes[1, :], shrink=0.8, label="Jacobian determinant of the backward map")
plt.show()
