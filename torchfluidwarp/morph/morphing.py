"""Morphing two images with a fitted fluid flow (the paper's Section on morphing).

A morph is a forward warping ``C_l`` of the source image ``f`` driven by fitted forces, an inverse warping of
the target image ``g``, and a cross-dissolve between them. A global pre-alignment ``M`` (similarity by
default) estimated from the points is interpolated over the morph and composed with the fluid warp, so the
fluid only has to produce the local, non-rigid part.

For a frame at time ``s`` (in fluid steps, ``0..T``) and an output pixel ``y``: ``z = M_s^-1 y`` is the
point in the fluid's frame; image A is read at ``g_s(z)`` (the fluid's backward map) and image B at
``M K_s(z)``, where ``K_s`` carries ``z`` forward from ``s`` to ``T`` through the same velocities
(``inverse="flow"``), or through a chain of small per-step fits (``inverse="paper"``).
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from torchfluidwarp._checks import check_int, check_positive, check_tensor
from torchfluidwarp.control.alignment import AlignKind, apply_alignment, estimate_alignment, interpolate_alignment
from torchfluidwarp.control.keyframes import KeyframeFit, check_points, fit_keyframes
from torchfluidwarp.core.fluid import Viscosity
from torchfluidwarp.core.grid import FluidGrid, mean_pixels_per_cell, rescale_points, scale_factor
from torchfluidwarp.core.spline import tps_fit
from torchfluidwarp.warp.forces import LandmarkForces, solve_midpoints
from torchfluidwarp.warp.layer import _warp_image, backward_maps, identity_map, jacobian_determinant, maps_to_end

__all__ = ["morph", "MorphResult", "resize_pair", "region_of_interest"]


Method = Literal["natural", "paper"]
InverseMethod = Literal["flow", "paper"]
Blend = Literal["linear", "smooth"]


@dataclass
class MorphResult:
    """What :func:`morph` returns.

    Attributes:
        frames: ``(N, C, H, W)`` the morph; frame 0 is image A, frame ``N - 1`` is image B.
        forward_frames: ``(N, C, H, W)`` image A warped forward (pre-alignment included).
        backward_frames: ``(N, C, H, W)`` image B pulled back along the flow.
        maps: ``(N, H, W, 2)`` backward coordinate maps of image A's whole warp (pre-alignment included), in
            A's pixels: ``forward_frames[k] = warp_image(A, maps[k])``. Check them for folds with
            :func:`~torchfluidwarp.warp.layer.jacobian_determinant`.
        maps_b: ``(N, H, W, 2)`` where each frame reads image B (B's pixels, after resizing to A's size).
        fit: the keyframe fit; its ``points``, ``trajectories`` and ``error`` are in the frames' pixel
            coordinates (A's points carried to the last frame, and their distance to B's points).
        alignment: ``(3, 3)`` pre-alignment ``M`` (A's pixels to B's pixels).
        times: ``(N,)`` the fluid time of each frame, in steps.
        seconds: wall time per phase: ``"fit"``, ``"inverse"``, ``"render"``, ``"total"``.
        folded: fraction of the pixels of ``maps`` and ``maps_b`` (all frames) whose Jacobian determinant is
            ``<= 0`` (0 for a fold-free morph; :func:`morph` warns with their number when it is not).
    """

    frames: Tensor
    forward_frames: Tensor
    backward_frames: Tensor
    maps: Tensor
    maps_b: Tensor
    fit: KeyframeFit
    alignment: Tensor
    times: Tensor
    seconds: dict[str, float] = field(default_factory=dict)
    folded: float = 0.0


def _as_image(name: str, image: Tensor) -> Tensor:
    img = check_tensor(name, image, ndim=(3, 4))
    img = img.unsqueeze(0) if img.ndim == 3 else img
    if img.shape[0] != 1:
        raise ValueError(f"{name} must be a single image (C, H, W) or (1, C, H, W), got {tuple(image.shape)}")
    return img


def resize_pair(image_a: Tensor, image_b: Tensor, points_b: Tensor) -> tuple[Tensor, Tensor]:
    """Bring ``image_b`` ``(1, C, H_b, W_b)`` to image A's size, scaling ``points_b`` ``(M, 2)`` to match.

    Pixel centres stay at integers: ``x' = (x + 0.5) W_a / W_b - 0.5``. Channel counts are matched too
    (grey to RGB, alpha dropped) so the two can be blended.
    """
    Ha, Wa = image_a.shape[-2:]
    Hb, Wb = image_b.shape[-2:]
    if (Ha, Wa) != (Hb, Wb):
        image_b = F.interpolate(image_b, size=(Ha, Wa), mode="bilinear", align_corners=False, antialias=True)
        scale = scale_factor((Hb, Wb), (Ha, Wa), device=points_b.device, dtype=points_b.dtype)
        points_b = rescale_points(points_b, scale)
    ca, cb = image_a.shape[1], image_b.shape[1]
    if cb != ca:
        if cb == 1:
            image_b = image_b.expand(-1, ca, -1, -1) if ca in (3, 4) else image_b
        if ca == 1:
            image_b = image_b[:, :3].mean(1, keepdim=True)
        elif image_b.shape[1] != ca:
            extra = torch.ones_like(image_b[:, :1]).expand(-1, ca - 3, -1, -1)
            image_b = torch.cat([image_b[:, :3], extra], 1) if ca == 4 else image_b[:, :ca]
    return image_b, points_b


def region_of_interest(points: Tensor, margin: float) -> tuple[int, int, int, int]:
    """Pixel box ``(x0, y0, x1, y1)`` (x1, y1 exclusive) around ``points`` ``(M, 2)``, grown by ``margin`` times
    its size on each side. It may reach beyond the image: points near an edge then stay clear of the fluid's
    walls, where a fluid cannot move them."""
    lo, hi = points.min(0).values, points.max(0).values
    ext = (hi - lo).clamp(min=8.0)
    x0, y0 = (lo - margin * ext).floor().tolist()
    x1, y1 = (hi + margin * ext).ceil().tolist()
    return int(x0), int(y0), int(x1) + 1, int(y1) + 1


def _blend_weights(times: Tensor, T: int, blend: Blend) -> Tensor:
    u = times / T
    if blend == "linear":
        return u
    if blend == "smooth":
        return u * u * (3 - 2 * u)  # smoothstep: ease in and out
    raise ValueError(f"blend must be 'linear' or 'smooth', got {blend!r}")


PAD = 0.125
"""The natural morph's fluid box reaches this fraction of the image's longer side beyond each edge: the walls,
which no flow crosses, stay outside the picture, and the forces fade to zero between the picture and the walls."""

MIN_AREA = 0.1
"""The natural morph never squeezes an area below this fraction of its size in the middle frame (see
:func:`_straight_paths`): a margin that keeps the discrete flow and its resampled maps from folding."""

DEFAULTS: dict[str, dict[str, Any]] = {
    "natural": {"grid": (80, 80), "compressible": True, "smoothness": 3.0, "max_iter": 30},
    "paper": {"grid": (64, 64), "compressible": False, "smoothness": 5.0, "max_iter": 100},
}
"""Per-method defaults of :func:`morph`'s ``grid``, ``compressible``, ``smoothness`` and ``max_iter``. The
natural morph's grid covers the picture and a margin of :data:`PAD` around it: 80 cells are about 8 pixels of
a 512-pixel picture each, as 64 cells over the paper's box."""


