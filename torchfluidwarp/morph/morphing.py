"""Morphing two images with a fitted fluid flow (the paper's Section on morphing).

A morph is a forward warping ``C_l`` of the source image ``f`` driven by fitted forces, an inverse warping of
the target image ``g``, and a cross-dissolve between them. A global pre-alignment ``M`` (similarity by
default) estimated from the points is interpolated over the morph and composed with the fluid warp, so the
fluid only has to produce the local, non-rigid part.

For a frame at time ``s`` (in fluid steps, ``0..T``) and an output pixel ``y``: ``z = M_s^-1 y`` is the
point in the fluid's frame; image A is read at ``g_s(z)`` (the fluid's backward map) and image B at
``M K_s(z)``, where ``K_s`` carries ``z`` forward from ``s`` to ``T`` through the same velocities
(``inverse="flow"``), or through a chain of small per-step fits (``inverse="paper"``).

The settings are typed (:mod:`~torchfluidwarp.morph.settings`): the method's, the timing's, the blending's and
the point matching's, each a frozen dataclass whose defaults are the morph's.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import (
    check_instance,
    check_int,
    check_memory,
    check_picture,
    check_size,
    check_tensor,
    compute_dtype,
    warn,
)
from torchfluidwarp.control.alignment import apply_alignment, interpolate_alignment
from torchfluidwarp.control.keyframes import KeyframeFit, check_points
from torchfluidwarp.core.grid import FluidGrid, inside_picture, rescale_points, scale_factor
from torchfluidwarp.correspond import FoundPoints, MatchMode, MatchNotice, find_points, halfway_alignment
from torchfluidwarp.correspond.auto import MATCH_MODES
from torchfluidwarp.errors import Hint, InputError
from torchfluidwarp.io import resize_image
from torchfluidwarp.io.images import premultiplied, straight
from torchfluidwarp.morph.fit import MIN_AREA, PAD, fit_natural, fit_paper, fluid_grid, focus, paper_flows
from torchfluidwarp.morph.marks import (
    LET_GO,
    check_marks,
    check_not_normalised,
    drop_repeats,
    pose,
    warn_coarse_grid,
    warn_let_go,
    warn_let_go_alone,
    warn_missed,
)
from torchfluidwarp.morph.regions import hull_mask
from torchfluidwarp.morph.render import Scene
from torchfluidwarp.morph.result import MorphResult
from torchfluidwarp.morph.settings import (
    FEATHER,
    Blending,
    Matching,
    MorphSettings,
    NaturalSettings,
    PaperSettings,
    Timing,
)
from torchfluidwarp.morph.timing import schedule
from torchfluidwarp.warp.forces import ControlGrid
from torchfluidwarp.warp.landmarks import LandmarkForces

__all__ = ["morph", "match_channels", "placement", "resize_pair", "region_of_interest", "PAD", "MIN_AREA", "FEATHER"]


RANGE_SLACK = 1 / 255
"""How far beyond ``[0, 1]`` a picture's values may reach (rounding of a resize or a colour conversion) before
:func:`morph` says that they are not a picture's."""


def _as_image(name: str, image: Tensor) -> Tensor:
    """One picture ``(1, C, H, W)``, detached; values far outside ``[0, 1]`` are said (the frames are written
    clipped to it, so a 0..255 float picture would come out nearly white)."""
    if isinstance(image, Tensor) and image.ndim == 2 and image.shape[-1] == 2:  # (M, 2): points in a picture's place
        raise InputError(
            f"{name} has shape {tuple(image.shape)}, a set of points, not a picture; the order is "
            "morph(image_a, image_b, points_a, points_b)",
            argument=name,
        )
    img = check_picture(name, image)
    img = img.unsqueeze(0) if img.ndim == 3 else img
    if img.shape[0] != 1 or img.shape[1] < 1 or min(img.shape[2:]) < 2:
        raise InputError(
            f"{name} must be a single image (C, H, W) or (1, C, H, W) of at least 2 x 2 pixels, got "
            f"{tuple(image.shape)}",
            argument=name,
        )
    low, high = (float(v) for v in torch.aminmax(img))
    if low < -RANGE_SLACK or high > 1 + RANGE_SLACK:
        advice = "bring them to [0, 1]"
        if low >= 0 and high > 2:  # whole-number levels: 8 or 16 bits
            advice = "divide by 65535" if high > 256 else "divide by 255"
        warn(
            f"{name}'s values span [{low:.4g}, {high:.4g}], not a picture's [0, 1]: the morph blends them as they "
            f"are, and its frames are saved clipped to [0, 1] ({advice})"
        )
    return img.detach()


