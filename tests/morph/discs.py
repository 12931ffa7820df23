"""Pictures of a soft disc, its marks and its aspect ratio: the shared fixtures of the tests that check that no
picture is stretched (``test_morph_pictures.py``, ``test_sequence.py``)."""

from __future__ import annotations

import torch


def disc(size, centre, radius, band=1.5):
    """``(H, W)`` a soft disc: 1 inside, 0 outside, a ramp of ``band`` pixels."""
    H, W = size
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32), indexing="ij")
    r = ((xs - centre[0]) ** 2 + (ys - centre[1]) ** 2).sqrt()
    return ((radius - r) / band + 0.5).clamp(0, 1)


def disc_marks(centre, radius):
    """The disc's centre and four points on its rim: ``(5, 2)``."""
    cx, cy = centre
    return torch.tensor(
        [[cx, cy], [cx + radius, cy], [cx, cy + radius], [cx - radius, cy], [cx, cy - radius * 0.8]],
        dtype=torch.float32,
    )


def disc_picture(size, centre, radius, colour, gen):
    """A disc of ``colour`` (a list of channel values) on a faint noisy ground."""
    soft = disc(size, centre, radius)
    ground = 0.2 + 0.05 * torch.rand(len(colour), *size, generator=gen)
    return torch.lerp(ground, torch.tensor(colour).view(-1, 1, 1).expand(-1, *size), soft)


def aspect(frame):
    """Width over height of the bright disc in ``frame`` ``(C, H, W)``, from its second moments."""
    w = (frame[0] > 0.55).float()
    ys, xs = torch.meshgrid(torch.arange(w.shape[0]), torch.arange(w.shape[1]), indexing="ij")
    n = w.sum()
    cx, cy = (w * xs).sum() / n, (w * ys).sum() / n
    vx, vy = (w * (xs - cx) ** 2).sum() / n, (w * (ys - cy) ** 2).sum() / n
    return float((vx / vy).sqrt())


def crop_offset(marks, scale, extent, side, axis):
    """Where the library's placement crops a picture of ``extent`` pixels along ``axis`` (0: x, 1: y), scaled by
    ``scale`` onto a canvas ``side`` pixels long: the scaled picture's first pixel sits ``-offset`` pixels before
    the canvas's, the median of ``marks`` ``(M, 2)`` centred on the canvas as far as the picture reaches. Written
    from the rule, not from the library's code."""
    centre = float(marks[:, axis].median())
    return min(max(side / 2 - scale * (centre + 0.5), side - scale * extent), 0.0)


def crop(picture, top, left, size):
    """``picture`` ``(C, h, w)`` read at rows ``top .. top + H - 1`` and columns ``left .. left + W - 1`` of its
    pixels (fractional starts read bilinearly), ``(C, H, W)``."""
    H, W = size
    for axis, start, n in ((1, top, H), (2, left, W)):
        whole = int(start // 1)
        frac = start - whole
        lo = picture.narrow(axis, whole, n)
        picture = lo if frac < 1e-9 else (1 - frac) * lo + frac * picture.narrow(axis, whole + 1, n)
    return picture
