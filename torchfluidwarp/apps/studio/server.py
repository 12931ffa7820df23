"""Run the studio: parse ``torchfluidwarp studio``'s arguments, load the inputs, serve with uvicorn.

``torchfluidwarp studio [A.png [B.png]] [--points-a F] [--points-b F] [--port N] [--host H] [--no-browser]
[--save-dir DIR]``. Without images it opens the bundled samples (astronaut and cat) with their landmarks.

Exit status: 0 after a normal shutdown (Ctrl+C), 2 for bad input (a missing image, a bad points file, a port in
use) with a one-line message on stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import secrets
import socket
import sys
import threading
import webbrowser
from collections.abc import Iterator
from pathlib import Path

import torch
from torch import Tensor

from torchfluidwarp.apps.cli_args import fail
from torchfluidwarp.apps.studio.app import StudioConfig, create_app, loopback_hosts
from torchfluidwarp.control.keyframes import check_points
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import check_point_counts, read_image, read_points

__all__ = ["add_arguments", "run", "main", "serve_in_thread", "free_port", "DEFAULT_PORT"]

DEFAULT_PORT = 8765
PROG = "torchfluidwarp studio"
_LOOPBACK = ("127.0.0.1", "localhost", "::1")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the studio's options to ``parser`` (the CLI's ``studio`` subparser, or a standalone one)."""
    parser.add_argument("image_a", metavar="A", nargs="?", help="first image (default: the bundled astronaut)")
    parser.add_argument("image_b", metavar="B", nargs="?", help="second image (default: the bundled cat)")
    parser.add_argument("--points-a", metavar="FILE", help="points on A (.pts, .json or .csv)")
    parser.add_argument("--points-b", metavar="FILE", help="points on B (.pts, .json or .csv)")
    parser.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"port to listen on (default {DEFAULT_PORT}; 0 picks a free one)"
    )
    parser.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only). Anything else exposes "
        "your images to the network, guarded only by the session token",
    )
    parser.add_argument("--no-browser", action="store_true", help="do not open a web browser")
    parser.add_argument(
        "--save-dir",
        metavar="DIR",
        help="folder the page may save exports into (created if missing; existing files are never "
        "replaced). Without it the studio writes no file: exports are downloads",
    )


def free_port(host: str = "127.0.0.1") -> int:
    """A port that is free on ``host`` right now."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _check_port(host: str, port: int) -> None:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        try:
            s.bind((host, port))
        except OSError as exc:
            raise OSError(f"cannot listen on {host}:{port} ({exc.strerror}); try --port 0") from None


def _url(host: str, port: int, token: str) -> str:
    shown = "127.0.0.1" if host in ("0.0.0.0", "") else (f"[{host}]" if ":" in host else host)
    return f"http://{shown}:{port}/?token={token}"


def _load(args: argparse.Namespace) -> tuple[dict[str, tuple[Tensor, str]], dict[str, Tensor]]:
    images: dict[str, tuple[Tensor, str]] = {}
    points: dict[str, Tensor] = {}
    if args.image_a is None:
        from torchfluidwarp.data import load_sample, load_sample_points

        images = {"a": (load_sample("astronaut"), "astronaut.png"), "b": (load_sample("cat"), "cat.png")}
        if args.points_a is None and args.points_b is None:
            points = {"a": load_sample_points("astronaut"), "b": load_sample_points("cat")}
    else:
        images["a"] = (read_image(args.image_a, channels=3), Path(args.image_a).name)
        if args.image_b is not None:
            images["b"] = (read_image(args.image_b, channels=3), Path(args.image_b).name)
    for key, path in (("a", args.points_a), ("b", args.points_b)):
        if path is None:
            continue
        if key not in images:
            raise InputError(f"--points-{key} needs image {key.upper()}")
        image = images[key][0]
        points[key] = check_points(f"--points-{key} {path!r}", read_points(path), (image.shape[-2], image.shape[-1]))[0]
    if "a" in points and "b" in points:
        check_point_counts(points["a"], points["b"], "--points-a", "--points-b")
    return images, points


def run(args: argparse.Namespace) -> int:
    """Start the studio with parsed arguments; blocks until Ctrl+C. Returns the exit status."""
    import uvicorn

    try:
        if not 0 <= args.port <= 65535:
            raise InputError(f"--port must be in 0..65535, got {args.port}")
        images, points = _load(args)
        save_dir = None
        if args.save_dir is not None:
            save_dir = Path(args.save_dir).expanduser().resolve()
            if save_dir.exists() and not save_dir.is_dir():
                raise InputError(f"--save-dir {args.save_dir!r} is not a folder")
            save_dir.mkdir(parents=True, exist_ok=True)
        port = args.port or free_port(args.host)
        _check_port(args.host, port)
    except (InputError, OSError) as exc:
        return fail("studio", exc)
    if args.host not in _LOOPBACK:
        print(
            f"{PROG}: warning: listening on {args.host}, not only on this machine: anyone who can reach it and "
            "learns the address with its token can see your images",
            file=sys.stderr,
        )
    # the studio's fits are small (a 32 x 32 fluid): one torch thread runs a warm preview in about half the
    # time that two threads take from the server's worker thread (benchmarks/bench_studio.py); this process
    # is the studio's own, so its thread count is ours to set
    torch.set_num_threads(1)
    token = secrets.token_urlsafe(24)
    config = StudioConfig(token=token, allowed_hosts=loopback_hosts(port, args.host), save_dir=save_dir)
    app = create_app(config, images=images, points=points)
    url = _url(args.host, port, token)
    server = uvicorn.Server(uvicorn.Config(app, host=args.host, port=port, log_level="warning"))
    print(f"torchfluidwarp studio: {url}", flush=True)
    if save_dir is not None:
        print(f"torchfluidwarp studio: exports may be saved into {save_dir}", flush=True)
    if not args.no_browser:
        threading.Timer(1.0, lambda: webbrowser.open(url)).start()
    try:
        server.run()
    except KeyboardInterrupt:
        pass
    except (OSError, SystemExit):  # uvicorn exits when it cannot bind
        return fail("studio", f"cannot listen on {args.host}:{port}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``torchfluidwarp studio`` as a function: parse ``argv`` (default ``sys.argv[1:]``), then :func:`run`."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Mark corresponding points, preview the morph live, "
        "and animate a photo with brushes, in a local web page.",
    )
    add_arguments(parser)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 0
    return run(args)


@contextlib.contextmanager
def serve_in_thread(app, host: str = "127.0.0.1", port: int = 0) -> Iterator[int]:
    """Serve ``app`` with uvicorn in a background thread (for tests); yields the port, stops on exit."""
    import time

    import uvicorn

    port = port or free_port(host)
    server = uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level="warning", lifespan="off"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError(f"the studio server did not start on {host}:{port}")
        time.sleep(0.02)
    try:
        yield port
    finally:
        server.should_exit = True
        thread.join(timeout=10)
