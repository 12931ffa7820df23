"""Preconditioned conjugate gradient and its implicit adjoint.

:func:`implicit_solve` solves ``A(params) x = b`` for a symmetric positive (semi-)definite operator and is
differentiable in ``b`` and in ``params``. Its forward runs CG without building a graph; its backward solves
``A lambda = grad_x`` with one more CG solve and returns ``grad_b = lambda`` and
``grad_params = -lambda^T (dA/dparams) x``, the latter as a vector-Jacobian product of the operator's own code.
Backward memory is therefore that of one operator application, whatever the number of CG iterations.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from torchfluidwarp._checks import warn
from torchfluidwarp.errors import InputError

__all__ = ["CGConfig", "CGInfo", "ConvergenceWarning", "ConvergenceError", "conjugate_gradient", "implicit_solve"]

Operator = Callable[..., Tensor]
Preconditioner = Callable[[Tensor], Tensor]


class ConvergenceWarning(RuntimeWarning):
    """A linear solve stopped at ``max_iter`` before reaching its tolerance."""


class ConvergenceError(RuntimeError):
    """A linear solve did not converge and its config asked for an error."""


@dataclass(frozen=True)
class CGConfig:
    """Settings of one conjugate-gradient solve.

    Args:
        rtol: stop when ``||r|| <= rtol * ||b||`` for every batch element. ``None`` picks a default for the
            dtype: ``1e-5`` for float32 (near its round-off floor), ``1e-12`` for float64.
        atol: absolute floor on ``||r||``.
        max_iter: iteration cap.
        on_failure: what a solve that stops at ``max_iter`` does: ``"warn"`` (a :class:`ConvergenceWarning`),
            ``"raise"`` (a :class:`ConvergenceError`) or ``"ignore"``.
        precondition: use the solve's fast exact preconditioner (``False`` runs plain CG; for comparisons).
        backward: ``"implicit"`` (the adjoint: one more CG solve, memory independent of the iterations) or
            ``"unrolled"`` (plain autograd through every CG iteration; a reference for tests and benchmarks).
        verify_exact: a solve whose preconditioner is the operator's exact inverse (the pressure solve and the
            constant-viscosity solve) returns CG's first iterate, ``M^-1 b``, which is the solution, without
            computing its residual (``CGInfo.residual`` is NaN: unchecked). ``True`` runs the full CG loop with
            its residual checks, which in float32 may add an iteration to polish round-off.

    Example:
        >>> CGConfig(rtol=1e-8, max_iter=50).tolerance(torch.float32)
        1e-08
    """

    rtol: float | None = None
    atol: float = 0.0
    max_iter: int = 200
    on_failure: Literal["warn", "raise", "ignore"] = "warn"
    precondition: bool = True
    backward: Literal["implicit", "unrolled"] = "implicit"
    verify_exact: bool = False

    def __post_init__(self) -> None:
        if self.rtol is not None and not (self.rtol >= 0):
            raise InputError(f"rtol must be >= 0, got {self.rtol!r}")
        if not (self.atol >= 0):
            raise InputError(f"atol must be >= 0, got {self.atol!r}")
        if isinstance(self.max_iter, bool) or not isinstance(self.max_iter, int) or self.max_iter < 1:
            raise InputError(f"max_iter must be an int >= 1, got {self.max_iter!r}")
        if self.on_failure not in ("warn", "raise", "ignore"):
            raise InputError(f"on_failure must be 'warn', 'raise' or 'ignore', got {self.on_failure!r}")
        if self.backward not in ("implicit", "unrolled"):
            raise InputError(f"backward must be 'implicit' or 'unrolled', got {self.backward!r}")

    def tolerance(self, dtype: torch.dtype) -> float:
        """The relative tolerance in force for ``dtype``."""
        if self.rtol is not None:
            return self.rtol
        return 1e-12 if dtype == torch.float64 else 1e-5


@dataclass(frozen=True)
class CGInfo:
    """What a CG solve did: ``iterations`` run, worst relative ``residual``, and whether it ``converged``."""

    iterations: int
    residual: float
    converged: bool


def _dot(a: Tensor, b: Tensor) -> Tensor:
    return (a * b).flatten(1).sum(1).view(-1, *([1] * (a.ndim - 1)))


def conjugate_gradient(
    matvec: Callable[[Tensor], Tensor],
    b: Tensor,
    precond: Preconditioner | None = None,
    config: CGConfig = CGConfig(),
    *,
    name: str = "linear solve",
    differentiable: bool = False,
    exact: bool = False,
) -> tuple[Tensor, CGInfo]:
    """Batched preconditioned CG for ``A x = b``, starting from zero.

    Args:
        matvec: ``x -> A x`` for ``(B, ...)`` tensors; symmetric positive (semi-)definite per batch element.
        b: ``(B, ...)`` right-hand sides; each batch element is an independent system.
        precond: ``r -> M^-1 r``, symmetric positive definite; ``None`` for none.
        config: tolerance, iteration cap and failure policy.
        name: names the solve in warnings and errors.
        differentiable: record the iterations for autograd (the unrolled reference); otherwise no graph.
        exact: ``precond`` is the exact inverse of ``matvec``: unless ``config.verify_exact``, return its
            application to ``b`` (CG's first iterate) at once, as one unchecked iteration.

    Returns:
        ``(x, info)`` with ``x`` like ``b``. A zero right-hand side returns zero at once.

    Raises:
        ConvergenceError: the solve stopped at ``max_iter`` and ``config.on_failure == "raise"``.
    """
    with torch.set_grad_enabled(differentiable and torch.is_grad_enabled()):
        if exact and precond is not None and not config.verify_exact:
            return precond(b), CGInfo(1, math.nan, True)
        b_norm = _dot(b, b).detach().sqrt()
        bound = torch.clamp(b_norm * config.tolerance(b.dtype), min=config.atol)
        x = torch.zeros_like(b)
        if not bool((b_norm > 0).any()):
            return x, CGInfo(0, 0.0, True)
        r = b.clone()
        z = precond(r) if precond is not None else r
        p = z
        rz = _dot(r, z)
        for it in range(1, config.max_iter + 1):
            Ap = matvec(p)
            pAp = _dot(p, Ap)
            alpha = torch.where(pAp > 0, rz / torch.where(pAp > 0, pAp, 1), 0)
            x = x + alpha * p
            r = r - alpha * Ap
            r_norm = _dot(r, r).detach().sqrt()
            if bool((r_norm <= bound).all()):
                return x, CGInfo(it, _relative(r_norm, b_norm), True)
            z = precond(r) if precond is not None else r
            rz_new = _dot(r, z)
            beta = torch.where(rz > 0, rz_new / torch.where(rz > 0, rz, 1), 0)
            p = z + beta * p
            rz = rz_new
        info = CGInfo(config.max_iter, _relative(r_norm, b_norm), False)
    message = (
        f"{name}: conjugate gradient stopped after {info.iterations} iterations at relative residual "
        f"{info.residual:.3g} > rtol {config.tolerance(b.dtype):.3g}"
    )
    if config.on_failure == "raise":
        raise ConvergenceError(message)
    if config.on_failure == "warn":
        warn(message, ConvergenceWarning)
    return x, info


def _relative(r_norm: Tensor, b_norm: Tensor) -> float:
    return float((r_norm / torch.where(b_norm > 0, b_norm, 1)).max())


def _use(precond: Preconditioner | None, config: CGConfig) -> Preconditioner | None:
    return precond if config.precondition else None


class _ImplicitSolve(torch.autograd.Function):
    """``x = A(params)^-1 b`` with the implicit adjoint as its backward."""

    # forward(ctx, ...) rather than a separate setup_context: with setup_context, Function.apply binds its
    # arguments through inspect.signature on every call (about 150 us per solve in an ad-hoc cProfile run)
    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        b: Tensor,
        operator: Operator,
        precond: Preconditioner | None,
        config: CGConfig,
        adjoint: CGConfig,
        name: str,
        exact: bool,
        *params: Tensor,
    ) -> tuple[Tensor, Tensor]:
        x, info = conjugate_gradient(
            lambda v: operator(v, *params), b, _use(precond, config), config, name=name, exact=exact
        )
        ctx.operator, ctx.precond, ctx.adjoint, ctx.name, ctx.exact = operator, precond, adjoint, name, exact
        iterations = torch.tensor(info.iterations)
        ctx.mark_non_differentiable(iterations)
        ctx.save_for_backward(x, *params)
        return x, iterations

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad_x: Tensor, _grad_iters: Tensor | None) -> tuple[Tensor | None, ...]:
        x, *params = ctx.saved_tensors
        lam, _ = conjugate_gradient(
            lambda v: ctx.operator(v, *params),
            grad_x.contiguous(),
            _use(ctx.precond, ctx.adjoint),
            ctx.adjoint,
            name=f"{ctx.name} (adjoint)",
            exact=ctx.exact,
        )
        grad_b = lam if ctx.needs_input_grad[0] else None
        wanted = [i for i, p in enumerate(params) if ctx.needs_input_grad[7 + i]]
        grad_params: list[Tensor | None] = [None] * len(params)
        if wanted:
            with torch.enable_grad():
                leaves = [p.detach().requires_grad_(i in wanted) for i, p in enumerate(params)]
                Ax = ctx.operator(x, *leaves)
                grads = torch.autograd.grad(Ax, [leaves[i] for i in wanted], grad_outputs=-lam, allow_unused=True)
            for i, g in zip(wanted, grads):
                grad_params[i] = torch.zeros_like(params[i]) if g is None else g
        return (grad_b, None, None, None, None, None, None, *grad_params)


def implicit_solve(
    operator: Operator,
    b: Tensor,
    params: tuple[Tensor, ...] = (),
    *,
    precond: Preconditioner | None = None,
    config: CGConfig = CGConfig(),
    adjoint_config: CGConfig | None = None,
    name: str = "linear solve",
    exact: bool = False,
) -> tuple[Tensor, int]:
    """Solve ``operator(x, *params) = b`` by preconditioned CG, differentiably, with an implicit adjoint.

    Args:
        operator: ``(x, *params) -> A(params) x``, linear and symmetric in ``x``, written in differentiable
            torch code (its vector-Jacobian product in ``params`` gives their gradient).
        b: ``(B, ...)`` right-hand side.
        params: tensors the operator depends on (e.g. a viscosity field); gradients flow to them.
        precond: ``r -> M^-1 r``; should not depend on anything that needs a gradient.
        config: settings of the forward solve.
        adjoint_config: settings of the backward solve (defaults to ``config``).
        name: names the solve in warnings and errors.
        exact: ``precond`` inverts the operator exactly (see :attr:`CGConfig.verify_exact`).

    Returns:
        ``(x, iterations)``: the solution like ``b`` and the forward CG iteration count.
    """
    if config.backward == "unrolled":
        x, info = conjugate_gradient(
            lambda v: operator(v, *params),
            b,
            _use(precond, config),
            config,
            name=name,
            differentiable=True,
            exact=exact,
        )
        return x, info.iterations
    x, iters = _ImplicitSolve.apply(b, operator, precond, config, adjoint_config or config, name, exact, *params)
    return x, int(iters)
