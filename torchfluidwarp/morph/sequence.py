"""Morphing more than two images: a sequence through each of them, and the average of several.

* :func:`morph_sequence` chains the two-image morphs ``0 -> 1 -> 2 -> ...`` into one animation. The frames are
  shared out in proportion to how far the marked points travel in each segment, so with the default linear
  timing the points keep one speed through every middle image instead of jumping at the joint.
* :func:`average` warps each image to the mean shape of all the point sets with its own fitted flow and averages
  the results: the mean face (or object) of a set, fold-free like every morph.

Images are ``(C, H, W)`` (or ``(1, C, H, W)``) in ``[0, 1]``, of any size and aspect ratio; points ``(M, 2)`` in each
image's pixels, the same ``M`` features in the same order in every image. Both work on the first image's canvas,
where each image is placed as :func:`~torchfluidwarp.morph.morph` places a picture (one scale factor for both
axes: :func:`~torchfluidwarp.morph.morphing.placement`), never stretched.
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from torchfluidwarp._checks import check_instance, check_int, check_real, check_size, warn
from torchfluidwarp.control.alignment import apply_alignment, estimate_alignment
from torchfluidwarp.correspond import FoundPoints, MatchNotice, Note, find_each_face
from torchfluidwarp.correspond.auto import bordered_pairs
from torchfluidwarp.errors import AdvisedWarning, InputError, InputTypeError
from torchfluidwarp.io import write_animation
from torchfluidwarp.io.images import premultiplied, straight
from torchfluidwarp.morph.morphing import _as_image, _as_points, match_channels, morph, placement
from torchfluidwarp.morph.render import on_canvas
from torchfluidwarp.morph.result import MorphResult
from torchfluidwarp.morph.settings import Blending, MorphSettings, NaturalSettings, Timing

__all__ = ["MorphSequence", "morph_sequence", "AverageResult", "average"]


def _checked(
    images: Sequence[Tensor],
    points: Sequence[Tensor] | None,
    face_index: int | None = None,
    names: Sequence[str] | None = None,
) -> tuple[list[tuple[Tensor, Tensor]], bool, list[str]]:
    """Each image ``(1, C, H, W)``, in the richest colour model among them (:func:`match_channels`: nothing is
    dropped), with its points ``(M, 2)`` in its own pixels, neither resized; whether the points were found
    (``points`` ``None``: each one's face landmarks, :func:`~torchfluidwarp.correspond.find_each_face`, with a
    :class:`~torchfluidwarp.correspond.MatchNotice` where a picture shows several faces); and what messages call
    each image (its name, or ``images[i]``)."""
    if not isinstance(images, (list, tuple)) or not isinstance(points, (list, tuple, type(None))):
        raise InputTypeError("images and points must be lists (or tuples) of tensors (points may be None)")
    if len(images) < 2:
        raise InputError(f"images must hold at least 2 images, got {len(images)}")
    if points is not None and len(points) != len(images):
        raise InputError(f"points must hold one point set per image: {len(images)} images, {len(points)} sets")
    labels = list(names) if names is not None else [f"images[{i}]" for i in range(len(images))]
    pictures = [_as_image(name, image) for name, image in zip(labels, images)]
    found = points is None
    if points is None:  # the same landmarks of each one's face, in the same order
        points, note = find_each_face(pictures, face_index=face_index, names=labels)
        if note.notable:
            warn(MatchNotice(note))
    richest = pictures[0][..., :1, :1]  # one pixel stands for the picture's colour model
    for picture in pictures[1:]:
        richest, _ = match_channels(richest, picture[..., :1, :1])
    out = []
    for i, (picture, p) in enumerate(zip(pictures, points)):
        out.append((match_channels(richest, picture)[1], _as_points(f"points[{i}]", p, picture)))
    return out, found, labels


def _marks(
    pa: Tensor, pb: Tensor, found: bool, sizes: tuple[tuple[int, int], tuple[int, int]] | None = None
) -> tuple[Tensor | None, Tensor | None, FoundPoints | None]:
    """:func:`~torchfluidwarp.morph.morph`'s ``points_a``, ``points_b`` and ``placed``: the user's marks, or the
    landmarks the library found as ``placed`` (a crossing among them is not the user's order to check), with the
    border pairs a two-picture face morph has (:func:`~torchfluidwarp.correspond.auto.bordered_pairs`) when the
    pictures' ``sizes`` ``(H, W)`` are given."""
    if not found:
        return pa, pb, None
    if sizes is not None:
        pa, pb = bordered_pairs(pa, pb, *sizes)
    return None, None, FoundPoints(pa, pb, "faces", Note("the face landmarks of each picture"))


def _placed(image: Tensor, canvas: tuple[int, int], points: Tensor) -> Tensor:
    """``(3, 3)`` float64 on ``image``'s device: where :func:`~torchfluidwarp.morph.morph` places ``image``
    ``(1, C, H, W)`` marked at ``points`` ``(M, 2)`` on ``canvas`` ``(H_c, W_c)``, from its pixels to the canvas's
    (:func:`placement`)."""
    return placement((image.shape[-2], image.shape[-1]), canvas, points)[0].to(image.device)


class MorphSequence:
    """A morph through several images: its segments (:class:`MorphResult`), played one after the other.

    Segment ``i`` morphs image ``i`` into image ``i + 1``; its last frame is the next one's first, shown once.
    ``len(sequence)`` frames in all; ``frame(t)`` for any ``t`` in ``[0, 1]``; ``iter_frames()`` streams them.
    ``points`` holds the point set of each image, ``(M, 2)`` in its own pixels: the ones given, or the face
    landmarks found.
    """

    def __init__(self, segments: list[MorphResult], counts: list[int], points: list[Tensor] | None = None) -> None:
        self.segments = segments
        self.counts = counts  # frames of each segment, joints included in both
        self.points = points if points is not None else []
        self._starts = [0.0]
        total = sum(c - 1 for c in counts)
        for c in counts:
            self._starts.append(self._starts[-1] + (c - 1) / total)
        self._starts[-1] = 1.0

    def __len__(self) -> int:
        return sum(c - 1 for c in self.counts) + 1

    def frame(self, t: float) -> Tensor:
        """The frame at ``t`` in ``[0, 1]`` of the whole sequence, ``(C, H, W)``."""
        u = check_real("t", t)
        if not 0 <= u <= 1:
            raise InputError(f"t must be in [0, 1], got {t!r}")
        i = max(k for k in range(len(self.segments)) if self._starts[k] <= u)
        lo, hi = self._starts[i], self._starts[i + 1]
        return self.segments[i].frame(min(1.0, (u - lo) / (hi - lo)))

    def iter_frames(self, chunk: int = 8) -> Iterator[Tensor]:
        """Yield the ``len(self)`` frames in order, ``(C, H, W)`` each, in bounded memory."""
        for i, segment in enumerate(self.segments):
            frames = segment.iter_frames(chunk)
            if i:
                next(frames)  # the joint: already shown as the previous segment's last frame
            yield from frames

    @property
    def frames(self) -> Tensor:
        """``(N, C, H, W)`` all frames at once."""
        return torch.stack(list(self.iter_frames()))

    def save(self, path: str | os.PathLike[str], *, fps: float = 15.0, overwrite: bool = False, loop: int = 0) -> Path:
        """Write the sequence's frames to ``path``, rendering them as they are written: the arguments, the result
        and the errors of :meth:`MorphResult.save <torchfluidwarp.morph.result.MorphResult.save>`."""
        return write_animation(path, self.iter_frames(), fps=fps, overwrite=overwrite, loop=loop)


def _travel(pa: Tensor, pb: Tensor) -> float:
    """Mean distance the marked points travel, in the canvas's pixels."""
    return float((pb.double() - pa.double()).norm(dim=-1).mean())


def morph_sequence(
    images: Sequence[Tensor],
    points: Sequence[Tensor] | None = None,
    *,
    face_index: int | None = None,
    names: Sequence[str] | None = None,
    settings: MorphSettings = NaturalSettings(),
    frames: int = 60,
    timing: Timing = Timing(),
    blending: Blending = Blending(),
    progress: bool = True,
    max_memory: float | None = None,
) -> MorphSequence:
    """Morph through ``images`` in order, so that their ``points`` travel from set to set.

    Every segment is a :func:`~torchfluidwarp.morph.morph` on one canvas, the first image's size (or
    ``blending.size``), so no picture is stretched: each keeps its aspect ratio, placed on the canvas by one scale
    factor for both axes, the smallest that covers it, the crop centred on its points
    (:func:`~torchfluidwarp.morph.morphing.placement`), and read at its own resolution. The frames take the
    richest colour model of the images.

    Args:
        images: two or more images ``(C, H, W)`` (or ``(1, C, H, W)``), of any size and aspect ratio.
        points: one ``(M, 2)`` set per image, in that image's own pixels, the same features in the same order;
            ``None`` (the default): the landmarks of each image's face
            (:func:`~torchfluidwarp.correspond.find_each_face`; needs the ``faces`` extra), with border pairs and a
            crossing among them let go, as in a two-image face morph (:func:`~torchfluidwarp.correspond.find_points`).
        face_index: with ``points=None``, which face where an image shows several (0 = the largest, the default).
        names: what to call each image in messages (file names, say); default ``images[i]``.
        settings, timing, blending, progress, max_memory: as for :func:`~torchfluidwarp.morph.morph`, used for
            every segment. With the linear motion (``Timing()``, the default) the frames are shared out in
            proportion to each segment's travel on the canvas, so the points' speed is the same on both sides of
            every middle image; ``Timing(motion="smooth")`` eases to rest at each image instead.
        frames: frames of the whole sequence (at least one more than the number of segments).

    Returns:
        a :class:`MorphSequence` whose frames are ``(C, H, W)`` on the canvas: image ``i`` placed on it is the
        frame at the joint before segment ``i``.
    """
    check_instance("blending", blending, Blending)
    pairs, found, labels = _checked(images, points, face_index, names)
    first = pairs[0][0]
    canvas = (first.shape[-2], first.shape[-1]) if blending.size is None else check_size("blending.size", blending.size)
    on_canvas = replace(blending, size=canvas)
    placed = [apply_alignment(_placed(im, canvas, p), p.double()) for im, p in pairs]  # (M, 2) canvas pixels each
    n = check_int("frames", frames)
    if n < len(images):  # one frame at each image, the joints shared
        raise InputError(
            f"frames must be at least the number of images ({len(images)}: each is a frame of its own), got {n}",
            argument="frames",
        )
    travel = [max(_travel(a, b), 1e-6) for a, b in zip(placed, placed[1:])]
    segments = len(travel)
    # frames per segment (joints shared): at least 1 step each, then in proportion to the travel
    steps_total = n - 1
    shares = [max(1, round(steps_total * d / sum(travel))) for d in travel]
    shares[-1] = max(1, steps_total - sum(shares[:-1]))
    while sum(shares) > steps_total:  # rounding overshot: take from the largest
        shares[shares.index(max(shares))] -= 1
    results = []
    for i in range(segments):
        (a, pa), (b, pb) = pairs[i], pairs[i + 1]
        ma, mb, found_marks = _marks(pa, pb, found, ((a.shape[-2], a.shape[-1]), (b.shape[-2], b.shape[-1])))
        segment = partial(
            morph,
            a,
            b,
            ma,
            mb,
            placed=found_marks,
            settings=settings,
            frames=shares[i] + 1,
            timing=timing,
            blending=on_canvas,
            progress=progress,
            max_memory=max_memory,
        )
        results.append(_said_in(_terms(i, labels, found), segment))
    return MorphSequence(results, [s + 1 for s in shares], [p for _, p in pairs])


def _said_in(terms: dict[str, str], call: Callable[[], MorphResult]) -> MorphResult:
    """``call()``, one :func:`~torchfluidwarp.morph.morph` of a sequence or an average, with its warnings and its
    error said in ``terms`` (:func:`_in_terms`): every warning is caught as it is, then said again in the caller's
    terms, where the caller's own warning filters act on it; warnings said before an error are said too."""
    failure: InputError | InputTypeError | None = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # the caller's filters act on what is said again below
        warnings.filterwarnings("ignore", message=SAID_RANGE)  # said once per picture, by its name
        try:
            result = call()
        except (InputError, InputTypeError) as exc:
            failure = exc
    for caught_warning in caught:
        warn(_in_terms(caught_warning.message, terms))
    if failure is not None:
        raise _in_terms(failure, terms) from failure
    return result


def _terms(i: int, labels: Sequence[str], found: bool) -> dict[str, str]:
    """What :func:`morph_sequence` calls segment ``i``'s :func:`~torchfluidwarp.morph.morph` arguments: its
    ``image_a`` and ``image_b`` are the sequence's images ``i`` and ``i + 1`` (by their ``labels``), its
    ``points_a`` and ``points_b`` are ``points[i]`` and ``points[i + 1]``, or the landmarks found on those images
    when the caller gave no points (``found``); "A and B" in a message are those two images."""
    if found:
        points = f"{labels[i]}'s face landmarks", f"{labels[i + 1]}'s face landmarks"
    else:
        points = f"points[{i}]", f"points[{i + 1}]"
    return {
        "image_a": labels[i],
        "image_b": labels[i + 1],
        "points_a": points[0],
        "points_b": points[1],
        "A and B": f"{labels[i]} and {labels[i + 1]}",
    }


_ARGUMENT = re.compile(r"\b(image_[ab]|points_[ab]|A and B)\b")


def _in_terms(said: Exception | Warning | str, terms: dict[str, str]) -> Any:
    """An error or a warning of one segment's :func:`~torchfluidwarp.morph.morph`, said in ``terms``
    (:func:`_terms`): the library's own errors and warnings, and plain ``RuntimeWarning`` and ``UserWarning``
    (another kind says itself in its own terms and comes back as it is). The argument at fault is ``images`` or
    ``points`` (none where the points were found, or are the average's mean shape)."""
    if isinstance(said, (InputError, InputTypeError, AdvisedWarning)):
        argument = said.argument
        if argument in terms:  # the caller's images, its points, or none of its arguments (landmarks, mean shape)
            said_as = terms[argument]
            argument = "images" if argument.startswith("image") else "points" if said_as.startswith("points[") else None
        return type(said)(_ARGUMENT.sub(lambda m: terms[m.group(1)], said.message), argument=argument, hint=said.hint)
    if isinstance(said, str) or type(said) in (RuntimeWarning, UserWarning):
        text = _ARGUMENT.sub(lambda m: terms[m.group(1)], str(said))
        return text if isinstance(said, str) else type(said)(text)
    return said


SAID_RANGE = r"image_[ab]'s values span"
"""The start of :func:`~torchfluidwarp.morph.morph`'s note of a picture's values beyond ``[0, 1]``, which a
sequence or an average says once per picture under its own name instead of once per morph under another."""


@dataclass
class AverageResult:
    """What :func:`average` returns.

    Attributes:
        image: ``(C, H, W)`` the mean of the images, each warped to the mean shape, on the first image's canvas.
        points: ``(M, 2)`` the mean shape, in the first image's pixels.
        warped: ``(N, C, H, W)`` each image placed on the first image's canvas (one scale factor, never stretched)
            and warped to the mean shape.
        folded: the fraction of the warps' map pixels that fold (0 for a fold-free average).
        errors: ``(N,)`` each image's mean distance, in the first image's pixels, between its warped points and
            the mean shape, over the points its morph met (:attr:`~torchfluidwarp.morph.MorphResult.met_error`);
            NaN for an image whose every point was let go (its warning says so).
    """

    image: Tensor
    points: Tensor
    warped: Tensor
    folded: float
    errors: Tensor

    def __repr__(self) -> str:
        C, H, W = self.image.shape
        return (
            f"AverageResult(({C}, {H}, {W}) mean of {self.warped.shape[0]} images, {self.points.shape[0]} points, "
            f"{self.error_summary()}, folded {self.folded:.2%})"
        )

    def error_summary(self) -> str:
        """:attr:`errors` in words: their mean over the images that met any point, and how many met none
        (``"mean point error 0.41 px"``, ``"mean point error 0.41 px (1 of 3 images met no point)"``)."""
        met = self.errors.isfinite()  # NaN: an image whose every point was let go
        if not bool(met.any()):
            return "no image met any point"
        unmet = "" if bool(met.all()) else f" ({int((~met).sum())} of {met.numel()} images met no point)"
        return f"mean point error {float(self.errors[met].mean()):.2f} px{unmet}"


def average(
    images: Sequence[Tensor],
    points: Sequence[Tensor] | None = None,
    *,
    face_index: int | None = None,
    names: Sequence[str] | None = None,
    settings: MorphSettings = NaturalSettings(),
    progress: bool = False,
    max_memory: float | None = None,
) -> AverageResult:
    """The average of ``images``: each warped to the mean shape of ``points`` by its own flow, then averaged.

    Each image is placed on the first image's canvas as :func:`~torchfluidwarp.morph.morph` places a picture (one
    scale factor for both axes, the smallest that covers the canvas, the crop centred on its points:
    :func:`~torchfluidwarp.morph.morphing.placement`), so none is stretched, and read at its own resolution. The
    mean shape: every point set, so placed, brought onto the first by a similarity (least squares), averaged, and
    placed where the sets' own centroids and scales are on average on the canvas.

    Args:
        images: two or more images ``(C, H, W)`` (or ``(1, C, H, W)``), of any size and aspect ratio; the
            average takes the richest colour model among them.
        points: one ``(M, 2)`` set per image, in that image's own pixels, the same features in the same order;
            ``None`` (the default): the landmarks of each image's face
            (:func:`~torchfluidwarp.correspond.find_each_face`; needs the ``faces`` extra).
        face_index: with ``points=None``, which face where an image shows several (0 = the largest, the default).
        names: what to call each image in messages (file names, say); default ``images[i]``.
        settings, progress, max_memory: as for :func:`~torchfluidwarp.morph.morph`, used for every warp (each
            is rendered at its end only, so there are no frames, timing or region to set).

    Returns:
        an :class:`AverageResult`.
    """
    pairs, found, labels = _checked(images, points, face_index, names)
    first = pairs[0][0]
    H, W = first.shape[-2:]
    canvas = (H, W)
    places = [_placed(image, canvas, p) for image, p in pairs]
    sets = [apply_alignment(place, p.double()) for place, (_, p) in zip(places, pairs)]  # (M, 2) canvas pixels
    onto_first = [apply_alignment(estimate_alignment(p, sets[0], "similarity"), p) for p in sets]
    mean = torch.stack(onto_first).mean(0)
    # place the mean shape at the sets' mean position and size (rather than the first set's)
    back = torch.stack([apply_alignment(estimate_alignment(mean, p, "similarity"), mean) for p in sets]).mean(0)
    back[:, 0].clamp_(-0.5, W - 0.5)
    back[:, 1].clamp_(-0.5, H - 0.5)
    warped, folded, errors = [], 0.0, []
    for i, (place, (image, p)) in enumerate(zip(places, pairs)):
        # B is the same picture already on the canvas, where morph() places it by the identity, marked at the
        # mean shape `back` (a placement centred on `back` in the picture's own pixels would differ from A's)
        placed = on_canvas(image, place, canvas)
        terms = {
            "image_a": labels[i],
            "image_b": f"{labels[i]} on the canvas",
            "points_a": f"{labels[i]}'s face landmarks" if found else f"points[{i}]",
            "points_b": "the mean shape",
            "A and B": f"{labels[i]} and the mean shape",
        }
        ma, mb, found_marks = _marks(p, back.to(p), found)
        warp = partial(
            morph,
            image,
            placed,
            ma,
            mb,
            placed=found_marks,
            settings=settings,
            frames=2,
            blending=Blending(size=canvas),
            progress=progress,
            max_memory=max_memory,
        )
        result = _said_in(terms, warp)
        end = result.render([1.0])  # its forward warp at the end: A in the mean shape, on the canvas
        warped.append(end.forward[0])
        folded += end.folded / (2 * H * W)
        errors.append(float(result.met_error.mean()))  # the marks let go so as not to fold left out
    stack = torch.stack(warped)
    mean = straight(premultiplied(stack).mean(0, keepdim=True))[0]  # RGBA: averaged premultiplied, as frames blend
    return AverageResult(mean, back.to(first.dtype), stack, folded / len(pairs), torch.tensor(errors))
