"""
Coordinate conventions
======================

One picture of every coordinate system in the library, drawn from the library's own conversions
(:mod:`torchfluidwarp.core.grid`):

* points are ``(x, y)``: x to the right, y **down**; a tensor's last index 0 is x;
* **pixel coordinates** put pixel centres at integers, so an ``H x W`` image covers
  ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``. This is ``align_corners=False``: the image's outer *edges*, not its
  outer pixel centres, sit at -1 and +1 in ``grid_sample``'s normalised coordinates;
* **fluid-cell coordinates** follow the same rule on the ``h x w`` fluid grid, and the fluid covers the same
  rectangle as the image whatever their resolutions;
* the **staggered (MAC) velocity** ``(B, 2, h + 1, w + 1)`` stores ``u`` on vertical faces and ``v`` on
  horizontal faces.
"""

# %%
# A 6 x 4 image and a 3 x 2 fluid
# -------------------------------
import matplotlib.pyplot as plt
import torch

from torchfluidwarp.core import FluidGrid, interior_mask, pixel_to_cell
from torchfluidwarp.warp import identity_map

H, W = 4, 6  # image rows, columns
grid = FluidGrid(height=2, width=3)
h, w = grid.shape

centres = identity_map((H, W))[0].reshape(-1, 2)  # (H * W, 2) pixel centres (x, y), in pixels
probe = torch.tensor([[4.0, 1.0]])  # a pixel centre, in pixels
probe_cells = pixel_to_cell(probe, (H, W), grid)  # the same point in fluid cells
print(f"pixel (x, y) = {probe[0].tolist()}  ->  fluid cell (x, y) = {probe_cells[0].tolist()}")

# which faces of the staggered velocity are free (1) and which are walls or padding (0)
mask = interior_mask(grid)[0]  # (2, h + 1, w + 1)
print("staggered velocity shape:", (1, 2, *grid.staggered_shape))


def to_normalised(x, n):
    """Pixel coordinate -> grid_sample's normalised coordinate with align_corners=False."""
    return (2 * x + 1) / n - 1


def from_normalised(u, n):
    return ((u + 1) * n - 1) / 2


# %%
# The picture
# -----------
fig, (ax_px, ax_cell) = plt.subplots(1, 2, figsize=(12, 5.6), layout="constrained")

# left: pixels, their centres, and grid_sample's normalised coordinates on the top and right axes
for x in range(W + 1):
    ax_px.axvline(x - 0.5, color="0.75", lw=1)
for y in range(H + 1):
    ax_px.axhline(y - 0.5, color="0.75", lw=1)
ax_px.plot(centres[:, 0], centres[:, 1], "o", color="tab:blue", ms=5, label="pixel centres (integers)")
ax_px.plot(*probe[0].tolist(), "*", color="tab:red", ms=14, label=f"the point {tuple(probe[0].tolist())}")
ax_px.annotate("(0, 0)", (0, 0), (0.12, 0.3), color="tab:blue")
ax_px.annotate("corner (-0.5, -0.5)", (-0.5, -0.5), (0.2, -0.2), arrowprops=dict(arrowstyle="->"), fontsize=9)
ax_px.annotate(
    f"corner ({W - 0.5}, {H - 0.5})",
    (W - 0.5, H - 0.5),
    (W - 2.7, H - 1.45),
    arrowprops=dict(arrowstyle="->"),
    fontsize=9,
)
ax_px.set(
    xlim=(-0.5, W - 0.5), ylim=(H - 0.5, -0.5), aspect="equal", title=f"pixels: image[b, c, y, x], H x W = {H} x {W}"
)
ax_px.set_xlabel("x (pixels), to the right")
ax_px.set_ylabel("y (pixels), down")
top = ax_px.secondary_xaxis("top", functions=(lambda x: to_normalised(x, W), lambda u: from_normalised(u, W)))
top.set_ticks([-1, -0.5, 0, 0.5, 1])
top.set_xlabel("normalised x (grid_sample, align_corners=False)")
right = ax_px.secondary_yaxis("right", functions=(lambda y: to_normalised(y, H), lambda u: from_normalised(u, H)))
right.set_ticks([-1, 0, 1])
right.set_ylabel("normalised y")
ax_px.legend(loc="upper left", bbox_to_anchor=(0.0, -0.14), ncols=1, fontsize=9, frameon=False)

