"""What :func:`~torchfluidwarp.morph.morphing.morph` returns: a fitted morph that renders its frames on demand.

Nothing is rendered until asked for, so a morph of any length holds only its fit and its two images:

* ``result.frame(t)`` renders the frame at any ``t`` in ``[0, 1]`` (``frame(0.5)`` is the middle image);
* ``result.iter_frames()`` yields the ``N`` frames in order, a few at a time, in bounded memory (what the CLI
  streams to its writers);
* ``result.frames``, ``forward_frames``, ``backward_frames``, ``maps``, ``maps_b`` and ``folded`` render all ``N``
  frames once, on first access (refused beforehand when they would not fit in ``max_memory``).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import torch
from torch import Tensor

from torchfluidwarp._checks import check_int, check_memory, check_real, warn
from torchfluidwarp.control.keyframes import KeyframeFit
from torchfluidwarp.errors import AdvisedWarning, Hint, InputError
from torchfluidwarp.io import write_animation
from torchfluidwarp.morph.render import MorphFrames, Scene, raster_bytes, raster_maps, render

RASTER_BYTES = 2**26
"""How many bytes of the maps' working rasters :meth:`MorphResult.iter_frames` computes in one pass through time
(64 MB: about 60 frames' maps at the default grid): each pass serves that many frames, rendered ``chunk`` at a
time, instead of one pass per ``chunk``."""

__all__ = ["MorphResult"]


class MorphResult:
    """A fitted morph of ``N`` frames (``len(result)``), rendered on demand.

    Two frames of coordinates, each stated:

    * **the frames' pixels** (the canvas, ``(x, y)``, pixel centres at integers; image A's pixels unless
      ``Blending(size=...)`` sets another size): :attr:`trajectories`, :attr:`points`, :attr:`error` and the
      frames. These are the morph's figures: the pre-alignment is in them. Each picture lies on the canvas by one
      scale factor for both axes, the smallest that covers it, the crop centred on its points (:attr:`canvas_from_a`,
      :attr:`canvas_from_b`): neither is stretched, and each is read at its own resolution. Frame 0 is A so
      placed, the last frame B so placed. :attr:`maps` are in A's own pixels and :attr:`maps_b` in B's.
    * **the fluid box's frame**: everything :attr:`fit` holds (its ``points``, ``trajectories``, ``error``,
      ``keyframe_errors``, ``warp`` and ``forces``) is in pixels of the fluid's box :attr:`box`, before the
      pre-alignment: box pixel ``(0, 0)`` is pixel ``(box[0], box[1])`` of the canvas. So ``fit.error`` is
      ``fit.keyframe_errors[-1]``'s, and ``fit.animate(image)`` replays the flow on a picture of the box's size
      ``(box[3] - box[1], box[2] - box[0])``. When the box is the picture (``PaperSettings(margin=None)``) and
      there is no pre-alignment (``align=None``), ``fit.animate(image_a)`` gives :attr:`forward_frames` at the
      frames' times ``0, 1, ..., T`` steps (``frames=T + 1`` with the linear motion).

    Attributes:
        fit: the keyframe fit, in the fluid box's frame (see above): pass it as another morph's ``warm_start``.
        alignment: ``(3, 3)`` pre-alignment ``M`` in the canvas's pixels: from A's place on the canvas to B's
            (B's pixels are ``canvas_from_b^-1 M`` of A's on the canvas).
        box: ``(x0, y0, x1, y1)`` the fluid's box in the canvas's pixels (``x1``, ``y1`` exclusive); it may reach beyond
            the picture (the natural method's does, by :data:`~torchfluidwarp.morph.fit.PAD` on each side or more).
        trajectories: ``(T + 1, M, 2)`` A's points at each fluid step, in the frames' pixels (the fit's paths
            moved to the canvas and pre-aligned by ``M`` interpolated to that step).
        points: ``(M, 2)`` A's points carried to the last frame (``trajectories[-1]``), the frames' pixels.
        targets: ``(M, 2)`` where A's points were to end, the frames' pixels: B's points placed on the canvas,
            or, for points that features or a flow placed (``morph(match=...)`` without faces), where the pixels'
            alignment moved B's side (``apply_alignment(torch.linalg.inv(result.canvas_from_b), result.targets)``
            gives them in B's own pixels).
        error: ``(M,)`` pixels of the last frame: the distance from each of A's points carried to the last frame
            to its target (divide by B's scale, ``canvas_from_b[0, 0]``, for B's pixels).
        let_go: ``(M,)`` bool: the marks the natural morph let go so as not to fold (they cross, as where a head
            turns and hides part of one side, or lie around a squeeze): each ends where the spline through the
            others takes it, and its :attr:`error` says how far that is from its target. False for every mark of
            the paper's method and of points that features or the pixels placed.
        message: the fit's summary, with :attr:`error`'s mean and maximum, over the marks met and the marks let
            go apart when any was let go (:meth:`error_summary`).
        seconds: wall time per phase: ``"fit"``, ``"inverse"`` (the fitted flow's roll-out, and the paper
            inverse's small fits), ``"total"`` (both); ``"render"`` once all frames have been rendered.
        frames: ``(N, C, H, W)`` the morph on the canvas; frame 0 is image A, frame ``N - 1`` is image B, each
            placed on the canvas. ``C`` is the richer colour model of the two (grey and RGB give RGB; alpha, RGBA
            if either has it). This and the
            attributes below render all ``N`` frames once, on first access of any of them, and keep them.
        forward_frames: ``(N, C, H, W)`` image A warped forward (pre-alignment included).
        backward_frames: ``(N, C, H, W)`` image B pulled back along the flow.
        maps: ``(N, H, W, 2)`` backward coordinate maps of image A's whole warp (pre-alignment included), in
            A's own pixels: ``forward_frames[k] = warp_image(A, maps[k])``. Check them for folds with
            :func:`~torchfluidwarp.warp.frames.jacobian_determinant`.
        maps_b: ``(N, H, W, 2)`` where each frame reads image B (B's own pixels).
        folded: fraction of the pixels of ``maps`` and ``maps_b`` (all frames) whose Jacobian determinant is
            ``<= 0`` (0 for a fold-free morph; a ``RuntimeWarning`` gives their number when it is not).
    """

    def __init__(
        self,
        scene: Scene,
        fit: KeyframeFit,
        alignment: Tensor,
        trajectories: Tensor,
        targets: Tensor,
        count: int,
        dtype: torch.dtype,
        seconds: dict[str, float],
        max_memory: float | None = None,
        let_go: Tensor | None = None,
        smoother: Hint | None = None,
    ) -> None:
        self._scene = scene
        self._smoother = smoother  # the fold warning's advice: the method's own setting that smooths its flow
        self.fit = fit
        self.alignment = alignment
        self.trajectories = trajectories
        self.targets = targets
        self.error = (trajectories[-1] - targets.to(trajectories.dtype)).norm(dim=-1)
        self.let_go = torch.zeros_like(self.error, dtype=torch.bool) if let_go is None else let_go.to(self.error.device)
        self._count = count
        self._dtype = dtype
        self.seconds = seconds
        self._max_memory = max_memory
        self._all: MorphFrames | None = None
        self._folded: float | None = None

    @property
    def box(self) -> tuple[int, int, int, int]:
        return self._scene.box

    @property
    def sizes(self) -> tuple[tuple[int, int], tuple[int, int]]:
        """``((H_a, W_a), (H_b, W_b))``: the sizes of image A and image B as the morph was given them (the frames'
        size, the canvas, is ``frames.shape[-2:]``)."""
        assert self._scene.size_a is not None and self._scene.size_b is not None
        return tuple(self._scene.size_a), tuple(self._scene.size_b)  # type: ignore[return-value]

    @property
    def canvas_from_a(self) -> Tensor:
        """``(3, 3)`` float64: image A's pixels to the frames' (one scale factor and a shift, or one factor per
        axis on a canvas of A's shape up to rounding; the identity when the canvas is A's size)."""
        assert self._scene.place_a is not None
        return self._scene.place_a

    @property
    def canvas_from_b(self) -> Tensor:
        """``(3, 3)`` float64: image B's pixels to the frames' (one scale factor and a shift): where the last
        frame shows each of B's pixels. ``apply_alignment(torch.linalg.inv(result.canvas_from_b), result.points)``
        gives A's points carried to the last frame in B's own pixels."""
        assert self._scene.place_b is not None
        return self._scene.place_b

    @property
    def points(self) -> Tensor:
        return self.trajectories[-1]

    @property
    def message(self) -> str:
        return f"{self.fit.message}; in the last frame's pixels: {self.error_summary(4)}"

    @property
    def met_error(self) -> Tensor:
        """``(K,)`` :attr:`error` of the marks the morph did not let go (:attr:`let_go`): how well the fit met
        them, pixels of the last frame."""
        return self.error[~self.let_go]

    def error_summary(self, digits: int = 2) -> str:
        """:attr:`error`'s mean and maximum in words, over the marks met and over those let go (:attr:`let_go`,
        the first five named by their indices into :attr:`error`: the marks the morph kept, which are the points
        given unless a ``Blending.size`` crop left some out or points placed twice were dropped) apart: a mark let
        go on purpose, however far it ends, says nothing of how well the fit met the rest.

        Args:
            digits: decimals of the figures (pixels of the last frame).
        """
        kept, gone = self.met_error, self.error[self.let_go]
        if not gone.numel():
            return f"mean point error {float(kept.mean()):.{digits}f} px (max {float(kept.max()):.{digits}f})"
        met = (
            f"mean point error {float(kept.mean()):.{digits}f} px (max {float(kept.max()):.{digits}f}) over the "
            f"{kept.numel()} mark{'s' if kept.numel() != 1 else ''} met"
            if kept.numel()
            else "no mark met"
        )
        which = [int(i) for i in self.let_go.nonzero().flatten()]
        named = ", ".join(map(str, which[:5])) + (", ..." if len(which) > 5 else "")
        if gone.numel() == 1:
            return f"{met}; 1 let go so as not to fold (point {named}), {float(gone[0]):.{digits}f} px from its target"
        return (
            f"{met}; {gone.numel()} let go so as not to fold (points {named}), {float(gone.min()):.{digits}f} to "
            f"{float(gone.max()):.{digits}f} px from their targets"
        )

    def __len__(self) -> int:
        return self._count

    def __repr__(self) -> str:
        C, (H, W) = self._scene.a.shape[1], self._scene.size
        return f"MorphResult({self._count} frames of ({C}, {H}, {W}), {self._dtype}, rendered={self._all is not None})"

    @property
    def times(self) -> Tensor:
        """``(N,)`` the fluid time of each frame, in steps ``0..T`` (the shape's schedule of its ``t``)."""
        steps, motion = self._scene.steps, self._scene.motion
        return torch.tensor([steps * motion(t) for t in self.frame_ts(0, self._count)], dtype=torch.float64)

    def frame_ts(self, start: int, stop: int) -> list[float]:
        """The morph times ``t`` in ``[0, 1]`` of frames ``start`` to ``stop - 1``: the ``N`` frames are evenly
        spaced, frame ``k`` at ``k / (N - 1)``, the last exactly at 1 (what :meth:`render` takes)."""
        return [1.0 if k == self._count - 1 else k / (self._count - 1) for k in range(start, min(stop, self._count))]

    def _render(self, ts: list[float], keep: bool = True) -> MorphFrames:
        with torch.no_grad():
            return render(self._scene, ts, keep)

    def render(self, ts: Sequence[float]) -> MorphFrames:
        """Render the morph at the times ``ts`` (increasing, each in ``[0, 1]``) with its warped images and maps.

        Memory grows with ``len(ts)``; the frames come in the computation's dtype (float32 for half inputs).
        """
        values = [check_real("ts", t) for t in ts]
        if not values or any(not 0 <= t <= 1 for t in values) or any(b < a for a, b in zip(values, values[1:])):
            raise InputError(f"ts must be a non-empty, non-decreasing sequence of times in [0, 1], got {list(ts)}")
        return self._render(values)

    def frame(self, t: float) -> Tensor:
        """The morph at ``t`` in ``[0, 1]`` (0 is image A, 1 image B): ``(C, H, W)`` in A's and B's dtype.

        Any ``t``, not only the ``N`` frames' times: ``frame(0.5)`` is the middle image of the morph.
        """
        u = check_real("t", t)
        if not 0 <= u <= 1:
            raise InputError(f"t must be in [0, 1], got {t!r}")
        return self._render([u]).frames[0].to(self._dtype)

    def iter_frames(self, chunk: int = 8) -> Iterator[Tensor]:
        """Yield the ``N`` frames in order, ``(C, H, W)`` each, rendering ``chunk`` at a time.

        Memory stays that of ``chunk`` frames whatever ``N``. Once the last frame is out, a ``RuntimeWarning``
        gives the number of folded map pixels if there were any, and :attr:`folded` is known.
        """
        if self._all is not None:
            check_int("chunk", chunk)
            yield from self._all.frames.to(self._dtype).unbind(0)
            return
        for part in self.iter_rendered(chunk, keep=False):  # frames only: the warped images and maps come back empty
            yield from part.frames.unbind(0)

    def save(self, path: str | os.PathLike[str], *, fps: float = 15.0, overwrite: bool = False, loop: int = 0) -> Path:
        """Write the morph's ``N`` frames to ``path``, rendering them as they are written (:meth:`iter_frames`), as
        :func:`~torchfluidwarp.io.write_animation` writes them.

        Args:
            path: ``*.gif``, ``*.mp4`` (the ``video`` extra), ``*.webp``, or a folder of PNG frames (a path ending
                in ``/``); missing parent folders are made.
            fps: frames per second, 0.01 to 1000 (15 by default, as the command line's).
            overwrite: replace an existing output.
            loop: a GIF's repeat count, 0 (forever) to 65535.

        Returns:
            The path written.

        Raises:
            FileExistsError: the output exists and ``overwrite`` is false.
            InputError: an unknown suffix, or a bad ``fps`` or ``loop`` (before any frame is rendered).

        Example:
            >>> import tempfile, torch
            >>> from torchfluidwarp import morph
            >>> a = torch.rand(3, 32, 32)
            >>> pa = torch.tensor([[8.0, 8.0], [24.0, 8.0], [16.0, 24.0]])
            >>> result = morph(a, a.flip(-1), pa, pa + 1, frames=4, progress=False)
            >>> result.save(tempfile.mkdtemp() + "/morph.gif").name
            'morph.gif'
        """
        return write_animation(path, self.iter_frames(), fps=fps, overwrite=overwrite, loop=loop)

    def iter_rendered(self, chunk: int = 8, keep: bool = True) -> Iterator[MorphFrames]:
        """Render the ``N`` frames in order, ``chunk`` at a time: each chunk's frames in A's and B's dtype, with
        (``keep``) their warped images and maps, as :meth:`render` returns them.

        The maps of many frames are made in one pass through the fluid's time. Memory stays that of ``chunk``
        frames whatever ``N``; once the last chunk is out, :attr:`folded` is known and a ``RuntimeWarning`` gives
        the number of folded map pixels if there were any.
        """
        chunk = check_int("chunk", chunk)
        folded = 0
        with torch.no_grad():
            group = max(chunk, RASTER_BYTES // raster_bytes(self._scene))  # frames whose maps one pass makes
        for first in range(0, self._count, group):
            ts = self.frame_ts(first, first + group)
            with torch.no_grad():
                g, k = raster_maps(self._scene, ts)
            for start in range(0, len(ts), chunk):
                rasters = (g[start : start + chunk], None if k is None else k[start : start + chunk])
                with torch.no_grad():
                    part = render(self._scene, ts[start : start + chunk], keep=keep, rasters=rasters)
                folded += part.folded
                part.frames = part.frames.to(self._dtype)
                yield part
                del part
        self._set_folded(folded)

    def _set_folded(self, count: int) -> None:
        H, W = self._scene.size
        n_pixels = 2 * self._count * H * W
        self._folded = count / n_pixels
        if count:
            warn(
                AdvisedWarning(
                    f"the morph's maps fold on {count:,} of {n_pixels:,} pixels ({_share(count / n_pixels)}) over "
                    "all frames of both images: the flow crushes part of a picture onto itself; check the marks for "
                    "points that cross",
                    hint=self._smoother,
                )
            )

    def bytes_per_frame(self) -> int:
        """Bytes one rendered frame holds with its warped images and maps."""
        C, (H, W) = self._scene.a.shape[1], self._scene.size
        return H * W * (3 * C + 2 * 2) * self._scene.a.element_size()

    def materialize(self) -> MorphResult:
        """Render all ``N`` frames (and their maps) now and keep them; returns ``self``.

        Raises:
            ValueError: they would not fit in the morph's ``max_memory``.
        """
        if self._all is None:
            check_memory(
                f"all {self._count} frames of this morph (result.frames, .maps, ...)",
                self._count * self.bytes_per_frame(),
                self._max_memory,
                "morph(max_memory=...), or stream them with result.iter_frames()",
            )
            t0 = time.perf_counter()
            self._all = self._render(self.frame_ts(0, self._count))
            self.seconds["render"] = time.perf_counter() - t0
            self._set_folded(self._all.folded)
        return self

    def _get_all(self) -> MorphFrames:
        self.materialize()
        assert self._all is not None
        return self._all

    @property
    def frames(self) -> Tensor:
        return self._get_all().frames.to(self._dtype)

    @property
    def forward_frames(self) -> Tensor:
        return self._get_all().forward.to(self._dtype)

    @property
    def backward_frames(self) -> Tensor:
        return self._get_all().backward.to(self._dtype)

    @property
    def maps(self) -> Tensor:
        return self._get_all().maps_a

    @property
    def maps_b(self) -> Tensor:
        return self._get_all().maps_b

    @property
    def folded(self) -> float:
        if self._folded is None:
            self.materialize()
        assert self._folded is not None
        return self._folded


def _share(fraction: float) -> str:
    """``0.0123`` as ``'1.2%'``; a share under 0.01% as ``'under 0.01%'``."""
    return "under 0.01%" if fraction < 1e-4 else f"{100 * fraction:.2g}%"