FEATHER = 64.0
"""Output pixels: the cross-dissolve hands a frame over to the other image within this distance inside an
image's edge (see :func:`_dissolve`), so neither image's edge, nor the edge pixels that sampling smears beyond
it, shows as a line."""


def _coverage(coords: Tensor, det: Tensor, size: tuple[int, int]) -> Tensor:
    """``(1, 1, H, W)`` in ``[0, 1]``: 1 where a map ``(1, H, W, 2)`` reads at least :data:`FEATHER` output pixels
    inside an image of ``size``, falling linearly to 0 at its edge (and 0 beyond). Distances in the image are
    converted to output pixels by the map's local scale, ``sqrt |det J|`` source pixels per output pixel, from the
    map's Jacobian determinant ``det`` ``(1, H, W)``."""
    H, W = size
    x, y = coords[..., 0], coords[..., 1]
    inside = torch.minimum(torch.minimum(x + 0.5, W - 0.5 - x), torch.minimum(y + 0.5, H - 0.5 - y))
    scale = det.abs().clamp(min=1e-12).sqrt()
    return (inside / (scale * FEATHER)).clamp(0, 1).unsqueeze(1)


def _dissolve(
    fa: Tensor, fb: Tensor, map_a: Tensor, map_b: Tensor, det_a: Tensor, det_b: Tensor, w: float, size: tuple[int, int]
) -> Tensor:
    """Cross-dissolve ``(1 - w) fa + w fb``, except near and beyond an image's edge.

    Beyond it, sampling holds the edge pixels and smears them into streaks (the pre-alignment can reach far beyond
    the other image), and at it the picture ends in a line; so the weight moves toward the image that is read
    further inside, ``w' = w c_b / ((1 - w) c_a + w c_b)`` with the coverages ``c`` of :func:`_coverage`. Where both
    read at least :data:`FEATHER` output pixels inside, or both beyond, it is ``w``.
    """
    ca, cb = _coverage(map_a, det_a, size), _coverage(map_b, det_b, size)
    den = (1 - w) * ca + w * cb
    weight = torch.where(den > 0, w * cb / den.clamp(min=1e-12), torch.full_like(den, w))
    return torch.lerp(fa, fb, weight)


