"""The studio's settings: one frozen :class:`StudioConfig` per server."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

__all__ = ["StudioConfig", "MAX_UPLOAD"]

MAX_UPLOAD = 20 * 1024 * 1024
"""Largest request body in bytes (uploads included)."""


@dataclass(frozen=True)
class StudioConfig:
    """The studio's settings.

    Attributes:
        token: the session token every request must carry.
        allowed_hosts: accepted ``Host`` header values (lower case, with the port), see
            :func:`~torchfluidwarp.apps.studio.guard.loopback_hosts`.
        save_dir: folder exports may be saved into; ``None`` means exports are downloads only.
        max_upload: largest request body in bytes.
        preview_frames: frames of a morph preview (the slider's positions).
        preview_size: longer side in pixels at which morph previews are rendered (0 = image A's size).
        preview_iter: L-BFGS iterations of a warm-started preview fit (five times as many when cold): a moved
            point needs few iterations from the previous forces, and the next edit refines further.
        preview_tolerance: pixels; a preview fit stops once every point is this close (exports use 0.05).
        export_iter: L-BFGS iterations of an export's fit (``None``: the morph method's default).
        animate_preview_size: longer side in pixels of the animate preview.
        animate_export_size: longer side in pixels of an animate export (0 = the photo's size).
    """

    token: str
    allowed_hosts: tuple[str, ...]
    save_dir: Path | None = None
    max_upload: int = MAX_UPLOAD
    preview_frames: int = 9
    preview_size: int = 320
    preview_iter: int = 10
    preview_tolerance: float = 0.25
    export_iter: int | None = None
    animate_preview_size: int = 320
    animate_export_size: int = 800
