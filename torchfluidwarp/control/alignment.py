"""Global pre-alignment from corresponding points: similarity or affine, and its interpolation over time.

A closed incompressible fluid can neither translate a whole picture nor change areas, so a morph between
two photos first estimates a global transform ``M`` with ``M a_i ~ b_i`` and lets the fluid handle the local,
non-rigid rest. Matrices are ``(3, 3)`` homogeneous, acting on pixel coordinates ``(x, y, 1)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

import torch
from torch import Tensor

from torchfluidwarp._checks import check_int, check_tensor
from torchfluidwarp.errors import InputError
from torchfluidwarp.warp.frames import identity_map, warp_image

__all__ = [
    "estimate_alignment",
    "robust_alignment",
    "interpolate_alignment",
    "apply_alignment",
    "best_shift",
    "SHIFT_SIDE",
]

AlignKind = Literal["similarity", "affine", "none"]


def estimate_alignment(points_a: Tensor, points_b: Tensor, kind: AlignKind | None = "similarity") -> Tensor:
    """Least-squares transform ``M`` ``(3, 3)`` with ``M [a_i; 1] ~ [b_i; 1]``.

    Args:
        points_a, points_b: ``(M, 2)`` corresponding points in pixels.
        kind: ``"similarity"`` (scale, rotation, translation; Umeyama 1991; needs 2 points), ``"affine"``
            (needs 3 non-collinear points) or ``"none"``/``None`` (identity).

    Example:
        >>> a = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
        >>> M = estimate_alignment(a, 2 * a + 3)  # scale 2, shift (3, 3)
        >>> torch.allclose(M, torch.tensor([[2.0, 0.0, 3.0], [0.0, 2.0, 3.0], [0.0, 0.0, 1.0]]), atol=1e-6)
        True
    """
    a = check_tensor("points_a", points_a, shape=[None, 2]).double()
    b = check_tensor("points_b", points_b, shape=[None, 2]).double()
    if a.shape != b.shape:
        raise InputError(f"points_a has {a.shape[0]} points but points_b has {b.shape[0]}", argument="points_b")
    eye = torch.eye(3, dtype=torch.float64, device=a.device)
    if kind in (None, "none"):
        return eye.to(points_a.dtype)
    ca, cb = a.mean(0), b.mean(0)
    da, db = a - ca, b - cb
    if kind == "similarity":
        if a.shape[0] < 2 or float((da**2).sum()) == 0:
            raise InputError(
                f"a similarity alignment needs at least 2 distinct points in points_a, got {a.shape[0]} points "
                f"spread over {float((da**2).sum()):.3g} px^2",
                argument="points_a",
            )
        u, s, vh = torch.linalg.svd(db.T @ da / a.shape[0])
        d = torch.ones(2, dtype=torch.float64, device=a.device)
        d[1] = torch.sign(torch.linalg.det(u @ vh))  # no reflections
        rot = u @ torch.diag(d) @ vh
        scale = float((s * d).sum() / (da**2).sum(1).mean())
        lin = scale * rot
    elif kind == "affine":
        if a.shape[0] < 3:
            raise InputError(f"an affine alignment needs at least 3 points, got {a.shape[0]}", argument="points_a")
        sol = torch.linalg.lstsq(da, db).solution  # (2, 2): db ~ da @ sol
        lin = sol.T
        if abs(float(torch.linalg.det(lin))) < 1e-9:
            raise InputError("an affine alignment needs 3 non-collinear points", argument="points_a")
    else:
        raise InputError(f"kind must be 'similarity', 'affine' or 'none', got {kind!r}", argument="kind")
    m = eye.clone()
    m[:2, :2] = lin
    m[:2, 2] = cb - lin @ ca
    return m.to(points_a.dtype)


INLIER = 3.0
""":func:`robust_alignment` keeps the pairs whose distance from the pose is within this many ``sigma``, the
per-axis standard deviation of the Gaussian noise whose distances have the residuals' median (a Rayleigh
distribution's median is ``sigma sqrt(2 ln 2)``): about 1 % of pairs with such noise alone lie beyond it."""

