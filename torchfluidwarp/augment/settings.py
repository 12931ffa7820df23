"""The settings of a random fluid warp: one validated dataclass that every augmentation entry point builds.

:class:`FluidWarpSettings` is the one place the augmentation's arguments are declared, checked and documented.
:class:`~torchfluidwarp.augment.tensor.FluidWarpAugment`, :func:`~torchfluidwarp.augment.tensor.random_fluid_warp`
and the torchvision transform :class:`~torchfluidwarp.augment.transforms.RandomFluidWarp` take the same keyword
arguments (``count=(1, 3), strength=0.2, grid=16, ...``) and hand them to :func:`make_settings`, or take a ready
``settings=FluidWarpSettings(...)``. :func:`settings_signature` shows the fields in their signatures.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable, Sequence
from dataclasses import KW_ONLY, dataclass
from typing import Any, TypeVar

from torchfluidwarp._checks import check_instance, check_int, check_positive, describe
from torchfluidwarp.core.grid import FluidGrid
from torchfluidwarp.errors import InputError, InputTypeError

__all__ = ["MAX_SHEAR", "FluidWarpSettings", "make_settings", "settings_signature"]

MAX_SHEAR: float = 2.0
"""Bound on ``S * max(1, T / 4)`` where ``S = count_max * strength_max * steps_max * dt**2 / radius_min``.

``S`` is the velocity difference across one brush radius, per step, of all brushes stacked on one spot (the
worst case): a step folds where it nears 1 to 2. ``S * T / 4`` is half the stacked brushes' free displacement
``count * strength * (T dt)^2 / 2`` in radii. In a sweep over 64 to 512 px images, 16 to 64 cell grids,
2 to 16 steps and dt 1 to 2, stacked brushes at this bound folded no map when their radius was 8% of the
image size; at 20% and 40% of it some did (the walls crowd the flow), and the map check catches those."""

Number = int | float
RangeArg = Number | Sequence[Number]


def _range(name: str, value: RangeArg, *, integer: bool, minimum: float, strict: bool) -> tuple[Any, Any]:
    """``value`` or ``(lo, hi)`` as a validated closed range."""
    pair = (value, value) if isinstance(value, (int, float)) and not isinstance(value, bool) else value
    if not isinstance(pair, (tuple, list)) or len(pair) != 2:
        raise InputTypeError(f"{name} must be a number or a pair (min, max), got {describe(value)}")
    lo, hi = pair
    for v in (lo, hi):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (integer and not isinstance(v, int)):
            raise InputTypeError(f"{name} must hold {'ints' if integer else 'numbers'}, got {describe(value)}")
        if not math.isfinite(v) or v < minimum or (strict and v == minimum):
            raise InputError(f"{name} must be finite and {'>' if strict else '>='} {minimum}, got {tuple(pair)}")
    if hi < lo:
        raise InputError(f"{name} must be (min, max) with min <= max, got {tuple(pair)}")
    return (int(lo), int(hi)) if integer else (float(lo), float(hi))


@dataclass(frozen=True)
class FluidWarpSettings:
    """How a random fluid warp is drawn: ranges for the brushes, the fluid, and the fold guard.

    Per sample, ``count`` brushes are placed uniformly over the image, each pushing in a uniformly random
    direction with its own ``strength`` and ``radius``, steadily for ``steps`` fluid steps. Every range is
    ``(min, max)`` (closed; a single number fixes the value) and is drawn uniformly. Values are validated and
    normalised when the settings are built: the fields read back as ``(min, max)`` tuples and a
    :class:`~torchfluidwarp.core.grid.FluidGrid`.

    Args:
        count: number of brushes per sample (ints).
        strength: peak acceleration of a brush in pixels per time unit^2. A single brush of strength ``a``,
            radius ``r`` pushing for ``T`` steps moves the image's centre by roughly ``a T^2 dt^2 / 2`` px
            (less: the fluid around it resists).
        radius: Gaussian radius of a brush in pixels (> 0; keep it above a fluid cell, ``W / w`` px).
        steps: number of fluid steps per sample (ints).
        grid: fluid grid ``(h, w)`` (an int for square); it covers the whole image (or canvas) whatever its size.
        dt: time step (time units).
        viscosity: constant viscosity (cells^2 per time unit); it smooths the flow.
        edge_points: points carried per box edge.
        max_retries: how many times a sample whose map would fold is rolled out again with half its force
            before it is left unwarped.
        max_memory: bytes one draw may set out to hold (its roll-out and maps); default
            :data:`torchfluidwarp._checks.MAX_BYTES`. A larger draw is refused before any work.

    Raises:
        TypeError, ValueError: a range that is not a number or a pair, empty, negative or non-finite, naming it;
            or a setting strong enough to fold: ``S * max(1, steps_max / 4)`` with
            ``S = count_max * strength_max * steps_max * dt**2 / radius_min`` must be at most :data:`MAX_SHEAR`.

    Example:
        >>> s = FluidWarpSettings(count=2, strength=(0.1, 0.3), grid=16)
        >>> s.count, s.grid.shape
        ((2, 2), (16, 16))
        >>> dataclasses.replace(s, dt=0.5).dt
        0.5
    """

    count: tuple[int, int] = (1, 4)
    strength: tuple[float, float] = (0.1, 0.5)
    radius: tuple[float, float] = (16.0, 48.0)
    steps: tuple[int, int] = (4, 8)
    _: KW_ONLY
    grid: FluidGrid = FluidGrid(32, 32)
    dt: float = 1.0
    viscosity: float = 0.0
    edge_points: int = 8
    max_retries: int = 3
    max_memory: float | None = None

    def __post_init__(self) -> None:
        normalised = {
            "count": _range("count", self.count, integer=True, minimum=1, strict=False),
            "strength": _range("strength", self.strength, integer=False, minimum=0.0, strict=False),
            "radius": _range("radius", self.radius, integer=False, minimum=0.0, strict=True),
            "steps": _range("steps", self.steps, integer=True, minimum=1, strict=False),
            "grid": FluidGrid.of(self.grid),
            "dt": check_positive("dt", self.dt),
            "viscosity": check_positive("viscosity", self.viscosity, allow_zero=True),
            "edge_points": _at_most(
                "edge_points", check_int("edge_points", self.edge_points, minimum=2), MAX_EDGE_POINTS
            ),
            "max_retries": check_int("max_retries", self.max_retries, minimum=0),
            "max_memory": None if self.max_memory is None else check_positive("max_memory", self.max_memory),
        }
        for name, value in normalised.items():
            object.__setattr__(self, name, value)  # frozen: validated once, here
        stretch = self.stretch
        if stretch > MAX_SHEAR:
            limit = self.strength[1] * MAX_SHEAR / stretch
            raise InputError(
                f"strength up to {self.strength[1]} px/time^2 could fold the warp: with count={self.count}, "
                f"steps={self.steps}, radius={self.radius} px and dt={self.dt}, S * max(1, T / 4) = {stretch:.3g} "
                f"> MAX_SHEAR = {MAX_SHEAR} (S = count_max * strength_max * steps_max * dt^2 / radius_min); "
                f"keep strength <= {limit:.4g}, or widen the smallest radius"
            )

    @property
    def stretch(self) -> float:
        """The dimensionless worst case ``S * max(1, steps_max / 4)`` bounded by :data:`MAX_SHEAR`: all brushes
        stacked, at the largest strength and steps and the smallest radius."""
        shear = self.count[1] * self.strength[1] * self.steps[1] * self.dt**2 / self.radius[0]
        return shear * max(1.0, self.steps[1] / 4)

    def describe(self) -> str:
        """The settings for a ``repr``: ``count=(1, 4), strength=..., grid=(32, 32), dt=..., viscosity=...``."""
        return (
            f"count={self.count}, strength={self.strength}, radius={self.radius}, steps={self.steps}, "
            f"grid={self.grid.shape}, dt={self.dt}, viscosity={self.viscosity}"
        )


MAX_EDGE_POINTS = 1024
"""The most points carried per box edge (``edge_points``): more cannot follow a fluid grid any better."""


def _at_most(name: str, value: int, limit: int) -> int:
    if value > limit:
        raise InputError(f"{name} must be at most {limit}, got {value}")
    return value


FIELDS = frozenset(f.name for f in dataclasses.fields(FluidWarpSettings))
"""The names of :class:`FluidWarpSettings`' fields."""


