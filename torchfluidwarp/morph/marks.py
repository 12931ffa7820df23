"""The marks of a morph, checked before the fit and after it: marks that repeat, cross or tear apart, the pose
they agree on (the pre-alignment), and the warnings about marks the fit let go or met slowly.

Points are ``(M, 2)`` in pixels, ``(x, y)``, pixel centres at integers.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import torch
from torch import Tensor

from torchfluidwarp._checks import argument_of, warn
from torchfluidwarp.control.alignment import AlignKind, apply_alignment, estimate_alignment, robust_alignment
from torchfluidwarp.control.keyframes import check_points
from torchfluidwarp.core.grid import mean_pixels_per_cell
from torchfluidwarp.errors import AdvisedWarning, Hint, InputError

MIN_POSE_FIT = 0.25
"""The least share of B's marks' spread that the pre-alignment must explain (:func:`pose`). The 68 marks of two
different faces give 0.73 to 1 (median 0.96 over the ordered pairs of ``benchmarks/bench_morph_quality.py``'s
faces); 10 marks listed in a random order give a median of 0.07, and 20 of 0.04. Below it the least-squares
transform shrinks towards a point, and its inverse would throw B's marks far outside the picture."""


def pose(pa: Tensor, pb: Tensor, align: AlignKind | None, numbers: Tensor | None = None) -> Tensor:
    """The morph's global pre-alignment ``(3, 3)`` float64, A's pixels to B's, of kind ``align``: the least
    squares (:func:`~torchfluidwarp.control.alignment.estimate_alignment`) when it explains at least
    :data:`TRUSTED_POSE_FIT` of the spread of B's marks ``pb`` ``(M, 2)``.

    Below it a few marks may be far off (one put in the wrong place drags the least squares): the pose that most
    of them agree on (:func:`~torchfluidwarp.control.alignment.robust_alignment`) is taken, with a warning that
    names the others with their distances, when those agreeing are at least :data:`POSE_MAJORITY` of the marks
    and it explains :data:`ROBUST_POSE_FIT` of their spread. Failing that, the least squares if it explains
    :data:`MIN_POSE_FIT`, else the identity, with a warning: marks that do not agree on a pose are better morphed
    by the flow alone. ``numbers`` ``(M,)``: what the warning calls each mark, the caller's index (default its
    place in ``pa``)."""
    a, b = pa.double(), pb.double()
    if align in (None, "none") or float((b - b.mean(0)).square().sum()) == 0:
        return estimate_alignment(a, b, align)
    M, far, explained = _agreed(a, b, align)
    if M is not None and far:
        off = (apply_alignment(M, a[far]) - b[far]).norm(dim=-1)  # the frames' pixels, as pa and pb
        order = off.argsort(descending=True).tolist()  # the farthest first
        named = [far[k] if numbers is None else int(numbers[far[k]]) for k in order]
        one = len(far) == 1
        warn(
            f"{_marks_off(named, off[order])} of points_a and points_b {'lies' if one else 'lie'} far from the "
            f"{align} pose the other {a.shape[0] - len(far)} marks agree on (the frames' pixels), which the morph's "
            f"pre-alignment follows; check where {'it is' if one else 'they are'} marked",
            RuntimeWarning,
        )
    if M is not None:
        return M
    warn(
        f"the marks do not agree on a pose: the {align} pre-alignment explains {max(explained, 0):.0%} of how "
        f"points_b spread (under {MIN_POSE_FIT:.0%}), so the morph runs without it; check that points_a and "
        "points_b list the same features in the same order",
        RuntimeWarning,
    )
    return torch.eye(3, dtype=torch.float64, device=a.device)


