"""The studio's web app: a Starlette application over the public API (no fluid logic lives here).

Security model (the server runs on the user's machine and may see their photos):

* every request, the page and its static files included, carries the session's random token, as the query
  parameter ``token`` or the header ``X-Studio-Token``; a missing or wrong token gets 403;
* the ``Host`` header must name the loopback address the server listens on (or the explicit ``--host``), so
  a DNS-rebinding page cannot talk to it; otherwise 403;
* request bodies are limited (20 MiB by default, 413 beyond); uploads are decoded in memory with
  :func:`~torchfluidwarp.io.read_image_bytes`;
* nothing is written to disk except into the ``save_dir`` the user named, never outside it, never over an
  existing file.

Bad input (not an image, a points file with a wrong count, non-finite values, bad settings) gets a 400 with a
one-line JSON ``{"error": ...}`` that the page shows; the server keeps serving.

Fits run in a worker thread, one at a time. A newer preview supersedes an older one: a stale request that has
not started yet is dropped (409) and a stale result is discarded (409), so the latest edit runs next instead
of queueing behind outdated ones.

Conventions: points are ``(x, y)`` in each image's pixels, pixel centres at integers (as in
:mod:`torchfluidwarp.io`).
"""

from __future__ import annotations

import copy
import dataclasses
import io
import json
import math
import os
import re
import secrets
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal, TypeVar, cast

import anyio.to_thread
import torch
from PIL import Image
from starlette.applications import Starlette
from starlette.datastructures import Headers, QueryParams
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from torch import Tensor

from torchfluidwarp.apps.animate import auto_grid, build_forces, build_viscosity, parse_config
from torchfluidwarp.control.alignment import estimate_alignment
from torchfluidwarp.control.keyframes import KeyframeFit
from torchfluidwarp.io import (
    encode_animation,
    read_image_bytes,
    read_points,
    resize_image,
    shrink_image,
    write_points,
)
from torchfluidwarp.morph.morphing import MorphResult, morph
from torchfluidwarp.warp.layer import FluidWarp, jacobian_determinant

__all__ = ["StudioConfig", "create_app", "LatestOnly", "Superseded", "TOKEN_HEADER", "MAX_UPLOAD", "loopback_hosts"]

TOKEN_HEADER = "X-Studio-Token"
MAX_UPLOAD = 20 * 1024 * 1024
"""Largest request body in bytes (uploads included)."""

_STATIC = {"index.html": "text/html", "studio.js": "text/javascript", "studio.css": "text/css"}
_IMAGE_SLOTS = ("a", "b")
_POINT_FORMATS = ("pts", "json", "csv")
_ANIMATION_FORMATS = ("gif", "mp4")

T = TypeVar("T")


def loopback_hosts(port: int, host: str | None = None) -> tuple[str, ...]:
    """The ``Host`` header values the server accepts: loopback names with ``port``, and ``host:port``."""
    names = ["127.0.0.1", "localhost", "[::1]"]
    if host and host not in ("127.0.0.1", "localhost", "::1"):
        names.append(f"[{host}]" if ":" in host else host)
    return tuple(f"{n}:{port}" for n in names)


@dataclass(frozen=True)
class StudioConfig:
    """The studio's settings.

    Attributes:
        token: the session token every request must carry.
        allowed_hosts: accepted ``Host`` header values (lower case, with the port), see :func:`loopback_hosts`.
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


class BadInput(ValueError):
    """Bad input from the page: answered with 400 and a one-line message."""


class Superseded(Exception):
    """A newer request of the same kind arrived: this one's result is not wanted any more."""


