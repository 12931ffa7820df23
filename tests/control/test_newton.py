import pytest
import torch

from torchfluidwarp.control.keyframes import fit_keyframes, keyframe_loss
from torchfluidwarp.control.newton import model_jacobian, newton_start, rest_response
from torchfluidwarp.errors import FlowBlewUp
from torchfluidwarp.warp.forces import Brushes, ControlGrid
from torchfluidwarp.warp.layer import FluidWarp

SIZE = (32, 32)
SRC = torch.tensor([[[9.0, 10.0], [21.5, 11.0], [12.0, 22.5], [22.0, 20.0], [16.0, 15.5]]], dtype=torch.float64)


def _autograd_jacobian(warp, forces, src, times):
    """Rows d p_i(t)/d weight, (K, M, 2, P), through the whole solver by autograd."""
    paths = warp.carry_points(src, forces)
    rows = torch.stack([paths[0, t] for t in times])  # (K, M, 2)
    flat = rows.flatten()
    jac = [torch.autograd.grad(flat[i], forces.weight, retain_graph=True)[0].flatten() for i in range(flat.numel())]
    return torch.stack(jac).view(*rows.shape, -1), paths.detach()


def _model(warp, forces, paths, times, viscosity=0.0, size=SIZE):
    response = rest_response(warp, tuple(forces.weight.shape[-2:]), viscosity, dtype=torch.float64)
    with torch.no_grad():
        vel = warp.rollout(forces, size).velocities
    return model_jacobian(response, vel, paths, times, size, warp.dt)[0]


@pytest.mark.parametrize(
    "compressible,viscosity,grid,size,control,dt",
    [
        (False, 0.0, 16, SIZE, (3, 3), 1.0),
        (True, 0.0, 16, SIZE, (3, 3), 1.0),
        (0.5, 0.0, 16, SIZE, (3, 3), 1.0),  # the step's linear part is no projection: every lag counts
        (False, 0.3, 16, SIZE, (3, 3), 1.0),
        (0.3, 0.2, (12, 20), (30, 44), (3, 4), 0.7),  # nothing square: x and y kept apart
    ],
)
def test_the_model_jacobian_is_exact_at_rest(compressible, viscosity, grid, size, control, dt):
    warp = FluidWarp(grid, steps=4, dt=dt, viscosity=viscosity, image_size=size, compressible=compressible)
    warp = warp.double()
    forces = ControlGrid(4, control).double()
    times = [2, 4]
    src = SRC * torch.tensor([size[1] / SIZE[1], size[0] / SIZE[0]], dtype=torch.float64)
    exact, paths = _autograd_jacobian(warp, forces, src, times)
    model = _model(warp, forces, paths, times, viscosity, size)
    assert exact.abs().max() > 0.05  # the points do respond
    torch.testing.assert_close(model, exact, atol=1e-10, rtol=1e-8)


def test_the_model_jacobian_follows_a_moving_flow(gen):
    """Away from rest the model re-linearises the points' transport along their paths, and comes closer to
    the true Jacobian than the Jacobian at rest does (what it leaves out, the flow's self-advection, Broyden's
    updates correct in the start)."""
    warp = FluidWarp(32, steps=4, image_size=SIZE).double()
    forces = ControlGrid(4, (4, 4)).double()
    rest, _ = _autograd_jacobian(warp, forces, SRC, [4])
    pattern = torch.randn(1, 1, 2, 4, 4, generator=gen, dtype=torch.float64)
    with torch.no_grad():  # a steady kick at step 0 that moves the points by pixels
        forces.weight.copy_(0.6 * pattern.expand_as(forces.weight) / pattern.abs().max())
    exact, paths = _autograd_jacobian(warp, forces, SRC, [4])
    assert float((paths[0, -1] - SRC[0]).norm(dim=-1).max()) > 1.0
    model = _model(warp, forces, paths, [4])
    err_model = float((model - exact).norm() / exact.norm())
    err_rest = float((rest - exact).norm() / exact.norm())
    assert err_model < 0.8 * err_rest, (err_model, err_rest)


def _flow_targets(steps=5, grid=32, **fluid):
    """Targets that a flow reaches: where a brush-driven flow (incompressible and inviscid by default) carries
    the sources."""
    brushes = Brushes(
        torch.tensor([[12.0, 12.0], [21.0, 20.0]]), torch.tensor([[1.0, 0.3], [-0.4, 1.0]]), radius=7.0, amplitude=0.5
    ).double()
    warp = FluidWarp(grid, steps, image_size=SIZE, **fluid).double()
    with torch.no_grad():
        end = warp.carry_points(SRC, brushes)[:, -1]
    assert float((end - SRC).norm(dim=-1).min()) > 1.0
    return end


