"""The animation settings: one frozen configuration, read from JSON or built from ``--brush``-style values.

The JSON file (every key optional; unknown keys are an error, to catch typos)::

    {
      "brushes": [
        {"position": [x, y], "direction": [dx, dy], "radius": r,
         "frequency": f, "amplitude": a, "phase": p}
      ],
      "viscosity": {
        "base": 0.0,
        "regions": [{"position": [x, y], "radius": r, "value": v}],
        "mask": "stiff.png", "stiff": 5.0, "soft": 0.0
      },
      "grid": [64, 64],
      "steps": 60,
      "dt": 1.0,
      "fps": 20
    }

Units and meaning:

* ``position``, ``radius``: pixels of the input image, ``(x, y)`` with pixel centres at integers.
* ``direction``: the push direction, any non-zero length (it is normalised).
* ``amplitude``: peak acceleration in pixels per time unit^2 (may be negative). An oscillating brush moves the
  image by roughly ``amplitude / (2 pi frequency)^2`` pixels.
* ``frequency``: oscillations per time unit (0 = a steady push); ``phase``: radians (default 0).
  A brush needs ``position``, ``direction``, ``radius`` and ``amplitude``; ``frequency`` and ``phase``
  default to 0.
* ``viscosity``: fluid cells^2 per time unit; high values make a region resist deformation. The field is
  ``base`` plus a Gaussian bump of height ``value`` for each region (negative values soften; the sum is
  clamped at 0), plus ``soft + (stiff - soft) * mask`` when ``mask`` names a gray image (1 = stiff) of the
  input image's size. A relative ``mask`` path is relative to the JSON file.
* ``grid``: fluid cells ``[h, w]`` (or one int for a square grid); by default 64 along the image's longer
  side. ``steps``: fluid steps (the animation has ``steps + 1`` frames); ``dt``: time units per step;
  ``fps``: frames per second of the output.

Values are checked with the library's validators (:mod:`torchfluidwarp._checks`); every error is a
``ValueError`` naming the key path, e.g. ``brushes[1].radius``, and the value received.

Example:
    >>> cfg = parse_config({"brushes": [{"position": [20, 30], "direction": [0, 1], "radius": 8,
    ...                                  "frequency": 0.05, "amplitude": 0.5}], "steps": 10})
    >>> cfg.steps, cfg.brushes[0].position
    (10, (20.0, 30.0))
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from torchfluidwarp._checks import check_int, check_positive, check_real, check_size, describe
from torchfluidwarp.core.grid import rescale_points
from torchfluidwarp.errors import InputError

__all__ = [
    "BrushSpec",
    "RegionSpec",
    "ViscositySpec",
    "AnimationConfig",
    "parse_config",
    "load_config",
    "config_json",
    "brush_from_values",
    "region_from_values",
]


@dataclass(frozen=True)
class BrushSpec:
    """One oscillating Gaussian brush; see :class:`~torchfluidwarp.warp.forces.Brushes` (pixels, radians)."""

    position: tuple[float, float]
    direction: tuple[float, float]
    radius: float
    amplitude: float
    frequency: float = 0.0
    phase: float = 0.0


@dataclass(frozen=True)
class RegionSpec:
    """A Gaussian bump of viscosity ``value`` (cells^2 per time unit) at ``position`` (pixels)."""

    position: tuple[float, float]
    radius: float
    value: float


@dataclass(frozen=True)
class ViscositySpec:
    """The viscosity field: ``base`` + region bumps (+ a mask's ``soft``..``stiff`` map if ``mask`` is set)."""

    base: float = 0.0
    regions: tuple[RegionSpec, ...] = ()
    mask: Path | None = None
    stiff: float = 5.0
    soft: float = 0.0


@dataclass(frozen=True)
class AnimationConfig:
    """Everything an animation needs besides the image. ``grid=None`` means
    :func:`~torchfluidwarp.apps.animate.pipeline.auto_grid`."""

    brushes: tuple[BrushSpec, ...] = ()
    viscosity: ViscositySpec = ViscositySpec()
    grid: tuple[int, int] | None = None
    steps: int = 60
    dt: float = 1.0
    fps: float = 20.0

    def rescaled(self, sx: float, sy: float) -> AnimationConfig:
        """The same animation on the image resized by ``(sx, sy)``: positions, radii and amplitudes scale.

        Positions move with :func:`~torchfluidwarp.core.grid.rescale_points` (pixel centres at integers,
        ``x' = (x + 0.5) sx - 0.5``); radii and accelerations scale by the mean factor. Viscosities are per
        fluid cell and do not change.
        """
        scale = torch.tensor([sx, sy], dtype=torch.float64)

        def pos(p: tuple[float, float]) -> tuple[float, float]:
            x, y = rescale_points(torch.tensor(p, dtype=torch.float64), scale).tolist()
            return (x, y)

        s = 0.5 * (sx + sy)
        brushes = tuple(
            dataclasses.replace(b, position=pos(b.position), radius=b.radius * s, amplitude=b.amplitude * s)
            for b in self.brushes
        )
        regions = tuple(
            dataclasses.replace(r, position=pos(r.position), radius=r.radius * s) for r in self.viscosity.regions
        )
        viscosity = dataclasses.replace(self.viscosity, regions=regions)
        return dataclasses.replace(self, brushes=brushes, viscosity=viscosity)


# ----------------------------------------------------------------------------------------------- reading

_TOP_KEYS = ("brushes", "viscosity", "grid", "steps", "dt", "fps")
_BRUSH_KEYS = ("position", "direction", "radius", "frequency", "amplitude", "phase")
_VISCOSITY_KEYS = ("base", "regions", "mask", "stiff", "soft")
_REGION_KEYS = ("position", "radius", "value")


def load_config(path: str | Path) -> AnimationConfig:
    """Read and validate an animation JSON file (format in the module docstring).

    Raises:
        ValueError: the file is missing or unreadable, is not valid JSON, or breaks the schema; the one-line
            message names the file and the offending key and value.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"cannot read config {str(path)!r}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read config {str(path)!r}: {exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"config {str(path)!r} is not valid JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})"
        ) from None
    except RecursionError:  # the decoder recurses once per level: a few bytes of "[[[[..." exhaust the stack
        raise InputError(f"config {str(path)!r} is nested too deeply to be an animation config") from None
    try:
        return parse_config(data, base_dir=path.parent)
    except InputError as exc:
        raise InputError(f"config {str(path)!r}: {exc}") from None


def parse_config(data: object, *, base_dir: Path | None = None) -> AnimationConfig:
    """Validate a decoded JSON object (format in the module docstring).

    Args:
        data: the decoded JSON.
        base_dir: folder a relative ``viscosity.mask`` path is relative to (default: the working folder).

    Returns:
        The validated configuration; missing keys take the :class:`AnimationConfig` defaults.

    Raises:
        ValueError: a wrong type or value, a missing required key, or an unknown key; the message names the key
            path, e.g. ``brushes[1].radius``, and the value received.
    """
    with _as_value_error():
        obj = _object("the top level", data, _TOP_KEYS)
        fields: dict[str, Any] = {}
        if "brushes" in obj:
            fields["brushes"] = tuple(
                _brush(f"brushes[{k}]", b) for k, b in enumerate(_list("brushes", obj["brushes"]))
            )
        if "viscosity" in obj:
            fields["viscosity"] = _viscosity(obj["viscosity"], base_dir)
        if "grid" in obj:
            fields["grid"] = check_size("grid", obj["grid"], minimum=2)
        if "steps" in obj:
            fields["steps"] = check_int("steps", obj["steps"], minimum=1)
        for key in ("dt", "fps"):
            if key in obj:
                fields[key] = check_positive(key, obj[key])
        return AnimationConfig(**fields)


def brush_from_values(values: Sequence[float], where: str = "brush") -> BrushSpec:
    """A brush from ``X, Y, DX, DY, RADIUS, FREQ, AMP[, PHASE]`` (the order of ``--brush``).

    Raises:
        ValueError: not 7 or 8 values, or an invalid one (named with ``where``).
    """
    if len(values) not in (7, 8):
        raise InputError(f"{where} needs 7 or 8 values X,Y,DX,DY,RADIUS,FREQ,AMP[,PHASE], got {len(values)}")
    x, y, dx, dy, radius, freq, amp, *phase = values
    spec = {"position": [x, y], "direction": [dx, dy], "radius": radius, "frequency": freq, "amplitude": amp}
    with _as_value_error():
        return _brush(where, {**spec, "phase": phase[0] if phase else 0.0})


def region_from_values(values: Sequence[float], where: str = "region") -> RegionSpec:
    """A viscosity region from ``X, Y, RADIUS, VALUE`` (the order of ``--stiff``).

    Raises:
        ValueError: not 4 values, or an invalid one (named with ``where``).
    """
    if len(values) != 4:
        raise InputError(f"{where} needs 4 values X,Y,RADIUS,VALUE, got {len(values)}")
    x, y, radius, value = values
    with _as_value_error():
        return _region(where, {"position": [x, y], "radius": radius, "value": value})


def config_json(config: AnimationConfig) -> dict[str, Any]:
    """``config`` as the JSON :func:`parse_config` reads (a mask path is left out: it names a local file)."""
    viscosity = config.viscosity
    out: dict[str, Any] = {
        "brushes": [dataclasses.asdict(b) for b in config.brushes],
        "viscosity": {"base": viscosity.base, "regions": [dataclasses.asdict(r) for r in viscosity.regions]},
        "steps": config.steps,
        "dt": config.dt,
        "fps": config.fps,
    }
    if config.grid is not None:
        out["grid"] = list(config.grid)
    return out


@contextlib.contextmanager
def _as_value_error() -> Iterator[None]:
    """Turn the validators' ``TypeError`` (a wrong JSON type) into the ``ValueError`` this module promises."""
    try:
        yield
    except TypeError as exc:
        raise InputError(str(exc)) from None


def _object(where: str, value: object, allowed: Sequence[str], required: Sequence[str] = ()) -> Mapping:
    if not isinstance(value, Mapping):
        raise InputError(f"{where} must be a JSON object, got {describe(value)}")
    unknown = [k for k in value if k not in allowed]
    if unknown:
        raise InputError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(allowed)})")
    missing = [k for k in required if k not in value]
    if missing:
        raise InputError(f"{where}: missing key {missing[0]!r}")
    return value