def _as_points(name: str, points: object, image: Tensor) -> Tensor:
    """One set of points ``(M, 2)`` inside ``image``, detached, on the image's device. A list of ``[x, y]`` pairs,
    a NumPy array or an integer tensor is converted to the image's computing dtype (float32 for a half-precision
    picture, so that a point keeps its fraction of a pixel); a float tensor keeps its own."""
    if not (isinstance(points, Tensor) and points.is_floating_point()):
        try:
            data = np.asarray(points.detach().cpu() if isinstance(points, Tensor) else points)
            if data.dtype.kind in "iuf":  # numbers, not booleans or strings: those check_points refuses by name
                points = torch.as_tensor(data.astype(np.float64), device=image.device).to(compute_dtype(image.dtype))
        except (TypeError, ValueError):
            pass  # a ragged list, tensors on a GPU: check_points refuses it, naming it
    H, W = image.shape[-2], image.shape[-1]
    p = check_points(name, points, (H, W))
    if p.shape[0] != 1:
        raise InputError(f"{name} must be one set of points (M, 2) for a morph, got shape {tuple(p.shape)}")
    check_not_normalised(name, p[0], (H, W))
    return p[0].detach().to(image.device)


def _region_masks(blending: Blending, pa: Tensor, pb: Tensor, a: Tensor, b: Tensor) -> tuple[Tensor, Tensor] | None:
    """The region's soft masks ``(1, 1, H_a, W_a)`` over A and ``(1, 1, H_b, W_b)`` over B, each in its own
    picture's pixels (the frames read them through each picture's map), or ``None``."""
    region = blending.region
    if region is None:
        return None
    size_a, size_b = (a.shape[-2], a.shape[-1]), (b.shape[-2], b.shape[-1])
    if isinstance(region, str):  # "points", checked by Blending
        margin = blending.region_margin
        masks = hull_mask(pa, size_a, margin), hull_mask(pb, size_b, margin)
    else:
        ma = check_tensor("Blending.region[0] (mask_a)", region[0], shape=[*size_a])
        mb = check_tensor("Blending.region[1] (mask_b)", region[1], shape=[*size_b])
        masks = ma, mb
    return tuple(m.to(a)[None, None].clamp(0, 1) for m in masks)  # type: ignore[return-value]


def match_channels(image_a: Tensor, image_b: Tensor) -> tuple[Tensor, Tensor]:
    """Bring two images ``(1, C, H, W)`` to the richer colour model of the two, without dropping anything.

    Colour if either has colour (grey is repeated to RGB), alpha if either has alpha (an opaque alpha is added
    to the other); grey with alpha (``C = 2``) becomes RGBA, as :func:`~torchfluidwarp.io.read_image` reads it.
    ``C`` = 1 grey, 2 grey + alpha, 3 RGB, 4 RGBA; images with the same ``C`` are returned as they are.

    Raises:
        ValueError: different channel counts of which one is not 1 to 4.
    """
    ca, cb = image_a.shape[1], image_b.shape[1]
    if ca == cb:
        return image_a, image_b
    if not (1 <= ca <= 4 and 1 <= cb <= 4):
        raise InputError(
            f"image_a has {ca} channels but image_b has {cb}: different channel counts are matched only for "
            "grey (1), grey + alpha (2), RGB (3) and RGBA (4)"
        )
    colour = max(ca, cb) >= 3
    alpha = ca in (2, 4) or cb in (2, 4)
    channels = 4 if alpha else 3 if colour else 1

    def convert(image: Tensor) -> Tensor:
        c = image.shape[1]
        if c == channels:
            return image
        grey = c in (1, 2)
        rgb = image[:, :1].expand(-1, 3, -1, -1) if grey else image[:, :3]
        if channels == 3:
            return rgb.contiguous()
        own = c in (2, 4)
        opacity = image[:, c - 1 :] if own else torch.ones_like(image[:, :1])
        return torch.cat([rgb, opacity], 1)

    return convert(image_a), convert(image_b)


