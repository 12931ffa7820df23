"""Rendering a fitted morph: each frame's maps for image A and image B, and the cross-dissolve.

A frame at fluid time ``s`` (steps, ``0..T``) and an output pixel ``y``: ``z = M_s^-1 y`` is the point in the
fluid's frame; image A is read at ``g_s(z)`` (the fluid's backward map) and image B at ``M K_s(z)``, where
``K_s`` carries ``z`` forward from ``s`` to ``T`` through the same velocities (``inverse="flow"``), or through a
chain of small per-step fits (``inverse="paper"``). Maps are ``(1, H, W, 2)`` in pixels, ``(x, y)``, pixel
centres at integers.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from torchfluidwarp.control.alignment import apply_alignment, interpolate_alignment
from torchfluidwarp.morph.regions import composite
from torchfluidwarp.morph.settings import FEATHER, InverseMethod
from torchfluidwarp.warp.frames import identity_map, jacobian_determinant, sample_map
from torchfluidwarp.warp.maps import backward_maps, raster_displacements, read_displacement, upsample_raster


def _coverage(coords: Tensor, det: Tensor, size: tuple[int, int], feather: float = FEATHER) -> Tensor:
    """``(1, 1, H, W)`` in ``[0, 1]``: 1 where a map ``(1, H, W, 2)`` reads at least ``feather`` output pixels
    inside an image of ``size``, falling linearly to 0 at its edge (and 0 beyond). Distances in the image are
    converted to output pixels by the map's local scale, ``sqrt |det J|`` source pixels per output pixel, from the
    map's Jacobian determinant ``det`` ``(1, H, W)``."""
    H, W = size
    x, y = coords[..., 0], coords[..., 1]
    inside = torch.minimum(torch.minimum(x + 0.5, W - 0.5 - x), torch.minimum(y + 0.5, H - 0.5 - y))
    scale = det.abs().clamp(min=1e-12).sqrt()
    if feather <= 0:  # no band: the hand-over happens at the edge itself
        return (inside >= 0).to(coords.dtype).unsqueeze(1)
    return (inside / (scale * feather)).clamp(0, 1).unsqueeze(1)


def _dissolve(
    fa: Tensor,
    fb: Tensor,
    map_a: Tensor,
    map_b: Tensor,
    det_a: Tensor,
    det_b: Tensor,
    w: float,
    size: tuple[int, int],
    feather: float = FEATHER,
    size_b: tuple[int, int] | None = None,
) -> Tensor:
    """Cross-dissolve ``(1 - w) fa + w fb``, except near and beyond an image's edge.

    Beyond it, sampling holds the edge pixels and smears them into streaks (the pre-alignment can reach far beyond
    the other image), and at it the picture ends in a line; so the weight moves toward the image that is read
    further inside, ``w' = w c_b / ((1 - w) c_a + w c_b)`` with the coverages ``c`` of :func:`_coverage`. Where both
    read at least ``feather`` output pixels inside, or both beyond, it is ``w``.
    """
    ca, cb = _coverage(map_a, det_a, size, feather), _coverage(map_b, det_b, size, feather)
    den = (1 - w) * ca + w * cb
    weight = torch.where(den > 0, w * cb / den.clamp(min=1e-12), torch.full_like(den, w))
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

    def __post_init__(self) -> None:
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
        H, W = self.size
        identity = torch.eye(3, dtype=place.dtype, device=place.device)
        if (H, W) == tuple(size) == tuple(image.shape[-2:]) and bool((place == identity).all()):
            return image[:, :, rows[0] : rows[1]]  # the picture itself: no resampling
        ident = identity_map((rows[1] - rows[0], W), device=image.device, dtype=torch.float64)
        ident = ident + ident.new_tensor([0.0, float(rows[0])])
        return read(image, apply_alignment(torch.linalg.inv(place), ident).to(image.dtype), size)


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

BAND_PIXELS = 2**20
"""Output pixels rendered at once: a frame larger than this is rendered in bands of rows, so that its
float64 coordinates and temporaries stay bounded (about 0.15 GB) whatever the picture's size."""


def _band(scene: Scene, g: Tensor, k: Tensor, unalign: Tensor, w: float, rows: tuple[int, int]) -> list[Tensor]:
    """One band of rows ``[r0, r1)`` of a frame whose pre-alignment is undone by ``unalign`` ``(3, 3)``, whose
    maps ``g_s`` and ``K_s`` minus the identity are ``g`` and ``k`` ``(1, 2, h_r, w_r)`` (box pixels, on rasters
    over the box, or on the box's pixels) and whose colour weight is ``w``: the frame, A and B warped
    ``(1, C, n, W)``, the maps ``(1, n, W, 2)`` (each in its own picture's pixels) and the folded pixel count,
    over the rows ``r0 - 1`` to ``r1`` (one more row each side, where the picture has one, for the Jacobian's
    central differences)."""
    a, b = scene.a, scene.b
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
    frame = _dissolve(fa, fb, map_a, map_b, det_a, det_b, w, scene.size_a, scene.feather, scene.size_b)
    mine = slice(rows[0] - lo, rows[1] - lo)  # the band's own rows
    frame, fa, fb, map_a, map_b = frame[:, :, mine], fa[:, :, mine], fb[:, :, mine], map_a[:, mine], map_b[:, mine]
    if scene.masks is not None:  # the region, carried by each image's map, shows the morph; the rest the background
        ma = read(scene.masks[0], map_a, scene.size_a)
        mb = read(scene.masks[1], map_b, scene.size_b)
        if scene.background == "a":
            background = scene.placed("a", rows)
        elif scene.background == "b":
            background = scene.placed("b", rows)
        else:
            background = torch.lerp(scene.placed("a", rows), scene.placed("b", rows), w)
        frame = composite(frame, background, torch.lerp(ma, mb, w))
    folded = (det_a[:, mine] <= 0).sum() + (det_b[:, mine] <= 0).sum()
    return [frame, fa, fb, map_a, map_b, folded]


def render(scene: Scene, ts: list[float], keep: bool = True) -> MorphFrames:
    """Render the frames of a fitted morph at the morph's times ``ts`` (increasing, in ``[0, 1]``).

    Frame ``t`` shows the fluid at time ``motion(t) T`` (steps) and image B with weight ``blend(t)``.
    ``keep=False`` keeps the frames only (the warped images and maps come back empty), for streaming.

    Cost: one pass of the fluid's maps through time (``T`` raster steps) for the whole list, and per frame two
    resamplings of the images and two of the maps; memory grows with ``len(times)`` only, so callers render long
    morphs a few frames at a time. Frames over :data:`BAND_PIXELS` are rendered in bands of rows.
    """
    a, steps = scene.a, scene.steps
    roi, (H, W), dt = scene.roi, scene.size, scene.dt
    times = [steps * scene.motion(t) for t in ts]  # fluid times, steps
    # the maps live on the fluid's box (box pixels), as displacements: resized once from their working rasters
    # to the box's pixels, or, for a box over MAP_PIXELS, read from the rasters themselves (a few MB whatever the
    # picture's size); each frame reads them where its pixels come from
    box_maps = roi[0] * roi[1] <= MAP_PIXELS
    g = raster_displacements(scene.velocities, roi, dt, times)[0]  # (n, 2, h_r, w_r)
    g = (upsample_raster(g, roi) if box_maps else g).unsqueeze(1)  # (n, 1, 2, h, w)
    if scene.inverse == "flow":
        k = raster_displacements(scene.velocities, roi, dt, times, to_end=True)[0]
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
