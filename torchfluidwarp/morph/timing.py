"""Timing of a morph: how the shape and the colour progress over the morph's time ``t`` in ``[0, 1]``.

A schedule maps ``t`` to a progress in ``[0, 1]``, from 0 at ``t = 0`` to 1 at ``t = 1``, never going back. The
shape's progress picks the fluid time (``progress * T`` steps) and the pre-alignment's share; the colour's is the
cross-dissolve's weight of image B. Give the shape a schedule that leads the colour (``"ease-out"`` for the
shape, ``"ease-in"`` for the colour) and the features arrive before their colours change:
``morph(a, b, pa, pb, timing=Timing(motion="ease-out", blend="ease-in"))``
(:class:`~torchfluidwarp.morph.settings.Timing`).

A schedule is a name or a few control points ``[(t, progress), ...]`` joined by straight lines:

* ``"linear"``: ``t`` (the paper's cross-dissolve);
* ``"smooth"``: smoothstep ``t^2 (3 - 2t)``, easing in and out;
* ``"ease-in"``: ``t^2``, slow at first; ``"ease-out"``: ``1 - (1 - t)^2``, slow at the end;
* e.g. ``[(0, 0), (0.3, 0.7), (1, 1)]``: 70% of the change in the first 30% of the time.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Literal

from torchfluidwarp._checks import describe
from torchfluidwarp.errors import InputError, InputTypeError

__all__ = ["Schedule", "EASINGS", "schedule"]

Easing = Literal["linear", "smooth", "ease-in", "ease-out"]
Schedule = Easing | Sequence[Sequence[float]]
"""A schedule: an easing name or control points ``[(t, progress), ...]`` (the fields of
:class:`~torchfluidwarp.morph.settings.Timing`)."""

EASINGS: dict[str, Callable[[float], float]] = {
    "linear": lambda t: t,
    "smooth": lambda t: t * t * (3 - 2 * t),
    "ease-in": lambda t: t * t,
    "ease-out": lambda t: 1 - (1 - t) * (1 - t),
}
"""The named schedules: ``t`` in ``[0, 1]`` to progress in ``[0, 1]``."""


def schedule(name: str, timing: object) -> Callable[[float], float]:
    """The schedule ``t -> progress`` for a name in :data:`EASINGS` or control points ``[(t, progress), ...]``.

    Control points run from ``(0, 0)`` to ``(1, 1)``, with ``t`` increasing and ``progress`` never decreasing.

    Example:
        >>> f = schedule("motion", [(0, 0), (0.5, 0.8), (1, 1)])
        >>> round(f(0.25), 6), round(f(0.75), 6)
        (0.4, 0.9)

    Raises:
        ValueError, TypeError: naming ``name``, for an unknown easing or control points that do not qualify.
    """
    if isinstance(timing, str):
        if timing not in EASINGS:
            raise InputError(f"{name} must be one of {', '.join(map(repr, EASINGS))} or control points, got {timing!r}")
        return EASINGS[timing]
    try:
        points = [(float(t), float(v)) for t, v in timing]  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise InputTypeError(
            f"{name} must be an easing name or control points [(t, progress), ...], got {describe(timing)}"
        ) from None
    ts, vs = [t for t, _ in points], [v for _, v in points]
    if len(points) < 2 or ts[0] != 0 or ts[-1] != 1 or vs[0] != 0 or vs[-1] != 1:
        raise InputError(f"{name}'s control points must run from (0, 0) to (1, 1), got {points}")
    if not all(math.isfinite(x) for x in ts + vs):
        raise InputError(f"{name}'s control points must be finite, got {points}")
    if any(b <= a for a, b in zip(ts, ts[1:])) or any(b < a for a, b in zip(vs, vs[1:])):
        raise InputError(f"{name}'s control points need increasing t and non-decreasing progress, got {points}")

    def piecewise(t: float) -> float:
        for (t0, v0), (t1, v1) in zip(points, points[1:]):
            if t <= t1:
                return v0 + (v1 - v0) * (t - t0) / (t1 - t0)
        return 1.0

    return piecewise