PAIR_CANDIDATES = 2000
""":func:`robust_alignment` tries the similarities through at most this many pairs of points (all pairs of up to
63 points; beyond, as many pairs drawn with a fixed seed)."""

FEWEST_TO_JUDGE = 5
""":func:`robust_alignment` needs this many pairs of points to tell some from the rest: the similarity through two
of them leaves at least 3 others to judge it by."""


def robust_alignment(
    points_a: Tensor, points_b: Tensor, kind: AlignKind | None = "similarity"
) -> tuple[Tensor, Tensor]:
    """A transform that most of the pairs agree on, and which pairs they are: a pose that a few pairs placed far
    off (a mark in the wrong place, two listed in the wrong order) do not drag, as they drag
    :func:`estimate_alignment`'s least squares.

    The least median of squares (Rousseeuw 1984) over the similarities through two pairs each (all pairs of
    points, or :data:`PAIR_CANDIDATES` of them drawn with a fixed seed: the result does not vary from call to
    call), each judged by the median distance of the other pairs, gives a first pose and the scale of its
    residuals; then, three times, the least-squares ``kind`` (:func:`estimate_alignment`) through the pairs
    within :data:`INLIER` standard deviations of the pose, the scale taken again from the median distance of all
    the pairs. With fewer than :data:`FEWEST_TO_JUDGE` pairs, or inliers too few or in a row for ``kind``, it is
    the least squares through all of them, all counted as inliers.

    Args:
        points_a, points_b: ``(M, 2)`` corresponding points in pixels.
        kind: as for :func:`estimate_alignment`.

    Returns:
        ``(M_ab, inliers)``: the ``(3, 3)`` transform (``points_a``'s dtype) and ``(M,)`` bool, the pairs it
        agrees with.

    Example:
        >>> a = torch.tensor([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0], [5.0, 5.0]])
        >>> b = a + 3.0
        >>> b[4] = torch.tensor([40.0, -20.0])  # one pair far off
        >>> M, inliers = robust_alignment(a, b)
        >>> inliers.tolist(), round(float(M[0, 2]), 3)
        ([True, True, True, True, False], 3.0)
    """
    a = check_tensor("points_a", points_a, shape=[None, 2]).double()
    b = check_tensor("points_b", points_b, shape=[None, 2]).double()
    n = a.shape[0]
    if b.shape != a.shape:
        raise InputError(f"points_a has {n} points but points_b has {b.shape[0]}", argument="points_b")
    everyone = torch.ones(n, dtype=torch.bool, device=a.device)
    if kind in (None, "none") or n < FEWEST_TO_JUDGE:
        return estimate_alignment(points_a, points_b, kind), everyone
    if n * (n - 1) // 2 <= PAIR_CANDIDATES:
        i, j = torch.triu_indices(n, n, 1, device=a.device)
    else:  # a fixed sample of distinct pairs: the same pose on every call
        seed = torch.Generator().manual_seed(0)
        i = torch.randint(n, (PAIR_CANDIDATES,), generator=seed, device="cpu")
        j = torch.randint(n - 1, (PAIR_CANDIDATES,), generator=seed, device="cpu")
        i, j = i.to(a.device), (j + (j >= i)).to(a.device)
    da, db = a[j] - a[i], b[j] - b[i]  # (P, 2)
    norm = (da * da).sum(1)
    usable = norm > 1e-12 * float(norm.max())  # two pairs at one place in A say nothing of a pose
    if not bool(usable.any()):
        raise InputError("points_a must hold at least 2 distinct points for an alignment", argument="points_a")
    da, db, i, j, norm = da[usable], db[usable], i[usable], j[usable], norm[usable]
    # the similarity z a + t through both pairs, z = db / da as complex numbers
    zr = (db[:, 0] * da[:, 0] + db[:, 1] * da[:, 1]) / norm
    zi = (db[:, 1] * da[:, 0] - db[:, 0] * da[:, 1]) / norm
    tx = b[i, 0] - (zr * a[i, 0] - zi * a[i, 1])
    ty = b[i, 1] - (zi * a[i, 0] + zr * a[i, 1])
    rx = zr[:, None] * a[None, :, 0] - zi[:, None] * a[None, :, 1] + tx[:, None] - b[None, :, 0]
    ry = zi[:, None] * a[None, :, 0] + zr[:, None] * a[None, :, 1] + ty[:, None] - b[None, :, 1]
    residual = (rx * rx + ry * ry).sqrt()  # (P, M)
    rows = torch.arange(len(i), device=a.device)
    others = residual.clone()
    others[rows, i] = others[rows, j] = torch.nan  # each is judged by the pairs it was not made from
    median = others.nanmedian(1).values
    best = int(median.argmin())
    floor = 1e-6 * float((b - b.mean(0)).norm(dim=-1).max()) + 1e-12  # float32 points' rounding

    def within(r: Tensor, typical: float) -> Tensor:
        sigma = max(typical / math.sqrt(2 * math.log(2)) * (1 + 5 / (n - 2)), floor)  # small-sample correction
        return r <= INLIER * sigma

    inliers = within(residual[best], float(median[best]))
    least = 3 if kind == "affine" else 2
    fit: tuple[Tensor, Tensor] | None = None
    for _ in range(3):  # refit through the inliers, then find them again
        if int(inliers.sum()) < least:
            break
        try:
            M = estimate_alignment(a[inliers], b[inliers], kind)
        except InputError:  # inliers in a row: an affine through them is not defined
            break
        r = (apply_alignment(M, a) - b).norm(dim=-1)
        fit = M, within(r, float(r.median()))
        inliers = fit[1]
    if fit is None:
        return estimate_alignment(points_a, points_b, kind), everyone
    return fit[0].to(points_a.dtype), fit[1]


