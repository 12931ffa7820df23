"""Ghosting seen in the pixels: how far apart A's and B's structures stand in a frame where both are warped to the
same shape (a morph's middle frame).

The measure needs no points: the two warped pictures are compared directly. The displacement that aligns them
locally is estimated coarse to fine, the same window in pixels at every level of a pyramid:

1. a block search of the local normalised cross-correlation (NCC) of their gradient magnitudes, from the
   displacement of the level above, a parabola through the correlation's peak for the sub-pixel part; flat windows,
   where a normalised correlation means nothing, take the displacement of the structures around them, and a
   3 x 3 median removes single wrong matches (the classic pyramidal block matcher; the NCC is the local similarity
   of Avants et al. 2008, ANTs SyN);
2. at the finest level, Lucas-Kanade steps (Lucas and Kanade 1981; Bouguet 2001) on the pictures normalised over
   each window, B's with the sign of the window's correlation, which remove the parabola's bias toward whole
   pixels.

Gradient magnitudes, normalised windows and the correlation's sign make the figure blind to the brightness, the
contrast and a flipped contrast of either picture: a grey A and a colour B, or a darker B, compare by their
structure. The displacement's magnitude, over the pixels where both pictures show structure, is the ghosting a
viewer sees as a doubled edge.
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import check_int, check_tensor, compute_dtype
from torchfluidwarp.errors import InputError
from torchfluidwarp.warp import identity_map, warp_image

GHOST_SIDE = 512
"""Pixels: frames longer than this on their long side are measured on an area-averaged copy this long, and the
displacements scaled back to the frame's pixels (bounded memory and time whatever the frame's size)."""

GHOST_WINDOW = 7
"""Pixels of the analysed raster: the side of the square window the local correlation is taken over, the same
at every level of the pyramid."""

GHOST_TEXTURE = 0.05
"""The structure a pixel needs to be measured: the root mean square over its window of the (lightly smoothed)
gradient magnitude, as a fraction of the picture's own intensity spread (standard deviation over the covered
area) per analysed pixel, in both pictures."""

_RADIUS = 2  # the block search's reach per pass, analysed pixels
_COARSEST = 24  # analysed pixels: the pyramid halves the picture while its long side stays at least this
_FLAT = 0.05  # a window is flat below this fraction of the picture's mean window variance
_CONFIDENT = 0.5  # the NCC below which a match is not trusted: the pixel takes its neighbours' flow
_LK_STEPS = 3  # Lucas-Kanade steps at the finest level (they settle in two or three)
_PASSES = 2  # block-search passes per level; the finest takes two more, where every pixel's match settles


def _grey(name: str, x: Tensor) -> Tensor:
    """``(C, H, W)`` or ``(1, C, H, W)`` as ``(1, 1, H, W)``, the channels averaged."""
    check_tensor(name, x, ndim=(3, 4))
    if x.ndim == 4 and x.shape[0] != 1:
        raise InputError(f"{name} must be (C, H, W) or (1, C, H, W), got shape {tuple(x.shape)}", argument=name)
    if min(x.shape[-2:]) < 1 or x.shape[-3] < 1:
        raise InputError(f"{name} must be non-empty, got shape {tuple(x.shape)}", argument=name)
    return x.reshape(1, -1, *x.shape[-2:]).mean(1, keepdim=True)


def _box(x: Tensor, k: int) -> Tensor:
    """The mean over a ``k x k`` window (``k`` odd), over the pixels inside the picture at its edges."""
    return F.avg_pool2d(x, k, stride=1, padding=k // 2, count_include_pad=False)


def _shift(x: Tensor, dx: int, dy: int, fill: float | None = None) -> Tensor:
    """``out(x, y) = x(x + dx, y + dy)`` ``(1, C, h, w)``: beyond the edge the edge held, or ``fill``."""
    r = max(abs(dx), abs(dy))
    if r == 0:
        return x
    h, w = x.shape[-2:]
    pad = (r, r, r, r)
    padded = F.pad(x, pad, mode="replicate") if fill is None else F.pad(x, pad, value=fill)
    return padded[..., r + dy : r + dy + h, r + dx : r + dx + w]


def _structure(grey: Tensor) -> Tensor:
    """The gradient magnitude ``(1, 1, h, w)`` of ``grey`` smoothed by a 3-tap binomial (central differences)."""
    k = grey.new_tensor([0.25, 0.5, 0.25])
    g = F.pad(grey, (1, 1, 1, 1), mode="replicate")
    g = F.conv2d(F.conv2d(g, k.view(1, 1, 1, 3)), k.view(1, 1, 3, 1))  # (1, 1, h, w)
    g = F.pad(g, (1, 1, 1, 1), mode="replicate")
    gx = (g[..., 1:-1, 2:] - g[..., 1:-1, :-2]) / 2
    gy = (g[..., 2:, 1:-1] - g[..., :-2, 1:-1]) / 2
    return (gx.square() + gy.square()).sqrt()


def _median3(u: Tensor) -> Tensor:
    """A 3 x 3 median of each channel of ``u`` ``(1, C, h, w)``, the edge held: robust to a few wrong matches."""
    h, w = u.shape[-2:]
    patches = F.unfold(F.pad(u, (1, 1, 1, 1), mode="replicate"), 3)  # (1, C * 9, h * w)
    return patches.view(1, u.shape[1], 9, h * w).median(2).values.view_as(u)


def _interior(cover: Tensor, window: int) -> Tensor:
    """``(1, 1, h, w)`` float, 1 where the whole ``window`` around a pixel is inside the picture and ``cover``."""
    whole = F.avg_pool2d(cover, window, stride=1, padding=window // 2, count_include_pad=True)
    return (whole > 1 - 1e-6).to(cover.dtype)


def _variance(f: Tensor, window: int) -> tuple[Tensor, Tensor]:
    """The window mean and variance of ``f`` ``(1, 1, h, w)``."""
    m = _box(f, window)
    return m, (_box(f * f, window) - m * m).clamp(min=0)


def _structured(v: Tensor) -> Tensor:
    """Where a window's variance ``v`` ``(1, 1, h, w)`` is not negligible next to the picture's average
    (:data:`_FLAT`): only there does a normalised correlation mean anything (a flat patch correlates as well with
    its textured neighbour as with itself)."""
    return v > _FLAT * v.mean()


def _fill(flow: Tensor, found: Tensor, known: Tensor, window: int) -> Tensor:
    """``found`` where ``known``; elsewhere the mean of the known ``found`` in the window where there is any
    (normalised convolution), else ``flow``: flat areas take the displacement of the structures around them."""
    weight = known.to(flow.dtype)
    count = _box(weight, window)
    mean = _box(found * weight, window) / count.clamp(min=1e-12)
    return torch.where(known, found, torch.where(count > 0, mean, flow))


def _search(fa: Tensor, fb: Tensor, interior: Tensor, flow: Tensor, window: int) -> Tensor:
    """One block-search pass: the flow ``(1, 2, h, w)`` (analysed pixels, ``fb`` read at ``x + flow``) moved to the
    best local NCC of ``fa`` and ``fb`` within :data:`_RADIUS` pixels, sub-pixel by a parabola through the peak.

    ``interior`` ``(1, 1, h, w)`` marks the pixels whose whole window is covered and inside the picture. A
    candidate whose ``fb`` window is not, or is flat, is never taken. Where ``fa``'s window is not interior or is
    flat, or the best correlation is weak (:data:`_CONFIDENT`), the pixel takes the flow of the structures around
    it (:func:`_fill`); a 3 x 3 median ends the pass."""
    h, w = fa.shape[-2:]
    # fb is read at whole pixels (exactly, no interpolation) and the pass finds the flow anew from there: sub-pixel
    # steps added pass after pass would random-walk, each estimated on a differently blurred fb
    flow = flow.round()
    at = identity_map((h, w), device=fa.device, dtype=fa.dtype) + flow.permute(0, 2, 3, 1)  # (1, h, w, 2)
    fb = warp_image(fb, at)
    x, y = at[..., 0], at[..., 1]
    readable = (warp_image(interior, at)[:, 0] > 1 - 1e-6) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    ma, va = _variance(fa, window)
    mb, vb = _variance(fb, window)
    usable = (readable[:, None] & _structured(vb)).to(fa.dtype)  # (1, 1, h, w): candidates fb may offer
    tiny = torch.finfo(fa.dtype).tiny
    offsets = range(-_RADIUS, _RADIUS + 1)
    scores = []
    for dy in offsets:
        for dx in offsets:
            cross = _box(fa * _shift(fb, dx, dy), window) - ma * _shift(mb, dx, dy)
            ncc = cross / (va * _shift(vb, dx, dy)).clamp(min=tiny).sqrt()
            scores.append(torch.where(_shift(usable, dx, dy, fill=0.0) > 0, ncc, -2.0))  # NCC >= -1
    side = 2 * _RADIUS + 1
    ncc = torch.cat(scores, 1)[0]  # (side * side, h, w): offsets (dy, dx) in row-major order
    best = ncc.argmax(0)  # (h, w)
    iy, ix = best // side, best % side

    def at_offset(ky: Tensor, kx: Tensor) -> Tensor:
        return ncc.gather(0, (ky.clamp(0, side - 1) * side + kx.clamp(0, side - 1))[None])[0]

    def vertex(lo: Tensor, mid: Tensor, hi: Tensor, k: Tensor) -> Tensor:
        # the parabola through three samples peaks at (lo - hi) / (2 (lo - 2 mid + hi)); none at the search's edge
        curve = lo - 2 * mid + hi
        step = torch.where(curve < 0, (lo - hi) / (2 * curve.clamp(max=-1e-12)), torch.zeros_like(mid))
        inner = (k > 0) & (k < side - 1) & (lo > -2) & (hi > -2)
        return torch.where(inner, step.clamp(-0.5, 0.5), torch.zeros_like(step))

    peak = at_offset(iy, ix)
    sx = vertex(at_offset(iy, ix - 1), peak, at_offset(iy, ix + 1), ix)
    sy = vertex(at_offset(iy - 1, ix), peak, at_offset(iy + 1, ix), iy)
    step = torch.stack([ix - _RADIUS + sx, iy - _RADIUS + sy])[None].to(flow.dtype)  # (1, 2, h, w)
    known = (interior > 0) & _structured(va) & (peak > _CONFIDENT)
    return _median3(_fill(flow, flow + step, known, window))


def _refine(ga: Tensor, gb: Tensor, interior: Tensor, flow: Tensor, window: int) -> Tensor:
    """One Lucas-Kanade step (Lucas and Kanade 1981; Bouguet 2001, eq. 28) on the pictures ``ga`` and ``gb`` read
    at ``x + flow``, each normalised over the window and ``gb`` given the sign of the window's correlation (a
    flipped contrast is a flipped sign): the sub-pixel correction the block search's parabola leaves (its peak is
    biased toward whole pixels). A step is capped at half a pixel per axis, and taken only where both windows have
    structure and the window's structure tensor is well conditioned (no aperture problem)."""
    h, w = ga.shape[-2:]
    # linearised about the window's mean flow: a window read through a flow that changes from pixel to pixel
    # (whole pixels here, sub-pixel there) is no longer the picture moved, and the steps would feed on that jitter
    flow = _box(flow, window)
    at = identity_map((h, w), device=ga.device, dtype=ga.dtype) + flow.permute(0, 2, 3, 1)  # (1, h, w, 2)
    gb = warp_image(gb, at)
    ma, va = _variance(ga, window)
    mb, vb = _variance(gb, window)
    tiny = torch.finfo(ga.dtype).tiny
    na, nb = (ga - ma) / va.clamp(min=tiny).sqrt(), (gb - mb) / vb.clamp(min=tiny).sqrt()
    nb = nb * torch.where(_box(na * nb, window) < 0, -1.0, 1.0)
    g = F.pad(nb, (1, 1, 1, 1), mode="replicate")
    gx = (g[..., 1:-1, 2:] - g[..., 1:-1, :-2]) / 2
    gy = (g[..., 2:, 1:-1] - g[..., :-2, 1:-1]) / 2
    e = nb - na
    sxx, sxy, syy = _box(gx * gx, window), _box(gx * gy, window), _box(gy * gy, window)
    bx, by = _box(gx * e, window), _box(gy * e, window)
    det = sxx * syy - sxy * sxy
    ok = (det > 1e-2 * (sxx + syy).square()) & _structured(va) & _structured(vb) & (interior > 0)
    safe = torch.where(ok, det, torch.ones_like(det))
    ux = torch.where(ok, -(syy * bx - sxy * by) / safe, torch.zeros_like(det)).clamp(-0.5, 0.5)
    uy = torch.where(ok, -(sxx * by - sxy * bx) / safe, torch.zeros_like(det)).clamp(-0.5, 0.5)
    return flow + torch.cat([ux, uy], 1)