@pytest.mark.parametrize("fluid", [{}, {"viscosity": 0.3}, {"compressible": 0.5}], ids=str)
def test_the_start_meets_reachable_targets_with_roll_outs_only(fluid):
    tgt = _flow_targets(**fluid)
    kw = dict(image_size=SIZE, grid=32, steps=5, control=(4, 4), progress=False, dtype=torch.float64, **fluid)
    fit = fit_keyframes(SRC, tgt, **kw)
    assert fit.reached and fit.converged and fit.evaluations == 0 and float(fit.error.max()) <= 0.01
    assert len(fit.loss_history) == fit.forwards and "quasi-Newton start: targets met" in fit.message
    with torch.no_grad():  # the returned forces are the ones that met the targets, on the returned paths
        replay = fit.warp.carry_points(SRC, fit.forces)
    torch.testing.assert_close(fit.trajectories, replay, rtol=0, atol=1e-12)
    assert float((replay[:, -1] - tgt).norm(dim=-1).max()) <= 0.01
    plain = fit_keyframes(SRC, tgt, method="lbfgs", **kw)
    assert plain.reached and plain.forwards == 0
    assert fit.forwards < plain.evaluations  # each a roll-out without autograd, against a roll-out with its adjoint


def test_a_batch_starts_its_problems_independently():
    tgt = _flow_targets()
    tgt2 = SRC + torch.tensor([1.5, -1.0], dtype=torch.float64)
    fit = fit_keyframes(
        SRC.expand(2, -1, -1), torch.cat([tgt, tgt2]), image_size=SIZE, grid=32, steps=5, control=(4, 4),
        progress=False, dtype=torch.float64,
    )  # fmt: skip
    assert fit.reached and fit.forwards > 0 and fit.error.shape == (2, 5) and float(fit.error.max()) <= 0.01


def test_unreachable_targets_are_handed_to_lbfgs_from_the_best_start():
    src = torch.tensor([[16.0, 16.0], [16.0, 16.0], [8.0, 8.0]], dtype=torch.float64)
    tgt = torch.tensor([[19.0, 16.0], [13.0, 16.0], [9.0, 8.0]], dtype=torch.float64)
    fit = fit_keyframes(
        src, tgt, image_size=SIZE, grid=16, steps=4, control=3, progress=False, max_iter=20, dtype=torch.float64
    )
    assert not fit.reached and fit.forwards > 0 and fit.evaluations > 0 and "handed over to L-BFGS" in fit.message
    final = float(keyframe_loss(fit.trajectories, [(4, tgt[None])]))
    assert final <= min(fit.loss_history[: fit.forwards]) * (1 + 1e-9)
    assert final == pytest.approx(min(fit.loss_history), rel=1e-6)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"method": "lbfgs"},
        {"smoothness": 1.0},
        {"regularization": 1e-3},
        {"viscosity": torch.full((1, 1, 16, 16), 0.1)},
        {"forces": ControlGrid(4, 3, cumulative=False)},
    ],
)
def test_other_objectives_run_lbfgs_alone(kwargs):
    src = SRC[0].float()
    fit = fit_keyframes(
        src, src + 1.0, image_size=SIZE, grid=16, steps=4, control=3, progress=False, tolerance=0.05, **kwargs
    )
    assert fit.forwards == 0 and fit.evaluations == len(fit.loss_history) > 0


def test_an_unknown_method_is_refused_by_name():
    with pytest.raises(ValueError, match="method must be 'auto' or 'lbfgs', got 'newton'"):
        fit_keyframes(SRC[0], SRC[0] + 1.0, image_size=SIZE, grid=16, steps=4, progress=False, method="newton")


