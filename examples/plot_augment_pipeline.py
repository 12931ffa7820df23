"""
Fluid warps as data augmentation in a torchvision pipeline
==========================================================

:class:`torchfluidwarp.RandomFluidWarp <torchfluidwarp.augment.transforms.RandomFluidWarp>` is a torchvision v2
transform: each call pushes an incompressible fluid with a few random Gaussian brushes and moves *everything*
in the sample through the same flow. Images are resampled, masks are resampled by nearest sampling (they stay
binary), keypoints are carried by the flow itself (RK2 particles through the same velocities, not an
approximate inverse), and boxes become the box around their carried outline. Labels pass through. Because the
fluid is incompressible, the warp never tears or folds the image.

(:class:`torchfluidwarp.augment.tensor.FluidWarpAugment` is the same augmentation as a plain ``nn.Module`` over
batches of tensors, one draw per sample, for pipelines without torchvision; ``random_fluid_warp`` is its
one-call form.)
"""

# %%
# A sample: image, mask, boxes, keypoints and a label
# ---------------------------------------------------
# The bundled astronaut photo at 256 x 256 with its face landmarks. Boxes around the eyes and the mouth come
# from the landmarks; the mask is a disc on the face. torchvision's boxes put pixel *edges* at integers and its
# keypoints put pixel *centres* there, like the library; the transform converts between the two.
import time

import matplotlib.pyplot as plt
import torch
import torch.nn.functional as F
from matplotlib.patches import Rectangle
from torchvision import tv_tensors
from torchvision.transforms import v2

from torchfluidwarp import RandomFluidWarp
from torchfluidwarp.data import load_sample, load_sample_points

N = 256
photo = F.interpolate(load_sample("astronaut"), size=(N, N), mode="bilinear", antialias=True, align_corners=False)
points = (load_sample_points("astronaut") + 0.5) * N / 512 - 0.5  # (23, 2) pixel centres at integers


def box_around(idx, pad):
    p = points[idx]
    return [
        float(p[:, 0].min()) - pad,
        float(p[:, 1].min()) - pad,
        float(p[:, 0].max()) + pad + 1,
        float(p[:, 1].max()) + pad + 1,
    ]


yy, xx = torch.meshgrid(torch.arange(N), torch.arange(N), indexing="ij")
nose = points[7]
sample = {
    "image": tv_tensors.Image((photo[0] * 255).round().to(torch.uint8)),
    "mask": tv_tensors.Mask(((xx - nose[0]) ** 2 + (yy - nose[1]) ** 2 < 28.0**2).to(torch.uint8)),
    "boxes": tv_tensors.BoundingBoxes(
        [box_around([0, 1, 2], 4), box_around([3, 4, 5], 4), box_around([10, 11, 12, 13], 4)],
        format="XYXY",
        canvas_size=(N, N),
    ),
    "keypoints": tv_tensors.KeyPoints(points, canvas_size=(N, N)),
    "label": "astronaut",
}

# %%
# The pipeline
# ------------
# A flip, the fluid warp and a dtype conversion: torchvision's own transforms and ours share one
# ``v2.Compose``. Strength is the brushes' peak acceleration in pixels per time unit^2; the settings stay
# within the bound that keeps every warp fold-free (``RandomFluidWarp`` refuses stronger ones).
augment = v2.Compose(
    [
        v2.RandomHorizontalFlip(p=0.5),
        RandomFluidWarp(
            count=(2, 4),
            strength=(0.4, 0.7),
            radius=(24.0, 48.0),
            steps=(6, 8),
            grid=32,
            generator=torch.Generator().manual_seed(3),
        ),
        v2.ToDtype(torch.float32, scale=True),
    ]
)
print(augment)
start = time.perf_counter()
draws = [augment(sample) for _ in range(3)]
print(f"3 draws in {time.perf_counter() - start:.2f} s")
for d in draws:
    kinds = {k: type(v).__name__ for k, v in d.items()}
    print(kinds, "mask values:", d["mask"].unique().tolist(), "canvas:", d["boxes"].canvas_size)


# %%
# Before and after
# ----------------
# Keypoints (dots) stay on the features they mark, the boxes still hold their keypoints, and the mask (the
# shaded outline) moved with the face.
def show(ax, s, title):
    img = s["image"]
    img = img.float() / 255 if img.dtype == torch.uint8 else img
    ax.imshow(img.permute(1, 2, 0).clamp(0, 1).numpy())
    ax.contour(s["mask"].numpy(), levels=[0.5], colors="cyan", linewidths=1.2)
    for x1, y1, x2, y2 in s["boxes"].tolist():
        # pixel edges at integers -> imshow's pixel centres at integers
        ax.add_patch(Rectangle((x1 - 0.5, y1 - 0.5), x2 - x1, y2 - y1, fill=False, ec="yellow", lw=1.3))
    ax.scatter(*s["keypoints"].T, s=9, c="red", edgecolors="white", linewidths=0.4)
    ax.set_title(title, fontsize=10)
    ax.set_axis_off()


fig, axes = plt.subplots(2, 2, figsize=(9, 9), layout="constrained")
show(axes[0, 0], sample, "original")
for ax, d, k in zip(axes.flat[1:], draws, range(1, 4)):
    show(ax, d, f"draw {k}")
plt.show()
