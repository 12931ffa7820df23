import math

import pytest
import torch
from conftest import gradcheck64

from torchfluidwarp.core import advection, fluid
from torchfluidwarp.core.grid import FluidGrid, interior_mask
from torchfluidwarp.core.linalg import CGConfig

GRIDS = [(8, 8), (7, 9)]


def _velocity(h, w, gen, scale=0.3, dtype=torch.float64, batch=2):
    v = torch.randn(batch, 2, h + 1, w + 1, generator=gen, dtype=dtype) * scale
    return v * interior_mask(FluidGrid(h, w), dtype=dtype)


@pytest.mark.parametrize("grid", GRIDS)
def test_gradcheck_advect(grid, gen):
    h, w = grid
    q = torch.randn(2, 3, h, w, generator=gen)
    v = _velocity(h, w, gen)
    assert gradcheck64(lambda q, v: advection.advect(q, v, 0.7), q, v)
    assert gradcheck64(lambda v: advection.advect_velocity(v, 0.7), v)


@pytest.mark.parametrize("grid", GRIDS)
def test_gradcheck_diffuse_constant_and_variable(grid, gen):
    h, w = grid
    v = _velocity(h, w, gen, batch=1)
    cfg = CGConfig(rtol=1e-13)
    assert gradcheck64(lambda v: fluid.diffuse(v, 0.8, 1.0, config=cfg), v)
    mu = torch.rand(1, 1, h, w, generator=gen) + 0.1
    # the variable-viscosity solve iterates; fast mode checks random vector-Jacobian products in float64
    assert gradcheck64(lambda v, mu: fluid.diffuse(v, mu, 1.0, config=cfg), v, mu, fast_mode=True)


@pytest.mark.parametrize("grid", GRIDS)
def test_gradcheck_project(grid, gen):
    h, w = grid
    cfg = CGConfig(rtol=1e-13)
    assert gradcheck64(lambda v: fluid.project(v, config=cfg), _velocity(h, w, gen))


@pytest.mark.parametrize("dtype,bound", [(torch.float32, 1e-5), (torch.float64, 1e-10)])
@pytest.mark.parametrize("grid", [(7, 9), (32, 32), (48, 80)])
def test_projection_removes_divergence(grid, dtype, bound, gen):
    h, w = grid
    v = _velocity(h, w, gen, scale=1.0, dtype=dtype)
    p = fluid.project(v)
    assert fluid.divergence(p).abs().max() <= bound * p.abs().max()
    # projecting again changes a divergence-free field by less than the same bound
    assert (fluid.project(p) - p).abs().max() <= bound * p.abs().max()
    # the walls stay closed
    assert torch.equal(p * (1 - interior_mask(FluidGrid(h, w), dtype=dtype)), torch.zeros_like(p))


@pytest.mark.parametrize("kx,ky", [(0, 3), (2, 1), (5, 4)])
def test_diffusion_of_a_mode_decays_by_the_discrete_factor(kx, ky):
    h, w, mu, dt = 16, 12, 0.7, 0.5
    v = torch.zeros(1, 2, h + 1, w + 1, dtype=torch.float64)
    # u on x-faces: sin along x (walls at j = 0, w), cos along y (free slip), cell-centred rows
    j = torch.arange(w + 1, dtype=torch.float64)
    i = torch.arange(h, dtype=torch.float64)
    mode = torch.cos(math.pi * ky * (i[:, None] + 0.5) / h) * torch.sin(math.pi * (kx + 1) * j[None, :] / w)
    v[0, 0, :h] = mode
    lam = 4 * math.sin(math.pi * ky / (2 * h)) ** 2 + 4 * math.sin(math.pi * (kx + 1) / (2 * w)) ** 2
    out = fluid.diffuse(v, mu, dt)
    torch.testing.assert_close(out, v / (1 + dt * mu * lam), atol=1e-12, rtol=0)


def test_strain_operator_is_the_energy_gradient_and_reduces_for_constant_viscosity(gen):
    h, w = 7, 9
    v = _velocity(h, w, gen, batch=1)
    mu = torch.rand(1, 1, h, w, generator=gen, dtype=torch.float64) + 0.2
    # gradient of E = sum mu (exx^2 + eyy^2) + sum_corners mu_n / 2 (u_y + v_x)^2
    vv = v.clone().requires_grad_()
    u, vy = vv[:, 0, :h], vv[:, 1, :, :w]
    mu_n = 0.25 * (mu[0, 0, 1:, 1:] + mu[0, 0, :-1, 1:] + mu[0, 0, 1:, :-1] + mu[0, 0, :-1, :-1])
    shear = (u[:, 1:, 1:-1] - u[:, :-1, 1:-1]) + (vy[:, 1:-1, 1:] - vy[:, 1:-1, :-1])
    energy = (mu[:, 0] * ((u[..., 1:] - u[..., :-1]) ** 2 + (vy[:, 1:] - vy[:, :-1]) ** 2)).sum()
    energy = energy + (0.5 * mu_n * shear**2).sum()
    (grad,) = torch.autograd.grad(energy, vv)
    mask = interior_mask(FluidGrid(h, w), dtype=torch.float64)
    torch.testing.assert_close(fluid.strain_operator(v, mu), grad * mask)
    # constant viscosity: -mu (laplacian + grad div)
    c = torch.full_like(mu, 0.6)
    expected = -0.6 * (fluid.vector_laplacian(v) + fluid.gradient(fluid.divergence(v)))
    torch.testing.assert_close(fluid.strain_operator(v, c), expected)