class LatestOnly:
    """Runs jobs one at a time; on a channel, only the newest job's result counts.

    ``run(channel, fn)`` numbers the request. It waits for the single worker slot; if a newer request on the
    same channel arrived meanwhile it raises :class:`Superseded` without running ``fn``, and if one arrived
    while ``fn`` ran the result is discarded the same way. So a burst of edits runs the first and the last,
    never the ones in between. ``channel=None`` (exports) is never superseded.
    """

    def __init__(self) -> None:
        self._slot = threading.Lock()  # at most one fit at a time
        self._mutex = threading.Lock()
        self._latest: dict[str, int] = {}

    def ticket(self, channel: str) -> int:
        with self._mutex:
            self._latest[channel] = self._latest.get(channel, 0) + 1
            return self._latest[channel]

    def current(self, channel: str) -> int:
        with self._mutex:
            return self._latest.get(channel, 0)

    def run(self, channel: str | None, fn: Callable[[], T], ticket: int | None = None) -> tuple[int, T]:
        """Run ``fn`` in the worker slot: ``(ticket, result)``. Call from a worker thread.

        Raises:
            Superseded: a newer request on ``channel`` arrived before or while ``fn`` ran.
        """
        if channel is None:
            with self._slot:
                return 0, fn()
        gen = self.ticket(channel) if ticket is None else ticket
        with self._slot:
            if gen != self.current(channel):
                raise Superseded
            result = fn()
        if gen != self.current(channel):
            raise Superseded
        return gen, result


@dataclass
class _Slot:
    image: Tensor  # (1, C, H, W)
    name: str
    version: int


@dataclass
class _State:
    images: dict[str, _Slot] = field(default_factory=dict)
    points: dict[str, Tensor] = field(default_factory=dict)  # (M, 2) pixels, the last ones the page sent
    fit: KeyframeFit | None = None  # the newest fit, for warm starts
    fit_key: tuple = ()
    morph_gen: int = 0
    morph_result: MorphResult | None = None
    animate_gen: int = 0
    animate_frames: Tensor | None = None  # (T + 1, C, H, W)
    versions: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)


# ------------------------------------------------------------------------------------------- middleware


class _TooLarge(Exception):
    pass


class _Guard:
    """ASGI middleware: the Host check, the token check and the body size limit, before any route runs."""

    def __init__(self, app: ASGIApp, config: StudioConfig) -> None:
        self.app = app
        self.config = config
        self.hosts = {h.lower() for h in config.allowed_hosts}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        if headers.get("host", "").lower() not in self.hosts:
            await _error("host not allowed (the studio answers only on its own loopback address)", 403)(
                scope, receive, send
            )
            return
        given = QueryParams(scope.get("query_string", b"").decode("latin-1")).get("token") or headers.get(
            TOKEN_HEADER, ""
        )
        if not secrets.compare_digest(given.encode(), self.config.token.encode()):
            await _error("missing or wrong session token: open the address the studio printed", 403)(
                scope, receive, send
            )
            return
        limit = self.config.max_upload
        length = headers.get("content-length")
        if length is not None and (not length.isdigit() or int(length) > limit):
            await _error(f"upload too large (limit {limit // (1024 * 1024)} MiB)", 413)(scope, receive, send)
            return
        received = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise _TooLarge
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except _TooLarge:
            if not started:
                await _error(f"upload too large (limit {limit // (1024 * 1024)} MiB)", 413)(scope, receive, send)


def _error(message: str, status: int = 400) -> JSONResponse:
    lines = str(message).strip().splitlines()
    return JSONResponse({"error": lines[0] if lines else "error"}, status_code=status)


# ---------------------------------------------------------------------------------------------- helpers


