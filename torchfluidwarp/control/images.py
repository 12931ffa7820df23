"""Image registration: fit the fluid's forces so that the warped source matches a target image.

The same machinery as keyframe control (:func:`~torchfluidwarp.control.keyframes.fit_keyframes`): the control vector is
a coarse :class:`~torchfluidwarp.warp.forces.ControlGrid`, found by ``torch.optim.LBFGS`` with a strong-Wolfe line
search; gradients come from autograd through the solver (implicit adjoints for its linear solves) and through
the backward map and the image sampling. No finite differences.

Objective: ``phi(u) = sum_b L(f_b(g_T), target_b) + point_weight * sum_b mean_i ||p_i(T) - q_i||^2
+ regularization * ||u||^2`` where ``f(g_T)`` is the source sampled through the backward map of the last
step (frame ``T`` of :class:`~torchfluidwarp.warp.layer.FluidWarp`), ``L`` is ``1 -`` the squared local
normalised cross-correlation (the default), the mean squared error, ``1 - NCC`` or the structural dissimilarity
``(1 - SSIM) / 2`` (kornia's), and the optional points ``p_i``
are carried by the forward map (pixels^2).

Coarse to fine: each level fits on a smaller fluid grid and on images downsampled in proportion (the same
pixels per fluid cell), then hands its control grid to the next. A control grid does not depend on the fluid
grid's resolution (it is upsampled to any grid), but forces are in fluid cells per time unit^2, so they are
multiplied by the ratio of grid sizes on the way up.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import torch
from torch import Tensor

from torchfluidwarp._checks import (
    check_float_dtype,
    check_fraction,
    check_int,
    check_positive,
    check_returned_loss,
    check_size,
    check_tensor,
    compute_dtype,
    describe,
    warn,
)
from torchfluidwarp.control.alignment import best_shift
from torchfluidwarp.control.keyframes import check_fit_memory, check_points
from torchfluidwarp.control.losses import ImageLoss, LossName, image_loss
from torchfluidwarp.control.optim import HISTORY_SIZE, minimize
from torchfluidwarp.core.fluid import Viscosity
from torchfluidwarp.core.grid import FluidGrid, scale_factor
from torchfluidwarp.errors import FlowBlewUp, InputError, InputTypeError
from torchfluidwarp.io import resize_image
from torchfluidwarp.warp.forces import ControlGrid
from torchfluidwarp.warp.frames import jacobian_determinant, warp_image
from torchfluidwarp.warp.layer import FluidWarp
from torchfluidwarp.warp.maps import iter_backward_maps

__all__ = ["FoldWarning", "ImageFit", "LevelFit", "fit_images", "shift_out", "shift_rivals", "usable_shift"]


class FoldWarning(RuntimeWarning):
    """:func:`fit_images`' fitted map folds: the flow crushes part of the source onto itself."""


SHIFT_CHECK = 0.1
"""A fit whose loss ends above this fraction of the starting loss is compared with the best plain shift of the
source (:func:`~torchfluidwarp.control.alignment.best_shift`)."""

SHIFT_RIVAL = 1.5
"""Such a fit warns when a plain shift of at least 2 pixels comes within this factor of its loss: a flow that does
barely better than a motion it cannot carry (a closed, incompressible box does not translate its whole content) has
most likely found a swirl instead of the pictures' motion. On the stereo motorcycle (741 x 500, true disparity 7-60
px) the defaults reach 51% of the starting loss with a map 43.6 px from the truth, farther than no motion (34.7
px), while a shift by 49 px reaches 63%; fits that find their motion end far below either
(``tests/control/test_shift.py``)."""

SHIFT_GAIN = 0.75
"""And only where that shift explains part of the mismatch itself, its loss at most this fraction of the starting
loss: on pictures that no shift relates (noise against noise), the best shift barely moves the loss, and says
nothing about the fit."""


