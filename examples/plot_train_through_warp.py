"""
Training a network through the fluid warp
=========================================

:class:`~torchfluidwarp.warp.layer.FluidWarp` is an ordinary differentiable layer, so a network can learn to
*steer* the fluid. Here a tiny CNN looks at an image of a blob and predicts a coarse force field (the shape
of a :class:`~torchfluidwarp.warp.forces.ControlGrid`: ``(T, 2, K_y, K_x)`` per image); the fluid warps the image
with those forces; and the loss compares the warped image with the blob moved to the centre. The gradient
flows from the loss through the image sampling, the backward maps and the fluid solver (implicit adjoints)
into the CNN's weights: nothing here is specific to the task but the data.

The data are made in the script: Gaussian blobs at random positions, each to be moved to the centre.
"""

# %%
# Data: blobs that must move to the centre
# ----------------------------------------
import os
import time

import matplotlib.pyplot as plt
import torch
import torch.nn.functional as F
from torch import nn

from torchfluidwarp.warp import FluidWarp

SIZE, GRID, STEPS, CONTROL = 32, 16, 4, (4, 4)
ITERATIONS = int(os.environ.get("TORCHFLUIDWARP_EXAMPLE_ITERATIONS", "100"))  # the test suite runs fewer
torch.manual_seed(0)  # the network's initial weights
gen = torch.Generator().manual_seed(0)  # the data
yy, xx = torch.meshgrid(torch.arange(SIZE, dtype=torch.float32), torch.arange(SIZE, dtype=torch.float32), indexing="ij")


def blobs(centres: torch.Tensor, sigma: float = 3.0) -> torch.Tensor:
    """Images ``(B, 1, SIZE, SIZE)`` of one Gaussian blob each, centred at ``centres`` ``(B, 2)`` pixels."""
    d2 = (xx - centres[:, 0, None, None]) ** 2 + (yy - centres[:, 1, None, None]) ** 2
    return torch.exp(-d2 / (2 * sigma**2)).unsqueeze(1)


def batch(n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Blobs anywhere in the middle of the image, and the same blobs at the centre."""
    centres = 9.0 + 13.0 * torch.rand(n, 2, generator=gen)
    return blobs(centres), blobs(torch.full((n, 2), (SIZE - 1) / 2))


# %%
# The model: a CNN that outputs forces, and the fluid layer
# ---------------------------------------------------------
# Two coordinate channels let the convolutions know where they are (the push depends on where the blob is
# relative to the centre). The head gives ``T x 2`` force maps on a ``4 x 4`` control grid; they are
# upsampled to the fluid grid bicubically, corners on corners, as ``ControlGrid`` does (cells per time^2).
class ForceNet(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(3, 16, 3, padding=1),
            nn.GELU(),
            nn.MaxPool2d(2),
            nn.Conv2d(16, 32, 3, padding=1),
            nn.GELU(),
            nn.MaxPool2d(2),
            nn.Conv2d(32, 32, 3, padding=1),
            nn.GELU(),
            nn.AdaptiveAvgPool2d(CONTROL),
            nn.Conv2d(32, STEPS * 2, 1),
        )
        coords = torch.stack([xx, yy]) / (SIZE - 1) * 2 - 1
        self.register_buffer("coords", coords[None])

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        x = torch.cat([image, self.coords.expand(image.shape[0], -1, -1, -1)], dim=1)
        coarse = 0.1 * self.body(x)  # (B, T * 2, K_y, K_x)
        fine = F.interpolate(coarse, size=(GRID, GRID), mode="bicubic", align_corners=True)
        return fine.view(-1, STEPS, 2, GRID, GRID)  # (B, T, 2, h, w) forces


net = ForceNet()
warp = FluidWarp(grid=GRID, steps=STEPS)


def moved(image: torch.Tensor) -> torch.Tensor:
    """The last frame of the fluid warp driven by the network's forces."""
    return warp(image, net(image))[:, -1]


# %%
# Training end to end
# -------------------
# Adam on the mean squared error between the warped image and the target. The fluid layer has no trainable
# parameters; all of the learning is in the CNN.
optimizer = torch.optim.Adam(net.parameters(), lr=5e-3)
test_in, test_target = batch(64)
with torch.no_grad():
    start_loss = float(F.mse_loss(test_in, test_target))
losses = []
start = time.perf_counter()
for it in range(ITERATIONS):
    images, targets = batch(12)
    loss = F.mse_loss(moved(images), targets)
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    losses.append(float(loss.detach()))
    if it % 20 == 0 or it == ITERATIONS - 1:
        print(f"iteration {it:4d}: loss {losses[-1]:.5f}")
with torch.no_grad():
    test_loss = float(F.mse_loss(moved(test_in), test_target))
print(f"{ITERATIONS} iterations in {time.perf_counter() - start:.1f} s")
print(f"held-out loss: {start_loss:.5f} unwarped -> {test_loss:.5f} warped ({test_loss / start_loss:.1%})")

# %%
# The loss falls, and blobs move towards the centre
# -------------------------------------------------
with torch.no_grad():
    shown = moved(test_in[:4])
fig = plt.figure(figsize=(10, 5.2), layout="constrained")
left, right = fig.subfigures(1, 2, width_ratios=[1, 1.3])
ax = left.subplots()
ax.plot(losses, lw=1, label="training batch")
ax.axhline(start_loss, color="gray", ls="--", lw=1, label="no warp")
ax.set_xlabel("iteration")
ax.set_ylabel("MSE to the centred blob")
ax.set_yscale("log")
ax.legend()
axes = right.subplots(3, 4)
for j in range(4):
    for i, (img, name) in enumerate([(test_in, "input"), (shown, "warped"), (test_target, "target")]):
        axes[i, j].imshow(img[j, 0].numpy(), cmap="magma", vmin=0, vmax=1)
        axes[i, j].set_axis_off()
        if j == 0:
            axes[i, j].set_title(name, fontsize=9, loc="left")
plt.show()
