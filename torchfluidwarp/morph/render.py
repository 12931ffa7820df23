"""Rendering a fitted morph: each frame's maps for image A and image B, and the cross-dissolve.

A frame at fluid time ``s`` (steps, ``0..T``) and an output pixel ``y``: ``z = M_s^-1 y`` is the point in the
fluid's frame; image A is read at ``g_s(z)`` (the fluid's backward map) and image B at ``M K_s(z)``, where
``K_s`` carries ``z`` forward from ``s`` to ``T`` through the same velocities (``inverse="flow"``), or through a
chain of small per-step fits (``inverse="paper"``). Maps are ``(1, H, W, 2)`` in pixels, ``(x, y)``, pixel
centres at integers.

Pictures with alpha (``C = 2`` or ``4``) are read and blended premultiplied (colour times alpha) and shown straight:
the colour stored under transparent pixels, often black or anything, never bleeds into a frame (a cross-dissolve
of a transparent pixel into an opaque green one is green at half alpha, not half the hidden colour).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor

from torchfluidwarp.control.alignment import apply_alignment, interpolate_alignment
from torchfluidwarp.io.images import premultiplied, straight
from torchfluidwarp.morph.regions import composite
from torchfluidwarp.morph.settings import FEATHER, InverseMethod
from torchfluidwarp.warp.frames import identity_map, jacobian_determinant, sample_map
from torchfluidwarp.warp.maps import backward_maps, raster_displacements, read_displacement, upsample_raster

EDGE_DEPTH = 4.0
"""The hand-over band inside a picture's edge is at most this many times as wide as the strip of the canvas that
the picture leaves uncovered beyond that edge (and at most the feather): an edge that only just enters the canvas
hands over in a band that grows with the strip, instead of one that appears at the feather's full width."""

EDGE_SHARE = 0.25
"""The hand-over band inside a side of a picture is at most this fraction of the picture's extent across that side
in the output (its width for the left and right sides, its height for the top and bottom), so that a picture drawn
small on the canvas still shows, not only its bands."""


FACING = 8
"""How the distance from an edge to the canvas's border behind it weighs the canvas's two borders that the edge's
normal heads for: by the cosine of the angle between them to this power. The border the edge faces counts almost
alone; near 45 degrees the two are averaged, so the weight moves smoothly from one to the other."""

EDGE_MIRROR = 0.5
"""A strip of the canvas that a picture leaves uncovered beyond one of its sides, narrower than this fraction of the
feather, is filled by the picture itself mirrored about that side (fully as the strip's width goes to 0, not at all
from this width on): a thin strip of the other picture along a border would show as a line. The width counts in
the picture's pixels too where the canvas shows the picture shrunk, so that no more than this much of the picture
is ever shown mirrored (where the map squeezes a picture, its distances beyond the edge are the least certain)."""


def _smoothstep(t: Tensor) -> Tensor:
    """``3 t^2 - 2 t^3`` of ``t`` clamped to ``[0, 1]``: a ramp whose slope is 0 at both ends, so that neither end
    of a hand-over band shows as a kink."""
    t = t.clamp(0, 1)
    return t * t * (3 - 2 * t)


def _power(x: Tensor, k: int) -> Tensor:
    """``x ** k`` for a whole ``k >= 1`` by repeated squaring (``pow`` with a float exponent costs 10x more)."""
    out = None
    while k:
        if k & 1:
            out = x if out is None else out * x
        k >>= 1
        if k:
            x = x * x
    assert out is not None
    return out