SHIFT_OUT = 1 / 3
"""A shift that moves more than this share of the source out of the frame (``1 - (1 - |dx| / W) (1 - |dy| / H)``)
rivals the fit only if it beats it outright (:data:`SHIFT_RIVAL` does not apply). Its copy is then mostly the
source's edge pixels held, which a local loss scores as it does flat regions: two plain face masks side by side
(709 x 354 and 680 x 366) found a shift by (-269, -66) px at 0.51 of a loss the flow had brought from 0.85 to
0.36, and warned of a missed motion where there was none. A blob that truly crosses half a small picture is
matched far better by its shift than by a flow that missed it, and still warns."""


def shift_rivals(shift: Tensor, by_shift: float, final: float, initial: float, size: tuple[int, int]) -> bool:
    """Whether a plain ``shift`` ``(2,)`` ``(dx, dy)`` pixels of a picture of ``size`` ``(H, W)``, at loss
    ``by_shift``, rivals a fit that took the loss from ``initial`` to ``final``: a shift of at least 2 pixels,
    within :data:`SHIFT_RIVAL` of the fit's loss (below it, if the shift moves more than :data:`SHIFT_OUT` of the
    picture out of the frame), and removing a quarter of the starting loss itself (:data:`SHIFT_GAIN`).
    :func:`fit_images` warns then.

    Example:
        >>> shift_rivals(torch.tensor([49.0, 0.0]), 0.03444, 0.03189, 0.05433, (500, 741))  # motorcycle, old defaults
        True
        >>> shift_rivals(torch.tensor([-269.0, -66.0]), 0.5137, 0.3561, 0.8491, (354, 709))  # two face masks
        False
    """
    rival = SHIFT_RIVAL if shift_out(shift, size) <= SHIFT_OUT else 1.0
    return max(abs(float(v)) for v in shift) >= 2 and by_shift < min(rival * final, SHIFT_GAIN * initial)


def shift_out(shift: Tensor, size: tuple[int, int]) -> float:
    """The share of a picture of ``size`` ``(H, W)`` that a plain ``shift`` ``(2,)`` ``(dx, dy)`` pixels moves out
    of the frame: ``1 - (1 - |dx| / W) (1 - |dy| / H)``, each factor at least 0."""
    dx, dy = (abs(float(v)) for v in shift)
    H, W = size
    return 1 - max(0.0, 1 - dx / W) * max(0.0, 1 - dy / H)


def usable_shift(shift: Tensor, by_shift: float, initial: float, size: tuple[int, int]) -> bool:
    """Whether a plain ``shift`` ``(2,)`` pixels of a picture of ``size`` ``(H, W)``, at loss ``by_shift`` against a
    starting loss ``initial``, is the pictures' main motion, to pre-align them by: at least 2 pixels, moving at
    most :data:`SHIFT_OUT` of the picture out of the frame, and explaining part of the mismatch itself (its loss
    below :data:`SHIFT_GAIN` of the starting one): the rules by which :func:`shift_rivals` judges a shift. Between
    pictures that no shift relates, the best one only moves the picture out of the way.

    Example:
        >>> usable_shift(torch.tensor([46.0, 0.0]), 0.3092, 0.4652, (500, 741))  # the stereo motorcycle's views
        True
        >>> usable_shift(torch.tensor([-185.0, -192.0]), 0.8426, 1.0938, (400, 600))  # a cup against a cat
        False
    """
    far = max(abs(float(v)) for v in shift) >= 2
    return far and shift_out(shift, size) <= SHIFT_OUT and by_shift < SHIFT_GAIN * initial


@dataclass
class LevelFit:
    """One level of a coarse-to-fine fit.

    Attributes:
        grid: the fluid grid ``(h, w)``.
        image_size: ``(H, W)`` of the (downsampled) images fitted at this level.
        initial_loss: the objective at this level's starting forces.
        final_loss: the objective at its best forces.
        evaluations: objective-and-gradient evaluations.
        seconds: wall time.
        converged: L-BFGS stopped on its own criterion before ``max_iter``; False also when a non-finite loss
            stopped it (the best finite iterate is kept: :func:`~torchfluidwarp.control.optim.minimize`).
    """

    grid: tuple[int, int]
    image_size: tuple[int, int]
    initial_loss: float
    final_loss: float
    evaluations: int
    seconds: float
    converged: bool


