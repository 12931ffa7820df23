"""A quasi-Newton start for keyframe fits: the points' residuals driven to zero with forward roll-outs only.

The keyframe objective is a sum of squared residuals, ``r(u) = sqrt(w) (p(t_k; u) - q^k)``: 2 per point and
keyframe (28 for the paper's 14 points) against hundreds of controls ``u``. L-BFGS sees only the gradient
``J^T r`` and needs some 30-40 evaluations, each a roll-out with its adjoint. With a model of the Jacobian ``J``
itself, a Levenberg-Marquardt step ``du = -J^T (J J^T + lambda I)^-1 r`` (the smallest change of ``u`` that
zeroes the linearised residuals, damped) costs one roll-out without autograd (about a third of an evaluation)
and typically meets the 0.05 px tolerance within some 10-15 of them.

The model Jacobian (:func:`model_jacobian`), for the default control (a cumulative
:class:`~torchfluidwarp.warp.forces.ControlGrid`) in a fluid whose viscosity is one number:

* the flow's response to the controls is linearised at rest, where self-advection is the identity and a step
  is its linear part ``S`` alone (diffusion and projection, :func:`rest_response`). In an inviscid,
  incompressible fluid ``S = P`` is idempotent: ``d v_t / d u_s = dt P F`` if ``s = t`` and 0 otherwise (``F``
  the control grid's upsampling onto the faces); with a viscosity or a partial projection a control also acts
  on the later steps' flow. This part is exact at ``u = 0`` (tested against autograd);
* the points' transport is linearised along their current paths, through each RK2 step's deformation
  ``I + dt grad v(mid) (I + dt/2 grad v(p))`` of the current flow (gradients by central differences over half
  a cell).

What the model leaves out (self-advection of a moving flow) is learnt from the roll-outs themselves: every
step adds Broyden's rank-one update along its direction to a correction term. An accepted step re-linearises
the model, and the correction carries over to it. A step that does not lower the objective is rejected and
the damping raised. The start stops when every point is within ``tolerance`` of its target at every keyframe, or
when it stalls: :func:`~torchfluidwarp.control.keyframes.fit_keyframes` then hands its best iterate to
L-BFGS, which finishes the fit with adjoint gradients as it did before the start existed (from that iterate
rather than from rest, so it may end elsewhere, and it was slower on one of the benchmark's instances).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn
from tqdm.auto import tqdm

from torchfluidwarp.core.fluid import faces_from_cells
from torchfluidwarp.core.grid import rescale_points, scale_factor
from torchfluidwarp.core.staggered import StaggeredGrid
from torchfluidwarp.errors import FlowBlewUp
from torchfluidwarp.warp.forces import ControlGrid, bicubic_axis
from torchfluidwarp.warp.layer import FluidWarp

__all__ = [
    "NewtonStart",
    "rest_response",
    "response_lags",
    "model_jacobian",
    "newton_start",
    "start_bytes",
    "startable_control",
    "MAX_FORWARDS",
    "PATIENCE",
    "MAX_START_BYTES",
]

MAX_FORWARDS = 40
"""Roll-outs the start may spend before it hands over to L-BFGS."""

PATIENCE = 6
"""The start hands over after this many roll-outs in a row without lowering its best objective by 10%."""

MAX_START_BYTES = 256 * 2**20
"""The most memory the start may hold (:func:`start_bytes`); a larger problem makes the fit run L-BFGS alone."""


def start_bytes(
    batch: int,
    keyframes: int,
    points: int,
    steps: int,
    control: tuple[int, int],
    grid: tuple[int, int],
    lags: int = 1,
) -> int:
    """Bytes, at 8 a value, that the start holds for ``batch`` problems of ``points`` points at ``keyframes``
    keyframes, with a control grid of ``control`` over ``steps`` steps on a fluid ``grid`` ``(h, w)``:

    * three Jacobians (the model, its correction and their sum), each ``batch x residuals x controls``;
    * the ``lags`` rest responses of the unit controls, and their copy laid out for sampling;
    * those responses sampled at every step's points and midpoints, twice (:func:`model_jacobian`).

    ``lags`` is :func:`response_lags`: 1 in an inviscid fluid with a plain or no projection, ``steps``
    otherwise.
    """
    controls = 2 * control[0] * control[1]
    jacobians = 3 * batch * (2 * keyframes * points) * (controls * steps)
    responses = 2 * lags * controls * 2 * (grid[0] + 1) * (grid[1] + 1)
    samples = 2 * (lags * controls) * (batch * steps * 2 * points) * 2
    return 8 * (jacobians + responses + samples)


def startable_control(
    warp: FluidWarp, module: nn.Module, batch: int, keyframes: int, points: int, viscosity: float
) -> ControlGrid | None:
    """``module`` if the start's model knows it (a plain cumulative control grid of ``batch`` problems: the
    default, or a previous fit's to warm-start) and the start would hold at most :data:`MAX_START_BYTES`
    (:func:`start_bytes`) for ``points`` points at ``keyframes`` keyframes in ``warp``'s fluid; otherwise None."""
    if not (type(module) is ControlGrid and module.cumulative and module.weight.shape[0] == batch):
        return None
    ky, kx = module.weight.shape[-2:]
    lags = response_lags(warp, viscosity)
    need = start_bytes(batch, keyframes, points, warp.steps, (ky, kx), warp.grid.shape, lags)
    return module if need <= MAX_START_BYTES else None


