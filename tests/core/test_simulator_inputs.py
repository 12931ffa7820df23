"""FluidSimulator and the sub-step cap refuse bad input by name, and follow the dtype policy (#19)."""

from __future__ import annotations

import pytest
import torch

from torchfluidwarp import FluidSimulator
from torchfluidwarp.core import advection
from torchfluidwarp.errors import FlowBlewUp


def forces(*shape: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    return (torch.randn(*shape, generator=torch.Generator().manual_seed(0)) * 0.1).to(dtype)


def test_a_zero_dim_viscosity_tensor_is_one_constant_viscosity():
    f = forces(1, 3, 2, 8, 8, dtype=torch.float64)
    as_tensor = FluidSimulator(8, viscosity=torch.tensor(0.1, dtype=torch.float64))(f).velocities
    as_float = FluidSimulator(8, viscosity=0.1)(f).velocities
    torch.testing.assert_close(as_tensor, as_float)


@pytest.mark.parametrize("force_dtype", [torch.float32, torch.float16, torch.bfloat16])
def test_mixed_dtypes_are_promoted_and_half_precision_computed_in_float32(force_dtype):
    f = forces(1, 2, 2, 8, 8, dtype=force_dtype)
    points = torch.tensor([[[2.0, 3.0], [5.5, 4.0]]], dtype=torch.float64)
    out = FluidSimulator(8)(f, points=points)
    assert out.points is not None and out.points.dtype == torch.float64
    assert out.velocities.dtype == torch.float64
    reference = FluidSimulator(8)(f.double(), points=points)
    assert reference.points is not None
    torch.testing.assert_close(out.points, reference.points)


def test_half_precision_alone_comes_back_in_its_dtype_computed_in_float32():
    f = forces(1, 2, 2, 8, 8, dtype=torch.bfloat16)
    out = FluidSimulator(8)(f).velocities
    assert out.dtype == torch.bfloat16
    reference = FluidSimulator(8)(f.float()).velocities
    torch.testing.assert_close(out.float(), reference, atol=1e-2, rtol=1e-2)


@pytest.mark.parametrize("shape", [(0, 2, 2, 8, 8), (1, 0, 2, 8, 8)])
def test_an_empty_batch_or_schedule_is_refused_by_name(shape):
    with pytest.raises(ValueError, match="forces must have shape .* B >= 1 and at least one step"):
        FluidSimulator(8)(torch.zeros(shape))


@pytest.mark.parametrize("bad", ["yes", None, 2, -0.5, float("nan")])
def test_compressible_is_checked_by_name(bad):
    with pytest.raises((TypeError, ValueError), match="compressible"):
        FluidSimulator(8, compressible=bad)


def test_a_blown_up_flow_is_an_arithmetic_error_naming_forces_and_dt():
    with pytest.raises(FlowBlewUp, match="forces, velocity or dt") as info:
        FluidSimulator(8, dt=1e200)(forces(1, 3, 2, 8, 8, dtype=torch.float64) * 1e200)
    assert isinstance(info.value, ArithmeticError) and not isinstance(info.value, ValueError)


def test_a_flow_needing_too_many_substeps_is_refused_with_the_limit_and_its_setting():
    f = forces(1, 2, 2, 8, 8) * 1e7  # used to run for minutes
    velocity = FluidSimulator(8)(f).velocities[:, -1]
    with pytest.raises(FlowBlewUp, match=r"sub-steps .* above the limit of 4096; .* max_substeps"):
        advection.substeps(velocity, 1.0)
    n = advection.substeps(velocity, 1e-9)
    assert n == 1
    with pytest.raises(FlowBlewUp, match="above the limit of 4096"):
        FluidSimulator(8)(f, points=torch.full((1, 1, 2), 3.0))


def test_max_substeps_raises_the_limit_and_is_checked():
    velocity = FluidSimulator(8)(forces(1, 1, 2, 8, 8) * 10).velocities[:, 0]
    n = advection.substeps(velocity, 1.0)
    assert n > 4
    assert advection.substeps(velocity, 1.0, max_substeps=n) == n
    with pytest.raises(FlowBlewUp, match=f"needs {n} sub-steps .* limit of {n - 1}"):
        advection.substeps(velocity, 1.0, max_substeps=n - 1)
    with pytest.raises(TypeError, match="max_substeps"):
        advection.substeps(velocity, 1.0, max_substeps=1.5)  # type: ignore[arg-type]
    pts = torch.full((1, 2, 2), 3.0)
    with pytest.raises(FlowBlewUp, match="limit of 1"):
        advection.advect_points(pts, velocity, 1.0, max_substeps=1)


def test_points_or_velocity_with_another_batch_name_the_forces_batch():
    f = forces(2, 1, 2, 8, 8)
    with pytest.raises(ValueError, match="points has batch 1 but forces have batch 2"):
        FluidSimulator(8)(f, points=torch.zeros(1, 3, 2))
    with pytest.raises(ValueError, match="velocity has batch 3 but forces have batch 2"):
        FluidSimulator(8)(f, velocity=torch.zeros(3, 2, 9, 9))


def test_a_viscosity_and_dt_whose_product_overflows_the_dtype_are_named():
    from torchfluidwarp import FluidSimulator

    sim = FluidSimulator(5, dt=1e30, viscosity=1e30)
    with pytest.raises(ValueError, match=r"dt \* viscosity = 1e\+60 is beyond the range of torch.float32"):
        sim(torch.zeros(1, 2, 2, 5, 5))
