"""Sparse correspondences between two pictures of anything, from hand-crafted features (no learned weights).

:func:`match_features` runs kornia's SIFT (a difference-of-Gaussians detector with RootSIFT descriptors:
:class:`kornia.feature.SIFTFeature`) on both images, keeps the mutual nearest neighbours that pass a
ratio test (:func:`kornia.feature.match_smnn`), drops the outliers of a global model fitted by RANSAC
(:class:`kornia.geometry.ransac.RANSAC`) and those that move unlike their neighbours
(:func:`consistent_matches`), and thins what is left with :func:`thin_matches` to at most
``max_points`` matches, one per cell of a coarse grid, so that they spread over the picture like hand-placed
morph landmarks. Nothing is downloaded: SIFT has no weights.

A morph's pairs differ by more than a homography, so the RANSAC threshold is loose by default (3 % of the
image diagonal): it removes matches that land somewhere else entirely, not the non-rigid part of the motion.
The neighbour check is the tight one, and it is local: it allows any smooth motion.
"""

from __future__ import annotations

from typing import Literal

import kornia.feature as KF
import torch
from kornia.geometry.ransac import RANSAC
from torch import Tensor

from torchfluidwarp._checks import check_int, check_positive
from torchfluidwarp.correspond._image import gray, single_image
from torchfluidwarp.errors import InputError

__all__ = ["RansacModel", "consistent_matches", "match_features", "thin_matches"]

RansacModel = Literal["homography", "affine", "fundamental"]
NEIGHBOURS = 8  # matches each match is compared with by the consistency check
MIN_SIDE = 32
"""Pixels: the shorter side a picture needs for kornia's SIFT (its scale pyramid pads past a smaller one); on a
smaller picture :func:`match_features` finds no feature."""
MIN_RANSAC = {"homography": 4, "affine": 3, "fundamental": 8}  # matches needed for a model and its check


def _sift(image: Tensor, num_features: int) -> tuple[Tensor, Tensor]:
    """Keypoints ``(N, 2)`` (pixels) and descriptors ``(N, 128)`` of a ``(1, 1, H, W)`` float32 image."""
    sift = KF.SIFTFeature(num_features=num_features, upright=False, rootsift=True)
    with torch.no_grad():
        lafs, _, descs = sift(image)
    return KF.get_laf_center(lafs)[0], descs[0]


def consistent_matches(points_a: Tensor, points_b: Tensor, neighbours: int, tolerance: float) -> Tensor:
    """Which matches move like their neighbours: a smooth map moves nearby points alike.

    Args:
        points_a: ``(N, 2)`` matched points in image A, pixels.
        points_b: ``(N, 2)`` their partners in image B, pixels.
        neighbours: how many nearest matches (in A) each match is compared with.
        tolerance: the largest distance, in pixels, between a match's displacement ``b - a`` and the
            componentwise median displacement of its neighbours.

    Returns:
        ``(N,)`` bool, True for the matches kept (all of them when there are too few to compare).
    """
    n = len(points_a)
    if n <= neighbours:
        return torch.ones(n, dtype=torch.bool, device=points_a.device)
    moves = points_b - points_a
    near = torch.cdist(points_a, points_a).topk(neighbours + 1, largest=False).indices[:, 1:]  # not itself
    expected = moves[near].median(dim=1).values
    return (moves - expected).norm(dim=-1) <= tolerance


def thin_matches(points: Tensor, scores: Tensor, size: tuple[int, int], cells: int) -> Tensor:
    """Indices of the matches that :func:`match_features` keeps: the best (lowest score) per grid cell.

    Args:
        points: ``(N, 2)`` matched points in image A, pixels.
        scores: ``(N,)`` lower is better (the ratio-test distance).
        size: image A's ``(H, W)``.
        cells: cells along the longer side; the shorter side gets proportionally fewer (at least 1).

    Returns:
        ``(K,)`` long indices into the matches, best first, ``K <= N``.
    """
    points_a = points
    H, W = size
    n_x = max(1, round(cells * W / max(H, W)))
    n_y = max(1, round(cells * H / max(H, W)))
    col = (points_a[:, 0] * n_x / W).floor().clamp(0, n_x - 1).long()
    row = (points_a[:, 1] * n_y / H).floor().clamp(0, n_y - 1).long()
    cell = row * n_x + col
    order = torch.argsort(scores, stable=True)
    seen: set[int] = set()
    keep = []
    for i, c in zip(order.tolist(), cell[order].tolist()):
        if c not in seen:
            seen.add(c)
            keep.append(i)
    return torch.tensor(keep, dtype=torch.long, device=points_a.device)


