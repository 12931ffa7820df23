"""The one L-BFGS driver behind :func:`~torchfluidwarp.control.keyframes.fit_keyframes` and
:func:`~torchfluidwarp.control.images.fit_images`.

:func:`minimize` builds ``torch.optim.LBFGS`` with a strong-Wolfe line search and one history size, runs the
closure (clear the gradients, evaluate under ``enable_grad``, backpropagate), keeps the best iterate and puts it
back at the end, and shows one tqdm bar that counts L-BFGS iterations up to ``max_iter``. Its NaN policy: a
non-finite loss, or non-finite parameters after a line-search step, ends the fit with ``converged=False`` and a
message saying so, and the best finite iterate is restored. A trial point where the objective is undefined (it
raised one of ``undefined``: for the fits, a flow that blew up) is a step too long: L-BFGS starts afresh from the
best iterate, whose first step is short, at most :data:`MAX_RESTARTS` times; with ``stall_restarts``, so does a run
that stops on its own short of ``stop``. An optional ``stop`` callback ends the fit early with ``converged=True``
(the keyframe fit stops once every point is within tolerance).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor
from tqdm.auto import tqdm

from torchfluidwarp._checks import all_finite, check_int, check_positive, check_returned_loss, describe
from torchfluidwarp.errors import InputError, InputTypeError

__all__ = ["OptimResult", "minimize", "HISTORY_SIZE", "MAX_RESTARTS"]

HISTORY_SIZE = 100
"""L-BFGS memory: ``benchmarks/bench_keyframes.py``'s median evaluations fell from 48 (with 20) to 39."""

MAX_RESTARTS = 4
"""How often :func:`minimize` starts L-BFGS afresh from its best iterate after a trial point where the objective
is undefined; the next such point ends the fit with ``converged=False``."""


@dataclass(frozen=True)
class OptimResult:
    """The result of :func:`minimize`.

    Attributes:
        loss_history: the objective at every completed evaluation, in order (a non-finite value that stopped
            the fit is not included).
        evaluations: completed objective-and-gradient evaluations (``len(loss_history)``).
        iterations: L-BFGS iterations, at most ``max_iter`` (over all restarts).
        restarts: fresh starts of L-BFGS after trial points where the objective was undefined.
        converged: ``stop`` returned True, or L-BFGS stopped on its own criterion (gradient or change below
            its tolerance) before ``max_iter`` iterations and ``max_eval`` evaluations. False when the fit ran
            out of iterations or evaluations, met a non-finite loss or parameter, or an undefined point after
            :data:`MAX_RESTARTS` restarts.
        message: a one-line reason for stopping.
        seconds: wall time of the fit, from after the optimiser is built.
        best_loss: the smallest finite loss seen, that of the restored parameters (``inf`` if none was finite).
    """

    loss_history: tuple[float, ...]
    evaluations: int
    iterations: int
    converged: bool
    message: str
    seconds: float
    best_loss: float
    restarts: int = 0


class _LBFGS(torch.optim.LBFGS):
    """``torch.optim.LBFGS`` itself, built without importing ``torch._dynamo``.

    ``Optimizer.add_param_group`` (called by the constructor) and ``zero_grad`` are wrapped in torch's
    ``_disable_dynamo``, whose first call in a process imports ``torch._dynamo``: about 1.2 s, more than a whole
    warm keyframe fit, paid by every CLI run and demo. The wrapper only keeps ``torch.compile`` from tracing the
    method, and nothing here is compiled, so the group is added by the undecorated method (``functools.wraps``
    keeps it as ``__wrapped__``) and :func:`minimize` clears gradients itself. L-BFGS' step and line search are
    torch's, unchanged. Should a future torch drop ``__wrapped__``, the decorated method is used.
    """

    def add_param_group(self, param_group: dict) -> None:  # type: ignore[override]
        add = getattr(torch.optim.Optimizer.add_param_group, "__wrapped__", torch.optim.Optimizer.add_param_group)
        add(self, param_group)