def make_settings(settings: FluidWarpSettings | None, *args: Any, **kwargs: Any) -> FluidWarpSettings:
    """The settings of a call: ``FluidWarpSettings(*args, **kwargs)``, or ``settings`` with ``kwargs`` replaced.

    Args:
        settings: ready settings, or ``None`` to build them from ``args`` and ``kwargs``.
        args: ``count, strength, radius, steps`` by position (only without ``settings``).
        kwargs: fields of :class:`FluidWarpSettings` by name.

    Raises:
        TypeError: ``settings`` that is not a :class:`FluidWarpSettings`, positional ranges next to it, or an
            unknown keyword; and whatever :class:`FluidWarpSettings` raises for the values.
    """
    unknown = sorted(set(kwargs) - FIELDS)
    if unknown:
        raise InputTypeError(f"unknown fluid warp setting(s) {unknown}; the settings are {sorted(FIELDS)}")
    if settings is None:
        return FluidWarpSettings(*args, **kwargs)
    check_instance("settings", settings, FluidWarpSettings, optional=True)
    if args:
        raise InputTypeError(f"pass the ranges by name next to settings (to replace them), got positional {args!r}")
    return dataclasses.replace(settings, **kwargs) if kwargs else settings


_F = TypeVar("_F", bound=Callable[..., Any])


def settings_signature(func: _F) -> _F:
    """Show :class:`FluidWarpSettings`' fields in ``func``'s signature (``help``, IDEs, Sphinx).

    ``func`` takes the fields as ``*ranges`` (``count, strength, radius, steps`` by position; optional) and
    ``**kwargs``, next to a keyword ``settings``, and passes them to :func:`make_settings`. Its signature then
    lists the positional fields in place of ``*ranges``, and the rest, keyword-only, just before ``settings``.
    """
    fields = list(inspect.signature(FluidWarpSettings).parameters.values())
    params: list[inspect.Parameter] = []
    for p in inspect.signature(func).parameters.values():
        if p.kind == p.VAR_POSITIONAL:
            params += [f for f in fields if f.kind == f.POSITIONAL_OR_KEYWORD]
        elif p.name == "settings":
            shown = {q.name for q in params}
            params += [f.replace(kind=f.KEYWORD_ONLY) for f in fields if f.name not in shown]
        if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            params.append(p)
    func.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    return func
