import math
import subprocess
import sys

import pytest
import torch

from torchfluidwarp.control.optim import MAX_RESTARTS, OptimResult, minimize
from torchfluidwarp.errors import InputError, InputTypeError


def _quadratic(gen, n=6):
    """``1/2 x^T A x - b^T x`` with a well-conditioned SPD ``A``: its minimum is at ``A^-1 b``."""
    q, _ = torch.linalg.qr(torch.randn(n, n, generator=gen, dtype=torch.float64))
    a = q @ torch.diag(torch.linspace(1.0, 10.0, n, dtype=torch.float64)) @ q.T
    b = torch.randn(n, generator=gen, dtype=torch.float64)
    return a, b


def test_a_quadratic_is_minimised_to_its_analytic_minimum(gen):
    a, b = _quadratic(gen)
    x = torch.zeros(6, dtype=torch.float64, requires_grad=True)
    res = minimize(lambda: 0.5 * x @ a @ x - b @ x, [x], max_iter=50)
    x_star = torch.linalg.solve(a, b)
    torch.testing.assert_close(x.detach(), x_star, atol=1e-8, rtol=0)
    assert res.converged and "no further progress" in res.message
    assert res.best_loss == pytest.approx(float(-0.5 * b @ x_star), abs=1e-12)
    assert res.evaluations == len(res.loss_history) and res.iterations <= 50 and res.seconds > 0


@pytest.mark.parametrize("max_iter", [1, 3, 7])
def test_max_iter_is_respected(max_iter):
    # the Rosenbrock function: far from done after a few iterations
    x = torch.tensor([-1.5, 2.0], dtype=torch.float64, requires_grad=True)
    res = minimize(lambda: (1 - x[0]) ** 2 + 100 * (x[1] - x[0] ** 2) ** 2, [x], max_iter=max_iter)
    assert 1 <= res.iterations <= max_iter
    assert not res.converged and f"max_iter={max_iter}" in res.message


def test_a_nan_loss_stops_the_fit_and_restores_the_best_finite_iterate():
    x = torch.tensor([3.0, -2.0], dtype=torch.float64, requires_grad=True)
    seen: list[torch.Tensor] = []

    def objective():
        seen.append(x.detach().clone())
        loss = ((x - 1.0) ** 2).sum() + 0.1 * (x**4).sum()
        return loss * math.nan if len(seen) > 3 else loss

    res = minimize(objective, [x], max_iter=100)
    assert not res.converged
    assert "non-finite" in res.message and "restored the best finite iterate" in res.message
    assert res.evaluations == 3 and all(math.isfinite(v) for v in res.loss_history)
    best = min(range(3), key=lambda i: res.loss_history[i])
    assert res.best_loss == res.loss_history[best]
    torch.testing.assert_close(x.detach(), seen[best], atol=0, rtol=0)


def test_a_nan_gradient_stops_the_fit_at_non_finite_parameters_and_restores_the_start():
    # torch.where's unused branch (sqrt of a negative) gives a finite loss but a NaN gradient, so the line
    # search steps to NaN parameters: the classic where-NaN trap
    x = torch.tensor([2.0, -1.0], dtype=torch.float64, requires_grad=True)
    res = minimize(lambda: (x**2).sum() + torch.where(x > 10, torch.sqrt(x - 10), 0 * x).sum(), [x], max_iter=20)
    assert not res.converged and "parameters became non-finite" in res.message
    assert res.loss_history == (5.0,) and res.best_loss == 5.0
    torch.testing.assert_close(x.detach(), torch.tensor([2.0, -1.0], dtype=torch.float64), atol=0, rtol=0)


class Undefined(Exception):
    """The objective's way of saying that it has no value at these parameters."""


def pseudo_huber(x: torch.Tensor, bound: float):
    """sqrt(1 + (x - 3)^2) summed, minimum 2 at (3, 3); undefined where some |x_i| > ``bound``. Its flat tails
    make L-BFGS' line search extrapolate far past the minimum from a start at (-8, -4)."""
    trials: list[torch.Tensor] = []

    def objective():
        trials.append(x.detach().clone())
        if float(x.detach().abs().max()) > bound:
            raise Undefined(f"|x| > {bound}")
        return torch.sqrt(1 + (x - 3) ** 2).sum()

    return objective, trials