def _coverage(
    coords: Tensor,
    size: tuple[int, int],
    canvas: tuple[int, int],
    top: int,
    feather: float = FEATHER,
    share: float = 0.0,
) -> tuple[Tensor, Tensor]:
    """How far a frame may show the picture of ``size`` ``(h, w)`` that a map ``(1, n, W, 2)`` reads, the map
    covering rows ``top .. top + n - 1`` of a canvas of ``canvas`` ``(H, W)``.

    Each side of the picture (left, right, top, bottom) is measured on its own, in output pixels: its distance
    ``d`` is how far inside that side the map reads divided by the map's stretch across it (the norm of the output
    gradient of the read point's ``x`` for the left and right sides, of ``y`` for the top and bottom), and the
    direction towards it, ``u``, is that gradient's. The side's edge lies inside the canvas by ``depth = t - d``,
    ``t`` being the distance along ``u`` to the canvas's border behind the edge: the distances ``b_x / |u_x|`` and
    ``b_y / |u_y|`` to the two borders ``u`` heads for, weighted by ``|u_x|^k`` and ``|u_y|^k`` (:data:`FACING`),
    so that a border the edge only grazes near a corner of the canvas does not cut the strip short.
    Where ``depth > 0`` the coverage ramps from 0 at the edge to 1 at
    ``min(feather, EDGE_DEPTH * depth, EDGE_SHARE * extent)`` inside (:func:`_smoothstep`), ``extent`` being the
    picture's extent across the side in output pixels. A side whose edge lies on or beyond the canvas's border
    does not show in the frame and covers fully: a picture that fills the canvas keeps the plain dissolve up to
    the canvas's border. A side whose edge lies only just inside covers nearly fully, beyond its edge too (the
    picture is read mirrored there, :func:`_dissolve`): the coverage is ``m + (1 - m) ramp`` with
    ``m = smoothstep(1 - depth max(1, g) (1 - share^4) / (EDGE_MIRROR * feather))``, ``g`` the map's stretch
    across the side (source pixels per output pixel), ``share`` the picture's weight in the dissolve at this frame:
    the strip a picture may fill mirrored widens as the picture takes over, little before its share passes 1/2 and
    without bound as it reaches 1, so that the strip a zoomed picture leaves uncovered near the end of a morph
    dissolves into it over the last frames instead of showing the other picture until the very last one. The
    picture's coverage is the product over its sides.

    Returns:
        ``(coverage, inside)``: ``(1, 1, n, W)`` in ``[0, 1]`` and the distance inside the nearest side,
        ``(1, n, W)`` output pixels (negative beyond it).
    """
    h, w = size
    H, W = canvas
    n = coords.shape[1]
    d_row, d_col = torch.gradient(coords[0], dim=(0, 1))  # (n, W, 2): d/d(row) and d/d(column) of the read point
    cols = torch.arange(W, device=coords.device, dtype=coords.dtype).expand(n, W)
    rows = torch.arange(top, top + n, device=coords.device, dtype=coords.dtype).view(-1, 1).expand(n, W)
    coverage = torch.ones_like(coords[0, ..., 0])  # (n, W)
    inside = torch.full_like(coverage, float("inf"))
    for axis, extent_src in ((0, w), (1, h)):  # the left and right sides, then the top and bottom
        gx, gy = d_col[..., axis], d_row[..., axis]  # (n, W): the output gradient of the read point's coordinate
        norm = (gx * gx + gy * gy).sqrt().clamp(min=1e-12)
        for sign, to_edge in ((-1, coords[0, ..., axis] + 0.5), (1, extent_src - 0.5 - coords[0, ..., axis])):
            d = to_edge / norm  # output pixels inside this side
            inside = torch.minimum(inside, d)
            if feather <= 0:
                continue
            # a pixel at least the feather inside this side is covered fully by it (its band is no wider): the
            # rest is worked out only over the rows and columns where it can fall short of 1, a strip along the side
            near = d < feather
            rows_near, cols_near = near.any(1).nonzero(), near.any(0).nonzero()
            if rows_near.numel() == 0:
                continue
            box = (slice(int(rows_near[0]), int(rows_near[-1]) + 1), slice(int(cols_near[0]), int(cols_near[-1]) + 1))
            g, dn = norm[box], d[box]
            vx, vy = sign * gx[box] / g, sign * gy[box] / g  # the output direction towards this side's edge
            # the distances to the canvas's borders on the far side of the edge, along that direction, weighted by
            # how squarely the edge faces each (cos^FACING): the one it faces counts, one it only grazes does not
            ax, ay = vx.abs().clamp(min=1e-4), vy.abs().clamp(min=1e-4)  # 1e-4 ** FACING is no float32 zero
            fx, fy = _power(ax, FACING), _power(ay, FACING)
            c, r = cols[box], rows[box]
            to_x = torch.where(vx < 0, c + 0.5, W - 0.5 - c) / ax
            to_y = torch.where(vy < 0, r + 0.5, H - 0.5 - r) / ay
            depth = ((fx * to_x + fy * to_y) / (fx + fy) - dn).clamp(min=0)  # how far inside the canvas the edge lies
            extent = extent_src / g  # the picture's width (or height) in output pixels
            band = torch.minimum(EDGE_DEPTH * depth, EDGE_SHARE * extent).clamp(max=feather, min=1e-12)
            # a strip beyond the edge that is thin on the canvas and in the picture: the picture mirrored
            mirror = _smoothstep(1 - depth * g.clamp(min=1) * (1 - share**4) / (EDGE_MIRROR * feather))
            coverage[box] *= mirror + (1 - mirror) * _smoothstep(dn / band)
    if feather <= 0:  # no band: the hand-over happens at the edge itself
        return (inside >= 0).to(coords.dtype)[None, None], inside[None]
    return coverage[None, None], inside[None]


