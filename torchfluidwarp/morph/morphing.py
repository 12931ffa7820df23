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

import time

import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import check_instance, check_int, check_memory, check_tensor, compute_dtype
from torchfluidwarp.control.alignment import apply_alignment, interpolate_alignment
from torchfluidwarp.control.keyframes import KeyframeFit, check_points
from torchfluidwarp.core.grid import FluidGrid, rescale_points, scale_factor
from torchfluidwarp.correspond import auto_points
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import resize_image
from torchfluidwarp.morph.fit import MIN_AREA, PAD, check_marks, fit_natural, fit_paper, paper_flows, pose
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

__all__ = ["morph", "resize_pair", "region_of_interest", "PAD", "MIN_AREA", "FEATHER"]


def _as_image(name: str, image: Tensor) -> Tensor:
    img = check_tensor(name, image, ndim=(3, 4))
    img = img.unsqueeze(0) if img.ndim == 3 else img
    if img.shape[0] != 1 or min(img.shape[1:]) < 1:
        raise InputError(
            f"{name} must be a single image (C, H, W) or (1, C, H, W) with C, H, W >= 1, got {tuple(image.shape)}"
        )
    return img.detach()


def _as_points(name: str, points: object, image: Tensor) -> Tensor:
    """One set of points ``(M, 2)`` inside ``image``, detached, on the image's device."""
    p = check_points(name, points, (image.shape[-2], image.shape[-1]))
    if p.shape[0] != 1:
        raise InputError(f"{name} must be one set of points (M, 2) for a morph, got shape {tuple(p.shape)}")
    return p[0].detach().to(image.device)


def _region_masks(
    blending: Blending, pa: Tensor, pb: Tensor, a: Tensor, size_b: tuple[int, int]
) -> tuple[Tensor, Tensor] | None:
    """The region's soft masks ``(1, 1, H, W)`` over A and over B (resized to A's size), or ``None``."""
    region = blending.region
    if region is None:
        return None
    size = (a.shape[-2], a.shape[-1])
    if isinstance(region, str):  # "points", checked by Blending
        margin = blending.region_margin
        masks = hull_mask(pa, size, margin), hull_mask(pb, size, margin)  # pb is already in A's size
    else:
        ma = check_tensor("Blending.region[0] (mask_a)", region[0], shape=[*size])
        mb = check_tensor("Blending.region[1] (mask_b)", region[1], shape=[*size_b])
        masks = ma, resize_image(mb[None, None].to(a.dtype), size)[0, 0]
    return tuple(m.to(a)[None, None].clamp(0, 1) for m in masks)  # type: ignore[return-value]


def _memory(size: tuple[int, int], channels: int, frames: int, steps: int, grid: object, itemsize: int) -> float:
    """Bytes a morph sets out to hold: ``frames`` rendered at once (one, streamed) and the fit's fluid states."""
    H, W = size
    per_frame = H * W * (3 * channels + 2 * 2 + 2 * 2 * 2)  # frames, A and B warped; maps; maps on the fluid box
    g = FluidGrid.of(grid)  # type: ignore[arg-type]
    fluid = (steps + 1) * g.height * g.width * 2 * 8 * 8  # float64 velocities, forces and their adjoints
    return float(frames * per_frame * itemsize + fluid)