def _pyramid(x: Tensor, levels: int) -> list[Tensor]:
    """``x`` and ``levels - 1`` copies each half the last's size (2 x 2 means), finest first."""
    out = [x]
    for _ in range(levels - 1):
        out.append(F.avg_pool2d(out[-1], 2, ceil_mode=True))
    return out


def _local_displacement(
    image_a: Tensor, image_b: Tensor, valid: Tensor | None = None, *, window: int = GHOST_WINDOW
) -> Tensor:
    """The displacement that aligns ``image_b`` with ``image_a`` locally, at every pixel of the analysed raster.

    Args:
        image_a: ``(1, 1, h, w)`` the first picture.
        image_b: ``(1, 1, h, w)`` the second.
        valid: ``(1, 1, h, w)`` bool: the pixels both pictures cover (the rest is blanked before matching).
        window: the correlation window's side, pixels (odd).

    Returns:
        ``(1, 2, h, w)`` ``(dx, dy)`` in pixels: ``image_b`` at ``x + d`` shows what ``image_a`` shows at ``x``.
    """
    levels = max(1, int(math.log2(max(image_a.shape[-2:]) / _COARSEST)) + 1)
    ga, gb = _pyramid(image_a, levels), _pyramid(image_b, levels)
    cover = _pyramid(torch.ones_like(image_a) if valid is None else valid.to(image_a.dtype), levels)
    flow = image_a.new_zeros(1, 2, *ga[-1].shape[-2:])
    for level in range(levels - 1, -1, -1):
        size = ga[level].shape[-2:]
        if flow.shape[-2:] != size:
            scale = flow.new_tensor([size[1] / flow.shape[-1], size[0] / flow.shape[-2]]).view(1, 2, 1, 1)
            flow = F.interpolate(flow, size=size, mode="bilinear", align_corners=False) * scale
        inside = (cover[level] > 1 - 1e-6).to(flow.dtype)
        interior = _interior(inside, window)
        fa, fb = _structure(ga[level]) * inside, _structure(gb[level]) * inside
        for _ in range(_PASSES + (2 if level == 0 else 0)):
            flow = _search(fa, fb, interior, flow, window)
    known = inside > 0  # the finest level's
    if bool(known.any()):
        # uncovered pixels take the covered ones' mean: neutral, and it follows a change of brightness or contrast
        a = torch.where(known, image_a, image_a[known].mean())
        b = torch.where(known, image_b, image_b[known].mean())
        for _ in range(_LK_STEPS):
            flow = _refine(a, b, interior, flow, window)
    return _median3(flow)