def _reflect(coords: Tensor, size: tuple[int, int]) -> Tensor:
    """Read points ``(..., 2)`` beyond a picture of ``size`` mirrored back into it about its border (pixel centres
    at integers: the border is at ``-0.5`` and ``w - 0.5``), so that what is shown beyond the edge continues the
    picture's own content instead of holding its edge pixels."""
    h, w = size
    span = coords.new_tensor([w, h])
    u = torch.remainder(coords + 0.5, 2 * span)
    return torch.where(u < span, u, 2 * span - u) - 0.5


def _mirrored(image: Tensor, frame: Tensor, coords: Tensor, size: tuple[int, int], where: Tensor) -> Tensor:
    """``frame`` ``(1, C, n, W)`` (``image`` read at ``coords`` ``(1, n, W, 2)``) with the pixels ``where``
    ``(1, n, W)`` read again at :func:`_reflect`'s mirrored points."""
    if not bool(where.any()):
        return frame
    mirrored = read(image, _reflect(coords[where], size).view(1, 1, -1, 2), size)  # (1, C, 1, P)
    out = frame.clone()
    out[0][:, where[0]] = mirrored[0, :, 0]
    return out


BEYOND_SHARPNESS = 4.0
"""Where neither picture covers a pixel, the weights of the two follow the inverse of how far beyond its edge each
is read, to this power: the one read nearer its own interior takes over within a short distance of where the two
are equally far out (the weights there are the colour's schedule)."""


FAR = 1e30
"""Output pixels: a distance beyond a picture's edge counts as at most this (a crushed map's distance is infinite)."""