def _sample_map(coords: Tensor, at: Tensor) -> Tensor:
    """Read a map ``(1, h, w, 2)`` at pixel positions ``(1, H, W, 2)`` of its grid (bilinear).

    The map's displacement is what is interpolated (and held constant beyond the map's grid), so outside the
    grid the map continues as a translation instead of collapsing onto the edge: the composite stays a proper,
    fold-free map, without a kink where the grid (a fluid box) ends."""
    disp = coords - identity_map((coords.shape[1], coords.shape[2]), dtype=coords.dtype)
    return at + _warp_image(disp.permute(0, 3, 1, 2), at, "bilinear").permute(0, 2, 3, 1)


def _paper_inverse(fit: KeyframeFit, times: list[float], size: tuple[int, int], kwargs: dict) -> list[Tensor]:
    """The paper's stepwise inverse warping: maps ``P_s(z)`` into the fluid frame of time ``T``.

    For ``l = T-1 .. 0`` a one-step fit carries the points from their step-``l+1`` positions to their step-``l``
    positions; ``P_l = P_{l+1} o g^(l)`` with ``g^(l)`` that small flow's backward map.
    """
    traj = fit.trajectories  # (1, T + 1, M, 2) in the fluid frame
    T = traj.shape[1] - 1
    current = identity_map(size, dtype=traj.dtype)  # P_T
    by_step: dict[int, list[tuple[float, Tensor]]] = {}
    for s in times:
        by_step.setdefault(min(int(s), T - 1) if s < T else T, []).append((s, None))  # type: ignore[arg-type]
    out: dict[float, Tensor] = {float(T): current} if T in by_step else {}
    for step in range(T - 1, -1, -1):
        small = fit_keyframes(traj[:, step + 1], traj[:, step], steps=1, **kwargs)
        vel = small.warp.rollout(small.forces, size).velocities
        wanted = sorted({step + 1 - s for s, _ in by_step.get(step, [])} | {1.0})
        maps = backward_maps(vel, size, small.warp.dt, times=wanted)
        for frac, m in zip(wanted, maps.unbind(1)):
            composed = _sample_map(current, m)
            if frac == 1.0:
                nxt = composed
            out[float(step + 1 - frac)] = composed
        current = nxt
    return [out[float(s)] for s in times]


