"""The animation settings of ``torchfluidwarp animate``: parse and validate them, then build the force and
viscosity modules that drive :class:`~torchfluidwarp.warp.layer.FluidWarp`.

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

Example:
    >>> cfg = parse_config({"brushes": [{"position": [20, 30], "direction": [0, 1], "radius": 8,
    ...                                  "frequency": 0.05, "amplitude": 0.5}], "steps": 10})
    >>> cfg.steps, cfg.brushes[0].position
    (10, (20.0, 30.0))
    >>> build_forces(cfg)(FluidGrid(16, 16), steps=10, dt=1.0, image_size=(48, 48)).shape
    torch.Size([1, 10, 2, 16, 16])
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from torchfluidwarp.core.grid import FluidGrid
from torchfluidwarp.io import read_image
from torchfluidwarp.warp.forces import Brushes, ViscosityBrushes, viscosity_from_mask

__all__ = [
    "BrushSpec",
    "RegionSpec",
    "ViscositySpec",
    "AnimationConfig",
    "DEFAULT_GRID",
    "parse_config",
    "load_config",
    "brush_from_values",
    "region_from_values",
    "auto_grid",
    "build_forces",
    "build_viscosity",
]

DEFAULT_GRID = 64
"""Fluid cells along the image's longer side when no grid is given."""


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
    """Everything ``torchfluidwarp animate`` needs besides the image. ``grid=None`` means :func:`auto_grid`."""

    brushes: tuple[BrushSpec, ...] = ()
    viscosity: ViscositySpec = ViscositySpec()
    grid: tuple[int, int] | None = None
    steps: int = 60
    dt: float = 1.0
    fps: float = 20.0

    def rescaled(self, sx: float, sy: float) -> AnimationConfig:
        """The same animation on the image resized by ``(sx, sy)``: positions, radii and amplitudes scale.

        Positions keep the pixel-centre convention, ``x' = (x + 0.5) sx - 0.5``; radii and accelerations scale
        by the mean factor. Viscosities are per fluid cell and do not change.
        """

        def pos(p: tuple[float, float]) -> tuple[float, float]:
            return ((p[0] + 0.5) * sx - 0.5, (p[1] + 0.5) * sy - 0.5)

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


# ----------------------------------------------------------------------------------------------- parsing

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
        raise ValueError(f"cannot read config {str(path)!r}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read config {str(path)!r}: {exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(
            f"config {str(path)!r} is not valid JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})"
        ) from None
    try:
        return parse_config(data, base_dir=path.parent)
    except ValueError as exc:
        raise ValueError(f"config {str(path)!r}: {exc}") from None


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
    obj = _object("the top level", data, _TOP_KEYS)
    fields: dict[str, object] = {}
    if "brushes" in obj:
        fields["brushes"] = tuple(_brush(f"brushes[{k}]", b) for k, b in enumerate(_list("brushes", obj["brushes"])))
    if "viscosity" in obj:
        fields["viscosity"] = _viscosity(obj["viscosity"], base_dir)
    if "grid" in obj:
        fields["grid"] = _grid("grid", obj["grid"])
    if "steps" in obj:
        fields["steps"] = _int("steps", obj["steps"], minimum=1)
    if "dt" in obj:
        fields["dt"] = _number("dt", obj["dt"], positive=True)
    if "fps" in obj:
        fields["fps"] = _number("fps", obj["fps"], positive=True)
    return AnimationConfig(**fields)  # type: ignore[arg-type]


def brush_from_values(values: Sequence[float], where: str = "brush") -> BrushSpec:
    """A brush from ``X, Y, DX, DY, RADIUS, FREQ, AMP[, PHASE]`` (the order of ``--brush``).

    Raises:
        ValueError: not 7 or 8 values, or an invalid one (named with ``where``).
    """
    if len(values) not in (7, 8):
        raise ValueError(f"{where} needs 7 or 8 values X,Y,DX,DY,RADIUS,FREQ,AMP[,PHASE], got {len(values)}")
    x, y, dx, dy, radius, freq, amp, *phase = values
    return _brush(
        where,
        {
            "position": [x, y],
            "direction": [dx, dy],
            "radius": radius,
            "frequency": freq,
            "amplitude": amp,
            "phase": phase[0] if phase else 0.0,
        },
    )


