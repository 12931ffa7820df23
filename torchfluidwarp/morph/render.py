"""Rendering a fitted morph: each frame's maps for image A and image B, and the cross-dissolve.

A frame at fluid time ``s`` (steps, ``0..T``) and an output pixel ``y``: ``z = M_s^-1 y`` is the point in the
fluid's frame; image A is read at ``g_s(z)`` (the fluid's backward map) and image B at ``M K_s(z)``, where
``K_s`` carries ``z`` forward from ``s`` to ``T`` through the same velocities (``inverse="flow"``), or through a
chain of small per-step fits (``inverse="paper"``). Maps are ``(1, H, W, 2)`` in pixels, ``(x, y)``, pixel
centres at integers.
"""

from __future__ import annotations

import time
from typing import Any, Literal

import torch
from torch import Tensor

from torchfluidwarp.control.alignment import apply_alignment, interpolate_alignment
from torchfluidwarp.control.keyframes import KeyframeFit, fit_keyframes
from torchfluidwarp.warp.layer import _warp_image, backward_maps, identity_map, jacobian_determinant, maps_to_end

InverseMethod = Literal["flow", "paper"]
Blend = Literal["linear", "smooth"]


def _blend_weights(times: Tensor, T: int, blend: Blend) -> Tensor:
    u = times / T
    if blend == "linear":
        return u
    if blend == "smooth":
        return u * u * (3 - 2 * u)  # smoothstep: ease in and out
    raise ValueError(f"blend must be 'linear' or 'smooth', got {blend!r}")


FEATHER = 64.0
"""Output pixels: the cross-dissolve hands a frame over to the other image within this distance inside an
image's edge (see :func:`_dissolve`), so neither image's edge, nor the edge pixels that sampling smears beyond
it, shows as a line."""


def _coverage(coords: Tensor, det: Tensor, size: tuple[int, int], feather: float = FEATHER) -> Tensor:
    """``(1, 1, H, W)`` in ``[0, 1]``: 1 where a map ``(1, H, W, 2)`` reads at least ``feather`` output pixels
    inside an image of ``size``, falling linearly to 0 at its edge (and 0 beyond). Distances in the image are
    converted to output pixels by the map's local scale, ``sqrt |det J|`` source pixels per output pixel, from the
    map's Jacobian determinant ``det`` ``(1, H, W)``."""
    H, W = size
    x, y = coords[..., 0], coords[..., 1]
    inside = torch.minimum(torch.minimum(x + 0.5, W - 0.5 - x), torch.minimum(y + 0.5, H - 0.5 - y))
    scale = det.abs().clamp(min=1e-12).sqrt()
    if feather <= 0:  # no band: the hand-over happens at the edge itself
        return (inside >= 0).to(coords.dtype).unsqueeze(1)
    return (inside / (scale * feather)).clamp(0, 1).unsqueeze(1)


def _dissolve(
    fa: Tensor,
    fb: Tensor,
    map_a: Tensor,
    map_b: Tensor,
    det_a: Tensor,
    det_b: Tensor,
    w: float,
    size: tuple[int, int],
    feather: float = FEATHER,
) -> Tensor:
    """Cross-dissolve ``(1 - w) fa + w fb``, except near and beyond an image's edge.

    Beyond it, sampling holds the edge pixels and smears them into streaks (the pre-alignment can reach far beyond
    the other image), and at it the picture ends in a line; so the weight moves toward the image that is read
    further inside, ``w' = w c_b / ((1 - w) c_a + w c_b)`` with the coverages ``c`` of :func:`_coverage`. Where both
    read at least ``feather`` output pixels inside, or both beyond, it is ``w``.
    """
    ca, cb = _coverage(map_a, det_a, size, feather), _coverage(map_b, det_b, size, feather)
    den = (1 - w) * ca + w * cb
    weight = torch.where(den > 0, w * cb / den.clamp(min=1e-12), torch.full_like(den, w))
    return torch.lerp(fa, fb, weight)


def _sample_map(coords: Tensor, at: Tensor) -> Tensor:
    """Read a map ``(1, h, w, 2)`` at pixel positions ``(1, H, W, 2)`` of its grid (bilinear).

    The map's displacement is what is interpolated (and held constant beyond the map's grid), so outside the
    grid the map continues as a translation instead of collapsing onto the edge: the composite stays a proper,
    fold-free map, without a kink where the grid (a fluid box) ends."""
    disp = coords - identity_map((coords.shape[1], coords.shape[2]), device=coords.device, dtype=coords.dtype)
    return at + _warp_image(disp.permute(0, 3, 1, 2), at, "bilinear").permute(0, 2, 3, 1)


