"""
The adjoint method: a gradient costs one backward pass
======================================================

Keyframe control fits thousands of force parameters (the control vector ``u``) by L-BFGS, which needs the
gradient of the objective ``phi(u)`` at every evaluation. Finite differences would cost one simulation per
parameter. The adjoint method, here reverse-mode autograd through the solver whose linear solves carry their
own implicit adjoint (:mod:`torchfluidwarp.core.linalg`), costs about one more simulation, **whatever the number
of parameters**.

This example times one forward + backward of a keyframe objective on a 64 x 64 fluid over 10 steps, for
:class:`~torchfluidwarp.warp.forces.ControlGrid` sizes from 3 x 3 to 16 x 16 control points per step
(180 to 5120 parameters).
"""

# %%
# The objective
# -------------
import statistics
import time

import matplotlib.pyplot as plt
import torch

from torchfluidwarp.control import keyframe_loss
from torchfluidwarp.warp import ControlGrid, FluidWarp

size, steps = (256, 256), 10
warp = FluidWarp(grid=(64, 64), steps=steps, image_size=size).double()
gen = torch.Generator().manual_seed(0)
source = 40 + 176 * torch.rand(1, 8, 2, generator=gen, dtype=torch.float64)  # (B, M, 2) pixels
target = source + 6 * torch.randn(1, 8, 2, generator=gen, dtype=torch.float64)


def objective(forces: ControlGrid) -> torch.Tensor:
    """The paper's keyframe objective (pixels^2): points carried through the warp against their targets."""
    paths = warp.carry_points(source, forces)  # (B, T + 1, M, 2) pixels
    return keyframe_loss(paths, [(steps, target)])


def timed(fn, repeats: int = 5) -> float:
    """Median wall time of ``fn()`` in seconds."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


# %%
# Timing
# ------
# Each control grid starts from small random forces. "forward" runs the objective without a graph;
# "forward + backward" also computes the gradient with respect to every parameter.
sizes = [3, 4, 6, 8, 11, 16]
n_params, t_forward, t_gradient = [], [], []
for k in sizes:
    init = 0.01 * torch.randn(1, steps, 2, k, k, generator=gen, dtype=torch.float64)
    forces = ControlGrid(steps, (k, k), init=init).double()

    def forward_only():
        with torch.no_grad():
            objective(forces)

    def forward_backward():
        forces.zero_grad()
        objective(forces).backward()

    forward_backward()  # warm-up
    n_params.append(forces.weight.numel())
    t_forward.append(timed(forward_only))
    t_gradient.append(timed(forward_backward))
    print(
        f"{k:2d} x {k:<2d} control points per step: {n_params[-1]:5d} parameters, "
        f"forward {1e3 * t_forward[-1]:6.1f} ms, forward + backward {1e3 * t_gradient[-1]:6.1f} ms"
    )

# %%
# Is the gradient right?
# ----------------------
# A central finite difference along one random direction against the adjoint's directional derivative.
direction = torch.randn(forces.weight.shape, generator=gen, dtype=torch.float64)
forces.zero_grad()
objective(forces).backward()
adjoint = float((forces.weight.grad * direction).sum())
eps = 1e-5
with torch.no_grad():
    forces.weight += eps * direction
    plus = float(objective(forces))
    forces.weight -= 2 * eps * direction
    minus = float(objective(forces))
    forces.weight += eps * direction
print(f"directional derivative: adjoint {adjoint:.6f}, finite difference {(plus - minus) / (2 * eps):.6f}")

# %%
# The picture
# -----------
# The cost of a gradient stays flat as the control vector grows 28-fold; the dotted line is what finite
# differences would cost (one forward simulation per parameter, plus one).
fig, ax = plt.subplots(figsize=(7, 4.5), layout="constrained")
ax.plot(n_params, [1e3 * t for t in t_gradient], "o-", label="adjoint: forward + backward")
ax.plot(n_params, [1e3 * t for t in t_forward], "s--", label="forward only")
ax.plot(
    n_params,
    [1e3 * (p + 1) * t for p, t in zip(n_params, t_forward)],
    ":",
    color="0.4",
    label="finite differences, estimated: (parameters + 1) forwards",
)
for p, k in zip(n_params, sizes):
    ax.annotate(
        f"{k}x{k}", (p, 1e3 * t_gradient[sizes.index(k)]), (0, 8), textcoords="offset points", ha="center", fontsize=8
    )
ax.set(
    xscale="log",
    yscale="log",
    xlabel="number of force parameters (2 x K x K x 10 steps)",
    ylabel="time per evaluation (ms)",
    title="One gradient of a keyframe objective, 64 x 64 fluid, 10 steps",
)
ax.set_xticks(n_params, [str(p) for p in n_params], minor=False)
ax.set_xticks([], minor=True)
ax.grid(True, which="both", alpha=0.3)
ax.legend(loc="upper left")
plt.show()
