"""The studio: a local web page to mark corresponding points, preview the morph live, and animate a photo.

Start it with ``torchfluidwarp studio [A.png [B.png]]``; it needs the ``[studio]`` extra
(``pip install 'torchfluidwarp[studio]'``). :func:`main` parses the subcommand's arguments itself, and
:func:`add_arguments` + :func:`run` let the CLI build a proper subparser. :func:`create_app` is the Starlette
app, for embedding or testing.
"""

from __future__ import annotations

from torchfluidwarp.apps.studio.app import StudioConfig, create_app, loopback_hosts
from torchfluidwarp.apps.studio.server import add_arguments, main, run, serve_in_thread

__all__ = ["main", "add_arguments", "run", "create_app", "StudioConfig", "loopback_hosts", "serve_in_thread"]
