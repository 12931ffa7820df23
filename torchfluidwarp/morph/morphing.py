"""Morphing two images with a fitted fluid flow (the paper's Section on morphing).

A morph is a forward warping ``C_l`` of the source image ``f`` driven by fitted forces, an inverse warping of
the target image ``g``, and a cross-dissolve between them. A global pre-alignment ``M`` (similarity by
default) estimated from the points is interpolated over the morph and composed with the fluid warp, so the
fluid only has to produce the local, non-rigid part.

For a frame at time ``s`` (in fluid steps, ``0..T``) and an output pixel ``y``: ``z = M_s^-1 y`` is the
point in the fluid's frame; image A is read at ``g_s(z)`` (the fluid's backward map) and image B at
``M K_s(z)``, where ``K_s`` carries ``z`` forward from ``s`` to ``T`` through the same velocities
(``inverse="flow"``), or through a chain of small per-step fits (``inverse="paper"``).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from torchfluidwarp._checks import (
    check_fraction,
    check_instance,
    check_int,
    check_memory,
    check_positive,
    check_tensor,
    compute_dtype,
    describe,
)
from torchfluidwarp.control.alignment import AlignKind, apply_alignment, interpolate_alignment
from torchfluidwarp.control.keyframes import KeyframeFit, check_points, fit_keyframes
from torchfluidwarp.core.fluid import Viscosity
from torchfluidwarp.core.grid import FluidGrid, mean_pixels_per_cell, rescale_points, scale_factor
from torchfluidwarp.correspond import MatchMode, auto_points
from torchfluidwarp.io import resize_image
from torchfluidwarp.morph.fit import MIN_AREA, PAD, check_marks, fit_natural, pose
from torchfluidwarp.morph.regions import Background, hull_mask
from torchfluidwarp.morph.render import FEATHER, InverseMethod, Scene, paper_flows
from torchfluidwarp.morph.result import MorphResult
from torchfluidwarp.morph.timing import Timing, schedule

__all__ = ["morph", "resize_pair", "region_of_interest", "DEFAULTS", "PAD", "MIN_AREA", "FEATHER"]


Method = Literal["natural", "paper"]


def _as_image(name: str, image: Tensor) -> Tensor:
    img = check_tensor(name, image, ndim=(3, 4))
    img = img.unsqueeze(0) if img.ndim == 3 else img
    if img.shape[0] != 1 or min(img.shape[1:]) < 1:
        raise ValueError(
            f"{name} must be a single image (C, H, W) or (1, C, H, W) with C, H, W >= 1, got {tuple(image.shape)}"
        )
    return img.detach()


def _as_points(name: str, points: object, image: Tensor) -> Tensor:
    """One set of points ``(M, 2)`` inside ``image``, detached, on the image's device."""
    p = check_points(name, points, (image.shape[-2], image.shape[-1]))
    if p.shape[0] != 1:
        raise ValueError(f"{name} must be one set of points (M, 2) for a morph, got shape {tuple(p.shape)}")
    return p[0].detach().to(image.device)


def _region_masks(
    region: object, margin: float, pa: Tensor, pb: Tensor, a: Tensor, size_b: tuple[int, int]
) -> tuple[Tensor, Tensor] | None:
    """The region's soft masks ``(1, 1, H, W)`` over A and over B (resized to A's size), or ``None``."""
    if region is None:
        return None
    size = (a.shape[-2], a.shape[-1])
    if isinstance(region, str):
        if region != "points":
            raise ValueError(f"region must be 'points', a pair of masks (mask_a, mask_b) or None, got {region!r}")
        masks = hull_mask(pa, size, margin), hull_mask(pb, size, margin)  # pb is already in A's size
    elif isinstance(region, (tuple, list)) and len(region) == 2:
        ma = check_tensor("region[0] (mask_a)", region[0], shape=[*size])
        mb = check_tensor("region[1] (mask_b)", region[1], shape=[*size_b])
        masks = ma, resize_image(mb[None, None].to(a.dtype), size)[0, 0]
    else:
        raise TypeError(f"region must be 'points', a pair of masks (mask_a, mask_b) or None, got {describe(region)}")
    return tuple(m.to(a)[None, None].clamp(0, 1) for m in masks)  # type: ignore[return-value]


MAX_MARGIN = 10.0
"""The largest ``margin`` of :func:`morph`: a box ten times the points' extent on each side already holds a fluid
21 times wider than the points."""


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


DEFAULTS: dict[str, dict[str, Any]] = {
    "natural": {"grid": (80, 80), "compressible": True, "smoothness": 3.0, "max_iter": 30},
    "paper": {"grid": (64, 64), "compressible": False, "smoothness": 5.0, "max_iter": 100},
}
"""Per-method defaults of :func:`morph`'s ``grid``, ``compressible``, ``smoothness`` and ``max_iter``. The
natural morph's grid covers the picture and a margin of :data:`PAD` around it: 80 cells are about 8 pixels of
a 512-pixel picture each, as 64 cells over the paper's box."""