def placement(size: tuple[int, int], canvas: tuple[int, int], points: Tensor | None = None) -> tuple[Tensor, float]:
    """Where a picture of ``size`` ``(H, W)`` lies on the output ``canvas`` ``(H_c, W_c)``: the ``(3, 3)`` float64
    transform from its pixels to the canvas's, and its scale.

    One scale factor for both axes (nothing is stretched), the smallest that covers the canvas; what overflows the
    canvas is cropped. The crop is centred on the median of the picture's ``points`` ``(M, 2)`` (its pixels; the
    median, so that a few border points do not outweigh a face's landmarks), as far as the picture reaches: the
    marked content (a face at the edge of a group photograph) stays on the canvas. Without points, on the
    picture. Pixel centres at integers, so a picture of the canvas's size is placed by the identity:
    ``y = s (x + 0.5) + o - 0.5``, with the offset ``o`` between ``W_c - s W`` and ``0``.

    A canvas of the picture's aspect ratio up to rounding (one side the other's scaled size within half a pixel:
    the picture's size shrunk and rounded, as the command line's ``--max-size`` makes it) is filled exactly
    instead: each axis by its own factor, ``W_c / W`` and ``H_c / H``, which differ by at most half a pixel over
    the picture, so that no sliver of its border, and no point on it, is cut off (the cover would cut up to half
    a pixel times the aspect ratio). The scale returned is the larger.
    """
    (H, W), (Hc, Wc) = size, canvas
    s = max(Hc / H, Wc / W)
    out = torch.eye(3, dtype=torch.float64)
    if min(abs(Wc - W * Hc / H), abs(Hc - H * Wc / W)) <= 0.5:  # the same shape up to rounding: filled exactly
        out[0, 0], out[1, 1] = Wc / W, Hc / H
        out[0, 2], out[1, 2] = 0.5 * Wc / W - 0.5, 0.5 * Hc / H - 0.5
        return out, s
    out[0, 0] = out[1, 1] = s
    for axis, (extent, side) in enumerate(((W, Wc), (H, Hc))):
        low = side - s * extent  # <= 0: the offset that puts the picture's far edge on the canvas's
        if points is None or points.shape[0] == 0 or low > -1e-9:
            offset = 0.5 * low
        else:
            p = points[:, axis].double()
            middle = s * (float(p.median()) + 0.5)  # the points' median on the scaled picture
            offset = min(max(0.5 * side - middle, low), 0.0)
        out[axis, 2] = 0.5 * s + offset - 0.5
    return out, s


def _marks_on_canvas(points: Tensor, canvas: tuple[int, int]) -> Tensor:
    """``(M,)`` bool: which of A's marks ``points`` ``(M, 2)`` (canvas pixels) lie on the output ``canvas``
    ``(H, W)`` that ``Blending.size`` crops A to. The others are left out with a warning that counts them; fewer
    than 3 left is the caller's error."""
    H, W = canvas
    keep = inside_picture(points, canvas)
    dropped = (~keep).nonzero().flatten().tolist()
    if not dropped:
        return keep
    what = f"the output size {W} x {H} (width x height; Blending.size, --size on the command line)"
    if int(keep.sum()) < 3:
        raise InputError(
            f"{what} crops image_a so that only {int(keep.sum())} of its {len(keep)} points stay on it (3 are "
            "needed): choose a size nearer image_a's aspect ratio, or mark what the crop shows",
            argument="blending",
        )
    listed = ", ".join(map(str, dropped[:5])) + (" ..." if len(dropped) > 5 else "")
    warn(
        f"{what} crops image_a: {len(dropped)} of its {len(keep)} points lie beyond it and are left out of the "
        f"morph (indices {listed})",
        RuntimeWarning,
    )
    return keep