def _render(
    a: Tensor,
    b: Tensor,
    fit: KeyframeFit,
    M: Tensor,
    center: Tensor,
    box: tuple[int, int, int, int],
    size: tuple[int, int],
    roi: tuple[int, int],
    steps: int,
    n: int,
    inverse: InverseMethod,
    blend: Blend,
    fit_kwargs: dict[str, Any],
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor, float, int]:
    """Render the frames of a fitted morph (see :func:`morph`); the last value counts the folded map pixels."""
    times = torch.linspace(0, steps, n, dtype=torch.float64)  # fluid time of each frame, on the CPU: scalars
    time_list = [float(s) for s in times]
    time_list[-1] = float(steps)
    velocities = fit.warp.rollout(fit.forces, roi).velocities.to(a.dtype)
    # the maps live on the fluid's box (box pixels); each frame reads them where its pixels come from
    g = backward_maps(velocities, roi, fit.warp.dt, time_list)[0].unsqueeze(1)  # (N, 1, h_r, w_r, 2)
    if inverse == "flow":
        k_maps = maps_to_end(velocities, roi, fit.warp.dt, time_list)[0].unsqueeze(1)
    else:
        small_kwargs = {**fit_kwargs, "progress": False}
        k_maps = torch.cat(_paper_inverse(fit, time_list, roi, small_kwargs)).to(a.dtype).unsqueeze(1)
    t_inv = time.perf_counter()
    offset = torch.tensor([box[0], box[1]], dtype=a.dtype, device=a.device)

    weights = _blend_weights(times, steps, blend)
    ident = identity_map(size, dtype=torch.float64)
    out, fwd, bwd, maps_a, maps_b = [], [], [], [], []
    folded = 0
    for k, s in enumerate(time_list):
        Mk = interpolate_alignment(M, s / steps, center)
        z = apply_alignment(torch.linalg.inv(Mk), ident).to(a.dtype) - offset  # (1, H, W, 2) in the box
        map_a = _sample_map(g[k], z) + offset
        k_at = _sample_map(k_maps[k], z) + offset
        map_b = apply_alignment(M, k_at.double()).to(a.dtype)
        fa, fb = _warp_image(a, map_a, "bilinear"), _warp_image(b, map_b, "bilinear")
        det_a, det_b = jacobian_determinant(map_a), jacobian_determinant(map_b)  # (1, H, W) each
        folded += int((det_a <= 0).sum()) + int((det_b <= 0).sum())
        out.append(_dissolve(fa, fb, map_a, map_b, det_a, det_b, float(weights[k]), size))
        fwd.append(fa)
        bwd.append(fb)
        maps_a.append(map_a)
        maps_b.append(map_b)
    frames_t = torch.cat(out)
    # the endpoints are the inputs by definition; rendering them reproduces them to sampling round-off
    frames_t[0], frames_t[-1] = a[0], b[0]
    return frames_t, torch.cat(fwd), torch.cat(bwd), torch.cat(maps_a), torch.cat(maps_b), times, t_inv, folded