class _Halt(Exception):
    """Raised inside the closure to leave ``LBFGS.step``; ``reason`` is ``"stop"`` or a non-finite cause."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def minimize(
    objective: Callable[[], Tensor],
    params: Sequence[Tensor],
    *,
    max_iter: int,
    stop: Callable[[float], bool] | None = None,
    progress: bool = False,
    desc: str = "minimize",
    history_size: int = HISTORY_SIZE,
    max_eval: int | None = None,
    tolerance_grad: float = 1e-12,
    tolerance_change: float = 1e-14,
    undefined: tuple[type[Exception], ...] = (),
    stall_restarts: int = 0,
) -> OptimResult:
    """Minimise ``objective()`` over ``params`` in place with L-BFGS (strong-Wolfe line search).

    Args:
        objective: a function of no arguments returning the scalar loss (a 0-d tensor) for the current values
            of ``params``. It is called under ``torch.enable_grad``, so the fit also works inside ``no_grad``.
        params: the leaf tensors to optimise (each ``requires_grad``), updated in place. At the end they hold
            the best finite iterate seen (the initial values if no evaluation was finite).
        max_iter: L-BFGS iterations at most; the progress bar counts them.
        stop: optional ``stop(loss) -> bool``, called after every evaluation that improves on the best loss so
            far (so the iterate it judges is the one kept); True ends the fit with ``converged=True``. It may
            read what the objective left behind for this evaluation, e.g. the points it carried.
        progress: show a tqdm bar of iterations, with the loss and the evaluation count.
        desc: the bar's label.
        history_size: L-BFGS memory (pairs of steps and gradient changes kept).
        max_eval: evaluation budget (default ``2 * max_iter``); a line search may overshoot it by a few.
        tolerance_grad: L-BFGS stops when the largest gradient entry is at most this.
        tolerance_change: L-BFGS stops when a step or the loss changes by at most this.
        undefined: exception types by which ``objective`` says that it is undefined at the current values (the
            fits pass :class:`~torchfluidwarp.errors.FlowBlewUp`). At a trial point, L-BFGS restarts from
            the best iterate (see :data:`MAX_RESTARTS`); at the starting point the exception propagates.
        stall_restarts: how many times L-BFGS starts afresh from the best iterate when it stops on its own
            criterion before ``stop`` is met and budget remains (default 0). A fresh start forgets the curvature
            pairs and takes a short first step, which gets past a line search that failed in a rough stretch
            of the objective; one that makes no progress costs one iteration's line search.

    Returns:
        an :class:`OptimResult`.

    Raises:
        InputError: ``params`` empty or holding a tensor that does not require grad; non-positive
            ``max_iter``, ``history_size`` or tolerances; an ``objective`` that returns more than one number, or a
            tensor without an autograd graph (detached, or computed under ``no_grad``).
        InputTypeError: ``params`` holding something other than a tensor; an ``objective`` that returns no tensor.
        Exception: one of ``undefined``, raised by the objective at the starting point.

    Example:
        >>> x = torch.zeros(2, dtype=torch.float64, requires_grad=True)
        >>> res = minimize(lambda: ((x - torch.tensor([1.0, -2.0], dtype=torch.float64)) ** 2).sum(), [x], max_iter=20)
        >>> res.converged, [round(v, 6) for v in x.tolist()]
        (True, [1.0, -2.0])
    """
    params = list(params)
    if not params:
        raise InputError("params must hold at least one tensor, got none", argument="params")
    for i, p in enumerate(params):
        if not isinstance(p, Tensor):
            raise InputTypeError(f"params[{i}] must be a tensor, got {describe(p)}", argument="params")
        if not p.requires_grad:
            raise InputError(
                f"params[{i}] must require grad, got {describe(p)} with requires_grad=False", argument="params"
            )
    max_iter = check_int("max_iter", max_iter)
    history_size = check_int("history_size", history_size)
    stall_restarts = check_int("stall_restarts", stall_restarts, minimum=0)
    max_eval = 2 * max_iter if max_eval is None else check_int("max_eval", max_eval)
    check_positive("tolerance_grad", tolerance_grad)
    check_positive("tolerance_change", tolerance_change)

    history: list[float] = []
    best_loss = math.inf
    best_state = [p.detach().clone() for p in params]  # the starting point, should nothing be finite
    calls = 0  # objective calls, over all restarts (max_eval's budget)
    done_iters = 0  # iterations of the L-BFGS runs before the current one
    state: dict = {}  # the current run's counters (LBFGS keeps n_iter and func_evals here)
    start = time.perf_counter()
    # each L-BFGS iteration is one or more evaluations (its line search)
    bar = tqdm(total=max_iter, desc=desc, unit="iter", disable=not progress, leave=False)

    @torch.enable_grad()
    def closure() -> Tensor:
        nonlocal best_loss, best_state, calls
        for p in params:  # optimizer.zero_grad() would import torch._dynamo (see _LBFGS)
            p.grad = None
        if not all(all_finite(p) for p in params):
            raise _Halt("the parameters became non-finite (a line-search step overflowed)")
        calls += 1
        loss = check_returned_loss("objective", objective())
        value = float(loss.detach())
        if not math.isfinite(value):
            raise _Halt(f"the loss became non-finite ({value})")
        loss.backward()
        history.append(value)
        bar.update(min(done_iters + int(state.get("n_iter", 0)), max_iter) - bar.n)
        bar.set_postfix(loss=f"{value:.4g}", evals=len(history))
        if value < best_loss:
            best_loss = value
            best_state = [p.detach().clone() for p in params]
            if stop is not None and stop(value):
                raise _Halt("stop")
        return loss

    def restore_best() -> None:
        with torch.no_grad():
            for p, v in zip(params, best_state):
                p.copy_(v)

    halt: str | None = None
    restarts = stalls = 0
    try:
        while done_iters < max_iter and calls < max_eval:
            restore_best()  # each run starts from the best iterate (the first: the starting values)
            optimizer = _LBFGS(
                params,
                lr=1.0,
                max_iter=max_iter - done_iters,
                max_eval=max_eval - calls,
                history_size=history_size,
                tolerance_grad=tolerance_grad,
                tolerance_change=tolerance_change,
                line_search_fn="strong_wolfe",
            )
            state = optimizer.state[params[0]]
            try:
                optimizer.step(closure)
            except _Halt as e:
                halt = e.reason
            except undefined as e:
                if not history:  # the starting point itself: the caller's values, not a step too long
                    raise
                if restarts < MAX_RESTARTS:  # a fresh L-BFGS from the best iterate, whose first step is short
                    restarts += 1
                    continue
                halt = f"the objective was undefined ({type(e).__name__}) at a trial point after {restarts} restarts"
            finally:
                done_iters += int(state.get("n_iter", 0))
            if halt is None and stalls < stall_restarts and done_iters < max_iter and calls < max_eval:
                stalls += 1  # L-BFGS stopped on its own short of `stop`: once more, afresh, from the best iterate
                continue
            break
    finally:
        iterations = min(done_iters, max_iter)
        bar.update(iterations - bar.n)
        bar.close()
    restore_best()

    again = f", {restarts} restart{'s' if restarts != 1 else ''}" if restarts else ""
    again += f", {stalls} fresh start{'s' if stalls != 1 else ''} after a stall" if stalls else ""
    done = f"after {iterations} iterations ({len(history)} evaluations{again}), best loss {best_loss:.6g}"
    if halt == "stop":
        converged, message = True, f"converged: the stop criterion was met {done}"
    elif halt is not None:
        converged = False
        message = f"did not converge: {halt} {done}; restored the best finite iterate"
    elif iterations >= max_iter:
        converged, message = False, f"did not converge: reached max_iter={max_iter} {done}"
    elif calls >= max_eval:
        converged, message = False, f"did not converge: used the evaluation budget max_eval={max_eval} {done}"
    else:
        converged, message = True, f"converged: L-BFGS made no further progress {done}"
    return OptimResult(
        loss_history=tuple(history),
        evaluations=len(history),
        iterations=iterations,
        converged=converged,
        message=message,
        seconds=time.perf_counter() - start,
        best_loss=best_loss,
        restarts=restarts,
    )
