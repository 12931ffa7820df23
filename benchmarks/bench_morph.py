"""Benchmark of morphing: the fluid morph against a thin-plate-spline morph, on the bundled face pair.

The pair is the bundled astronaut (a photograph of a human face) and cat (a photograph of a cat's face), both
512 x 512, with their 23 corresponding points (:func:`torchfluidwarp.data.load_sample_points`). With
``--pair faces`` it is two real photographs of human faces, 512 x 512 with 41 landmarks each (``face_pair.py``
says where they come from), and the middle frames are written as ``morph_faces_mid_*.png``. Everything runs in
float32 on CPU, in one process, so every figure below comes from the same run:

1. **Fluid morph** (:func:`torchfluidwarp.morph.morphing.morph`, default settings otherwise) with ``method="natural"``
   (the default) and ``method="paper"`` (the paper's incompressible keyframe fit), each with
   ``inverse="flow"`` and ``inverse="paper"``. For each:

   * **end error**: ``fit.error.mean()``, the mean distance in pixels between A's points carried to the last
     frame and B's points (pixels of the last frame, i.e. of image B);
   * **folded fraction**: the fraction of pixels, over all frames, where the Jacobian determinant of A's
     backward map (``jacobian_determinant(result.maps)``) is ``<= 0``; then the same counted only over pixels
     whose map source lies inside A's image; and the same for B's maps (``result.maps_b``);
   * **middle-frame misalignment**: at frame ``N // 2``, where A's landmark ``i`` appears in the frame (the
     point ``y_i`` with ``maps[mid](y_i) = a_i``, found by Newton's method on the bilinearly read map
     (:func:`torchfluidwarp.metrics.invert_map_at`, the library's), started from ``fit.trajectories``
     interpolated linearly between fluid steps to the frame's fluid time), and where
     that frame reads image B there: ``|maps_b[mid](y_i) - b_i|``, in B's pixels. "ghost px" is the same gap
     in the frame's own pixels: the distance between ``y_i`` and the point ``z_i`` with
     ``maps_b[mid](z_i) = b_i`` (where B's landmark appears). "traj gap" checks the maps against the point
     trajectories: ``|y_i - trajectory_i(s_mid)|``;
   * **time** of the whole ``N``-frame morph (wall clock around the call) and its split as ``result.seconds``
     reports it (fit, inverse, render), medians over ``--repeats`` repeats; the fit's objective evaluations.

2. **Thin-plate-spline morph** on the same pair: for frame ``k`` (``u = k / (N - 1)``) the points
   ``p_k = (1 - u) a + u b``; A is warped from ``a`` to ``p_k`` and B from ``b`` to ``p_k``, then the two are
   cross-dissolved linearly. Points are in kornia's normalised ``align_corners=False`` frame, as its Convention
   block requires, and ``padding_mode="border"`` matches the fluid morph, which reads the edge pixels beyond
   the image. Two splines, both rendered by ``kornia.geometry.transform.warp_image_tps``:

   * ``kornia``: kornia's documented composition, ``get_tps_transform(p_k, a)`` and ``warp_image_tps(A, a, ...)``
     (kernel centres at the *source* points ``a``), in float32 like the images;
   * ``standard``: the textbook TPS, kernel centres at the points ``p_k`` where the backward map is evaluated,
     solved in float64 by this script (:func:`standard_tps`) and passed to ``warp_image_tps`` with centres
     ``p_k``; the baseline for what a thin-plate spline itself does on this pair.

   The same figures as for the fluid: the end error (where A's landmarks appear in the last frame, against B's
   points; and the spline evaluated exactly at B's points against A's points, zero by construction up to
   round-off), the folded fractions of the TPS backward maps (evaluated with ``warp_points_tps`` on the pixel
   grid, the same arithmetic that ``warp_image_tps`` samples through, and checked against it), the
   middle-frame misalignment and the time.

3. With ``--images DIR`` the middle frames of the natural fluid morphs (``flow`` and ``paper`` inverse) and of
   the kornia TPS morph are written as ``morph_mid_fluid_flow.png``, ``morph_mid_fluid_paper.png`` and
   ``morph_mid_tps.png``.

The fluid morphs are plain :func:`morph` calls, as a user makes them (grad mode on). A tiny call first checks
that the returned frames and maps carry no autograd graph (an earlier version of :func:`morph` kept one, which
with ``inverse="paper"`` chained through all the one-step fits). Repeats are interleaved over the configurations
so that other load on the machine affects them alike; the load average before and after is printed, and the
JSON records a digest of the package's sources. Run ``python benchmarks/bench_morph.py --help`` for the options.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch
import torch.nn.functional as F
from _common import add_threads_argument, status_kib, table, verdict, write_json
from _common import machine as common_machine
from kornia.geometry.transform import get_tps_transform, warp_image_tps, warp_points_tps
from torch import Tensor

import torchfluidwarp
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import write_image
from torchfluidwarp.metrics import LOCATE_TOLERANCE, invert_map_at, read_map
from torchfluidwarp.morph import MorphResult, morph
from torchfluidwarp.warp import identity_map, jacobian_determinant, warp_image

SAMPLE_A, SAMPLE_B = "astronaut", "cat"
# (inverse, method): morph()'s default method first
FLUID_CONFIGS: list[tuple[str, str]] = [
    ("flow", "natural"),
    ("paper", "natural"),
    ("flow", "paper"),
    ("paper", "paper"),
]
IMAGE_METHOD = "natural"  # the default: its middle frames are the ones saved
TIME_TARGET_S = 5.0
TIME_TARGET_FRAMES, TIME_TARGET_SIZE = 30, 512

# ----------------------------------------------------------------------------------------------- inputs


PAIRS = {"bundled": f"{SAMPLE_A} -> {SAMPLE_B}", "faces": "two human faces cropped from a photograph (face_pair.py)"}


def load_pair(size: int | None, pair: str = "bundled") -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """A pair ``(1, 3, H, W)`` x 2 and their points ``(M, 2)`` x 2, optionally resized to ``size``.

    ``"bundled"``: the library's sample pair; ``"faces"``: :func:`face_pair.load_face_pair`.
    """
    if pair == "faces":
        from face_pair import load_face_pair

        a, b, pa, pb = load_face_pair()
    else:
        a, b = load_sample(SAMPLE_A), load_sample(SAMPLE_B)
        pa, pb = load_sample_points(SAMPLE_A), load_sample_points(SAMPLE_B)
    if size is not None and size != a.shape[-1]:
        scale = size / a.shape[-1]
        a, b = (
            F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False, antialias=True) for x in (a, b)
        )
        pa, pb = ((p + 0.5) * scale - 0.5 for p in (pa, pb))  # pixel centres stay at integers
    return a, b, pa, pb


# ----------------------------------------------------------------------------------------------- maps


@dataclass
class FoldStats:
    """Jacobian determinants ``<= 0`` of a stack of backward maps ``(N, H, W, 2)``."""

    fraction: float  # over all pixels of all frames
    fraction_inside: float  # over the pixels whose map source lies inside the source image
    worst_frame_fraction: float
    worst_frame: int
    frames_with_folds: int
    min_det: float


def fold_stats(maps: Tensor) -> FoldStats:
    H, W = maps.shape[1:3]
    det = jacobian_determinant(maps)  # (N, H, W)
    folded = det <= 0
    x, y = maps[..., 0], maps[..., 1]
    inside = (x >= -0.5) & (x <= W - 0.5) & (y >= -0.5) & (y <= H - 0.5)
    per_frame = folded.flatten(1).double().mean(1)
    return FoldStats(
        fraction=float(folded.double().mean()),
        fraction_inside=float((folded & inside).sum() / inside.sum().clamp(min=1)),
        worst_frame_fraction=float(per_frame.max()),
        worst_frame=int(per_frame.argmax()),
        frames_with_folds=int((per_frame > 0).sum()),
        min_det=float(det.min()),
    )


INVERT_OK_PX = LOCATE_TOLERANCE  # a landmark is located when the map at the found point is this close to it


@dataclass
class Landmarks:
    """Where the landmarks are at the middle and last frames, located in the frames through the maps.

    Means and maxima are over the landmarks that Newton's method located (map residual <= ``INVERT_OK_PX``
    source pixels); a landmark carried out of the frame, for instance, cannot be located there.
    """

    mid_frame: int
    mid_u: float  # the frame's position in the morph, k / (N - 1)
    mid_located: int  # landmarks of A located in the middle frame (of M)
    mid_misalign_b_px: float  # mean |maps_b[mid](y_i) - b_i|, B's pixels
    mid_misalign_b_px_max: float
    ghost_located: int  # landmarks of both A and B located in the middle frame
    mid_ghost_px: float  # mean |y_i - z_i|, frame pixels
    end_located: int
    end_error_px: float  # mean distance of A's landmarks, as the last frame's map shows them, to B's points
    end_error_px_max: float
    traj_gap_mid_px: float | None = None  # fluid only: mean |y_i - trajectory_i(s_mid)| (linear in time)
    traj_gap_end_px: float | None = None  # fluid only: mean |y_i - trajectory_i(T)| at the last frame
    traj_gap_end_px_max: float | None = None
    exact_end_px: float | None = None  # TPS only: max |T_A,last(b_i) - a_i|, the spline evaluated at B's points


def _masked(values: Tensor, ok: Tensor) -> tuple[float, float]:
    if not bool(ok.any()):
        return float("nan"), float("nan")
    return float(values[ok].mean()), float(values[ok].max())


def landmarks(
    maps: Tensor, maps_b: Tensor, pa: Tensor, pb: Tensor, init_mid: Tensor, init_end: Tensor, mid: int
) -> tuple[Landmarks, tuple[Tensor, Tensor], tuple[Tensor, Tensor]]:
    """The middle-frame misalignment and the last-frame error of a morph, from its maps ``(N, H, W, 2)``.

    Also returns where A's landmarks appear in the middle and in the last frame, each as ``(M, 2)`` points and
    an ``(M,)`` mask of those located.
    """
    pa, pb = pa.double(), pb.double()
    n = maps.shape[0]
    y, ry = invert_map_at(maps[mid : mid + 1], pa, init_mid)  # where A's landmarks appear in the middle frame
    z, rz = invert_map_at(maps_b[mid : mid + 1], pb, y)  # where B's landmarks appear in it
    ok_y, ok_z = ry <= INVERT_OK_PX, rz <= INVERT_OK_PX
    gap_b = (read_map(maps_b[mid : mid + 1], y) - pb).norm(dim=-1)
    y_end, r_end = invert_map_at(maps[n - 1 :], pa, init_end)
    ok_end = r_end <= INVERT_OK_PX
    mis, mis_max = _masked(gap_b, ok_y)
    ghost, _ = _masked((y - z).norm(dim=-1), ok_y & ok_z)
    end, end_max = _masked((y_end - pb).norm(dim=-1), ok_end)
    marks = Landmarks(
        mid_frame=mid,
        mid_u=mid / (n - 1),
        mid_located=int(ok_y.sum()),
        mid_misalign_b_px=mis,
        mid_misalign_b_px_max=mis_max,
        ghost_located=int((ok_y & ok_z).sum()),
        mid_ghost_px=ghost,
        end_located=int(ok_end.sum()),
        end_error_px=end,
        end_error_px_max=end_max,
    )
    return marks, (y, ok_y), (y_end, ok_end)


# ----------------------------------------------------------------------------------------------- fluid


@dataclass
class FluidRow:
    """One fluid configuration."""

    inverse: str
    method: str
    fit_error_px: float  # fit.error.mean()
    fit_error_px_max: float
    fit_evaluations: int
    fit_message: str
    folds_a: FoldStats
    folds_b: FoldStats
    marks: Landmarks
    seconds: dict[str, float] = field(default_factory=dict)  # medians: wall, fit, inverse, render, total
    seconds_all: dict[str, list[float]] = field(default_factory=dict)
    fit_ms_per_evaluation: float = 0.0
    peak_rss_growth_mib: float = 0.0
    deterministic: bool = True  # every repeat gave the same end error


def trajectory_at(traj: Tensor, s: float) -> Tensor:
    """Trajectories ``(1, T + 1, M, 2)`` at fluid time ``s`` (steps), linear between steps: ``(M, 2)``."""
    T = traj.shape[1] - 1
    lo = min(int(s), T - 1)
    w = s - lo
    return ((1 - w) * traj[0, lo] + w * traj[0, lo + 1]).double()


def fluid_row(res: MorphResult, inverse: str, method: str, pa: Tensor, pb: Tensor) -> FluidRow:
    n = res.frames.shape[0]
    mid = n // 2
    traj = res.fit.trajectories  # (1, T + 1, M, 2), frame pixels
    init_mid = trajectory_at(traj, float(res.times[mid]))
    end = traj[0, -1].double()
    marks, (y_mid, ok_mid), (y_end, ok_end) = landmarks(res.maps, res.maps_b, pa, pb, init_mid, end, mid)
    marks.traj_gap_mid_px, _ = _masked((y_mid - init_mid).norm(dim=-1), ok_mid)
    marks.traj_gap_end_px, marks.traj_gap_end_px_max = _masked((y_end - end).norm(dim=-1), ok_end)
    return FluidRow(
        inverse=inverse,
        method=method,
        fit_error_px=float(res.fit.error.mean()),
        fit_error_px_max=float(res.fit.error.max()),
        fit_evaluations=res.fit.evaluations,
        fit_message=res.fit.message,
        folds_a=fold_stats(res.maps),
        folds_b=fold_stats(res.maps_b),
        marks=marks,
    )


def run_fluid(
    a: Tensor, b: Tensor, pa: Tensor, pb: Tensor, inverse: str, method: str, frames: int, max_iter: int | None
) -> tuple[MorphResult, float]:
    t0 = time.perf_counter()
    res = morph(
        a,
        b,
        pa,
        pb,
        frames=frames,
        inverse=inverse,
        method=method,  # type: ignore[arg-type]
        max_iter=max_iter,
        progress=False,
    )
    return res, time.perf_counter() - t0


def graph_probe(a: Tensor, b: Tensor, pa: Tensor, pb: Tensor) -> dict[str, bool]:
    """Whether a plain ``morph`` call (grad mode on, as a user calls it) returns tensors that carry a graph."""
    small = 64
    s = small / a.shape[-1]
    a2, b2 = (
        F.interpolate(x, size=(small, small), mode="bilinear", align_corners=False, antialias=True) for x in (a, b)
    )
    res = morph(a2, b2, (pa + 0.5) * s - 0.5, (pb + 0.5) * s - 0.5, frames=2, max_iter=1, progress=False)
    return {"frames": res.frames.requires_grad, "maps": res.maps.requires_grad, "maps_b": res.maps_b.requires_grad}


# ----------------------------------------------------------------------------------------------- TPS

TpsKind = Literal["kornia", "standard"]
TPS_KINDS: tuple[TpsKind, ...] = ("kornia", "standard")


def to_norm(points: Tensor, size: tuple[int, int]) -> Tensor:
    """Pixels (centres at integers) to kornia's normalised ``align_corners=False`` frame: ``(2x + 1) / W - 1``."""
    H, W = size
    scale = torch.tensor([2.0 / W, 2.0 / H], dtype=points.dtype)
    return points * scale + scale / 2 - 1