def _dissolve(
    images: tuple[Tensor, Tensor],
    fa: Tensor,
    fb: Tensor,
    map_a: Tensor,
    map_b: Tensor,
    w: float,
    sizes: tuple[tuple[int, int], tuple[int, int]],
    canvas: tuple[int, int],
    top: int,
    feather: float = FEATHER,
) -> Tensor:
    """Cross-dissolve ``(1 - w) fa + w fb``, except where a picture's edge shows in the canvas.

    ``fa`` and ``fb`` ``(1, C, n, W)`` are ``images`` A and B read at ``map_a`` and ``map_b`` ``(1, n, W, 2)``
    (each in its picture's pixels, ``sizes``), rows ``top ..`` of the ``canvas``. With the coverages ``c_a``,
    ``c_b`` of :func:`_coverage` and ``r = c_b / c_a``, the weight of B is ``w r`` where ``c_b <= c_a`` and
    ``1 - (1 - w) / r`` where ``c_b >= c_a``: ``w`` where both cover alike, the picture that covers where only one
    does, and across a band where one picture's coverage ramps while the other's is full, a hand-over spread
    evenly over the whole band whatever ``w`` (``w c_b`` inside B's edge, ``1 - (1 - w) c_a`` inside A's). Where
    neither covers, ``r`` is the ratio of how far beyond its edge each is read, ``(i_a / i_b)^k``
    (:data:`BEYOND_SHARPNESS`): the picture read nearer its own interior takes over. Where the weight falls on a
    picture read beyond its edge, that picture is read mirrored about its border (:func:`_reflect`): its content
    continues there instead of its edge pixels smeared into streaks.
    """
    ca, ia = _coverage(map_a, sizes[0], canvas, top, feather, share=1 - w)
    cb, ib = _coverage(map_b, sizes[1], canvas, top, feather, share=w)
    neither = (ca == 0) & (cb == 0)
    tiny = torch.finfo(ca.dtype).tiny
    if bool(neither.any()):  # the nearer one's share: the other's distance beyond its edge (output pixels)
        ca, cb = ca.clone(), cb.clone()
        out_a = (-ia.unsqueeze(1)[neither]).clamp(min=tiny, max=FAR)
        out_b = (-ib.unsqueeze(1)[neither]).clamp(min=tiny, max=FAR)
        # only their ratio counts: relative to the larger, so that a map that crushes a picture (its stretch near
        # 0, its distances beyond the edge near infinite) cannot overflow the power into inf / inf
        farther = torch.maximum(out_a, out_b)
        ca[neither] = (out_b / farther).pow(BEYOND_SHARPNESS)
        cb[neither] = (out_a / farther).pow(BEYOND_SHARPNESS)
    weight = torch.where(cb <= ca, w * cb / ca.clamp(min=tiny), 1 - (1 - w) * ca / cb.clamp(min=tiny))  # (1, 1, n, W)
    fa = _mirrored(images[0], fa, map_a, sizes[0], (ia < 0) & (weight[:, 0] < 1))
    fb = _mirrored(images[1], fb, map_b, sizes[1], (ib < 0) & (weight[:, 0] > 0))
    return torch.lerp(fa, fb, weight)


def read(image: Tensor, coords: Tensor, size: tuple[int, int]) -> Tensor:
    """Read ``image`` ``(1, C, h, w)`` (bilinear) at ``coords`` ``(1, H', W', 2)`` given in the pixels of a picture of
    ``size`` ``(H, W)``, of which ``image`` is a resized copy (or the picture itself): a morph's maps stay in each
    picture's own pixels while it reads a copy shrunk to the canvas's scale (``(x + 0.5) w / W - 0.5``)."""
    h, w = image.shape[-2:]
    if (h, w) != tuple(size):
        factor = coords.new_tensor([w / size[1], h / size[0]])
        coords = (coords + 0.5) * factor - 0.5
    return sample_map(image, coords, "bilinear")


def on_canvas(
    image: Tensor,
    place: Tensor,
    canvas: tuple[int, int],
    rows: tuple[int, int] | None = None,
    size: tuple[int, int] | None = None,
) -> Tensor:
    """A picture placed on a canvas of ``canvas`` ``(H, W)`` pixels: ``(1, C, r1 - r0, W)``, the canvas's rows
    ``rows`` ``(r0, r1)`` (``None``: all), bilinear.

    ``place`` ``(3, 3)`` takes the picture's pixels to the canvas's
    (:func:`~torchfluidwarp.morph.morphing.placement`); ``image`` ``(1, C, h, w)`` is the picture of ``size``
    ``(H_p, W_p)`` or a resized copy of it (:func:`read`; ``None``: the picture itself). Alpha is read premultiplied
    and returned straight (:func:`~torchfluidwarp.io.images.premultiplied`)."""
    r0, r1 = rows or (0, canvas[0])
    ident = identity_map((r1 - r0, canvas[1]), device=image.device, dtype=torch.float64)
    ident = ident + ident.new_tensor([0.0, float(r0)])
    coords = apply_alignment(torch.linalg.inv(place.double()), ident).to(image.dtype)
    return straight(read(premultiplied(image), coords, size or (image.shape[-2], image.shape[-1])))


