"""The one owner of the staggered layout (:class:`~torchfluidwarp.core.staggered.StaggeredGrid`): its split and
pack, its extension for sampling, its constants held per instance, and its unchecked kernels agreeing with the
checked public functions of :mod:`torchfluidwarp.core.advection`."""

from __future__ import annotations

import pytest
import torch
from conftest import gradcheck64

from torchfluidwarp.core import advection
from torchfluidwarp.core.grid import FluidGrid, cell_to_pixel, interior_mask, pixel_to_cell
from torchfluidwarp.core.simulator import FluidSimulator
from torchfluidwarp.core.staggered import StaggeredGrid

GRIDS = [(6, 6), (5, 8), (9, 4)]  # square, wide and tall: u and v differ in shape unless h == w


def _velocity(grid, gen, batch=2, scale=0.4, dtype=torch.float64):
    """A random staggered velocity ``(batch, 2, h + 1, w + 1)``: zero on the walls and the padding."""
    h, w = grid
    v = torch.randn(batch, 2, h + 1, w + 1, generator=gen, dtype=dtype) * scale
    return v * interior_mask(FluidGrid(h, w), dtype=dtype)


def _points(grid, gen, batch=2, n=7, dtype=torch.float64):
    """``(batch, n, 2)`` points in cells, inside the box and a little beyond it."""
    h, w = grid
    box = torch.tensor([w, h], dtype=dtype)
    return torch.rand(batch, n, 2, generator=gen, dtype=dtype) * (box + 1.0) - 1.0


@pytest.mark.parametrize("grid", GRIDS)
def test_split_gives_each_component_without_its_padding_and_pack_restores_it_with_zeros(grid, gen):
    h, w = grid
    g = StaggeredGrid(grid)
    assert g.shape == (h + 1, w + 1) and (g.h, g.w) == (h, w)
    full = torch.randn(3, 2, h + 1, w + 1, generator=gen, dtype=torch.float64)  # garbage in the padding too
    u, v = g.split(full)
    assert u.shape == (3, h, w + 1) and v.shape == (3, h + 1, w)
    assert u.data_ptr() == full.data_ptr()  # views, not copies
    packed = g.pack(u, v)
    assert packed.shape == full.shape
    assert not packed[:, 0, h, :].any() and not packed[:, 1, :, w].any()  # zero padding
    torch.testing.assert_close(packed[:, 0, :h], full[:, 0, :h], rtol=0, atol=0)
    torch.testing.assert_close(packed[:, 1, :, :w], full[:, 1, :, :w], rtol=0, atol=0)
    # a velocity with zero padding goes round exactly
    clean = _velocity(grid, gen, batch=3)
    torch.testing.assert_close(g.pack(*g.split(clean)), clean, rtol=0, atol=0)


@pytest.mark.parametrize("grid", GRIDS)
def test_the_mask_is_one_on_the_free_faces_only(grid):
    g = StaggeredGrid(grid)
    like = torch.zeros(1, dtype=torch.float64)
    mask = g.mask(like)
    assert mask.dtype == torch.float64 and mask.shape == (1, 2, *g.shape)
    torch.testing.assert_close(mask, interior_mask(FluidGrid(*grid), dtype=torch.float64), rtol=0, atol=0)
    assert torch.equal(g.zeros(2, like=like), torch.zeros(2, 2, *g.shape, dtype=torch.float64))


def test_of_reads_the_grid_from_a_velocity():
    g = StaggeredGrid.of(torch.zeros(2, 2, 6, 9))
    assert (g.h, g.w) == (5, 8) and g.grid == FluidGrid(5, 8)
    assert StaggeredGrid(7).shape == (8, 8)


@pytest.mark.parametrize("grid", GRIDS)
def test_extend_and_velocity_at_agree_with_sample_velocity(grid, gen):
    g = StaggeredGrid(grid)
    vel, pts = _velocity(grid, gen), _points(grid, gen)
    got = g.velocity_at(g.extend(vel), pts)
    assert got.shape == pts.shape
    torch.testing.assert_close(got, advection.sample_velocity(vel, pts), rtol=0, atol=0)


@pytest.mark.parametrize("grid", GRIDS)
def test_velocity_at_reads_each_component_on_its_faces(grid, gen):
    # in (x, y) cells, u[j, i] sits at (i - 1/2, j) and v[j, i] at (i, j - 1/2): sampled there, each reads its own
    h, w = grid
    g = StaggeredGrid(grid)
    vel = _velocity(grid, gen, batch=1)
    ext = g.extend(vel)
    ju, iu = torch.meshgrid(torch.arange(h), torch.arange(1, w), indexing="ij")
    at_u = torch.stack([iu - 0.5, ju.double()], -1).reshape(1, -1, 2).double()
    torch.testing.assert_close(g.velocity_at(ext, at_u)[0, :, 0], vel[0, 0, :h, 1:w].flatten())
    jv, iv = torch.meshgrid(torch.arange(1, h), torch.arange(w), indexing="ij")
    at_v = torch.stack([iv.double(), jv - 0.5], -1).reshape(1, -1, 2).double()
    torch.testing.assert_close(g.velocity_at(ext, at_v)[0, :, 1], vel[0, 1, 1:h, :w].flatten())


