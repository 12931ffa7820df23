"""A morph's settings, typed: one frozen dataclass per method, and small ones for the timing, the blending and the
point matching.

* :class:`NaturalSettings` (``method="natural"``, the default) and :class:`PaperSettings` (``method="paper"``):
  the fluid, the fit, the pre-alignment and how image B is pulled back. Each field has one meaning and one unit;
  the defaults differ by method and live on the classes.
* :class:`Timing`: how the shape and the colour progress over the morph's time ``t`` in ``[0, 1]``.
* :class:`Blending`: how each frame puts the two warped images together: the hand-over at an image's edge, and an
  optional region with a background.
* :class:`Matching`: how the points are found when none are given.

Every field is checked when the object is built; an error names the class, the field and the value received.

Example:
    >>> PaperSettings(grid=32, smoothness=2.0).method
    'paper'
    >>> NaturalSettings(steps=0)
    Traceback (most recent call last):
    ...
    torchfluidwarp.errors.InputError: NaturalSettings.steps must be >= 1, got 0
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import ClassVar, Literal

from torch import Tensor, nn

from torchfluidwarp._checks import (
    check_fraction,
    check_instance,
    check_int,
    check_positive,
    check_size,
    describe,
)
from torchfluidwarp.control.alignment import AlignKind
from torchfluidwarp.core.grid import FluidGrid, SquareCells
from torchfluidwarp.correspond import HalfwaySettings, MatchMode
from torchfluidwarp.correspond.auto import MATCH_MODES
from torchfluidwarp.errors import InputError, InputTypeError
from torchfluidwarp.morph.regions import Background
from torchfluidwarp.morph.timing import Schedule, schedule

__all__ = [
    "Method",
    "InverseMethod",
    "NaturalSettings",
    "PaperSettings",
    "MorphSettings",
    "METHODS",
    "Timing",
    "Blending",
    "Matching",
    "FEATHER",
    "MAX_MARGIN",
]

Method = Literal["natural", "paper"]
InverseMethod = Literal["flow", "paper"]

FEATHER = 64.0
"""Output pixels: the cross-dissolve hands a frame over to the other image within this distance inside an
image's edge (:class:`Blending`), so neither image's edge, nor the edge pixels that sampling smears beyond it,
shows as a line. At most: the band is narrower where the picture is drawn small or its edge only just enters the
canvas, and an edge on the canvas's border has none (:mod:`~torchfluidwarp.morph.render`)."""

MAX_MARGIN = 10.0
"""The largest :attr:`PaperSettings.margin`: a box ten times the points' extent on each side already holds a fluid
21 times wider than the points."""


def _choice(name: str, value: object, options: tuple[object, ...]) -> None:
    if not any(value is option or (isinstance(value, str) and value == option) for option in options):
        names = [repr(option) for option in options]
        listed = f"{', '.join(names[:-1])} or {names[-1]}"
        raise InputError(f"{name} must be {listed}, got {value!r}")


def _set(obj: object, name: str, value: object) -> None:
    """Store a field's normalised value on a frozen dataclass (only from ``__post_init__``)."""
    object.__setattr__(obj, name, value)


def _check_flow(obj: NaturalSettings | PaperSettings) -> None:
    """The fields both methods share: the fluid, the fit's stopping rules, the pre-alignment, the inverse."""
    cls = type(obj).__name__
    if not isinstance(obj.grid, (FluidGrid, SquareCells)):
        _set(obj, "grid", FluidGrid(*check_size(f"{cls}.grid", obj.grid, minimum=2)))
    check_int(f"{cls}.steps", obj.steps)
    if isinstance(obj.viscosity, (int, float)):
        _set(obj, "viscosity", check_positive(f"{cls}.viscosity", obj.viscosity, allow_zero=True))
    else:
        check_instance(f"{cls}.viscosity", obj.viscosity, (float, Tensor, nn.Module))
    keep = check_fraction(f"{cls}.compressible", obj.compressible)
    _set(obj, "compressible", obj.compressible if isinstance(obj.compressible, bool) else keep)
    check_int(f"{cls}.max_iter", obj.max_iter)
    _set(obj, "tolerance", check_positive(f"{cls}.tolerance", obj.tolerance, allow_zero=True))
    _choice(f"{cls}.align", obj.align, ("similarity", "affine", "none", None))
    _choice(f"{cls}.inverse", obj.inverse, ("flow", "paper"))


