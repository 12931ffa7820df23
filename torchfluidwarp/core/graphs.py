"""Replaying the fluid step from a CUDA graph: a roll-out on a GPU without a kernel launch per operator.

On a GPU a step of a 64 x 64 fluid is some 240 small operators whose launches, not their arithmetic, set its time
(about 1 ms a step on an H100 against 0.25 ms replayed, ``benchmarks/bench_device.py``). A
:class:`~torchfluidwarp.core.simulator.FluidSimulator` built with ``cuda_graphs=True`` holds a :class:`StepGraphs`:
its step captured once per batch shape, dtype, device and viscosity, on first use, and replayed by every later
roll-out of that simulator. Nothing is held by the module or the process: the graphs go with the simulator (or
with :meth:`StepGraphs.clear`).

A roll-out replays its step when it runs on the current CUDA device, has at least :data:`GRAPH_MIN_STEPS` steps,
records no gradient, has a float viscosity, and every linear solve of its step is exact (no conjugate-gradient
loop: a viscosity field, ``CGConfig(precondition=False)`` or ``verify_exact=True`` read a residual on the host
every iteration). Its velocities are those of the step run step by step (``tests/core/test_simulator.py``). One
roll-out of a simulator replays at a time (a lock of the instance; another thread meanwhile runs step by step).
Where capture fails, the roll-out warns and runs step by step.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Protocol

import torch
from torch import Tensor

from torchfluidwarp._checks import warn
from torchfluidwarp.core.linalg import CGConfig

if TYPE_CHECKING:
    from torchfluidwarp.core.fluid import Viscosity
    from torchfluidwarp.core.simulator import StableFluidsStep

__all__ = ["GRAPH_MIN_STEPS", "GraphCaptureWarning", "StepGraphs"]

GRAPH_MIN_STEPS = 8
"""The fewest steps of a roll-out that replays its step from a CUDA graph: shorter ones do not repay the
capture (two warm-up steps and the capture itself)."""


class GraphCaptureWarning(RuntimeWarning):
    """The fluid step could not be captured in a CUDA graph; the roll-out runs step by step (same result)."""


class Step(Protocol):
    """What a roll-out calls once per step: :class:`~torchfluidwarp.core.simulator.StableFluidsStep`'s signature."""

    def __call__(
        self, velocity: Tensor, force: Tensor, viscosity: Viscosity, staggered: bool = ...
    ) -> tuple[Tensor, tuple[int, int]]: ...


def _exact(config: CGConfig) -> bool:
    # the solve returns its preconditioner's application at once, with no host read (linalg.conjugate_gradient)
    return config.precondition and not config.verify_exact


def graphable(step: StableFluidsStep, forces: Tensor, velocity: Tensor, viscosity: Viscosity, steps: int) -> bool:
    """Whether a roll-out of ``step`` can replay it from a CUDA graph (see the module's docstring)."""
    if not velocity.is_cuda or steps < GRAPH_MIN_STEPS or isinstance(viscosity, Tensor):
        return False
    if torch.is_grad_enabled() and (forces.requires_grad or velocity.requires_grad):
        return False
    solves = [] if step.project is None else [step.project.config]
    solves += [] if viscosity == 0 else [step.diffuse.config]
    if not all(_exact(c) for c in solves):
        return False
    # the current device only (a capture and its replays run on the current device's streams); not inside a
    # caller's own capture, which records the steps itself
    return velocity.device.index == torch.cuda.current_device() and not torch.cuda.is_current_stream_capturing()


class _GraphedStep:
    """A no-grad step captured in a CUDA graph: each call copies the velocity and force into the graph's input
    buffers, replays it and returns a copy of its output. Captured after two warm-up steps on the side stream (as
    ``torch.cuda.graphs`` asks), which also fill the library's caches of grid constants outside the capture."""

    def __init__(
        self, step: Step, velocity: Tensor, force: Tensor, viscosity: Viscosity, side: torch.cuda.Stream
    ) -> None:
        self.viscosity = viscosity
        self.velocity, self.force = velocity.clone(), force.clone()
        side.wait_stream(torch.cuda.current_stream(velocity.device))
        with torch.no_grad(), torch.cuda.stream(side):
            for _ in range(2):
                step(self.velocity, self.force, viscosity, staggered=True)
        torch.cuda.current_stream(velocity.device).wait_stream(side)
        self.graph = torch.cuda.CUDAGraph()
        # thread_local: other threads' CUDA work (a frame worker, a server's other jobs) may go on meanwhile
        with torch.no_grad(), torch.cuda.graph(self.graph, stream=side, capture_error_mode="thread_local"):
            self.out, self.iterations = step(self.velocity, self.force, viscosity, staggered=True)

    def __call__(
        self, velocity: Tensor, force: Tensor, viscosity: Viscosity, staggered: bool = True
    ) -> tuple[Tensor, tuple[int, int]]:
        if viscosity is not self.viscosity or not staggered:
            raise RuntimeError("a captured step replays the viscosity it was captured with, on staggered forces")
        self.velocity.copy_(velocity)
        self.force.copy_(force)
        self.graph.replay()
        return self.out.clone(), self.iterations

    def close(self) -> None:
        self.graph.reset()


class StepGraphs:
    """The CUDA graphs of one simulator's step, captured on first use per batch shape, dtype, device and viscosity,
    and replayed by every later roll-out; owned by the simulator.

    Attributes:
        captures: how many captures this instance has made (a roll-out that replays makes none).
    """

    def __init__(self, step: StableFluidsStep) -> None:
        self.step = step
        self.captures = 0
        self._graphs: dict[tuple, _GraphedStep] = {}
        self._streams: dict[torch.device, torch.cuda.Stream] = {}
        self._lock = threading.Lock()

    def clear(self) -> None:
        """Free the graphs and their memory."""
        with self._lock:
            for graphed in self._graphs.values():
                graphed.close()
            self._graphs.clear()

    @contextmanager
    def rollout_step(self, forces: Tensor, velocity: Tensor, viscosity: Viscosity, steps: int) -> Iterator[Step]:
        """The step for each step of a roll-out: the step module itself, or its replayed capture where
        :func:`graphable` allows and no other roll-out of this simulator is replaying. ``forces`` are the
        roll-out's staggered forces ``(B, T, 2, h + 1, w + 1)`` and ``velocity`` its initial velocity."""
        if not graphable(self.step, forces, velocity, viscosity, steps) or not self._lock.acquire(blocking=False):
            yield self.step
            return
        try:
            key = (tuple(velocity.shape), velocity.dtype, velocity.device, float(viscosity))
            graphed = self._graphs.get(key)
            if graphed is None:
                graphed = self._capture(key, forces[:, 0], velocity, viscosity)
            yield self.step if graphed is None else graphed
        finally:
            self._lock.release()

    def _capture(self, key: tuple, force: Tensor, velocity: Tensor, viscosity: Viscosity) -> _GraphedStep | None:
        stream = torch.cuda.current_stream(velocity.device)
        side = self._streams.setdefault(velocity.device, torch.cuda.Stream(device=velocity.device))
        try:
            graphed = _GraphedStep(self.step, velocity, force, viscosity, side)
        except Exception as e:  # noqa: BLE001  (any failure to capture leaves the same roll-out, step by step)
            torch.cuda.set_stream(stream)  # a capture that fails while ending may leave its stream current
            warn(
                f"the fluid step could not be captured in a CUDA graph ({type(e).__name__}: {e}); the roll-out runs "
                "step by step",
                GraphCaptureWarning,
            )
            return None
        self.captures += 1
        self._graphs[key] = graphed
        return graphed
