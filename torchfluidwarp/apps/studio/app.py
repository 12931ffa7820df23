"""The studio's web app: a Starlette application over the public API (no fluid logic lives here).

:func:`create_app` wires the pieces, one module a job:

* :mod:`~torchfluidwarp.apps.studio.config`: :class:`StudioConfig`, the settings;
* :mod:`~torchfluidwarp.apps.studio.guard`: the token, the Host check, the upload limit, the save folder (the
  security model is described there);
* :mod:`~torchfluidwarp.apps.studio.session`: the images, points and newest results of one server;
* :mod:`~torchfluidwarp.apps.studio.jobs`: fits in a worker thread, one at a time, newest first;
* :mod:`~torchfluidwarp.apps.studio.inputs` and :mod:`~torchfluidwarp.apps.studio.render`: what the page sends,
  checked, and what it gets back, encoded;
* :mod:`~torchfluidwarp.apps.studio.routes` and :mod:`~torchfluidwarp.apps.studio.previews`: the routes.

Conventions: points are ``(x, y)`` in each image's pixels, pixel centres at integers (as in
:mod:`torchfluidwarp.io`).
"""

from __future__ import annotations

from starlette.applications import Starlette
from torch import Tensor

from torchfluidwarp.apps.studio.config import StudioConfig
from torchfluidwarp.apps.studio.guard import Guard, loopback_hosts
from torchfluidwarp.apps.studio.routes import routes
from torchfluidwarp.apps.studio.session import Session

__all__ = ["StudioConfig", "create_app", "loopback_hosts"]


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
        A Starlette app; serve it with uvicorn (see :mod:`torchfluidwarp.apps.studio.server`). Its
        ``state.studio`` is the :class:`~torchfluidwarp.apps.studio.session.Session` and ``state.worker`` the
        job runner, for tests and debugging.
    """
    session = Session(config, images, points)
    app = Starlette(routes=routes(session))
    app.add_middleware(Guard, config=config)
    app.state.studio = session
    app.state.worker = session.worker
    return app