def from_norm(points: Tensor, size: tuple[int, int]) -> Tensor:
    H, W = size
    scale = torch.tensor([W / 2.0, H / 2.0], dtype=points.dtype)
    return (points + 1) * scale - 0.5


def standard_tps(dst: Tensor, src: Tensor) -> tuple[Tensor, Tensor]:
    """Textbook TPS weights for ``f(y) = a_0 + A y + sum_j w_j U(|y - dst_j|)`` with ``f(dst_i) = src_i``.

    ``U(r) = r^2 log r``; the symmetric system ``[K P; P^T 0] [w; a] = [src; 0]`` with ``K_ij = U(|dst_i - dst_j|)``
    is solved in float64. Same layout as kornia's weights ``(1, M, 2)`` and ``(1, 3, 2)``, with the kernel
    centres at ``dst``, so kornia's ``warp_points_tps``/``warp_image_tps`` evaluate it unchanged.
    """
    d, s = dst.double(), src.double()
    m = d.shape[1]
    r2 = (d[:, :, None] - d[:, None]).pow(2).sum(-1)  # (1, M, M)
    k = torch.where(r2 > 0, 0.5 * r2 * r2.clamp(min=1e-300).log(), torch.zeros_like(r2))
    p = torch.cat([torch.ones_like(d[..., :1]), d], dim=-1)  # (1, M, 3)
    lhs = torch.cat([torch.cat([k, p], -1), torch.cat([p.transpose(1, 2), d.new_zeros(1, 3, 3)], -1)], 1)
    w = torch.linalg.solve(lhs, torch.cat([s, d.new_zeros(1, 3, 2)], 1))
    return w[:, :m].to(dst.dtype), w[:, m:].to(dst.dtype)


