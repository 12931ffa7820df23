"""The measures over a whole :class:`~torchfluidwarp.morph.MorphResult`, streamed: per-frame folds, the path, and
:func:`morph_report`, every figure in one JSON-ready dict (what ``torchfluidwarp morph --report`` writes)."""

from __future__ import annotations

import math
from collections.abc import Generator, Iterator
from typing import Any, Protocol

import torch
from torch import Tensor

from torchfluidwarp._checks import check_int, check_picture, check_tensor
from torchfluidwarp.control.alignment import apply_alignment
from torchfluidwarp.control.keyframes import KeyframeFit
from torchfluidwarp.errors import InputError
from torchfluidwarp.metrics.ghost import image_ghosting
from torchfluidwarp.metrics.maps import folded_pixels, seam_figure
from torchfluidwarp.metrics.path import PathKind, PathTally, path_distances, path_smoothness
from torchfluidwarp.metrics.points import end_error, ghosting


class Morph(Protocol):
    """What the measures read from a morph (a :class:`~torchfluidwarp.morph.MorphResult`)."""

    fit: KeyframeFit
    error: Tensor  # (M,) pixels of the last frame
    let_go: Tensor  # (M,) bool: the marks let go so as not to fold

    @property
    def met_error(self) -> Tensor: ...  # (K,) error of the marks not let go

    @property
    def sizes(self) -> tuple[tuple[int, int], tuple[int, int]]: ...  # image A's and image B's (H, W)

    @property
    def canvas_from_b(self) -> Tensor: ...  # (3, 3) B's pixels to the frames' (canvas) pixels

    def __len__(self) -> int: ...

    def iter_frames(self, chunk: int = 8) -> Iterator[Tensor]: ...

    def iter_rendered(self, chunk: int = 8) -> Iterator[Any]: ...  # MorphFrames of chunk frames, in order


def _stream(result: Morph, chunk: int) -> Iterator[tuple[Tensor, Tensor, Tensor, Tensor, Tensor]]:
    """``(frame (C, H, W), map_a (H, W, 2), map_b (H, W, 2), warped_a (C, H, W), warped_b (C, H, W))`` for each of
    the ``N`` frames, in order, rendered ``chunk`` frames at a time through the result's public
    :meth:`iter_rendered` (``warped_a`` is A warped forward, ``warped_b`` B pulled back)."""
    for part in result.iter_rendered(chunk):
        yield from zip(
            part.frames.unbind(0),
            part.maps_a.unbind(0),
            part.maps_b.unbind(0),
            part.forward.unbind(0),
            part.backward.unbind(0),
        )


def morph_folds(result: Morph, chunk: int = 8) -> tuple[Tensor, Tensor]:
    """Folded pixels per frame of a morph's maps into A and into B (:func:`folded_pixels`), rendered ``chunk``
    frames at a time: ``(N,)`` int64 each."""
    chunk = check_int("chunk", chunk)
    counts = [(folded_pixels(ma)[0], folded_pixels(mb)[0]) for _, ma, mb, *_ in _stream(result, chunk)]
    return torch.stack([a for a, _ in counts]), torch.stack([b for _, b in counts])


def morph_path(result: Morph, kind: PathKind = "pixel", chunk: int = 8) -> Tensor:
    """:func:`path_distances` of a morph's ``N`` frames, rendered ``chunk`` at a time: ``(N - 1,)``."""
    return path_distances(result.iter_frames(check_int("chunk", chunk)), kind)


def _number(x: float) -> float | None:
    return None if math.isnan(x) or math.isinf(x) else x


def _stats(d: Tensor, ok: Tensor) -> dict[str, Any]:
    """JSON-ready figures of distances ``(K,)`` over the points located (``None`` where none was)."""
    v = d[ok]
    some = v.numel() > 0
    return {
        "mean": float(v.mean()) if some else None,
        "median": float(v.median()) if some else None,
        "max": float(v.max()) if some else None,
        "located": int(ok.sum()),
        "of": int(ok.numel()),
        "per_point": [float(x) if bool(o) else None for x, o in zip(d, ok)],
    }


def _inside(map1: Tensor, size: tuple[int, int]) -> Tensor:
    """``(H, W)`` bool: where a map ``(H, W, 2)`` reads inside a picture of ``size`` ``(h, w)`` (between its
    first and last pixel centres, where bilinear reading holds no edge pixel)."""
    x, y = map1[..., 0], map1[..., 1]
    return (x >= 0) & (x <= size[1] - 1) & (y >= 0) & (y <= size[0] - 1)