@dataclass(frozen=True)
class NaturalSettings:
    """The natural morph (the default): straight paths at constant speed, the rest of the picture as a thin-plate
    spline between the points says, in a compressible, inviscid fluid over the whole picture.

    Each marked point travels on a straight line at constant speed. The fluid covers the picture and a margin of
    :data:`~torchfluidwarp.morph.fit.PAD` around it, or more (its walls lie outside the picture), or, where the
    last frame shows under half of A (a small face zoomed into a large one), that part of A and its margin
    (:func:`~torchfluidwarp.morph.fit.focus`: ``grid`` then spans the part, whose cells shrink by the zoom, and the
    rest of A moves by the pre-alignment alone); one kick at step 0
    (:class:`~torchfluidwarp.warp.landmarks.LandmarkForces`) sets it moving, after which every particle coasts on
    a straight line (Burgers' equation), and ``max_iter`` L-BFGS iterations correct the kicks so that the points,
    and a lattice of points between them (``lattice``), stay on their paths at every step. Needs at least 3
    points whose midpoints (halfway between each pair) are not all on one line.

    Attributes:
        grid: the fluid's cells over the picture (or the part the fluid covers) and its margin:
            :class:`~torchfluidwarp.core.grid.SquareCells` (the default, 6,400 square cells whatever the aspect
            ratio: 80 x 80 on a square picture, about 8 pixels each of a 512-pixel one; 108 x 59 on a 970 x 2204
            portrait), or ``(h, w)`` rows and columns (an int: as many rows as columns, so the cells stretch with
            the picture). On the non-square photographs of ``benchmarks/bench_framing.py`` square cells meet the
            marks closer than 80 x 80 stretched ones, in the same time (``docs/benchmarks.md``). Where the margin
            widens (:data:`~torchfluidwarp.morph.fit.WALL_CLEARANCE`) the fluid gets more cells of the same size.
        steps: fluid steps ``T`` of the roll-out (time steps).
        viscosity: the fluid's viscosity, fluid cells^2 per time step (0: inviscid), or a viscosity field
            ``(1, 1, h, w)`` or module (see :class:`~torchfluidwarp.warp.layer.FluidWarp`).
        compressible: the fraction of the flow's divergent part kept, in ``[0, 1]``: ``True`` (1, the default)
            skips the pressure projection, so regions change size as the marks say; ``False`` (0) keeps every area.
        straightness: the weight on the fit's corrections to the points' straight-line velocities, in pixels^2 of
            point error per (pixel per time step)^2 of velocity correction, the same whatever the image or grid
            size; 0 (the default) lets the fit bend the paths as it needs to meet the marks (the bundled demo's
            marks end 0.02 px from B's on average; 1.3 px at 3, the earlier default).
        max_iter: L-BFGS iterations of the fit (it starts on the straight paths, so few are needed).
        tolerance: pixels; the fit stops once every point is this close to its path at every step.
        align: the global pre-alignment from the points: ``"similarity"``, ``"affine"`` or ``None`` (``"none"``).
            Marks that do not agree on a pose (:data:`~torchfluidwarp.morph.marks.MIN_POSE_FIT`) are morphed without
            it, with a warning.
        inverse: how image B is pulled back: ``"flow"`` (along the same fitted velocities, no second fit) or
            ``"paper"`` (the paper's stepwise chain of one-step fits; slower, for comparison).
        dense: how the pixels align what the marks leave open
            (:class:`~torchfluidwarp.correspond.halfway.HalfwaySettings`): a residual travel ``R`` found on the
            middle frame, added to the spline's between the marks and carried by the forces' first kick;
            ``None``: the marks alone (the spline between them).
        lattice: the spacing, in fluid cells, of the points between the marks that the fit also keeps on their
            straight paths (the travel ``D + R`` at the middle frame, on a lattice over the picture, none within a
            third of a spacing of a mark); ``None``: the marks alone. One kick sets the whole picture moving, but
            the discrete fluid drifts off the paths between the marks where they stretch or squeeze it (up to tens
            of pixels); the lattice holds it there, so that the frames show the spline's and the pixels' travel.
            At 6 (48 px of a 512-px picture, about 100 points) a 512-px morph takes about a second longer. These
            points are the fit's own, weighed below the marks (:data:`~torchfluidwarp.morph.fit.LATTICE_WEIGHT`):
            ``result.error`` and ``result.fit`` speak of the marks alone.
    """

    method: ClassVar[Method] = "natural"

    grid: FluidGrid | SquareCells | int | tuple[int, int] = SquareCells(80 * 80)
    steps: int = 10
    viscosity: float | Tensor | nn.Module = 0.0
    compressible: bool | float = True
    straightness: float = 0.0
    max_iter: int = 30
    tolerance: float = 0.05
    align: AlignKind | None = "similarity"
    inverse: InverseMethod = "flow"
    dense: HalfwaySettings | None = HalfwaySettings()
    lattice: int | None = 6

    def __post_init__(self) -> None:
        _check_flow(self)
        check_instance("NaturalSettings.dense", self.dense, HalfwaySettings, optional=True)
        if self.lattice is not None:
            check_int("NaturalSettings.lattice", self.lattice, minimum=1)
        _set(self, "straightness", check_positive("NaturalSettings.straightness", self.straightness, allow_zero=True))


