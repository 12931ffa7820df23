"""Path smoothness: the distance between neighbouring frames of a morph, its total and its variance."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Literal

import torch
from torch import Tensor

from torchfluidwarp._checks import check_tensor
from torchfluidwarp.control.losses import ssim_loss
from torchfluidwarp.errors import InputError

PathKind = Literal["pixel", "ssim"]


def path_distances(frames: Iterable[Tensor], kind: PathKind = "pixel") -> Tensor:
    """The distance between each pair of neighbouring frames of a morph, streamed.

    Args:
        frames: ``N`` frames ``(C, H, W)`` (or an ``(N, C, H, W)`` tensor) in ``[0, 1]``, in order; an iterator
            such as ``result.iter_frames()`` keeps only two in memory.
        kind: ``"pixel"``: the mean absolute difference over channels and pixels (image units);
            ``"ssim"``: the structural dissimilarity ``(1 - SSIM) / 2``
            (:func:`~torchfluidwarp.control.losses.ssim_loss`, an 11-pixel Gaussian window).

    Returns:
        ``(N - 1,)`` float64; zeros for a still morph.
    """
    tally = PathTally(kind)
    for frame in frames:
        tally.add(frame)
    return tally.distances()


class PathTally:
    """:func:`path_distances` one frame at a time, for a caller that hands the frames on (to a writer) as they come.

    Example:
        >>> import torch
        >>> tally = PathTally()
        >>> for frame in torch.stack([torch.zeros(1, 2, 2), torch.ones(1, 2, 2)]):
        ...     tally.add(frame)
        >>> tally.distances()
        tensor([1.], dtype=torch.float64)
    """

    def __init__(self, kind: PathKind = "pixel") -> None:
        if kind not in ("pixel", "ssim"):
            raise InputError(f"kind must be 'pixel' or 'ssim', got {kind!r}", argument="kind")
        self.kind = kind
        self._out: list[float] = []
        self._prev: Tensor | None = None

    def add(self, frame: Tensor) -> None:
        """The next frame ``(C, H, W)``: its distance from the one before is kept (only that frame is held)."""
        check_tensor("frames", frame, ndim=3)
        cur = frame.detach().double()
        if self._prev is not None:
            prev = self._prev
            d = (cur - prev).abs().mean() if self.kind == "pixel" else ssim_loss(cur[None], prev[None])
            self._out.append(float(d))
        self._prev = cur

    def distances(self) -> Tensor:
        """``(N - 1,)`` float64: the distances of the frames added so far."""
        return torch.tensor(self._out, dtype=torch.float64)


def path_smoothness(distances: Tensor) -> dict[str, float]:
    """Summary of neighbour distances ``(N - 1,)`` (:func:`path_distances`): their ``total`` (the path's length),
    ``mean``, ``max`` and ``variance`` (population; 0 when the morph moves at an even pace), in the distances'
    units."""
    check_tensor("distances", distances, ndim=1)
    d = distances.double()
    if d.numel() == 0:
        return {"total": 0.0, "mean": 0.0, "max": 0.0, "variance": 0.0}
    return {
        "total": float(d.sum()),
        "mean": float(d.mean()),
        "max": float(d.max()),
        "variance": float(d.var(correction=0)),
    }