def _check_marks(pa: Tensor, pb: Tensor) -> None:
    """Refuse marks that cannot be morphed, and warn about marks whose order crosses."""
    for name, p in (("points_a", pa), ("points_b", pb)):
        d = torch.cdist(p.double(), p.double())
        d.fill_diagonal_(math.inf)
        i, j = torch.nonzero(d < 1e-6, as_tuple=True)
        pairs = [(int(a), int(b)) for a, b in zip(i, j) if a < b]
        if pairs:
            raise ValueError(
                f"{name} repeats points: indices {', '.join(f'{a} and {b}' for a, b in pairs[:5])} are at the same "
                "position; each feature must be marked once"
            )
    # a pair of marks crosses when the segment between them turns by more than 90 degrees relative to the
    # rest of the marks, or when close marks (under a tenth of the spread) end up far apart (over half)
    if pa.shape[0] >= 3:
        M = estimate_alignment(pa.double(), pb.double(), "similarity")
        qa, qb = apply_alignment(M, pa.double()), pb.double()
        da, db = qa[:, None] - qa[None], qb[:, None] - qb[None]  # (M, M, 2)
        spread = float((qb - qb.mean(0)).norm(dim=-1).max())
        la, lb = da.norm(dim=-1), db.norm(dim=-1)
        turned = ((da * db).sum(-1) < 0) & (la > 0.02 * spread) & (lb > 0.02 * spread)
        torn = (la < 0.1 * spread) & (lb > 0.5 * spread)
        bad = torch.triu(turned | torn, diagonal=1).nonzero().tolist()
        if bad:
            listed = ", ".join(f"{a} and {b}" for a, b in bad[:5]) + (" ..." if len(bad) > 5 else "")
            warnings.warn(
                f"the marks cross: points {listed} swap sides or tear apart between A and B, which no smooth morph "
                "can do without folding; check their order (result.fit.error shows which points were not reached)",
                RuntimeWarning,
                stacklevel=3,
            )


def _least_area(travel: Tensor, spacing: float) -> float:
    """The least area ratio ``det(I + sigma J)`` over ``sigma`` in ``[-1/2, 1/2]`` of a field ``(n, n, 2)`` of
    displacements ``D`` sampled ``spacing`` pixels apart: how far the straight paths ``m + sigma D(m)`` of the
    natural morph squeeze the picture, relative to its middle frame."""
    dux_dy, dux_dx = torch.gradient(travel[..., 0], spacing=spacing)
    duy_dy, duy_dx = torch.gradient(travel[..., 1], spacing=spacing)
    trace, det = dux_dx + duy_dy, dux_dx * duy_dy - dux_dy * duy_dx
    # det(I + sigma J) = 1 + sigma trace + sigma^2 det: a parabola; its least value is at an end or its vertex
    safe = torch.where(det > 0, det, torch.ones_like(det))
    vertex = -trace / (2 * safe)
    inner = (det > 0) & (vertex.abs() < 0.5)
    ends = torch.minimum(1 + 0.5 * trace + 0.25 * det, 1 - 0.5 * trace + 0.25 * det)
    least = torch.where(inner, 1 - trace.square() / (4 * safe), ends)
    return float(least.min())


def _straight_paths(src: Tensor, tgt: Tensor, inside: tuple[float, float, float, float]) -> tuple[Tensor, Tensor]:
    """The natural morph's motion: midpoints and displacements ``(M, 2)`` with ``m - d / 2 = src``.

    The marks travel from ``src`` to ``tgt`` on straight lines, ``m = (src + tgt) / 2``, ``d = tgt - src``,
    unless the spline ``D`` through them would squeeze part of the picture (the rectangle ``inside``) below
    :data:`MIN_AREA` of its area on the way: marks that cross, or squeeze a region to nothing. Then the
    spline's smoothing (:func:`~torchfluidwarp.core.spline.tps_fit`) is raised, by bisection on its logarithm, until
    none does, and each mark travels as that spline says; the marks it then misses show in ``fit.error``.
    """
    x0, y0, x1, y1 = inside
    n = 64
    spacing = max(x1 - x0, y1 - y0) / (n - 1)
    gy, gx = torch.meshgrid(
        torch.linspace(y0, y1, n, dtype=torch.float64, device=src.device),
        torch.linspace(x0, x1, n, dtype=torch.float64, device=src.device),
        indexing="ij",
    )
    at = torch.stack([gx, gy], -1).reshape(-1, 2)
    mids, disp = 0.5 * (src + tgt), tgt - src

    def least(smoothing: float) -> float:
        return _least_area(tps_fit(mids, disp, smoothing)(at).view(n, n, 2), spacing)

    if least(0.0) >= MIN_AREA:
        return mids, disp
    lo, hi = -8.0, 4.0  # log10 of the smoothing: from interpolating to nearly affine
    for _ in range(14):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if least(10.0**mid) >= MIN_AREA else (mid, hi)
    travel = tps_fit(mids, disp, 10.0**hi)
    m = solve_midpoints(travel, src, -0.5)
    return m, travel(m)