def morph(
    image_a: Tensor,
    image_b: Tensor,
    points_a: Tensor | None = None,
    points_b: Tensor | None = None,
    *,
    match: MatchMode = "auto",
    face_index: tuple[int | None, int | None] = (None, None),
    frames: int = 30,
    method: Method = "natural",
    grid: FluidGrid | int | tuple[int, int] | None = None,
    steps: int = 10,
    control: tuple[int, int] | int = (8, 8),
    viscosity: Viscosity | nn.Module = 0.0,
    align: AlignKind | None = "similarity",
    inverse: InverseMethod = "flow",
    blend: Timing = "linear",
    motion: Timing = "linear",
    feather: float = FEATHER,
    region: Literal["points"] | tuple[Tensor, Tensor] | None = None,
    background: Background = "blend",
    region_margin: float = 0.25,
    compressible: bool | float | None = None,
    smoothness: float | None = None,
    max_iter: int | None = None,
    tolerance: float = 0.05,
    margin: float | None = 0.5,
    warm_start: KeyframeFit | None = None,
    progress: bool = True,
    max_memory: float | None = None,
) -> MorphResult:
    """Morph ``image_a`` into ``image_b`` so that ``points_a`` travel to ``points_b``.

    Two methods (``method``):

    * ``"natural"`` (default): every marked point travels on a straight line at constant speed, and the rest
      of the picture moves as a thin-plate spline between the points says. The fluid is compressible and
      inviscid and covers the whole picture (its walls lie :data:`PAD` beyond the edges); one kick at step 0
      (:class:`~torchfluidwarp.warp.forces.LandmarkForces`) sets it moving, after which every particle coasts on
      a straight line (Burgers' equation), and ``max_iter`` L-BFGS iterations correct the kicks so that the
      points stay on their paths at every step. Regions change size as the marks say; the maps never fold
      where the spline does not, and no box edge shows. ``control`` and ``margin`` do not apply.
    * ``"paper"``: the paper's keyframe fit: a :class:`~torchfluidwarp.warp.forces.ControlGrid` of forces, fitted
      so that the points reach their targets at the last step, in an incompressible fluid (every region keeps
      its area) over a box around the points (``margin``).

    Args:
        image_a: ``(C, H, W)`` or ``(1, C, H, W)`` source image in ``[0, 1]``; it sets the output size.
        image_b: target image; resized to A's size if needed (its points are scaled to match).
        points_a, points_b: ``(M, 2)`` corresponding points ``(x, y)`` in each image's pixels; ``"natural"``
            needs ``M >= 3`` points, not all on one line. ``None`` (both): found from the pictures by
            :func:`~torchfluidwarp.correspond.auto.auto_points` with ``match`` and ``face_index``.
        match: how to find the points when none are given: ``"auto"`` (faces when both images show one and
            the faces extra is installed, else matched features), ``"faces"``, ``"features"`` or ``"pixels"``.
        face_index: which face in A and in B (0 = the largest; ``None``: the largest, with a warning if several).
        frames: number of output frames ``N >= 2``.
        method: ``"natural"`` or ``"paper"`` (see above).
        grid, steps, viscosity: the fluid (see :func:`fit_keyframes`); ``grid`` cells cover the fluid's box
            (default per method, :data:`DEFAULTS`: 80 x 80 for ``"natural"``, 64 x 64 for ``"paper"``).
        control: ``(K_y, K_x)`` control points per step of ``"paper"``'s control grid.
        align: global pre-alignment ``"similarity"`` (default), ``"affine"`` or ``None``. Marks that do not agree
            on a pose (it would explain under :data:`~torchfluidwarp.morph.fit.MIN_POSE_FIT` of B's marks'
            spread: points listed in different orders) are morphed without it, with a warning.
        inverse: how B is pulled back: ``"flow"`` (default: along the same fitted velocities, no second fit)
            or ``"paper"`` (the paper's stepwise chain of one-step fits; slower, for comparison).
        blend: the colour's schedule, how the cross-dissolve's weight of B grows over the morph's time ``t``:
            a name (``"linear"``, the paper's; ``"smooth"``, ``"ease-in"``, ``"ease-out"``) or control points
            ``[(t, weight), ...]`` from ``(0, 0)`` to ``(1, 1)`` (:mod:`~torchfluidwarp.morph.timing`). Where a
            frame reads one image beyond its edge, the other image is shown instead, rather than the first
            image's edge pixels smeared into streaks.
        motion: the shape's schedule, the same kinds of values: how far along the flow (and the pre-alignment)
            each frame is. ``motion="ease-out", blend="ease-in"`` lets the shape lead the colour.
        region: limit the morph to a region: ``"points"`` (each image's points' convex hull, grown by
            ``region_margin`` of its extent, with a soft edge; :func:`~torchfluidwarp.morph.regions.hull_mask`)
            or soft masks ``(mask_a, mask_b)``, ``(H_a, W_a)`` and ``(H_b, W_b)`` in ``[0, 1]``. Each frame carries
            A's mask along A's map and B's along B's; the morph shows inside, ``background`` outside, blended
            over the masks' soft edges. ``None`` (default): the whole frame.
        background: what a region morph shows outside the region: ``"a"`` (A's picture throughout), ``"b"``, or
            ``"blend"`` (A and B cross-dissolved in place, with the colour schedule).
        region_margin: how far ``region="points"`` reaches beyond the points' hull (a fraction of their extent).
        feather: output pixels over which that hand-over happens inside an image's edge (default
            :data:`FEATHER`, 64); 0 hands over at the edge itself.
        compressible: ``True`` to let regions change area (skips the projection) or a weight in ``[0, 1]``;
            default ``True`` for ``"natural"`` and ``False`` (the paper's incompressible fluid) for ``"paper"``.
        smoothness: how strongly the fit keeps the flow calm (default per method, :data:`DEFAULTS`).
            ``"natural"``: the weight on changes to the points' straight-line velocities, in pixels^2 of point
            error per (pixel per step)^2 of velocity change, the same whatever the image or grid size; 0 lets
            the fit bend the paths as it likes to reach the points. ``"paper"``: the weight on
            :func:`~torchfluidwarp.control.keyframes.velocity_gradient_energy`, in fluid cells^2 per pixel^2 of error,
            scaled by the square of the pixels per fluid cell.
        max_iter: L-BFGS iterations (default per method: 30 for ``"natural"``, which starts on its paths,
            100 for ``"paper"``, which starts from rest).
        tolerance: pixels; the fit stops once every point is this close to its target (at every step for
            ``"natural"``).
        margin: ``"paper"`` only: the fluid fills a box around the points (A's and their targets) grown by
            this fraction of its size on each side; the rest of the picture follows the pre-alignment only.
            ``None`` makes the fluid cover exactly the whole image (targets beyond it are clamped onto it).
        warm_start: a previous :class:`KeyframeFit` of the same method whose control values start the
            optimisation (interactive use); ignored when its shape does not match.
        progress: show progress bars.
        max_memory: bytes the morph may set out to hold (its frames, maps and fluid states); default
            8 GiB (:data:`~torchfluidwarp._checks.MAX_BYTES`). A request above it is refused before any work.

    Mixed dtypes: A and B of different float dtypes are computed in the wider one, half precision in float32;
    the frames come back in the promoted dtype of A and B.

    Returns:
        a :class:`~torchfluidwarp.morph.result.MorphResult`: the fit, rendered on demand. ``result.frame(t)``
        renders any ``t`` in ``[0, 1]``; ``result.iter_frames()`` streams the ``frames`` in bounded memory;
        ``result.frames`` (and ``maps`` ...) renders all of them at once.

    Raises:
        ImportError: ``match="faces"`` without the faces extra (``pip install "torchfluidwarp[faces]"``).
        ValueError: different point counts, points outside their image, repeated points, non-finite values,
            ``frames < 2``, fewer than 3 points or points on one line for ``"natural"``.

    Warns:
        RuntimeWarning: marks that cross (swap sides or tear apart between A and B), naming them; when the
            frames are rendered, maps that fold, with the number of folded pixels.
    """
    t0 = time.perf_counter()
    a = _as_image("image_a", image_a)
    b = _as_image("image_b", image_b)
    if b.device != a.device:
        raise ValueError(f"image_a is on {a.device} but image_b is on {b.device}; put both on one device")
    out_dtype = torch.promote_types(a.dtype, b.dtype)
    a, b = a.to(compute_dtype(out_dtype)), b.to(compute_dtype(out_dtype))
    if (points_a is None) != (points_b is None):
        raise ValueError(
            "give both points_a and points_b, or neither (then match= finds them: "
            "'auto', 'faces', 'features' or 'pixels')"
        )
    if points_a is None:
        points_a, points_b = auto_points(a, b, match=match, face_index=face_index)
    n = check_int("frames", frames, minimum=2)
    pa = _as_points("points_a", points_a, a)
    pb = _as_points("points_b", points_b, b)
    if pa.shape[0] != pb.shape[0]:
        raise ValueError(f"points_a has {pa.shape[0]} points but points_b has {pb.shape[0]}")
    if method not in DEFAULTS:
        raise ValueError(f"method must be 'natural' or 'paper', got {method!r}")
    if inverse not in ("flow", "paper"):
        raise ValueError(f"inverse must be 'flow' or 'paper', got {inverse!r}")
    if method == "natural" and pa.shape[0] < 3:
        raise ValueError(f"method='natural' needs at least 3 points, got {pa.shape[0]}; method='paper' takes fewer")
    steps = check_int("steps", steps)
    defaults = DEFAULTS[method]
    compressible = defaults["compressible"] if compressible is None else check_fraction("compressible", compressible)
    grid = FluidGrid.of(defaults["grid"] if grid is None else grid)
    if margin is not None:
        margin = check_positive("margin", margin, allow_zero=True)
        if margin > MAX_MARGIN:
            raise ValueError(f"margin must be <= {MAX_MARGIN} (a fraction of the points' extent), got {margin!r}")
    check_instance("warm_start", warm_start, KeyframeFit, optional=True)
    shape, colour = schedule("motion", motion), schedule("blend", blend)
    estimate = _memory((a.shape[-2], a.shape[-1]), a.shape[1], 1, steps, grid, a.element_size())  # streamed
    check_memory(f"morph(frames={n}, steps={steps}, grid={grid})", estimate, max_memory, "morph(max_memory=...)")
    smoothness = defaults["smoothness"] if smoothness is None else smoothness
    smoothness = check_positive("smoothness", smoothness, allow_zero=True)
    feather = check_positive("feather", feather, allow_zero=True)
    max_iter = check_int("max_iter", defaults["max_iter"] if max_iter is None else max_iter)
    check_marks(pa, pb)
    image_b_size = (b.shape[-2], b.shape[-1])
    if background not in ("a", "b", "blend"):
        raise ValueError(f"background must be 'a', 'b' or 'blend', got {background!r}")
    b, pb = resize_pair(a, b, pb)
    H, W = a.shape[-2:]
    size = (H, W)
    M = pose(pa, pb, align)
    center = pa.double().mean(0)
    # the fluid moves A's points to where B's points are in A's (unaligned) frame
    target = apply_alignment(torch.linalg.inv(M), pb.double())
    fit_kwargs: dict[str, Any] = dict(
        grid=grid,
        viscosity=viscosity,
        compressible=compressible,
        max_iter=max_iter,
        tolerance=tolerance,
        progress=progress,
    )
    if method == "natural":
        fit, box = fit_natural(pa, target, size, steps, {**fit_kwargs, "regularization": smoothness}, warm_start)
        roi = (box[3] - box[1], box[2] - box[0])
        fit_kwargs["image_size"] = roi
    else:
        if margin is None:
            box = (0, 0, W, H)
            target = torch.stack([target[:, 0].clamp(-0.5, W - 0.5), target[:, 1].clamp(-0.5, H - 0.5)], -1)
        else:
            box = region_of_interest(torch.cat([pa.double(), target]), margin)
        roi = (box[3] - box[1], box[2] - box[0])
        offset = torch.tensor([box[0], box[1]], dtype=torch.float64, device=a.device)
        fit_kwargs.update(image_size=roi, control=control, smoothness=smoothness * mean_pixels_per_cell(roi, grid) ** 2)
        fit = fit_keyframes(
            pa.double() - offset,
            target - offset,
            steps=steps,
            forces=None if warm_start is None else warm_start.forces,
            **fit_kwargs,
        )
    offset = torch.tensor([box[0], box[1]], dtype=torch.float64, device=a.device)
    t_fit = time.perf_counter()

    with torch.no_grad():  # the fit is done: rendering needs no graph
        velocities = fit.warp.rollout(fit.forces, roi).velocities.to(a.dtype)
        flows = None if inverse == "flow" else paper_flows(fit, roi, {**fit_kwargs, "progress": False})
    scene = Scene(
        a, b, velocities, fit.warp.dt, steps, M, center, box, roi, inverse, shape, colour, feather, flows,
        masks=_region_masks(region, region_margin, pa, pb, a, image_b_size),
        background=background,
    )  # fmt: skip
    t_inv = time.perf_counter()

    traj = torch.stack(
        [
            apply_alignment(interpolate_alignment(M, t / steps, center), fit.trajectories[:, t] + offset)
            for t in range(steps + 1)
        ],
        dim=1,
    )
    err = (traj[:, -1] - pb.to(traj.dtype)).norm(dim=-1)
    message = (
        f"{fit.message}; in the last frame's pixels: mean error {float(err.mean()):.4f} px, "
        f"max {float(err.max()):.4f} px"
    )
    fit = dataclasses.replace(fit, trajectories=traj, points=traj[:, -1], error=err, message=message)
    seconds = {"fit": t_fit - t0, "inverse": t_inv - t_fit, "total": t_inv - t0}
    return MorphResult(scene, fit, M, n, out_dtype, seconds, max_memory)