def region_from_values(values: Sequence[float], where: str = "region") -> RegionSpec:
    """A viscosity region from ``X, Y, RADIUS, VALUE`` (the order of ``--stiff``).

    Raises:
        ValueError: not 4 values, or an invalid one (named with ``where``).
    """
    if len(values) != 4:
        raise ValueError(f"{where} needs 4 values X,Y,RADIUS,VALUE, got {len(values)}")
    x, y, radius, value = values
    return _region(where, {"position": [x, y], "radius": radius, "value": value})


def _describe(value: object) -> str:
    return f"{type(value).__name__} {json.dumps(value) if _jsonable(value) else repr(value)}"


def _jsonable(value: object) -> bool:
    try:
        json.dumps(value, allow_nan=False)
    except (TypeError, ValueError):
        return False
    return len(repr(value)) < 60


def _object(where: str, value: object, allowed: Sequence[str], required: Sequence[str] = ()) -> Mapping:
    if not isinstance(value, Mapping):
        raise ValueError(f"{where} must be a JSON object, got {_describe(value)}")
    unknown = [k for k in value if k not in allowed]
    if unknown:
        raise ValueError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(allowed)})")
    missing = [k for k in required if k not in value]
    if missing:
        raise ValueError(f"{where}: missing key {missing[0]!r}")
    return value


def _list(where: str, value: object) -> list:
    if not isinstance(value, list):
        raise ValueError(f"{where} must be a list, got {_describe(value)}")
    return value


def _number(where: str, value: object, *, positive: bool = False, non_negative: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where} must be a number, got {_describe(value)}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{where} must be finite, got {value!r}")
    if positive and v <= 0:
        raise ValueError(f"{where} must be > 0, got {value!r}")
    if non_negative and v < 0:
        raise ValueError(f"{where} must be >= 0, got {value!r}")
    return v