def image_ghosting(
    warped_a: Tensor,
    warped_b: Tensor,
    valid: Tensor | None = None,
    *,
    max_side: int = GHOST_SIDE,
    window: int = GHOST_WINDOW,
) -> dict[str, Any]:
    """Ghosting from the pixels: how far apart A's and B's structures stand in a frame that shows both warped to
    the same shape (a morph's middle frame: A warped forward and B pulled back).

    The displacement that best aligns the two pictures locally is estimated coarse to fine (a block search of the
    local normalised cross-correlation of their gradient magnitudes, then Lucas-Kanade steps on the pictures
    normalised over each window); its magnitude is summarised over the *textured* pixels: those both pictures
    cover, whose whole window does too, and where both show structure (:data:`GHOST_TEXTURE`). Brightness,
    contrast and a flipped contrast of either picture leave the figure unchanged (up to round-off).

    Conventions: ``(x, y)``, pixel centres at integers; displacements in the frame's pixels. A frame longer than
    ``max_side`` is measured on an area-averaged copy and the displacements scaled back. The search reaches about
    a quarter of the (analysed) long side; a displacement larger than the spacing of repeated structures may be
    taken for a smaller one, as the eye would.

    Args:
        warped_a: ``(C, H, W)`` or ``(1, C, H, W)``: picture A warped to the frame (channels averaged).
        warped_b: ``(C', H, W)`` or ``(1, C', H, W)``: picture B warped to the same frame (``C'`` may differ).
        valid: ``(H, W)``, ``(1, H, W)`` or ``(1, 1, H, W)`` bool: where both pictures are covered (both maps read
            inside their picture); default everywhere.
        max_side: the long side, in pixels, above which the frame is measured on a smaller copy.
        window: the correlation window's side, pixels of the analysed copy (odd, >= 3).

    Returns:
        ``{"median", "p90", "mean", "covered", "textured", "scale"}``: the median, 90th percentile and mean
        displacement magnitude over the textured pixels, in the frame's pixels (``None`` where no pixel is
        textured); the fractions of the frame's pixels covered and textured; the frame's pixels per analysed
        pixel (1 when the frame was measured as it is).

    Raises:
        InputError: shapes that do not match, a window that is not odd, or non-finite values.

    Example:
        >>> import torch
        >>> g = torch.Generator().manual_seed(0)
        >>> a = torch.nn.functional.avg_pool2d(torch.rand(1, 1, 96, 96, generator=g), 3, 1, 1)
        >>> b = torch.roll(a, shifts=3, dims=-1)  # A's structures stand 3 px to the right in B
        >>> r = image_ghosting(a, b)
        >>> round(r["median"], 1)
        3.0
    """
    ga, gb = _grey("warped_a", warped_a), _grey("warped_b", warped_b)
    H, W = ga.shape[-2:]
    if gb.shape[-2:] != (H, W):
        raise InputError(
            f"warped_b must have warped_a's height and width {(H, W)}, got shape {tuple(warped_b.shape)}",
            argument="warped_b",
        )
    if valid is None:
        cover = torch.ones(1, 1, H, W, dtype=torch.bool, device=ga.device)
    else:
        check_tensor("valid", valid, floating=False, finite=False)
        if valid.dtype != torch.bool or valid.shape[-2:] != (H, W) or valid.numel() != H * W:
            raise InputError(
                f"valid must be a bool tensor of shape (H, W) = {(H, W)}, got {tuple(valid.shape)} {valid.dtype}",
                argument="valid",
            )
        cover = valid.reshape(1, 1, H, W).to(ga.device)
    max_side = check_int("max_side", max_side, minimum=16)
    window = check_int("window", window, minimum=3)
    if window % 2 == 0:
        raise InputError(f"window must be odd, got {window}", argument="window")
    dtype = compute_dtype(ga.dtype, gb.dtype)
    ga, gb = ga.to(dtype), gb.to(dtype)
    covered = float(cover.sum()) / (H * W)
    figures: dict[str, Any] = {"median": None, "p90": None, "mean": None, "covered": covered, "textured": 0.0}
    h, w = H, W
    if max(H, W) > max_side:  # the analysed copy: area means, covered only where every frame pixel under it is
        h, w = max(1, round(H * max_side / max(H, W))), max(1, round(W * max_side / max(H, W)))
        ga, gb = F.interpolate(ga, (h, w), mode="area"), F.interpolate(gb, (h, w), mode="area")
        cover = F.interpolate(cover.to(dtype), (h, w), mode="area") > 1 - 1e-6
    figures["scale"] = max(H / h, W / w)
    if not bool(cover.any()):
        return figures
    # each picture's intensity spread over the covered area: the unit of its structure
    spread_a = ga[cover].std() if int(cover.sum()) > 1 else ga.new_tensor(0.0)
    spread_b = gb[cover].std() if int(cover.sum()) > 1 else gb.new_tensor(0.0)
    flow = _local_displacement(ga, gb, cover, window=window)  # (1, 2, h, w), analysed pixels
    inside = _interior(cover.to(dtype), window) > 0  # the whole window covered, and inside the frame
    sa = _box(_structure(ga).square(), window).sqrt()
    sb = _box(_structure(gb).square(), window).sqrt()
    textured = inside & (sa > GHOST_TEXTURE * spread_a) & (sb > GHOST_TEXTURE * spread_b)
    textured &= (spread_a > 0) & (spread_b > 0)
    figures["textured"] = float(textured.sum()) / (h * w)
    if not bool(textured.any()):
        return figures
    frame = flow * flow.new_tensor([W / w, H / h]).view(1, 2, 1, 1)  # the frame's pixels
    d = frame.square().sum(1, keepdim=True).sqrt()[textured].double()
    figures.update(median=float(d.median()), p90=float(torch.quantile(d, 0.9)), mean=float(d.mean()))
    return figures