def _number(name: str, value: object, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise BadInput(f"{name} must be a finite number, got {value!r}")
    if not lo <= value <= hi:
        raise BadInput(f"{name} must be in [{lo:g}, {hi:g}], got {value!r}")
    return float(value)


def _integer(name: str, value: object, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise BadInput(f"{name} must be an integer, got {value!r}")
    if not lo <= value <= hi:
        raise BadInput(f"{name} must be in {lo}..{hi}, got {value}")
    return value


def _choice(name: str, value: object, options: Sequence[str]) -> str:
    if value not in options:
        raise BadInput(f"{name} must be one of {', '.join(options)}, got {value!r}")
    return str(value)


def _points(name: str, value: object) -> Tensor:
    """``[[x, y], ...]`` from JSON as a finite ``(M, 2)`` float64 tensor."""
    if not isinstance(value, list) or not all(isinstance(p, list) and len(p) == 2 for p in value):
        raise BadInput(f"{name} must be a list of [x, y] pairs")
    for p in value:
        for v in p:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise BadInput(f"{name} has a non-finite or non-numeric coordinate: {p!r}")
    return torch.tensor(value, dtype=torch.float64).reshape(-1, 2)


def _morph_settings(value: object) -> dict[str, Any]:
    """The page's morph settings as :func:`~torchfluidwarp.morph.morphing.morph` keyword arguments."""
    s = value if isinstance(value, dict) else {}
    align = _choice("align", s.get("align", "similarity"), ("similarity", "affine", "none"))
    compressible = s.get("compressible")
    if compressible is not None and not isinstance(compressible, bool):
        compressible = _number("compressible", compressible, 0.0, 1.0)
    return {
        "method": _choice("method", s.get("method", "natural"), ("natural", "paper")),
        "inverse": _choice("inverse", s.get("inverse", "flow"), ("flow", "paper")),
        "grid": _integer("grid", s.get("grid", 32), 4, 256),
        "steps": _integer("steps", s.get("steps", 8), 1, 100),
        "control": _integer("control", s.get("control", 6), 2, 32),
        "align": None if align == "none" else align,
        "blend": _choice("blend", s.get("blend", "linear"), ("linear", "smooth")),
        "compressible": compressible,
    }


def _safe_name(name: object, suffixes: Sequence[str]) -> str:
    """A file name for the save folder: relative, no ``..``, one of ``suffixes``."""
    if not isinstance(name, str) or not name or len(name) > 200 or "\x00" in name:
        raise BadInput("the file name must be a non-empty string")
    parts = re.split(r"[\\/]", name)
    if os.path.isabs(name) or name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name) or ".." in parts:
        raise BadInput(f"refusing file name {name!r}: it must stay inside the save folder (no '..', not absolute)")
    if not name.lower().endswith(tuple(suffixes)):
        raise BadInput(f"file name {name!r} must end in {' or '.join(suffixes)}")
    return name


def _save(save_dir: Path | None, name: str, data: bytes) -> Path:
    """Write ``data`` to ``save_dir / name`` atomically, refusing to leave the folder or replace a file."""
    if save_dir is None:
        raise BadInput("saving needs a folder: start the studio with --save-dir DIR")
    root = save_dir.resolve()
    target = (root / name).resolve()
    if target == root or root not in target.parents:
        raise BadInput(f"refusing file name {name!r}: it resolves outside the save folder")
    if target.exists() or target.is_symlink():
        raise BadInput(f"{name!r} already exists in the save folder; choose another name")
    target.parent.mkdir(parents=True, exist_ok=True)
    if root not in target.parent.resolve().parents and target.parent.resolve() != root:
        raise BadInput(f"refusing file name {name!r}: it resolves outside the save folder")
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=".studio-", suffix=".part")
    try:
        with os.fdopen(fd, "wb") as fp:
            fp.write(data)
        os.link(tmp, target)  # fails if the name appeared meanwhile: never replaces a file
    except FileExistsError:
        raise BadInput(f"{name!r} already exists in the save folder; choose another name") from None
    finally:
        os.unlink(tmp)
    return target


def _points_bytes(points: Tensor, fmt: str) -> bytes:
    """``points`` ``(M, 2)`` encoded as :func:`~torchfluidwarp.io.write_points` writes them."""
    # io has no in-memory writer: go through a private temporary folder that is removed at once.
    with tempfile.TemporaryDirectory(prefix="tfw-studio-") as folder:
        path = write_points(Path(folder) / f"points.{fmt}", points)
        return path.read_bytes()


def _points_from_bytes(data: bytes, name: str) -> Tensor:
    """Parse a points file's contents with :func:`~torchfluidwarp.io.read_points` (format by suffix)."""
    suffix = Path(name).suffix.lower()
    if suffix not in (".pts", ".json", ".csv"):
        raise BadInput(f"points file {name!r}: use a .pts, .json or .csv file")
    with tempfile.TemporaryDirectory(prefix="tfw-studio-") as folder:
        path = Path(folder) / f"points{suffix}"
        path.write_bytes(data)
        try:
            return read_points(path, dtype=torch.float64)
        except ValueError as exc:
            raise BadInput(str(exc).replace(str(path), name)) from None