def _list(where: str, value: object) -> list:
    if not isinstance(value, list):
        raise InputError(f"{where} must be a list, got {describe(value)}")
    return value


def _pair(where: str, value: object) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise InputError(f"{where} must be a pair [x, y] of numbers, got {describe(value)}")
    return (check_real(f"{where}[0]", value[0]), check_real(f"{where}[1]", value[1]))


def _brush(where: str, value: object) -> BrushSpec:
    obj = _object(where, value, _BRUSH_KEYS, required=("position", "direction", "radius", "amplitude"))
    direction = _pair(f"{where}.direction", obj["direction"])
    if direction == (0.0, 0.0):
        raise InputError(f"{where}.direction must be a non-zero vector, got [0, 0]")
    return BrushSpec(
        position=_pair(f"{where}.position", obj["position"]),
        direction=direction,
        radius=check_positive(f"{where}.radius", obj["radius"]),
        frequency=check_positive(f"{where}.frequency", obj.get("frequency", 0.0), allow_zero=True),
        amplitude=check_real(f"{where}.amplitude", obj["amplitude"]),
        phase=check_real(f"{where}.phase", obj.get("phase", 0.0)),
    )


def _region(where: str, value: object) -> RegionSpec:
    obj = _object(where, value, _REGION_KEYS, required=_REGION_KEYS)
    return RegionSpec(
        position=_pair(f"{where}.position", obj["position"]),
        radius=check_positive(f"{where}.radius", obj["radius"]),
        value=check_real(f"{where}.value", obj["value"]),
    )


def _viscosity(value: object, base_dir: Path | None) -> ViscositySpec:
    obj = _object("viscosity", value, _VISCOSITY_KEYS)
    mask = obj.get("mask")
    if mask is not None:
        if not isinstance(mask, str) or not mask:
            raise InputError(f"viscosity.mask must be an image path (a string), got {describe(mask)}")
        mask = Path(mask) if base_dir is None else base_dir / mask
    regions = obj.get("regions", [])
    return ViscositySpec(
        base=check_positive("viscosity.base", obj.get("base", 0.0), allow_zero=True),
        regions=tuple(_region(f"viscosity.regions[{k}]", r) for k, r in enumerate(_list("viscosity.regions", regions))),
        mask=mask,
        stiff=check_positive("viscosity.stiff", obj.get("stiff", 5.0), allow_zero=True),
        soft=check_positive("viscosity.soft", obj.get("soft", 0.0), allow_zero=True),
    )
