import warnings

import pytest
import torch

from torchfluidwarp.core.linalg import (
    CGConfig,
    ConvergenceError,
    ConvergenceWarning,
    conjugate_gradient,
    implicit_solve,
)


def _spd(n: int, gen: torch.Generator) -> torch.Tensor:
    a = torch.randn(n, n, generator=gen, dtype=torch.float64)
    return a @ a.T + n * torch.eye(n, dtype=torch.float64)


def _operator(x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    # A(d) = diag(d) + second-difference coupling: symmetric positive definite for d > 0
    lap = 2 * x - torch.roll(x, 1, -1) - torch.roll(x, -1, -1)
    return d * x + lap


def test_cg_solves_spd_systems_batched(gen):
    A = _spd(12, gen)
    b = torch.randn(3, 12, generator=gen, dtype=torch.float64)
    x, info = conjugate_gradient(lambda v: v @ A.T, b, config=CGConfig(rtol=1e-12))
    torch.testing.assert_close(x @ A.T, b, atol=1e-9, rtol=0)
    assert info.converged and info.iterations <= 12


def test_zero_rhs_returns_zero_at_once():
    x, info = conjugate_gradient(lambda v: 2 * v, torch.zeros(2, 5))
    assert info.iterations == 0 and torch.equal(x, torch.zeros(2, 5)) and not x.isnan().any()


def test_non_convergence_warns_or_raises(gen):
    A = _spd(30, gen)
    b = torch.randn(1, 30, generator=gen, dtype=torch.float64)
    with pytest.warns(ConvergenceWarning, match="stopped after 2 iterations"):
        conjugate_gradient(lambda v: v @ A.T, b, config=CGConfig(rtol=1e-12, max_iter=2))
    with pytest.raises(ConvergenceError):
        conjugate_gradient(lambda v: v @ A.T, b, config=CGConfig(rtol=1e-12, max_iter=2, on_failure="raise"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        conjugate_gradient(lambda v: v @ A.T, b, config=CGConfig(rtol=1e-12, max_iter=2, on_failure="ignore"))


def test_implicit_adjoint_matches_unrolled_cg(gen):
    b = torch.randn(2, 16, generator=gen, dtype=torch.float64, requires_grad=True)
    d = (torch.rand(2, 16, generator=gen, dtype=torch.float64) + 0.5).requires_grad_()
    w = torch.randn(2, 16, generator=gen, dtype=torch.float64)
    grads = {}
    for mode in ("implicit", "unrolled"):
        x, _ = implicit_solve(_operator, b, (d,), config=CGConfig(rtol=1e-14, backward=mode))
        grads[mode] = torch.autograd.grad((x * w).sum() + (x**2).sum(), (b, d))
    for gi, gu in zip(grads["implicit"], grads["unrolled"]):
        torch.testing.assert_close(gi, gu, atol=1e-8, rtol=0)


def test_implicit_solve_gradcheck(gen):
    b = torch.randn(1, 8, generator=gen, dtype=torch.float64, requires_grad=True)
    d = (torch.rand(1, 8, generator=gen, dtype=torch.float64) + 0.5).requires_grad_()
    cfg = CGConfig(rtol=1e-14)
    assert torch.autograd.gradcheck(lambda b, d: implicit_solve(_operator, b, (d,), config=cfg)[0], (b, d))


@pytest.mark.parametrize("kwargs", [{"rtol": -1.0}, {"max_iter": 0}, {"on_failure": "explode"}, {"backward": "x"}])
def test_config_rejects_bad_values(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        CGConfig(**kwargs)