def interpolate_alignment(matrix: Tensor, u: float, center: Tensor | None = None) -> Tensor:
    """The transform a fraction ``u`` in ``[0, 1]`` of the way from the identity to ``matrix``.

    A similarity (``A = s R``) interpolates its scale geometrically and its angle linearly; any other linear
    part interpolates linearly. The translation is chosen so that ``center`` (e.g. the centroid of the
    source points; default the origin) moves on a straight line to its image.
    """
    m = matrix.double()
    lin = m[:2, :2]
    ata = lin.T @ lin
    eye = torch.eye(2, dtype=torch.float64, device=m.device)
    is_similarity = bool(torch.allclose(ata, ata[0, 0] * eye, atol=1e-9 * float(ata.abs().max() + 1)))
    if is_similarity and float(torch.linalg.det(lin)) > 0:
        s = math.sqrt(float(ata[0, 0]))
        angle = math.atan2(float(lin[1, 0]), float(lin[0, 0]))
        su, au = s**u, angle * u
        rotation = [[math.cos(au), -math.sin(au)], [math.sin(au), math.cos(au)]]
        lin_u = su * torch.tensor(rotation, dtype=torch.float64, device=m.device)
    else:
        lin_u = (1 - u) * eye + u * lin
    c = m.new_zeros(2) if center is None else center.to(m)
    target = c + u * (lin @ c + m[:2, 2] - c)
    out = torch.eye(3, dtype=torch.float64, device=m.device)
    out[:2, :2] = lin_u
    out[:2, 2] = target - lin_u @ c
    return out.to(matrix.dtype)


def apply_alignment(matrix: Tensor, points: Tensor) -> Tensor:
    """Apply a ``(3, 3)`` transform to ``(..., 2)`` points."""
    m = matrix.to(points.dtype).to(points.device)
    return points @ m[:2, :2].T + m[:2, 2]