@dataclass
class ImageFit:
    """The result of :func:`fit_images`.

    Attributes:
        forces: the fitted :class:`~torchfluidwarp.warp.forces.ControlGrid` (control vector ``(B, T, 2, K_y, K_x)``).
        warp: a :class:`~torchfluidwarp.warp.layer.FluidWarp` on the finest grid that replays the forces on any image:
            ``fit.warp(source, fit.forces)[:, -1]`` is ``warped``.
        warped: ``(B, C, H, W)`` the source warped by the fitted forces (frame ``T``), full resolution.
        initial_loss: the image term at full resolution before fitting (identity map).
        final_loss: the image term at full resolution after fitting.
        min_det: ``(B,)`` the smallest Jacobian determinant of the fitted backward map (> 0: no folds; a fit
            whose map folds also warns, naming how many pixels fold).
        loss_history: the objective at every evaluation, all levels in order.
        evaluations: total objective-and-gradient evaluations.
        seconds: total wall time.
        converged: the finest level's L-BFGS stopped on its own criterion before ``max_iter``.
        levels: one :class:`LevelFit` per level, coarse to fine.
        message: a one-line summary.
    """

    forces: ControlGrid
    warp: FluidWarp
    warped: Tensor
    initial_loss: float
    final_loss: float
    min_det: Tensor
    loss_history: list[float] = field(default_factory=list)
    evaluations: int = 0
    seconds: float = 0.0
    converged: bool = False
    levels: list[LevelFit] = field(default_factory=list)
    message: str = ""

    def animate(self, image: Tensor) -> Tensor:
        """Replay the fitted forces on ``image`` ``(B|1, C, H, W)``: frames ``(B, T + 1, C, H, W)``."""
        return self.warp(image, self.forces)


COARSEST_LEVEL = 16
"""``levels="auto"``'s coarsest level, in cells along the grid's longer side: the grid's longer side is halved
while the half has at least this many cells, so the default 64 x 64 grid fits at 16, 32 and 64."""