def test_an_undefined_trial_point_restarts_from_the_best_iterate_and_the_fit_goes_on():
    x = torch.tensor([-8.0, -4.0], dtype=torch.float64, requires_grad=True)
    objective, trials = pseudo_huber(x, bound=8.0)
    with pytest.raises(Undefined):  # the unguarded driver meets the undefined region on this problem
        minimize(objective, [x], max_iter=100)

    x.data = torch.tensor([-8.0, -4.0], dtype=torch.float64)
    objective, trials = pseudo_huber(x, bound=8.0)
    res = minimize(objective, [x], max_iter=100, undefined=(Undefined,))
    assert 1 <= res.restarts <= MAX_RESTARTS and "restart" in res.message
    assert res.converged and abs(res.best_loss - 2.0) < 1e-12
    torch.testing.assert_close(x.detach(), torch.full((2,), 3.0, dtype=torch.float64), atol=1e-6, rtol=0)
    assert any(float(t.abs().max()) > 8.0 for t in trials)  # it did step into the undefined region
    assert res.evaluations == len(res.loss_history) == sum(float(t.abs().max()) <= 8.0 for t in trials)


def test_an_objective_undefined_at_the_starting_point_raises():
    x = torch.tensor([-9.0, 0.0], dtype=torch.float64, requires_grad=True)
    objective, _ = pseudo_huber(x, bound=8.0)
    with pytest.raises(Undefined):
        minimize(objective, [x], max_iter=10, undefined=(Undefined,))


def test_an_objective_undefined_at_every_trial_point_ends_after_max_restarts_at_the_start():
    start = torch.tensor([1.0, -2.0], dtype=torch.float64)
    x = start.clone().requires_grad_(True)

    def objective():
        if not torch.equal(x.detach(), start):
            raise Undefined("only the start is defined")
        return (x**2).sum()

    res = minimize(objective, [x], max_iter=50, undefined=(Undefined,))
    assert not res.converged and res.restarts == MAX_RESTARTS
    assert "undefined (Undefined)" in res.message and f"{MAX_RESTARTS} restarts" in res.message
    assert res.best_loss == 5.0 and set(res.loss_history) == {5.0}
    torch.testing.assert_close(x.detach(), start, atol=0, rtol=0)


def test_a_stalled_run_starts_afresh_from_the_best_iterate_only_when_asked_and_short_of_stop():
    # a loose tolerance_change makes L-BFGS stop on its own after a few iterations, short of the minimum
    def run(stall_restarts: int, stop_at: float):
        x = torch.tensor([-8.0, -4.0], dtype=torch.float64, requires_grad=True)
        objective, seen = pseudo_huber(x, bound=math.inf)
        res = minimize(
            objective,
            [x],
            max_iter=100,
            tolerance_change=0.05,
            stall_restarts=stall_restarts,
            stop=lambda v: v < stop_at,
        )
        return res, seen

    plain, _ = run(0, 0.0)
    again, seen = run(2, 0.0)
    assert "2 fresh starts after a stall" in again.message and "fresh start" not in plain.message
    assert again.iterations <= 100 and again.evaluations > plain.evaluations
    assert again.best_loss <= plain.best_loss
    # each fresh run begins with an evaluation at the best iterate seen before it
    first_of_second = seen[plain.evaluations]
    torch.testing.assert_close(
        first_of_second, seen[min(range(plain.evaluations), key=lambda i: again.loss_history[i])]
    )
    # stop met: nothing to start afresh for
    met, _ = run(2, 1e9)
    assert met.converged and "fresh start" not in met.message and met.evaluations == 1


def test_the_stop_callback_ends_the_fit_as_converged():
    x = torch.tensor([4.0, -3.0], dtype=torch.float64, requires_grad=True)
    calls: list[float] = []

    def stop(loss: float) -> bool:
        calls.append(loss)
        return loss < 1.0

    res = minimize(lambda: (x**2).sum(), [x], max_iter=100, stop=stop, tolerance_change=1e-300)
    assert res.converged and "stop criterion" in res.message
    assert calls[-1] == res.best_loss < 1.0 and float((x.detach() ** 2).sum()) == res.best_loss
    # it is asked only about improvements, each better than the last
    assert all(b < a for a, b in zip(calls, calls[1:]))