def _agreed(a: Tensor, b: Tensor, kind: AlignKind) -> tuple[Tensor | None, list[int], float]:
    """The pose of kind ``kind`` that the marks ``a``, ``b`` ``(M, 2)`` float64 agree on (:func:`pose`), the
    indices of the marks that lie far from it (none when the least squares is taken) and the share of the spread
    that the least squares explains; ``None`` for the pose when they agree on none."""
    M = estimate_alignment(a, b, kind)
    explained = _explained(M, a, b)
    if explained >= TRUSTED_POSE_FIT:
        return M, [], explained
    R, agree = robust_alignment(a, b, kind)
    kept = int(agree.sum())
    if (
        kept < a.shape[0]
        and kept >= POSE_MAJORITY * a.shape[0]
        and _explained(R, a[agree], b[agree]) >= ROBUST_POSE_FIT
    ):
        return R, (~agree).nonzero()[:, 0].tolist(), explained
    return (M if explained >= MIN_POSE_FIT else None), [], explained


TRUSTED_POSE_FIT = 0.6
"""Where the least squares through all the marks explains at least this share of B's marks' spread, :func:`pose`
takes it as it is; below, a pose that most marks agree on is looked for first (a mark put in the wrong place in
A dragged the least squares of the bundled astronaut -> cat down to 42 %, and made every mark cross). Real face
pairs stay above it: over the ordered pairs of ``benchmarks/bench_morph_quality.py``'s faces, with all 68 marks or
the 46 it gives, similarity or affine, 0.68 to 1 (the least: einstein and t1-5, turned 21 and -51 degrees); over
``benchmarks/bench_hand_marks.py``'s hand marks 0.74 to 0.96 (scratch, twenty-first session)."""

POSE_MAJORITY = 0.75
"""The least share of the marks that must agree on a pose for :func:`pose` to follow them when the least squares
through all of them explains too little: a few marks placed wrong are outvoted, marks in no common order are
not."""

ROBUST_POSE_FIT = 0.5
"""The least share of the agreeing marks' spread that the pose they agree on must explain (:func:`pose`). Scratch
draws through :func:`pose` (300 each, ``/tmp`` script, twenty-first session): the bundled astronaut's 23 marks
against the cat's shuffled were never taken for a pose; 6, 8 or 12 random marks against as many others were in
0-3 of 300, 30 in none. With 1 to 5 of the cat's 23 marks thrown up to 2000 px off (100 draws each), the pose the
others agree on was taken in every draw where the least squares explained too little with 1 or 2 thrown (20 and
66 draws), and in 73 % of them with 5 (the rest: too many flagged for a majority, and the identity, as before)."""


def _marks_off(numbers: list[int], distances: Tensor) -> str:
    """Marks by their numbers with how far each is off (``(K,)`` pixels), the first five: ``"point 4 (12 px)"``,
    ``"points 4 (12 px), 7 (3 px) and 2 more"``."""
    listed = ", ".join(f"{i} ({float(d):.0f} px)" for i, d in zip(numbers[:5], distances[:5]))
    more = f" and {len(numbers) - 5} more" if len(numbers) > 5 else ""
    return f"{'point' if len(numbers) == 1 else 'points'} {listed}{more}"


def _explained(M: Tensor, a: Tensor, b: Tensor) -> float:
    """The share of the spread of ``b`` ``(M, 2)`` around its mean that ``M`` ``(3, 3)`` applied to ``a`` explains."""
    spread = float((b - b.mean(0)).square().sum())
    return 1 - float((apply_alignment(M, a) - b).square().sum()) / spread if spread > 0 else 0.0