@dataclass(frozen=True)
class PaperSettings:
    """The paper's keyframe fit: a :class:`~torchfluidwarp.warp.forces.ControlGrid` of forces, fitted so that the
    points reach their targets at the last step, in an incompressible fluid (every region keeps its area) over a
    box around the points.

    Attributes:
        grid: fluid cells ``(h, w)`` (an int: as many rows as columns) over the fluid's box, or square cells
            laid over it (:class:`~torchfluidwarp.core.grid.SquareCells`).
        steps: fluid steps ``T`` of the roll-out (time steps).
        control: ``(K_y, K_x)`` control points per step of the fitted force grid (an int: square).
        viscosity: the fluid's viscosity, fluid cells^2 per time step (0: inviscid), or a viscosity field
            ``(1, 1, h, w)`` or module (see :class:`~torchfluidwarp.warp.layer.FluidWarp`).
        compressible: the fraction of the flow's divergent part kept, in ``[0, 1]``: ``False`` (0, the default,
            the paper's incompressible fluid) keeps every area; ``True`` (1) skips the pressure projection.
        smoothness: the weight on the flow's
            :func:`~torchfluidwarp.control.keyframes.velocity_gradient_energy`, in fluid cells^2 per pixel^2 of
            point error (it is scaled by the square of the pixels per fluid cell, so it means the same at any
            image size); it keeps the flow calm and the maps fold-free.
        max_iter: L-BFGS iterations of the fit (it starts from rest).
        tolerance: pixels; the fit stops once every point is this close to its target at the last step.
        margin: the fluid fills a box around the points (A's and their targets) grown by this fraction of its
            size on each side, at most :data:`MAX_MARGIN`; the rest of the picture follows the pre-alignment only.
            ``None``: the box is the picture.
        align: the global pre-alignment from the points: ``"similarity"``, ``"affine"`` or ``None`` (``"none"``).
        inverse: how image B is pulled back: ``"flow"`` (along the same fitted velocities) or ``"paper"`` (the
            paper's stepwise chain of one-step fits).
    """

    method: ClassVar[Method] = "paper"

    grid: FluidGrid | SquareCells | int | tuple[int, int] = (64, 64)
    steps: int = 10
    control: int | tuple[int, int] = (8, 8)
    viscosity: float | Tensor | nn.Module = 0.0
    compressible: bool | float = False
    smoothness: float = 5.0
    max_iter: int = 100
    tolerance: float = 0.05
    margin: float | None = 0.5
    align: AlignKind | None = "similarity"
    inverse: InverseMethod = "flow"

    def __post_init__(self) -> None:
        _check_flow(self)
        _set(self, "control", check_size("PaperSettings.control", self.control, minimum=1))
        _set(self, "smoothness", check_positive("PaperSettings.smoothness", self.smoothness, allow_zero=True))
        if self.margin is not None:
            margin = check_positive("PaperSettings.margin", self.margin, allow_zero=True)
            if margin > MAX_MARGIN:
                raise InputError(
                    f"PaperSettings.margin must be <= {MAX_MARGIN} (a fraction of the points' extent), got {margin!r}"
                )
            _set(self, "margin", margin)


MorphSettings = NaturalSettings | PaperSettings
"""The settings of either method; :func:`~torchfluidwarp.morph.morph` picks the method by the class."""

METHODS: dict[str, type[NaturalSettings] | type[PaperSettings]] = {"natural": NaturalSettings, "paper": PaperSettings}
"""The settings class of each method's name (what the command line and the studio build from ``--method``)."""


def _frozen_schedule(name: str, value: object) -> Schedule:
    """A schedule checked by :func:`~torchfluidwarp.morph.timing.schedule`, control points as a tuple of pairs."""
    schedule(name, value)
    if isinstance(value, str):
        return value  # type: ignore[return-value]
    return tuple((float(t), float(v)) for t, v in value)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class Timing:
    """How a morph progresses over its time ``t`` in ``[0, 1]`` (:mod:`~torchfluidwarp.morph.timing`).

    Each is a schedule, ``t`` to a progress in ``[0, 1]``: a name (``"linear"``, the paper's; ``"smooth"``,
    ``"ease-in"``, ``"ease-out"``) or control points ``[(t, progress), ...]`` from ``(0, 0)`` to ``(1, 1)``
    (kept as a tuple of pairs). ``Timing(motion="ease-out", blend="ease-in")`` lets the shape lead the colour.

    Attributes:
        motion: the shape's schedule: how far along the flow (and the pre-alignment) each frame is; the frame at
            ``t`` shows the fluid at ``motion(t) T`` time steps.
        blend: the colour's schedule: the cross-dissolve's weight of image B at ``t``.
    """

    motion: Schedule = "linear"
    blend: Schedule = "linear"

    def __post_init__(self) -> None:
        _set(self, "motion", _frozen_schedule("Timing.motion", self.motion))
        _set(self, "blend", _frozen_schedule("Timing.blend", self.blend))