# right: the fluid grid over the same rectangle, in fluid cells, with its staggered velocity faces
px_edges_x = pixel_to_cell(torch.stack([torch.arange(W + 1) - 0.5, torch.zeros(W + 1)], -1), (H, W), grid)[:, 0]
px_edges_y = pixel_to_cell(torch.stack([torch.zeros(H + 1), torch.arange(H + 1) - 0.5], -1), (H, W), grid)[:, 1]
for x in px_edges_x:
    ax_cell.axvline(float(x), color="0.7", lw=0.8, ls=":")
for y in px_edges_y:
    ax_cell.axhline(float(y), color="0.7", lw=0.8, ls=":")
for j in range(w + 1):
    ax_cell.axvline(j - 0.5, color="k", lw=3 if j in (0, w) else 1)
for i in range(h + 1):
    ax_cell.axhline(i - 0.5, color="k", lw=3 if i in (0, h) else 1)
cy, cx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
ax_cell.plot(cx.flatten(), cy.flatten(), "s", color="tab:green", ms=7, label="cell centres: pressure, forces")
for i in range(h):  # u = vel[:, 0, i, j] sits at (j - 1/2, i)
    for j in range(w + 1):
        free = bool(mask[0, i, j])
        ax_cell.annotate(
            "",
            (j - 0.5 + 0.22, i),
            (j - 0.5 - 0.22, i),
            arrowprops=dict(arrowstyle="->", lw=2, color="tab:orange" if free else "0.6"),
        )
        ax_cell.text(
            j - 0.5, i + 0.12, f"u[{i},{j}]", ha="center", va="top", fontsize=8, color="tab:orange" if free else "0.5"
        )
for i in range(h + 1):  # v = vel[:, 1, i, j] sits at (j, i - 1/2)
    for j in range(w):
        free = bool(mask[1, i, j])
        ax_cell.annotate(
            "",
            (j, i - 0.5 + 0.22),
            (j, i - 0.5 - 0.22),
            arrowprops=dict(arrowstyle="->", lw=2, color="tab:purple" if free else "0.6"),
        )
        ax_cell.text(
            j + 0.06,
            i - 0.5 - 0.08,
            f"v[{i},{j}]",
            ha="left",
            va="bottom",
            fontsize=8,
            color="tab:purple" if free else "0.5",
        )
ax_cell.plot(
    *probe_cells[0].tolist(),
    "*",
    color="tab:red",
    ms=14,
    label="the same point: ({:.2f}, {:.2f}) cells".format(*probe_cells[0].tolist()),
)
ax_cell.plot([], [], color="tab:orange", lw=2, label="u (x-velocity) on vertical faces")
ax_cell.plot([], [], color="tab:purple", lw=2, label="v (y-velocity) on horizontal faces")
ax_cell.plot([], [], color="0.6", lw=2, label="on a wall: always 0")
ax_cell.set(
    xlim=(-0.75, w - 0.25),
    ylim=(h - 0.25, -0.75),
    aspect="equal",
    title=f"fluid cells: {h} x {w} grid, staggered velocity (B, 2, {h + 1}, {w + 1})\n"
    "(dotted: the image's pixel edges)",
)
ax_cell.set_xlabel("x (fluid cells), to the right")
ax_cell.set_ylabel("y (fluid cells), down")
ax_cell.legend(loc="upper left", bbox_to_anchor=(0.0, -0.14), ncols=2, fontsize=9, frameon=False)
plt.show()

# %%
# The same rule at any resolution
# -------------------------------
# A 600 x 600 photo over a 64 x 64 fluid: the photo's outer edges are the fluid's walls.
corners = torch.tensor([[-0.5, -0.5], [599.5, 599.5], [299.5, 299.5]])
print(pixel_to_cell(corners, (600, 600), (64, 64)))
