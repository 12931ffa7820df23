"""The advection module (:mod:`torchfluidwarp.core.advection`): its sub-step strain as an argument, and its names
having one home."""

import math

import pytest
import torch

from torchfluidwarp.core import advection, fluid
from torchfluidwarp.core.grid import FluidGrid, interior_mask
from torchfluidwarp.core.staggered import MAX_STRAIN_PER_SUBSTEP


def _swirl(h: int, w: int, strength: float) -> torch.Tensor:
    """A smooth divergence-free staggered velocity ``(1, 2, h + 1, w + 1)`` (one projected bump)."""
    forces = torch.zeros(1, 2, h, w, dtype=torch.float64)
    forces[:, 0, h // 3 : 2 * h // 3, w // 3 : 2 * w // 3] = strength
    v = fluid.project(fluid.faces_from_cells(forces))
    return v * interior_mask(FluidGrid(h, w), dtype=torch.float64)


@pytest.mark.parametrize("name", advection.__all__)
def test_the_advection_names_have_one_home(name):
    assert not hasattr(fluid, name)


@pytest.mark.parametrize("max_strain", [0.05, 0.25, 1.0])
def test_substeps_bound_the_strain_per_substep(max_strain):
    v = _swirl(12, 12, 3.0)
    u, w = v[:, 0, :12, :], v[:, 1, :, :12]
    strain = max(float(u.diff(dim=-1).abs().max()), float(u.diff(dim=-2).abs().max()))
    strain = max(strain, float(w.diff(dim=-1).abs().max()), float(w.diff(dim=-2).abs().max()))
    n = advection.substeps(v, 1.5, max_strain)
    assert n == max(1, math.ceil(strain * 1.5 / max_strain))
    assert strain * 1.5 / n <= max_strain * (1 + 1e-12)
    assert advection.substeps(v, 1.5) == advection.substeps(v, 1.5, MAX_STRAIN_PER_SUBSTEP)


def test_finer_substeps_converge_on_the_same_paths():
    v = _swirl(16, 16, 2.0)  # strong: about 8 sub-steps at the default strain
    pts = torch.tensor([[[6.0, 7.0], [9.5, 8.0], [4.0, 10.0]]], dtype=torch.float64)
    reference = advection.advect_points(pts, v, 2.0, max_strain=0.001)
    err = [
        float((advection.advect_points(pts, v, 2.0, max_strain=s) - reference).abs().max()) for s in (1.0, 0.25, 0.05)
    ]
    assert err[1] < err[0] / 4 and err[2] < err[1] / 4
    assert err[1] < 1e-3  # cells, at the default's order of strain


@pytest.mark.parametrize("bad", [0.0, -0.1, float("nan"), float("inf")])
def test_a_bad_max_strain_is_refused_by_name(bad):
    v = _swirl(8, 8, 1.0)
    with pytest.raises(ValueError, match="max_strain"):
        advection.substeps(v, 1.0, bad)
    with pytest.raises(ValueError, match="max_strain"):
        advection.advect_points(torch.zeros(1, 2, 2, dtype=torch.float64), v, 1.0, max_strain=bad)