def _sample_map(coords: Tensor, at: Tensor) -> Tensor:
    """Read a map ``(1, h, w, 2)`` at pixel positions ``(1, H, W, 2)`` of its grid (bilinear).

    The map's displacement is what is interpolated (and held constant beyond the map's grid), so outside the
    grid the map continues as a translation instead of collapsing onto the edge: the composite stays a proper,
    fold-free map, without a kink where the grid (a fluid box) ends."""
    size = (coords.shape[1], coords.shape[2])
    disp = coords - identity_map(size, device=coords.device, dtype=coords.dtype)
    return at + read_displacement(disp.permute(0, 3, 1, 2), size, at)


def _paper_inverse(flows: list[tuple[Tensor, float]], times: list[float], size: tuple[int, int]) -> list[Tensor]:
    """Maps ``P_s(z)`` into the fluid frame of time ``T`` from the small flows of
    :func:`~torchfluidwarp.morph.fit.paper_flows`:
    ``P_T`` is the identity and ``P_l = P_{l+1} o g^(l)`` with ``g^(l)`` step ``l``'s small backward map."""
    T = len(flows)
    vel0 = flows[0][0]
    current = identity_map(size, device=vel0.device, dtype=vel0.dtype)  # P_T
    step_of = [min(int(s), T - 1) for s in times]  # the step whose small flow each frame's time falls in
    out: list[Tensor | None] = [current if s >= T else None for s in times]
    lowest = min(step_of)
    for step in range(T - 1, lowest - 1, -1):
        vel, dt = flows[step]
        mine = [k for k, s in enumerate(times) if out[k] is None and step_of[k] == step]
        back = [step + 1 - times[k] for k in mine]  # how far back from the step's end each frame lies
        wanted = sorted(set(back) | {1.0})  # the whole step too: it carries on to P_step
        maps = backward_maps(vel, size, dt, times=wanted).unbind(1)
        composed = {frac: _sample_map(current, m) for frac, m in zip(wanted, maps)}
        for k, frac in zip(mine, back):
            out[k] = composed[frac]
        current = composed[1.0]
    return [m for m in out if m is not None]