def test_the_best_iterate_is_restored_not_the_last():
    # a loss that grows with the evaluation count after the first: L-BFGS ends on a worse point
    x = torch.tensor([2.0], dtype=torch.float64, requires_grad=True)
    count = [0]
    first: list[torch.Tensor] = []

    def objective():
        count[0] += 1
        if count[0] == 1:
            first.append(x.detach().clone())
        return (x**2).sum() + (0.0 if count[0] == 1 else 100.0 * count[0])

    res = minimize(objective, [x], max_iter=5)
    assert res.best_loss == res.loss_history[0] < min(res.loss_history[1:])
    torch.testing.assert_close(x.detach(), first[0], atol=0, rtol=0)


def test_it_works_under_no_grad_and_the_result_is_frozen():
    x = torch.tensor([1.0], requires_grad=True)
    with torch.no_grad():
        res = minimize(lambda: ((x - 2.0) ** 2).sum(), [x], max_iter=10)
    assert isinstance(res, OptimResult) and abs(float(x.detach()) - 2.0) < 1e-4
    with pytest.raises(AttributeError):
        res.converged = False  # type: ignore[misc]


@pytest.mark.parametrize(
    "params, kwargs, error, match",
    [
        ([], {}, ValueError, "at least one tensor"),
        ([torch.zeros(2)], {}, ValueError, "must require grad"),
        (["x"], {}, TypeError, r"params\[0\] must be a tensor"),
        (None, {"max_iter": 0}, ValueError, "max_iter must be >= 1"),
        (None, {"history_size": 0}, ValueError, "history_size must be >= 1"),
        (None, {"stall_restarts": -1}, ValueError, "stall_restarts must be >= 0"),
    ],
)
def test_bad_arguments(params, kwargs, error, match):
    x = torch.zeros(2, requires_grad=True)
    with pytest.raises(error, match=match):
        minimize(lambda: (x**2).sum(), [x] if params is None else params, **{"max_iter": 5, **kwargs})


def _rosenbrock(x):
    return (1 - x[0]) ** 2 + 100 * (x[1] - x[0] ** 2) ** 2


def test_the_iterates_are_those_of_torch_optim_lbfgs():
    x = torch.tensor([-1.2, 1.0], dtype=torch.float64, requires_grad=True)
    res = minimize(lambda: _rosenbrock(x), [x], max_iter=15, history_size=10)

    y = torch.tensor([-1.2, 1.0], dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS(
        [y],
        lr=1.0,
        max_iter=15,
        max_eval=30,
        history_size=10,
        tolerance_grad=1e-12,
        tolerance_change=1e-14,
        line_search_fn="strong_wolfe",
    )
    losses = []

    def closure():
        opt.zero_grad()
        loss = _rosenbrock(y)
        loss.backward()
        losses.append(float(loss.detach()))
        return loss

    opt.step(closure)
    assert res.loss_history == pytest.approx(losses, rel=1e-12, abs=1e-300)
    best = min(range(len(losses)), key=losses.__getitem__)
    assert res.best_loss == pytest.approx(losses[best], rel=1e-12)


def test_a_fit_does_not_import_torch_dynamo():
    # the first torch.optim optimiser of a process would import torch._dynamo (about 1 s, more than a fit)
    code = (
        "import sys, torch\n"
        "from torchfluidwarp.control import fit_images, fit_keyframes\n"
        "src = torch.tensor([[10.0, 10.0], [20.0, 15.0]])\n"
        "fit = fit_keyframes(src, src + 2.0, image_size=(32, 32), grid=16, steps=4, control=3, progress=False)\n"
        "assert fit.reached, fit.message\n"
        "img = torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(0))\n"
        "fit_images(img, img.roll(1, -1), grid=8, levels=None, steps=2, control=2, max_iter=3, progress=False)\n"
        "print('torch._dynamo' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize(
    ("objective", "error", "match"),
    [
        (lambda x: (x**2).sum().detach(), InputError, "objective returned a tensor without an autograd graph"),
        (lambda x: float((x**2).sum()), InputTypeError, "objective must return a tensor"),
        (lambda x: x**2, InputError, r"objective must return a scalar .* shape \(2,\)"),
    ],
)
def test_an_objective_that_cannot_be_differentiated_is_the_callers_error(objective, error, match):
    x = torch.ones(2, requires_grad=True)
    with pytest.raises(error, match=match) as info:  # not autograd's RuntimeError, which names no one
        minimize(lambda: objective(x), [x], max_iter=5)
    assert info.value.argument == "objective"
    torch.testing.assert_close(x.detach(), torch.ones(2))  # nothing was stepped