def morph_report(
    result: Morph,
    image_a: Tensor,
    image_b: Tensor,
    points_a: Tensor,
    points_b: Tensor,
    held_out: tuple[Tensor, Tensor] | None = None,
    *,
    path: PathKind = "pixel",
    chunk: int = 8,
) -> dict[str, Any]:
    """Every measure of a morph in one pass over its frames (``chunk`` rendered at a time), as a JSON-ready dict.

    Args:
        result: the morph of ``image_a`` into ``image_b`` (:func:`~torchfluidwarp.morph.morph`).
        image_a: ``(C, H, W)`` or ``(1, C, H, W)``, as given to the morph.
        image_b: ``(C, H_b, W_b)`` or ``(1, C, H_b, W_b)``, as given to the morph (any size).
        points_a: ``(M, 2)`` the marked points, A's pixels.
        points_b: ``(M, 2)`` the marked points, B's pixels.
        held_out: ``(points_a, points_b)`` ``(K, 2)`` each: corresponding points that were not given to the morph.
        path: the neighbour distance of :func:`path_distances`.
        chunk: frames rendered at a time.

    Returns:
        ``{"frames", "size": [H, W], "mid_frame", "mid_t", "folds": {"a", "b": per-frame counts, "total",
        "fraction"}, "landmark_error_px": {"mean", "max", "met", "let_go", "per_point"}, "marked": {"end",
        "ghost"}, "held_out": {"end", "ghost"} or None, "image_ghost": {"median", "p90", "mean", "covered",
        "textured", "scale"}, "seam": {"a", "b", "max"}, "path": {"kind", "distances", "total", "mean", "max",
        "variance"}}``; ``"size"`` is the frames' (A's, or ``Blending.size``), and each ``"end"``/``"ghost"``
        holds ``mean``, ``median``, ``max`` (pixels of the frame; ``None`` when no point was located),
        ``located``, ``of`` and ``per_point``. ``"landmark_error_px"`` is ``result.error`` (pixels of the last
        frame): its ``mean`` and ``max`` over the ``met`` marks (``result.met_error``; ``None`` when every mark
        was let go), ``let_go`` the indices of the marks let go so as not to fold (``result.let_go``), and
        ``per_point`` every mark's; indices into ``result.error``, the marks the morph kept (those a
        ``Blending.size`` crop leaves out, or repeats, are not among them). The middle frame is ``N // 2``;
        "end" is measured in the last frame, "ghost" in the middle one. ``"image_ghost"`` is the ghosting seen in
        the middle frame's pixels, with no points (:func:`~torchfluidwarp.metrics.image_ghosting`): how far apart
        A's and B's structures stand there, from A warped forward and B pulled back, over the pixels both maps
        read inside their picture (``"covered"``, a fraction of the frame) and where both show structure
        (``"textured"``); ``median``, ``p90`` and ``mean`` are in the frame's pixels (``None`` when nothing is
        textured).
    """
    frames = report_frames(result, image_a, image_b, points_a, points_b, held_out, path=path, chunk=chunk)
    while True:
        try:
            next(frames)
        except StopIteration as done:
            return done.value


def report_frames(
    result: Morph,
    image_a: Tensor,
    image_b: Tensor,
    points_a: Tensor,
    points_b: Tensor,
    held_out: tuple[Tensor, Tensor] | None = None,
    *,
    path: PathKind = "pixel",
    chunk: int = 8,
) -> Generator[Tensor, None, dict[str, Any]]:
    """:func:`morph_report` as its pass goes: yields the ``N`` frames ``(C, H, W)`` as they are rendered, and
    returns the report (``report = yield from report_frames(...)``).

    A caller who writes the frames (an animation writer reading this generator) and measures the morph renders
    each frame once. The arguments are those of :func:`morph_report`, checked before the generator is returned.

    Example:
        >>> import torch
        >>> from torchfluidwarp.morph import morph
        >>> a, p = torch.rand(3, 32, 32), torch.tensor([[8.0, 8.0], [24.0, 8.0], [16.0, 24.0]])
        >>> result = morph(a, a, p, p, frames=3, progress=False)
        >>> written = []
        >>> def frames():
        ...     report = yield from report_frames(result, a, a, p, p)
        ...     written.append(report["frames"])
        >>> [tuple(f.shape) for f in frames()], written
        ([(3, 32, 32), (3, 32, 32), (3, 32, 32)], [3])
    """
    check_picture("image_a", image_a)
    check_picture("image_b", image_b)
    check_tensor("points_a", points_a, shape=[None, 2])
    check_tensor("points_b", points_b, shape=[points_a.shape[0], 2])
    chunk = check_int("chunk", chunk)
    for name, image, size in zip(("image_a", "image_b"), (image_a, image_b), result.sizes):
        if (image.shape[-2], image.shape[-1]) != tuple(size):
            raise InputError(
                f"{name} must be the morph's image {name[-1].upper()}, of size {tuple(size)}, got "
                f"{(image.shape[-2], image.shape[-1])}",
                argument=name,
            )
    pairs = {"marked": (points_a, points_b)}
    if held_out is not None:
        check_tensor("held_out[0]", held_out[0], shape=[None, 2])
        check_tensor("held_out[1]", held_out[1], shape=[held_out[0].shape[0], 2])
        pairs["held_out"] = held_out
    tally = PathTally(path)
    return _report_pass(result, image_a, image_b, pairs, tally, chunk)


