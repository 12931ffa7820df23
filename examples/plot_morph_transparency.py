"""
Transparency: RGBA in, RGBA out
===============================

A morph of two RGBA images warps the alpha channel like the colours: a cut-out object stays cut out on every
frame. :func:`~torchfluidwarp.io.write_animation` keeps the alpha in the formats that can hold it:

* a folder of PNG frames: exactly;
* a GIF: pixels with alpha below 0.5 are transparent (a GIF has one transparent palette index, no partial
  transparency);
* an animated WebP: lossless alpha with lossy colour (its frames are held in memory until written, up to
  :data:`~torchfluidwarp.io.animation.MAX_WEBP_BYTES`).

Here the astronaut and the cat are cut out by soft discs around their faces, morphed, written in the three
formats to a temporary folder, and read back over a checkerboard.
"""

# %%
# Two cut-outs and their morph
# ----------------------------
import tempfile
from pathlib import Path

import imageio.v3 as iio
import matplotlib.pyplot as plt
import numpy as np
import torch
from PIL import Image, ImageSequence

from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import resize_image, write_animation
from torchfluidwarp.morph import NaturalSettings, morph

S = 128
ys, xs = torch.meshgrid(torch.arange(S, dtype=torch.float32), torch.arange(S, dtype=torch.float32), indexing="ij")


def cut_out(name: str, centre: tuple[float, float], radius: float) -> torch.Tensor:
    """The sample at S x S with an alpha that is 1 inside a disc and falls to 0 over 6 pixels."""
    rgb = resize_image(load_sample(name), (S, S))[0]
    alpha = ((radius - ((xs - centre[0]) ** 2 + (ys - centre[1]) ** 2).sqrt()) / 6 + 0.5).clamp(0, 1)
    return torch.cat([rgb, alpha[None]])


a, b = cut_out("astronaut", (56, 34), 30), cut_out("cat", (64, 72), 56)
pa, pb = ((load_sample_points(name)[:14] + 0.5) * (S / 512) - 0.5 for name in ("astronaut", "cat"))
result = morph(a, b, pa, pb, settings=NaturalSettings(grid=24, steps=6, max_iter=15), frames=5, progress=False)
frames = result.frames  # (5, 4, S, S)
print(f"frames {tuple(frames.shape)}; alpha from {float(frames[:, 3].min()):.2f} to {float(frames[:, 3].max()):.2f}")

# %%
# Written as PNG frames, GIF and WebP, read back
# ----------------------------------------------
with tempfile.TemporaryDirectory() as folder:
    png = write_animation(Path(folder) / "frames/", frames)
    back = {"PNG frames": np.stack([iio.imread(p) for p in sorted(png.iterdir())])}
    back["GIF"] = iio.imread(write_animation(Path(folder) / "m.gif", frames), index=None, mode="RGBA")
    with Image.open(write_animation(Path(folder) / "m.webp", frames)) as webp:
        back["WebP"] = np.stack([np.asarray(frame.convert("RGBA")) for frame in ImageSequence.Iterator(webp)])

want = frames.mul(255).round().permute(0, 2, 3, 1).numpy()
for name, got in back.items():
    error = np.abs(got[..., 3].astype(float) - want[..., 3])
    note = " (every pixel 0 or 255, thresholded at 128)" if name == "GIF" else ""
    print(f"{name:>10}: alpha off by at most {error.max():.0f} of 255{note}")

# %%
# Over a checkerboard
# -------------------
checker = ((xs // 8 + ys // 8) % 2 * 0.4 + 0.4).numpy()[..., None]
fig, axes = plt.subplots(3, 5, figsize=(8, 5))
for row, (name, got) in zip(axes, back.items()):
    for ax, frame in zip(row, got):
        rgb, alpha = frame[..., :3] / 255.0, frame[..., 3:] / 255.0
        ax.imshow(alpha * rgb + (1 - alpha) * checker)
        ax.axis("off")
    row[0].set_title(name, fontsize=9, loc="left")
fig.tight_layout()
plt.show()
