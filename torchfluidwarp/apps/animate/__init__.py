"""The one animation pipeline of ``torchfluidwarp animate`` and the studio.

:mod:`~torchfluidwarp.apps.animate.config` holds the settings (:class:`AnimationConfig`, read from JSON by
:func:`load_config`, whose format it documents); :mod:`~torchfluidwarp.apps.animate.pipeline` turns a
configuration and a photo into frames (:func:`animate_frames`, streamed one at a time).
"""

from __future__ import annotations

from torchfluidwarp.apps.animate.config import (
    AnimationConfig,
    BrushSpec,
    RegionSpec,
    ViscositySpec,
    brush_from_values,
    config_json,
    load_config,
    parse_config,
    region_from_values,
)
from torchfluidwarp.apps.animate.pipeline import (
    DEFAULT_GRID,
    animate_frames,
    auto_grid,
    build_forces,
    build_viscosity,
)

__all__ = [
    "BrushSpec",
    "RegionSpec",
    "ViscositySpec",
    "AnimationConfig",
    "DEFAULT_GRID",
    "parse_config",
    "load_config",
    "config_json",
    "brush_from_values",
    "region_from_values",
    "animate_frames",
    "auto_grid",
    "build_forces",
    "build_viscosity",
]
