"""Fitting a morph's flow: the natural morph's straight paths and its fit, the paper's keyframe fit, and the paper
inverse's small fits (the marks are checked first, :mod:`~torchfluidwarp.morph.marks`).

Points are ``(M, 2)`` in pixels, ``(x, y)``, pixel centres at integers; the fluid's box is given in the same
pixels as ``(x0, y0, x1, y1)``. Every fit here is in the fluid box's frame: its points, trajectories, errors,
warp and forces are in pixels of the box, whose top-left pixel is ``(x0, y0)`` of image A.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import torch
from torch import Tensor, nn

from torchfluidwarp._checks import warn
from torchfluidwarp.control.alignment import apply_alignment
from torchfluidwarp.control.keyframes import KeyframeFit, Keyframes, fit_keyframes
from torchfluidwarp.core.grid import FluidGrid, SquareCells, mean_pixels_per_cell
from torchfluidwarp.core.spline import tps_fit
from torchfluidwarp.correspond.halfway import least_area_ratio
from torchfluidwarp.errors import InputError
from torchfluidwarp.morph.marks import crossing_pairs
from torchfluidwarp.morph.settings import MorphSettings, NaturalSettings, PaperSettings
from torchfluidwarp.warp.landmarks import LandmarkForces, solve_midpoints

PAD = 0.125
"""The natural morph's fluid box reaches this fraction of the image's longer side beyond each edge: the walls,
which no flow crosses, stay outside the picture, and the forces fade to zero between the picture and the walls."""

MIN_AREA = 0.1
"""The natural morph never squeezes an area below this fraction of its size in the middle frame (see
:func:`straight_paths`): a margin that keeps the discrete flow and its resampled maps from folding."""


def _squeeze_points(mids: Tensor, inside: tuple[float, float, float, float]) -> Tensor:
    """``(N, 2)``: where :func:`straight_paths` looks for a squeeze: a 64 x 64 lattice over the rectangle
    ``inside``, and between each of the marks' midpoints ``mids`` ``(M, 2)`` and its six nearest, 7 points along
    the segment and 7 on each side of it, a quarter of its length away. Marks close together squeeze the picture
    between them at scales a lattice misses: eyelids that close, a few pixels apart."""
    x0, y0, x1, y1 = inside
    gy, gx = torch.meshgrid(
        torch.linspace(y0, y1, 64, dtype=torch.float64, device=mids.device),
        torch.linspace(x0, x1, 64, dtype=torch.float64, device=mids.device),
        indexing="ij",
    )
    gaps = torch.cdist(mids, mids).fill_diagonal_(math.inf)
    near = gaps.topk(min(6, mids.shape[0] - 1), largest=False).indices  # (M, k)
    start, step = mids[:, None, None], (mids[near] - mids[:, None])[:, :, None]  # (M, 1, 1, 2), (M, k, 1, 2)
    along = start + step * torch.arange(1, 8, dtype=torch.float64, device=mids.device).view(1, 1, -1, 1) / 8
    side = 0.25 * torch.stack([-step[..., 1], step[..., 0]], -1)
    points = torch.cat(
        [torch.stack([gx, gy], -1).reshape(-1, 2), *(p.reshape(-1, 2) for p in (along, along + side, along - side))]
    )
    low, high = points.new_tensor([x0, y0]), points.new_tensor([x1, y1])
    return points[((points >= low) & (points <= high)).all(1)]


def _least_area(travel: Callable[[Tensor], Tensor], at: Tensor) -> tuple[float, Tensor]:
    """The least area ratio ``det(I + sigma J)`` over ``sigma`` in ``[-1/2, 1/2]`` and the points ``at``
    ``(N, 2)`` of a displacement field ``travel`` (pixels): how far the straight paths ``m + sigma D(m)`` of the
    natural morph squeeze the picture, relative to its middle frame, and the point ``(2,)`` where it is least.
    ``J`` is exact (autograd), not differenced."""
    x = at.detach().clone().requires_grad_(True)
    with torch.enable_grad():
        u = travel(x)
        rows = [torch.autograd.grad(u[:, i].sum(), x, retain_graph=i == 0)[0] for i in range(2)]
    least = least_area_ratio(torch.stack(rows, -2))
    least = torch.where(torch.isfinite(least), least, math.inf)
    i = int(least.argmin())
    return float(least[i]), at[i]


def straight_paths(src: Tensor, tgt: Tensor, inside: tuple[float, float, float, float]) -> tuple[Tensor, Tensor]:
    """The natural morph's motion: midpoints and displacements ``(M, 2)`` with ``m - d / 2 = src``.

    The marks travel from ``src`` to ``tgt`` on straight lines, ``m = (src + tgt) / 2``, ``d = tgt - src``,
    unless the spline ``D`` through them would squeeze part of the picture (the rectangle ``inside``) below
    :data:`MIN_AREA` of its area on the way: marks that cross, or squeeze a region to nothing. Where marks cross
    or squeeze (a head that turns: the far jaw line passes behind the nose, the far cheek shrinks to a sliver),
    marks are released one at a time until the spline through the others squeezes no part below
    :data:`MIN_AREA`: first the marks of crossing pairs (:func:`~torchfluidwarp.morph.marks.crossing_pairs`),
    then those around the worst squeeze, the most shrunken first (:func:`_shrink`), at most :data:`RELEASE` of
    them. The marks kept still
    travel straight, so the features that both pictures show meet at every frame, and the released ones follow
    the spline (the hidden side compresses). Where that is not enough, the spline's smoothing
    (:func:`~torchfluidwarp.core.spline.tps_fit`) is raised, by bisection on its logarithm, until no part is
    squeezed, and each mark travels as that spline says. The marks not met show in the morph's ``result.error``.
    """
    mids, disp = 0.5 * (src + tgt), tgt - src
    _check_spread(mids)
    at = _squeeze_points(mids, inside)
    n = mids.shape[0]
    keep = torch.ones(n, dtype=torch.bool, device=mids.device)

    def least(smoothing: float) -> tuple[float, Tensor | None]:
        try:
            return _least_area(tps_fit(mids[keep], disp[keep], smoothing), at)
        except InputError:  # marks that swap places share a midpoint: no spline interpolates both
            return -math.inf, None

    area, where = least(0.0)
    if area >= MIN_AREA:
        return mids, disp
    shrink = _shrink(src, tgt)
    live = crossing_pairs(src, tgt).tolist() if n >= 3 else []
    while area < MIN_AREA and int(keep.sum()) - 1 >= max(3, (1 - RELEASE) * n):
        live = [pair for pair in live if bool(keep[pair[0]] & keep[pair[1]])]
        if live:  # first the marks that cross
            candidates = sorted({i for pair in live for i in pair})
        elif where is not None:  # then those around the worst squeeze
            kept = keep.nonzero()[:, 0]
            nearest = (mids[kept] - where).norm(dim=-1).topk(min(4, len(kept)), largest=False).indices
            candidates = kept[nearest].tolist()
        else:
            break
        keep[min(candidates, key=lambda i: float(shrink[i]))] = False
        area, where = least(0.0)
    smoothing = 0.0
    if area < MIN_AREA:
        lo, hi = -8.0, 4.0  # log10 of the smoothing: from interpolating to nearly affine
        for _ in range(14):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if least(10.0**mid)[0] >= MIN_AREA else (mid, hi)
        smoothing = 10.0**hi
    try:
        travel = tps_fit(mids[keep], disp[keep], smoothing)
    except InputError as exc:
        raise InputError(TOO_FEW_MIDPOINTS) from exc
    m = solve_midpoints(travel, src, -0.5)
    if smoothing == 0.0:  # the kept marks travel straight, exactly
        m[keep] = mids[keep]
    return m, travel(m)


def _check_spread(mids: Tensor) -> None:
    """Refuse marks whose midpoints ``(M, 2)`` (pixels) lie on one line: no spline says how the picture moves off
    it (the caller's points are to blame, so the error names them). A picture's marks against its mirror image's,
    not reordered, give such midpoints: :func:`~torchfluidwarp.morph.marks.check_marks` warned of them first."""
    distinct = torch.unique(torch.round(mids / SPREAD), dim=0).shape[0]
    if distinct < 3:
        raise InputError(TOO_FEW_MIDPOINTS, argument="points_a")
    spread = torch.linalg.svdvals(mids - mids.mean(0))
    if float(spread[-1]) >= SPREAD and float(spread[-1]) < THIN * float(spread[0]):
        warn(
            f"points_a and points_b: the {mids.shape[0]} marks' midpoints lie close to one line (their spread "
            f"across it is {float(spread[-1] / spread[0]):.1%} of their spread along it), so the morph guesses how "
            "the picture moves away from it and may stretch it; add a mark away from that line",
            RuntimeWarning,
        )
    if float(spread[-1]) < SPREAD:
        raise InputError(
            f"points_a and points_b: the {mids.shape[0]} marks' midpoints (halfway between each pair) lie on one "
            "line, so nothing says how the picture moves off it; add a mark away from that line (the natural "
            "method needs 3 or more whose midpoints are not in a row)",
            argument="points_a",
        )


TOO_FEW_MIDPOINTS = (
    "points_a and points_b: the marks' straight paths meet in too few distinct midpoints (marks that swap places "
    "meet halfway) to guide the morph; check that both list the same features in the same order"
)
"""The refusal of marks that leave fewer than 3 distinct midpoints, before the paths and after some are let go."""


SPREAD = 1e-3
"""Pixels: the least spread of the marks' midpoints across their best-fitting line (the second singular value of
the centred midpoints) for :func:`straight_paths`; below it they lie on one line."""


THIN = 0.05
"""The natural morph warns of marks whose midpoints spread across their best-fitting line less than this share of
their spread along it (the two singular values of the centred midpoints; :func:`_check_spread`): six marks on two
eyes, 33 px by 1 px, gave a grossly stretched face without a word. The 68 landmarks of two faces spread across at
77 % or more of their spread along (every ordered pair of ``benchmarks/bench_morph_quality.py``'s faces, all 68
or the 46 it gives; scratch, twenty-first session)."""


RELEASE = 0.5
"""At most this share of the marks is released from their straight paths (:func:`straight_paths`); beyond it the
spline through those kept is smoothed instead."""


def _shrink(src: Tensor, tgt: Tensor) -> Tensor:
    """``(M,)``: how much each mark's neighbourhood (its 4 nearest in ``src``) changes size between ``src`` and
    ``tgt`` ``(M, 2)``, as the ratio of the mean distances taken below 1 either way: 1 where it keeps its size,
    small where it shrinks away (the side of a turning head that goes out of sight in B, or comes into sight from
    A). :func:`straight_paths` releases the most shrunken first."""
    near = torch.cdist(src, src).fill_diagonal_(math.inf).topk(min(4, len(src) - 1), largest=False).indices
    ratio = (tgt[near] - tgt[:, None]).norm(dim=-1).mean(1) / (src[near] - src[:, None]).norm(dim=-1).mean(1)
    return torch.minimum(ratio, 1 / ratio).nan_to_num(0.0)


WALL_CLEARANCE = 1.75
"""The natural morph's margin (:data:`PAD`) is widened, with the fluid's cells kept their size, to this many
times the farthest the picture's edge travels towards the walls. The forces fade to zero across the margin (a
half cosine, steepest at ``pi / 2`` per margin width), so the particles between the edge and the walls travel
less than the edge, and the margin shrinks by up to ``pi / 2`` times the edge's travel over the margin's width:
at 1.75 it keeps a tenth of its area (:data:`MIN_AREA`), instead of being crushed against the walls until it
folds (turned heads, whose marks' spline carries the face's stretch on to the picture's edge). The travel it
answers is capped at the picture's longer side. A viscosity field or module (``NaturalSettings.viscosity``) is
given over the user's grid, so the margin then keeps its :data:`PAD`."""


def _margin_for(
    travel: Callable[[Tensor], Tensor], inside: tuple[float, float, float, float], device: torch.device
) -> int:
    """Pixels of margin (:data:`WALL_CLEARANCE`) that the ``travel`` ``(N, 2) -> (N, 2)`` (box pixels) of the
    picture's edge, the rectangle ``inside``, needs: from 64 points per side, each side's outward component."""
    x0, y0, x1, y1 = inside
    t = torch.linspace(0, 1, 64, dtype=torch.float64, device=device)
    far = 0.0
    for (ax, ay), (bx, by), outward in (
        ((x0, y0), (x1, y0), (0.0, -1.0)),
        ((x1, y0), (x1, y1), (1.0, 0.0)),
        ((x0, y1), (x1, y1), (0.0, 1.0)),
        ((x0, y0), (x0, y1), (-1.0, 0.0)),
    ):
        side = torch.stack([ax + t * (bx - ax), ay + t * (by - ay)], -1)
        far = max(far, float((travel(side) * side.new_tensor(outward)).sum(-1).max()))
    return math.ceil(WALL_CLEARANCE * min(far, max(x1 - x0, y1 - y0)))


def _frame(
    pad: int, region: tuple[int, int, int, int], device: torch.device
) -> tuple[tuple[int, int, int, int], Tensor, tuple[float, float, float, float]]:
    """The natural morph's fluid box around the ``region`` ``(x0, y0, x1, y1)`` of A's pixels (``x1, y1``
    exclusive) with ``pad`` pixels of margin: the box ``(x0, y0, x1, y1)`` in A's pixels, the offset ``(2,)``
    float64 from box pixels to A's, and the region's rectangle ``inside`` in box pixels (its pixels' outer
    edges)."""
    x0, y0, x1, y1 = region
    offset = torch.tensor([x0 - pad, y0 - pad], dtype=torch.float64, device=device)
    inside = (pad - 0.5, pad - 0.5, pad + x1 - x0 - 0.5, pad + y1 - y0 - 0.5)
    return (x0 - pad, y0 - pad, x1 + pad, y1 + pad), offset, inside


FOCUS = 0.5
"""The natural morph's fluid covers only what its last frame shows of A (:func:`focus`) when that is under this
fraction of A's area: a small face in a wide photograph morphed into a large one."""

FOCUS_MARGIN = 0.1
""":func:`focus` grows the region the last frame shows by this fraction of its longer side on each side (the
fluid's own margin, :data:`PAD`, lies beyond it). On the four zooms of ``benchmarks/bench_framing.py`` the marks
end 0.13-0.57 px off at 0.1, 0.17-1.08 px at 0.25 (5.24 px at most over the whole picture)."""


def focus(size: tuple[int, int], alignment: Tensor, points: Tensor) -> tuple[int, int, int, int] | None:
    """The part of A, a region ``(x0, y0, x1, y1)`` of its pixels (``x1, y1`` exclusive), that the natural morph's
    fluid covers when the last frame shows little of A; ``None``: the whole picture.

    The last frame shows A's pixels where the pre-alignment ``alignment`` ``(3, 3)`` (canvas pixels to canvas
    pixels, A's place to B's) sends them onto the canvas of ``size`` ``(H, W)``. Where B's face is several times
    the size of A's (a small face in a group photograph morphed into a portrait) that is a small part of A, and on
    the whole picture the fluid's cells would be larger than the gaps between the marks, which the pre-alignment's
    zoom then magnifies in the last frame. That part, the ``points`` ``(N, 2)`` (both ends of the marks' travel,
    canvas pixels) and :data:`FOCUS_MARGIN` around them, when under :data:`FOCUS` of the canvas's area, is the
    region: the fluid's cells shrink by the zoom, and the rest of A moves by the pre-alignment alone, as the posed
    border points of :func:`~torchfluidwarp.correspond.auto.border_pairs` say it does."""
    H, W = size
    m, p = alignment.double(), points.double()
    corners = m.new_tensor([[-0.5, -0.5], [W - 0.5, -0.5], [-0.5, H - 0.5], [W - 0.5, H - 0.5]])
    seen = apply_alignment(torch.linalg.inv(m), corners)
    lo = torch.minimum(seen.min(0).values.clamp(min=-0.5), p.min(0).values)
    hi = torch.maximum(torch.minimum(seen.max(0).values, m.new_tensor([W - 0.5, H - 0.5])), p.max(0).values)
    grow = FOCUS_MARGIN * float((hi - lo).max())
    x0, y0 = (int(math.floor(max(float(v) - grow + 0.5, 0))) for v in lo)
    x1, y1 = int(math.ceil(min(float(hi[0]) + grow + 0.5, W))), int(math.ceil(min(float(hi[1]) + grow + 0.5, H)))
    if (x1 - x0) * (y1 - y0) >= FOCUS * H * W:
        return None
    return x0, y0, x1, y1


def fluid_grid(settings: MorphSettings, box: tuple[int, int]) -> FluidGrid:
    """The fluid's cells over a box of ``box`` ``(H, W)`` pixels: ``settings.grid``, square cells
    (:class:`~torchfluidwarp.core.grid.SquareCells`) laid over the box."""
    grid = settings.grid
    return grid.over(box) if isinstance(grid, SquareCells) else FluidGrid.of(grid)  # type: ignore[arg-type]


def fit_natural(
    pa: Tensor,
    target: Tensor,
    size: tuple[int, int],
    settings: NaturalSettings,
    warm_start: KeyframeFit | None,
    progress: bool,
    dense: Callable[[Tensor, Tensor], Callable[[Tensor], Tensor]] | None = None,
    found: bool = False,
    max_memory: float | None = None,
    region: tuple[int, int, int, int] | None = None,
) -> tuple[KeyframeFit, tuple[int, int, int, int], Tensor]:
    """The natural morph's fit: straight paths, a thin-plate-spline kick, L-BFGS corrections (see
    :class:`~torchfluidwarp.morph.settings.NaturalSettings`), for the marks and for a lattice of points between
    them (``settings.lattice``), whose paths the whole travel ``D + R`` gives.

    Args:
        pa: ``(M, 2)`` A's points, A's pixels.
        target: ``(M, 2)`` where they must go, A's pixels (B's points taken back through the pre-alignment).
        size: ``(H, W)`` of image A.
        settings: the method's settings.
        warm_start: a previous natural fit whose kicks' corrections start this one (:func:`warm_corrections`).
        progress: tqdm bars.
        dense: given the marks' midpoints and travels ``(M, 2)`` (A's pixels), the residual travel ``R`` between
            them, points ``(N, 2)`` -> ``(N, 2)``, A's pixels
            (:func:`~torchfluidwarp.correspond.halfway.halfway_alignment`), which the forces carry.
        found: the marks were found automatically (``morph(match=...)``), not given: they only start the
            pixels' alignment, and each of A's marks then travels where the pixels' whole travel ``D + R`` takes
            it (B's side re-placed), instead of ``R`` bending around marks that may be wrong.
        max_memory: bytes the fit may set out to hold, checked by
            :func:`~torchfluidwarp.control.keyframes.fit_keyframes` on the grid as the margin widened it
            (``morph(max_memory=...)``; ``None``: its default).
        region: ``(x0, y0, x1, y1)``, A's pixels (``x1, y1`` exclusive): the part of A the fluid covers
            (:func:`focus`), which must hold the marks' ends; ``None``: the whole picture.

    Returns:
        The fit, in the box's frame, of the marks alone (the lattice's points are left out of its points, paths
        and errors); the box ``(x0, y0, x1, y1)`` in A's pixels: the picture (or the ``region``) and :data:`PAD`
        of its longer side around it, or more (:data:`WALL_CLEARANCE`); and ``(M, 2)`` where the paths end A's
        marks, A's pixels: ``target``, except where a mark was let go so as not to fold (:func:`straight_paths`:
        where the spline takes it), where it was held clear of the walls, and, when ``found``, where the pixels
        re-placed it.
    """
    region = region or (0, 0, size[1], size[0])
    H, W = region[3] - region[1], region[2] - region[0]
    steps = settings.steps
    pad = max(1, round(PAD * max(H, W)))
    box, offset, inside = _frame(pad, region, pa.device)
    src = pa.double() - offset
    far = src.new_tensor([W + 1.5 * pad, H + 1.5 * pad])

    def clear(mids: Tensor, disp: Tensor) -> tuple[Tensor, Tensor]:  # the ends stay clear of the walls' fade
        end = torch.minimum(mids + disp / 2, far).clamp(min=pad / 2)
        return (src + end) / 2, end - src

    mids, disp = clear(*straight_paths(src, target - offset, inside))
    travel: Callable[[Tensor], Tensor] = tps_fit(mids, disp)  # D, box pixels
    if dense is not None:
        travel = _plus(travel, dense(mids + offset, disp), offset)  # D + R (R reads canvas pixels)
        if found:  # the marks follow the pixels: A's marks travel where the whole travel D + R takes them
            mids = solve_midpoints(travel, src, -0.5)
            mids, disp = clear(mids, travel(mids))
    grid = fluid_grid(settings, (H + 2 * pad, W + 2 * pad)).shape
    wider = _margin_for(travel, inside, mids.device)
    uniform = not isinstance(settings.viscosity, (nn.Module, Tensor)) or settings.viscosity.ndim == 0
    # the walls move out, and the fluid's cells keep their size (a viscosity field or module is given over the
    # user's grid: then the margin is kept)
    if wider > pad and uniform:
        shift = wider - pad
        grid = (
            math.ceil(grid[0] * (H + 2 * wider) / (H + 2 * pad)),
            math.ceil(grid[1] * (W + 2 * wider) / (W + 2 * pad)),
        )
        pad, src, mids = wider, src + shift, mids + shift
        box, offset, inside = _frame(pad, region, pa.device)
        travel = _shifted(travel, -shift)  # it was made in the narrower box's pixels
    marks, weights = mids.shape[0], None
    if settings.lattice is not None:  # points between the marks, held on the paths of the whole travel too
        extra, moved = _lattice(mids, travel, inside, settings.lattice * (box[2] - box[0]) / grid[1])
        mids, disp, src = torch.cat([mids, extra]), torch.cat([disp, moved]), torch.cat([src, extra - moved / 2])
        weights = torch.cat([mids.new_ones(marks), mids.new_full((len(extra),), LATTICE_WEIGHT)])
    whole = None if dense is None and mids.shape[0] == marks else travel
    forces = LandmarkForces(mids, disp, steps, inside=inside, travel=whole, origin=(float(offset[0]), float(offset[1])))
    if warm_start is not None:
        warm_corrections(forces, warm_start.forces)
    along = torch.linspace(0, 1, steps + 1, dtype=torch.float64, device=pa.device).view(-1, 1, 1)
    straight = mids + (along - 0.5) * disp  # (T + 1, M, 2) box pixels
    keyframes = [(t, straight[t]) for t in range(1, steps + 1)]
    fit = fit_keyframes(
        src,
        keyframes,
        steps=steps,
        forces=forces,
        image_size=(H + 2 * pad, W + 2 * pad),
        grid=grid,
        viscosity=settings.viscosity,
        compressible=settings.compressible,
        regularization=settings.straightness,
        max_iter=settings.max_iter,
        tolerance=settings.tolerance,
        progress=progress,
        max_memory=max_memory,  # the fit's own check, on the grid the margin may have widened
        weights=weights,
    )
    if mids.shape[0] > marks:  # the result speaks of the marks alone
        fit = dataclasses.replace(
            fit,
            points=fit.points[:, :marks],
            trajectories=fit.trajectories[:, :, :marks],
            error=fit.error[:, :marks],
            keyframe_errors=[(t, e[:, :marks]) for t, e in fit.keyframe_errors],
        )
    mids, disp = mids[:marks], disp[:marks]
    return fit, box, mids + disp / 2 + offset


LATTICE_WEIGHT = 0.5
"""The weight of a lattice point's path error in the natural fit (``NaturalSettings.lattice``), a mark's being 1:
the marks come first. On the bundled demo pair (30 L-BFGS iterations) the marks end 0.19 px from B's on average
without a lattice, 0.26 px with one weighted as a mark, and 0.19 px at 0.5; at 0.3 (0.16 px there) the automatic
morph of one hand-marked pair of ``benchmarks/bench_hand_marks.py`` fitted its marks worse (0.44 px against 0.18)
and folded B's map in its first frames, which 0.5 and 1 do not."""


def _plus(
    travel: Callable[[Tensor], Tensor], residual: Callable[[Tensor], Tensor], offset: Tensor
) -> Callable[[Tensor], Tensor]:
    """Points ``(N, 2)`` -> ``(N, 2)`` pixels: ``travel(p) + residual(p + offset)``."""
    return lambda p: travel(p) + residual(p + offset)


def _shifted(travel: Callable[[Tensor], Tensor], by: float) -> Callable[[Tensor], Tensor]:
    """Points ``(N, 2)`` -> ``(N, 2)`` pixels: ``travel(p + by)``."""
    return lambda p: travel(p + by)


def warm_corrections(forces: LandmarkForces, previous: nn.Module) -> int:
    """Start ``forces``' corrections (``weight`` ``(1, T, N, 2)``) from a previous natural fit's forces: each of
    its points takes the corrections of the previous fit's point whose midpoint is nearest, where that is within
    half the median distance between this fit's neighbouring points (a mark dragged by a few pixels keeps its
    corrections; the lattice between the marks, whose points change in number as the travel changes, keeps
    those at the same places); the rest start at 0. The midpoints are compared in A's pixels (each fit's box has
    its own origin, :attr:`LandmarkForces.origin`, which moves when a dragged mark widens the margin). Returns
    how many points were started.
    """
    if not isinstance(previous, LandmarkForces) or previous.weight.shape[:2] != forces.weight.shape[:2]:
        return 0
    shift = forces.midpoints.new_tensor(
        [previous.origin[0] - forces.origin[0], previous.origin[1] - forces.origin[1]]
    )  # the previous box's pixels to this box's
    new, old = forces.midpoints, previous.midpoints.to(forces.midpoints) + shift  # 3 or more each
    gaps = torch.cdist(new, new)
    gaps.fill_diagonal_(float("inf"))
    reach = 0.5 * float(gaps.min(1).values.median())
    distance, nearest = torch.cdist(new, old).min(1)
    keep = distance <= reach
    with torch.no_grad():
        forces.weight[:, :, keep] = previous.weight.detach().to(forces.weight)[:, :, nearest[keep]]
    return int(keep.sum())


def _lattice(mids: Tensor, travel: Callable[[Tensor], Tensor], inside: tuple[float, float, float, float],
             spacing: float) -> tuple[Tensor, Tensor]:  # fmt: skip
    """``(N, 2)`` middle-frame points on a lattice of ``spacing`` pixels over ``inside``, at least a third of it from
    every mark's midpoint ``mids``, whose two ends ``p -+ travel(p) / 2`` lie inside, and their travel ``(N, 2)``."""
    x0, y0, x1, y1 = inside
    # from half a spacing in, as many as fall short of the far side (none along a side under half a spacing)
    ys, xs = (
        lo + spacing / 2 + spacing * torch.arange(n, dtype=mids.dtype, device=mids.device)
        for lo, n in ((y0, math.ceil(max(0.0, y1 - y0 - spacing / 2) / spacing)),
                      (x0, math.ceil(max(0.0, x1 - x0 - spacing / 2) / spacing)))
    )  # fmt: skip
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    p = torch.stack([gx, gy], -1).reshape(-1, 2)
    p = p[torch.cdist(p, mids).min(1).values > spacing / 3]
    d = travel(p)
    low, high = p.new_tensor([x0, y0]), p.new_tensor([x1, y1])
    ok = torch.ones(p.shape[0], dtype=torch.bool, device=p.device)
    for end in (p - d / 2, p + d / 2):
        ok &= ((end >= low) & (end <= high)).all(1)
    return p[ok], d[ok]


def fit_paper(
    source: Tensor,
    target: Keyframes,
    size: tuple[int, int],
    settings: PaperSettings,
    forces: nn.Module | None,
    progress: bool,
    max_memory: float | None = None,
) -> KeyframeFit:
    """The paper's keyframe fit of a control grid (:class:`~torchfluidwarp.morph.settings.PaperSettings`) on a
    box of ``size`` ``(H, W)`` pixels: ``source`` ``(M, 2)`` box pixels to ``target`` at the last step.
    ``settings.smoothness`` is scaled by the square of the pixels per fluid cell (its unit is fluid cells^2 per
    pixel^2 of point error); ``forces``: a previous fit's, to warm-start from; ``max_memory``: the limit of
    :func:`~torchfluidwarp.control.keyframes.fit_keyframes`' memory check (bytes; ``None``: its default)."""
    grid = fluid_grid(settings, size)
    return fit_keyframes(
        source,
        target,
        steps=settings.steps,
        image_size=size,
        grid=grid,
        control=settings.control,
        viscosity=settings.viscosity,
        compressible=settings.compressible,
        smoothness=settings.smoothness * mean_pixels_per_cell(size, grid) ** 2,
        max_iter=settings.max_iter,
        tolerance=settings.tolerance,
        forces=forces,
        progress=progress,
        max_memory=max_memory,
    )


def paper_flows(fit: KeyframeFit, size: tuple[int, int], settings: MorphSettings) -> list[tuple[Tensor, float]]:
    """The paper's stepwise inverse warping, fitted: one small flow per step, ``(velocities, dt)`` for
    ``l = 0 .. T-1``, each carrying the points from their step-``l+1`` positions back to their step-``l`` ones.

    ``fit`` and the flows are in the fluid box's frame, of ``size`` ``(H, W)`` pixels. The small fits use the
    method's fluid and stopping rules; for the paper's method also its control grid and smoothness, for the
    natural method :func:`~torchfluidwarp.control.keyframes.fit_keyframes`' default control grid.
    """
    traj = fit.trajectories  # (1, T + 1, M, 2) box pixels
    flows = []
    for step in range(traj.shape[1] - 1):
        source, target = traj[:, step + 1], traj[:, step]
        if isinstance(settings, PaperSettings):
            small = fit_paper(source, target, size, dataclasses.replace(settings, steps=1), None, False)
        else:
            small = fit_keyframes(
                source,
                target,
                steps=1,
                image_size=size,
                grid=fit.warp.grid,  # the forward fit's, over the same box (its margin may have widened)
                viscosity=settings.viscosity,
                compressible=settings.compressible,
                max_iter=settings.max_iter,
                tolerance=settings.tolerance,
                progress=False,
            )
        flows.append((small.warp.rollout(small.forces, size).velocities, small.warp.dt))
    return flows
