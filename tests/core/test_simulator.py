import math
from types import SimpleNamespace

import pytest
import torch
from conftest import gradcheck64

from torchfluidwarp.core.fluid import divergence
from torchfluidwarp.core.grid import FluidGrid
from torchfluidwarp.core.linalg import CGConfig
from torchfluidwarp.core.simulator import FluidSimulator, StableFluidsStep

TIGHT = CGConfig(rtol=1e-13)


@pytest.mark.parametrize("grid", [(8, 8), (7, 9)])
def test_gradcheck_one_step(grid, gen):
    h, w = grid
    step = StableFluidsStep(1.0, pressure=TIGHT, diffusion=TIGHT)
    v = torch.zeros(1, 2, h + 1, w + 1)
    f = torch.randn(1, 2, h, w, generator=gen) * 0.3
    mu = torch.rand(1, 1, h, w, generator=gen) * 0.5 + 0.1
    assert gradcheck64(lambda f, mu: step(v.double(), f, mu)[0], f, mu, fast_mode=True)


@pytest.mark.parametrize("grid", [(8, 8), (7, 9)])
def test_gradcheck_rollout_with_particles(grid, gen):
    h, w = grid
    sim = FluidSimulator(grid, dt=1.0, viscosity=0.3, pressure=TIGHT, diffusion=TIGHT)
    forces = torch.randn(1, 3, 2, h, w, generator=gen) * 0.2
    pts = torch.tensor([[[2.3, 3.1], [4.6, 2.2], [5.1, 4.4]]])
    assert gradcheck64(lambda f, p: sim(f, p).points, forces, pts)


def test_adjoint_gradients_match_unrolled_cg_through_a_rollout(gen):
    h, w = 12, 10
    forces = torch.randn(1, 4, 2, h, w, generator=gen, dtype=torch.float64) * 0.3
    mu = torch.rand(1, 1, h, w, generator=gen, dtype=torch.float64) * 0.5 + 0.2
    pts = torch.tensor([[[3.3, 4.1], [6.6, 7.2]]], dtype=torch.float64)
    grads = []
    for backward in ("implicit", "unrolled"):
        cfg = CGConfig(rtol=1e-14, max_iter=500, backward=backward)
        f, m = forces.clone().requires_grad_(), mu.clone().requires_grad_()
        sim = FluidSimulator((h, w), viscosity=m, pressure=cfg, diffusion=cfg)
        out = sim(f, pts)
        loss = (out.points[:, -1] ** 2).sum() + (out.velocities**2).sum()
        grads.append(torch.autograd.grad(loss, (f, m)))
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b, atol=1e-8, rtol=0)


def test_rollout_is_divergence_free_every_step(gen):
    sim = FluidSimulator((24, 40), viscosity=0.2)
    out = sim(torch.randn(2, 5, 2, 24, 40, generator=gen))
    for t in range(5):
        v = out.velocities[:, t]
        assert divergence(v).abs().max() <= 1e-5 * v.abs().max()
    assert all(p == 1 for _, p in out.iterations)


def _polygon_area(p: torch.Tensor) -> torch.Tensor:
    x, y = p[..., 0], p[..., 1]
    return 0.5 * (x * torch.roll(y, -1, -1) - torch.roll(x, -1, -1) * y).sum(-1).abs()


def _smooth_random_forces(gen, steps, h, w, amplitude):
    coarse = torch.randn(1, steps * 2, 4, 4, generator=gen, dtype=torch.float64)
    fine = torch.nn.functional.interpolate(coarse, size=(h, w), mode="bicubic", align_corners=True)
    return amplitude * fine.view(1, steps, 2, h, w)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_ring_of_particles_keeps_its_area(seed):
    h = w = 64
    gen = torch.Generator().manual_seed(seed)
    theta = torch.arange(400, dtype=torch.float64) * (2 * math.pi / 400)
    r = w / 4
    ring = torch.stack([31.5 + r * torch.cos(theta), 31.5 + r * torch.sin(theta)], -1)[None]
    sim = FluidSimulator((h, w), viscosity=0.0)
    forces = _smooth_random_forces(gen, 20, h, w, amplitude=0.3)
    out = sim(forces, ring)
    moved = (out.points[:, -1] - ring).norm(dim=-1).mean()
    assert 5.0 <= moved <= 20.0, f"forcing should move the ring about 10 cells, moved {moved:.2f}"
    area0, area1 = _polygon_area(ring), _polygon_area(out.points[:, -1])
    assert abs(float(area1 / area0) - 1) < 0.01


@pytest.mark.parametrize(
    "bad,match",
    [
        (torch.full((1, 2, 2, 8, 8), float("nan")), "forces contains non-finite"),
        (torch.zeros(1, 2, 3, 8, 8), r"forces must have shape \(\*, \*, 2, 8, 8\)"),
        (torch.zeros(2, 8, 8), "forces must have shape"),
        (torch.zeros(1, 0, 2, 8, 8), "at least one step"),
        ([1.0], "forces must be a torch.Tensor"),
    ],
)
def test_bad_forces(bad, match):
    sim = FluidSimulator((8, 8))
    with pytest.raises((ValueError, TypeError), match=match):
        sim(bad)