@dataclass
class NewtonStart:
    """What :func:`newton_start` did.

    Attributes:
        forwards: roll-outs run (each without autograd), the first at the starting controls included.
        loss_history: the objective (pixels^2) after each roll-out that ran to the end.
        reached: every point is within the tolerance of its target at every keyframe.
        message: why the start stopped.
        paths: ``(B, T + 1, M, 2)`` the points' paths under the controls left in the module, pixels.
    """

    forwards: int = 0
    loss_history: list[float] = field(default_factory=list)
    reached: bool = False
    message: str = ""
    paths: Tensor | None = None


def rest_response(
    warp: FluidWarp,
    control: tuple[int, int],
    viscosity: float = 0.0,
    *,
    device: torch.device | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """How the flow at rest answers each unit control value, step by step: ``(L, 2 K_y K_x, 2, h + 1, w + 1)``.

    With ``Z_k = S^k (dt F e_j)``, the flow ``k`` steps after a unit force at rest (``S`` the step's linear
    part, :meth:`~torchfluidwarp.core.simulator.StableFluidsStep.relax`: diffusion, then the projection as the
    warp's ``compressible`` weighs it; ``F`` the :class:`~torchfluidwarp.warp.forces.ControlGrid` upsampling of
    basis vector ``e_j`` onto the faces), entry ``k - 1`` is ``G_k = Z_k - Z_{k-1}``: the change of the flow at
    step ``t`` per unit change of a cumulative control ``u_s``, ``k = t - s + 1``. Cells per time unit per unit
    control; exact at rest, where self-advection is the identity. Without viscosity and with a plain or no
    projection, ``S`` is idempotent and ``L = 1`` (only ``G_1`` is non-zero); otherwise ``L = T`` steps.
    """
    ky, kx = control
    h, w = warp.grid.shape
    basis = torch.eye(2 * ky * kx, device=device, dtype=dtype).view(-1, 2, ky, kx)
    ry, rx = (
        bicubic_axis(ky, h, device=basis.device, dtype=dtype),
        bicubic_axis(kx, w, device=basis.device, dtype=dtype),
    )
    step = warp.simulator.step
    z = step.relax(warp.dt * faces_from_cells(ry @ basis @ rx.T), viscosity)[0]
    if response_lags(warp, viscosity) == 1:
        return z.unsqueeze(0)
    lags = [z]
    for _ in range(warp.steps - 1):
        lags.append(step.relax(lags[-1], viscosity)[0])
    zs = torch.stack(lags)
    return torch.cat([zs[:1], zs.diff(dim=0)])


def response_lags(warp: FluidWarp, viscosity: float) -> int:
    """How many steps of :func:`rest_response` matter: 1 when a step's linear part is idempotent (no viscosity,
    and a plain or no projection), ``warp.steps`` otherwise."""
    return 1 if viscosity == 0 and warp.simulator.step.keep_divergence in (0.0, 1.0) else warp.steps


def _velocity_and_gradient(grid: StaggeredGrid, extended: Tensor, points: Tensor) -> tuple[Tensor, Tensor]:
    """Velocity ``(N, M, 2)`` and its gradient ``(N, M, 2, 2)`` (``[..., i, j] = d v_i / d x_j``, central
    differences over half a cell) at points ``(N, M, 2)`` in cells, of velocities ``(N, 2, h + 1, w + 1)``
    given as ``grid.extend`` of them. Unchecked: internal, on the roll-outs' finite velocities and points."""
    M = points.shape[1]
    e = points.new_tensor([[0.0, 0.0], [0.5, 0.0], [-0.5, 0.0], [0.0, 0.5], [0.0, -0.5]])
    at = grid.velocity_at(extended, (points.unsqueeze(1) + e.view(1, 5, 1, 2)).flatten(1, 2))
    at = at.unflatten(1, (5, M))
    grad = torch.stack([at[:, 1] - at[:, 2], at[:, 3] - at[:, 4]], dim=-1)  # the offsets are one cell apart
    return at[:, 0], grad


def model_jacobian(
    response: Tensor,
    velocities: Tensor,
    paths: Tensor,
    times: Sequence[int],
    size: tuple[int, int],
    dt: float,
    extended: Tensor | None = None,
) -> Tensor:
    """The model Jacobian of the points at ``times`` with respect to a cumulative control grid's weights.

    Args:
        response: :func:`rest_response` ``(L, P1, 2, h + 1, w + 1)``, ``P1 = 2 K_y K_x``.
        velocities: the current roll-out's staggered velocities ``(B, T, 2, h + 1, w + 1)``.
        paths: the points' current paths ``(B, T + 1, M, 2)``, pixels.
        times: the keyframe steps, each in ``1..T``.
        size: ``(H, W)`` of the pixel frame. dt: the time step.
        extended: the response prepared for sampling once (``StaggeredGrid.extend(response.flatten(0, 1))``), when the
            same response serves many calls; made here otherwise.

    Returns:
        ``(B, len(times), M, 2, T * P1)``: pixels per unit weight, columns in the order of
        ``ControlGrid.weight[b].flatten()``.
    """
    B, T = velocities.shape[:2]
    L, P1 = response.shape[:2]
    M = paths.shape[2]
    grid = StaggeredGrid.of(velocities)
    c = scale_factor(size, grid.grid.shape, device=paths.device, dtype=paths.dtype)
    p = rescale_points(paths[:, :-1].flatten(0, 1), c)  # (B T, M, 2): where each step starts, cells
    flow = grid.extend(velocities.flatten(0, 1))  # once, for the starting points and the midpoints
    vp, gp = _velocity_and_gradient(grid, flow, p)
    mid = p + 0.5 * dt * vp
    _, gm = _velocity_and_gradient(grid, flow, mid)
    eye = torch.eye(2, dtype=p.dtype, device=p.device)
    deform = (eye + dt * gm @ (eye + 0.5 * dt * gp)).view(B, T, M, 2, 2)
    # the responses at the starting points and the midpoints of every step: (L P1, B T 2M, 2)
    extended = grid.extend(response.flatten(0, 1)) if extended is None else extended
    z = grid.velocity_at(extended, torch.cat([p, mid], dim=1).flatten(0, 1).expand(L * P1, -1, -1))
    z = z.view(L * P1, B * T, 2, M, 2).permute(1, 2, 3, 4, 0)  # (B T, start|mid, M, 2, L P1)
    source = (dt * (z[:, 1] + 0.5 * dt * gm @ z[:, 0])).view(B, T, M, 2, L, P1)
    # forward accumulation of d p_t / d u: D_t = deform_t D_{t-1}, plus step t's sources, lag k = t - s + 1 in
    # the column block of control s
    D = p.new_zeros(B, M, 2, T, P1)
    wanted, at_time = set(times), {}
    for t in range(T):
        D = torch.einsum("bmij,bmjsp->bmisp", deform[:, t], D)
        lags = min(L, t + 1)
        D[:, :, :, t + 1 - lags : t + 1] += source[:, t, :, :, :lags].flip(-2)
        if t + 1 in wanted:
            at_time[t + 1] = D  # the next step makes a new D: this one stays as it is
    J = torch.stack([at_time[t] for t in times], dim=1)  # (B, K, M, 2, T, P1) cells
    return (J / c.view(1, 1, 1, 2, 1, 1)).flatten(-2)  # pixels


def _damped_step(J: Tensor, r: Tensor, lam: Tensor) -> Tensor:
    """The Levenberg-Marquardt step ``du = -(J^T J + mu I)^-1 J^T r = -J^T (J J^T + mu I)^-1 r`` ``(B, P)`` of
    ``J`` ``(B, R, P)`` and ``r`` ``(B, R)``, with ``mu = lam ||J||_F^2 / R``: solved in the residuals' space when
    there are fewer residuals than controls (the usual case), in the controls' otherwise."""
    R, P = J.shape[1:]
    mu = (lam * (J**2).sum((1, 2)) / R).clamp_min(torch.finfo(J.dtype).tiny).view(-1, 1, 1)
    Jt = J.transpose(1, 2)
    if R <= P:
        eye = torch.eye(R, dtype=J.dtype, device=J.device)
        return -(Jt @ torch.linalg.solve(J @ Jt + mu * eye, r.unsqueeze(-1))).squeeze(-1)
    eye = torch.eye(P, dtype=J.dtype, device=J.device)
    return -torch.linalg.solve(Jt @ J + mu * eye, Jt @ r.unsqueeze(-1)).squeeze(-1)


def newton_start(
    warp: FluidWarp,
    module: ControlGrid,
    source: Tensor,
    keyframes: Sequence[tuple[int, Tensor]],
    weights: Tensor,
    tolerance: float,
    size: tuple[int, int],
    viscosity: float = 0.0,
    max_forwards: int = MAX_FORWARDS,
    patience: int = PATIENCE,
    progress: bool = False,
) -> NewtonStart:
    """Move ``module.weight`` in place towards controls that carry ``source`` onto the keyframes' targets.

    Damped Gauss-Newton steps on the model Jacobian (see the module doc), one roll-out without autograd each.
    Each problem of the batch accepts or rejects its own steps, keeps its own damping, and stops moving once
    it meets its targets while the others go on. At the end
    ``module.weight`` holds each problem's best iterate (the one with the smallest objective). Roll-outs that
    blow up count as rejected steps. Inputs are not checked: :func:`~torchfluidwarp.control.keyframes.fit_keyframes`
    validates them and calls this.

    Args:
        warp: the fit's :class:`~torchfluidwarp.warp.layer.FluidWarp` (its grid, steps and ``dt``).
        module: a cumulative :class:`~torchfluidwarp.warp.forces.ControlGrid`, ``weight`` ``(B, T, 2, K_y, K_x)``
            in cells per time unit^2, the starting controls.
        source: ``(B, M, 2)`` points ``(x, y)`` in pixels of an image of ``size``.
        keyframes: ``(time_step, targets (B, M, 2))`` pairs, pixels, ``1 <= time_step <= T``.
        weights: ``(B, M)`` non-negative weights of the points in the objective.
        tolerance: pixels; the start stops once every point is this close to its target at every keyframe.
        size: ``(H, W)`` pixels. viscosity: the warp's, a number (cells^2 per time unit).
        max_forwards: roll-outs at most (:data:`MAX_FORWARDS`).
        patience: roll-outs in a row without a 10% lower objective before it gives up (:data:`PATIENCE`).
        progress: show a tqdm bar of roll-outs, with the objective (pixels^2) of the accepted controls.

    Returns:
        a :class:`NewtonStart`.
    """
    B, T = module.weight.shape[:2]
    dt = warp.dt
    times = [t for t, _ in keyframes]
    targets = torch.stack([q for _, q in keyframes], dim=1)  # (B, K, M, 2)
    sqrt_w = weights.sqrt().view(B, 1, -1, 1)
    ky, kx = module.weight.shape[-2:]
    response = rest_response(warp, (ky, kx), viscosity, device=source.device, dtype=source.dtype)
    layout = warp.simulator.layout
    extended = layout.extend(response.flatten(0, 1))
    lm = torch.float64  # the small linear algebra, whatever the fit's dtype

    def roll() -> tuple[Tensor, Tensor]:
        with torch.no_grad():
            vel = warp.rollout(module, size).velocities
            return vel, layout.trajectories(vel.expand(B, *vel.shape[1:]), source, dt, size)

    def residual(paths: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        diff = paths[:, times] - targets  # (B, K, M, 2)
        r = (sqrt_w * diff).flatten(1).to(lm)
        return r, 0.5 * (r**2).sum(1), diff.norm(dim=-1).flatten(1).amax(1) <= tolerance

    def jacobian(vel: Tensor, paths: Tensor) -> Tensor:  # (B, residuals, P), weighted as the residuals
        J = model_jacobian(response, vel.expand(B, *vel.shape[1:]), paths, times, size, dt, extended).to(lm)
        return (J * sqrt_w.unsqueeze(-1).to(lm)).flatten(1, 3)

    result = NewtonStart()
    bar = tqdm(total=max_forwards, desc="quasi-Newton start", unit="roll-out", disable=not progress, leave=False)
    vel, paths = roll()
    result.forwards = 1
    r, loss, met = residual(paths)
    result.loss_history.append(float(loss.sum()))
    bar.update(1)
    u = module.weight.detach().flatten(1).to(lm, copy=True)  # (B, P), not a view: the weight is written below
    lam = torch.full((B,), 0.1, dtype=lm, device=u.device)
    best, stalled = float(loss.sum()), 0
    J = jacobian(vel, paths)
    correction = torch.zeros_like(J)
    kept = paths  # the paths of each problem's accepted controls
    while not bool(met.all()) and result.forwards < max_forwards and stalled < patience:
        du = torch.where(met.view(B, 1), 0.0, _damped_step(J, r, lam))  # a problem that met its targets rests
        with torch.no_grad():
            module.weight.copy_((u + du).view_as(module.weight))
        result.forwards += 1
        try:
            vel, paths = roll()
        except FlowBlewUp:  # the flow blew up or needs too many sub-steps: a step far too long
            accepted = torch.zeros(B, dtype=torch.bool, device=u.device)
            r_new = None
        else:
            r_new, loss_new, met_new = residual(paths)
            result.loss_history.append(float(loss_new.sum()))
            accepted = loss_new < loss  # False for a NaN
            # Broyden's rank-one update along the step (where the roll-out gave finite residuals), kept as a
            # correction to the model that outlives its re-linearisation
            finite = torch.isfinite(r_new).all(1).view(B, 1, 1)
            miss = torch.nan_to_num(r_new - r - (J @ du.unsqueeze(-1)).squeeze(-1), nan=0.0, posinf=0.0, neginf=0.0)
            step2 = (du**2).sum(1).clamp_min(torch.finfo(lm).tiny).view(B, 1, 1)
            update = torch.where(finite, miss.unsqueeze(-1) * du.unsqueeze(1) / step2, 0.0)
            J, correction = J + update, correction + update
        lam = torch.where(accepted, lam / 3, lam * 4)
        if r_new is not None and bool(accepted.any()):  # the problems of the batch that moved on re-linearise
            keep = accepted.view(B, 1)
            u, r = torch.where(keep, u + du, u), torch.where(keep, r_new, r)
            loss, met = torch.where(accepted, loss_new, loss), torch.where(accepted, met_new, met)
            if not bool(met.all()):  # the next step's model; none is needed once every target is met
                J = torch.where(keep.unsqueeze(-1), jacobian(vel, paths) + correction, J)
            kept = torch.where(accepted.view(B, 1, 1, 1), paths, kept)
        total = float(loss.sum())
        bar.update(1)
        bar.set_postfix(loss=f"{total:.4g}")
        if total < 0.9 * best:
            best, stalled = total, 0
        else:
            stalled += 1
    bar.close()
    with torch.no_grad():
        module.weight.copy_(u.view_as(module.weight))
    result.reached, result.paths = bool(met.all()), kept
    how = "targets met" if result.reached else "handed over to L-BFGS"
    result.message = f"quasi-Newton start: {how} after {result.forwards} roll-outs"
    return result
