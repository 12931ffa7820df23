"""The studio's morph and animate routes: previews while the user edits, frames of the newest preview, exports.

A morph preview is :func:`~torchfluidwarp.morph.morph` at about the pane's size, warm-started from the previous
fit; an animation is :func:`~torchfluidwarp.apps.animate.animate_frames`, the pipeline the command line runs.
Points move between an image's pixels and a resized copy's through :mod:`torchfluidwarp.core.grid`. Each
handler is ``async (session, request) -> response``; :mod:`~torchfluidwarp.apps.studio.routes` mounts them.
"""

from __future__ import annotations

import dataclasses
import json
import time
from typing import Literal, cast

import torch
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from torch import Tensor

from torchfluidwarp.apps.animate import AnimationConfig, animate_frames, config_json, parse_config
from torchfluidwarp.apps.studio.guard import error_response
from torchfluidwarp.apps.studio.inputs import (
    BadInput,
    body_json,
    choice,
    frame_index,
    integer,
    morph_settings,
    number,
    points,
    points_inside,
)
from torchfluidwarp.apps.studio.jobs import in_thread, run_in_worker
from torchfluidwarp.apps.studio.render import area_change_png, export_response, png, png_response
from torchfluidwarp.apps.studio.session import Session
from torchfluidwarp.control.alignment import estimate_alignment
from torchfluidwarp.core.grid import rescale_points, scale_factor
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import encode_animation, shrink_image
from torchfluidwarp.morph import MorphResult, MorphSettings, Timing, morph

__all__ = [
    "ANIMATION_FORMATS",
    "checked_pair",
    "proposal",
    "morph_preview",
    "morph_frame",
    "morph_export",
    "animate_preview",
    "animate_frame",
    "animate_export",
]

ANIMATION_FORMATS = ("gif", "mp4")
_STALE = "that preview is stale; a newer one replaced it"


def checked_pair(session: Session, data: dict) -> tuple[Tensor, Tensor]:
    """The request's ``points_a`` and ``points_b``: the same count, each inside its image."""
    pa, pb = points("points_a", data.get("points_a")), points("points_b", data.get("points_b"))
    if pa.shape[0] != pb.shape[0]:
        raise BadInput(f"points_a has {pa.shape[0]} points but points_b has {pb.shape[0]}")
    return points_inside("points_a", pa, session.image("a")), points_inside("points_b", pb, session.image("b"))


def proposal(pa: Tensor, pb: Tensor, align: str | None) -> list | None:
    """The alignment A -> B (original pixels) that proposes partners, once 3 pairs exist."""
    if pa.shape[0] < 3:
        return None
    try:
        return estimate_alignment(pa, pb, "affine" if align == "affine" else "similarity").tolist()
    except InputError:
        return None


def _to_size(pts: Tensor, image: Tensor, size: tuple[int, int]) -> Tensor:
    """``pts`` ``(M, 2)`` in the pixels of ``image`` ``(1, C, H, W)`` as pixels of the same picture at ``size``."""
    moved = rescale_points(pts, scale_factor((image.shape[-2], image.shape[-1]), size, dtype=pts.dtype))
    hi = torch.tensor([size[1] - 0.5, size[0] - 0.5], dtype=pts.dtype)
    return torch.minimum(moved.clamp(min=-0.5), hi)  # round-off stays inside


# ---------------------------------------------------------------------------------------------------- morph


def _morph_inputs(session: Session, data: dict) -> tuple[Tensor, Tensor, Tensor, Tensor, MorphSettings, Timing, tuple]:
    """Images, points and settings of a morph request, and the key under which its fit warm-starts others."""
    pa, pb = checked_pair(session, data)
    settings, timing = morph_settings(data.get("settings"))
    need = 3 if settings.align == "affine" else 2
    if pa.shape[0] < need:
        raise BadInput(f"place at least {need} pairs of points first (have {pa.shape[0]})")
    a, b = session.image("a"), session.image("b")
    # a fit warm-starts another of the same fluid and forces (the pre-alignment, inverse and timing may differ)
    flow = (settings.method, settings.grid, settings.steps, getattr(settings, "control", None), settings.compressible)
    key = (*flow, tuple(a.shape), tuple(b.shape))
    return a, b, pa, pb, settings, timing, key


async def morph_preview(session: Session, request: Request) -> Response:
    t0 = time.perf_counter()
    config = session.config
    a, b, pa, pb, settings, timing, key = _morph_inputs(session, await body_json(request))
    with session.lock:
        session.points["a"], session.points["b"] = pa, pb
    ticket = session.worker.ticket("morph")

    def job() -> MorphResult:
        # the fit costs the same at any resolution; the inverse maps and the frames cost per pixel, so the
        # preview is rendered at about the pane's size: A shrunk to it, and B by the same factor, so that the
        # morph places B on the preview's canvas as the export places it on A's (one factor, never stretched)
        small_a = shrink_image(a, config.preview_size)
        size = (small_a.shape[-2], small_a.shape[-1])
        factor = max(size) / max(a.shape[-2], a.shape[-1])
        small_b = shrink_image(b, max(2, round(max(b.shape[-2], b.shape[-1]) * factor)))
        start = session.warm(key)
        iterations = config.preview_iter if start is not None else 5 * config.preview_iter
        return morph(
            small_a[0],
            small_b[0],
            _to_size(pa, a, size).float(),
            _to_size(pb, b, (small_b.shape[-2], small_b.shape[-1])).float(),
            settings=dataclasses.replace(settings, max_iter=iterations, tolerance=config.preview_tolerance),
            frames=config.preview_frames,
            timing=timing,
            warm_start=start,
            progress=False,
        )

    gen, res = await run_in_worker(session.worker, "morph", job, ticket)
    session.keep_fit(key, res.fit)
    with session.lock:
        session.morph_gen, session.morph_result = gen, res
    frame_size = (res.frames.shape[-2], res.frames.shape[-1])
    to_a = scale_factor(frame_size, (a.shape[-2], a.shape[-1]), dtype=res.error.dtype)[0]
    err = res.error * to_a  # in A's pixels
    met = err[~res.let_go] if bool((~res.let_go).any()) else err  # the marks let go so as not to fold apart
    return JSONResponse(
        {
            "generation": gen,
            "frames": int(res.frames.shape[0]),
            "times": (res.times / settings.steps).tolist(),
            "trajectories": res.trajectories.permute(1, 0, 2).tolist(),  # (M, T + 1, 2) frame pixels
            "error": err.tolist(),
            "mean_error": float(met.mean()),
            "let_go": res.let_go.tolist(),  # (M,) the marks let go so as not to fold (they cross)
            "alignment": proposal(pa, pb, settings.align),
            "seconds": {k: round(v, 4) for k, v in res.seconds.items()},
            "server_seconds": round(time.perf_counter() - t0, 4),
            "size": [frame_size[1], frame_size[0]],  # trajectories are in these pixels
        }
    )