def tps_spline(kind: TpsKind, dst: Tensor, src: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Kernel centres, kernel weights and affine weights of a backward TPS map from ``dst`` to ``src`` (normalised).

    ``"kornia"`` is kornia's documented composition for ``warp_image_tps``: ``get_tps_transform(dst, src)`` with
    the kernel centres at ``src``; ``"standard"`` is :func:`standard_tps`, centres at ``dst``.
    """
    if kind == "kornia":
        kw, aw = get_tps_transform(dst, src)
        return src, kw, aw
    kw, aw = standard_tps(dst, src)
    return dst, kw, aw


def tps_morph(kind: TpsKind, a: Tensor, b: Tensor, pa: Tensor, pb: Tensor, frames: int) -> Tensor:
    """The TPS morph ``(N, C, H, W)``: the timed path; kornia renders every frame."""
    size = (a.shape[-2], a.shape[-1])
    na, nb = to_norm(pa, size)[None], to_norm(pb, size)[None]  # (1, M, 2)
    out = []
    for k in range(frames):
        u = k / (frames - 1)
        nk = (1 - u) * na + u * nb
        fa = warp_image_tps(a, *tps_spline(kind, nk, na), align_corners=False, padding_mode="border")
        fb = warp_image_tps(b, *tps_spline(kind, nk, nb), align_corners=False, padding_mode="border")
        out.append(torch.lerp(fa, fb, u))
    res = torch.cat(out)
    res[0], res[-1] = a[0], b[0]  # as the fluid morph does: the endpoints are the inputs
    return res


def tps_maps(kind: TpsKind, pa: Tensor, pb: Tensor, size: tuple[int, int], frames: int) -> tuple[Tensor, Tensor, float]:
    """The TPS morph's backward maps of A and B ``(N, H, W, 2)`` in pixels, and ``max |T_A,last(b) - a|`` px."""
    H, W = size
    na, nb = to_norm(pa, size)[None], to_norm(pb, size)[None]
    grid = to_norm(identity_map(size).reshape(1, -1, 2), size)  # (1, H*W, 2): what warp_image_tps evaluates
    maps_a, maps_b = [], []
    exact = float("nan")
    for k in range(frames):
        u = k / (frames - 1)
        nk = (1 - u) * na + u * nb
        spline_a, spline_b = tps_spline(kind, nk, na), tps_spline(kind, nk, nb)
        maps_a.append(from_norm(warp_points_tps(grid, *spline_a), size).view(1, H, W, 2))
        maps_b.append(from_norm(warp_points_tps(grid, *spline_b), size).view(1, H, W, 2))
        if k == frames - 1:
            at_b = from_norm(warp_points_tps(nk, *spline_a), size)[0]
            exact = float((at_b.double() - pa.double()).norm(dim=-1).max())
    return torch.cat(maps_a), torch.cat(maps_b), exact


@dataclass
class TpsRow:
    """One TPS variant."""

    kind: str
    folds_a: FoldStats
    folds_b: FoldStats
    marks: Landmarks
    map_check: float  # max |frame re-rendered through the maps - warp_image_tps frame| at the middle frame
    seconds: float = 0.0  # median
    seconds_all: list[float] = field(default_factory=list)
    peak_rss_growth_mib: float = 0.0


def tps_row(kind: TpsKind, a: Tensor, b: Tensor, pa: Tensor, pb: Tensor, frames: int, res_frames: Tensor) -> TpsRow:
    size = (a.shape[-2], a.shape[-1])
    maps_a, maps_b, exact = tps_maps(kind, pa, pb, size, frames)
    mid = frames // 2
    u = mid / (frames - 1)
    pk = (1 - u) * pa.double() + u * pb.double()
    marks, _, _ = landmarks(maps_a, maps_b, pa, pb, pk, pb.double(), mid)
    marks.exact_end_px = exact
    # the maps are what warp_image_tps samples through: re-render the middle frame from them
    again = torch.lerp(warp_image(a, maps_a[mid : mid + 1]), warp_image(b, maps_b[mid : mid + 1]), u)
    check = float((again - res_frames[mid : mid + 1]).abs().max())
    return TpsRow(kind=kind, folds_a=fold_stats(maps_a), folds_b=fold_stats(maps_b), marks=marks, map_check=check)


# ----------------------------------------------------------------------------------------------- helpers


def peak_baseline() -> float:
    """Reset ``VmHWM`` to the current RSS (Linux); return the RSS in KiB (0 where unsupported)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return status_kib("VmRSS")
    except (OSError, StopIteration):
        return 0.0


def peak_growth_mib(base_kib: float) -> float:
    try:
        return (status_kib("VmHWM") - base_kib) / 1024 if base_kib else float("nan")
    except (OSError, StopIteration):
        return float("nan")


def sources_digest() -> str:
    """A short digest of the installed package's Python sources, to tell which state of the library ran."""
    digest = hashlib.sha256()
    for path in sorted(Path(torchfluidwarp.__file__).parent.rglob("*.py")):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def machine() -> dict[str, Any]:
    """What the figures were measured on, with the versions this comparison depends on."""
    import kornia

    return {
        **common_machine(),
        "kornia": kornia.__version__,
        "torchfluidwarp": torchfluidwarp.__version__,
        "torchfluidwarp_sources_sha256": sources_digest(),
    }


def pct(x: float) -> str:
    return f"{100 * x:.3f}%"


def label(inverse: str, method: str) -> str:
    return f"fluid {method}, inverse {inverse}"


# ----------------------------------------------------------------------------------------------- report


def tps_label(kind: str) -> str:
    return {"kornia": "TPS kornia", "standard": "TPS standard"}[kind]


def report(
    fluid: list[FluidRow], tps: list[TpsRow], frames: int, size: int, n_points: int, probe: dict[str, bool]
) -> tuple[str, dict[str, Any]]:
    M = f"/{n_points}"
    mid = fluid[0].marks
    out = [
        f"Landmarks ({size}x{size}, {frames} frames; px = pixels of B (= of the last frame); mid = frame "
        f"{mid.mid_frame}, u = {mid.mid_u:.3f}; 'loc' = landmarks located in the frame through its map)"
    ]
    rows = []
    for r in fluid:
        m = r.marks
        rows.append(
            [
                label(r.inverse, r.method),
                f"{r.fit_error_px:.2f}",
                f"{r.fit_error_px_max:.2f}",
                f"{m.end_error_px:.2f}",
                f"{m.end_error_px_max:.2f}",
                f"{m.end_located}{M}",
                f"{m.traj_gap_end_px:.2f}",
                f"{m.traj_gap_end_px_max:.2f}",
                f"{m.mid_misalign_b_px:.2f}",
                f"{m.mid_misalign_b_px_max:.2f}",
                f"{m.mid_located}{M}",
                f"{m.mid_ghost_px:.2f}",
                f"{m.ghost_located}{M}",
            ]
        )
    for t in tps:
        m = t.marks
        rows.append(
            [
                tps_label(t.kind),
                "-",
                "-",
                f"{m.end_error_px:.2f}",
                f"{m.end_error_px_max:.2f}",
                f"{m.end_located}{M}",
                "-",
                "-",
                f"{m.mid_misalign_b_px:.2f}",
                f"{m.mid_misalign_b_px_max:.2f}",
                f"{m.mid_located}{M}",
                f"{m.mid_ghost_px:.2f}",
                f"{m.ghost_located}{M}",
            ]
        )
    out.append(
        table(
            [
                "method",
                "fit.error",
                "max",
                "end (map)",
                "max",
                "loc",
                "traj gap",
                "max",
                "mid B-px",
                "max",
                "loc",
                "mid ghost",
                "loc",
            ],
            rows,
        )
    )
    out.append(
        "fit.error = fit.error (A's points advected to the last frame vs B's); end (map) = where the last "
        "frame's map shows A's landmarks vs B's points; traj gap = end (map) position vs advected point; "
        "mid B-px = |maps_b[mid](y) - b| at A's landmark y in the middle frame; mid ghost = |y - z|, z = "
        "B's landmark in the middle frame (frame px)"
    )
    for t in tps:
        out.append(
            f"{tps_label(t.kind)}: spline at B's points vs A's points (exact by construction) max "
            f"{t.marks.exact_end_px:.2e} px; middle frame re-rendered from the maps vs warp_image_tps: max "
            f"|diff| {t.map_check:.1e}"
        )

    out.append(
        "\nFolds: Jacobian determinant <= 0 of the backward maps, over all frames (inside = only pixels "
        "whose map source lies inside the source image)"
    )
    rows = []
    for name, fa, fb in [(label(r.inverse, r.method), r.folds_a, r.folds_b) for r in fluid] + [
        (tps_label(t.kind), t.folds_a, t.folds_b) for t in tps
    ]:
        rows.append(
            [
                name,
                pct(fa.fraction),
                pct(fa.fraction_inside),
                f"{fa.frames_with_folds}/{frames}",
                f"{pct(fa.worst_frame_fraction)} @{fa.worst_frame}",
                f"{fa.min_det:.3g}",
                pct(fb.fraction),
                pct(fb.fraction_inside),
                f"{fb.frames_with_folds}/{frames}",
                f"{fb.min_det:.3g}",
            ]
        )
    out.append(
        table(
            [
                "method",
                "A folded",
                "A inside",
                "A frames",
                "A worst frame",
                "A min det",
                "B folded",
                "B inside",
                "B frames",
                "B min det",
            ],
            rows,
        )
    )

    out.append("\nTime of a whole morph (median s over the repeats; the fluid's split as result.seconds reports it)")
    rows = []
    for r in fluid:
        s = r.seconds
        rows.append(
            [
                label(r.inverse, r.method),
                f"{s['wall']:.2f}",
                f"{s['fit']:.2f}",
                f"{s['inverse']:.2f}",
                f"{s['render']:.2f}",
                str(r.fit_evaluations),
                f"{r.fit_ms_per_evaluation:.0f}",
                f"{r.peak_rss_growth_mib:.0f}",
                " ".join(f"{x:.1f}" for x in r.seconds_all["wall"]),
            ]
        )
    for t in tps:
        rows.append(
            [
                tps_label(t.kind),
                f"{t.seconds:.2f}",
                "-",
                "-",
                f"{t.seconds:.2f}",
                "-",
                "-",
                f"{t.peak_rss_growth_mib:.0f}",
                " ".join(f"{x:.2f}" for x in t.seconds_all),
            ]
        )
    out.append(
        table(
            [
                "method",
                "total s",
                "fit s",
                "inverse s",
                "render s",
                "fit evals",
                "ms/eval",
                "peak RSS +MiB",
                "repeats s",
            ],
            rows,
        )
    )
    base_row = fluid[0]
    base = base_row.seconds["wall"]
    out.append(
        f"ratios to '{label(base_row.inverse, base_row.method)}': "
        + ", ".join(
            [f"{label(r.inverse, r.method)} {r.seconds['wall'] / base:.2f}x" for r in fluid[1:]]
            + [f"{tps_label(t.kind)} {t.seconds / base:.3f}x" for t in tps]
        )
    )
    for r in fluid:
        out.append(
            f"  {label(r.inverse, r.method)}: {r.fit_message}" + ("" if r.deterministic else " [repeats differed]")
        )
    out.append(f"plain morph() call (grad mode on) returns tensors with requires_grad: {probe}")

    targets: dict[str, Any] = {}
    out.append("")
    for r in fluid:
        if r.inverse != "flow":
            continue
        # the target is for 30 frames at 512 x 512; a smoke run is not judged against it
        judged = (frames, size) == (TIME_TARGET_FRAMES, TIME_TARGET_SIZE)
        met = r.seconds["wall"] < TIME_TARGET_S if judged else None
        targets[f"time_{r.inverse}_{r.method}"] = {"seconds": r.seconds["wall"], "met": met}
        out.append(
            f"{label(r.inverse, r.method)}: {frames}-frame {size}x{size} morph {r.seconds['wall']:.1f} s "
            f"(target: < {TIME_TARGET_S:g} s for {TIME_TARGET_FRAMES} frames at {TIME_TARGET_SIZE}x{TIME_TARGET_SIZE})"
            f" -> {verdict(met) if met is not None else 'not judged (other size)'}"
        )
    for r in fluid:
        met = r.folds_a.fraction == 0
        targets[f"folds_{r.inverse}_{r.method}"] = {
            "fraction": r.folds_a.fraction,
            "fraction_inside": r.folds_a.fraction_inside,
            "met": met,
        }
        out.append(
            f"{label(r.inverse, r.method)}: folded fraction of A's maps {pct(r.folds_a.fraction)}, "
            f"inside A's image {pct(r.folds_a.fraction_inside)} (target: 0) -> {verdict(met)}"
        )
    for t in tps:
        folds = t.folds_a.fraction > 0 or t.folds_b.fraction > 0
        targets[f"tps_folds_{t.kind}"] = {
            "fraction_a": t.folds_a.fraction,
            "fraction_b": t.folds_b.fraction,
            "folds": folds,
        }
        out.append(
            f"{tps_label(t.kind)}: folded fraction A {pct(t.folds_a.fraction)}, B {pct(t.folds_b.fraction)} "
            f"(expected: folds on large motions) -> {'folds seen' if folds else 'no folds seen'}"
        )
    return "\n".join(out), targets


# ----------------------------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--quick", action="store_true", help="smoke mode: the pair at 128x128, 6 frames, 15 fit iterations, 1 repeat"
    )
    parser.add_argument(
        "--pair",
        choices=sorted(PAIRS),
        default="bundled",
        help="the bundled astronaut -> cat pair (default) or two real human faces (see face_pair.py)",
    )
    parser.add_argument("--json", metavar="PATH", help="also write the results as JSON to PATH")
    parser.add_argument("--images", metavar="DIR", help="write the middle frames as PNGs into DIR")
    parser.add_argument("--repeats", type=int, default=None, help="timing repeats (default 3; 1 with --quick)")
    parser.add_argument("--frames", type=int, default=None, help="frames per morph (default 30; 6 with --quick)")
    parser.add_argument(
        "--max-iter",
        type=int,
        default=None,
        help="L-BFGS iterations of each fit (default: morph's, per method; 15 with --quick)",
    )
    add_threads_argument(parser)
    args = parser.parse_args(argv)
    size, frames, repeats, max_iter = (128, 6, 1, 15) if args.quick else (None, 30, 3, None)  # None: morph's
    max_iter = args.max_iter if args.max_iter is not None else max_iter
    frames = args.frames if args.frames is not None else frames
    repeats = args.repeats if args.repeats is not None else repeats
    checks = [
        ("--repeats", repeats, 1),
        ("--frames", frames, 3),
        ("--threads", args.threads, 1),
        ("--max-iter", max_iter, 1),
    ]
    for name, value, low in checks:
        if value is not None and value < low:
            parser.error(f"{name} must be >= {low}, got {value}")

    torch.set_num_threads(args.threads)
    a, b, pa, pb = load_pair(size, args.pair)
    size = a.shape[-1]
    info = machine()
    load_before = os.getloadavg()
    print(
        f"bench_morph: {info['cpu']}, {info['cpu_count']} CPUs, torch {info['torch']} with "
        f"{info['torch_threads']} thread(s), kornia {info['kornia']}, Python {info['python']}, {info['date']}"
        + (" [--quick]" if args.quick else ""),
        flush=True,
    )
    print(
        f"pair: {PAIRS[args.pair]}, {size}x{size}, {pa.shape[0]} points; {frames} frames, "
        f"{repeats} repeat(s); load average before: {' '.join(f'{x:.2f}' for x in load_before)}; "
        f"torchfluidwarp {info['torchfluidwarp']} sources {info['torchfluidwarp_sources_sha256']}",
        flush=True,
    )
    log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731

    prefix = "morph" if args.pair == "bundled" else f"morph_{args.pair}"
    t_start = time.perf_counter()
    probe = graph_probe(a, b, pa, pb)
    for kind in TPS_KINDS:
        tps_morph(kind, a, b, pa, pb, 3)  # warm-up
    times: dict[Any, dict[str, list[float]]] = {cfg: {} for cfg in FLUID_CONFIGS}
    tps_times: dict[str, list[float]] = {kind: [] for kind in TPS_KINDS}
    rows: dict[Any, FluidRow] = {}
    tps_rows: dict[str, TpsRow] = {}
    mids: dict[str, Tensor] = {}
    for rep in range(repeats):
        for inverse, method in FLUID_CONFIGS:
            log(f"  repeat {rep + 1}/{repeats}: {label(inverse, method)} ...")
            base = peak_baseline()
            res, wall = run_fluid(a, b, pa, pb, inverse, method, frames, max_iter)
            growth = peak_growth_mib(base)
            cfg = (inverse, method)
            for k, v in {"wall": wall, **res.seconds}.items():
                times[cfg].setdefault(k, []).append(v)
            if rep == 0:
                row = fluid_row(res, inverse, method, pa, pb)
                row.peak_rss_growth_mib = growth
                rows[cfg] = row
                if method == IMAGE_METHOD:
                    mids[f"{prefix}_mid_fluid_{inverse}.png"] = res.frames[frames // 2].clone()
            elif float(res.fit.error.mean()) != rows[cfg].fit_error_px:
                rows[cfg].deterministic = False
            del res
        for kind in TPS_KINDS:
            log(f"  repeat {rep + 1}/{repeats}: {tps_label(kind)} ...")
            base = peak_baseline()
            t0 = time.perf_counter()
            tps_frames = tps_morph(kind, a, b, pa, pb, frames)
            tps_times[kind].append(time.perf_counter() - t0)
            growth = peak_growth_mib(base)
            if rep == 0:
                tps_rows[kind] = tps_row(kind, a, b, pa, pb, frames, tps_frames)
                tps_rows[kind].peak_rss_growth_mib = growth
                if kind == "kornia":
                    mids[f"{prefix}_mid_tps.png"] = tps_frames[frames // 2].clone()
    tps = [tps_rows[kind] for kind in TPS_KINDS]
    for t in tps:
        t.seconds_all, t.seconds = tps_times[t.kind], statistics.median(tps_times[t.kind])
    fluid = []
    for cfg in FLUID_CONFIGS:
        row = rows[cfg]
        row.seconds_all = times[cfg]
        row.seconds = {k: statistics.median(v) for k, v in times[cfg].items()}
        row.fit_ms_per_evaluation = row.seconds["fit"] / max(row.fit_evaluations, 1) * 1e3
        fluid.append(row)

    text, targets = report(fluid, tps, frames, size, pa.shape[0], probe)
    print("\n" + text)
    load_after = os.getloadavg()
    total = time.perf_counter() - t_start
    print(f"\nload average after: {' '.join(f'{x:.2f}' for x in load_after)}; total {total:.0f} s")
    digest_after = sources_digest()
    if digest_after != info["torchfluidwarp_sources_sha256"]:
        print(
            f"WARNING: the package's sources changed during the run ({info['torchfluidwarp_sources_sha256']} -> "
            f"{digest_after}): the figures may mix two versions"
        )

    if args.images:
        folder = Path(args.images)
        folder.mkdir(parents=True, exist_ok=True)
        for name, image in mids.items():
            print(f"wrote {write_image(folder / name, image)}")
    if args.json:
        result = {
            "machine": info,
            "args": vars(args),
            "size": size,
            "frames": frames,
            "repeats": repeats,
            "max_iter": max_iter,
            "load_before": load_before,
            "load_after": load_after,
            "sources_sha256_after": digest_after,
            "graph_probe": probe,
            "fluid": [asdict(r) for r in fluid],
            "tps": [asdict(t) for t in tps],
            "targets": targets,
            "total_s": total,
        }
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