@pytest.mark.parametrize("key", ["device", "presure"])
def test_an_unknown_setting_is_refused_by_the_simulators_name_with_its_settings(key):
    # the step's own TypeError named StableFluidsStep.__init__, a class the caller never called
    with pytest.raises(TypeError, match=rf"FluidSimulator got unexpected keyword argument\(s\) '{key}'") as caught:
        FluidSimulator((8, 8), **{key: None})
    assert "pressure, diffusion, adjoint, compressible" in str(caught.value)
    assert ("there is no device argument" in str(caught.value)) == (key == "device")
    FluidSimulator((8, 8), pressure=CGConfig())  # a known one passes


def test_bad_settings():
    with pytest.raises(ValueError, match="dt must be finite and > 0"):
        FluidSimulator((8, 8), dt=0.0)
    with pytest.raises(ValueError, match="grid must be a pair of ints >= 2"):
        FluidSimulator((0, 8))
    with pytest.raises(ValueError, match="viscosity must be finite and >= 0"):
        FluidSimulator((8, 8), viscosity=-1.0)
    with pytest.raises(ValueError, match="grid"):
        FluidGrid(1, 5)


def test_nan_points_raise(gen):
    sim = FluidSimulator((8, 8))
    with pytest.raises(ValueError, match="points contains non-finite"):
        sim(torch.zeros(1, 2, 2, 8, 8), torch.tensor([[[float("nan"), 2.0]]]))