def _fit_natural(
    pa: Tensor,
    target: Tensor,
    size: tuple[int, int],
    steps: int,
    fit_kwargs: dict[str, Any],
    warm_start: KeyframeFit | None,
) -> tuple[KeyframeFit, tuple[int, int, int, int]]:
    """The natural morph's fit: straight paths, a thin-plate-spline kick, L-BFGS corrections (see :func:`morph`)."""
    H, W = size
    pad = max(1, round(PAD * max(H, W)))
    box = (-pad, -pad, W + pad, H + pad)
    offset = torch.tensor([-pad, -pad], dtype=torch.float64, device=pa.device)
    src = pa.double() - offset
    inside = (pad - 0.5, pad - 0.5, pad + W - 0.5, pad + H - 0.5)
    mids, disp = _straight_paths(src, target - offset, inside)
    # the ends stay clear of the walls, where the forces fade out
    end = torch.minimum(mids + disp / 2, src.new_tensor([W + 1.5 * pad, H + 1.5 * pad])).clamp(min=pad / 2)
    mids, disp = (src + end) / 2, end - src
    forces = LandmarkForces(mids, disp, steps, inside=inside)
    previous = None if warm_start is None else getattr(warm_start.forces, "weight", None)
    if previous is not None and previous.shape == forces.weight.shape:
        with torch.no_grad():
            forces.weight.copy_(previous)
    along = torch.linspace(0, 1, steps + 1, dtype=torch.float64, device=pa.device).view(-1, 1, 1)
    straight = mids + (along - 0.5) * disp  # (T + 1, M, 2) box pixels
    keyframes = [(t, straight[t]) for t in range(1, steps + 1)]
    fit = fit_keyframes(src, keyframes, steps=steps, forces=forces, image_size=(H + 2 * pad, W + 2 * pad), **fit_kwargs)
    return fit, box