@pytest.mark.parametrize("grid", GRIDS)
@pytest.mark.parametrize("dt", [0.7, -1.3])
def test_carry_agrees_with_advect_points(grid, dt, gen):
    g = StaggeredGrid(grid)
    vel, pts = _velocity(grid, gen, scale=1.5), _points(grid, gen)
    got = g.carry(vel, pts, dt)
    assert got.shape == pts.shape
    torch.testing.assert_close(got, advection.advect_points(pts, vel, dt), rtol=0, atol=0)
    n = advection.substeps(vel, dt)
    torch.testing.assert_close(g.carry(vel, pts, dt, n=n), got, rtol=0, atol=0)
    assert g.substeps(g.extend(vel), dt) == n


@pytest.mark.parametrize("grid", GRIDS)
def test_trajectories_in_pixels_are_the_carry_in_cells_rescaled(grid, gen):
    g = StaggeredGrid(grid)
    size = (37, 29)
    velocities = torch.stack([_velocity(grid, gen) for _ in range(3)], dim=1)  # (B, T, 2, h + 1, w + 1)
    pixels = torch.rand(2, 5, 2, generator=gen, dtype=torch.float64) * torch.tensor([29.0, 37.0]) - 0.5
    got = g.trajectories(velocities, pixels, 0.8, size)
    assert got.shape == (2, 4, 5, 2)
    cells = [pixel_to_cell(pixels, size, grid)]
    for t in range(velocities.shape[1]):
        cells.append(g.carry(velocities[:, t], cells[-1], 0.8))
    want = cell_to_pixel(torch.stack(cells, dim=1), size, grid)
    torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(got[:, 0], pixels, rtol=0, atol=1e-12)
    # without a size the points are cells, carried as they are
    in_cells = g.trajectories(velocities, cells[0], 0.8)
    torch.testing.assert_close(in_cells, torch.stack(cells, dim=1), rtol=0, atol=0)


def test_trajectories_carry_half_precision_in_float32():
    g = StaggeredGrid((6, 6))
    velocities = torch.zeros(1, 2, 2, 7, 7, dtype=torch.bfloat16)
    points = torch.tensor([[[2.0, 3.0]]], dtype=torch.bfloat16)
    assert g.trajectories(velocities, points, 1.0).dtype == torch.bfloat16
    assert g.trajectories(velocities, points.double(), 1.0).dtype == torch.float64


def test_the_simulator_carries_points_with_its_own_grid(gen):
    sim = FluidSimulator((5, 8))
    forces = torch.randn(2, 3, 2, 5, 8, generator=gen, dtype=torch.float64) * 0.3
    pts = _points((5, 8), gen)
    out = sim(forces, points=pts)
    assert isinstance(sim.layout, StaggeredGrid) and sim.layout.grid == sim.grid
    torch.testing.assert_close(out.points, sim.layout.trajectories(out.velocities, pts, sim.dt), rtol=0, atol=0)


def test_the_constants_are_built_once_per_device_and_dtype_and_held_by_the_instance():
    g = StaggeredGrid((5, 8))
    x32, x64 = torch.zeros(1), torch.zeros(1, dtype=torch.float64)
    first = g.constants(x32)
    assert g.constants(x32) is first  # the same object on a second call
    assert all(a is b for a, b in zip(first.values(), g.constants(torch.ones(3)).values()))
    wide = g.constants(x64)
    assert wide is not first
    floats = [k for k, c in wide.items() if c.is_floating_point()]
    assert {"affine", "shift", "lo", "hi", "faces", "cells"} <= set(floats)
    assert all(wide[k].dtype == torch.float64 for k in floats)  # built in float64, not cast from float32
    assert all(first[k].dtype == torch.float32 for k in floats)
    torch.testing.assert_close(wide["affine"].float(), first["affine"])
    assert g.constants(x64) is wide and g.constants(x32) is first  # each kept
    other = StaggeredGrid((5, 8))
    theirs = other.constants(x32)
    assert theirs is not first and all(a is not b for a, b in zip(theirs.values(), first.values()))
    assert other.constants(x32) is theirs


def test_the_constants_are_built_outside_inference_mode_and_without_grad():
    g = StaggeredGrid((4, 4))
    with torch.inference_mode():
        c = g.constants(torch.zeros(1))
    assert not any(t.is_inference() or t.requires_grad for t in c.values())
    vel = torch.zeros(1, 2, 5, 5, requires_grad=True)
    assert not any(t.requires_grad for t in g.constants(vel).values())


@pytest.mark.parametrize("grid", [(3, 4), (4, 3)])
def test_gradcheck_velocity_at_in_the_velocity_and_the_points(grid, gen):
    g = StaggeredGrid(grid)
    vel = _velocity(grid, gen, batch=2)
    # points off the nodes (bilinear sampling has kinks there) and inside the box (clamped beyond it)
    pts = torch.tensor([[[0.3, 0.6], [1.7, 1.2], [2.2, 0.4]], [[1.1, 1.9], [0.45, 0.15], [1.6, 2.3]]])
    pts = pts.clamp(max=min(grid) - 0.7)
    assert gradcheck64(lambda v, p: g.velocity_at(g.extend(v), p), vel, pts)


@pytest.mark.parametrize("grid", [(3, 4)])
def test_gradcheck_carry_in_the_velocity_and_the_points(grid, gen):
    g = StaggeredGrid(grid)
    vel = _velocity(grid, gen, batch=1, scale=0.2)
    pts = torch.tensor([[[0.8, 1.3], [2.2, 0.9]]])
    assert gradcheck64(lambda v, p: g.carry(v, p, 0.6, n=2), vel, pts)
