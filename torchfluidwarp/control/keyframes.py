"""Keyframe control: fit the fluid's forces so that marked points reach their targets.

The paper's precise control mechanism (Bonilla, Velho & Nonato; McNamara et al. 2004): the user marks points
on the source image and where they must be at a keyframe; the control vector ``u`` (the parameters of a
force module, by default a coarse :class:`~torchfluidwarp.warp.forces.ControlGrid`) is found by L-BFGS with a
strong-Wolfe line search (:func:`~torchfluidwarp.control.optim.minimize`). Gradients come from autograd through the
solver, whose linear solves use their implicit adjoint, so one gradient costs about one more simulation
whatever the number of parameters. No finite differences are used anywhere.

Objective (pixels^2): ``phi(u) = 1/2 sum_k sum_i w_i ||p_i(t_k) - q_i^k||^2 + regularization * ||u||^2``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from torchfluidwarp._checks import (
    argument_of,
    check_float_dtype,
    check_fraction,
    check_instance,
    check_int,
    check_memory,
    check_positive,
    check_size,
    check_tensor,
    compute_dtype,
    describe,
)
from torchfluidwarp.control.newton import MAX_FORWARDS, newton_start, startable_control
from torchfluidwarp.control.optim import minimize
from torchfluidwarp.core.fluid import Viscosity
from torchfluidwarp.core.grid import FluidGrid, inside_picture
from torchfluidwarp.core.staggered import StaggeredGrid
from torchfluidwarp.errors import FlowBlewUp, InputError, InputTypeError
from torchfluidwarp.warp.forces import ControlGrid
from torchfluidwarp.warp.layer import FluidWarp

__all__ = ["KeyframeFit", "fit_keyframes", "keyframe_loss", "velocity_gradient_energy", "check_points"]

Keyframes = Tensor | Sequence[tuple[int, Tensor]]


@dataclass
class KeyframeFit:
    """The result of :func:`fit_keyframes`.

    Attributes:
        forces: the fitted force module (its parameters are the control vector).
        warp: a :class:`~torchfluidwarp.warp.layer.FluidWarp` that replays the fitted forces on any image of
            ``image_size``: ``fit.warp(image, fit.forces)``.
        points: ``(B, M, 2)`` the source points carried to the last step, pixels.
        trajectories: ``(B, T + 1, M, 2)`` their paths, pixels.
        error: ``(B, M)`` distance in pixels from each point to its target at the last keyframe.
        keyframe_errors: per keyframe ``(time_step, (B, M) errors)``.
        loss_history: the objective (pixels^2) after every roll-out of the quasi-Newton start, then at every
            L-BFGS evaluation.
        evaluations: number of objective-and-gradient evaluations (L-BFGS'; 0 when the quasi-Newton start
            met the targets on its own).
        forwards: roll-outs without autograd run by the quasi-Newton start (``method="auto"``), about a third
            of an evaluation each; 0 without it.
        seconds: wall time of the fit.
        converged: the fit stopped on its own criterion (targets met, or L-BFGS made no further progress)
            before ``max_iter`` iterations; False also when a non-finite loss stopped it
            (:func:`~torchfluidwarp.control.optim.minimize`'s NaN policy: the best finite iterate is kept).
        reached: every point is within ``tolerance`` pixels of its target at every keyframe.
        message: a one-line summary: reached or not, the last keyframe's mean and largest error and, with several
            keyframes, the largest error of the worst one where another keyframe is farther off than the last.
    """

    forces: nn.Module
    warp: FluidWarp
    points: Tensor
    trajectories: Tensor
    error: Tensor
    keyframe_errors: list[tuple[int, Tensor]]
    loss_history: list[float] = field(default_factory=list)
    evaluations: int = 0
    forwards: int = 0
    seconds: float = 0.0
    converged: bool = False
    reached: bool = False
    message: str = ""

    def animate(self, image: Tensor) -> Tensor:
        """Replay the fitted forces on ``image`` ``(B|1, C, H, W)``: frames ``(B, T + 1, C, H, W)``."""
        return self.warp(image, self.forces)


def check_fit_memory(
    what: str,
    batch: int,
    steps: int,
    grid: object,
    size: tuple[int, int] | None,
    dtype: torch.dtype,
    limit: object,
    control: object = 2,
) -> None:
    """Refuse a fit whose roll-out with autograd (some 16 velocity-sized tensors per step, some 8 maps of
    ``size`` when images are fitted, and the ``control`` weights with L-BFGS' history of 100 steps) would exceed
    ``limit`` bytes (``max_memory``), before any work."""
    h, w = FluidGrid.of(grid).shape  # type: ignore[arg-type]
    ky, kx = check_size("control", control)
    per_step = 16 * 2 * (h + 1) * (w + 1) + (0 if size is None else 8 * 2 * size[0] * size[1]) + 210 * 2 * ky * kx
    nbytes = batch * steps * per_step * dtype.itemsize
    where = f"{what} over {steps} steps on a grid of {h} x {w} cells, control {ky} x {kx}"
    where += "" if size is None else f", images {size}"
    check_memory(where, nbytes, limit, "max_memory")  # type: ignore[arg-type]


def check_points(name: str, points: object, image_size: tuple[int, int], batch: int | None = None) -> Tensor:
    """Validate pixel points ``(M, 2)`` or ``(B, M, 2)`` inside the image; returns ``(B, M, 2)``."""
    p = check_tensor(name, points, ndim=(2, 3))
    given = tuple(p.shape)  # the caller's shape, for the messages
    if p.ndim == 2:
        p = p.unsqueeze(0)
    if p.shape[-1] != 2 or p.shape[1] < 1:
        raise InputError(
            f"{name} must have shape (M, 2) or (B, M, 2) with M >= 1, got {given}", argument=argument_of(name)
        )
    if batch is not None and p.shape[0] not in (1, batch):
        raise InputError(f"{name} must have batch size {batch} (or 1), got {given}", argument=argument_of(name))
    H, W = image_size
    outside = ~inside_picture(p, image_size)
    if bool(outside.any()):
        i = int(outside.flatten().nonzero()[0])
        where = [round(float(v), 2) for v in p.reshape(-1, 2)[i]]
        raise InputError(
            f"{name} has a point outside the {W} x {H} image: point {i % p.shape[1]} at {where} "
            f"(pixels, x in [-0.5, {W - 0.5}], y in [-0.5, {H - 0.5}]){_likely_cause(p, image_size)}",
            argument=argument_of(name),
        )
    return p


def _likely_cause(p: Tensor, image_size: tuple[int, int]) -> str:
    """Why points ``(B, M, 2)`` some of which lie outside a picture of ``image_size`` ``(H, W)`` may have been
    given so, when changing one convention puts them all inside, the smallest change first: the advice, after
    ``"; "``, or ``""``. Points that fit with their columns swapped also fit the picture turned a quarter."""
    for changes in (
        {"1-based (subtract 1)": p - 1, "measured from pixel corners (subtract 0.5)": p - 0.5},
        {
            "(y, x) pairs, points being (x, y), or marked on the picture turned a quarter (a photograph stored "
            "sideways, which its EXIF orientation turns upright)": p.flip(-1)
        },
    ):
        fitting = [advice for advice, moved in changes.items() if bool(inside_picture(moved, image_size).all())]
        if fitting:
            return f"; all of them fit if they are {' or '.join(fitting)}"
    return ""


def _worst_keyframe(errors: list[tuple[int, Tensor]]) -> str:
    """The message's words on which keyframe its figures are of, when there are several: the last one's, and the
    worst one's maximum where another is farther off (``" at the last keyframe (step 10); worst at step 5: max
    0.0649 px"``)."""
    if len(errors) < 2:
        return ""
    last = errors[-1][0]
    step, worst = max(errors, key=lambda item: float(item[1].max()))
    note = f" at the last keyframe (step {last})"
    return note if step == last else f"{note}; worst at step {step}: max {float(worst.max()):.4f} px"


def _keyframes(
    target: Keyframes, steps: int, image_size: tuple[int, int], m: int, batch: int
) -> list[tuple[int, Tensor]]:
    if not isinstance(target, (Tensor, list, tuple)):
        raise InputTypeError(
            f"target must be a tensor of points or a list of (time_step, points), got {describe(target)}"
        )
    frames = [(steps, target)] if isinstance(target, Tensor) else list(target)
    if not frames:
        raise InputError("target must be a tensor of points or a non-empty list of (time_step, points)")
    out = []
    for item in frames:
        if not (isinstance(item, (tuple, list)) and len(item) == 2):
            raise InputTypeError(f"each keyframe must be a (time_step, points) pair, got {type(item).__name__}")
        t, q = item
        t = check_int("keyframe time_step", t)
        if t > steps:
            raise InputError(f"keyframe time_step must be in 1..{steps} (steps), got {t}")
        q = check_points("target", q, image_size, batch)
        if q.shape[1] != m:
            raise InputError(f"source has {m} points but target (time step {t}) has {q.shape[1]}")
        out.append((t, q))
    return out


def keyframe_loss(paths: Tensor, keyframes: Sequence[tuple[int, Tensor]], weights: Tensor | None = None) -> Tensor:
    """The paper's objective ``1/2 sum_k sum_i w_i ||p_i(t_k) - q_i^k||^2`` in pixels^2.

    Args:
        paths: ``(B, T + 1, M, 2)`` point trajectories in pixels.
        keyframes: ``(time_step, targets (B|1, M, 2))`` pairs.
        weights: optional ``(B|1, M)`` per-point weights.

    Example:
        >>> paths = torch.zeros(1, 3, 2, 2)
        >>> float(keyframe_loss(paths, [(2, torch.ones(1, 2, 2))]))
        2.0
    """
    loss = paths.new_zeros(())
    for t, q in keyframes:
        sq = ((paths[:, t] - q) ** 2).sum(-1)
        loss = loss + 0.5 * (sq if weights is None else weights * sq).sum()
    return loss


def velocity_gradient_energy(velocities: Tensor) -> Tensor:
    """``sum_b sum_t mean_cells |grad v_t|^2`` of staggered velocities ``(B, T, 2, h + 1, w + 1)``, in 1 / time unit^2.

    Large where the flow shears or spins; :func:`fit_keyframes` can penalise it (``smoothness``) so that the
    fitted flow moves the points without the vortices that stretch the picture into sub-pixel spirals.
    """
    grid = StaggeredGrid.of(velocities)
    h, w = grid.h, grid.w
    u, v = grid.split(velocities.flatten(0, 1))  # (B T, h, w + 1), (B T, h + 1, w): walls included (they are zero)
    terms = [u.diff(dim=-1), u.diff(dim=-2), v.diff(dim=-1), v.diff(dim=-2)]
    return torch.stack([(d**2).sum() for d in terms]).sum() / (h * w)


def fit_keyframes(
    source: Tensor,
    target: Keyframes,
    *,
    image_size: tuple[int, int],
    grid: FluidGrid | int | tuple[int, int] = (64, 64),
    steps: int = 10,
    control: tuple[int, int] | int = (5, 5),
    dt: float = 1.0,
    viscosity: Viscosity | nn.Module = 0.0,
    forces: nn.Module | None = None,
    weights: Tensor | None = None,
    regularization: float = 0.0,
    smoothness: float = 0.0,
    max_iter: int = 200,
    tolerance: float = 0.01,
    compressible: bool | float = False,
    dtype: torch.dtype = torch.float32,
    progress: bool = True,
    max_memory: float | None = None,
    method: str = "auto",
) -> KeyframeFit:
    """Fit forces so that ``source`` points reach ``target`` at the keyframe(s).

    Args:
        source: ``(M, 2)`` or ``(B, M, 2)`` source points ``(x, y)`` in pixels (pixel centres at integers) of
            an image of ``image_size``; B independent problems are fitted together.
        target: ``(M, 2)`` / ``(B, M, 2)`` targets at the last step, or a list of ``(time_step, targets)``
            keyframes with ``1 <= time_step <= steps`` (Treuille et al. 2003).
        image_size: ``(H, W)`` in pixels.
        grid: fluid grid ``(h, w)``.
        steps: fluid steps ``T``.
        control: ``(K_y, K_x)`` control points per step of the default :class:`ControlGrid` (``2 K_y K_x T``
            parameters; (5, 5) over 10 steps is the paper's 500).
        dt: time step. viscosity: as for :class:`~torchfluidwarp.warp.layer.FluidWarp`.
        forces: a force module to fit instead of the control grid (its parameters are optimised, starting
            from their current values: pass a previous fit's ``forces`` to warm-start; a
            :class:`~torchfluidwarp.warp.forces.ControlGrid` with ``cumulative=True`` keeps the quasi-Newton start
            of ``method="auto"``).
        weights: optional ``(M,)`` or ``(B, M)`` per-point weights (default 1).
        regularization: weight on ``||u||^2`` (default 0: off). The default control grid's ``u`` holds running
            sums of the forces (:class:`ControlGrid`), so this penalises the speed the forces build up.
        smoothness: weight on :func:`velocity_gradient_energy` of the flow (pixels^2 per 1 / time unit^2;
            default 0: off). It trades accuracy at the points for a calmer flow without vortices; the morph
            uses it to keep its maps fold-free.
        max_iter: maximum L-BFGS iterations (see :func:`~torchfluidwarp.control.optim.minimize`); the
            quasi-Newton start of ``method="auto"`` takes at most as many steps too (and at most
            :data:`~torchfluidwarp.control.newton.MAX_FORWARDS` roll-outs).
        tolerance: pixels; the fit stops once every point is this close to its target.
        compressible: skip (``True``) or weight the pressure projection (see
            :class:`~torchfluidwarp.warp.layer.FluidWarp`).
        dtype: dtype of the fit. float32 (the default) met the same tolerance as float64 on the paper's
            set-up, within 3 evaluations either way, at about 0.8x the time per evaluation
            (``benchmarks/bench_keyframes.py``); float64 is there for tight tolerances and checks.
        progress: show a tqdm bar of the quasi-Newton start's roll-outs, then one of L-BFGS iterations, with the
            loss.
        max_memory: bytes the fit may set out to hold (its roll-out with autograd); default
            :data:`torchfluidwarp._checks.MAX_BYTES`. A larger fit is refused before any work.
        method: ``"auto"`` (the default): when the objective is the points' alone (a control grid, no
            ``regularization`` or ``smoothness``, a viscosity that is a number, any ``compressible``, and
            a start within :data:`~torchfluidwarp.control.newton.MAX_START_BYTES` of memory), start
            with :func:`~torchfluidwarp.control.newton.newton_start`, damped Gauss-Newton steps on a model
            Jacobian that cost one roll-out without autograd each, and hand over to L-BFGS only if it stalls
            (on the paper's set-up it met the targets alone on all 5 benchmark instances, at about a seventh
            of L-BFGS' time: ``benchmarks/bench_keyframes.py``). Other objectives, and ``"lbfgs"``, run
            L-BFGS from the start. The two may settle on different controls that both meet the targets.

    Returns:
        a :class:`KeyframeFit`.

    Raises:
        ValueError: mismatched point counts, points outside the image, non-finite values, no points,
            ``steps < 1``, bad keyframe times.
        FlowBlewUp: the starting forces (``forces``, a warm start) make the flow blow up.
            A trial step of the fit that does is a step too long: the fit steps back (see
            :func:`~torchfluidwarp.control.optim.minimize`).

    Example:
        >>> src = torch.tensor([[20.0, 20.0], [40.0, 30.0]])
        >>> fit = fit_keyframes(src, src + 2.0, image_size=(64, 64), grid=16, steps=4, control=3, progress=False)
        >>> bool(fit.error.max() < 0.05)
        True
    """
    H, W = check_size("image_size", image_size)
    steps = check_int("steps", steps)
    check_int("max_iter", max_iter)
    tolerance = check_positive("tolerance", tolerance)
    regularization = check_positive("regularization", regularization, allow_zero=True)
    smoothness = check_positive("smoothness", smoothness, allow_zero=True)
    dt = check_positive("dt", dt)
    check_fraction("compressible", compressible)
    check_instance("forces", forces, nn.Module, optional=True)
    if method not in ("auto", "lbfgs"):
        raise InputError(f"method must be 'auto' or 'lbfgs', got {method!r}")
    dtype = compute_dtype(check_float_dtype("dtype", dtype))  # half precision is fitted in float32
    src = check_points("source", source, (H, W))
    keyframes = _keyframes(target, steps, (H, W), src.shape[1], src.shape[0])
    B = max([src.shape[0]] + [q.shape[0] for _, q in keyframes])
    check_fit_memory("fit_keyframes", B, steps, grid, None, dtype, max_memory, control)
    device = src.device
    src = src.expand(B, -1, -1).to(dtype)
    keyframes = [(t, q.expand(B, -1, -1).to(device, dtype)) for t, q in keyframes]
    M = src.shape[1]
    w = (
        torch.ones(B, M, device=device, dtype=dtype)
        if weights is None
        else check_tensor("weights", weights, ndim=(1, 2)).to(device, dtype)
    )
    w = w.expand(B, M) if w.shape[-1] == M else w
    if w.shape != (B, M) or bool((w < 0).any()):
        raise InputError(f"weights must be non-negative with shape ({M},) or ({B}, {M}), got {tuple(w.shape)}")

    warp = FluidWarp(grid, steps, dt, viscosity, image_size=(H, W), compressible=compressible).to(device, dtype)
    module = ControlGrid(steps, control, batch=B) if forces is None else forces
    module = module.to(device, dtype)
    params = [p for p in module.parameters() if p.requires_grad]
    if not params:
        raise InputError("the force module has no trainable parameters")

    # the stop criterion reads the points that the evaluation it judges carried
    last: dict[str, Tensor] = {}

    def objective() -> Tensor:
        vel = warp.rollout(module, (H, W)).velocities
        paths = warp.simulator.layout.trajectories(vel.expand(B, *vel.shape[1:]), src, dt, (H, W))  # (B, T+1, M, 2) px
        last["paths"] = paths.detach()
        loss = keyframe_loss(paths, keyframes, w)
        if smoothness > 0:
            loss = loss + smoothness * velocity_gradient_energy(vel)
        if regularization > 0:
            loss = loss + regularization * sum((p**2).sum() for p in params)
        return loss

    def targets_met(_loss: float) -> bool:
        paths = last["paths"]
        return max(float((paths[:, t] - q).norm(dim=-1).max()) for t, q in keyframes) <= tolerance

    start = time.perf_counter()
    # the start's model: the points' residuals alone, a viscosity that is one number, a control grid
    uniform = None if isinstance(viscosity, (bool, Tensor, nn.Module)) else float(viscosity)
    newton = None
    if method == "auto" and regularization == smoothness == 0 and uniform is not None:
        grid_module = startable_control(warp, module, B, len(keyframes), M, uniform)
        if grid_module is not None:
            # max_iter bounds the start too: one roll-out per iteration, the first one's included
            forwards = min(MAX_FORWARDS, max_iter + 1)
            newton = newton_start(
                warp, grid_module, src, keyframes, w, tolerance, (H, W), uniform, forwards, progress=progress
            )
    paths: Tensor | None = None
    if newton is not None and newton.reached:  # its last roll-out's paths are those of the controls it leaves
        history, evaluations, converged, how, paths = newton.loss_history, 0, True, newton.message, newton.paths
    else:
        result = minimize(
            objective,
            params,
            max_iter=max_iter,
            stop=targets_met,
            progress=progress,
            desc="fit_keyframes",
            undefined=(FlowBlewUp,),  # a trial step whose flow blew up was too long: restart from the best one
            # after the quasi-Newton start, L-BFGS' first run can stall early in a rough stretch (its line search
            # fails); one fresh run from the best controls goes on from there
            stall_restarts=0 if newton is None else 1,
        )
        history = ([] if newton is None else newton.loss_history) + list(result.loss_history)
        evaluations, converged = result.evaluations, result.converged
        how = result.message if newton is None else f"{newton.message}; {result.message}"
    if paths is None:
        with torch.no_grad():
            paths = warp.carry_points(src, module)
    kf_err = [(t, (paths[:, t] - q).norm(dim=-1)) for t, q in keyframes]
    reached = all(bool(e.max() <= tolerance) for _, e in kf_err)
    err = kf_err[-1][1]
    message = (
        f"{'reached' if reached else 'did not reach'} the targets (within {tolerance:g} px): mean error "
        f"{float(err.mean()):.4f} px, max {float(err.max()):.4f} px{_worst_keyframe(kf_err)}; {how}"
    )
    return KeyframeFit(
        forces=module,
        warp=warp,
        points=paths[:, -1],
        trajectories=paths,
        error=err,
        keyframe_errors=kf_err,
        loss_history=history,
        evaluations=evaluations,
        forwards=0 if newton is None else newton.forwards,
        seconds=time.perf_counter() - start,
        converged=converged,
        reached=reached,
        message=message,
    )