def crossing_pairs(pa: Tensor, pb: Tensor) -> Tensor:
    """``(K, 2)`` int64: the pairs ``i < j`` of marks ``pa``, ``pb`` ``(M, 2)`` (M >= 3) whose order crosses. After a
    similarity that best maps ``pa`` onto ``pb`` (the one most marks agree on where a few lie far off, as for
    :func:`pose`), the segment between the two turns by more than 90 degrees (both longer than 2 % of B's spread),
    or marks close in A (under a tenth of the spread) end far apart in B (over half): what no smooth, fold-free map
    does."""
    qb = pb.double()
    M, _, _ = _agreed(pa.double(), qb, "similarity")  # the pose most marks agree on: one far off drags no other
    qa = apply_alignment(estimate_alignment(pa.double(), qb) if M is None else M, pa.double())
    da, db = qa[:, None] - qa[None], qb[:, None] - qb[None]  # (M, M, 2)
    spread = float((qb - qb.mean(0)).norm(dim=-1).max())
    la, lb = da.norm(dim=-1), db.norm(dim=-1)
    turned = ((da * db).sum(-1) < 0) & (la > 0.02 * spread) & (lb > 0.02 * spread)
    torn = (la < 0.1 * spread) & (lb > 0.5 * spread)
    return torch.triu(turned | torn, diagonal=1).nonzero()


def _repeats(points: Tensor) -> list[tuple[int, int]]:
    """The pairs ``i < j`` of points ``(M, 2)`` at the same position (within ``1e-6`` px)."""
    d = torch.cdist(points.double(), points.double())
    d.fill_diagonal_(math.inf)
    i, j = torch.nonzero(d < 1e-6, as_tuple=True)
    return [(int(a), int(b)) for a, b in zip(i, j) if a < b]


def drop_repeats(pa: Tensor, pb: Tensor, placed_by: str) -> tuple[Tensor, Tensor]:
    """Points ``(M, 2)`` that the ``placed_by`` matcher put where an earlier one already is, in either picture,
    dropped with a warning: a matcher's doing, not the user's, and the later point adds nothing to the morph."""
    later = sorted({j for p in (pa, pb) for _, j in _repeats(p)})
    if not later:
        return pa, pb
    keep = torch.ones(pa.shape[0], dtype=torch.bool, device=pa.device)
    keep[later] = False
    warn(
        f"the {placed_by} matcher placed {len(later)} point(s) where an earlier one already is (indices "
        f"{', '.join(map(str, later[:5]))}{' ...' if len(later) > 5 else ''}); the morph uses each position once",
        RuntimeWarning,
    )
    return pa[keep], pb[keep]


LET_GO = 1.0
"""Pixels: a point the library placed that ends farther than this from its target in the last frame was let go
(the morph meets the rest of its points within a fraction of it). #31 asks marks to be met within 1 px."""

LET_GO_HINT = Hint(
    "{setting} names the points let go and how far each ended",
    "report",
    spelling="result.let_go (and result.error)",
)
"""Where a caller sees the marks a morph let go: the result's ``let_go`` and ``error`` (the command line's
``--report``; a command without one gives no advice)."""


def check_not_normalised(name: str, points: Tensor, size: tuple[int, int]) -> None:
    """Refuse ``points`` ``(M, 2)`` that look like normalised coordinates on a picture of ``size`` ``(H, W)``: 3
    or more, all within ``[0, 1]``, on a picture whose shorter side is at least :data:`NORMALISED_SIDE`; the
    message gives the product that makes pixels, and names ``name``."""
    H, W = size
    if points.shape[0] >= 3 and min(H, W) >= NORMALISED_SIDE and bool(((points >= 0) & (points <= 1)).all()):
        raise InputError(
            f"{name}: all {points.shape[0]} points lie within [0, 1] on a {W} x {H} picture: normalised "
            f"coordinates? Points are pixels (x, y); multiply by ({W}, {H})",
            argument=argument_of(name),
        )


NORMALISED_SIDE = 16
"""Pixels: on a picture whose shorter side is at least this, 3 or more points all within ``[0, 1]`` are taken for
normalised coordinates (fractions of the picture's width and height) and refused, with the product that gives
pixels (:func:`check_not_normalised`); a morph of a picture this size has no use for marks within one pixel of its
corner."""