def _png(image: Tensor) -> bytes:
    """``(C, H, W)`` in ``[0, 1]`` as PNG bytes (fast compression: these are previews)."""
    arr = image.detach().clamp(0, 1).mul(255).round().to(torch.uint8).permute(1, 2, 0).cpu().numpy()
    if arr.shape[-1] == 1:
        arr = arr[..., 0]
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, "PNG", compress_level=1)
    return buf.getvalue()


def _heat(det: Tensor) -> Tensor:
    """Colour a Jacobian determinant ``(H, W)``: blue shrinks, white keeps area, red grows, black folds."""
    v = torch.log2(det.clamp(min=1e-6)).clamp(-1, 1)  # (H, W): -1 = half the area, +1 = double
    r = torch.where(v < 0, 1 + v, torch.ones_like(v))
    g = 1 - v.abs()
    b = torch.where(v > 0, 1 - v, torch.ones_like(v))
    rgb = torch.stack([r, g, b])
    return torch.where(det > 0, rgb, torch.zeros_like(rgb))


def _rescale(points: Tensor, image: Tensor, size: tuple[int, int]) -> Tensor:
    """``points`` ``(M, 2)`` in the pixels of ``image`` ``(1, C, H, W)`` as pixels of an image of ``size`` ``(H', W')``
    covering the same picture (pixel centres at integers: ``x' = (x + 0.5) W' / W - 0.5``)."""
    H, W = image.shape[-2:]
    scale = torch.tensor([size[1] / W, size[0] / H], dtype=points.dtype)
    hi = torch.tensor([size[1] - 0.5, size[0] - 0.5], dtype=points.dtype)
    return torch.minimum(((points + 0.5) * scale - 0.5).clamp(min=-0.5), hi)  # round-off stays inside


def _download(data: bytes, name: str, media: str) -> Response:
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", Path(name).name) or "export"
    return Response(
        data,
        media_type=media,
        headers={"Content-Disposition": f'attachment; filename="{safe}"', "Cache-Control": "no-store"},
    )


_MEDIA = {"gif": "image/gif", "mp4": "video/mp4", "pts": "text/plain", "json": "application/json", "csv": "text/csv"}


# -------------------------------------------------------------------------------------------------- app


