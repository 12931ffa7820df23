"""The studio's routes: the page and its files, the state, images and points; the table of every route.

Each handler is ``async (session, request) -> response``. :func:`routes` binds them to one
:class:`~torchfluidwarp.apps.studio.session.Session` and turns bad input (``ValueError``, ``TypeError``) into a
400 with a one-line JSON ``{"error": ...}`` that the page shows, and a superseded job into a 409; the server
keeps serving. The morph and animate handlers live in :mod:`~torchfluidwarp.apps.studio.previews`.
"""

from __future__ import annotations

import warnings
from collections.abc import Awaitable, Callable
from importlib import resources
from pathlib import Path

from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route
from torch import Tensor

from torchfluidwarp.apps.studio import previews
from torchfluidwarp.apps.studio.guard import error_response
from torchfluidwarp.apps.studio.inputs import BadInput, body_json, choice, morph_settings, points, points_inside
from torchfluidwarp.apps.studio.jobs import Superseded, in_thread
from torchfluidwarp.apps.studio.render import export_response, png, png_response, points_bytes, points_from_bytes
from torchfluidwarp.apps.studio.session import IMAGE_SLOTS, Session
from torchfluidwarp.errors import FlowBlewUp, InputError, InputTypeError
from torchfluidwarp.io import read_image_bytes

__all__ = ["routes"]

Handler = Callable[[Session, Request], Awaitable[Response]]

_STATIC = {"index.html": "text/html", "studio.js": "text/javascript", "studio.css": "text/css"}
_POINT_FORMATS = ("pts", "json", "csv")


def _static(name: str) -> bytes:
    return (resources.files("torchfluidwarp.apps.studio") / "static" / name).read_bytes()


# ------------------------------------------------------------------------------- page, static files, state


async def index(session: Session, request: Request) -> Response:
    html = _static("index.html").decode("utf-8").replace("__TOKEN__", session.config.token)
    return Response(
        html, media_type="text/html", headers={"Cache-Control": "no-store", "Referrer-Policy": "no-referrer"}
    )


async def static_file(session: Session, request: Request) -> Response:
    name = request.path_params["name"]
    if name not in _STATIC:
        return error_response("not found", 404)
    return Response(_static(name), media_type=_STATIC[name], headers={"Cache-Control": "no-store"})


async def get_state(session: Session, request: Request) -> Response:
    return JSONResponse(session.describe())


# ---------------------------------------------------------------------------------------------------- images


async def put_image(session: Session, request: Request) -> Response:
    slot = choice("image slot", request.path_params["slot"], IMAGE_SLOTS)
    data = await request.body()
    name = Path(request.query_params.get("name", f"{slot}.png")).name or f"{slot}.png"
    if not data:
        raise BadInput("the upload is empty")
    try:
        img, said = await in_thread(lambda: _read_upload(data, name))
    except InputError as exc:  # the reader's reason: not an image, a HEIC without pillow-heif, too many pixels
        raise BadInput(exc.explain({})) from None  # without advice on Python arguments a page user cannot pass
    if min(img.shape[-2:]) < 8:
        raise BadInput(f"{name!r} is too small ({img.shape[-1]}x{img.shape[-2]} pixels; at least 8x8)")
    session.set_image(slot, img, name)
    return JSONResponse({**session.describe(), "warnings": said})


def _read_upload(data: bytes, name: str) -> tuple[Tensor, list[str]]:
    """An upload as ``(1, 3, H, W)``, with what the reader warned of (only the first frame of an animation was
    read, a colour profile that could not be applied) for the page to show."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        img = read_image_bytes(data, channels=3, name=name)
    return img, [str(w.message) for w in caught if issubclass(w.category, UserWarning)]


async def get_image(session: Session, request: Request) -> Response:
    slot = choice("image slot", request.path_params["slot"], IMAGE_SLOTS)
    return png_response(await in_thread(lambda: png(session.image(slot)[0])))


# ---------------------------------------------------------------------------------------------------- points


async def put_points(session: Session, request: Request) -> Response:
    data = await body_json(request)
    pa, pb = previews.checked_pair(session, data)
    settings, _ = morph_settings(data.get("settings"))
    with session.lock:
        session.points["a"], session.points["b"] = pa, pb
    return JSONResponse({"count": pa.shape[0], "alignment": previews.proposal(pa, pb, settings.align)})


async def import_points(session: Session, request: Request) -> Response:
    slot = choice("image slot", request.path_params["slot"], IMAGE_SLOTS)
    name = Path(request.query_params.get("name", "points.pts")).name
    pts = points_from_bytes(await request.body(), name)
    other = "b" if slot == "a" else "a"
    want = request.query_params.get("count")
    if want is not None and want.isdigit() and int(want) > 0 and int(want) != pts.shape[0]:
        raise BadInput(f"{name!r} has {pts.shape[0]} points but image {other.upper()} has {want}")
    return JSONResponse({"points": points_inside(repr(name), pts, session.image(slot)).tolist()})


async def export_points(session: Session, request: Request) -> Response:
    data = await body_json(request)
    fmt = choice("format", data.get("format", "pts"), _POINT_FORMATS)
    pts = points("points", data.get("points"))
    if pts.shape[0] == 0:
        raise BadInput("there are no points to export")
    return export_response(session.config.save_dir, data, points_bytes(pts, fmt), f"points.{fmt}", fmt)


# ----------------------------------------------------------------------------------------------------- table


def _endpoint(session: Session, handler: Handler) -> Callable[[Request], Awaitable[Response]]:
    async def endpoint(request: Request) -> Response:
        try:
            return await handler(session, request)
        except (InputError, InputTypeError) as exc:  # BadInput, and the library's own argument errors
            return error_response(str(exc), 400)
        except FlowBlewUp as exc:  # the page's settings make the flow blow up: say so, it is not a bug
            return error_response(str(exc), 422)
        except Superseded:
            return error_response("superseded by a newer request", 409)
        except RuntimeError as exc:  # e.g. MP4 without imageio-ffmpeg
            return error_response(str(exc), 400 if "imageio-ffmpeg" in str(exc) else 500)

    return endpoint


_TABLE: tuple[tuple[str, Handler, list[str] | None], ...] = (
    ("/", index, None),
    ("/static/{name}", static_file, None),
    ("/api/state", get_state, None),
    ("/api/image/{slot}", put_image, ["PUT", "POST"]),
    ("/api/image/{slot}", get_image, ["GET"]),
    ("/api/points", put_points, ["PUT", "POST"]),
    ("/api/points/{slot}/import", import_points, ["POST"]),
    ("/api/points/export", export_points, ["POST"]),
    ("/api/morph/preview", previews.morph_preview, ["POST"]),
    ("/api/morph/frame", previews.morph_frame, ["GET"]),
    ("/api/morph/export", previews.morph_export, ["POST"]),
    ("/api/animate/preview", previews.animate_preview, ["POST"]),
    ("/api/animate/frame", previews.animate_frame, ["GET"]),
    ("/api/animate/export", previews.animate_export, ["POST"]),
)


def routes(session: Session) -> list[Route]:
    """Every route of the studio, bound to ``session``."""
    return [Route(path, _endpoint(session, handler), methods=methods) for path, handler, methods in _TABLE]