SHIFT_SIDE = 256
"""Pixels: :func:`best_shift` looks for its candidates on copies of the pictures at most this long a side."""


def best_shift(
    source: Tensor, target: Tensor, loss: Callable[[Tensor, Tensor], Tensor], candidates: int = 4
) -> tuple[Tensor, float]:
    """The plain translation of ``source`` that matches ``target`` best under ``loss``: the simplest motion there
    is, against which a fitted flow can be judged (:func:`~torchfluidwarp.control.images.fit_images` warns when it
    does better than the fit).

    The candidates are the ``candidates`` highest peaks of the zero-mean grey pictures' cross-correlation, each
    normalised by the overlap it is taken over, on copies at most :data:`SHIFT_SIDE` pixels a side, for shifts of
    up to half the picture's size; each is scaled back to whole pixels and scored at full size, ``source`` read
    through the shifted identity map with border padding (as the fits read it).

    Args:
        source: ``(B, C, H, W)`` the picture to move.
        target: ``(B, C, H, W)`` the picture to match.
        loss: ``loss(moved, target) -> scalar``, e.g. :func:`~torchfluidwarp.control.losses.mse_loss`.
        candidates: how many correlation peaks are scored (``>= 1``).

    Returns:
        ``(shift, value)``: ``(2,)`` ``(dx, dy)`` whole pixels (``source`` is read at ``x + dx``: the shift moves its
        content by ``-dx``), shared by the batch, and ``loss`` at that shift, a float; the zero shift is always a
        candidate, so ``value`` is at most ``loss(source, target)``.
    """
    check_tensor("source", source, ndim=4)
    check_tensor("target", target, shape=list(source.shape))
    candidates = check_int("candidates", candidates, minimum=1)
    H, W = source.shape[-2:]
    f = min(1.0, SHIFT_SIDE / max(H, W))
    h, w = max(2, round(H * f)), max(2, round(W * f))

    def grey(x: Tensor) -> Tensor:  # (h, w), zero mean, the batch averaged
        g = torch.nn.functional.interpolate(x.mean(1, keepdim=True), size=(h, w), mode="area").mean(0)[0]
        return g - g.mean()

    a, b = grey(source.detach()), grey(target.detach())
    size = (2 * h, 2 * w)
    # c[s] = sum_x b(x) a(x + s): how well source read at x + s matches target at x
    corr = torch.fft.irfft2(torch.fft.rfft2(a, s=size) * torch.fft.rfft2(b, s=size).conj(), s=size)
    sy = torch.fft.fftfreq(2 * h, 1 / (2 * h), device=a.device).round().view(-1, 1)  # shifts in rows
    sx = torch.fft.fftfreq(2 * w, 1 / (2 * w), device=a.device).round().view(1, -1)
    overlap = (h - sy.abs()).clamp(min=1) * (w - sx.abs()).clamp(min=1)
    score = torch.where((sy.abs() <= h // 2) & (sx.abs() <= w // 2), corr / overlap, torch.full_like(corr, -math.inf))
    top = score.flatten().topk(min(candidates, score.numel())).indices
    shifts = [(0.0, 0.0)] + [(float(sx[0, i % (2 * w)]) / f, float(sy[i // (2 * w), 0]) / f) for i in top.tolist()]
    ident = identity_map((H, W), device=source.device, dtype=source.dtype)
    best, value = (0.0, 0.0), math.inf
    with torch.no_grad():
        for dx, dy in dict.fromkeys((round(dx), round(dy)) for dx, dy in shifts):
            moved = warp_image(source, (ident + ident.new_tensor([dx, dy])).expand(source.shape[0], -1, -1, -1))
            v = float(loss(moved, target))
            if v < value:
                best, value = (float(dx), float(dy)), v
    return source.new_tensor(best), value