@dataclass
class Scene:
    """Everything a fitted morph needs to render any frame: the two images ``(1, C, h, w)`` (computed dtype; each
    the picture of ``size_a`` or ``size_b``, or a copy shrunk to the scale the canvas shows it at), the fitted
    velocities ``(1, T, 2, h + 1, w + 1)`` on the fluid's box ``roi`` (canvas pixels, top-left at ``box``), the
    pre-alignment ``M`` ``(3, 3)`` (canvas to canvas) about ``center``, each picture's placement on the canvas
    (``(3, 3)`` from its pixels to the canvas's, one scale factor for both axes) and the rendering settings of
    :func:`morph`."""

    a: Tensor
    b: Tensor
    velocities: Tensor
    dt: float
    steps: int
    M: Tensor
    center: Tensor
    box: tuple[int, int, int, int]
    roi: tuple[int, int]
    inverse: InverseMethod
    motion: Callable[[float], float]  # the shape's schedule: t -> progress (see morph.timing)
    blend: Callable[[float], float]  # the colour's schedule: t -> the weight of image B
    feather: float
    flows: list[tuple[Tensor, float]] | None = None  # inverse="paper": the small flows of fit.paper_flows
    masks: tuple[Tensor, Tensor] | None = None  # a region: soft masks (1, 1, H, W) over A and over B, own pixels
    background: str = "blend"  # outside the region: "a", "b" or "blend" (see morph.regions)
    canvas: tuple[int, int] | None = None  # the frames' (H, W); default A's size
    size_a: tuple[int, int] | None = None  # A's (H, W), of which `a` may be a shrunk copy; default a's size
    size_b: tuple[int, int] | None = None
    place_a: Tensor | None = None  # (3, 3) float64, A's pixels to the canvas's; default the identity
    place_b: Tensor | None = None
    read_a: Tensor = field(init=False, repr=False)  # what the frames read: premultiplied where there is alpha
    read_b: Tensor = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # what the frames read and blend: premultiplied where there is alpha (the module's docstring)
        self.read_a, self.read_b = premultiplied(self.a), premultiplied(self.b)
        eye = torch.eye(3, dtype=torch.float64, device=self.a.device)
        self.size_a = self.size_a or (self.a.shape[-2], self.a.shape[-1])
        self.size_b = self.size_b or (self.b.shape[-2], self.b.shape[-1])
        self.canvas = self.canvas or self.size_a
        self.place_a = eye if self.place_a is None else self.place_a
        self.place_b = eye if self.place_b is None else self.place_b

    @property
    def size(self) -> tuple[int, int]:
        """The frames' ``(H, W)``: the canvas."""
        assert self.canvas is not None
        return self.canvas

    def placed(self, which: str, rows: tuple[int, int]) -> Tensor:
        """Rows ``[r0, r1)`` of picture ``which`` (``"a"`` or ``"b"``) placed on the canvas, ``(1, C, n, W)``: what
        the first (``"a"``) and the last frame show, and a region's background."""
        image, size, place = (
            (self.a, self.size_a, self.place_a) if which == "a" else (self.b, self.size_b, self.place_b)
        )
        assert size is not None and place is not None
        identity = torch.eye(3, dtype=place.dtype, device=place.device)
        if tuple(self.size) == tuple(size) == tuple(image.shape[-2:]) and bool((place == identity).all()):
            return image[:, :, rows[0] : rows[1]]  # the picture itself: no resampling
        return on_canvas(image, place, self.size, rows, size)


@dataclass
class MorphFrames:
    """A morph's frames at some times ``ts`` (``(n,)`` in ``[0, 1]``), from :meth:`MorphResult.render`.

    Attributes:
        frames: ``(n, C, H, W)`` the morph.
        forward: ``(n, C, H, W)`` image A warped forward (pre-alignment included).
        backward: ``(n, C, H, W)`` image B pulled back along the flow.
        maps_a: ``(n, H, W, 2)`` where each output pixel reads image A (A's pixels).
        maps_b: ``(n, H, W, 2)`` where each output pixel reads image B (B's own pixels).
        folded: the number of pixels of ``maps_a`` and ``maps_b`` whose Jacobian determinant is ``<= 0``.
    """

    frames: Tensor
    forward: Tensor
    backward: Tensor
    maps_a: Tensor
    maps_b: Tensor
    folded: int


MAP_PIXELS = 2**23
"""The largest fluid box, in pixels, whose maps are resized to the box's pixels before a frame reads them (2 maps
of 64 MB each at float32). Bilinear reading of the resized map is what the morph's seam figure was tuned on (the
raster's cell edges are blended over a pixel); a larger box reads the maps' rasters directly, which bounds a
6000 x 6000 morph's memory and leaves the maps within a fraction of a pixel of the resized ones."""

BAND_PIXELS = 2**19
"""Output pixels rendered at once: a frame larger than this is rendered in bands of rows, so that its
float64 coordinates and temporaries stay bounded (about 0.08 GB) whatever the picture's size. Half a
megapixel: the 6000 x 6000 morph of ``benchmarks/bench_memory.py`` peaks 0.2 GB lower than with bands of 2**20
pixels, and a 970 x 2204 frame renders as fast."""