def check_point_files(
    files: Sequence[str | os.PathLike[str]], points: Sequence[Tensor], pictures: Sequence[Tensor]
) -> None:
    """Refuse each file's points ``(M, 2)`` that do not fit its picture ``(1, C, H, W)``: outside it
    (:func:`~torchfluidwarp.control.keyframes.check_points`, with the convention that would fit them) or in
    normalised coordinates (:func:`check_not_normalised`), naming the file (the command line's point files)."""
    for file, p, picture in zip(files, points, pictures):
        size = (picture.shape[-2], picture.shape[-1])
        check_points(f"points file {str(file)!r}", p, size)
        check_not_normalised(f"points file {str(file)!r}", p, size)


def check_met(error: Tensor, let_go: Tensor, targets: Tensor) -> None:
    """Refuse a morph of the user's marks that met none of them: each was let go so as not to fold (``let_go``
    ``(M,)``) or ended (``error`` ``(M,)``, the last frame's pixels) farther from its target than
    :data:`MISSED_SHARE` of the targets' extent (``targets`` ``(M, 2)``), as when the marks are listed in another
    order or mirrored: frames that follow no mark (the command line writes nothing then)."""
    extent = float((targets.max(0).values - targets.min(0).values).max())
    if bool((let_go | (error > MISSED_SHARE * extent)).all()):
        raise InputError(
            f"the morph met none of the {let_go.numel()} marks: each was let go so as not to fold or ended far "
            f"from its target ({float(error.min()):.0f} to {float(error.max()):.0f} px); check that both lists "
            "give the same features in the same order",
        )


MISSED_SHARE = 0.1
"""A mark that ends farther from its target than this share of the targets' extent is not met (:func:`check_met`):
a fit that meets its marks at all leaves them within a few pixels."""


def check_marks(pa: Tensor, pb: Tensor, placed_by: str | None = None) -> None:
    """Refuse marks that cannot be morphed (repeated), and warn about the user's marks that are a mirror image of
    each other (:func:`mirrored`) or whose order crosses. Points the library placed (``placed_by``, the matcher's
    name) are nobody's order to check: :func:`warn_let_go` names after the fit the crossing pairs that the morph
    had to let go (points placed twice are dropped before, by :func:`drop_repeats`)."""
    for name, p in (("points_a", pa), ("points_b", pb)):
        pairs = _repeats(p)
        if pairs:
            raise InputError(
                f"{name} repeats points: indices {', '.join(f'{a} and {b}' for a, b in pairs[:5])} are at the same "
                "position; each feature must be marked once",
                argument=name,
            )
    if placed_by is not None:
        return
    if mirrored(pa, pb):
        warn(AdvisedWarning(f"{MIRRORED}; check their order: a morph that follows them folds", hint=LET_GO_HINT))
        return
    bad = _crossings(pa, pb)
    if bad:
        warn(
            AdvisedWarning(
                f"the marks cross: points {_listed(bad)} swap sides or tear apart between A and B, which no smooth "
                "morph can do without folding; check their order",
                hint=LET_GO_HINT,
            )
        )


MIRRORED = (
    "points_b look mirrored: they agree with points_a on a pose once reflected (features listed in mirror order, "
    "left for right; a mirror image whose points were not reordered; or (y, x) pairs where (x, y) belong)"
)
"""What :func:`check_marks` says of the user's marks that are a mirror image of each other (:func:`mirrored`)."""


MIRROR_MARKS = 8
"""The fewest marks :func:`mirrored` judges: with fewer, two marks listed the other way round often look like a
reflection of them all (scratch, 300 random sets each with one or two pairs of marks swapped: 5-12 % of the sets
of 5 or 6 marks agreed on a reflection, 0.3-1.3 % of 8, none of 12)."""


