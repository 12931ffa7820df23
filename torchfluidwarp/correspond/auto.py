"""Landmarks for a morph from the two pictures alone: faces when both show one, matched features otherwise."""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor

from torchfluidwarp._checks import check_int, check_size
from torchfluidwarp.correspond._image import single_image
from torchfluidwarp.correspond.faces import NoFaceFound, detect_face_points, load_mediapipe
from torchfluidwarp.correspond.features import match_features
from torchfluidwarp.correspond.refine import refine_points
from torchfluidwarp.errors import InputError

__all__ = ["MatchMode", "auto_points", "border_points", "usable_pairs"]

MatchMode = Literal["auto", "faces", "features", "pixels"]


def border_points(
    size: tuple[int, int], *, per_side: int = 3, device: torch.device | None = None, dtype: torch.dtype = torch.float32
) -> Tensor:
    """Anchors on the image's border: the corners and evenly spaced points along each edge.

    Paired with the same anchors in the other image, they keep the picture's frame on the frame while the
    inside moves, as a morph tool's border points do.

    Args:
        size: the image's ``(H, W)`` in pixels.
        per_side: points per edge, corners included (2: the corners only; 3: corners and edge midpoints).
        device, dtype: of the result.

    Returns:
        ``(4 * (per_side - 1), 2)`` points ``(x, y)`` in pixels, pixel centres at integers (the corners are
        ``(0, 0)`` and ``(W - 1, H - 1)``), clockwise from the top-left corner.

    Example:
        >>> border_points((3, 5)).tolist()
        [[0.0, 0.0], [2.0, 0.0], [4.0, 0.0], [4.0, 1.0], [4.0, 2.0], [2.0, 2.0], [0.0, 2.0], [0.0, 1.0]]
    """
    H, W = check_size("size", size)
    per_side = check_int("per_side", per_side, minimum=2)
    t = torch.linspace(0, 1, per_side, device=device, dtype=torch.float64)[:-1]
    x1, y1 = float(W - 1), float(H - 1)
    top = torch.stack([t * x1, torch.zeros_like(t)], -1)
    right = torch.stack([torch.full_like(t, x1), t * y1], -1)
    bottom = torch.stack([(1 - t) * x1, torch.full_like(t, y1)], -1)
    left = torch.stack([torch.zeros_like(t), (1 - t) * y1], -1)
    return torch.cat([top, right, bottom, left]).to(dtype)


def usable_pairs(points_a: Tensor, points_b: Tensor, size_a: tuple[int, int], size_b: tuple[int, int]) -> Tensor:
    """Which pairs a morph can take: both points inside their image, and neither within a pixel of an earlier one.

    Args:
        points_a, points_b: ``(M, 2)`` pairs, pixels of images of ``size_a`` and ``size_b`` ``(H, W)``.

    Returns:
        ``(M,)`` bool, True for the pairs kept (inside: ``x`` in ``[-0.5, W - 0.5]``, ``y`` likewise, the
        bounds that :func:`~torchfluidwarp.control.keyframes.check_points` allows).
    """
    keep = torch.ones(len(points_a), dtype=torch.bool, device=points_a.device)
    for p, (H, W) in ((points_a, size_a), (points_b, size_b)):
        keep &= (p[:, 0] >= -0.5) & (p[:, 0] <= W - 0.5) & (p[:, 1] >= -0.5) & (p[:, 1] <= H - 0.5)
        close = torch.cdist(p, p) < 1.0
        keep &= ~torch.tril(close, diagonal=-1).any(dim=1)  # close to an earlier point
    return keep


def _faces_or_none(a: Tensor, b: Tensor, face_index: tuple[int | None, int | None], names: tuple[str, str]):
    """Both images' face points, or None when mediapipe is missing or either image shows no face."""
    try:
        load_mediapipe()
        return (
            detect_face_points(a, face_index=face_index[0], name=names[0]),
            detect_face_points(b, face_index=face_index[1], name=names[1]),
        )
    except (ImportError, NoFaceFound):
        return None