def _band(scene: Scene, g: Tensor, k: Tensor, unalign: Tensor, w: float, rows: tuple[int, int]) -> list[Tensor]:
    """One band of rows ``[r0, r1)`` of a frame whose pre-alignment is undone by ``unalign`` ``(3, 3)``, whose
    maps ``g_s`` and ``K_s`` minus the identity are ``g`` and ``k`` ``(1, 2, h_r, w_r)`` (box pixels, on rasters
    over the box, or on the box's pixels) and whose colour weight is ``w``: the frame, A and B warped
    ``(1, C, n, W)``, the maps ``(1, n, W, 2)`` (each in its own picture's pixels) and the folded pixel count,
    over the rows ``r0 - 1`` to ``r1`` (one more row each side, where the picture has one, for the Jacobian's
    central differences)."""
    a, b = scene.read_a, scene.read_b  # premultiplied where they have alpha: straight() below
    H, W = scene.size
    assert scene.place_a is not None and scene.place_b is not None and scene.size_a and scene.size_b
    lo, hi = max(rows[0] - 1, 0), min(rows[1] + 1, H)
    offset = a.new_tensor([scene.box[0], scene.box[1]])
    ident = identity_map((hi - lo, W), device=a.device, dtype=torch.float64)
    ident = ident + ident.new_tensor([0.0, float(lo)])
    z = apply_alignment(unalign, ident).to(a.dtype) - offset  # (1, n, W, 2) in the box
    # canvas pixels to each picture's own: A's placement undone, and B's after the pre-alignment
    to_a = torch.linalg.inv(scene.place_a)
    to_b = torch.linalg.solve(scene.place_b, scene.M.to(scene.place_b))
    map_a = z + read_displacement(g, scene.roi, z) + offset
    if not bool((to_a == torch.eye(3, dtype=to_a.dtype, device=to_a.device)).all()):
        map_a = apply_alignment(to_a, map_a.double()).to(a.dtype)
    map_b = apply_alignment(to_b, (z + read_displacement(k, scene.roi, z) + offset).double()).to(a.dtype)
    fa, fb = read(a, map_a, scene.size_a), read(b, map_b, scene.size_b)
    det_a, det_b = jacobian_determinant(map_a), jacobian_determinant(map_b)  # (1, n, W) each
    sizes = (scene.size_a, scene.size_b)
    frame = _dissolve((a, b), fa, fb, map_a, map_b, w, sizes, (H, W), lo, scene.feather)
    mine = slice(rows[0] - lo, rows[1] - lo)  # the band's own rows
    frame, fa, fb, map_a, map_b = frame[:, :, mine], fa[:, :, mine], fb[:, :, mine], map_a[:, mine], map_b[:, mine]
    if scene.masks is not None:  # the region, carried by each image's map, shows the morph; the rest the background
        ma = read(scene.masks[0], map_a, scene.size_a)
        mb = read(scene.masks[1], map_b, scene.size_b)

        def behind(which: str) -> Tensor:  # the background, premultiplied as the frame is blended
            return premultiplied(scene.placed(which, rows))

        if scene.background == "blend":
            background = torch.lerp(behind("a"), behind("b"), w)
        else:
            background = behind(scene.background)
        frame = composite(frame, background, torch.lerp(ma, mb, w))
    folded = (det_a[:, mine] <= 0).sum() + (det_b[:, mine] <= 0).sum()
    return [straight(frame), straight(fa), straight(fb), map_a, map_b, folded]


def raster_maps(scene: Scene, ts: list[float]) -> tuple[Tensor, Tensor | None]:
    """The maps of the frames at the morph's times ``ts`` on their working rasters over the fluid's box, minus the
    identity (box pixels): ``g_s`` and, for ``inverse="flow"``, ``K_s``, ``(n, 2, h_r, w_r)`` each (``K_s`` is
    ``None`` for ``inverse="paper"``, whose maps :func:`render` builds itself). One pass of the fluid's maps
    through time serves the whole list, so a caller that renders many frames a few at a time passes each few
    their share of one call instead of paying a pass per few."""
    times = [scene.steps * scene.motion(t) for t in ts]  # fluid times, steps
    g = raster_displacements(scene.velocities, scene.roi, scene.dt, times)[0]
    if scene.inverse != "flow":
        return g, None
    return g, raster_displacements(scene.velocities, scene.roi, scene.dt, times, to_end=True)[0]