def test_a_step_whose_flow_blows_up_is_rejected(monkeypatch):
    tgt = _flow_targets()
    rollout, calls = FluidWarp.rollout, []

    def flaky(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:  # the first trial step
            raise FlowBlewUp("the flow blew up at step 3")
        return rollout(self, *args, **kwargs)

    monkeypatch.setattr(FluidWarp, "rollout", flaky)
    warp = FluidWarp(32, 5, image_size=SIZE).double()
    forces = ControlGrid(5, (4, 4)).double()
    start = newton_start(warp, forces, SRC, [(5, tgt)], torch.ones(1, 5, dtype=torch.float64), 0.01, SIZE)
    assert start.reached and start.forwards == len(start.loss_history) + 1


def test_a_previous_fit_warm_starts_the_start():
    """A control grid passed as ``forces`` is started from its values: after one point moves a little, the
    start begins far closer than from rest, and needs no more roll-outs."""
    tgt = _flow_targets()
    kw = dict(image_size=SIZE, grid=32, steps=5, control=(4, 4), progress=False, dtype=torch.float64)
    first = fit_keyframes(SRC, tgt, **kw)
    moved = tgt.clone()
    moved[0, 2] += torch.tensor([0.6, -0.4], dtype=torch.float64)
    cold = fit_keyframes(SRC, moved, **kw)
    warm = fit_keyframes(SRC, moved, forces=first.forces, **kw)
    assert cold.reached and warm.reached and warm.evaluations == 0
    assert 0 < warm.forwards <= cold.forwards
    assert warm.loss_history[0] < 0.05 * cold.loss_history[0]


def test_max_iter_bounds_the_start_too():
    tgt = _flow_targets()
    kw = dict(image_size=SIZE, grid=32, steps=5, control=(4, 4), progress=False, dtype=torch.float64)
    fit = fit_keyframes(SRC, tgt, max_iter=2, tolerance=1e-6, **kw)
    assert fit.forwards == 3 and not fit.reached and fit.evaluations > 0  # then L-BFGS, with its own max_iter


@pytest.mark.parametrize("shape", [(2, 6, 9), (2, 9, 6)])
def test_the_damped_step_is_the_same_in_either_space(gen, shape):
    """Fewer residuals than controls: solved among the residuals; more: among the controls. Both are the
    minimiser of |r + J du|^2 + mu |du|^2."""
    from torchfluidwarp.control.newton import _damped_step

    J = torch.randn(shape, generator=gen, dtype=torch.float64)
    r = torch.randn(shape[:2], generator=gen, dtype=torch.float64)
    lam = torch.tensor([0.1, 2.0], dtype=torch.float64)
    du = _damped_step(J, r, lam)
    mu = lam * (J**2).sum((1, 2)) / shape[1]
    normal = J.transpose(1, 2) @ J + mu.view(-1, 1, 1) * torch.eye(shape[2], dtype=torch.float64)
    torch.testing.assert_close(normal @ du.unsqueeze(-1), -(J.transpose(1, 2) @ r.unsqueeze(-1)))


def test_more_residuals_than_controls(gen):
    """24 points (48 residuals) against a 3 x 3 control grid over 2 steps (36 controls): targets that such
    controls reach are met."""
    warp = FluidWarp(16, 2, image_size=SIZE).double()
    made = ControlGrid(2, (3, 3)).double()
    with torch.no_grad():
        made.weight.copy_(torch.randn(made.weight.shape, generator=gen, dtype=torch.float64) * 0.5)
    src = 6.0 + 20.0 * torch.rand(1, 24, 2, generator=gen, dtype=torch.float64)
    with torch.no_grad():
        tgt = warp.carry_points(src, made)[:, -1]
    assert float((tgt - src).norm(dim=-1).max()) > 0.5
    fit = fit_keyframes(
        src, tgt, image_size=SIZE, grid=16, steps=2, control=(3, 3), progress=False, dtype=torch.float64
    )
    assert fit.reached and fit.evaluations == 0 and fit.forwards > 1


def test_a_problem_of_the_batch_that_met_its_targets_rests():
    """A problem of a batch met at rest (targets 0.006 px from the sources, within the 0.01 px tolerance) keeps
    its controls at rest while the other goes on: no step moves it."""
    tgt = _flow_targets()
    easy = SRC + 0.004
    kw = dict(image_size=SIZE, grid=32, steps=5, control=(4, 4), progress=False, dtype=torch.float64)
    both = fit_keyframes(SRC.expand(2, -1, -1), torch.cat([easy, tgt]), **kw)
    assert both.reached and both.forwards > 1 and both.evaluations == 0
    assert bool((both.forces.weight[0] == 0).all()) and bool((both.forces.weight[1] != 0).any())


def test_the_start_shows_its_progress(capsys):
    src = SRC[0].float()
    fit_keyframes(src, src + 1.0, image_size=SIZE, grid=16, steps=4, control=3, tolerance=0.05, progress=True)
    assert "quasi-Newton start" in capsys.readouterr().err
    fit_keyframes(src, src + 1.0, image_size=SIZE, grid=16, steps=4, control=3, tolerance=0.05, progress=False)
    assert "quasi-Newton start" not in capsys.readouterr().err


def test_a_start_that_would_not_fit_in_memory_is_skipped(monkeypatch):
    from torchfluidwarp.control import newton

    src = SRC[0].float()
    kw = dict(image_size=SIZE, grid=16, steps=4, control=3, tolerance=0.05, progress=False)
    need = newton.start_bytes(1, 1, 5, 4, (3, 3), (16, 16))
    # three Jacobians, one lag's responses and their copy, and their samples twice
    assert need == 8 * (3 * 10 * 72 + 2 * 18 * 2 * 17 * 17 + 2 * 18 * 4 * 10 * 2)
    monkeypatch.setattr(newton, "MAX_START_BYTES", need)
    assert fit_keyframes(src, src + 1.0, **kw).forwards > 0
    monkeypatch.setattr(newton, "MAX_START_BYTES", need - 1)
    fit = fit_keyframes(src, src + 1.0, **kw)
    assert fit.forwards == 0 and fit.evaluations > 0 and fit.reached
