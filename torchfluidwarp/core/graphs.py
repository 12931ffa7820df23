"""Replaying the fluid step from a CUDA graph: a roll-out on a GPU without a kernel launch per operator.

On a GPU a step of a 64 x 64 fluid is some 240 small operators whose launches, not their arithmetic, set its time
(about 1 ms a step on an H100 against 0.25 ms replayed, ``benchmarks/bench_device.py``). :func:`rollout_step`
gives :class:`~torchfluidwarp.core.simulator.FluidSimulator` the step to call for each step of a roll-out: the
module itself, or, where it can, one step captured in a CUDA graph and replayed.

A roll-out replays its step when it runs on the current CUDA device, has at least :data:`GRAPH_MIN_STEPS` steps,
records no gradient, has a float viscosity, and every linear solve of its step is exact (no conjugate-gradient
loop: a viscosity field, ``CGConfig(precondition=False)`` or ``verify_exact=True`` read a residual on the host
every iteration). Its velocities are those of the step run step by step (``tests/core/test_simulator.py``).

The cost: each such roll-out captures its step once (two warm-up steps and a capture; ``torch.cuda.graph``
synchronises the device and empties the allocator's cache first), and holds the graph's memory until it ends.
One graphed roll-out runs at a time in a process (a lock; another thread meanwhile runs step by step), on one
side stream per device, so that no two of the library's graphs are alive at once and none shares a stream with
a caller's own graphs. Where capture fails, the roll-out warns and runs step by step.
"""

from __future__ import annotations

import functools
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Protocol

import torch
from torch import Tensor

from torchfluidwarp.core.linalg import CGConfig

if TYPE_CHECKING:
    from torchfluidwarp.core.fluid import Viscosity
    from torchfluidwarp.core.simulator import StableFluidsStep

__all__ = ["GRAPH_MIN_STEPS", "GraphCaptureWarning", "rollout_step"]

GRAPH_MIN_STEPS = 8
"""The fewest steps of a roll-out that replays its step from a CUDA graph: shorter ones do not repay the
capture (two warm-up steps and the capture itself)."""

_ONE_AT_A_TIME = threading.Lock()


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


@functools.cache
def _side_stream(device: torch.device) -> torch.cuda.Stream:
    """Memo: the one stream per device that the library's captures run on."""
    return torch.cuda.Stream(device=device)


class _GraphedStep:
    """A no-grad step captured in a CUDA graph: each call copies the velocity and force into the graph's input
    buffers, replays it and returns a copy of its output. Captured after two warm-up steps on the side stream (as
    ``torch.cuda.graphs`` asks), which also fill the library's caches of grid constants outside the capture."""

    def __init__(self, step: Step, velocity: Tensor, force: Tensor, viscosity: Viscosity) -> None:
        self.viscosity = viscosity
        self.velocity, self.force = velocity.clone(), force.clone()
        side = _side_stream(velocity.device)
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
            raise ValueError("a captured step replays the viscosity it was captured with, on staggered forces")
        self.velocity.copy_(velocity)
        self.force.copy_(force)
        self.graph.replay()
        return self.out.clone(), self.iterations

    def close(self) -> None:
        self.graph.reset()


@contextmanager
def rollout_step(
    step: StableFluidsStep, forces: Tensor, velocity: Tensor, viscosity: Viscosity, steps: int
) -> Iterator[Step]:
    """The step for each step of a roll-out: ``step`` itself, or its capture where :func:`graphable` allows and no
    other graphed roll-out is running. ``forces`` are the roll-out's staggered forces ``(B, T, 2, h + 1, w + 1)``
    and ``velocity`` its initial velocity; the graph is freed on leaving the block."""
    if not graphable(step, forces, velocity, viscosity, steps) or not _ONE_AT_A_TIME.acquire(blocking=False):
        yield step
        return
    try:
        stream = torch.cuda.current_stream(velocity.device)
        graphed: _GraphedStep | None = None
        try:
            graphed = _GraphedStep(step, velocity, forces[:, 0], viscosity)
        except Exception as e:  # noqa: BLE001  (any failure to capture leaves the same roll-out, step by step)
            torch.cuda.set_stream(stream)  # a capture that fails while ending may leave its stream current
            warnings.warn(
                f"the fluid step could not be captured in a CUDA graph ({type(e).__name__}: {e}); the roll-out runs "
                "step by step",
                GraphCaptureWarning,
                stacklevel=4,
            )
        if graphed is None:
            yield step
            return
        try:
            yield graphed
        finally:
            graphed.close()
    finally:
        _ONE_AT_A_TIME.release()
