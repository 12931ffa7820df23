"""Clean edges: whether a picture's border shows as a line in a morph's frames, and whether anything is smeared
beyond it.

A morph's frame reads picture A at ``maps_a`` and picture B at ``maps_b``. Where a map reads beyond its picture's
border, the picture has nothing to show: a renderer that holds the edge pixels there (``grid_sample``'s border
padding) smears them into streaks, and one that shows the other picture instead draws the border as a curve in the
frame, the **edge**: the output pixels where the map crosses its picture's border. :func:`border_seam` measures,
for every frame,

* the **seam**: how much more abruptly the frame changes across each picture's edge than beside it (0: the edge
  cannot be told from the frame around it; 1: it jumps twice as much as the frame beside it);
* the **streak**: over the pixels read beyond one side of a picture, the ratio of the frame's gradient along that
  side to its gradient across it (about 1 for a photograph; a smear, constant across the side, sends it up);
* the fraction of output pixels read **beyond both** pictures, where any renderer has to invent what it shows.

Conventions: frames ``(N, C, H, W)`` with values in ``[0, 1]``; maps ``(N, H, W, 2)`` are backward maps (output
pixel -> the picture's pixel), ``(x, y)``, in each picture's own pixels with pixel centres at integers, so a
picture of ``size`` ``(h, w)`` spans ``[-0.5, w - 0.5] x [-0.5, h - 0.5]``. Distances beyond an edge are
converted to output pixels by the map's local stretch across that side of the picture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from torchfluidwarp._checks import check_int, check_positive, check_size, check_tensor
from torchfluidwarp.errors import InputError

__all__ = ["BorderSeam", "border_seam", "SEAM_REACH", "SEAM_FLOOR", "BEYOND"]

SEAM_REACH = 4
"""Output pixels: the run over which :func:`border_seam` takes the frame's slope on each side of an edge."""

SEAM_FLOOR = 1 / 255
"""Intensity per output pixel (frames in ``[0, 1]``): a change of slope below one 8-bit level per pixel counts as
none, so a flat or smooth frame has no seam rather than a ratio of two round-off errors."""

BEYOND = 2.0
"""Output pixels: a pixel is read beyond a picture's edge when its read point lies more than this beyond it (a
smear of a pixel or two shows nothing, and a picture mirrored about its border has a crease there)."""

MIN_CROSSINGS = 16
"""The fewest crossings of an edge (pixel pairs it passes between) for a frame's seam figure; fewer give NaN."""

MIN_BEYOND = 64
"""The fewest pixels read beyond a picture's side for a frame's streak figure; fewer give NaN."""


@dataclass(frozen=True)
class BorderSeam:
    """The border figures of ``N`` frames, from :func:`border_seam`; column 0 is picture A, column 1 picture B.

    Attributes:
        seam: ``(N, 2)`` float64, no unit: the excess of the frame's change of slope across the picture's edge over
            the same measure beside it (:func:`border_seam`); 0 for an edge that does not show, NaN where fewer
            than :data:`MIN_CROSSINGS` pixel pairs straddle the edge inside the frame.
        streak: ``(N, 2)`` float64, no unit: over the pixels read beyond one side of the picture (by more than
            :data:`BEYOND` output pixels), the frame's gradient along that side over its gradient across it; about
            1 for photographic content, large for a smear; NaN where fewer than :data:`MIN_BEYOND` such pixels.
        beyond_both: ``(N,)`` float64: the fraction of output pixels read beyond both pictures' edges.
        crossings: ``(N, 2)`` int64: the pixel pairs straddling each picture's edge that the seam was measured on.
    """

    seam: Tensor
    streak: Tensor
    beyond_both: Tensor
    crossings: Tensor

    def worst(self) -> dict[str, float]:
        """The largest figure over the frames (NaN frames left out; NaN if every frame is):
        ``{"seam_a", "seam_b", "streak_a", "streak_b", "beyond_both"}``."""

        def top(x: Tensor) -> float:
            x = x[~x.isnan()]
            return float(x.max()) if x.numel() else math.nan

        return {
            "seam_a": top(self.seam[:, 0]),
            "seam_b": top(self.seam[:, 1]),
            "streak_a": top(self.streak[:, 0]),
            "streak_b": top(self.streak[:, 1]),
            "beyond_both": top(self.beyond_both),
        }


