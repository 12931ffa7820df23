"""Landmarks for a morph from the two pictures alone: faces when both show one, matched features otherwise, and
the pixels where too few features match.

:func:`find_points` says which matcher it used and why (:attr:`FoundPoints.reason`, a :class:`Note` that a
caller words in its own terms, as it does an :class:`~torchfluidwarp.errors.InputError`'s hint);
:func:`auto_points` returns the points alone and warns (:class:`MatchNotice`) when the automatic mode fell back
from faces or chose among several.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal, get_args

import torch
from torch import Tensor

from torchfluidwarp._checks import check_int, check_size, warn
from torchfluidwarp.control.alignment import apply_alignment, estimate_alignment
from torchfluidwarp.control.images import FoldWarning
from torchfluidwarp.core.grid import inside_picture, rescale_points, scale_factor
from torchfluidwarp.correspond._image import single_image
from torchfluidwarp.correspond.faces import (
    FACE_MESH_INDICES,
    INSTALL_HINT,
    Chosen,
    NoFaceFound,
    choose_face,
    find_faces,
    listing,
    load_mediapipe,
)
from torchfluidwarp.correspond.features import MIN_SIDE, match_features
from torchfluidwarp.correspond.refine import refine_points
from torchfluidwarp.errors import Hint, InputError
from torchfluidwarp.io import shrink_image

__all__ = [
    "FoundPoints",
    "MATCH_MODES",
    "MatchMode",
    "MatchNotice",
    "Matcher",
    "Note",
    "ValueHint",
    "auto_points",
    "border_pairs",
    "border_points",
    "bordered_pairs",
    "find_each_face",
    "find_points",
    "usable_pairs",
]

MatchMode = Literal["auto", "faces", "features", "pixels"]
MATCH_MODES: tuple[MatchMode, ...] = get_args(MatchMode)
"""The matchers' modes, :data:`MatchMode`'s values in order."""
Matcher = Literal["faces", "features", "pixels"]


@dataclass(frozen=True)
class ValueHint(Hint):
    """A :class:`~torchfluidwarp.errors.Hint` that names a setting with its value: ``match='features'`` for a
    Python caller, ``--match features`` for the command line (a name that starts with ``-`` is a flag: its first
    word, a space and the value).

    Example:
        >>> hint = ValueHint("use {setting} to skip the face search", "match", value="features")
        >>> hint.render("match"), hint.render("--match")
        ("use match='features' to skip the face search", 'use --match features to skip the face search')
    """

    value: str = ""

    def render(self, name: str | None) -> str:
        if name is None:
            return self.otherwise
        said = f"{name.split()[0]} {self.value}" if name.startswith("-") else f"{name}={self.value!r}"
        return self.text.format(setting=said)


def _skip_faces() -> ValueHint:
    return ValueHint("use {setting} to skip the face search", "match", value="features")


@dataclass(frozen=True)
class Note:
    """What :func:`find_points` did and why, with a hint that a caller says in its own terms.

    Attributes:
        message: what was used and why (``"no face found in a.jpg (817 x 1024 pixels); matched image features
            instead"``).
        hint: what to change, naming the setting (:class:`ValueHint`), or ``None``.
        notable: whether the user may want to act on it: the automatic mode fell back from faces, or from
            features to the pixels, or picked the largest of several faces; features asked for matched so few that
            they may be chance; the pixels' flow folds. :func:`auto_points` warns with the notable ones.
    """

    message: str
    hint: Hint | None = None
    notable: bool = False

    def explain(self, names: Mapping[str, str]) -> str:
        """The message and its hint with the settings called by the caller's ``names`` (``{"match": "--match"}``),
        as :meth:`torchfluidwarp.errors.InputError.explain` does."""
        if self.hint is None:
            return self.message
        advice = self.hint.render(names.get(self.hint.setting))
        return f"{self.message}; {advice}" if advice else self.message

    def __str__(self) -> str:
        return self.explain({} if self.hint is None else {self.hint.setting: self.hint.spelling or self.hint.setting})


class MatchNotice(UserWarning):
    """:func:`auto_points` fell back from faces to features, or from features to the pixels, or chose the largest of
    several faces (a notable :class:`Note`).

    Its message is the note with its hint as the library's functions spell the setting, or in the ``names`` given
    (a caller's own, as :meth:`Note.explain` takes them).

    Attributes:
        note: the :class:`Note`, to word it in a caller's terms (:meth:`Note.explain`).
    """

    def __init__(self, note: Note, names: Mapping[str, str] | None = None) -> None:
        super().__init__(str(note) if names is None else note.explain(names))
        self.note = note


@dataclass(frozen=True, eq=False)  # compared by identity: it holds tensors
class FoundPoints:
    """What :func:`find_points` found.

    Attributes:
        points_a, points_b: ``(M, 2)`` corresponding points, pixels ``(x, y)`` of each image (as
            :func:`auto_points` returns them).
        matcher: which matcher placed them: ``"faces"``, ``"features"`` or ``"pixels"``.
        reason: which matcher and why, in words (:class:`Note`).
    """

    points_a: Tensor
    points_b: Tensor
    matcher: Matcher
    reason: Note


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


BORDER_SLACK = 0.1
"""How far, as a fraction of B's longer side, B's own border point may lie from where the matched points' pose
sends A's (:func:`border_pairs`) and still be its partner: pictures framed alike (two face crops) keep their
frames on each other; a head-and-shoulders portrait against a group photograph does not."""


def border_pairs(
    points_a: Tensor, points_b: Tensor, size_a: tuple[int, int], size_b: tuple[int, int], per_side: int = 3
) -> tuple[Tensor, Tensor]:
    """Border points for a pair of pictures, and their partners, consistent with what was matched.

    A's :func:`border_points` are paired with B's own where the similarity that best maps the matched points
    ``points_a`` onto ``points_b`` ``(M, 2)`` (M >= 2) sends them within :data:`BORDER_SLACK` of B's longer side:
    the frames correspond, as a morph tool's border points assume. Elsewhere the partner is where the similarity
    sends A's point: pinning frames that do not correspond (a face that fills A and sits at the edge of a group
    photograph B) would drag the whole picture against the matched points, and the morph would swirl. Partners
    outside B are left out later (:func:`usable_pairs`).

    Args:
        points_a, points_b: ``(M, 2)`` the matched points, pixels ``(x, y)`` of each picture.
        size_a, size_b: the pictures' ``(H, W)``.
        per_side: as for :func:`border_points`.

    Returns:
        ``(border_a, border_b)``, ``(4 * (per_side - 1), 2)`` each, in ``points_a``'s dtype and device.

    Example:
        >>> pa = torch.tensor([[40.0, 40.0], [60.0, 40.0], [50.0, 60.0]])
        >>> ea, eb = border_pairs(pa, pa + 3, (100, 100), (100, 100))  # framed alike: B's own border
        >>> torch.equal(eb, border_points((100, 100)))
        True
        >>> ea, eb = border_pairs(pa, pa / 2 + 5, (100, 100), (100, 100))  # A's face twice B's
        >>> eb[:3].tolist()  # the top-left corners agree within 10 px; the pose sends the others inside B
        [[0.0, 0.0], [29.75, 5.0], [54.5, 5.0]]
    """
    ea, eb = (
        border_points(size, per_side=per_side, device=points_a.device, dtype=points_a.dtype)
        for size in (size_a, size_b)
    )
    if points_a.shape[0] < 2:
        return ea, eb
    posed = apply_alignment(estimate_alignment(points_a.double(), points_b.double(), "similarity"), ea.double())
    slack = BORDER_SLACK * max(size_b)
    agree = (posed - eb.double()).norm(dim=-1) <= slack
    return ea, torch.where(agree[:, None], eb, posed.to(eb.dtype))


def bordered_pairs(
    points_a: Tensor, points_b: Tensor, size_a: tuple[int, int], size_b: tuple[int, int], border: int | None = 3
) -> tuple[Tensor, Tensor]:
    """Matched points ``(M, 2)`` with their :func:`border_pairs` appended (``border`` a side; ``None``: none), the
    pairs a morph cannot take left out (:func:`usable_pairs`): what :func:`find_points` returns for a pair of
    pictures of ``size_a`` and ``size_b`` ``(H, W)``."""
    if border is not None:
        ea, eb = border_pairs(points_a, points_b, size_a, size_b, per_side=border)
        points_a, points_b = torch.cat([points_a, ea]), torch.cat([points_b, eb])
    keep = usable_pairs(points_a, points_b, size_a, size_b)
    return points_a[keep], points_b[keep]


def usable_pairs(points_a: Tensor, points_b: Tensor, size_a: tuple[int, int], size_b: tuple[int, int]) -> Tensor:
    """Which pairs a morph can take: both points inside their image, and neither within a pixel of an earlier one.

    Args:
        points_a, points_b: ``(M, 2)`` pairs, pixels of images of ``size_a`` and ``size_b`` ``(H, W)``.

    Returns:
        ``(M,)`` bool, True for the pairs kept (inside: :func:`~torchfluidwarp.core.grid.inside_picture`, the
        bounds that :func:`~torchfluidwarp.control.keyframes.check_points` allows).
    """
    keep = torch.ones(len(points_a), dtype=torch.bool, device=points_a.device)
    for p, size in ((points_a, size_a), (points_b, size_b)):
        keep &= inside_picture(p, size)
        close = torch.cdist(p, p) < 1.0
        keep &= ~torch.tril(close, diagonal=-1).any(dim=1)  # close to an earlier point
    return keep


def _several(name: str, chosen: Chosen) -> str:
    """Which of the faces a picture ``name`` shows was used, in words."""
    which = "the largest" if chosen.index == 0 else f"face {chosen.index}"
    return f"{name} shows {chosen.count} faces ({listing(chosen.others)}): used {which}"


def _faces_note(chosen: tuple[Chosen, Chosen], names: tuple[str, str], face_index, asked: bool) -> Note:
    """Which faces were matched, and the images that show several when the largest was taken by default."""
    where = " and ".join(f"{name}'s ({c.face})" for name, c in zip(names, chosen))
    message = f"matched the face landmarks of {where}" + (", as asked" if asked else "")
    several = [_several(name, c) for name, c, i in zip(names, chosen, face_index) if i is None and c.count > 1]
    if not several:
        return Note(message)
    hint = Hint("choose another with {setting}", "face_index", spelling="face_index=(i, j)")
    return Note("; ".join([message, *several]), hint, notable=True)


def find_each_face(
    images: Sequence[Tensor], *, face_index: int | None = None, names: Sequence[str] | None = None
) -> tuple[list[Tensor], Note]:
    """The landmarks of one face in each of several pictures: the same
    :data:`~torchfluidwarp.correspond.faces.FACE_MESH_INDICES` points in the same order, for a morph through them
    or their average.

    Args:
        images: pictures ``(C, H, W)`` or ``(1, C, H, W)`` in ``[0, 1]``, any size.
        face_index: which face where a picture shows several, by size (0 = the largest, the default). A picture
            that shows one face uses it, whatever the index.
        names: what to call each picture in messages (file names, say); default ``images[i]``.

    Returns:
        ``(points, note)``: one ``(63, 2)`` set per picture, in its own pixels with its dtype and device, and a
        :class:`Note` saying so, notable (with how to choose another) when a picture showed several faces.

    Raises:
        ImportError: mediapipe is not installed (the message says ``pip install "torchfluidwarp[faces]"``).
        NoFaceFound: a picture shows no face (the message names it and its size).
        InputError: ``face_index`` beyond the faces of a picture that shows several (the message lists them).
    """
    labels = list(names) if names is not None else [f"images[{i}]" for i in range(len(images))]
    if face_index is not None:
        face_index = check_int("face_index", face_index, minimum=0)
    points, several = [], []
    for image, name in zip(images, labels):
        x = single_image(name, image)
        faces = find_faces(x)
        try:
            chosen = choose_face(faces, face_index if len(faces) > 1 else None, name, (x.shape[-2], x.shape[-1]))
        except NoFaceFound as exc:  # the caller's way past it: its own points for every picture
            hint = Hint("give every picture's points ({setting}) to mark other features", "points")
            raise NoFaceFound(exc.message, argument=exc.argument, hint=hint) from None
        points.append(chosen.face.mesh[list(FACE_MESH_INDICES)].to(device=x.device, dtype=x.dtype))
        if chosen.count > 1:
            several.append(_several(name, chosen))
    message = f"found the face landmarks ({len(FACE_MESH_INDICES)} points) of each of the {len(labels)} pictures"
    if not several:
        return points, Note(message)
    hint = Hint("choose another with {setting} (where a picture shows several)", "face_index")
    return points, Note("; ".join([message, *several]), hint, notable=True)


TRUSTED_MATCHES = 8
"""Feature pairs that :func:`find_points`' automatic mode trusts: with fewer it lets the pixels place the points
(``match="pixels"``). Unrelated pictures match a few features by chance, and a morph on them twists the picture:
on 12 pairs of pictures of different scenes (a person against a cat, a rocket against a camera man, portraits
taken apart, one pair of them of one man) :func:`~torchfluidwarp.correspond.features.match_features` kept 0-6
pairs; on 7 pairs of one scene (a stereo pair, crops, zooms, rotations, a photograph against itself at half
size) it kept 27-64 (``benchmarks/bench_correspond.py``)."""


def _size(image: Tensor) -> tuple[int, int]:
    """``(H, W)`` of an image ``(..., H, W)``."""
    return image.shape[-2], image.shape[-1]


PIXELS_SIDE = 1024
"""Pixels: the pictures :func:`_pixel_lattice` fits its flow to are shrunk to this longer side first. The flow
has 32 x 32 cells, so a 3-megapixel photograph's own pixels add only time: obama3 (1434 x 2333) against a cat
took 17.5 s at full size, most of it the gradient of the image loss (scratch, 2 CPU cores)."""


def _pixel_lattice(a: Tensor, b: Tensor, n: int) -> tuple[tuple[Tensor, Tensor], str, bool]:
    """``n x n`` lattice points of ``a`` ``(1, C, H, W)`` and where a flow fitted to the pixels carries them in
    ``b`` (:func:`~torchfluidwarp.correspond.refine.refine_points` with no anchors, on copies shrunk to
    :data:`PIXELS_SIDE`; the points in each picture's own pixels), what was done, in words, and whether that flow
    folds (the note is then notable)."""
    small_a, small_b = shrink_image(a, PIXELS_SIDE), shrink_image(b, PIXELS_SIDE)
    none = a.new_zeros(0, 2)
    with warnings.catch_warnings(record=True) as caught:  # the flow's own fold warning is said below, as ours
        warnings.simplefilter("always")
        refined = refine_points(small_a, small_b, none, none, extra=n)
    folds = bool((refined[2].min_det <= 0).any())
    for w in caught:
        if not (folds and issubclass(w.category, FoldWarning)):  # the flow only places points
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    message = f"placed {len(refined[0])} points of a lattice of {n} x {n} through a flow fitted to the pixels"
    if folds:  # pictures whose content does not correspond: the points there are guesses
        message += "; that flow folds in places, so points there may cross, and the morph lets those go"
    back = [
        rescale_points(p, scale_factor(_size(x), _size(y), device=p.device, dtype=p.dtype))
        for p, x, y in ((refined[0], small_a, a), (refined[1], small_b, b))
    ]
    return (back[0], back[1]), message, folds


def _features_or_pixels(
    a: Tensor, b: Tensor, auto: bool, why_not_faces: str, names: tuple[str, str], max_points: int, pixels: int
) -> tuple[tuple[Tensor, Tensor], Matcher, Note]:
    """:func:`find_points` past the faces: matched features, or (``auto``, where fewer than
    :data:`TRUSTED_MATCHES` match) the pixels' lattice; the points, the matcher and why, in words.
    ``why_not_faces``: the automatic mode's reason not to use faces ("" when features were asked for)."""
    found = match_features(a, b, max_points=max_points)
    count = len(found[0])
    between = f"{names[0]} and {names[1]}"
    if auto and count < TRUSTED_MATCHES:  # no more than unrelated pictures match by chance
        lattice, message, _ = _pixel_lattice(a, b, pixels)
        back = ValueHint(f"use {{setting}} to morph on those {count}", "match", value="features")
        said = f"{why_not_faces}; only {count} image features match between {between} (chance level): {message}"
        return lattice, "pixels", Note(said, back if count >= 3 else None, notable=True)
    if count < 3:
        small = [
            f"{n} is {x.shape[-1]} x {x.shape[-2]} px" for n, x in zip(names, (a, b)) if min(x.shape[-2:]) < MIN_SIDE
        ]
        raise InputError(
            f"found {count} matching features between {between} (need 3 or more)"
            + (f"; the feature detector needs {MIN_SIDE} px on each side, and {' and '.join(small)}" if small else ""),
            argument="match",
            hint=ValueHint(
                "give the points by hand, or let the pixels place them ({setting})",
                "match",
                value="pixels",
                otherwise="give the points by hand",
            ),
        )
    if count < TRUSTED_MATCHES:
        said = (
            f"matched image features ({count} pairs), as asked; unrelated pictures match as many by chance "
            f"(fewer than {TRUSTED_MATCHES}), and a morph on chance pairs twists the picture"
        )
        hint = ValueHint("{setting} places points that follow the pixels", "match", value="pixels")
        return found, "features", Note(said, hint, notable=True)
    if why_not_faces:
        said = f"{why_not_faces}; matched image features instead ({count} pairs)"
        return found, "features", Note(said, _skip_faces(), notable=True)
    return found, "features", Note(f"matched image features ({count} pairs), as asked")


def find_points(
    image_a: Tensor,
    image_b: Tensor,
    *,
    match: MatchMode = "auto",
    face_index: int | tuple[int | None, int | None] | None = None,
    names: tuple[str, str] = ("image_a", "image_b"),
    border: int | None = 3,
    max_points: int = 64,
    pixels: int = 8,
) -> FoundPoints:
    """Corresponding points of two images, with which matcher found them and why.

    The arguments, the points and the errors are those of :func:`auto_points`; this one also returns the
    matcher and a :class:`Note` that says, in words a caller can put in its own terms (:meth:`Note.explain`),
    why it was used: ``"no face found in a.jpg (817 x 1024 pixels); matched image features instead (41 pairs);
    use match='features' to skip the face search"`` (the command line: ``use --match features``).

    Returns:
        a :class:`FoundPoints`.

    Example:
        >>> from torchfluidwarp.data import load_sample
        >>> a = load_sample("cat")
        >>> found = find_points(a, a[..., 8:, 4:], names=("cat.png", "crop.png"))
        >>> found.matcher, found.reason.notable
        ('features', True)
        >>> print(found.reason.explain({"match": "--match"}))  # doctest: +ELLIPSIS
        no face found in cat.png (512 x 512 pixels); matched image features instead (... pairs); use --match ...
    """
    a, b = single_image("image_a", image_a), single_image("image_b", image_b)
    if match not in MATCH_MODES:
        raise InputError(f"match must be 'auto', 'faces', 'features' or 'pixels', got {match!r}", argument="match")
    each = not isinstance(face_index, (tuple, list))  # one index: the face of each picture that shows several
    pair = tuple(face_index) if isinstance(face_index, (tuple, list)) else (face_index, face_index)
    if len(pair) != 2:
        raise InputError(f"face_index must be an int or a pair (i, j), got {face_index!r}", argument="face_index")
    fa, fb = (None if i is None else check_int("face_index", i, minimum=0) for i in pair)
    face_index = (fa, fb)
    pixels = check_int("pixels", pixels)  # checked whatever the matcher: the automatic mode may fall back to it
    found: tuple[Tensor, Tensor] | None = None
    matcher: Matcher = "features"
    reason: Note | None = None
    why_not_faces = ""  # the automatic mode's reason to match features
    if match in ("auto", "faces"):
        try:
            load_mediapipe()
        except ImportError:
            if match == "faces":
                raise
            why_not_faces = f"no face detector ({INSTALL_HINT})"
        else:
            try:
                chosen_a, chosen_b = (
                    choose_face(faces, None if each and len(faces) == 1 else i, name, (x.shape[-2], x.shape[-1]))
                    for x, i, name in zip((a, b), face_index, names)
                    for faces in [find_faces(x)]
                )
                chosen = (chosen_a, chosen_b)
            except NoFaceFound as exc:
                if match == "faces":
                    raise NoFaceFound(
                        exc.message,
                        argument=exc.argument,
                        hint=ValueHint("{setting} matches image features instead", "match", value="features"),
                    ) from None
                why_not_faces = exc.message
            else:
                found = (chosen_a.face.mesh[list(FACE_MESH_INDICES)], chosen_b.face.mesh[list(FACE_MESH_INDICES)])
                matcher = "faces"
                reason = _faces_note(chosen, names, face_index, asked=match == "faces")
    elif match == "pixels":
        found, message, folds = _pixel_lattice(a, b, pixels)
        matcher = "pixels"
        reason = Note(message, notable=folds)
    if found is None:
        found, matcher, reason = _features_or_pixels(a, b, match == "auto", why_not_faces, names, max_points, pixels)
    if reason is None:  # every branch above says why (or raised)
        raise RuntimeError("find_points chose no matcher")
    points_a, points_b = (p.to(device=a.device, dtype=a.dtype) for p in found)
    size_a, size_b = _size(a), _size(b)
    return FoundPoints(*bordered_pairs(points_a, points_b, size_a, size_b, border), matcher, reason)


def auto_points(
    image_a: Tensor,
    image_b: Tensor,
    *,
    match: MatchMode = "auto",
    face_index: int | tuple[int | None, int | None] | None = None,
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
            installed and both images show a face (:func:`~torchfluidwarp.correspond.faces.find_faces`: whole
            portraits, any size, grey or colour), features otherwise, and the pixels (as ``"pixels"``) where
            fewer than :data:`TRUSTED_MATCHES` features match, as between unrelated pictures, with a
            :class:`MatchNotice` that says so; ``"pixels"``: a lattice of ``pixels x pixels`` points placed by a
            flow fitted to the images (:func:`~torchfluidwarp.correspond.refine.refine_points` with no anchors;
            slower: a coarse-to-fine image fit).
        face_index: which face in A and in B, ``(i, j)`` (0 = largest; ``None``: the largest, with a
            :class:`MatchNotice` that lists them when there are several); one ``int``: that face in each picture
            that shows several (a picture of one face keeps it), as :func:`find_each_face` takes it.
        names: the images' names in messages (their file names, say).
        border: points per image edge for :func:`border_points` (3: corners and edge midpoints), appended to
            both lists, paired as :func:`border_pairs` says (B's own border where the frames correspond, else
            where the matched points' pose sends A's); ``None`` for none.
        max_points: the most feature matches (not counting the border).
        pixels: the lattice's points per side for ``match="pixels"``.

    Returns:
        ``(points_a, points_b)``: ``(M, 2)`` each, pixels ``(x, y)``, pixel centres at integers, in each
        image's own pixels, with image A's dtype and device; ``points_a[i]`` corresponds to ``points_b[i]``.
        Pairs that a morph cannot take are left out (:func:`usable_pairs`: a face point outside its
        image, a point within a pixel of an earlier one).

    Warns:
        MatchNotice: the automatic mode matched features because an image shows no face or the ``faces``
            extra is missing, or took the largest of several faces; :func:`find_points` returns the same
            :class:`Note` instead of warning.

    Raises:
        ImportError: ``match="faces"`` without mediapipe (the message says how to install it).
        NoFaceFound: ``match="faces"`` and no face in an image (a ``ValueError``; the message names it and its
            size).
        ValueError: ``face_index`` beyond the faces found (the message lists them); a bad argument;
            ``match="features"`` (or ``"auto"`` with no faces) and fewer than 3 matches.

    Example:
        >>> from torchfluidwarp.data import load_sample
        >>> a = load_sample("cat")
        >>> pa, pb = auto_points(a, a[..., 8:, 4:], match="features")  # B: A cropped, so b = a - (4, 8)
        >>> bool((pa - pb)[:-8].sub(torch.tensor([4.0, 8.0])).norm(dim=-1).median() < 0.5)  # the last 8: border
        True
    """
    found = find_points(
        image_a,
        image_b,
        match=match,
        face_index=face_index,
        names=names,
        border=border,
        max_points=max_points,
        pixels=pixels,
    )
    if found.reason.notable:
        warn(MatchNotice(found.reason))
    return found.points_a, found.points_b