def auto_points(
    image_a: Tensor,
    image_b: Tensor,
    *,
    match: MatchMode = "auto",
    face_index: tuple[int | None, int | None] = (None, None),
    names: tuple[str, str] = ("image_a", "image_b"),
    border: int | None = 3,
    max_points: int = 64,
    pixels: int = 8,
) -> tuple[Tensor, Tensor]:
    """Corresponding points of two images, for a morph with no point files.

    Args:
        image_a: ``(C, H, W)`` or ``(1, C, H, W)`` float image in ``[0, 1]``.
        image_b: the other image (its size may differ).
        match: ``"faces"``: the face landmarks of both (:func:`~torchfluidwarp.correspond.faces.detect_face_points`;
            needs the ``faces`` extra); ``"features"``: matched SIFT features
            (:func:`~torchfluidwarp.correspond.features.match_features`); ``"auto"``: faces when mediapipe is
            installed and both images show a face, features otherwise; ``"pixels"``: a lattice of ``pixels x pixels``
            points placed by a flow fitted to the images
            (:func:`~torchfluidwarp.correspond.refine.refine_points` with no anchors; slower: a coarse-to-fine
            image fit).
        face_index: which face in A and in B (0 = largest; ``None``: the largest, with a warning when there
            are several).
        names: the images' names in messages (their file names, say).
        border: points per image edge for :func:`border_points` (3: corners and edge midpoints), appended to
            both lists; ``None`` for none.
        max_points: the most feature matches (not counting the border).
        pixels: the lattice's points per side for ``match="pixels"``.

    Returns:
        ``(points_a, points_b)``: ``(M, 2)`` each, pixels ``(x, y)``, pixel centres at integers, in each
        image's own pixels, with image A's dtype and device; ``points_a[i]`` corresponds to ``points_b[i]``.
        Pairs that a morph cannot take are left out (:func:`usable_pairs`: a face point outside its
        image, a point within a pixel of an earlier one).

    Raises:
        ImportError: ``match="faces"`` without mediapipe (the message says how to install it).
        ValueError: ``match="faces"`` and no face in an image (the message names it); a bad argument;
            ``match="features"`` (or ``"auto"`` with no faces) and fewer than 3 matches.

    Example:
        >>> from torchfluidwarp.data import load_sample
        >>> a = load_sample("cat")
        >>> pa, pb = auto_points(a, a[..., 8:, 4:], match="features")  # B: A cropped, so b = a - (4, 8)
        >>> bool((pa - pb)[:-8].sub(torch.tensor([4.0, 8.0])).norm(dim=-1).median() < 0.5)  # the last 8: border
        True
    """
    a, b = single_image("image_a", image_a), single_image("image_b", image_b)
    if match not in ("auto", "faces", "features", "pixels"):
        raise InputError(f"match must be 'auto', 'faces', 'features' or 'pixels', got {match!r}", argument="match")
    found = None
    if match == "faces":
        found = (
            detect_face_points(a, face_index=face_index[0], name=names[0]),
            detect_face_points(b, face_index=face_index[1], name=names[1]),
        )
    elif match == "auto":
        found = _faces_or_none(a, b, face_index, names)
    elif match == "pixels":
        none = a.new_zeros(0, 2)
        found = refine_points(a, b, none, none, extra=check_int("pixels", pixels))[:2]
    if found is None:
        found = match_features(a, b, max_points=max_points)
        if len(found[0]) < 3:
            raise InputError(
                f"found {len(found[0])} matching features between {names[0]} and {names[1]} (need 3 or more); "
                "give the points by hand, or let the pixels place them (match='pixels')",
                argument="match",
            )
    points_a, points_b = (p.to(device=a.device, dtype=a.dtype) for p in found)
    size_a, size_b = (a.shape[-2], a.shape[-1]), (b.shape[-2], b.shape[-1])
    if border is not None:
        points_a = torch.cat([points_a, border_points(size_a, per_side=border, device=a.device, dtype=a.dtype)])
        points_b = torch.cat([points_b, border_points(size_b, per_side=border, device=a.device, dtype=a.dtype)])
    keep = usable_pairs(points_a, points_b, size_a, size_b)
    return points_a[keep], points_b[keep]