def match_features(
    image_a: Tensor,
    image_b: Tensor,
    *,
    max_points: int = 64,
    cells: int = 10,
    ratio: float = 0.9,
    model: RansacModel | None = "homography",
    inlier_threshold: float | None = None,
    consistency: float | None = 3.0,
    num_features: int = 2000,
    seed: int = 0,
) -> tuple[Tensor, Tensor]:
    """Matched points of two images, spread over image A, for use as morph landmarks.

    Args:
        image_a: ``(C, H, W)`` or ``(1, C, H, W)`` float image in ``[0, 1]`` (``C`` = 1, 3 or 4).
        image_b: the other image, the same way (its size may differ).
        max_points: the most matches returned (the best by ratio-test distance).
        cells: the thinning grid's cells along A's longer side; at most one match per cell.
        ratio: the ratio test's threshold (first to second nearest descriptor distance, both ways).
        model: the global model whose RANSAC outliers are dropped, or ``None`` to keep every mutual match.
        inlier_threshold: RANSAC's inlier distance in B's pixels (transfer error; Sampson distance for
            ``"fundamental"``); ``None``: 3 % of B's diagonal.
        consistency: drop a match whose displacement differs by more than this many pixels from the median
            displacement of its nearest matches (:func:`consistent_matches`); ``None`` keeps them.
        num_features: SIFT keypoints detected per image.
        seed: RANSAC's random seed (the result does not depend on the global RNG).

    Returns:
        ``(points_a, points_b)``: ``(K, 2)`` each, ``(x, y)`` in each image's pixels, pixel centres at
        integers, with image A's dtype and device; ``points_a[i]`` and ``points_b[i]`` are the same feature.
        ``K`` may be 0 when the images share nothing.

    Raises:
        TypeError / ValueError: an argument of the wrong type, shape or value (named in the message).

    Conventions:
        ``(x, y)`` order, pixels with pixel centres at integers (kornia's LAF centres use the same).

    Example:
        >>> from torchfluidwarp.data import load_sample
        >>> a = load_sample("astronaut")
        >>> pa, pb = match_features(a, a[..., 8:, 4:])  # B: A cropped, so b = a - (4, 8)
        >>> bool((pa - pb - torch.tensor([4.0, 8.0])).norm(dim=-1).median() < 0.5), len(pa) >= 20
        (True, True)
    """
    a, b = single_image("image_a", image_a), single_image("image_b", image_b)
    max_points = check_int("max_points", max_points)
    cells = check_int("cells", cells)
    num_features = check_int("num_features", num_features)
    seed = check_int("seed", seed, minimum=0)
    ratio = check_positive("ratio", ratio)
    if ratio > 1:
        raise InputError(f"ratio must be in (0, 1], got {ratio!r}", argument="ratio")
    if model is not None and model not in MIN_RANSAC:
        raise InputError(
            f"model must be 'homography', 'affine', 'fundamental' or None, got {model!r}", argument="model"
        )
    Hb, Wb = b.shape[-2:]
    threshold = 0.03 * float(Hb**2 + Wb**2) ** 0.5 if inlier_threshold is None else inlier_threshold
    threshold = check_positive("inlier_threshold", threshold)

    if min(a.shape[-2:]) < MIN_SIDE or min(b.shape[-2:]) < MIN_SIDE:
        return _empty(a), _empty(a)
    kp_a, desc_a = _sift(gray(a).detach().float().cpu(), num_features)
    kp_b, desc_b = _sift(gray(b).detach().float().cpu(), num_features)
    if len(kp_a) == 0 or len(kp_b) == 0:
        return _empty(a), _empty(a)
    with torch.no_grad():
        dists, idx = KF.match_smnn(desc_a, desc_b, th=ratio)
    pa, pb, scores = kp_a[idx[:, 0]], kp_b[idx[:, 1]], dists[:, 0]
    if model is not None and len(pa) > MIN_RANSAC[model]:
        ransac = RANSAC(model_type=model, inl_th=threshold, max_iter=10, seed=seed)
        with torch.no_grad():
            fitted, inliers = ransac(pa.double(), pb.double())
        if bool(fitted.abs().sum() > 0):  # an all-zero model: RANSAC found none; keep the mutual matches
            pa, pb, scores = pa[inliers], pb[inliers], scores[inliers]
    if consistency is not None:
        ok = consistent_matches(pa, pb, NEIGHBOURS, check_positive("consistency", consistency))
        pa, pb, scores = pa[ok], pb[ok], scores[ok]
    keep = thin_matches(pa, scores, (a.shape[-2], a.shape[-1]), cells)[:max_points]
    return pa[keep].to(device=a.device, dtype=a.dtype), pb[keep].to(device=a.device, dtype=a.dtype)


def _empty(like: Tensor) -> Tensor:
    return torch.zeros(0, 2, device=like.device, dtype=like.dtype)