@dataclass(frozen=True, eq=False)
class Blending:
    """How each frame puts image A warped forward and image B pulled back together.

    Attributes:
        feather: output pixels over which a frame hands over to the other image inside an image's edge (where
            one image is read beyond its edge, the other shows instead of its edge pixels smeared into streaks);
            0 hands over at the edge itself.
        region: limit the morph to a region: ``"points"`` (each image's points' convex hull, grown by
            ``region_margin``, with a soft edge; :func:`~torchfluidwarp.morph.regions.hull_mask`) or soft masks
            ``(mask_a, mask_b)``, ``(H_a, W_a)`` and ``(H_b, W_b)`` in ``[0, 1]``. Each frame carries A's mask
            along A's map and B's along B's; the morph shows inside, ``background`` outside, blended over the
            masks' soft edges. ``None``: the whole frame.
        region_margin: how far ``region="points"`` reaches beyond the points' hull, as a fraction of their extent.
        background: what a region morph shows outside the region: ``"a"`` (A's picture throughout), ``"b"``, or
            ``"blend"`` (A and B cross-dissolved in place, with the colour's schedule).
        size: the output canvas ``(H, W)`` in pixels (an int: square); ``None``: image A's size. Each picture is
            placed on the canvas by one scale factor for both axes (never stretched), the smallest that covers the
            canvas, the crop centred on the picture's points: what overflows is cropped. Frame 0 is A so placed, the
            last frame B so placed.
    """

    feather: float = FEATHER
    region: Literal["points"] | tuple[Tensor, Tensor] | None = None
    region_margin: float = 0.25
    background: Background = "blend"
    size: int | tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.size is not None:
            _set(self, "size", check_size("Blending.size", self.size, minimum=2))
        _set(self, "feather", check_positive("Blending.feather", self.feather, allow_zero=True))
        _set(self, "region_margin", check_positive("Blending.region_margin", self.region_margin, allow_zero=True))
        _choice("Blending.background", self.background, ("a", "b", "blend"))
        region = self.region
        if isinstance(region, str):
            if region != "points":
                raise InputError(
                    f"Blending.region must be 'points', a pair of masks (mask_a, mask_b) or None, got {region!r}"
                )
        elif isinstance(region, Sequence) and len(region) == 2 and all(isinstance(m, Tensor) for m in region):
            _set(self, "region", tuple(region))
        elif region is not None:
            raise InputTypeError(
                f"Blending.region must be 'points', a pair of masks (mask_a, mask_b) or None, got {describe(region)}"
            )


@dataclass(frozen=True)
class Matching:
    """How :func:`~torchfluidwarp.morph.morph` finds the points when none are given
    (:func:`~torchfluidwarp.correspond.auto.auto_points`).

    Attributes:
        mode: ``"auto"`` (faces when both images show one and the faces extra is installed, else matched
            features, or the pixels where too few match:
            :data:`~torchfluidwarp.correspond.auto.TRUSTED_MATCHES`), ``"faces"``, ``"features"`` or
            ``"pixels"``. ``morph(match="pixels")`` is ``morph(match=Matching("pixels"))``.
        face_index: which face in A and in B, ``(i, j)`` (0 = the largest; ``None``: the largest, with a warning if
            several); one ``int``: that face in each picture that shows several (a picture of one face keeps it).
    """

    mode: MatchMode = "auto"
    face_index: int | tuple[int | None, int | None] = field(default=(None, None))

    def __post_init__(self) -> None:
        _choice("Matching.mode", self.mode, MATCH_MODES)
        pair = self.face_index
        if isinstance(pair, int) and not isinstance(pair, bool):
            check_int("Matching.face_index", pair, minimum=0)
            return
        if not isinstance(pair, Sequence) or len(pair) != 2:
            raise InputTypeError(
                f"Matching.face_index must be an int or a pair (index in A, index in B), got {describe(pair)}"
            )
        for i in pair:
            if i is not None:
                check_int("Matching.face_index", i, minimum=0)
        _set(self, "face_index", tuple(pair))