def _at_scale(image: Tensor, scale: float) -> Tensor:
    """``image`` as it is read on the canvas: shrunk (antialiased, one factor for both axes up to the rounding of
    its size) when the canvas shows it smaller, so that the frames' bilinear reads do not alias; the renderer
    reads it in the original picture's pixels (:func:`~torchfluidwarp.morph.render.read`). A picture with alpha
    is shrunk premultiplied, so that no colour hidden under its transparent pixels bleeds into its edges."""
    if scale >= 1:
        return image
    H, W = image.shape[-2:]
    return straight(resize_image(premultiplied(image), (max(2, round(H * scale)), max(2, round(W * scale)))))


def _memory(size: tuple[int, int], channels: int, frames: int, steps: int, grid: object, itemsize: int) -> float:
    """Bytes a morph sets out to hold: ``frames`` rendered at once (one, streamed) and the fit's fluid states."""
    H, W = size
    per_frame = H * W * (3 * channels + 2 * 2 + 2 * 2 * 2)  # frames, A and B warped; maps; maps on the fluid box
    g = FluidGrid.of(grid)  # type: ignore[arg-type]
    fluid = (steps + 1) * g.height * g.width * 2 * 8 * 8  # float64 velocities, forces and their adjoints
    return float(frames * per_frame * itemsize + fluid)


def _check_warm_start(warm_start: KeyframeFit, settings: MorphSettings) -> None:
    """Refuse a ``warm_start`` that cannot start a fit with ``settings``: a fit of the other method, or one of
    another number of steps (or, for the paper's, of control points: its forces would be fitted as they are)."""
    natural = isinstance(warm_start.forces, LandmarkForces)
    if natural != isinstance(settings, NaturalSettings):
        given, wanted = ("the natural", "the paper's") if natural else ("the paper's", "the natural")
        raise InputError(
            f"warm_start is a fit of {given} method and this morph uses {wanted}: pass a result.fit of a morph "
            f"with the same settings' class, or none",
            argument="warm_start",
        )
    if isinstance(settings, NaturalSettings):
        forces = warm_start.forces
        assert isinstance(forces, LandmarkForces)  # checked above: a natural fit's
        steps = int(forces.weight.shape[1])  # (B, T, N, 2)
        if steps != settings.steps:
            raise InputError(
                f"warm_start is a fit of {steps} steps and this morph's has {settings.steps}: pass a result.fit "
                f"of a morph with the same NaturalSettings.steps",
                argument="warm_start",
            )
        return
    if isinstance(settings, PaperSettings):
        control = settings.control  # a pair once checked by PaperSettings
        ky, kx = (control, control) if isinstance(control, int) else control
        expected = (settings.steps, 2, ky, kx)  # a ControlGrid's weight is (B, T, 2, K_y, K_x)
        weight = getattr(warm_start.forces, "weight", None)
        given_shape = tuple(weight.shape[1:]) if isinstance(weight, Tensor) else ()
        if not isinstance(warm_start.forces, ControlGrid) or given_shape != expected:
            raise InputError(
                f"warm_start's control grid is {tuple(given_shape)} (steps, 2, K_y, K_x) and this morph's is "
                f"{tuple(expected)}: pass a result.fit of a morph with the same PaperSettings.steps and control",
                argument="warm_start",
            )


def resize_pair(image_a: Tensor, image_b: Tensor, points_b: Tensor) -> tuple[Tensor, Tensor]:
    """Bring ``image_b`` ``(1, C, H_b, W_b)`` to image A's size, scaling ``points_b`` ``(M, 2)`` to match.

    This stretches B when the aspect ratios differ; :func:`morph` does not use it (it places each picture on the
    canvas with one scale factor, :func:`placement`, and reads B at its own resolution).

    Pixel centres stay at integers: ``x' = (x + 0.5) W_a / W_b - 0.5``. Channel counts are matched too
    (grey to RGB, alpha dropped) so the two can be blended.
    """
    Ha, Wa = image_a.shape[-2:]
    Hb, Wb = image_b.shape[-2:]
    if (Ha, Wa) != (Hb, Wb):
        image_b = F.interpolate(image_b, size=(Ha, Wa), mode="bilinear", align_corners=False, antialias=True)
        scale = scale_factor((Hb, Wb), (Ha, Wa), device=points_b.device, dtype=points_b.dtype)
        points_b = rescale_points(points_b, scale)
    ca, cb = image_a.shape[1], image_b.shape[1]
    if cb != ca:
        if cb == 1:
            image_b = image_b.expand(-1, ca, -1, -1) if ca in (3, 4) else image_b
        if ca == 1:
            image_b = image_b[:, :3].mean(1, keepdim=True)
        elif image_b.shape[1] != ca:
            extra = torch.ones_like(image_b[:, :1]).expand(-1, ca - 3, -1, -1)
            image_b = torch.cat([image_b[:, :3], extra], 1) if ca == 4 else image_b[:, :ca]
    return image_b, points_b


