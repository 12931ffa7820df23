"""Dense correspondence on the halfway domain: the pixels' help between the marks.

The natural morph's middle frame is the thin-plate-spline morph to the average shape: a point ``m`` of the middle
frame reads A at ``m - D(m) / 2`` and B at ``m + D(m) / 2``, with ``D`` the spline through the marks'
displacements at their midpoints. :func:`halfway_alignment` adds a residual ``R`` to ``D`` so that the two
pictures, both warped to the middle frame, agree where nobody marked them (Liao et al. 2014, "Automating Image
Morphing using Structural Similarity on a Halfway Domain"):

``E(R) = mean_valid(1 - ncc_w^2) + smoothness * mean |grad R|^2 + anchor * mean_i |R(m_i)|^2 / s^2 + fold(D + R)``

* ``ncc_w`` is the normalised cross-correlation over ``window x window`` pixels of each level's raster, squared so
  that a change of brightness, contrast or contrast sign between A and B does not matter; where a window is flat
  it is 0 and the term is constant there, so flat regions and regions without a counterpart (a hat against hair)
  pull nothing: the smoothness carries the marks' motion through them.
* the smoothness is in (canvas pixels / canvas pixel)^2 over the canvas, the same at every level;
* the anchor keeps the marks where they are (``s`` is the canvas's longer side / 100 pixels);
* ``fold`` penalises any point of the paths ``m + sigma (D + R)(m)``, ``sigma`` in ``[-1/2, 1/2]``, squeezing an
  area below :data:`MIN_AREA` of its size in the middle frame; a result that folds anyway is shrunk until it does
  not.

It is solved coarse to fine (rasters of ``levels`` pixels on the canvas's longer side), each level by L-BFGS,
starting from ``R = 0``, the landmark flow. The morph's forces carry ``D + R``
(:class:`~torchfluidwarp.warp.landmarks.LandmarkForces`); its fit keeps the marks on their paths.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from torchfluidwarp._checks import check_int, check_positive
from torchfluidwarp.control.alignment import apply_alignment
from torchfluidwarp.control.losses import local_ncc2
from torchfluidwarp.control.optim import minimize
from torchfluidwarp.core.grid import normalized_affine, pixel_to_normalized
from torchfluidwarp.core.sampling import sample
from torchfluidwarp.core.spline import tps_fit
from torchfluidwarp.errors import InputError

MIN_AREA = 0.2
"""The least area ratio the residual may leave anywhere on the paths (relative to the middle frame)."""

FOLD_WEIGHT = 100.0
"""The weight of the fold penalty ``mean(max(0, floor - least area)^2)``: far above the other terms, whose values
are at most about 1."""


@dataclass(frozen=True)
class HalfwaySettings:
    """How the pixels align what the marks leave open (:func:`halfway_alignment`).

    Attributes:
        levels: the rasters' longer sides, pixels, coarse to fine (at most the canvas's longer side is used).
        window: the correlation window, pixels of each level's raster (odd, >= 3).
        smoothness: the weight of ``mean |grad R|^2`` (canvas pixels per canvas pixel, squared) against the
            image term (dimensionless, in ``[0, 1]``).
        anchor: the weight keeping the marks' residual at 0, per (1 % of the canvas's longer side)^2. A morph
            whose points features or a flow placed (``morph(match=...)`` without face landmarks) sets it to 0:
            those points are the pixels' own guess, and the pixels' alignment may correct them.
        iterations: L-BFGS iterations per level.
        cell: the residual's control points' spacing, pixels of each level's raster (bicubic between them).
        reach: how far the marks hold their spline, as a fraction of their median nearest-neighbour distance:
            the anchor weighs ``|R|^2`` by a Gaussian of that width around each mark.
    """

    levels: tuple[int, ...] = (32, 64, 128, 256)
    window: int = 7
    smoothness: float = 0.3
    anchor: float = 1.0
    iterations: int = 40
    cell: int = 8
    reach: float = 0.5

    def __post_init__(self) -> None:
        levels = tuple(check_int("HalfwaySettings.levels", v, minimum=8) for v in self.levels)
        if not levels or list(levels) != sorted(levels):
            raise InputError(f"HalfwaySettings.levels must be increasing and not empty, got {self.levels!r}")
        object.__setattr__(self, "levels", levels)
        window = check_int("HalfwaySettings.window", self.window, minimum=3)
        if window % 2 == 0:
            raise InputError(f"HalfwaySettings.window must be odd, got {window}")
        check_positive("HalfwaySettings.smoothness", self.smoothness, allow_zero=True)
        check_positive("HalfwaySettings.anchor", self.anchor, allow_zero=True)
        check_int("HalfwaySettings.iterations", self.iterations, minimum=0)
        check_int("HalfwaySettings.cell", self.cell, minimum=1)
        check_positive("HalfwaySettings.reach", self.reach)


@dataclass
class HalfwayAlignment:
    """The result of :func:`halfway_alignment`, in canvas pixels.

    Attributes:
        residual: ``(1, 2, h, w)`` float64 ``R`` on the finest raster over the canvas (pixels): the middle frame's
            point ``m`` reads A at ``m - (D + R)(m) / 2`` and B at ``m + (D + R)(m) / 2``.
        size: the canvas ``(H, W)``.
        valid: ``(1, 1, h, w)`` where both pictures cover the middle frame (1) or neither (0).
        energy: the image term ``mean(1 - ncc^2)`` at the end of each level; ``start``: the same of the marks'
            spline alone on the finest raster.
    """

    residual: Tensor
    size: tuple[int, int]
    valid: Tensor
    energy: list[float]
    start: float

    def __call__(self, points: Tensor) -> Tensor:
        """``R`` at ``points`` ``(N, 2)`` canvas pixels (bilinear; held at the raster's edge beyond it), ``(N, 2)``."""
        g = pixel_to_normalized(points, self.size).view(1, 1, -1, 2).to(self.residual.dtype)
        out = sample(self.residual, g, align_corners=False, check=None)[0, :, 0].T
        return out.to(points.dtype)


def _raster(size: tuple[int, int], long: int, device: torch.device) -> tuple[tuple[int, int], Tensor]:
    """A raster with ``long`` pixels on the canvas ``size``'s longer side: its ``(h, w)`` and its pixel centres in
    canvas pixels ``(h, w, 2)`` float64."""
    H, W = size
    k = min(1.0, long / max(H, W))
    h, w = max(2, round(H * k)), max(2, round(W * k))
    ys = (torch.arange(h, dtype=torch.float64, device=device) + 0.5) * (H / h) - 0.5
    xs = (torch.arange(w, dtype=torch.float64, device=device) + 0.5) * (W / w) - 0.5
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    return (h, w), torch.stack([gx, gy], -1)


def _on_canvas(image: Tensor, from_canvas: Tensor, at: Tensor) -> Tensor:
    """``image`` ``(1, C, H_i, W_i)`` read at canvas points ``at`` ``(h, w, 2)`` through ``from_canvas`` ``(3, 3)``
    (canvas pixels to the picture's), as grey plus a coverage channel, ``(1, 2, h, w)`` float64. Where the raster
    is coarser than the picture, the picture is first shrunk (antialiased) until the raster's spacing is about a
    pixel of it: the cost and memory follow the raster, not the picture (a 6000-pixel photograph is read from a
    copy of a few hundred pixels)."""
    size = (image.shape[-2], image.shape[-1])
    grey = image[:, :3].mean(1, keepdim=True) if image.shape[1] in (3, 4) else image[:, :1]
    points = apply_alignment(from_canvas, at.reshape(-1, 2)).reshape(at.shape)
    spacing = float((points[1:, :] - points[:-1, :]).norm(dim=-1).mean()) if at.shape[0] > 1 else 1.0
    if spacing > 1.5:  # the same [-1, 1] coordinates read the shrunk copy at the same places
        small = (max(2, round(size[0] / spacing)), max(2, round(size[1] / spacing)))
        grey = F.interpolate(grey, size=small, mode="bilinear", antialias=True, align_corners=False)
    grey = grey.double()
    g = pixel_to_normalized(points, size).unsqueeze(0).to(grey.dtype)
    x, y = points[..., 0], points[..., 1]
    depth = torch.minimum(torch.minimum(x + 0.5, size[1] - 0.5 - x), torch.minimum(y + 0.5, size[0] - 0.5 - y))
    covered = (depth + 0.5).clamp(0, 1).to(grey.dtype)[None, None]  # 1 inside, 0 a pixel beyond the edge
    return torch.cat([sample(grey, g, align_corners=False, check=None), covered], 1)


def _near_marks(at: Tensor, mids: Tensor, reach: float, chunk: int = 4096) -> Tensor:
    """``(1, 1, h, w)`` in ``[0, 1]``: how close each raster point ``at`` ``(h, w, 2)`` is to a mark ``mids``
    ``(M, 2)``: ``max_i exp(-|p - m_i|^2 / (2 sigma^2))`` with ``sigma`` ``reach`` times the marks' median
    nearest-neighbour distance, so that the marks' own spline holds near them and the pixels decide farther away."""
    d = torch.cdist(mids, mids)
    d.fill_diagonal_(float("inf"))
    sigma = reach * float(d.min(1).values.median()) if mids.shape[0] > 1 else 1.0
    flat = at.reshape(-1, 2)
    out = torch.cat([torch.cdist(flat[i : i + chunk], mids).min(1).values for i in range(0, flat.shape[0], chunk)])
    return torch.exp(-out.square() / (2 * sigma**2)).view(1, 1, *at.shape[:2])


def least_area_ratio(jacobian: Tensor) -> Tensor:
    """``(...)``: the least of ``det(I + sigma J)`` over ``sigma`` in ``[-1/2, 1/2]``, for Jacobians ``J``
    ``(..., 2, 2)`` of a displacement (row ``i``: component ``i``, column ``j``: its derivative along ``x_j``,
    pixels per pixel), differentiable: how far the straight paths ``m + sigma D(m)`` squeeze an area, relative to
    its size at ``sigma = 0``."""
    a, b, c, d = jacobian[..., 0, 0], jacobian[..., 0, 1], jacobian[..., 1, 0], jacobian[..., 1, 1]
    trace, det = a + d, a * d - b * c
    # det(I + sigma J) = 1 + sigma trace + sigma^2 det: a parabola; its least value is at an end or its vertex
    ends = torch.minimum(1 + 0.5 * trace + 0.25 * det, 1 - 0.5 * trace + 0.25 * det)
    safe = torch.where(det > 0, det, torch.ones_like(det))
    inner = (det > 0) & ((trace / (2 * safe)).abs() < 0.5)
    return torch.where(inner, torch.minimum(ends, 1 - trace.square() / (4 * safe)), ends)


def least_area(field: Tensor, spacing: tuple[float, float]) -> Tensor:
    """``(B, h, w)``: :func:`least_area_ratio` of a displacement field ``(B, 2, h, w)`` (pixels, ``spacing`` =
    ``(dy, dx)`` pixels between raster points), its Jacobian by central differences, differentiable."""
    b, a = torch.gradient(field[:, 0], spacing=spacing, dim=(-2, -1))  # dux/dy, dux/dx
    d, c = torch.gradient(field[:, 1], spacing=spacing, dim=(-2, -1))  # duy/dy, duy/dx
    return least_area_ratio(torch.stack([torch.stack([a, b], -1), torch.stack([c, d], -1)], -2))


class _Level:
    """One level of the coarse-to-fine solve: the raster ``at`` ``(h, w, 2)`` over the canvas, the marks' travel
    ``D`` ``(1, 2, h, w)`` on it, both pictures on it (grey and coverage), and the energy of a control raster."""

    def __init__(self, pictures: tuple[Tensor, Tensor, Tensor, Tensor], size: tuple[int, int], long: int,
                 travel: Callable[[Tensor], Tensor], mids: Tensor, settings: HalfwaySettings) -> None:  # fmt: skip
        image_a, image_b, from_a, from_b = pictures
        (h, w), self.at = _raster(size, long, mids.device)
        self.size, self.shape, self.settings = size, (h, w), settings
        self.spacing = (size[0] / h, size[1] / w)
        self.unit = max(size) / 100.0
        self.D = travel(self.at.reshape(-1, 2)).reshape(h, w, 2).permute(2, 0, 1).unsqueeze(0)
        self.control = (max(2, round(h / settings.cell)), max(2, round(w / settings.cell)))
        self.ca = _on_canvas(image_a, from_a.double(), self.at)
        self.cb = _on_canvas(image_b, from_b.double(), self.at)
        self.near = _near_marks(self.at, mids, settings.reach).to(self.D.dtype)
        self.floor = min(MIN_AREA, float(least_area(self.D, self.spacing).min()))  # the marks' squeeze is theirs
        # the solve works in float32 (a raster of a few hundred pixels needs no more; float64 doubled its time)
        self.at, self.D, self.ca, self.cb, self.near = (
            t.float() for t in (self.at, self.D, self.ca, self.cb, self.near)
        )
        # canvas pixels to grid_sample's coordinates, applied fused at every evaluation of the energy
        self.scale, self.shift = normalized_affine(size, device=self.at.device, dtype=self.at.dtype)

    def up(self, control: Tensor) -> Tensor:
        """The residual ``(1, 2, h, w)`` of control values ``(1, 2, k_y, k_x)``: bicubic between them."""
        return F.interpolate(control, size=self.shape, mode="bicubic", align_corners=True)

    def image_term(self, field: Tensor) -> tuple[Tensor, Tensor]:
        """``mean_valid(1 - ncc^2)`` of the pictures read through the travel ``field``, and the valid mask."""
        half = field.permute(0, 2, 3, 1)[0] / 2  # (h, w, 2)
        ga = torch.addcmul(self.shift, self.at - half, self.scale).unsqueeze(0)
        gb = torch.addcmul(self.shift, self.at + half, self.scale).unsqueeze(0)
        wa = sample(self.ca, ga, align_corners=False, check=None)  # finite: the travel is a spline plus R
        wb = sample(self.cb, gb, align_corners=False, check=None)
        valid = (wa[:, 1:] * wb[:, 1:]).detach()
        cost = (1 - local_ncc2(wa[:, :1], wb[:, :1], self.settings.window)) * valid
        return cost.sum() / valid.sum().clamp(min=1), valid

    def energy(self, control: Tensor) -> Tensor:
        """The module's ``E(R)`` of the residual of ``control``."""
        r = self.up(control)
        total = self.D + r
        dy, dx = self.spacing
        smooth = ((r[..., :, 1:] - r[..., :, :-1]) / dx).square().mean() + (
            (r[..., 1:, :] - r[..., :-1, :]) / dy
        ).square().mean()
        anchor = (self.near * r.square().sum(1, keepdim=True)).mean() / self.unit**2
        fold = (self.floor - least_area(total, self.spacing)).clamp(min=0).square().mean()
        s = self.settings
        return self.image_term(total)[0] + s.smoothness * smooth + s.anchor * anchor + FOLD_WEIGHT * fold


def halfway_alignment(
    image_a: Tensor,
    image_b: Tensor,
    from_canvas_a: Tensor,
    from_canvas_b: Tensor,
    size: tuple[int, int],
    midpoints: Tensor,
    displacements: Tensor,
    settings: HalfwaySettings = HalfwaySettings(),
) -> HalfwayAlignment:
    """Align two pictures on the halfway domain of their marks' spline (see the module's docstring).

    Args:
        image_a: ``(1, C, H_a, W_a)`` picture A in ``[0, 1]`` (grey, grey + alpha, RGB or RGBA).
        image_b: ``(1, C_b, H_b, W_b)`` picture B.
        from_canvas_a: ``(3, 3)`` canvas pixels to A's pixels.
        from_canvas_b: ``(3, 3)`` canvas pixels to B's pixels (B's placement and the pre-alignment undone).
        size: the canvas ``(H, W)``, pixels.
        midpoints: ``(M, 2)`` the marks' midpoints, canvas pixels.
        displacements: ``(M, 2)`` the marks' travel from A's side to B's, canvas pixels.
        settings: the levels, window and weights.

    Returns:
        a :class:`HalfwayAlignment`: the residual ``R`` on the finest raster, callable at any canvas points.

    Cost: about 1-3 s on a 2-core CPU for a 512-pixel canvas with the default levels (L-BFGS on a raster of up to
    256 pixels a side); memory a few dozen rasters of the finest level.
    """
    mids = midpoints.double()
    travel = tps_fit(mids, displacements.double())
    pictures = (image_a, image_b, from_canvas_a, from_canvas_b)
    control: Tensor | None = None
    energy: list[float] = []
    longs = sorted({min(long, max(size)) for long in settings.levels})  # a small canvas: fewer levels
    for long in longs:
        level = _Level(pictures, size, long, travel, mids, settings)
        if control is None:
            control = level.D.new_zeros(1, 2, *level.control)
        else:  # the previous level's control values, on this level's finer control raster
            control = F.interpolate(control.detach(), size=level.control, mode="bilinear", align_corners=True)
        control.requires_grad_(True)
        if settings.iterations:
            minimize(lambda: level.energy(control), [control], max_iter=settings.iterations, history_size=10)  # noqa: B023
        with torch.no_grad():
            energy.append(float(level.image_term(level.D + level.up(control))[0]))
    assert control is not None
    with torch.no_grad():
        start = float(level.image_term(level.D)[0])
        R = level.up(control.detach()).double()
        # what folds anyway is shrunk until it does not: the residual scaled by the largest of 1, 1/2, 1/4 ...
        for _ in range(8):
            if float(least_area(level.D.double() + R, level.spacing).min()) >= level.floor - 1e-6:
                break
            R = R / 2
        valid = level.image_term(level.D + R.float())[1].double()
    return HalfwayAlignment(R, size, valid, energy, start)