def _paper_inverse(fit: KeyframeFit, times: list[float], size: tuple[int, int], kwargs: dict) -> list[Tensor]:
    """The paper's stepwise inverse warping: maps ``P_s(z)`` into the fluid frame of time ``T``.

    For ``l = T-1 .. 0`` a one-step fit carries the points from their step-``l+1`` positions to their step-``l``
    positions; ``P_l = P_{l+1} o g^(l)`` with ``g^(l)`` that small flow's backward map.
    """
    traj = fit.trajectories  # (1, T + 1, M, 2) in the fluid frame
    T = traj.shape[1] - 1
    current = identity_map(size, device=traj.device, dtype=traj.dtype)  # P_T
    # the step whose one-step flow each frame's time falls in, and how far back from its end it lies
    step_of = [min(int(s), T - 1) for s in times]
    out: list[Tensor | None] = [current if s >= T else None for s in times]
    for step in range(T - 1, -1, -1):
        small = fit_keyframes(traj[:, step + 1], traj[:, step], steps=1, **kwargs)
        vel = small.warp.rollout(small.forces, size).velocities
        mine = [k for k, s in enumerate(times) if out[k] is None and step_of[k] == step]
        back = [step + 1 - times[k] for k in mine]  # how far back from the step's end each frame lies
        wanted = sorted(set(back) | {1.0})  # the whole step too: it carries on to P_step
        maps = backward_maps(vel, size, small.warp.dt, times=wanted).unbind(1)
        composed = {frac: _sample_map(current, m) for frac, m in zip(wanted, maps)}
        for k, frac in zip(mine, back):
            out[k] = composed[frac]
        current = composed[1.0]
    return [m for m in out if m is not None]


def render(
    a: Tensor,
    b: Tensor,
    fit: KeyframeFit,
    M: Tensor,
    center: Tensor,
    box: tuple[int, int, int, int],
    size: tuple[int, int],
    roi: tuple[int, int],
    steps: int,
    n: int,
    inverse: InverseMethod,
    blend: Blend,
    fit_kwargs: dict[str, Any],
    feather: float = FEATHER,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor, float, int]:
    """Render the frames of a fitted morph (see :func:`morph`); the last value counts the folded map pixels."""
    times = torch.linspace(0, steps, n, dtype=torch.float64)  # fluid time of each frame, on the CPU: scalars
    time_list = [float(s) for s in times]
    time_list[-1] = float(steps)
    velocities = fit.warp.rollout(fit.forces, roi).velocities.to(a.dtype)
    # the maps live on the fluid's box (box pixels); each frame reads them where its pixels come from
    g = backward_maps(velocities, roi, fit.warp.dt, time_list)[0].unsqueeze(1)  # (N, 1, h_r, w_r, 2)
    if inverse == "flow":
        k_maps = maps_to_end(velocities, roi, fit.warp.dt, time_list)[0].unsqueeze(1)
    else:
        small_kwargs = {**fit_kwargs, "progress": False}
        k_maps = torch.cat(_paper_inverse(fit, time_list, roi, small_kwargs)).to(a.dtype).unsqueeze(1)
    t_inv = time.perf_counter()
    offset = torch.tensor([box[0], box[1]], dtype=a.dtype, device=a.device)

    weights = _blend_weights(times, steps, blend)
    ident = identity_map(size, device=a.device, dtype=torch.float64)
    out, fwd, bwd, maps_a, maps_b = [], [], [], [], []
    folded = 0
    for k, s in enumerate(time_list):
        Mk = interpolate_alignment(M, s / steps, center)
        z = apply_alignment(torch.linalg.inv(Mk), ident).to(a.dtype) - offset  # (1, H, W, 2) in the box
        map_a = _sample_map(g[k], z) + offset
        k_at = _sample_map(k_maps[k], z) + offset
        map_b = apply_alignment(M, k_at.double()).to(a.dtype)
        fa, fb = _warp_image(a, map_a, "bilinear"), _warp_image(b, map_b, "bilinear")
        det_a, det_b = jacobian_determinant(map_a), jacobian_determinant(map_b)  # (1, H, W) each
        folded += int((det_a <= 0).sum()) + int((det_b <= 0).sum())
        out.append(_dissolve(fa, fb, map_a, map_b, det_a, det_b, float(weights[k]), size, feather))
        fwd.append(fa)
        bwd.append(fb)
        maps_a.append(map_a)
        maps_b.append(map_b)
    frames_t = torch.cat(out)
    # the endpoints are the inputs by definition; rendering them reproduces them to sampling round-off
    frames_t[0], frames_t[-1] = a[0], b[0]
    return frames_t, torch.cat(fwd), torch.cat(bwd), torch.cat(maps_a), torch.cat(maps_b), times, t_inv, folded
