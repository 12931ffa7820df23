import math

import pytest
import torch
from conftest import gradcheck64

from torchfluidwarp.core.grid import FluidGrid
from torchfluidwarp.warp.forces import (
    Brushes,
    CellForces,
    ControlGrid,
    SumForces,
    ViscosityBrushes,
    bicubic_axis,
    cell_centres,
    gaussian_bumps,
    viscosity_from_mask,
)
from torchfluidwarp.warp.landmarks import LandmarkForces


def test_brush_peak_direction_and_oscillation():
    b = Brushes([[31.5, 31.5]], [[3.0, 4.0]], radius=5.0, amplitude=2.0, frequency=0.25, phase=math.pi / 2)
    f = b(FluidGrid(64, 64), 4, 1.0, (64, 64))  # pixels == cells here
    assert f.shape == (1, 4, 2, 64, 64)
    peak = f[0, 0, :, 31:33, 31:33].mean(dim=(-2, -1))
    torch.testing.assert_close(peak, torch.tensor([1.2, 1.6]) * math.exp(-0.25 / 25), atol=1e-4, rtol=0)
    # sin(2 pi 0.25 t + pi/2) = cos(pi t / 2): 1, 0, -1, 0
    torch.testing.assert_close(
        f[0, :, 0, 31, 31] / f[0, 0, 0, 31, 31], torch.tensor([1.0, 0.0, -1.0, 0.0]), atol=1e-6, rtol=0
    )


def test_brush_units_follow_the_image_size():
    b = Brushes([[100.0, 50.0]], [[1.0, 0.0]], radius=20.0, amplitude=4.0)
    f = b(FluidGrid(25, 50), 1, 1.0, (100, 200))  # 4 px per cell
    assert torch.isclose(f.max(), torch.tensor(1.0), atol=0.05)


def test_brushes_are_differentiable_in_their_parameters():
    brush = Brushes([[6.0, 5.0]], [[1.0, 0.5]], radius=3.0, amplitude=1.5, frequency=0.1).double()

    def fn(centers, directions, radius, amplitude, frequency, phase):
        params = dict(
            centers=centers, directions=directions, radius=radius, amplitude=amplitude, frequency=frequency, phase=phase
        )
        return torch.func.functional_call(brush, params, (FluidGrid(6, 7), 3, 1.0, (12, 14)))

    names = ["centers", "directions", "radius", "amplitude", "frequency", "phase"]
    assert gradcheck64(fn, *[getattr(brush, n) for n in names])


def test_control_grid_is_linear_and_exact_at_its_nodes(gen):
    init = torch.randn(2, 3, 2, 4, 5, generator=gen)
    cg = ControlGrid(3, (4, 5), batch=2, init=init, cumulative=False)
    f = cg(FluidGrid(13, 17), 3, 1.0, (13, 17))
    assert f.shape == (2, 3, 2, 13, 17)
    torch.testing.assert_close(f[..., 0, 0], init[..., 0, 0])
    torch.testing.assert_close(f[..., -1, -1], init[..., -1, -1])
    assert sum(p.numel() for p in ControlGrid(10, (5, 5)).parameters()) == 500


@pytest.mark.parametrize("k,n", [(4, 13), (5, 17), (3, 3), (6, 4)])
def test_bicubic_axis_is_the_bicubic_resize_along_one_axis(k, n, gen):
    x = torch.randn(2, 3, k, 7, generator=gen, dtype=torch.float64)
    r = bicubic_axis(k, n, dtype=torch.float64)
    assert r.shape == (n, k) and r.dtype == torch.float64
    want = torch.nn.functional.interpolate(x, size=(n, 7), mode="bicubic", align_corners=True)
    torch.testing.assert_close(r @ x, want)
    assert bicubic_axis(k, n, dtype=torch.float64) is not r  # no module-level cache: a ControlGrid holds its own


def test_control_grid_is_the_separable_bicubic_resize_of_its_weights(gen):
    init = torch.randn(1, 2, 2, 4, 5, generator=gen, dtype=torch.float64)
    cg = ControlGrid(2, (4, 5), init=init, cumulative=False)
    f = cg(FluidGrid(13, 17), 2, 1.0, (13, 17))
    want = torch.nn.functional.interpolate(init.flatten(0, 1), size=(13, 17), mode="bicubic", align_corners=True)
    torch.testing.assert_close(f, want.view_as(f))
    torch.testing.assert_close(cg(FluidGrid(13, 17), 2, 1.0, (13, 17)), f, rtol=0, atol=0)  # built once, reused


def test_a_control_grid_first_called_in_inference_mode_still_trains(gen):
    # the grid builds its upsampling matrices on first use and keeps them: built under inference_mode they must
    # still serve a later call that autograd records (as the module-level cache they replaced did)
    init = torch.randn(1, 2, 2, 4, 4, generator=gen)
    cg = ControlGrid(2, (4, 4), init=init)
    with torch.inference_mode():
        preview = cg(FluidGrid(8, 8), 2, 1.0, (16, 16))
    forces = cg(FluidGrid(8, 8), 2, 1.0, (16, 16))
    forces.square().sum().backward()
    torch.testing.assert_close(forces.detach(), preview.clone())
    assert cg.weight.grad is not None and float(cg.weight.grad.abs().sum()) > 0


