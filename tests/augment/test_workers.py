"""Augmentation at scale: DataLoader workers draw different, reproducible warps; a batch draws in one call."""

import itertools
from functools import cache

import pytest
import torch
from torch.utils.data import DataLoader, Dataset, get_worker_info
from torchvision import tv_tensors

from torchfluidwarp.augment import FluidWarpAugment, FluidWarpSettings, brush_forces, draw_fluid_warp, raster_map
from torchfluidwarp.augment.draw import make_simulator
from torchfluidwarp.augment.transforms import RandomFluidWarp
from torchfluidwarp.core import graphs
from torchfluidwarp.core.simulator import FluidSimulator
from torchfluidwarp.warp.layer import FluidWarp

N, S = 8, 24  # 8 identical images of 24 x 24: only the warp differs between samples
SETTINGS = FluidWarpSettings(count=(1, 2), strength=(0.2, 0.4), radius=(4.0, 8.0), steps=(2, 4), grid=8)


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def _image():
    g = torch.Generator().manual_seed(0)
    return torch.rand(3, S, S, generator=g)


class _Same(Dataset):
    """``N`` copies of one image through ``transform``; each item also says which worker warped it."""

    def __init__(self, transform):
        self.transform, self.image = transform, _image()

    def __len__(self):
        return N

    def __getitem__(self, i):
        return self.transform(tv_tensors.Image(self.image)).as_subclass(torch.Tensor), get_worker_info().id


TRANSFORMS = {
    # no generator: the draws come from torch's default RNG, which DataLoader seeds in each worker
    "RandomFluidWarp, default RNG": lambda: RandomFluidWarp(settings=SETTINGS),
    # a generator made at construction is pickled into every worker, which re-seeds its own copy
    "FluidWarpAugment, own generator": lambda: FluidWarpAugment(
        settings=SETTINGS, generator=torch.Generator().manual_seed(5)
    ),
}


@cache
def _run(name, seed, run):
    """The ``N`` warped images and the worker of each, from a fresh transform in a 2-worker loader seeded with
    ``seed``. Cached (``run`` tells repeats apart), so each loader starts its workers once for the module."""
    loader = DataLoader(
        _Same(TRANSFORMS[name]()),
        batch_size=1,
        num_workers=2,
        generator=torch.Generator().manual_seed(seed),
    )
    images, workers = zip(*loader)
    return torch.cat(images), torch.cat(workers)


@pytest.mark.parametrize("name", TRANSFORMS)
def test_workers_and_samples_draw_different_warps(name):
    images, workers = _run(name, 1, 0)
    assert images.shape == (N, 3, S, S) and set(workers.tolist()) == {0, 1}
    # every pair differs, within a worker and across the two: no worker repeats another's draws
    for i, j in itertools.combinations(range(N), 2):
        assert (images[i] - images[j]).abs().amax() > 1e-3, (i, j, workers[i].item(), workers[j].item())
    # and they are warps of the image, not noise: each stays close to it on average
    assert ((images - _image()).abs().mean((1, 2, 3)) < 0.3).all()


@pytest.mark.parametrize("name", TRANSFORMS)
def test_seeded_runs_reproduce_and_another_seed_differs(name):
    first, workers = _run(name, 1, 0)
    again, workers_again = _run(name, 1, 1)
    assert torch.equal(workers, workers_again)
    assert torch.equal(first, again)  # bit for bit: same loader seed, same warps, sample by sample
    other, _ = _run(name, 2, 0)
    assert all((first[i] - other[i]).abs().amax() > 1e-3 for i in range(N))


def test_a_batch_is_drawn_and_rolled_out_in_one_call(monkeypatch):
    calls = []
    rollout = FluidSimulator.forward

    def counted(self, forces, *args, **kwargs):
        calls.append(forces.shape[0])
        return rollout(self, forces, *args, **kwargs)

    monkeypatch.setattr(FluidSimulator, "forward", counted)
    images = _image().expand(16, -1, -1, -1)
    out = FluidWarpAugment(settings=SETTINGS, generator=torch.Generator().manual_seed(0))(images)
    assert calls == [16]  # one roll-out for the whole batch (these settings never need a fold retry)
    # per-sample warps: no two samples of the batch share one
    for i, j in itertools.combinations(range(16), 2):
        assert (out[i] - out[j]).abs().amax() > 1e-3, (i, j)


