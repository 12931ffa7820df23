"""What the page sends, checked: JSON bodies, numbers in range, point lists, the morph's settings.

Values go through the library's validators (:mod:`torchfluidwarp._checks`,
:func:`~torchfluidwarp.control.keyframes.check_points`); the studio only adds the upper bounds that keep a
request small. Every error is a ``ValueError`` or ``TypeError`` with a one-line message, answered with 400.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any, Literal, cast

import torch
from starlette.requests import Request
from torch import Tensor

from torchfluidwarp._checks import check_int, check_real
from torchfluidwarp.control.keyframes import check_points
from torchfluidwarp.core.grid import SquareCells
from torchfluidwarp.errors import InputError
from torchfluidwarp.morph import MorphSettings, PaperSettings, Timing
from torchfluidwarp.morph.settings import METHODS

__all__ = [
    "BadInput",
    "body_json",
    "choice",
    "number",
    "integer",
    "points",
    "points_inside",
    "frame_index",
    "morph_settings",
]


class BadInput(InputError):
    """Bad input from the page: answered with 400 and a one-line message."""


async def body_json(request: Request) -> dict:
    """The request's body as a JSON object."""
    try:
        data = json.loads(await request.body())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise BadInput(f"the request is not valid JSON ({exc})") from None
    except RecursionError:  # the decoder recurses once per level of nesting
        raise BadInput("the request's JSON is nested too deeply") from None
    if not isinstance(data, dict):
        raise BadInput("the request must be a JSON object")
    return data


def choice(name: str, value: object, options: Sequence[str]) -> str:
    """``value`` if it is one of ``options``."""
    if value not in options:
        raise BadInput(f"{name} must be one of {', '.join(options)}, got {value!r}")
    return str(value)


def number(name: str, value: object, lo: float, hi: float) -> float:
    """A finite number in ``[lo, hi]``."""
    v = check_real(name, value)
    if not lo <= v <= hi:
        raise BadInput(f"{name} must be in [{lo:g}, {hi:g}], got {value!r}")
    return v


def integer(name: str, value: object, lo: int, hi: int) -> int:
    """An integer in ``lo..hi``."""
    v = check_int(name, value, minimum=lo)
    if v > hi:
        raise BadInput(f"{name} must be in {lo}..{hi}, got {value}")
    return v


def points(name: str, value: object) -> Tensor:
    """``[[x, y], ...]`` from JSON as a finite ``(M, 2)`` float64 tensor (``M`` may be 0)."""
    if not isinstance(value, list) or not all(isinstance(p, list) and len(p) == 2 for p in value):
        raise BadInput(f"{name} must be a list of [x, y] pairs")
    coords = [check_real(f"{name}[{i}]", v) for i, p in enumerate(value) for v in p]
    return torch.tensor(coords, dtype=torch.float64).reshape(-1, 2)


def points_inside(name: str, pts: Tensor, image: Tensor) -> Tensor:
    """``pts`` ``(M, 2)``, checked to lie inside ``image`` ``(1, C, H, W)`` (pixels; no points pass)."""
    if pts.numel():
        check_points(name, pts, (image.shape[-2], image.shape[-1]))
    return pts


def frame_index(text: str | None, frames: int) -> int:
    """The query's frame index ``k`` in ``0..frames - 1``."""
    try:
        k = int(text or "0")
    except ValueError:
        raise BadInput("k must be an integer frame index") from None
    if not 0 <= k < frames:
        raise BadInput(f"frame index k must be in 0..{frames - 1}, got {k}")
    return k


def morph_settings(value: object) -> tuple[MorphSettings, Timing]:
    """The page's morph settings as the typed settings :func:`~torchfluidwarp.morph.morph` takes: the method's
    (:class:`~torchfluidwarp.morph.NaturalSettings` or :class:`~torchfluidwarp.morph.PaperSettings`) and the
    :class:`~torchfluidwarp.morph.Timing`. The page's ``control`` applies to the paper's method only; a
    ``compressible`` of ``null`` leaves the method's default."""
    s = value if isinstance(value, dict) else {}
    cls = METHODS[choice("method", s.get("method", "natural"), ("natural", "paper"))]
    align = choice("align", s.get("align", "similarity"), ("similarity", "affine", "none"))
    fields: dict[str, Any] = {
        "inverse": choice("inverse", s.get("inverse", "flow"), ("flow", "paper")),
        "grid": SquareCells(integer("grid", s.get("grid", 32), 4, 256) ** 2),  # N x N on a square picture
        "steps": integer("steps", s.get("steps", 8), 1, 100),
        "align": None if align == "none" else align,
    }
    control = integer("control", s.get("control", 6), 2, 32)
    if cls is PaperSettings:
        fields["control"] = control
    compressible = s.get("compressible")
    if compressible is not None:
        fields["compressible"] = (
            compressible if isinstance(compressible, bool) else number("compressible", compressible, 0.0, 1.0)
        )
    blend = choice("blend", s.get("blend", "linear"), ("linear", "smooth"))
    timing = Timing(blend=cast(Literal["linear", "smooth"], blend))
    return cls(**fields), timing