def resize_pair(image_a: Tensor, image_b: Tensor, points_b: Tensor) -> tuple[Tensor, Tensor]:
    """Bring ``image_b`` ``(1, C, H_b, W_b)`` to image A's size, scaling ``points_b`` ``(M, 2)`` to match.

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
    match: Matching = Matching(),
    warm_start: KeyframeFit | None = None,
    progress: bool = True,
    max_memory: float | None = None,
) -> MorphResult:
    """Morph ``image_a`` into ``image_b`` so that ``points_a`` travel to ``points_b``.

    The method is the class of ``settings``:

    * :class:`~torchfluidwarp.morph.settings.NaturalSettings` (default): every marked point travels on a straight
      line at constant speed, and the rest of the picture moves as a thin-plate spline between the points says,
      in a compressible, inviscid fluid over the whole picture (its walls lie :data:`PAD` beyond the edges).
      Regions change size as the marks say; the maps never fold where the spline does not, and no box edge shows.
    * :class:`~torchfluidwarp.morph.settings.PaperSettings`: the paper's keyframe fit of a control grid of forces,
      so that the points reach their targets at the last step, in an incompressible fluid (every region keeps its
      area) over a box around the points.

    Args:
        image_a: ``(C, H, W)`` or ``(1, C, H, W)`` source image in ``[0, 1]``; it sets the output size.
        image_b: target image; resized to A's size if needed (its points are scaled to match).
        points_a, points_b: ``(M, 2)`` corresponding points ``(x, y)`` in each image's pixels (pixel centres at
            integers); the natural method needs ``M >= 3`` points, not all on one line. ``None`` (both): found
            from the pictures by :func:`~torchfluidwarp.correspond.auto.auto_points` as ``match`` says.
        settings: the method and its fluid, fit, pre-alignment and inverse
            (:class:`~torchfluidwarp.morph.settings.NaturalSettings` or
            :class:`~torchfluidwarp.morph.settings.PaperSettings`).
        frames: number of output frames ``N >= 2``.
        timing: how the shape and the colour progress over the morph
            (:class:`~torchfluidwarp.morph.settings.Timing`).
        blending: how each frame puts the two warped images together, and an optional region
            (:class:`~torchfluidwarp.morph.settings.Blending`).
        match: how the points are found when none are given (:class:`~torchfluidwarp.morph.settings.Matching`).
        warm_start: a previous morph's ``result.fit`` of the same method and number of points: its forces
            start this fit (the studio's live previews).
        progress: tqdm bars of the fit.
        max_memory: bytes the morph may set out to hold (its fit, and one frame at a time); default
            :data:`torchfluidwarp._checks.MAX_BYTES` (8 GiB). A larger request is refused before any work.

    Returns:
        a :class:`~torchfluidwarp.morph.result.MorphResult`: the fit, rendered on demand. ``result.frame(t)``
        renders any ``t`` in ``[0, 1]``; ``result.iter_frames()`` streams the ``frames`` in bounded memory;
        ``result.frames`` (and ``maps`` ...) renders all of them at once. ``result.error`` is each point's
        distance to B's in the last frame's pixels; ``result.fit`` is in the fluid box's frame.

    Raises:
        ImportError: ``Matching("faces")`` without the faces extra (``pip install "torchfluidwarp[faces]"``).
        ValueError: different point counts, points outside their image, repeated points, non-finite values,
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
    check_instance("match", match, Matching)
    check_instance("warm_start", warm_start, KeyframeFit, optional=True)
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
    if points_a is None:
        points_a, points_b = auto_points(a, b, match=match.mode, face_index=match.face_index)
    n = check_int("frames", frames, minimum=2)
    pa = _as_points("points_a", points_a, a)
    pb = _as_points("points_b", points_b, b)
    if pa.shape[0] != pb.shape[0]:
        raise InputError(f"points_a has {pa.shape[0]} points but points_b has {pb.shape[0]}")
    if isinstance(settings, NaturalSettings) and pa.shape[0] < 3:
        raise InputError(
            f"the natural method (NaturalSettings) needs at least 3 points, got {pa.shape[0]}; PaperSettings "
            "takes fewer"
        )
    steps = settings.steps
    shape, colour = schedule("motion", timing.motion), schedule("blend", timing.blend)
    estimate = _memory((a.shape[-2], a.shape[-1]), a.shape[1], 1, steps, settings.grid, a.element_size())  # streamed
    check_memory(
        f"morph(frames={n}, steps={steps}, grid={settings.grid})", estimate, max_memory, "morph(max_memory=...)"
    )
    check_marks(pa, pb)
    image_b_size = (b.shape[-2], b.shape[-1])
    b, pb = resize_pair(a, b, pb)
    H, W = a.shape[-2:]
    size = (H, W)
    M = pose(pa, pb, settings.align)
    center = pa.double().mean(0)
    # the fluid moves A's points to where B's points are in A's (unaligned) frame
    target = apply_alignment(torch.linalg.inv(M), pb.double())
    if isinstance(settings, NaturalSettings):
        fit, box = fit_natural(pa, target, size, settings, warm_start, progress)
    else:
        if settings.margin is None:
            box = (0, 0, W, H)
            target = torch.stack([target[:, 0].clamp(-0.5, W - 0.5), target[:, 1].clamp(-0.5, H - 0.5)], -1)
        else:
            box = region_of_interest(torch.cat([pa.double(), target]), settings.margin)
        offset = torch.tensor([box[0], box[1]], dtype=torch.float64, device=a.device)
        roi = (box[3] - box[1], box[2] - box[0])
        start = None if warm_start is None else warm_start.forces
        fit = fit_paper(pa.double() - offset, target - offset, roi, settings, start, progress)
    roi = (box[3] - box[1], box[2] - box[0])  # (H, W) of the fluid's box, pixels
    offset = torch.tensor([box[0], box[1]], dtype=torch.float64, device=a.device)
    t_fit = time.perf_counter()

    with torch.no_grad():  # the fit is done: rendering needs no graph
        velocities = fit.warp.rollout(fit.forces, roi).velocities.to(a.dtype)
        flows = None if settings.inverse == "flow" else paper_flows(fit, roi, settings)
    scene = Scene(
        a, b, velocities, fit.warp.dt, steps, M, center, box, roi, settings.inverse, shape, colour,
        blending.feather, flows,
        masks=_region_masks(blending, pa, pb, a, image_b_size),
        background=blending.background,
    )  # fmt: skip
    t_inv = time.perf_counter()

    # A's points in the frames' pixels: the fit's paths (box pixels) moved to A's pixels, then pre-aligned
    trajectories = torch.stack(
        [
            apply_alignment(interpolate_alignment(M, t / steps, center), fit.trajectories[0, t] + offset)
            for t in range(steps + 1)
        ]
    )  # (T + 1, M, 2)
    error = (trajectories[-1] - pb.to(trajectories.dtype)).norm(dim=-1)  # (M,) pixels of the last frame
    seconds = {"fit": t_fit - t0, "inverse": t_inv - t_fit, "total": t_inv - t0}
    return MorphResult(scene, fit, M, trajectories, error, n, out_dtype, seconds, max_memory)