def _report_pass(
    result: Morph,
    image_a: Tensor,
    image_b: Tensor,
    pairs: dict[str, tuple[Tensor, Tensor]],
    tally: PathTally,
    chunk: int,
) -> Generator[Tensor, None, dict[str, Any]]:
    """The pass of :func:`report_frames`, over checked arguments."""
    size = (image_a.shape[-2], image_a.shape[-1])
    n = len(result)
    mid = n // 2
    folds_a: list[int] = []
    folds_b: list[int] = []
    kept: dict[int, tuple[Tensor, Tensor]] = {}
    image_ghost: dict[str, Any] = {}
    size_b = (image_b.shape[-2], image_b.shape[-1])
    for k, (frame, ma, mb, fa, fb) in enumerate(_stream(result, chunk)):
        tally.add(frame)
        folds_a.append(int(folded_pixels(ma)[0]))
        folds_b.append(int(folded_pixels(mb)[0]))
        if k in (mid, n - 1):
            kept[k] = (ma.detach().cpu(), mb.detach().cpu())
        if k == mid:  # measured now, while the chunk holds the warped pictures
            image_ghost = image_ghosting(
                fa.detach(), fb.detach(), _inside(ma.detach(), size) & _inside(mb.detach(), size_b)
            )
        yield frame
    distances = tally.distances()
    canvas = (kept[mid][0].shape[0], kept[mid][0].shape[1])  # the frames' (H, W): A's size, or Blending.size
    figures: dict[str, Any] = {}
    for name, (pa, pb) in pairs.items():
        pa, pb = pa.detach().cpu().double(), pb.detach().cpu().double()  # maps_b read B's own pixels
        placed = apply_alignment(result.canvas_from_b.cpu(), pb)  # B's points where the last frame shows them
        figures[name] = {
            "end": _stats(*end_error(kept[n - 1][0], pa, placed)),
            "ghost": _stats(*ghosting(*kept[mid], pa, pb)),
        }
    err = result.error.detach().reshape(-1).double().cpu()  # the last frame's pixels (MorphResult.error)
    gone = result.let_go.detach().reshape(-1).cpu()
    met = result.met_error.detach().reshape(-1).double().cpu()
    seam_a, seam_b = seam_figure(kept[mid][0]), seam_figure(kept[mid][1])
    folded = sum(folds_a) + sum(folds_b)
    return {
        "frames": n,
        "size": list(canvas),
        "mid_frame": mid,
        "mid_t": mid / (n - 1),
        "folds": {"a": folds_a, "b": folds_b, "total": folded, "fraction": folded / (2 * n * canvas[0] * canvas[1])},
        "landmark_error_px": {
            "mean": _number(float(met.mean())) if met.numel() else None,
            "max": _number(float(met.max())) if met.numel() else None,
            "met": int(met.numel()),
            "let_go": gone.nonzero()[:, 0].tolist(),
            "per_point": [_number(float(e)) for e in err],
        },
        "marked": figures["marked"],
        "held_out": figures.get("held_out"),
        "image_ghost": image_ghost,
        "seam": {"a": seam_a, "b": seam_b, "max": max(seam_a, seam_b)},
        "path": {"kind": tally.kind, "distances": distances.tolist(), **path_smoothness(distances)},
    }