def raster_bytes(scene: Scene) -> int:
    """Bytes of one frame's :func:`raster_maps`."""
    g = raster_displacements(scene.velocities, scene.roi, scene.dt, [0.0])[0]  # time 0: no step to take
    return g.nbytes * (2 if scene.inverse == "flow" else 1)


def render(
    scene: Scene, ts: list[float], keep: bool = True, rasters: tuple[Tensor, Tensor | None] | None = None
) -> MorphFrames:
    """Render the frames of a fitted morph at the morph's times ``ts`` (increasing, in ``[0, 1]``).

    Frame ``t`` shows the fluid at time ``motion(t) T`` (steps) and image B with weight ``blend(t)``.
    ``keep=False`` keeps the frames only (the warped images and maps come back empty), for streaming.
    ``rasters``: the frames' :func:`raster_maps`, when the caller has them.

    Cost: one pass of the fluid's maps through time (``T`` raster steps) for the whole list, and per frame two
    resamplings of the images and two of the maps; memory grows with ``len(times)`` only, so callers render long
    morphs a few frames at a time. Frames over :data:`BAND_PIXELS` are rendered in bands of rows.
    """
    a, steps = scene.a, scene.steps
    roi, (H, W) = scene.roi, scene.size
    times = [steps * scene.motion(t) for t in ts]  # fluid times, steps
    # the maps live on the fluid's box (box pixels), as displacements: resized once from their working rasters
    # to the box's pixels, or, for a box over MAP_PIXELS, read from the rasters themselves (a few MB whatever the
    # picture's size); each frame reads them where its pixels come from
    box_maps = roi[0] * roi[1] <= MAP_PIXELS
    g, k = raster_maps(scene, ts) if rasters is None else rasters
    g = (upsample_raster(g, roi) if box_maps else g).unsqueeze(1)  # (n, 1, 2, h, w)
    if k is not None:
        k = (upsample_raster(k, roi) if box_maps else k).unsqueeze(1)
    else:
        assert scene.flows is not None
        ident = identity_map(roi, device=a.device, dtype=a.dtype)
        k = torch.stack([(m.to(a.dtype) - ident).permute(0, 3, 1, 2) for m in _paper_inverse(scene.flows, times, roi)])
    n, C = len(ts), a.shape[1]
    rows = max(2, BAND_PIXELS // W)
    frames = a.new_empty(n, C, H, W)
    kept = n if keep else 0  # warped images and maps are held only when asked for
    rest = [
        a.new_empty(kept, C, H, W),
        a.new_empty(kept, C, H, W),
        a.new_empty(kept, H, W, 2),
        a.new_empty(kept, H, W, 2),
    ]
    folded = 0
    for i, s in enumerate(times):
        unalign = torch.linalg.inv(interpolate_alignment(scene.M, s / steps, scene.center))  # the frame's M_s^-1
        for r0 in range(0, H, rows):
            r1 = min(H, r0 + rows)
            frame, *parts, count = _band(scene, g[i], k[i], unalign, scene.blend(ts[i]), (r0, r1))
            frames[i, :, r0:r1] = frame[0]
            if keep:
                fa, fb, map_a, map_b = parts
                rest[0][i, :, r0:r1], rest[1][i, :, r0:r1] = fa[0], fb[0]  # images (n, C, H, W)
                rest[2][i, r0:r1], rest[3][i, r0:r1] = map_a[0], map_b[0]  # maps (n, H, W, 2)
            folded += int(count)
        if scene.masks is None and ts[i] in (0, 1):
            # the endpoints are the inputs placed on the canvas by definition; rendering them reproduces them to
            # sampling round-off (and, for the last, where the pre-alignment has carried A past B's edge)
            frames[i] = scene.placed("a" if ts[i] == 0 else "b", (0, H))[0]
    return MorphFrames(frames, rest[0], rest[1], rest[2], rest[3], folded)