def _sides(m: Tensor, size: tuple[int, int]) -> tuple[Tensor, Tensor]:
    """A map ``(H, W, 2)`` (float64) of a picture of ``size``: how far inside each side of the picture it reads,
    ``(4, H, W)`` output pixels (left, right, top, bottom; negative beyond), and each side's direction along the
    side in the output, ``(4, H, W, 2)`` unit vectors (the output direction in which the read point moves along
    the side fastest)."""
    h, w = size
    x, y = m[..., 0], m[..., 1]
    dxy = torch.stack(torch.gradient(m, dim=(0, 1)), -1)  # (H, W, 2 coords, 2 output axes (d/dy, d/dx))
    grad = dxy.flip(-1)  # (..., coord, (d/dx, d/dy))
    gx, gy = grad[..., 0, :], grad[..., 1, :]  # output gradients of the read point's x and y, (H, W, 2)
    nx, ny = gx.norm(dim=-1).clamp(min=1e-12), gy.norm(dim=-1).clamp(min=1e-12)
    inside = torch.stack([(x + 0.5) / nx, (w - 0.5 - x) / nx, (y + 0.5) / ny, (h - 0.5 - y) / ny])
    along_lr, along_tb = gy / ny[..., None], gx / nx[..., None]  # a left or right side runs along y, top along x
    return inside, torch.stack([along_lr, along_lr, along_tb, along_tb])


def _jumps(f: Tensor, reach: int) -> Tensor:
    """The step and the kink across each pair of neighbouring columns ``c, c + 1`` of ``f`` ``(C, H, W)``, beyond
    what a polynomial of degree 2 through the ``2 reach`` pixels on either side gives.

    With the difference across the pair ``d0 = f[c + 1] - f[c]``, the slopes over the ``reach`` pixels next to it,
    ``g_l = (f[c] - f[c - reach]) / reach`` and ``g_r = (f[c + 1 + reach] - f[c + 1]) / reach``, and the slopes
    over the ``reach`` pixels beyond those, ``g_ll`` and ``g_rr``: ``2 |d0 - (g_l + g_r) / 2|`` (twice a step's
    height) plus ``|g_r - g_l - (g_rr - g_ll) (reach + 1) / (3 reach + 1)|`` (a kink's change of slope, less the
    change that the frame's curvature on either side accounts for), each a norm over channels. Both vanish for a
    quadratic profile. ``(H, W - 1 - 4 reach)``, column ``i`` for the pair at ``c = i + 2 reach``."""
    W, r = f.shape[-1], reach
    n = W - 1 - 4 * r

    def at(offset: int) -> Tensor:  # f[c + offset] for every pair's c = i + 2r
        return f[..., 2 * r + offset : 2 * r + offset + n]

    left, right = at(0), at(1)
    g_l, g_r = (left - at(-r)) / r, (at(1 + r) - right) / r
    g_ll, g_rr = (at(-r) - at(-2 * r)) / r, (at(1 + 2 * r) - at(1 + r)) / r
    step = (right - left - (g_l + g_r) / 2).norm(dim=0)
    kink = (g_r - g_l - (g_rr - g_ll) * ((r + 1) / (3 * r + 1))).norm(dim=0)
    return 2 * step + kink


def _seam_sums(f: Tensor, inside: Tensor, reach: int) -> tuple[float, float, int]:
    """Along rows: the jumps of :func:`_jumps` summed over the pairs that straddle an edge (``inside`` ``(H, W)``
    changes sign between them), the same measure beside each (the mean over the pairs ``4 reach + 2`` and
    ``8 reach + 4`` columns to either side that lie in the frame) summed over the same pairs, and their number."""
    r = reach
    jump = _jumps(f, r)  # (H, W - 1 - 4r)
    n = jump.shape[1]
    positive = inside > 0
    cross = positive[:, 2 * r : 2 * r + n] != positive[:, 2 * r + 1 : 2 * r + 1 + n]
    o = 4 * r + 2  # the stencils beside span no pixel of the edge's own
    nan = jump.new_full((jump.shape[0], 2 * o), math.nan)
    padded = torch.cat([nan, jump, nan], dim=1)
    beside = torch.stack([padded[:, 2 * o + d : 2 * o + d + n] for d in (-2 * o, -o, o, 2 * o)]).nanmean(0)
    ok = cross & ~beside.isnan()
    return float(jump[ok].sum()), float(beside[ok].sum()), int(ok.sum())