def test_control_grid_cumulative_weights_are_running_sums_of_the_forces(gen):
    init = torch.randn(2, 4, 2, 3, 3, generator=gen, dtype=torch.float64)
    size = FluidGrid(9, 11)
    plain = ControlGrid(4, (3, 3), batch=2, init=init, cumulative=False)(size, 4, 1.0, (9, 11))
    summed = ControlGrid(4, (3, 3), batch=2, init=init.cumsum(1))(size, 4, 1.0, (9, 11))
    torch.testing.assert_close(summed, plain)


def test_sum_and_cell_forces(gen):
    a = Brushes([[5.0, 5.0]], [[1.0, 0.0]])
    s = SumForces(a, a)
    torch.testing.assert_close(s(FluidGrid(8, 8), 2, 1.0, (8, 8)), 2 * a(FluidGrid(8, 8), 2, 1.0, (8, 8)))
    c = CellForces(2, (8, 8))
    assert c(FluidGrid(8, 8), 2, 1.0, (8, 8)).shape == (1, 2, 2, 8, 8)
    with pytest.raises(ValueError, match="CellForces holds"):
        c(FluidGrid(8, 9), 2, 1.0, (8, 8))


def test_viscosity_maps():
    mask = torch.zeros(1, 1, 32, 32)
    mask[..., :16, :] = 1
    mu = viscosity_from_mask(mask, (8, 8), stiff=4.0, soft=0.5)
    assert mu.shape == (1, 1, 8, 8)
    assert torch.allclose(mu[..., :4, :], torch.tensor(4.0)) and torch.allclose(mu[..., 4:, :], torch.tensor(0.5))
    vb = ViscosityBrushes([[16.0, 16.0]], radius=4.0, value=3.0, base=0.1)
    field = vb(FluidGrid(8, 8), (32, 32))
    assert field.shape == (1, 1, 8, 8) and field.min() >= 0.1 and field.max() <= 3.1


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"centers": [[1.0, float("nan")]], "directions": [[1.0, 0.0]]}, "centers contains non-finite"),
        ({"centers": [[1.0, 1.0]], "directions": [[0.0, 0.0]]}, "directions must be non-zero"),
        ({"centers": [[1.0, 1.0]], "directions": [[1.0, 0.0]], "radius": -1.0}, "radius must be > 0"),
        ({"centers": [[1.0, 1.0]], "directions": [[1.0, 0.0]], "frequency": -1.0}, "frequency must be >= 0"),
    ],
)
def test_bad_brushes(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Brushes(**kwargs)


def test_gaussian_bumps_profile_and_batching(gen):
    x = cell_centres(FluidGrid(6, 7), (30, 35), torch.zeros((), dtype=torch.float64))  # (6, 7, 2) pixels
    centers = torch.rand(3, 4, 2, generator=gen, dtype=torch.float64) * 30
    radius = torch.rand(3, 4, generator=gen, dtype=torch.float64) * 5 + 2
    bumps = gaussian_bumps(x, centers, radius)
    assert bumps.shape == (3, 4, 6, 7)
    for b in range(3):  # a batch of brush sets is each set on its own, bit for bit
        torch.testing.assert_close(bumps[b], gaussian_bumps(x, centers[b], radius[b]), rtol=0, atol=0)
    at = torch.stack([centers[0, 0], centers[0, 0] + radius[0, 0] * torch.tensor([0.6, 0.8], dtype=torch.float64)])
    values = gaussian_bumps(at.view(1, 2, 2), centers[0, :1], radius[0, :1])[0, 0]
    torch.testing.assert_close(values, torch.tensor([1.0, math.exp(-0.5)], dtype=torch.float64))


def test_force_modules_build_their_parameters_where_asked():
    assert ControlGrid(2, (2, 2), dtype=torch.float64).weight.dtype == torch.float64
    assert CellForces(2, (4, 4), dtype=torch.float64).weight.dtype == torch.float64
    assert ControlGrid(2, (2, 2)).weight.dtype == torch.get_default_dtype()
    mid = torch.tensor([[8.0, 8.0], [24.0, 8.0], [16.0, 24.0]], dtype=torch.float64)
    landmarks = LandmarkForces(mid, torch.ones(3, 2, dtype=torch.float64), steps=2)
    assert landmarks.weight.dtype == torch.float64 and landmarks.weight.device == mid.device
    brushes = Brushes(torch.tensor([[5.0, 5.0]]), [[1.0, 0.0]], radius=[3.0], amplitude=torch.tensor(0.5))
    assert {p.device for p in brushes.parameters()} == {brushes.centers.device}