def morph(
    image_a: Tensor,
    image_b: Tensor,
    points_a: Tensor,
    points_b: Tensor,
    *,
    frames: int = 30,
    method: Method = "natural",
    grid: FluidGrid | int | tuple[int, int] | None = None,
    steps: int = 10,
    control: tuple[int, int] | int = (8, 8),
    viscosity: Viscosity | nn.Module = 0.0,
    align: AlignKind | None = "similarity",
    inverse: InverseMethod = "flow",
    blend: Blend = "linear",
    compressible: bool | float | None = None,
    smoothness: float | None = None,
    max_iter: int | None = None,
    tolerance: float = 0.05,
    margin: float | None = 0.5,
    warm_start: KeyframeFit | None = None,
    progress: bool = True,
) -> MorphResult:
    """Morph ``image_a`` into ``image_b`` so that ``points_a`` travel to ``points_b``.

    Two methods (``method``):

    * ``"natural"`` (default): every marked point travels on a straight line at constant speed, and the rest
      of the picture moves as a thin-plate spline between the points says. The fluid is compressible and
      inviscid and covers the whole picture (its walls lie :data:`PAD` beyond the edges); one kick at step 0
      (:class:`~torchfluidwarp.warp.forces.LandmarkForces`) sets it moving, after which every particle coasts on
      a straight line (Burgers' equation), and ``max_iter`` L-BFGS iterations correct the kicks so that the
      points stay on their paths at every step. Regions change size as the marks say; the maps never fold
      where the spline does not, and no box edge shows. ``control`` and ``margin`` do not apply.
    * ``"paper"``: the paper's keyframe fit: a :class:`~torchfluidwarp.warp.forces.ControlGrid` of forces, fitted
      so that the points reach their targets at the last step, in an incompressible fluid (every region keeps
      its area) over a box around the points (``margin``).

    Args:
        image_a: ``(C, H, W)`` or ``(1, C, H, W)`` source image in ``[0, 1]``; it sets the output size.
        image_b: target image; resized to A's size if needed (its points are scaled to match).
        points_a, points_b: ``(M, 2)`` corresponding points ``(x, y)`` in each image's pixels; ``"natural"``
            needs ``M >= 3`` points, not all on one line.
        frames: number of output frames ``N >= 2``.
        method: ``"natural"`` or ``"paper"`` (see above).
        grid, steps, viscosity: the fluid (see :func:`fit_keyframes`); ``grid`` cells cover the fluid's box
            (default per method, :data:`DEFAULTS`: 80 x 80 for ``"natural"``, 64 x 64 for ``"paper"``).
        control: ``(K_y, K_x)`` control points per step of ``"paper"``'s control grid.
        align: global pre-alignment ``"similarity"`` (default), ``"affine"`` or ``None``.
        inverse: how B is pulled back: ``"flow"`` (default: along the same fitted velocities, no second fit)
            or ``"paper"`` (the paper's stepwise chain of one-step fits; slower, for comparison).
        blend: cross-dissolve schedule, ``"linear"`` (the paper's) or ``"smooth"`` (ease in and out). Where a
            frame reads one image beyond its edge, the other image is shown instead (over :data:`FEATHER`
            pixels), rather than the first image's edge pixels smeared into streaks.
        compressible: ``True`` to let regions change area (skips the projection) or a weight in ``[0, 1]``;
            default ``True`` for ``"natural"`` and ``False`` (the paper's incompressible fluid) for ``"paper"``.
        smoothness: how strongly the fit keeps the flow calm (default per method, :data:`DEFAULTS`).
            ``"natural"``: the weight on changes to the points' straight-line velocities, in pixels^2 of point
            error per (pixel per step)^2 of velocity change, the same whatever the image or grid size; 0 lets
            the fit bend the paths as it likes to reach the points. ``"paper"``: the weight on
            :func:`~torchfluidwarp.control.keyframes.velocity_gradient_energy`, in fluid cells^2 per pixel^2 of error,
            scaled by the square of the pixels per fluid cell.
        max_iter: L-BFGS iterations (default per method: 30 for ``"natural"``, which starts on its paths,
            100 for ``"paper"``, which starts from rest).
        tolerance: pixels; the fit stops once every point is this close to its target (at every step for
            ``"natural"``).
        margin: ``"paper"`` only: the fluid fills a box around the points (A's and their targets) grown by
            this fraction of its size on each side; the rest of the picture follows the pre-alignment only.
            ``None`` makes the fluid cover exactly the whole image (targets beyond it are clamped onto it).
        warm_start: a previous :class:`KeyframeFit` of the same method whose control values start the
            optimisation (interactive use); ignored when its shape does not match.
        progress: show progress bars.

    Returns:
        a :class:`MorphResult`.

    Raises:
        ValueError: different point counts, points outside their image, repeated points, non-finite values,
            ``frames < 2``, fewer than 3 points or points on one line for ``"natural"``.

    Warns:
        RuntimeWarning: marks that cross (swap sides or tear apart between A and B), naming them; maps that
            fold, with the number of folded pixels.
    """
    t0 = time.perf_counter()
    a = _as_image("image_a", image_a)
    b = _as_image("image_b", image_b)
    n = check_int("frames", frames, minimum=2)
    pa = check_points("points_a", points_a, (a.shape[-2], a.shape[-1]))[0]
    pb = check_points("points_b", points_b, (b.shape[-2], b.shape[-1]))[0]
    if pa.shape[0] != pb.shape[0]:
        raise ValueError(f"points_a has {pa.shape[0]} points but points_b has {pb.shape[0]}")
    if method not in DEFAULTS:
        raise ValueError(f"method must be 'natural' or 'paper', got {method!r}")
    if inverse not in ("flow", "paper"):
        raise ValueError(f"inverse must be 'flow' or 'paper', got {inverse!r}")
    if method == "natural" and pa.shape[0] < 3:
        raise ValueError(f"method='natural' needs at least 3 points, got {pa.shape[0]}; method='paper' takes fewer")
    steps = check_int("steps", steps)
    defaults = DEFAULTS[method]
    compressible = defaults["compressible"] if compressible is None else compressible
    grid = defaults["grid"] if grid is None else grid
    smoothness = defaults["smoothness"] if smoothness is None else smoothness
    smoothness = check_positive("smoothness", smoothness, allow_zero=True)
    max_iter = check_int("max_iter", defaults["max_iter"] if max_iter is None else max_iter)
    _check_marks(pa, pb)
    b, pb = resize_pair(a, b, pb)
    H, W = a.shape[-2:]
    size = (H, W)
    M = estimate_alignment(pa.double(), pb.double(), align)
    center = pa.double().mean(0)
    # the fluid moves A's points to where B's points are in A's (unaligned) frame
    target = apply_alignment(torch.linalg.inv(M), pb.double())
    fit_kwargs: dict[str, Any] = dict(
        grid=grid,
        viscosity=viscosity,
        compressible=compressible,
        max_iter=max_iter,
        tolerance=tolerance,
        progress=progress,
    )
    if method == "natural":
        fit, box = _fit_natural(pa, target, size, steps, {**fit_kwargs, "regularization": smoothness}, warm_start)
        roi = (box[3] - box[1], box[2] - box[0])
        fit_kwargs["image_size"] = roi
    else:
        if margin is None:
            box = (0, 0, W, H)
            target = torch.stack([target[:, 0].clamp(-0.5, W - 0.5), target[:, 1].clamp(-0.5, H - 0.5)], -1)
        else:
            box = region_of_interest(torch.cat([pa.double(), target]), margin)
        roi = (box[3] - box[1], box[2] - box[0])
        offset = torch.tensor([box[0], box[1]], dtype=torch.float64)
        fit_kwargs.update(image_size=roi, control=control, smoothness=smoothness * mean_pixels_per_cell(roi, grid) ** 2)
        fit = fit_keyframes(
            pa.double() - offset,
            target - offset,
            steps=steps,
            forces=None if warm_start is None else warm_start.forces,
            **fit_kwargs,
        )
    offset = torch.tensor([box[0], box[1]], dtype=torch.float64)
    t_fit = time.perf_counter()

    with torch.no_grad():  # the fit is done: rendering needs no graph
        result = _render(a, b, fit, M, center, box, size, roi, steps, n, inverse, blend, fit_kwargs)
    frames_t, fwd, bwd, maps_a, maps_b, times, t_inv, n_folded = result
    t_render = time.perf_counter()

    traj = torch.stack(
        [
            apply_alignment(interpolate_alignment(M, t / steps, center), fit.trajectories[:, t] + offset)
            for t in range(steps + 1)
        ],
        dim=1,
    )
    err = (traj[:, -1] - pb.to(traj.dtype)).norm(dim=-1)
    message = (
        f"{fit.message}; in the last frame's pixels: mean error {float(err.mean()):.4f} px, "
        f"max {float(err.max()):.4f} px"
    )
    fit = dataclasses.replace(fit, trajectories=traj, points=traj[:, -1], error=err, message=message)
    n_pixels = maps_a.shape[:3].numel() + maps_b.shape[:3].numel()
    folded = n_folded / n_pixels
    if n_folded:
        warnings.warn(
            f"the morph's maps fold on {n_folded} of {n_pixels} pixels over all frames of "
            "both images: the flow crushes part of a picture onto itself; check the marks for points that cross "
            "(result.fit.error names the points not reached), or raise smoothness",
            RuntimeWarning,
            stacklevel=2,
        )
    return MorphResult(
        frames=frames_t,
        forward_frames=fwd,
        backward_frames=bwd,
        maps=maps_a,
        maps_b=maps_b,
        fit=fit,
        alignment=M,
        times=times,
        seconds={"fit": t_fit - t0, "inverse": t_inv - t_fit, "render": t_render - t_inv, "total": t_render - t0},
        folded=folded,
    )