def test_zero_viscosity_is_the_identity(gen):
    v = _velocity(8, 8, gen)
    assert fluid.diffuse(v, 0.0, 1.0) is v


def test_variable_viscosity_solve_converges_in_a_few_iterations(gen):
    v = _velocity(32, 32, gen, dtype=torch.float32)
    mu = torch.rand(2, 1, 32, 32, generator=gen) * 0.5 + 0.5
    _, iters = fluid.diffuse(v, mu, 1.0, return_iterations=True)
    assert 1 <= iters <= 20


def test_points_follow_a_uniform_flow(gen):
    # a uniform horizontal velocity inside (walls aside) moves points by dt * u
    h, w = 16, 16
    v = torch.zeros(1, 2, h + 1, w + 1, dtype=torch.float64)
    v[0, 0, :h, 1:w] = 0.5
    pts = torch.tensor([[[5.0, 4.0], [8.3, 10.7]]], dtype=torch.float64)
    torch.testing.assert_close(
        advection.advect_points(pts, v, 2.0), pts + torch.tensor([1.0, 0.0], dtype=torch.float64)
    )
    torch.testing.assert_close(
        advection.sample_velocity(v, pts), torch.tensor([[[0.5, 0.0], [0.5, 0.0]]], dtype=torch.float64)
    )


@pytest.mark.parametrize(
    "fn",
    [
        lambda v: advection.advect_velocity(v, 1.0),
        lambda v: advection.advect(torch.zeros(1, 1, 8, 8), v, 1.0),
        lambda v: advection.advect_points(torch.zeros(1, 3, 2), v, 1.0),
        lambda v: advection.sample_velocity(v, torch.zeros(1, 3, 2)),
    ],
)
def test_nan_velocity_is_a_python_error_not_a_crash(fn):
    v = torch.zeros(1, 2, 9, 9)
    v[0, 0, 3, 3] = float("nan")
    with pytest.raises(ValueError, match="velocity contains non-finite"):
        fn(v)


def test_nan_points_are_refused():
    with pytest.raises(ValueError, match="points contains non-finite"):
        advection.advect_points(torch.tensor([[[float("nan"), 1.0]]]), torch.zeros(1, 2, 9, 9), 1.0)


@pytest.mark.parametrize(
    "bad,match",
    [
        (-0.1, "viscosity must be finite and >= 0"),
        (float("nan"), "viscosity must be finite"),
        (torch.full((1, 1, 8, 8), -1.0), "viscosity must be >= 0"),
        (torch.zeros(1, 1, 4, 4), r"viscosity must be a float or a field of shape"),
        (torch.full((1, 1, 8, 8), float("inf")), "viscosity contains non-finite"),
    ],
)
def test_bad_viscosity(bad, match):
    with pytest.raises(ValueError, match=match):
        fluid.check_viscosity(bad, 1, (8, 8))


@pytest.mark.parametrize("shape", [(1, 3, 9, 9), (1, 2, 9), (1, 2, 2, 9)])
def test_bad_velocity_shapes(shape):
    with pytest.raises(ValueError, match="velocity"):
        advection.advect_velocity(torch.zeros(shape), 1.0)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_exact_solves_skip_cg_and_agree_with_the_checked_loop(dtype, gen):
    v = _velocity(12, 10, gen, dtype=dtype)
    fast, it_fast = fluid.project(v, return_iterations=True)
    checked, _ = fluid.project(v, config=CGConfig(verify_exact=True), return_iterations=True)
    assert it_fast == 1
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    torch.testing.assert_close(fast, checked, atol=tol * float(v.abs().max()), rtol=0)
    assert float(fluid.divergence(fast).abs().max()) <= tol * float(v.abs().max())
    d_fast = fluid.diffuse(v, 0.8, 1.0)
    d_checked = fluid.diffuse(v, 0.8, 1.0, config=CGConfig(verify_exact=True))
    torch.testing.assert_close(d_fast, d_checked, atol=tol * float(v.abs().max()), rtol=0)


@pytest.mark.parametrize(
    "batch,grid",
    [(1, (8, 8)), (1, (7, 9)), (2, (8, 8)), (3, (7, 9)), (1, (100, 96))],  # the convolution, then the differences
)
def test_divergence_is_the_staggered_stencil_on_either_path(batch, grid, gen):
    """One small field takes the 2x2 convolution, a batch or a large grid two differences: both are
    ``u[j, i + 1] - u[j, i] + v[j + 1, i] - v[j, i]``, forward and backward."""
    h, w = grid
    v = torch.randn(batch, 2, h + 1, w + 1, generator=gen, dtype=torch.float64, requires_grad=True)
    expected = torch.zeros(batch, 1, h, w, dtype=torch.float64)
    for j in range(h):
        expected[:, 0, j] = v[:, 0, j, 1:] - v[:, 0, j, :-1] + v[:, 1, j + 1, :w] - v[:, 1, j, :w]
    div = fluid.divergence(v)
    torch.testing.assert_close(div, expected, rtol=0, atol=1e-12)
    weight = torch.randn(div.shape, generator=gen, dtype=torch.float64)
    (got,) = torch.autograd.grad((div * weight).sum(), v)
    (want,) = torch.autograd.grad((expected * weight).sum(), v)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