def mirrored(pa: Tensor, pb: Tensor) -> bool:
    """Whether the marks ``pa``, ``pb`` ``(M, 2)`` agree on a reflected pose, and much better than on any other:
    at least :data:`MIRROR_MARKS` of them, a similarity from ``pa`` to ``pb`` reflected left for right explains at
    least :data:`TRUSTED_POSE_FIT` of their spread, and the similarity to ``pb`` itself less than half of what the
    reflected one does, and no pose most of them agree on leaves a few far off (:func:`pose`). A reflection about any
    line is a reflection left for right and a turn, so (y, x) pairs are caught too."""
    a, b = pa.double(), pb.double()
    if a.shape[0] < MIRROR_MARKS:
        return False
    _, far, straight = _agreed(a, b, "similarity")  # straight: what the least squares explains
    if far:  # most agree on a pose: a few marks far off
        return False
    flip = b * b.new_tensor([-1.0, 1.0])
    reflected = _explained(estimate_alignment(a, flip, "similarity"), a, flip)
    return reflected >= TRUSTED_POSE_FIT and straight < 0.5 * reflected


def warn_let_go(pa: Tensor, pb: Tensor, let_go: Tensor, placed_by: str) -> None:
    """Warn about the pairs of points ``pa``, ``pb`` ``(M, 2)`` that the ``placed_by`` matcher placed whose order
    crosses (:func:`crossing_pairs`) and of which the morph let a point go so as not to fold (``let_go``
    ``(M,)`` bool, as :attr:`~torchfluidwarp.morph.MorphResult.let_go` holds it: its planned end more than
    :data:`LET_GO` px from its target). Pairs it met say nothing: crossing then was the matcher's noise."""
    missed = [(a, b) for a, b in _crossings(pa, pb) if bool(let_go[a]) or bool(let_go[b])]
    if missed:
        warn(
            AdvisedWarning(
                f"the points the {placed_by} matcher placed cross: points {_listed(missed)} swap sides or tear "
                "apart between A and B (as where a head turns and hides part of one side); the morph let them go "
                "so as not to fold",
                hint=LET_GO_HINT,
            )
        )


def warn_let_go_alone(
    pa: Tensor, pb: Tensor, let_go: Tensor, error: Tensor, numbers: Tensor, least_area: float
) -> None:
    """Warn about the user's marks ``pa``, ``pb`` ``(M, 2)`` that the morph let go (``let_go`` ``(M,)`` bool)
    although they cross no other (:func:`check_marks` named those that do): marks around a squeeze, that would
    crush part of the picture on the way. ``error`` ``(M,)``: how far each ended from its target (the last frame's
    pixels); ``numbers`` ``(M,)``: the caller's index of each mark; ``least_area``: the least share of its area
    that the morph lets a part of the picture keep on the way (``morph.fit.MIN_AREA``)."""
    crossing = {i for pair in _crossings(pa, pb) for i in pair}
    alone = [i for i in let_go.nonzero()[:, 0].tolist() if i not in crossing]
    if not alone:
        return
    one = len(alone) == 1
    warn(
        AdvisedWarning(
            f"{_marks_off([int(numbers[i]) for i in alone], error[alone])} of points_a and points_b "
            f"{'was' if one else 'were'} "
            f"let go so as not to fold: on the straight paths the picture between {'it' if one else 'them'} and "
            f"the marks near {'it' if one else 'them'} would be squeezed below {least_area:.0%} of its area; "
            "check where these marks are",
            hint=LET_GO_HINT,
        )
    )


FAR_OFF = 3.0
"""A mark that ends farther than this many times :data:`LET_GO` from its target, where the marks share the fluid's
cells, is warned about by :func:`warn_coarse_grid` even when the marks' mean is met."""

MIN_SPACING = 1.0
"""Fluid cells: marks that lie closer together than this (the median distance from each to its nearest, in A's
frame) share cells, where the fit converges slowly (see :func:`warn_coarse_grid`). Face crops of 512 pixels put
their 68 landmarks 1.2 to 2.3 cells apart on the default grid."""