def _int(where: str, value: object, *, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{where} must be an integer, got {_describe(value)}")
    if value < minimum:
        raise ValueError(f"{where} must be >= {minimum}, got {value}")
    return value


def _pair(where: str, value: object) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ValueError(f"{where} must be a pair [x, y] of numbers, got {_describe(value)}")
    return (_number(f"{where}[0]", value[0]), _number(f"{where}[1]", value[1]))


def _grid(where: str, value: object) -> tuple[int, int]:
    if isinstance(value, int) and not isinstance(value, bool):
        value = [value, value]
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ValueError(f"{where} must be [h, w] or one integer, got {_describe(value)}")
    return (_int(f"{where}[0]", value[0], minimum=2), _int(f"{where}[1]", value[1], minimum=2))


def _brush(where: str, value: object) -> BrushSpec:
    obj = _object(where, value, _BRUSH_KEYS, required=("position", "direction", "radius", "amplitude"))
    direction = _pair(f"{where}.direction", obj["direction"])
    if direction == (0.0, 0.0):
        raise ValueError(f"{where}.direction must be a non-zero vector, got [0, 0]")
    return BrushSpec(
        position=_pair(f"{where}.position", obj["position"]),
        direction=direction,
        radius=_number(f"{where}.radius", obj["radius"], positive=True),
        frequency=_number(f"{where}.frequency", obj.get("frequency", 0.0), non_negative=True),
        amplitude=_number(f"{where}.amplitude", obj["amplitude"]),
        phase=_number(f"{where}.phase", obj.get("phase", 0.0)),
    )


def _region(where: str, value: object) -> RegionSpec:
    obj = _object(where, value, _REGION_KEYS, required=_REGION_KEYS)
    return RegionSpec(
        position=_pair(f"{where}.position", obj["position"]),
        radius=_number(f"{where}.radius", obj["radius"], positive=True),
        value=_number(f"{where}.value", obj["value"]),
    )


def _viscosity(value: object, base_dir: Path | None) -> ViscositySpec:
    obj = _object("viscosity", value, _VISCOSITY_KEYS)
    mask = obj.get("mask")
    if mask is not None:
        if not isinstance(mask, str) or not mask:
            raise ValueError(f"viscosity.mask must be an image path (a string), got {_describe(mask)}")
        mask = Path(mask) if base_dir is None else base_dir / mask
    regions = tuple(
        _region(f"viscosity.regions[{k}]", r) for k, r in enumerate(_list("viscosity.regions", obj.get("regions", [])))
    )
    return ViscositySpec(
        base=_number("viscosity.base", obj.get("base", 0.0), non_negative=True),
        regions=regions,
        mask=mask,
        stiff=_number("viscosity.stiff", obj.get("stiff", 5.0), non_negative=True),
        soft=_number("viscosity.soft", obj.get("soft", 0.0), non_negative=True),
    )


# ---------------------------------------------------------------------------------------------- building


def auto_grid(image_size: tuple[int, int], cells: int = DEFAULT_GRID) -> tuple[int, int]:
    """A fluid grid with ``cells`` along the image's longer side and about square cells.

    Example:
        >>> auto_grid((300, 600))
        (32, 64)
    """
    H, W = image_size
    scale = cells / max(H, W)
    return (max(2, round(H * scale)), max(2, round(W * scale)))


def build_forces(config: AnimationConfig) -> Brushes:
    """The configuration's brushes as one :class:`~torchfluidwarp.warp.forces.Brushes` module.

    Raises:
        ValueError: the configuration has no brushes.
    """
    if not config.brushes:
        raise ValueError("nothing to animate: give at least one brush")
    b = config.brushes
    return Brushes(
        centers=[p.position for p in b],
        directions=[p.direction for p in b],
        radius=[p.radius for p in b],
        amplitude=[p.amplitude for p in b],
        frequency=[p.frequency for p in b],
        phase=[p.phase for p in b],
    )


def build_viscosity(
    config: AnimationConfig,
    grid: tuple[int, int],
    image_size: tuple[int, int],
    mask_size: tuple[int, int] | None = None,
) -> float | Tensor:
    """The viscosity: a float when it is uniform, else a field ``(1, 1, h, w)`` in cells^2 per time unit.

    Args:
        config: the animation settings, its positions in pixels of an image of size ``image_size``.
        grid: the fluid grid ``(h, w)``.
        image_size: ``(H, W)`` of the image being animated.
        mask_size: the size a mask image must have (the original image's, before any resizing);
            ``image_size`` by default.

    Raises:
        ValueError: the mask cannot be read or its size differs from ``mask_size``.
    """
    spec = config.viscosity
    field: float | Tensor = spec.base
    if spec.regions:
        r = spec.regions
        module = ViscosityBrushes(
            centers=[p.position for p in r], radius=[p.radius for p in r], value=[p.value for p in r], base=spec.base
        )
        with torch.no_grad():
            field = module(FluidGrid.of(grid), image_size).detach()
    if spec.mask is not None:
        try:
            mask = read_image(spec.mask, channels=1)
        except ValueError as exc:
            raise ValueError(f"viscosity.mask: {exc}") from None
        want = mask_size or image_size
        if tuple(mask.shape[-2:]) != tuple(want):
            raise ValueError(
                f"viscosity.mask {str(spec.mask)!r} is {mask.shape[-1]}x{mask.shape[-2]} pixels, "
                f"but the image is {want[1]}x{want[0]}"
            )
        field = field + viscosity_from_mask(mask, grid, stiff=spec.stiff, soft=spec.soft)
    return field
