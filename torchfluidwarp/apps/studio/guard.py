"""The studio's guards: who may talk to it, and where it may write.

Security model (the server runs on the user's machine and may see their photos):

* every request, the page and its static files included, carries the session's random token, as the query
  parameter ``token`` or the header ``X-Studio-Token``; a missing or wrong token gets 403;
* the ``Host`` header must name the loopback address the server listens on (or the explicit ``--host``), so
  a DNS-rebinding page cannot talk to it; otherwise 403;
* request bodies are limited (:attr:`~torchfluidwarp.apps.studio.config.StudioConfig.max_upload`, 413 beyond);
* nothing is written to disk except into the ``save_dir`` the user named (:func:`save`), never outside it,
  never over an existing file.
"""

from __future__ import annotations

import os
import re
import secrets
import tempfile
from collections.abc import Sequence
from pathlib import Path

from starlette.datastructures import Headers, QueryParams
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from torchfluidwarp.apps.studio.config import StudioConfig
from torchfluidwarp.apps.studio.inputs import BadInput

__all__ = ["TOKEN_HEADER", "Guard", "error_response", "loopback_hosts", "safe_name", "save"]

TOKEN_HEADER = "X-Studio-Token"


def loopback_hosts(port: int, host: str | None = None) -> tuple[str, ...]:
    """The ``Host`` header values the server accepts: loopback names with ``port``, and ``host:port``."""
    names = ["127.0.0.1", "localhost", "[::1]"]
    if host and host not in ("127.0.0.1", "localhost", "::1"):
        names.append(f"[{host}]" if ":" in host else host)
    return tuple(f"{n}:{port}" for n in names)


def error_response(message: str, status: int = 400) -> JSONResponse:
    """``{"error": <first line of message>}`` with ``status``: what the page shows."""
    lines = str(message).strip().splitlines()
    return JSONResponse({"error": lines[0] if lines else "error"}, status_code=status)


class _TooLarge(Exception):
    pass


class Guard:
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
        query = QueryParams(scope.get("query_string", b"").decode("latin-1"))
        limit = self.config.max_upload
        too_large = error_response(f"upload too large (limit {limit // (1024 * 1024)} MiB)", 413)
        length = headers.get("content-length")
        if headers.get("host", "").lower() not in self.hosts:
            refusal = error_response("host not allowed (the studio answers only on its own loopback address)", 403)
        elif not secrets.compare_digest(
            (query.get("token") or headers.get(TOKEN_HEADER, "")).encode(), self.config.token.encode()
        ):
            refusal = error_response("missing or wrong session token: open the address the studio printed", 403)
        elif length is not None and (not length.isdigit() or int(length) > limit):
            refusal = too_large
        else:
            await self._limited(scope, receive, send, too_large)
            return
        await refusal(scope, receive, send)

    async def _limited(self, scope: Scope, receive: Receive, send: Send, too_large: JSONResponse) -> None:
        """Run the app, counting the body as it streams in (a request without Content-Length)."""
        received = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.config.max_upload:
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
                await too_large(scope, receive, send)


def safe_name(name: object, suffixes: Sequence[str]) -> str:
    """A file name for the save folder: relative, no ``..``, one of ``suffixes``.

    Raises:
        BadInput: not a string, absolute, climbing out with ``..``, or another suffix.
    """
    if not isinstance(name, str) or not name or len(name) > 200 or "\x00" in name:
        raise BadInput("the file name must be a non-empty string")
    parts = re.split(r"[\\/]", name)
    if os.path.isabs(name) or name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name) or ".." in parts:
        raise BadInput(f"refusing file name {name!r}: it must stay inside the save folder (no '..', not absolute)")
    if not name.lower().endswith(tuple(suffixes)):
        raise BadInput(f"file name {name!r} must end in {' or '.join(suffixes)}")
    return name


def save(save_dir: Path | None, name: str, data: bytes) -> Path:
    """Write ``data`` to ``save_dir / name`` atomically, refusing to leave the folder or replace a file.

    Raises:
        BadInput: no save folder, a name that resolves outside it (a symlink, say), or a name that exists.
    """
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
