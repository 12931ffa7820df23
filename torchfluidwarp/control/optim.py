"""The one L-BFGS driver behind :func:`~torchfluidwarp.control.keyframes.fit_keyframes` and
:func:`~torchfluidwarp.control.images.fit_images`.

:func:`minimize` builds ``torch.optim.LBFGS`` with a strong-Wolfe line search and one history size, runs the
closure (zero the gradients, evaluate under ``enable_grad``, backpropagate), keeps the best iterate and puts it
back at the end, and shows one tqdm bar that counts L-BFGS iterations up to ``max_iter``. Its NaN policy: a
non-finite loss, or non-finite parameters after a line-search step, ends the fit with ``converged=False`` and a
message saying so, and the best finite iterate is restored. An optional ``stop`` callback ends the fit early
with ``converged=True`` (the keyframe fit stops once every point is within tolerance).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor
from tqdm.auto import tqdm

from torchfluidwarp._checks import all_finite, check_int, check_positive, describe

__all__ = ["OptimResult", "minimize", "HISTORY_SIZE"]

HISTORY_SIZE = 100
"""L-BFGS memory: ``benchmarks/bench_keyframes.py``'s median evaluations fell from 48 (with 20) to 39."""


@dataclass(frozen=True)
class OptimResult:
    """The result of :func:`minimize`.

    Attributes:
        loss_history: the objective at every completed evaluation, in order (a non-finite value that stopped
            the fit is not included).
        evaluations: completed objective-and-gradient evaluations (``len(loss_history)``).
        iterations: L-BFGS iterations, at most ``max_iter``.
        converged: ``stop`` returned True, or L-BFGS stopped on its own criterion (gradient or change below
            its tolerance) before ``max_iter`` iterations and ``max_eval`` evaluations. False when the fit ran
            out of iterations or evaluations, or met a non-finite loss or parameter.
        message: a one-line reason for stopping.
        seconds: wall time of the fit.
        best_loss: the smallest finite loss seen, that of the restored parameters (``inf`` if none was finite).
    """

    loss_history: tuple[float, ...]
    evaluations: int
    iterations: int
    converged: bool
    message: str
    seconds: float
    best_loss: float


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

    Returns:
        an :class:`OptimResult`.

    Raises:
        ValueError: ``params`` empty or holding a tensor that does not require grad; non-positive
            ``max_iter``, ``history_size`` or tolerances.
        TypeError: ``params`` holding something other than a tensor.

    Example:
        >>> x = torch.zeros(2, dtype=torch.float64, requires_grad=True)
        >>> res = minimize(lambda: ((x - torch.tensor([1.0, -2.0], dtype=torch.float64)) ** 2).sum(), [x], max_iter=20)
        >>> res.converged, [round(v, 6) for v in x.tolist()]
        (True, [1.0, -2.0])
    """
    params = list(params)
    if not params:
        raise ValueError("params must hold at least one tensor, got none")
    for i, p in enumerate(params):
        if not isinstance(p, Tensor):
            raise TypeError(f"params[{i}] must be a tensor, got {describe(p)}")
        if not p.requires_grad:
            raise ValueError(f"params[{i}] must require grad, got {describe(p)} with requires_grad=False")
    max_iter = check_int("max_iter", max_iter)
    history_size = check_int("history_size", history_size)
    max_eval = 2 * max_iter if max_eval is None else check_int("max_eval", max_eval)
    check_positive("tolerance_grad", tolerance_grad)
    check_positive("tolerance_change", tolerance_change)

    counts = {"n_iter": 0, "func_evals": 0}  # what torch.optim.LBFGS keeps in its state
    history: list[float] = []
    best_loss = math.inf
    best_state = [p.detach().clone() for p in params]  # the starting point, should nothing be finite
    start = time.perf_counter()
    # each L-BFGS iteration is one or more evaluations (its line search)
    bar = tqdm(total=max_iter, desc=desc, unit="iter", disable=not progress, leave=False)

    @torch.enable_grad()
    def closure() -> Tensor:
        nonlocal best_loss, best_state
        for p in params:
            p.grad = None
        if not all(all_finite(p) for p in params):
            raise _Halt("the parameters became non-finite (a line-search step overflowed)")
        loss = objective()
        value = float(loss.detach())
        if not math.isfinite(value):
            raise _Halt(f"the loss became non-finite ({value})")
        loss.backward()
        history.append(value)
        bar.update(min(counts["n_iter"], max_iter) - bar.n)
        bar.set_postfix(loss=f"{value:.4g}", evals=len(history))
        if value < best_loss:
            best_loss = value
            best_state = [p.detach().clone() for p in params]
            if stop is not None and stop(value):
                raise _Halt("stop")
        return loss

    halt: str | None = None
    try:
        _lbfgs(closure, params, counts, max_iter, max_eval, history_size, tolerance_grad, tolerance_change)
    except _Halt as e:
        halt = e.reason
    finally:
        iterations = min(counts["n_iter"], max_iter)
        bar.update(iterations - bar.n)
        bar.close()
    with torch.no_grad():
        for p, v in zip(params, best_state):
            p.copy_(v)

    done = f"after {iterations} iterations ({len(history)} evaluations), best loss {best_loss:.6g}"
    if halt == "stop":
        converged, message = True, f"converged: the stop criterion was met {done}"
    elif halt is not None:
        converged = False
        message = f"did not converge: {halt} {done}; restored the best finite iterate"
    elif iterations >= max_iter:
        converged, message = False, f"did not converge: reached max_iter={max_iter} {done}"
    elif counts["func_evals"] >= max_eval:
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
    )


def _flat_grad(params: list[Tensor]) -> Tensor:
    return torch.cat([p.new_zeros(p.numel()) if p.grad is None else p.grad.reshape(-1) for p in params])


def _add(params: list[Tensor], step: Any, direction: Tensor) -> None:
    offset = 0
    for p in params:
        p.add_(direction[offset : offset + p.numel()].view_as(p), alpha=step)
        offset += p.numel()


@torch.no_grad()
def _lbfgs(
    closure: Callable[[], Tensor],
    params: list[Tensor],
    counts: dict[str, int],
    max_iter: int,
    max_eval: int,
    history_size: int,
    tolerance_grad: float,
    tolerance_change: float,
) -> None:
    """``torch.optim.LBFGS(params, lr=1, line_search_fn="strong_wolfe", ...).step(closure)``, as a function.

    The same iterates, operation for operation (torch's own strong-Wolfe line search does the steps), without
    the optimiser class: building the first ``torch.optim`` optimiser of a process imports ``torch._dynamo``,
    about a second, which a one-off fit (the demo, the command line) would pay every run. ``counts`` receives
    ``n_iter`` and ``func_evals`` as the optimiser's state would; ``closure`` leaves the gradients in ``p.grad``.
    """
    from torch.optim.lbfgs import _strong_wolfe

    loss = float(closure())
    evals = 1
    counts["func_evals"] += 1
    flat_grad = _flat_grad(params)
    if flat_grad.abs().max() <= tolerance_grad:
        return
    old_dirs: list[Tensor] = []
    old_stps: list[Tensor] = []
    ro: list[Tensor] = []
    al: list[Any] = [None] * history_size  # 0-d tensors, as in torch; Any for alpha=
    h_diag: Any = 1
    d = flat_grad.neg()
    t: Any = 1.0  # a float, or a 0-d tensor from the first step's scaling and the line search
    prev_flat_grad: Tensor | None = None

    def evaluate(x: list[Tensor], step: float, direction: Tensor) -> tuple[float, Tensor]:
        _add(params, step, direction)
        value = float(closure())
        grad = _flat_grad(params)
        for p, v in zip(params, x):
            p.copy_(v)
        return value, grad

    while counts["n_iter"] < max_iter:
        counts["n_iter"] += 1
        if counts["n_iter"] > 1:  # the two-loop recursion over the kept pairs
            assert prev_flat_grad is not None
            y = flat_grad.sub(prev_flat_grad)
            s = d.mul(t)
            ys = y.dot(s)
            if ys > 1e-10:
                if len(old_dirs) == history_size:
                    old_dirs.pop(0)
                    old_stps.pop(0)
                    ro.pop(0)
                old_dirs.append(y)
                old_stps.append(s)
                ro.append(1.0 / ys)
                h_diag = ys / y.dot(y)
            q = flat_grad.neg()
            for i in range(len(old_dirs) - 1, -1, -1):
                al[i] = old_stps[i].dot(q) * ro[i]
                q.add_(old_dirs[i], alpha=-al[i])
            d = r = torch.mul(q, h_diag)
            for i in range(len(old_dirs)):
                be_i = old_dirs[i].dot(r) * ro[i]
                r.add_(old_stps[i], alpha=al[i] - be_i)
        if prev_flat_grad is None:
            prev_flat_grad = flat_grad.clone(memory_format=torch.contiguous_format)
        else:
            prev_flat_grad.copy_(flat_grad)
        prev_loss = loss
        t = min(1.0, 1.0 / flat_grad.abs().sum()) if counts["n_iter"] == 1 else 1.0
        gtd = flat_grad.dot(d)
        if gtd > -tolerance_change:
            break
        x_init = [p.clone(memory_format=torch.contiguous_format) for p in params]
        loss, flat_grad, t, ls_evals = _strong_wolfe(
            evaluate, x_init, t, d, loss, flat_grad, gtd, max_ls=max_eval - evals
        )
        _add(params, t, d)
        evals += ls_evals
        counts["func_evals"] += ls_evals
        if (
            counts["n_iter"] == max_iter
            or evals >= max_eval
            or flat_grad.abs().max() <= tolerance_grad
            or d.mul(t).abs().max() <= tolerance_change
            or abs(loss - prev_loss) < tolerance_change
        ):
            break
