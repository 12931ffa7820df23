"""What the studio sends back: PNG previews, the area-change colouring, downloads, point files as bytes.

No numerics of its own: the Jacobian determinant comes from :func:`~torchfluidwarp.warp.frames.jacobian_determinant`
and point files are written and read by :mod:`torchfluidwarp.io`; this module only encodes them.
"""

from __future__ import annotations

import io
import re
import tempfile
from pathlib import Path

import torch
from PIL import Image
from starlette.responses import JSONResponse, Response
from torch import Tensor

from torchfluidwarp.apps.studio.guard import safe_name, save
from torchfluidwarp.apps.studio.inputs import BadInput
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import read_points, write_points
from torchfluidwarp.warp import jacobian_determinant

__all__ = [
    "png",
    "png_response",
    "area_change_png",
    "download",
    "export_response",
    "points_bytes",
    "points_from_bytes",
    "MEDIA",
]

MEDIA = {"gif": "image/gif", "mp4": "video/mp4", "pts": "text/plain", "json": "application/json", "csv": "text/csv"}
"""Media types of the exports, by format."""


def png(image: Tensor) -> bytes:
    """``(C, H, W)`` in ``[0, 1]`` as PNG bytes (fast compression: these are previews)."""
    arr = image.detach().clamp(0, 1).mul(255).round().to(torch.uint8).permute(1, 2, 0).cpu().numpy()
    if arr.shape[-1] == 1:
        arr = arr[..., 0]
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, "PNG", compress_level=1)
    return buf.getvalue()


def png_response(data: bytes) -> Response:
    """PNG bytes as an uncached response."""
    return Response(data, media_type="image/png", headers={"Cache-Control": "no-store"})


def area_change_png(coords: Tensor) -> bytes:
    """A backward map's area change ``(1, H, W, 2)`` as a PNG: blue shrinks, white keeps, red grows, black folds.

    The colour follows ``log2`` of :func:`~torchfluidwarp.warp.frames.jacobian_determinant`, clamped to
    ``[-1, 1]`` (half to double the area); a determinant ``<= 0`` (a fold) is black.
    """
    det = jacobian_determinant(coords)[0]  # (H, W)
    v = torch.log2(det.clamp(min=1e-6)).clamp(-1, 1)
    one = torch.ones_like(v)
    rgb = torch.stack([torch.where(v < 0, 1 + v, one), 1 - v.abs(), torch.where(v > 0, 1 - v, one)])
    return png(torch.where(det > 0, rgb, torch.zeros_like(rgb)))


def download(data: bytes, name: str, media: str) -> Response:
    """``data`` as an attachment named ``name`` (reduced to a safe file name)."""
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", Path(name).name) or "export"
    return Response(
        data,
        media_type=media,
        headers={"Content-Disposition": f'attachment; filename="{safe}"', "Cache-Control": "no-store"},
    )


def export_response(save_dir: Path | None, data: dict, payload: bytes, default_name: str, fmt: str) -> Response:
    """An export: saved into ``save_dir`` when the request says ``"save"`` (``{"saved": path}``), else a download.

    ``data["name"]`` (else ``default_name``) names the file; a saved file's name must end in ``.fmt``.
    """
    name = data.get("name") or default_name
    if data.get("save"):
        return JSONResponse({"saved": str(save(save_dir, safe_name(name, (f".{fmt}",)), payload))})
    return download(payload, str(name) if isinstance(name, str) else f"export.{fmt}", MEDIA[fmt])


def points_bytes(points: Tensor, fmt: str) -> bytes:
    """``points`` ``(M, 2)`` encoded as :func:`~torchfluidwarp.io.write_points` writes them."""
    # io has no in-memory writer: go through a private temporary folder that is removed at once.
    with tempfile.TemporaryDirectory(prefix="tfw-studio-") as folder:
        path = write_points(Path(folder) / f"points.{fmt}", points)
        return path.read_bytes()


def points_from_bytes(data: bytes, name: str) -> Tensor:
    """Parse a points file's contents with :func:`~torchfluidwarp.io.read_points` (format by suffix)."""
    suffix = Path(name).suffix.lower()
    if suffix not in (".pts", ".json", ".csv"):
        raise BadInput(f"points file {name!r}: use a .pts, .json or .csv file")
    with tempfile.TemporaryDirectory(prefix="tfw-studio-") as folder:
        path = Path(folder) / f"points{suffix}"
        path.write_bytes(data)
        try:
            return read_points(path, dtype=torch.float64)
        except InputError as exc:
            raise BadInput(str(exc).replace(str(path), name)) from None