def test_a_sample_warp_depends_only_on_its_own_brushes():
    # the batched roll-out computes what a roll-out per sample would, from the same brushes
    params = draw_fluid_warp(SETTINGS, 6, (S, S), generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    assert (params.force_scale == 1).all()
    for b in range(params.batch):
        one = slice(b, b + 1)
        forces = brush_forces(
            params.centers[one],
            params.directions[one],
            params.amplitude[one],
            params.radius[one],
            grid=SETTINGS.grid,
            image_size=(S, S),
            steps=int(params.steps[b]),
        )
        with torch.no_grad():
            v = FluidWarp(SETTINGS.grid, int(params.steps[b]), SETTINGS.dt, SETTINGS.viscosity)
            v = v.rollout(forces, (S, S)).velocities
        torch.testing.assert_close(params.velocities[one, : v.shape[1]], v, rtol=1e-6, atol=1e-8)
        assert not params.velocities[b, v.shape[1] :].any()  # past its own steps, a sample stands still
        torch.testing.assert_close(params.raster_map[one], raster_map(v, (S, S), SETTINGS.dt), rtol=1e-6, atol=1e-6)


def test_a_batch_draw_is_not_a_sequence_of_single_draws():
    # the documented contract: a seed fixes the draws of a call of a given batch size; sample b of a batch of B
    # is not what the b-th call of batch 1 would draw (the batch draws each quantity for all samples at once)
    aug = FluidWarpAugment(settings=SETTINGS, generator=torch.Generator().manual_seed(4))
    batch = aug.make_params(4, (S, S)).centers
    aug.generator.manual_seed(4)
    singles = torch.cat([aug.make_params(1, (S, S)).centers for _ in range(4)])
    assert not torch.allclose(batch, singles)
    aug.generator.manual_seed(4)
    torch.testing.assert_close(aug.make_params(4, (S, S)).centers, batch, rtol=0, atol=0)


def test_draws_set_up_no_fluid_of_their_own(monkeypatch):
    # the augmentation holds one simulator (and so its grid's constants) for all its draws
    made = []
    init = FluidSimulator.__init__

    def counted(self, *args, **kwargs):
        made.append(self)
        init(self, *args, **kwargs)

    monkeypatch.setattr(FluidSimulator, "__init__", counted)
    aug = FluidWarpAugment(settings=SETTINGS, generator=torch.Generator().manual_seed(0))
    assert len(made) == 1 and made[0] is aug.simulator
    for batch in (1, 3, 1):
        aug(_image().expand(batch, -1, -1, -1))
    assert len(made) == 1


def test_draws_with_cuda_graphs_capture_once_per_batch_shape_not_per_draw(monkeypatch):
    # on the CPU: stand-ins for the CUDA calls and for the capture, which runs the step it was given; what is
    # counted is how often the augmentation captures, not the GPU's work
    class Captured:
        def __init__(self, step, *args):
            self.step = step

        def __call__(self, *args, **kwargs):
            return self.step(*args, **kwargs)

        def close(self):
            pass

    monkeypatch.setattr(graphs, "graphable", lambda *args: True)
    monkeypatch.setattr(graphs, "_GraphedStep", Captured)
    monkeypatch.setattr(torch.cuda, "current_stream", lambda device=None: None)
    monkeypatch.setattr(torch.cuda, "Stream", lambda device=None: None)
    aug = FluidWarpAugment(settings=SETTINGS, generator=torch.Generator().manual_seed(0))
    aug.simulator = make_simulator(aug.settings, cuda_graphs=True)
    for _ in range(4):  # each draw draws its own steps (2 to 4): the capture does not depend on them
        aug(_image().expand(2, -1, -1, -1))
    assert aug.simulator.graphs.captures == 1
    aug(_image().expand(3, -1, -1, -1))  # another batch shape: one more
    assert aug.simulator.graphs.captures == 2