def test_float64_and_batch_follow_inputs(gen):
    sim = FluidSimulator((9, 6))
    out = sim(torch.randn(3, 2, 2, 9, 6, generator=gen, dtype=torch.float64), torch.rand(3, 4, 2, dtype=torch.float64))
    assert out.velocities.dtype == torch.float64 and out.velocities.shape == (3, 2, 2, 10, 7)
    assert out.points.shape == (3, 3, 4, 2)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize(
    "settings",
    [
        {},
        {"viscosity": 0.3},
        {"dtype": torch.float64},
        {"compressible": 0.5, "points": True, "velocity": True},
    ],
)
def test_a_long_rollout_on_cuda_replays_its_step_from_a_graph_as_the_steps_run_one_by_one(gen, settings, monkeypatch):
    from torchfluidwarp.core import graphs

    dtype = settings.get("dtype", torch.float32)
    B, T = 2, graphs.GRAPH_MIN_STEPS + 2
    forces = (torch.randn(B, T, 2, 12, 14, generator=gen, dtype=dtype) * 0.3).cuda()
    given = {}
    if "velocity" in settings:
        given["velocity"] = (torch.randn(B, 2, 13, 15, generator=gen, dtype=dtype) * 0.1).cuda()
    if "points" in settings:
        given["points"] = torch.tensor([[[4.0, 5.0], [9.5, 7.0]]], dtype=dtype).expand(B, 2, 2).cuda()
    keep = settings.get("compressible", False)
    sim = FluidSimulator((12, 14), viscosity=settings.get("viscosity", 0.0), compressible=keep, cuda_graphs=True).cuda()
    captured = []
    real = graphs._GraphedStep

    class Spy(real):  # type: ignore[misc, valid-type]
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            captured.append(self)

    monkeypatch.setattr(graphs, "_GraphedStep", Spy)
    with torch.no_grad():
        out = sim(forces, **given)
        again = sim(forces, **given)  # a second roll-out replays the simulator's capture
        assert len(captured) == 1 and sim.graphs.captures == 1  # one capture, held by the simulator
        monkeypatch.setattr(graphs, "GRAPH_MIN_STEPS", 10**9)
        want = sim(forces, **given)  # step by step
    assert len(captured) == 1
    torch.testing.assert_close(out.velocities, want.velocities, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(again.velocities, out.velocities, rtol=0, atol=0)
    assert out.iterations == want.iterations
    if "points" in given:
        torch.testing.assert_close(out.points, want.points, rtol=1e-5, atol=1e-5)
    assert float(out.velocities.abs().max()) > 0.1  # the forces moved the fluid
    monkeypatch.setattr(graphs, "GRAPH_MIN_STEPS", T)
    with torch.enable_grad():  # a roll-out to differentiate runs step by step
        sim(forces.clone().requires_grad_())
    assert len(captured) == 1
    assert not sim.graphs._lock.locked()


def _stand_in(cuda: bool = True, requires_grad: bool = False, index: int = 0):
    # what graphable reads of a tensor, without a GPU
    return SimpleNamespace(is_cuda=cuda, requires_grad=requires_grad, device=SimpleNamespace(index=index))


@pytest.mark.parametrize(
    "kwargs,want",
    [
        ({}, True),  # on the current CUDA device, long enough, nothing to record, a float viscosity, exact solves
        ({"cuda": False}, False),  # the CPU has no launches to save
        ({"index": 1}, False),  # another device than the current one
        ({"steps": 7}, False),  # a short roll-out does not repay the capture
        ({"viscosity": torch.ones(1, 1, 4, 4)}, False),  # a viscosity field's CG reads its residual on the host
        ({"requires_grad": True}, False),  # a roll-out to differentiate: autograd records every step
        ({"requires_grad": True, "grad_mode": False}, True),  # ...unless grad is off
        ({"capturing": True}, False),  # inside a caller's own capture: theirs records the steps
        ({"pressure": CGConfig(verify_exact=True)}, False),  # the pressure solve runs its CG loop
        ({"pressure": CGConfig(precondition=False)}, False),
        ({"pressure": CGConfig(verify_exact=True), "compressible": True}, True),  # no projection, no solve
        ({"diffusion": CGConfig(verify_exact=True), "viscosity": 0.3}, False),  # the viscosity solve's CG loop
        ({"diffusion": CGConfig(verify_exact=True)}, True),  # zero viscosity: no viscosity solve
    ],
)
def test_which_rollouts_replay_a_captured_step(kwargs, want, monkeypatch):
    from torchfluidwarp.core import graphs

    # the policy alone: stand-ins for CUDA tensors, and the device's state (asking it needs a CUDA driver)
    monkeypatch.setattr(torch.cuda, "is_current_stream_capturing", lambda: kwargs.get("capturing", False))
    monkeypatch.setattr(torch.cuda, "current_device", lambda: 0)
    settings = {k: kwargs[k] for k in ("pressure", "diffusion", "compressible") if k in kwargs}
    step = StableFluidsStep(**settings)
    steps = kwargs.get("steps", graphs.GRAPH_MIN_STEPS)
    velocity = _stand_in(kwargs.get("cuda", True), kwargs.get("requires_grad", False), kwargs.get("index", 0))
    with torch.set_grad_enabled(kwargs.get("grad_mode", True)):
        got = graphs.graphable(step, _stand_in(), velocity, kwargs.get("viscosity", 0.0), steps)
    assert got is want


def _graphable_everywhere(monkeypatch):
    """Make StepGraphs believe every roll-out can be captured, and stand in for the CUDA stream calls."""
    from torchfluidwarp.core import graphs

    streams = []
    monkeypatch.setattr(graphs, "graphable", lambda *args: True)
    monkeypatch.setattr(torch.cuda, "current_stream", lambda device=None: "the caller's stream")
    monkeypatch.setattr(torch.cuda, "set_stream", streams.append)
    monkeypatch.setattr(torch.cuda, "Stream", lambda device=None: "the side stream")
    return graphs, streams


def test_a_step_that_cannot_be_captured_runs_step_by_step_with_a_warning(monkeypatch):
    graphs, streams = _graphable_everywhere(monkeypatch)

    def refuse(*args, **kwargs):
        raise RuntimeError("operation not permitted when stream is capturing")

    monkeypatch.setattr(graphs, "_GraphedStep", refuse)
    step, v = StableFluidsStep(), torch.zeros(1, 2, 9, 9)
    held = graphs.StepGraphs(step)
    with pytest.warns(graphs.GraphCaptureWarning, match="could not be captured in a CUDA graph.*step by step"):
        with held.rollout_step(v.unsqueeze(1).expand(1, 8, 2, 9, 9), v, 0.0, 8) as got:
            assert got is step
    assert streams == ["the caller's stream"]  # the caller's stream is current again
    assert not held._lock.locked() and held.captures == 0


def test_one_replaying_rollout_per_simulator_the_others_run_step_by_step_and_the_capture_is_kept(monkeypatch):
    graphs, _ = _graphable_everywhere(monkeypatch)
    made = []

    class Captured:
        def __init__(self, *args):
            made.append(self)
            self.closed = False

        def close(self):
            self.closed = True

    monkeypatch.setattr(graphs, "_GraphedStep", Captured)
    step, v = StableFluidsStep(), torch.zeros(1, 2, 9, 9)
    forces = v.unsqueeze(1).expand(1, 8, 2, 9, 9)
    held = graphs.StepGraphs(step)
    with held.rollout_step(forces, v, 0.0, 8) as first:
        assert first is made[0]
        with held.rollout_step(forces, v, 0.0, 8) as second:  # another thread's, say
            assert second is step and len(made) == 1
        assert not made[0].closed
    assert not made[0].closed and not held._lock.locked()  # kept for the next roll-out
    with held.rollout_step(forces, v, 0.0, 8) as again:
        assert again is made[0] and held.captures == 1  # replayed, not captured anew
    with held.rollout_step(forces.double(), v.double(), 0.0, 8) as other:
        assert other is made[1] and held.captures == 2  # another dtype: its own capture
    with graphs.StepGraphs(step).rollout_step(forces, v, 0.0, 8) as elsewhere:
        assert elsewhere is made[2]  # another simulator's graphs are its own
    held.clear()
    assert made[0].closed and made[1].closed and not made[2].closed  # freed with the graphs that hold them


def test_a_simulator_holds_no_graphs_unless_asked():
    assert FluidSimulator(8).graphs is None
    sim = FluidSimulator(8, cuda_graphs=True)
    assert sim.graphs is not None and sim.graphs.captures == 0 and sim.graphs.step is sim.step