def create_app(
    config: StudioConfig,
    *,
    images: dict[str, tuple[Tensor, str]] | None = None,
    points: dict[str, Tensor] | None = None,
) -> Starlette:
    """The studio's ASGI app.

    Args:
        config: token, accepted hosts, save folder and limits.
        images: optional start images ``{"a": (tensor (1, C, H, W), file name), "b": ...}``.
        points: optional start points ``{"a": (M, 2), "b": (M, 2)}`` in each image's pixels.

    Returns:
        A Starlette app; serve it with uvicorn (see :mod:`torchfluidwarp.apps.studio.server`).
    """
    state = _State()
    worker = LatestOnly()
    for key, (img, name) in (images or {}).items():
        state.versions += 1
        state.images[_choice("image slot", key, _IMAGE_SLOTS)] = _Slot(img, name, state.versions)
    for key, pts in (points or {}).items():
        state.points[key] = pts.to(torch.float64)
    static = resources.files("torchfluidwarp.apps.studio") / "static"

    def image(slot: str) -> Tensor:
        if slot not in state.images:
            raise BadInput(f"load image {slot.upper()} first")
        return state.images[slot].image

    async def body_json(request: Request) -> dict:
        try:
            data = json.loads(await request.body())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise BadInput(f"the request is not valid JSON ({exc})") from None
        if not isinstance(data, dict):
            raise BadInput("the request must be a JSON object")
        return data

    def guarded(handler: Callable) -> Callable:
        async def endpoint(request: Request) -> Response:
            try:
                return await handler(request)
            except (BadInput, ValueError, TypeError) as exc:
                return _error(str(exc), 400)
            except Superseded:
                return _error("superseded by a newer request", 409)
            except RuntimeError as exc:  # e.g. MP4 without imageio-ffmpeg
                return _error(str(exc), 400 if "imageio-ffmpeg" in str(exc) else 500)

        return endpoint

    # ------------------------------------------------------------------ page, static files, state

    async def index(request: Request) -> Response:
        html = (static / "index.html").read_text(encoding="utf-8").replace("__TOKEN__", config.token)
        return Response(
            html, media_type="text/html", headers={"Cache-Control": "no-store", "Referrer-Policy": "no-referrer"}
        )

    async def static_file(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in _STATIC:
            return _error("not found", 404)
        return Response((static / name).read_bytes(), media_type=_STATIC[name], headers={"Cache-Control": "no-store"})

    def describe_state() -> dict:
        out: dict[str, Any] = {
            "images": {},
            "points": {},
            "save_dir": config.save_dir is not None,
            "preview_frames": config.preview_frames,
        }
        for key in _IMAGE_SLOTS:
            slot = state.images.get(key)
            out["images"][key] = (
                None
                if slot is None
                else {
                    "width": slot.image.shape[-1],
                    "height": slot.image.shape[-2],
                    "channels": slot.image.shape[1],
                    "name": slot.name,
                    "version": slot.version,
                }
            )
            out["points"][key] = state.points[key].tolist() if key in state.points else []
        return out

    async def get_state(request: Request) -> Response:
        return JSONResponse(describe_state())

    # ---------------------------------------------------------------------------------- images

    async def put_image(request: Request) -> Response:
        slot = _choice("image slot", request.path_params["slot"], _IMAGE_SLOTS)
        data = await request.body()
        name = Path(request.query_params.get("name", f"{slot}.png")).name or f"{slot}.png"
        if not data:
            raise BadInput("the upload is empty")
        try:
            img = await anyio.to_thread.run_sync(lambda: read_image_bytes(data, channels=3))
        except ValueError:
            raise BadInput(f"{name!r} is not an image that can be read (PNG, JPEG, ...)") from None
        if min(img.shape[-2:]) < 8:
            raise BadInput(f"{name!r} is too small ({img.shape[-1]}x{img.shape[-2]} pixels; at least 8x8)")
        with state.lock:
            state.versions += 1
            state.images[slot] = _Slot(img, name, state.versions)
            state.points.pop(slot, None)
            state.fit, state.fit_key, state.morph_result = None, (), None
        return JSONResponse(describe_state())

    async def get_image(request: Request) -> Response:
        slot = _choice("image slot", request.path_params["slot"], _IMAGE_SLOTS)
        data = await anyio.to_thread.run_sync(lambda: _png(image(slot)[0]))
        return Response(data, media_type="image/png", headers={"Cache-Control": "no-store"})

    # ---------------------------------------------------------------------------------- points

    def checked_pair(data: dict) -> tuple[Tensor, Tensor]:
        pa, pb = _points("points_a", data.get("points_a")), _points("points_b", data.get("points_b"))
        if pa.shape[0] != pb.shape[0]:
            raise BadInput(f"points_a has {pa.shape[0]} points but points_b has {pb.shape[0]}")
        for key, p in (("a", pa), ("b", pb)):
            if not p.numel():
                continue
            H, W = image(key).shape[-2:]
            if bool(((p < -0.5) | (p > torch.tensor([W - 0.5, H - 0.5], dtype=p.dtype))).any()):
                raise BadInput(f"a point of image {key.upper()} lies outside its {W}x{H} pixels")
        return pa, pb

    def proposal(pa: Tensor, pb: Tensor, align: str | None) -> list | None:
        """The alignment A -> B (original pixels) that proposes partners, once 3 pairs exist."""
        if pa.shape[0] < 3:
            return None
        try:
            return estimate_alignment(pa, pb, "affine" if align == "affine" else "similarity").tolist()
        except ValueError:
            return None

    async def put_points(request: Request) -> Response:
        data = await body_json(request)
        pa, pb = checked_pair(data)
        settings = _morph_settings(data.get("settings"))
        with state.lock:
            state.points["a"], state.points["b"] = pa, pb
        return JSONResponse({"count": pa.shape[0], "alignment": proposal(pa, pb, settings["align"])})

    async def import_points(request: Request) -> Response:
        slot = _choice("image slot", request.path_params["slot"], _IMAGE_SLOTS)
        name = Path(request.query_params.get("name", "points.pts")).name
        pts = _points_from_bytes(await request.body(), name)
        other = "b" if slot == "a" else "a"
        want = request.query_params.get("count")
        if want is not None and want.isdigit() and int(want) > 0 and int(want) != pts.shape[0]:
            raise BadInput(f"{name!r} has {pts.shape[0]} points but image {other.upper()} has {want}")
        H, W = image(slot).shape[-2:]
        if bool(((pts < -0.5) | (pts > torch.tensor([W - 0.5, H - 0.5], dtype=pts.dtype))).any()):
            raise BadInput(f"{name!r} has points outside image {slot.upper()} ({W}x{H} pixels)")
        return JSONResponse({"points": pts.tolist()})

    async def export_points(request: Request) -> Response:
        data = await body_json(request)
        fmt = _choice("format", data.get("format", "pts"), _POINT_FORMATS)
        pts = _points("points", data.get("points"))
        if pts.shape[0] == 0:
            raise BadInput("there are no points to export")
        payload = _points_bytes(pts, fmt)
        name = data.get("name") or f"points.{fmt}"
        return respond_export(data, payload, name, (f".{fmt}",), fmt)

    def respond_export(data: dict, payload: bytes, name: object, suffixes: tuple[str, ...], fmt: str) -> Response:
        if data.get("save"):
            path = _save(config.save_dir, _safe_name(name, suffixes), payload)
            return JSONResponse({"saved": str(path)})
        return _download(payload, str(name) if isinstance(name, str) else f"export.{fmt}", _MEDIA[fmt])

    # ----------------------------------------------------------------------------------- morph

    def morph_inputs(data: dict) -> tuple[Tensor, Tensor, Tensor, Tensor, dict]:
        pa, pb = checked_pair(data)
        settings = _morph_settings(data.get("settings"))
        need = 3 if settings["align"] == "affine" else 2
        if pa.shape[0] < need:
            raise BadInput(f"place at least {need} pairs of points first (have {pa.shape[0]})")
        return image("a"), image("b"), pa, pb, settings

    def warm(key: tuple) -> KeyframeFit | None:
        with state.lock:
            if state.fit is None or state.fit_key != key:
                return None
            # fit_keyframes optimises the module in place: give it a copy so the stored fit stays intact
            return dataclasses.replace(state.fit, forces=copy.deepcopy(state.fit.forces))

    def keep_fit(key: tuple, fit: KeyframeFit) -> None:
        with state.lock:
            state.fit, state.fit_key = fit, key

    async def morph_preview(request: Request) -> Response:
        t0 = time.perf_counter()
        data = await body_json(request)
        a, b, pa, pb, settings = morph_inputs(data)
        with state.lock:
            state.points["a"], state.points["b"] = pa, pb
        key = (
            settings["method"],
            settings["grid"],
            settings["steps"],
            settings["control"],
            settings["compressible"],
            tuple(a.shape),
            tuple(b.shape),
        )
        ticket = worker.ticket("morph")

        def job() -> MorphResult:
            # the fit costs the same at any resolution; the inverse maps and the frames cost per pixel, so the
            # preview is rendered at about the pane's size
            small_a = shrink_image(a, config.preview_size)
            size = (small_a.shape[-2], small_a.shape[-1])
            small_b = resize_image(b, size).clamp(0, 1)
            start = warm(key)
            iters = config.preview_iter if start is not None else 5 * config.preview_iter
            return morph(
                small_a[0],
                small_b[0],
                _rescale(pa, a, size).float(),
                _rescale(pb, b, size).float(),
                frames=config.preview_frames,
                max_iter=iters,
                tolerance=config.preview_tolerance,
                warm_start=start,
                progress=False,
                **settings,
            )

        gen, res = await anyio.to_thread.run_sync(lambda: worker.run("morph", job, ticket))
        keep_fit(key, res.fit)
        with state.lock:
            state.morph_gen, state.morph_result = gen, res
        err = res.fit.error[0] * (a.shape[-1] / res.frames.shape[-1])  # in A's pixels
        return JSONResponse(
            {
                "generation": gen,
                "frames": int(res.frames.shape[0]),
                "times": (res.times / settings["steps"]).tolist(),
                "trajectories": res.fit.trajectories[0].permute(1, 0, 2).tolist(),  # (M, T + 1, 2) frame pixels
                "error": err.tolist(),
                "mean_error": float(err.mean()),
                "alignment": proposal(pa, pb, settings["align"]),
                "seconds": {k: round(v, 4) for k, v in res.seconds.items()},
                "server_seconds": round(time.perf_counter() - t0, 4),
                "size": [int(res.frames.shape[-1]), int(res.frames.shape[-2])],  # trajectories are in these pixels
            }
        )

    async def morph_frame(request: Request) -> Response:
        q = request.query_params
        kind = _choice("kind", q.get("kind", "blend"), ("blend", "forward", "backward", "jacobian"))
        with state.lock:
            res, gen = state.morph_result, state.morph_gen
        if res is None or q.get("gen") != str(gen):
            return _error("that preview is stale; a newer one replaced it", 410)
        try:
            k = int(q.get("k", "0"))
        except ValueError:
            raise BadInput("k must be an integer frame index") from None
        if not 0 <= k < res.frames.shape[0]:
            raise BadInput(f"frame index k must be in 0..{res.frames.shape[0] - 1}, got {k}")

        def render() -> bytes:
            if kind == "jacobian":
                return _png(_heat(jacobian_determinant(res.maps[k : k + 1])[0]))
            frames = {"blend": res.frames, "forward": res.forward_frames, "backward": res.backward_frames}[kind]
            return _png(frames[k])

        data = await anyio.to_thread.run_sync(render)
        return Response(data, media_type="image/png", headers={"Cache-Control": "no-store"})

    async def morph_export(request: Request) -> Response:
        data = await body_json(request)
        a, b, pa, pb, settings = morph_inputs(data)
        fmt = _choice("format", data.get("format", "gif"), _ANIMATION_FORMATS)
        frames = _integer("frames", data.get("frames", 30), 2, 600)
        fps = _number("fps", data.get("fps", 10), 0.1, 120)
        key = (
            settings["method"],
            settings["grid"],
            settings["steps"],
            settings["control"],
            settings["compressible"],
            tuple(a.shape),
            tuple(b.shape),
        )

        def job() -> bytes:
            res = morph(
                a[0],
                b[0],
                pa.float(),
                pb.float(),
                frames=frames,
                max_iter=config.export_iter,
                warm_start=warm(key),
                progress=False,
                **settings,
            )
            keep_fit(key, res.fit)
            return encode_animation(res.frames, cast(Literal["gif", "mp4"], fmt), fps=fps)

        _, payload = await anyio.to_thread.run_sync(lambda: worker.run(None, job))
        return respond_export(data, payload, data.get("name") or f"morph.{fmt}", (f".{fmt}",), fmt)

    # --------------------------------------------------------------------------------- animate

    def animation_config(data: dict):
        cfg_data = data.get("config")
        if (
            isinstance(cfg_data, dict)
            and isinstance(cfg_data.get("viscosity"), dict)
            and "mask" in cfg_data["viscosity"]
        ):
            raise BadInput("viscosity.mask is not supported in the studio: paint stiff and soft regions instead")
        cfg = parse_config(cfg_data)
        if not cfg.brushes:
            raise BadInput("place at least one brush first (drag on the photo)")
        return cfg

    def animate(cfg, longest: int) -> Tensor:
        original = image("a")
        img = shrink_image(original, longest)
        size = (img.shape[-2], img.shape[-1])
        scaled = cfg.rescaled(size[1] / original.shape[-1], size[0] / original.shape[-2])
        grid = scaled.grid or auto_grid(size)
        viscosity = build_viscosity(scaled, grid, size)
        warp = FluidWarp(grid, scaled.steps, scaled.dt, viscosity)
        with torch.no_grad():
            return torch.cat(list(warp.iter_frames(img, build_forces(scaled))))  # (T + 1, C, H, W)

    async def animate_preview(request: Request) -> Response:
        t0 = time.perf_counter()
        data = await body_json(request)
        cfg = animation_config(data)
        image("a")
        gen, frames = await anyio.to_thread.run_sync(
            lambda: worker.run("animate", lambda: animate(cfg, config.animate_preview_size))
        )
        with state.lock:
            state.animate_gen, state.animate_frames = gen, frames
        return JSONResponse(
            {
                "generation": gen,
                "frames": int(frames.shape[0]),
                "fps": cfg.fps,
                "size": [int(frames.shape[-1]), int(frames.shape[-2])],
                "server_seconds": round(time.perf_counter() - t0, 4),
            }
        )

    async def animate_frame(request: Request) -> Response:
        q = request.query_params
        with state.lock:
            frames, gen = state.animate_frames, state.animate_gen
        if frames is None or q.get("gen") != str(gen):
            return _error("that preview is stale; a newer one replaced it", 410)
        try:
            k = int(q.get("k", "0"))
        except ValueError:
            raise BadInput("k must be an integer frame index") from None
        if not 0 <= k < frames.shape[0]:
            raise BadInput(f"frame index k must be in 0..{frames.shape[0] - 1}, got {k}")
        data = await anyio.to_thread.run_sync(lambda: _png(frames[k]))
        return Response(data, media_type="image/png", headers={"Cache-Control": "no-store"})

    async def animate_export(request: Request) -> Response:
        data = await body_json(request)
        cfg = animation_config(data)
        fmt = _choice("format", data.get("format", "gif"), _ANIMATION_FORMATS + ("json",))
        if fmt == "json":
            payload = (json.dumps(config_json(cfg), indent=2) + "\n").encode()
        else:
            image("a")

            def job() -> bytes:
                return encode_animation(
                    animate(cfg, config.animate_export_size), cast(Literal["gif", "mp4"], fmt), fps=cfg.fps
                )

            _, payload = await anyio.to_thread.run_sync(lambda: worker.run(None, job))
        return respond_export(data, payload, data.get("name") or f"animation.{fmt}", (f".{fmt}",), fmt)

    routes = [
        Route("/", guarded(index)),
        Route("/static/{name}", guarded(static_file)),
        Route("/api/state", guarded(get_state)),
        Route("/api/image/{slot}", guarded(put_image), methods=["PUT", "POST"]),
        Route("/api/image/{slot}", guarded(get_image), methods=["GET"]),
        Route("/api/points", guarded(put_points), methods=["PUT", "POST"]),
        Route("/api/points/{slot}/import", guarded(import_points), methods=["POST"]),
        Route("/api/points/export", guarded(export_points), methods=["POST"]),
        Route("/api/morph/preview", guarded(morph_preview), methods=["POST"]),
        Route("/api/morph/frame", guarded(morph_frame), methods=["GET"]),
        Route("/api/morph/export", guarded(morph_export), methods=["POST"]),
        Route("/api/animate/preview", guarded(animate_preview), methods=["POST"]),
        Route("/api/animate/frame", guarded(animate_frame), methods=["GET"]),
        Route("/api/animate/export", guarded(animate_export), methods=["POST"]),
    ]
    app = Starlette(routes=routes)
    app.add_middleware(_Guard, config=config)
    app.state.studio = state  # for tests and debugging
    app.state.worker = worker
    return app


def config_json(cfg) -> dict:
    """An :class:`~torchfluidwarp.apps.animate.AnimationConfig` as the JSON ``torchfluidwarp animate`` reads."""
    out: dict[str, Any] = {
        "brushes": [
            {
                "position": list(b.position),
                "direction": list(b.direction),
                "radius": b.radius,
                "frequency": b.frequency,
                "amplitude": b.amplitude,
                "phase": b.phase,
            }
            for b in cfg.brushes
        ],
        "viscosity": {
            "base": cfg.viscosity.base,
            "regions": [
                {"position": list(r.position), "radius": r.radius, "value": r.value} for r in cfg.viscosity.regions
            ],
        },
        "steps": cfg.steps,
        "dt": cfg.dt,
        "fps": cfg.fps,
    }
    if cfg.grid is not None:
        out["grid"] = list(cfg.grid)
    return out