def _level_grids(grid: FluidGrid, levels: Sequence[int] | Literal["auto"] | None) -> list[FluidGrid]:
    """Coarse-to-fine grids: each level ``n`` is ``grid`` scaled so that its longer side has ``n`` cells."""
    longest = max(grid.shape)
    if levels is None:
        return [grid]
    if isinstance(levels, str):
        if levels != "auto":
            raise InputError(f"levels must be 'auto', None or a sequence of ints, got {levels!r}", argument="levels")
        levels = [longest]
        while levels[0] // 2 >= COARSEST_LEVEL:
            levels.insert(0, levels[0] // 2)
    if not isinstance(levels, (tuple, list)) or not levels:
        raise InputTypeError(
            f"levels must be 'auto', None or a non-empty sequence of ints, got {describe(levels)}", argument="levels"
        )
    sizes = [check_int("levels", n, minimum=2) for n in levels]
    if any(b <= a for a, b in zip(sizes, sizes[1:])) or sizes[-1] > longest:
        raise InputError(
            f"levels must increase and end at most at the finest grid's longer side ({longest}), got {tuple(sizes)}",
            argument="levels",
        )
    if sizes[-1] != longest:
        sizes.append(longest)
    h, w = grid.shape
    return [FluidGrid(max(2, round(h * n / longest)), max(2, round(w * n / longest))) for n in sizes[:-1]] + [grid]


def _warp_last(warp: FluidWarp, forces: ControlGrid, image: Tensor) -> Tensor:
    """Frame ``T`` of ``warp(image, forces)``, composing only the maps it needs."""
    size = (image.shape[-2], image.shape[-1])
    vel = warp.rollout(forces, size).velocities.to(image.dtype)
    coords = next(iter_backward_maps(vel, size, warp.dt, times=[warp.steps]))  # (B, H, W, 2)
    return warp_image(image, coords, warp.mode)


def fit_images(
    source: Tensor,
    target: Tensor,
    *,
    loss: LossName | ImageLoss = "lncc",
    points: tuple[Tensor, Tensor] | None = None,
    point_weight: float = 1e-3,
    grid: FluidGrid | int | tuple[int, int] = (64, 64),
    levels: Sequence[int] | Literal["auto"] | None = "auto",
    steps: int = 10,
    control: tuple[int, int] | int = (5, 5),
    dt: float = 1.0,
    viscosity: Viscosity = 0.0,
    regularization: float = 0.0,
    max_iter: int | Sequence[int] = 50,
    compressible: bool = True,
    dtype: torch.dtype = torch.float64,
    progress: bool = True,
    history_size: int = HISTORY_SIZE,
    max_memory: float | None = None,
) -> ImageFit:
    """Fit forces so that the fluid warps ``source`` onto ``target``, coarse to fine.

    Args:
        source: ``(1|B, C, H, W)`` the image to warp (floats, typically in ``[0, 1]``).
        target: ``(1|B, C, H, W)`` the image to match (same ``C, H, W``); B independent problems are fitted
            together.
        loss: ``"lncc"`` (the default: :func:`~torchfluidwarp.control.losses.lncc_loss`, ``1 -`` the squared local
            normalised cross-correlation over 9 x 9 pixels at every level, insensitive to brightness, contrast and
            contrast sign), ``"mse"`` (mean squared error), ``"ncc"`` (``1 - `` global normalised cross-correlation:
            robust to one brightness and contrast change over the whole picture), ``"ssim"``
            (:func:`~torchfluidwarp.control.losses.ssim_loss`, kornia's structural dissimilarity ``(1 - SSIM) / 2``,
            window 11, for images in ``[0, 1]``), or a callable ``loss(warped, target) -> scalar``. On the stereo
            motorcycle the default ends 5.7 px from the true map (``benchmarks/bench_stereo.py``), ``"mse"`` in the same
            fluid about 9 px (``docs/benchmarks.md``). Windows with no texture count as a mismatch that no motion
            improves: for a picture that is mostly flat (a lone shape on a plain ground) ``"mse"`` or ``"ncc"`` suit
            better.
        points: optional landmark pairs ``(src, tgt)``, each ``(M, 2)`` or ``(B, M, 2)`` in pixels of the
            full-resolution images (pixel centres at integers): ``src`` carried by the forward map should land
            on ``tgt``.
        point_weight: weight of the landmark term, the mean squared distance in pixels^2 (added to the image
            term, whose scale is that of ``loss``).
        grid: the finest fluid grid ``(h, w)``.
        levels: coarse-to-fine sizes, in cells along the longer side of ``grid`` (increasing; the finest grid
            is added when the last level is smaller); ``"auto"`` (the default): the longer side halved while
            the half keeps at least :data:`COARSEST_LEVEL` (16) cells, (16, 32, 64) for the default grid and
            (20, 40) for a grid of 40; ``None`` fits on ``grid`` only. Images at each level are downsampled to
            keep the finest level's pixels per cell.
        steps: fluid steps ``T``; the warped source is frame ``T``.
        control: ``(K_y, K_x)`` control points per step of the :class:`ControlGrid`.
        dt: time step. viscosity: as for :class:`~torchfluidwarp.warp.layer.FluidWarp` (float or ``(B|1, 1, h, w)``
            field on the finest grid; a field is used at the finest level only, coarser levels get its mean).
        regularization: weight on ``||u||^2`` (default 0: off).
        max_iter: L-BFGS iterations per level (an int, or one per level).
        compressible: skip the pressure projection (the default): regions may change size, and the content
            of the box may shift as a whole, as it does between two views or two framings. ``False`` is the
            paper's incompressible fluid, which keeps every area: it cannot carry a shift of the whole picture,
            and on the stereo motorcycle it ends farther from the true map than no motion at all.
        dtype: dtype of the fit. float64 by default: the image losses and the registration figures in
            ``docs/benchmarks.md`` were measured in float64
            (:func:`~torchfluidwarp.control.keyframes.fit_keyframes`, whose
            point loss was measured in both, defaults to float32).
        progress: show a tqdm bar of L-BFGS iterations per level, with the loss.
        max_memory: bytes the fit may set out to hold (its finest level with autograd); default
            :data:`torchfluidwarp._checks.MAX_BYTES`. A larger fit is refused before any work.
        history_size: L-BFGS memory, as for :func:`~torchfluidwarp.control.optim.minimize` (default 100, the
            library's one value; this fit used 20 before the driver was shared).

    Returns:
        an :class:`ImageFit`.

    Raises:
        InputError: mismatched shapes, an empty batch, non-finite values, points outside the image, bad ``loss``,
            ``levels``, ``max_iter``, ``steps`` or ``control``; a ``loss`` that returns more than one number, a
            non-finite one, or one without an autograd graph (detached, or computed under ``no_grad``). A
            ``ValueError``; ``error.argument`` names the argument.
        InputTypeError: arguments of the wrong type (a ``TypeError``).
        FlowBlewUp: the flow blows up at the starting forces (an ``ArithmeticError``).

    Warns:
        FoldWarning: (a ``RuntimeWarning``) the fitted map folds.
        RuntimeWarning: the fit ends above :data:`SHIFT_CHECK` of its starting loss and a
            plain shift of ``source`` (:func:`~torchfluidwarp.control.alignment.best_shift`) comes within
            :data:`SHIFT_RIVAL` of it while removing at least a quarter of the starting loss (:data:`SHIFT_GAIN`)
            (below it, for a shift that moves more than :data:`SHIFT_OUT` of the picture out of the frame;
            :func:`shift_rivals`): the map may then be farther from the truth than no motion at all.

    Example:
        >>> yy, xx = torch.meshgrid(torch.arange(32.0), torch.arange(32.0), indexing="ij")
        >>> blob = lambda cx: torch.exp(-((xx - cx) ** 2 + (yy - 16) ** 2) / 50)[None, None]
        >>> fit = fit_images(blob(14.0), blob(18.0), loss="mse", grid=16, levels=(8,), steps=4, control=3,
        ...                  progress=False)  # a lone blob on black: flat windows, where the MSE does better
        >>> fit.final_loss < 0.01 * fit.initial_loss
        True
    """
    src = check_tensor("source", source, ndim=4)
    tgt = check_tensor("target", target, ndim=4)
    if src.shape[1:] != tgt.shape[1:] or (src.shape[0] != tgt.shape[0] and 1 not in (src.shape[0], tgt.shape[0])):
        raise InputError(
            f"source and target must have the same (C, H, W) and batch sizes 1 or B, got source "
            f"{tuple(src.shape)} and target {tuple(tgt.shape)}",
            argument="target",
        )
    for name, x in (("source", src), ("target", tgt)):
        if x.shape[0] == 0:
            raise InputError(f"{name} must hold at least one image, got an empty batch {tuple(x.shape)}", argument=name)
    H, W = src.shape[-2:]
    if min(H, W) < 2:
        raise InputError(f"source must be at least 2 x 2 pixels, got {tuple(src.shape)}", argument="source")
    B = max(src.shape[0], tgt.shape[0])
    objective = image_loss(loss)
    fine = FluidGrid.of(grid)
    grids = _level_grids(fine, levels)
    steps = check_int("steps", steps)
    ky, kx = check_size("control", control, minimum=2)
    dt = check_positive("dt", dt)
    point_weight = check_positive("point_weight", point_weight, allow_zero=True)
    regularization = check_positive("regularization", regularization, allow_zero=True)
    if not isinstance(max_iter, (list, tuple)):
        check_int("max_iter", max_iter)
    iters = [max_iter] * len(grids) if isinstance(max_iter, int) else list(max_iter)
    if len(iters) != len(grids):
        raise InputError(
            f"max_iter must be an int or one int per level ({len(grids)}), got {max_iter!r}", argument="max_iter"
        )
    iters = [check_int("max_iter", n) for n in iters]
    check_int("history_size", history_size)
    check_fraction("compressible", compressible)
    dtype = compute_dtype(check_float_dtype("dtype", dtype))  # half precision is fitted in float32
    check_fit_memory("fit_images", B, steps, fine, (H, W), dtype, max_memory, (ky, kx))
    pts = None
    if points is not None:
        if not (isinstance(points, (tuple, list)) and len(points) == 2):
            raise InputTypeError(
                f"points must be a pair (src (M, 2), tgt (M, 2)), got {describe(points)}", argument="points"
            )
        p, q = check_points("points[0]", points[0], (H, W), B), check_points("points[1]", points[1], (H, W), B)
        if p.shape[1] != q.shape[1]:
            raise InputError(
                f"points must pair up: {p.shape[1]} source points and {q.shape[1]} target points", argument="points"
            )
        pts = (p.expand(B, -1, -1).to(src.device, dtype), q.expand(B, -1, -1).to(src.device, dtype))

    src = src.expand(B, -1, -1, -1).to(dtype)
    tgt = tgt.expand(B, -1, -1, -1).to(src.device, dtype)
    with torch.no_grad():
        initial = float(check_returned_loss("loss", objective(src, tgt), graph=False))
    if not math.isfinite(initial):
        raise InputError(
            f"loss must be finite, but it gave {initial} for source and target before any fitting", argument="loss"
        )
    start = time.perf_counter()
    history: list[float] = []
    records: list[LevelFit] = []
    weight = torch.zeros(B, steps, 2, ky, kx, device=src.device, dtype=dtype)
    previous: FluidGrid | None = None
    warp = module = None
    for g, n_iter in zip(grids, iters):
        if previous is not None:  # cells per time^2: forces scale with the grid's resolution
            ratio = scale_factor(previous.shape, g.shape, device=src.device, dtype=dtype)
            weight = weight * ratio.view(1, 1, 2, 1, 1)
        previous = g
        f = max(g.height / fine.height, g.width / fine.width)
        size = (H, W) if g == fine else (max(2, round(H * f)), max(2, round(W * f)))
        visc = viscosity if (g == fine or not isinstance(viscosity, Tensor)) else float(viscosity.mean())
        warp = FluidWarp(g, steps, dt, visc, image_size=(H, W), compressible=compressible).to(src.device, dtype)
        module = ControlGrid(steps, (ky, kx), batch=B, init=weight).to(src.device, dtype)
        s_l, t_l = resize_image(src, size), resize_image(tgt, size)
        record = _fit_level(
            warp,
            module,
            s_l,
            t_l,
            objective,
            pts,
            (H, W),
            point_weight,
            regularization,
            n_iter,
            history,
            progress,
            f"fit_images {g.height}x{g.width}",
            history_size,
        )
        records.append(record)
        weight = module.weight.detach().clone()

    assert warp is not None and module is not None  # at least one level, by construction
    with torch.no_grad():
        vel = warp.rollout(module, (H, W)).velocities
        coords = next(iter_backward_maps(vel, (H, W), dt, times=[steps]))
        warped = warp_image(src, coords, warp.mode)
        final = float(objective(warped, tgt))
        det = jacobian_determinant(coords).flatten(1)
        min_det, folded = det.amin(1), int((det <= 0).sum())
    if folded:
        warn(
            f"fit_images: the fitted map folds on {folded} of {det.numel()} pixels (min det "
            f"{float(min_det.min()):.3g}): the flow crushes part of the source onto itself; raise regularization "
            "for a calmer flow, at some cost in the loss",
            FoldWarning,
        )
    if not math.isfinite(final):
        raise InputError(
            f"loss became non-finite ({final}) on the fitted warp of source; no result to return", argument="loss"
        )
    if final > SHIFT_CHECK * initial:  # much of the mismatch is left: would the simplest motion do as well?
        shift, by_shift = best_shift(src, tgt, objective)
        if shift_rivals(shift, by_shift, final, initial, (src.shape[-2], src.shape[-1])):
            dx, dy = (0.0 - float(v) for v in shift)  # source is read at x + shift: its content moves by -shift (no -0)
            warn(
                f"fit_images: moving source's content by ({dx:+.0f}, {dy:+.0f}) px (x, y) matches target about "
                f"as well as the fitted flow or better (loss {by_shift:.4g} against {final:.4g}; {initial:.4g} "
                "before): the flow has likely missed the pictures' main motion, and its map may lie farther from the "
                "true one than no motion at all. "
                + (
                    "Pre-align the pictures (torchfluidwarp.control.best_shift)"
                    if compressible
                    else "A closed, incompressible box cannot carry a shift this large: pre-align the pictures "
                    "(torchfluidwarp.control.best_shift), or leave compressible=True (the default)"
                ),
                RuntimeWarning,
            )
    seconds = time.perf_counter() - start
    message = (
        f"loss {initial:.4g} -> {final:.4g} ({final / initial if initial else 0.0:.2%}) in "
        f"{len(history)} evaluations over {len(records)} level(s), {seconds:.1f} s; min det "
        f"{float(min_det.min()):.3f}"
    )
    return ImageFit(
        forces=module,
        warp=warp,
        warped=warped,
        initial_loss=initial,
        final_loss=final,
        min_det=min_det,
        loss_history=history,
        evaluations=len(history),
        seconds=seconds,
        converged=records[-1].converged,
        levels=records,
        message=message,
    )


def _fit_level(
    warp: FluidWarp,
    module: ControlGrid,
    source: Tensor,
    target: Tensor,
    objective: ImageLoss,
    points: tuple[Tensor, Tensor] | None,
    full_size: tuple[int, int],
    point_weight: float,
    regularization: float,
    max_iter: int,
    history: list[float],
    progress: bool,
    desc: str,
    history_size: int,
) -> LevelFit:
    """L-BFGS on one level with :func:`~torchfluidwarp.control.optim.minimize`; appends its losses to ``history``."""

    def phi() -> Tensor:
        # a value without a graph (the caller's loss detached it) would leave only the other terms to fit
        value = check_returned_loss("loss", objective(_warp_last(warp, module, source), target))
        if points is not None and point_weight > 0:
            p, q = points
            carried = warp.carry_points(p, module, full_size)[:, -1]
            value = value + point_weight * ((carried - q) ** 2).sum(-1).mean(-1).sum()
        if regularization > 0:
            value = value + regularization * (module.weight**2).sum()
        return value

    result = minimize(
        phi,
        [module.weight],
        max_iter=max_iter,
        progress=progress,
        desc=desc,
        history_size=history_size,
        # looser than the driver's defaults, as this fit has always run: image losses flatten out sooner
        tolerance_grad=1e-10,
        tolerance_change=1e-12,
        undefined=(FlowBlewUp,),  # a trial step whose flow blew up was too long: restart from the best one
    )
    history.extend(result.loss_history)
    return LevelFit(
        grid=warp.grid.shape,
        image_size=(source.shape[-2], source.shape[-1]),
        initial_loss=result.loss_history[0] if result.loss_history else math.nan,
        final_loss=result.best_loss,
        evaluations=result.evaluations,
        seconds=result.seconds,
        converged=result.converged,
    )