def region_of_interest(points: Tensor, margin: float) -> tuple[int, int, int, int]:
    """Pixel box ``(x0, y0, x1, y1)`` (x1, y1 exclusive) around ``points`` ``(M, 2)``, grown by ``margin`` times
    its size on each side. It may reach beyond the image: points near an edge then stay clear of the fluid's
    walls, where a fluid cannot move them."""
    lo, hi = points.min(0).values, points.max(0).values
    ext = (hi - lo).clamp(min=8.0)
    x0, y0 = (lo - margin * ext).floor().tolist()
    x1, y1 = (hi + margin * ext).ceil().tolist()
    return int(x0), int(y0), int(x1) + 1, int(y1) + 1


def morph(
    image_a: Tensor,
    image_b: Tensor,
    points_a: Tensor | None = None,
    points_b: Tensor | None = None,
    *,
    # the settings' defaults are frozen dataclasses: immutable, so one instance can serve every call
    settings: MorphSettings = NaturalSettings(),
    frames: int = 30,
    timing: Timing = Timing(),
    blending: Blending = Blending(),
    match: Matching | MatchMode = Matching(),
    warm_start: KeyframeFit | None = None,
    placed: FoundPoints | None = None,
    progress: bool = True,
    max_memory: float | None = None,
) -> MorphResult:
    """Morph ``image_a`` into ``image_b`` so that ``points_a`` travel to ``points_b``.

    The method is the class of ``settings``:

    * :class:`~torchfluidwarp.morph.settings.NaturalSettings` (default): every marked point travels on a straight
      line at constant speed, and the rest of the picture moves as a thin-plate spline between the points says,
      in a compressible, inviscid fluid over the whole picture (its walls lie :data:`PAD` or more beyond the edges),
      or over the part of A the last frame shows when that is under half of it
      (:func:`~torchfluidwarp.morph.fit.focus`).
      Regions change size as the marks say; the maps never fold where the spline does not, and no box edge shows.
    * :class:`~torchfluidwarp.morph.settings.PaperSettings`: the paper's keyframe fit of a control grid of forces,
      so that the points reach their targets at the last step, in an incompressible fluid (every region keeps its
      area) over a box around the points.

    Args:
        image_a: ``(C, H, W)`` or ``(1, C, H, W)`` source image in ``[0, 1]`` (values far outside it are said:
            the frames are saved clipped to it), at least 2 x 2 pixels; it sets the output size unless
            ``Blending(size=...)`` does.
        image_b: ``(C_b, H_b, W_b)`` or ``(1, C_b, H_b, W_b)`` target image, of any size and aspect ratio. Neither
            picture is stretched: each is placed on the output canvas by one scale factor for both axes, the
            smallest that covers it, the crop centred on its points (:func:`placement`: a face near the edge of a
            group photograph stays on the canvas), and read at its own resolution (a copy shrunk, antialiased, when
            the canvas shows it smaller). Grey, grey + alpha, RGB and RGBA mix: the frames take
            the richer model (:func:`match_channels`).
        points_a, points_b: ``(M, 2)`` corresponding points ``(x, y)`` in each image's pixels (pixel centres at
            integers): tensors, or lists of ``[x, y]`` pairs or NumPy arrays (converted to the images' computing
            dtype);
            the natural method needs ``M >= 3`` points whose midpoints (halfway between each pair) are not all
            on one line. ``None`` (both): found
            from the pictures by :func:`~torchfluidwarp.correspond.auto.auto_points` as ``match`` says. Points
            that features or a flow placed (not face landmarks) only start the natural method's pixel alignment
            (``NaturalSettings.dense``, then not anchored to them): A's points stay, and B's side follows the
            pixels' whole travel, which :attr:`MorphResult.error` is then measured against.
        settings: the method and its fluid, fit, pre-alignment and inverse
            (:class:`~torchfluidwarp.morph.settings.NaturalSettings` or
            :class:`~torchfluidwarp.morph.settings.PaperSettings`).
        frames: number of output frames ``N >= 2``.
        timing: how the shape and the colour progress over the morph
            (:class:`~torchfluidwarp.morph.settings.Timing`).
        blending: how each frame puts the two warped images together, and an optional region
            (:class:`~torchfluidwarp.morph.settings.Blending`).
        match: how the points are found when none are given (:class:`~torchfluidwarp.morph.settings.Matching`),
            or its mode alone: ``match="pixels"`` is ``match=Matching("pixels")``.
        warm_start: a previous morph's ``result.fit`` of the same method and ``steps`` (the studio's live
            previews): the paper's fit starts from its forces (the same ``control`` too); the natural fit starts
            each point's corrections from those of the previous fit's point at about the same place (a mark dragged
            by a few pixels keeps them; :func:`~torchfluidwarp.morph.fit.warm_corrections`). Any other fit is
            refused.
        placed: points that :func:`~torchfluidwarp.correspond.auto.find_points` already found for this pair (the
            command line finds them first, to say which matcher it used), taken as ``match`` would take its own:
            face landmarks held like given points, others only starting the pixels' alignment. Give it instead
            of ``points_a`` and ``points_b``.
        progress: tqdm bars of the fit.
        max_memory: bytes the morph may set out to hold (its fit, and one frame at a time); default
            :data:`torchfluidwarp._checks.MAX_BYTES` (8 GiB). A larger request is refused before any work.

    Returns:
        a :class:`~torchfluidwarp.morph.result.MorphResult`: the fit, rendered on demand, on the canvas
        (A's size by default): frame 0 is A and the last frame B, each placed on it. ``result.frame(t)``
        renders any ``t`` in ``[0, 1]``; ``result.iter_frames()`` streams the ``frames`` in bounded memory;
        ``result.frames`` (and ``maps`` ...) renders all of them at once. ``result.error`` is each point's
        distance to B's in the last frame's pixels; ``result.canvas_from_b`` places B's pixels on the canvas;
        ``result.fit`` is in the fluid box's frame.

    Raises:
        ImportError: ``Matching("faces")`` without the faces extra (``pip install "torchfluidwarp[faces]"``).
        ValueError: different point counts, points outside their image (each in its own picture's pixels), repeated
            points, non-finite values, channel counts that cannot be matched,
            ``frames < 2``, fewer than 3 points or points on one line for the natural method.
        TypeError: settings objects of the wrong class, e.g. ``settings="paper"``.

    Warns:
        RuntimeWarning: marks that cross (swap sides or tear apart between A and B), naming them; when the
            frames are rendered, maps that fold, with the number of folded pixels.

    Example:
        >>> a, b = torch.rand(3, 32, 32), torch.rand(3, 32, 32)
        >>> pa = torch.tensor([[8.0, 8.0], [24.0, 8.0], [16.0, 24.0]])
        >>> result = morph(a, b, pa, pa + 1, settings=PaperSettings(grid=16, steps=4), frames=5, progress=False)
        >>> result.frames.shape, result.error.shape
        (torch.Size([5, 3, 32, 32]), torch.Size([3]))
    """
    t0 = time.perf_counter()
    check_instance("settings", settings, (NaturalSettings, PaperSettings))
    check_instance("timing", timing, Timing)
    check_instance("blending", blending, Blending)
    if isinstance(match, str):  # the mode alone, as the matchers' notes and hints spell it
        if match not in MATCH_MODES:
            raise InputError(f"match must be a Matching or one of {MATCH_MODES}, got {match!r}", argument="match")
        match = Matching(match)
    check_instance("match", match, Matching)
    check_instance("warm_start", warm_start, KeyframeFit, optional=True)
    if warm_start is not None:
        _check_warm_start(warm_start, settings)
    a = _as_image("image_a", image_a)
    b = _as_image("image_b", image_b)
    if b.device != a.device:
        raise InputError(f"image_a is on {a.device} but image_b is on {b.device}; put both on one device")
    out_dtype = torch.promote_types(a.dtype, b.dtype)
    a, b = a.to(compute_dtype(out_dtype)), b.to(compute_dtype(out_dtype))
    if (points_a is None) != (points_b is None):
        raise InputError(
            "give both points_a and points_b, or neither (then match=Matching(...) finds them: "
            "'auto', 'faces', 'features' or 'pixels')"
        )
    if placed is not None:
        check_instance("placed", placed, FoundPoints)
        if points_a is not None or points_b is not None:
            raise InputError(
                "give points_a and points_b, or placed (points a matcher found), not both", argument="placed"
            )
    elif points_a is None:
        placed = find_points(a, b, match=match.mode, face_index=match.face_index)
        if placed.reason.notable:  # its hint in this call's terms: the face index is Matching's
            warn(MatchNotice(placed.reason, {"match": "match", "face_index": "match=Matching(face_index=(i, j))"}))
    found = False  # marks placed by features or a flow are the pixels' guess: the pixels' alignment may move them
    if placed is not None:
        points_a, points_b, found = placed.points_a, placed.points_b, placed.matcher != "faces"
    n = check_int("frames", frames, minimum=2)
    pa = _as_points("points_a", points_a, a)
    pb = _as_points("points_b", points_b, b)
    if pa.shape[0] != pb.shape[0]:
        raise InputError(f"points_a has {pa.shape[0]} points but points_b has {pb.shape[0]}")
    if placed is not None:
        pa, pb = drop_repeats(pa, pb, placed.matcher)
    if isinstance(settings, NaturalSettings) and pa.shape[0] < 3:
        raise InputError(
            f"the natural method (NaturalSettings) needs at least 3 points, got {pa.shape[0]}; PaperSettings "
            "takes fewer"
        )
    steps = settings.steps
    shape, colour = schedule("motion", timing.motion), schedule("blend", timing.blend)
    a, b = match_channels(a, b)
    size_a, size_b = (a.shape[-2], a.shape[-1]), (b.shape[-2], b.shape[-1])
    size = size_a if blending.size is None else check_size("blending.size", blending.size)  # the canvas (H, W)
    H, W = size
    grid = fluid_grid(settings, size).shape  # over the picture; the fit's box adds its margin
    estimate = _memory(size, a.shape[1], 1, steps, grid, a.element_size())  # streamed
    check_memory(f"morph(frames={n}, steps={steps}, grid={grid})", estimate, max_memory, "morph(max_memory=...)")
    check_marks(pa, pb, None if placed is None else placed.matcher)
    # each picture keeps its aspect ratio: placed on the canvas by one scale factor; the morph works in the
    # canvas's pixels and reads each picture through its placement, at (up to antialiasing) its own resolution
    (place_a, scale_a), (place_b, scale_b) = placement(size_a, size, pa), placement(size_b, size, pb)
    place_a, place_b = place_a.to(a.device), place_b.to(a.device)
    pa_c, pb_c = apply_alignment(place_a, pa.double()), apply_alignment(place_b, pb.double())  # canvas pixels
    keep = _marks_on_canvas(pa_c, size)  # all of them on A's own canvas; a crop to another size may leave some out
    pa, pb, pa_c, pb_c = pa[keep], pb[keep], pa_c[keep], pb_c[keep]
    numbers = keep.nonzero()[:, 0]  # the caller's index of each mark kept, for the warnings
    M = pose(pa_c, pb_c, settings.align, numbers=numbers)  # canvas to canvas: A's place to B's
    center = pa_c.mean(0)
    # the fluid moves A's points to where B's points are in A's (unaligned) frame
    target = apply_alignment(torch.linalg.inv(M), pb_c)
    if isinstance(settings, NaturalSettings):
        region = focus(size, M, torch.cat([pa_c, target]))  # a small part of A in the last frame: the fluid's box
        dense = None
        if settings.dense is not None:
            x0, y0, x1, y1 = region or (0, 0, W, H)  # the pixels align what the fluid covers
            corner = torch.eye(3, dtype=torch.float64, device=a.device)
            corner[0, 2], corner[1, 2] = x0, y0
            to_a, to_b = torch.linalg.solve(place_a, corner), torch.linalg.solve(place_b, M.to(place_b) @ corner)
            options = replace(settings.dense, anchor=0.0) if found else settings.dense
            at = corner[:2, 2]

            def dense(mids: Tensor, disp: Tensor) -> Callable[[Tensor], Tensor]:
                residual = halfway_alignment(a, b, to_a, to_b, (y1 - y0, x1 - x0), mids - at, disp, options)
                return lambda p: residual(p - at)

        fit, box, ends = fit_natural(
            pa_c, target, size, settings, warm_start, progress, dense, found, max_memory, region
        )
        planned = apply_alignment(M, ends)  # where the paths take A's marks: B's, or where a mark was let go
        let_go = (planned - pb_c).norm(dim=-1) > LET_GO  # released so as not to fold
        if found:  # the pixels placed these marks, and they re-placed B's side: the morph meets them there
            pb_c, let_go = planned, torch.zeros_like(let_go)
    else:
        let_go = None  # the paper's fit lets no mark go
        if settings.margin is None:
            box = (0, 0, W, H)
            target = torch.stack([target[:, 0].clamp(-0.5, W - 0.5), target[:, 1].clamp(-0.5, H - 0.5)], -1)
        else:
            box = region_of_interest(torch.cat([pa_c, target]), settings.margin)
        offset = torch.tensor([box[0], box[1]], dtype=torch.float64, device=a.device)
        roi = (box[3] - box[1], box[2] - box[0])
        start = (
            None if warm_start is None else copy.deepcopy(warm_start.forces)
        )  # the previous result's stays as it was
        fit = fit_paper(pa_c - offset, target - offset, roi, settings, start, progress, max_memory)
    roi = (box[3] - box[1], box[2] - box[0])  # (H, W) of the fluid's box, pixels
    offset = torch.tensor([box[0], box[1]], dtype=torch.float64, device=a.device)
    t_fit = time.perf_counter()

    with torch.no_grad():  # the fit is done: rendering needs no graph
        velocities = fit.warp.rollout(fit.forces, roi).velocities.to(a.dtype)
        flows = None if settings.inverse == "flow" else paper_flows(fit, roi, settings)
    scene = Scene(
        _at_scale(a, scale_a), _at_scale(b, scale_b), velocities, fit.warp.dt, steps, M, center, box, roi,
        settings.inverse, shape, colour, blending.feather, flows,
        masks=_region_masks(blending, pa, pb, a, b),
        background=blending.background,
        canvas=size, size_a=size_a, size_b=size_b, place_a=place_a, place_b=place_b,
    )  # fmt: skip
    t_inv = time.perf_counter()

    # A's points in the frames' pixels: the fit's paths (box pixels) moved to the canvas, then pre-aligned
    trajectories = torch.stack(
        [
            apply_alignment(interpolate_alignment(M, t / steps, center), fit.trajectories[0, t] + offset)
            for t in range(steps + 1)
        ]
    )  # (T + 1, M, 2)
    seconds = {"fit": t_fit - t0, "inverse": t_inv - t_fit, "total": t_inv - t0}
    smoother = "straightness" if isinstance(settings, NaturalSettings) else "smoothness"
    advice = Hint("raising {setting} smooths the flow", smoother, spelling=f"{type(settings).__name__}.{smoother}")
    result = MorphResult(scene, fit, M, trajectories, pb_c, n, out_dtype, seconds, max_memory, let_go, advice)
    if placed is not None:
        warn_let_go(pa, pb, result.let_go, placed.matcher)
    else:
        warn_let_go_alone(pa, pb, result.let_go, result.error, numbers, MIN_AREA)
    if isinstance(settings, NaturalSettings):
        warn_coarse_grid(pa_c, result.error, roi, fit.warp.grid, let_go)  # let go on purpose: not the grid's doing
    else:
        warn_missed(result.error, let_go)
    return result