def border_seam(
    frames: Tensor,
    maps_a: Tensor,
    maps_b: Tensor,
    size_a: tuple[int, int],
    size_b: tuple[int, int],
    reach: int = SEAM_REACH,
    floor: float = SEAM_FLOOR,
) -> BorderSeam:
    """Whether each picture's border shows as a line in each frame, and whether anything is smeared beyond it.

    **Seam.** A picture's edge in the output lies between the neighbouring pixels (along a row or a column) of
    which one reads inside the picture and the other beyond it. At each such pair the change of slope ``J`` is
    ``|d0 - g_in| + |d0 - g_out|``: the difference across the pair against the frame's slope over ``reach`` pixels
    on either side (a step counts twice its height, a kink its change of slope, a straight ramp nothing). The
    same measure at the pairs ``2 reach + 2`` pixels to either side of the edge, ``J_beside``, is what the frame's
    content gives there. The figure is ``(sum J + n floor) / (sum J_beside + n floor) - 1`` over the ``n`` pairs:
    about 0 where the edge cannot be told from the frame beside it, whatever the content, and large where the
    frame jumps at the edge (a picture pasted in with a hard border gives tens to hundreds).

    **Streak.** Over the pixels read more than :data:`BEYOND` output pixels beyond exactly one side of a picture,
    ``sum |d_along f| / sum |d_across f|`` (each plus ``floor`` per pixel), where *along* is the output direction in
    which the read point moves along that side: a renderer that holds the edge pixels shows there a smear that is
    constant across the side, and the ratio grows without bound; photographic content gives about 1.

    Args:
        frames: ``(N, C, H, W)`` the morph's frames, values in ``[0, 1]``.
        maps_a: ``(N, H, W, 2)`` where each output pixel reads picture A, in A's pixels.
        maps_b: ``(N, H, W, 2)`` where it reads picture B, in B's pixels.
        size_a: A's ``(h, w)`` in pixels.
        size_b: B's ``(h, w)`` in pixels.
        reach: output pixels over which the slope on each side of an edge is taken (``>= 1``); the frame must be
            at least ``8 reach + 6`` pixels wide and high.
        floor: intensity per output pixel added per pixel pair (and per pixel for the streak): changes below it
            count as none.

    Returns:
        :class:`BorderSeam`, float64, column 0 for A and 1 for B.

    Raises:
        InputError: a shape that does not fit the others, non-finite values, a frame too small for ``reach``.

    Example:
        >>> from torchfluidwarp.warp import identity_map
        >>> y, x = torch.meshgrid(torch.arange(128.0), torch.arange(128.0), indexing="ij")
        >>> smooth = (0.5 + 0.3 * torch.sin(x / 15) * torch.cos(y / 20)).expand(1, 3, 128, 128)
        >>> maps_a = identity_map((128, 128))  # A fills the frame
        >>> maps_b = identity_map((128, 128)) - 32  # B, 64 x 64, drawn in the middle
        >>> pasted = smooth.clone()
        >>> pasted[..., 32:96, 32:96] = 0.9  # B shown with a hard border
        >>> round(border_seam(smooth, maps_a, maps_b, (128, 128), (64, 64)).seam[0, 1].item(), 1)
        0.0
        >>> round(border_seam(pasted, maps_a, maps_b, (128, 128), (64, 64)).seam[0, 1].item())
        385
    """
    check_tensor("frames", frames, ndim=4)
    N, _, H, W = frames.shape
    check_tensor("maps_a", maps_a, shape=[N, H, W, 2])
    check_tensor("maps_b", maps_b, shape=[N, H, W, 2])
    sizes = (check_size("size_a", size_a), check_size("size_b", size_b))
    reach = check_int("reach", reach)
    floor = check_positive("floor", floor, allow_zero=True)
    if min(H, W) < 8 * reach + 6:
        raise InputError(
            f"frames must be at least 8 * reach + 6 = {8 * reach + 6} pixels wide and high for reach={reach}, "
            f"got {W} x {H}",
            argument="frames",
        )
    dev = frames.device
    seam = torch.full((N, 2), math.nan, dtype=torch.float64, device=dev)
    streak = torch.full((N, 2), math.nan, dtype=torch.float64, device=dev)
    beyond_both = torch.zeros(N, dtype=torch.float64, device=dev)
    crossings = torch.zeros(N, 2, dtype=torch.int64, device=dev)
    for k in range(N):
        f = frames[k].detach().double()  # (C, H, W)
        fy, fx = torch.gradient(f, dim=(1, 2))  # the frame's derivatives, per output pixel
        beyond = []
        for j, (maps, size) in enumerate(((maps_a, sizes[0]), (maps_b, sizes[1]))):
            inside, along = _sides(maps[k].detach().double(), size)  # (4, H, W), (4, H, W, 2)
            signed = inside.min(0).values  # output pixels inside the picture (negative beyond)
            beyond.append(signed < -BEYOND)
            rows = _seam_sums(f, signed, reach)
            cols = _seam_sums(f.transpose(1, 2), signed.T, reach)
            n = rows[2] + cols[2]
            crossings[k, j] = n
            if n >= MIN_CROSSINGS:
                seam[k, j] = (rows[0] + cols[0] + n * floor) / (rows[1] + cols[1] + n * floor) - 1
            out = inside < -BEYOND  # (4, H, W)
            one = out & (out.sum(0) == 1)  # beyond one side only: at a corner the held pixel is one colour
            if int(one.sum()) >= MIN_BEYOND:
                pick = one.any(0)  # (H, W)
                u = (along * one[..., None]).sum(0)[pick]  # (P, 2): along the side each pixel lies beyond
                dx, dy = fx[:, pick], fy[:, pick]  # (C, P)
                d_along = (u[:, 0] * dx + u[:, 1] * dy).norm(dim=0)
                d_across = (-u[:, 1] * dx + u[:, 0] * dy).norm(dim=0)
                P = d_along.numel()
                streak[k, j] = (float(d_along.sum()) + P * floor) / (float(d_across.sum()) + P * floor)
        beyond_both[k] = float((beyond[0] & beyond[1]).double().mean())
    return BorderSeam(seam, streak, beyond_both, crossings)