def warn_coarse_grid(
    points: Tensor, error: Tensor, box: tuple[int, int], grid: object, let_go: Tensor | None = None
) -> None:
    """Warn when the marks end more than :data:`LET_GO` px from their targets on average, or one of them more than
    :data:`FAR_OFF` times that (``error`` ``(M,)``, the last frame's pixels; the marks that the natural morph let go
    so as not to fold, ``let_go`` ``(M,)`` bool, do not count), and they lie closer together than
    :data:`MIN_SPACING` of the fluid's cells: ``points`` ``(M, 2)`` in A's frame, on a fluid box of ``box``
    ``(H, W)`` pixels and a ``grid`` of cells.

    The case: marks that share cells, where the fit's 30 iterations leave them about a pixel off in A's frame and
    the pre-alignment's zoom magnifies that in the last frame. A small face zoomed into a large one was the first
    (einstein -> obama2 of ``benchmarks/bench_framing.py``: 0.23 cells apart, 5.2 px at a 4.9x zoom), until the
    fluid covered only what the last frame shows (:func:`~torchfluidwarp.morph.fit.focus`: 0.20 px). Marks
    that share cells without a zoom to focus on remain (obama3 -> breakingbad, whose border points hold the whole
    of A: 2.5 px on square cells). A face small in a large photograph is another: on a whole-body portrait the
    mouth's marks end up to 5.7 px off while the marks' mean stays under a pixel (biden -> obama, 0.87 px)."""
    missed = _missed(error, let_go)
    if points.shape[0] < 2 or missed is None:
        return
    mean, worst = missed
    gaps = torch.cdist(points.double(), points.double()).fill_diagonal_(math.inf)
    spacing = float(gaps.min(1).values.median()) / mean_pixels_per_cell(box, grid)  # type: ignore[arg-type]
    if spacing >= MIN_SPACING:
        return
    warn(
        AdvisedWarning(
            f"the marks end {mean:.1f} px from their targets on average, up to {worst:.1f} px: they lie "
            f"{spacing:.2f} fluid cells apart in A (median), where the fit converges slowly",
            hint=Hint(
                "a finer grid ({setting}) or more iterations meet them closer, at more time",
                "grid",
                spelling="NaturalSettings.grid",
            ),
        )
    )


def warn_missed(error: Tensor, let_go: Tensor | None = None) -> None:
    """Warn when the paper's keyframe fit leaves the marks more than :data:`LET_GO` px from their targets on
    average, or one of them more than :data:`FAR_OFF` times that (``error`` ``(M,)``, the last frame's pixels; marks
    let go, ``let_go`` ``(M,)`` bool, do not count): its smoothness term trades the marks for a smooth flow, and a
    caller who asked for marks met should hear by how much they were not."""
    missed = _missed(error, let_go)
    if missed is None:
        return
    mean, worst = missed
    warn(
        AdvisedWarning(
            f"the marks end {mean:.1f} px from their targets on average, up to {worst:.1f} px: the paper's fit "
            "trades them for a smooth flow",
            hint=Hint(
                "a lower {setting} (or more iterations) meets them closer",
                "smoothness",
                spelling="PaperSettings.smoothness",
            ),
        )
    )


def _missed(error: Tensor, let_go: Tensor | None) -> tuple[float, float] | None:
    """The mean and the largest of ``error`` ``(M,)`` over the marks not let go (``let_go`` ``(M,)`` bool), when
    the mean passes :data:`LET_GO` or the largest :data:`FAR_OFF` times it; ``None`` when they are met (or all
    were let go)."""
    kept = error if let_go is None else error[~let_go]
    if kept.numel() == 0:
        return None
    mean, worst = float(kept.mean()), float(kept.max())
    return None if mean <= LET_GO and worst <= FAR_OFF * LET_GO else (mean, worst)


def _crossings(pa: Tensor, pb: Tensor) -> list[tuple[int, int]]:
    """:func:`crossing_pairs` as a list; none for fewer than 3 marks (no similarity to judge them by)."""
    return [] if pa.shape[0] < 3 else [(a, b) for a, b in crossing_pairs(pa, pb).tolist()]


def _listed(pairs: list[tuple[int, int]]) -> str:
    return ", ".join(f"{a} and {b}" for a, b in pairs[:5]) + (" ..." if len(pairs) > 5 else "")