async def morph_frame(session: Session, request: Request) -> Response:
    q = request.query_params
    kind = choice("kind", q.get("kind", "blend"), ("blend", "forward", "backward", "jacobian"))
    with session.lock:
        res, gen = session.morph_result, session.morph_gen
    if res is None or q.get("gen") != str(gen):
        return error_response(_STALE, 410)
    k = frame_index(q.get("k"), res.frames.shape[0])

    def render() -> bytes:
        if kind == "jacobian":
            return area_change_png(res.maps[k : k + 1])
        return png({"blend": res.frames, "forward": res.forward_frames, "backward": res.backward_frames}[kind][k])

    return png_response(await in_thread(render))


async def morph_export(session: Session, request: Request) -> Response:
    data = await body_json(request)
    a, b, pa, pb, settings, timing, key = _morph_inputs(session, data)
    fmt = choice("format", data.get("format", "gif"), ANIMATION_FORMATS)
    frames = integer("frames", data.get("frames", 30), 2, 600)
    fps = number("fps", data.get("fps", 10), 0.1, 120)

    def job() -> bytes:
        iterations = session.config.export_iter  # None: the method's default
        res = morph(
            a[0],
            b[0],
            pa.float(),
            pb.float(),
            settings=settings if iterations is None else dataclasses.replace(settings, max_iter=iterations),
            frames=frames,
            timing=timing,
            warm_start=session.warm(key),
            progress=False,
        )
        session.keep_fit(key, res.fit)
        return encode_animation(res.frames, cast(Literal["gif", "mp4"], fmt), fps=fps)

    _, payload = await run_in_worker(session.worker, None, job)
    return export_response(session.config.save_dir, data, payload, f"morph.{fmt}", fmt)


# -------------------------------------------------------------------------------------------------- animate


def _animation_config(data: dict) -> AnimationConfig:
    cfg_data = data.get("config")
    viscosity = cfg_data.get("viscosity") if isinstance(cfg_data, dict) else None
    if isinstance(viscosity, dict) and "mask" in viscosity:
        raise BadInput("viscosity.mask is not supported in the studio: paint stiff and soft regions instead")
    cfg = parse_config(cfg_data)
    if not cfg.brushes:
        raise BadInput("place at least one brush first (drag on the photo)")
    return cfg


def _animate(session: Session, cfg: AnimationConfig, longest: int) -> Tensor:
    """The animation of image A, its longer side at most ``longest`` pixels: ``(T + 1, C, H, W)``."""
    return torch.stack(list(animate_frames(cfg, session.image("a"), max_size=longest)))


async def animate_preview(session: Session, request: Request) -> Response:
    t0 = time.perf_counter()
    cfg = _animation_config(await body_json(request))
    session.image("a")
    longest = session.config.animate_preview_size
    gen, frames = await run_in_worker(session.worker, "animate", lambda: _animate(session, cfg, longest))
    with session.lock:
        session.animate_gen, session.animate_frames = gen, frames
    return JSONResponse(
        {
            "generation": gen,
            "frames": int(frames.shape[0]),
            "fps": cfg.fps,
            "size": [int(frames.shape[-1]), int(frames.shape[-2])],
            "server_seconds": round(time.perf_counter() - t0, 4),
        }
    )


async def animate_frame(session: Session, request: Request) -> Response:
    q = request.query_params
    with session.lock:
        frames, gen = session.animate_frames, session.animate_gen
    if frames is None or q.get("gen") != str(gen):
        return error_response(_STALE, 410)
    k = frame_index(q.get("k"), frames.shape[0])
    return png_response(await in_thread(lambda: png(frames[k])))


async def animate_export(session: Session, request: Request) -> Response:
    data = await body_json(request)
    cfg = _animation_config(data)
    fmt = choice("format", data.get("format", "gif"), (*ANIMATION_FORMATS, "json"))
    if fmt == "json":
        payload = (json.dumps(config_json(cfg), indent=2) + "\n").encode()
    else:
        session.image("a")
        longest = session.config.animate_export_size

        def job() -> bytes:
            return encode_animation(_animate(session, cfg, longest), cast(Literal["gif", "mp4"], fmt), fps=cfg.fps)

        _, payload = await run_in_worker(session.worker, None, job)
    return export_response(session.config.save_dir, data, payload, f"animation.{fmt}", fmt)
