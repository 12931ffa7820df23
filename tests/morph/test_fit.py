"""The morph's fitting helpers (torchfluidwarp.morph.fit): the pre-alignment's check and the straight paths."""

from __future__ import annotations

import copy
import math
import warnings

import pytest
import torch

from torchfluidwarp.core.grid import SquareCells
from torchfluidwarp.core.spline import tps_fit
from torchfluidwarp.correspond.halfway import least_area
from torchfluidwarp.errors import InputError
from torchfluidwarp.morph.fit import (
    FOCUS_MARGIN,
    MIN_AREA,
    RELEASE,
    fit_natural,
    fit_paper,
    focus,
    straight_paths,
    warm_corrections,
)
from torchfluidwarp.morph.morphing import morph
from torchfluidwarp.morph.settings import NaturalSettings, PaperSettings
from torchfluidwarp.warp.landmarks import solve_midpoints

PA = torch.tensor([[20.0, 22.0], [44.0, 20.0], [32.0, 40.0], [22.0, 46.0], [44.0, 44.0], [30.0, 12.0]])


def test_swapped_marks_get_smoothed_paths_that_start_at_the_sources():
    src = PA.double()
    tgt = src.clone()
    tgt[[0, 4]] = tgt[[4, 0]]  # both straight paths pass through the same midpoint
    inside = (0.0, 0.0, 64.0, 64.0)
    mids, disp = straight_paths(src, tgt, inside)
    torch.testing.assert_close(mids - disp / 2, src, atol=1e-6, rtol=0)  # each mark still starts at its source
    assert torch.cdist(mids, mids).add(torch.eye(6, dtype=torch.float64) * 1e9).min() > 1.0  # distinct midpoints


def test_too_few_distinct_midpoints_are_refused_naming_the_points():
    src = PA[:3].double()
    tgt = src[torch.tensor([1, 0, 2])]  # two of three marks swap: two distinct midpoints are left
    with pytest.raises(ValueError, match="points_a and points_b: .* swap places"):
        straight_paths(src, tgt, (0.0, 0.0, 64.0, 64.0))


def test_a_squeeze_between_close_marks_is_seen_and_smoothed():
    # an eye that closes: two marks 6 px apart in A end 0.2 px apart in B, squeezing the lid to 6% of its middle
    # height, between the 4-px samples of a 64 x 64 lattice over the 256-px picture
    ring = torch.tensor(
        [[x, y] for x in (30.0, 128.0, 226.0) for y in (30.0, 128.0, 226.0) if (x, y) != (128.0, 128.0)]
    )
    lids = torch.tensor([[128.0, 125.0], [128.0, 131.0]])
    src = torch.cat([ring, lids]).double()
    tgt = torch.cat([ring, torch.tensor([[128.0, 127.9], [128.0, 128.1]])]).double()
    inside = (0.0, 0.0, 255.0, 255.0)
    mids, disp = straight_paths(src, tgt, inside)
    torch.testing.assert_close(mids - disp / 2, src, atol=1e-6, rtol=0)  # each mark still starts at its source
    # the paths' least area on a 0.25-px raster around the lids, from central differences of the returned motion
    travel = tps_fit(mids, disp)
    n, lo, hi = 129, 112.0, 144.0
    gy, gx = torch.meshgrid(*[torch.linspace(lo, hi, n, dtype=torch.float64)] * 2, indexing="ij")
    field = travel(torch.stack([gx, gy], -1).reshape(-1, 2)).T.reshape(1, 2, n, n)
    spacing = (hi - lo) / (n - 1)
    assert float(least_area(field, (spacing, spacing)).min()) >= MIN_AREA - 0.01
    # the marks given straight would squeeze the lid far below it (the case the check is for)
    straight = tps_fit(0.5 * (src + tgt), tgt - src)(torch.stack([gx, gy], -1).reshape(-1, 2)).T.reshape(1, 2, n, n)
    assert float(least_area(straight, (spacing, spacing)).min()) < 0.5 * MIN_AREA


def _least_area_on(travel, lo: float, hi: float, n: int = 129) -> float:
    """The least area of the straight paths of ``travel`` on an ``n x n`` raster over ``[lo, hi]^2`` (central
    differences, independent of the library's check)."""
    gy, gx = torch.meshgrid(*[torch.linspace(lo, hi, n, dtype=torch.float64)] * 2, indexing="ij")
    field = travel(torch.stack([gx, gy], -1).reshape(-1, 2)).T.reshape(1, 2, n, n)
    spacing = (hi - lo) / (n - 1)
    return float(least_area(field, (spacing, spacing)).min())


def test_a_side_that_turns_away_is_released_and_the_rest_still_travels_straight():
    # a 7 x 7 'face' of marks over a 256-px picture; in B its right side turns away: the two columns beyond
    # x = 160 shrink to 3% of their width, squeezing that side far below MIN_AREA at B's end of the paths
    # (0.03 / 0.515 = 0.06 of the middle frame), while the rest of the face stays as it is
    g = torch.linspace(40.0, 216.0, 7, dtype=torch.float64)
    src = torch.cartesian_prod(g, g)
    away = src[:, 0] > 160
    tgt = src.clone()
    tgt[away, 0] = 160 + 0.03 * (src[away, 0] - 160)
    assert _least_area_on(tps_fit(0.5 * (src + tgt), tgt - src), 0.0, 255.0) < 0.7 * MIN_AREA  # the case at hand
    mids, disp = straight_paths(src, tgt, (0.0, 0.0, 255.0, 255.0))
    torch.testing.assert_close(mids - disp / 2, src, atol=1e-6, rtol=0)  # every mark starts at its source
    met = (mids + disp / 2 - tgt).norm(dim=-1) < 1e-6
    # what stays in view, short of the fold's column, travels straight, exactly (a spline smoothed over all the
    # marks, the way before, misses every one of them)
    assert bool(met[src[:, 0] < 150].all())
    released = int((~met).sum())
    assert 1 <= released <= int(RELEASE * len(src)) and bool((~met)[away].any())
    # and nothing on the paths is squeezed below MIN_AREA, on a raster 4x finer than the library's lattice
    assert _least_area_on(tps_fit(mids, disp), 0.0, 255.0, n=257) >= MIN_AREA - 0.01


@pytest.mark.parametrize("method", ["natural", "paper"])
def test_the_morphs_memory_limit_reaches_its_fit(method):
    # morph(max_memory=...) bounds the keyframe fit too, which checks the grid the margin may have widened: a limit
    # the fit's roll-out exceeds is refused before any work, naming the fit and the setting
    pa = torch.tensor([[20.0, 22.0], [44.0, 20.0], [32.0, 40.0], [22.0, 46.0]], dtype=torch.float64)
    pb = pa + torch.tensor([[2.0, 1.0], [-1.0, 2.0], [1.5, -1.5], [-2.0, 0.0]], dtype=torch.float64)
    with pytest.raises(InputError, match=r"fit_keyframes over 6 steps on a grid of .* above the limit") as info:
        if method == "natural":
            fit_natural(pa, pb, (64, 64), NaturalSettings(grid=24, steps=6, dense=None), None, False, max_memory=1e4)
        else:
            fit_paper(pa, pb, (64, 64), PaperSettings(grid=24, steps=6), None, False, max_memory=1e4)
    assert info.value.hint is not None and "max_memory" in str(info.value.hint)


def test_the_lattice_holds_the_fluid_on_its_paths_beyond_the_marks():
    # a 5 x 5 'face' of marks in the middle of a 128-px picture whose right side stretches outwards (up to 24 px,
    # the farther right the more, as a cheek does when the head turns): one kick at step 0 sets every particle on
    # the spline's straight path, but the discrete fluid, which the fit corrects at the marks, drifts off those
    # paths around them; 32 points on two rings around the marks, nobody's marks, show how far
    g = torch.linspace(44.0, 84.0, 5, dtype=torch.float64)
    pa = torch.cartesian_prod(g, g)
    pb = pa.clone()
    pb[:, 0] += 0.015 * (pa[:, 0] - 44).square()
    travel = tps_fit(0.5 * (pa + pb), pb - pa)
    assert _least_area_on(travel, 0.0, 127.0) > MIN_AREA  # the marks travel straight: no release, no smoothing
    turn = torch.linspace(0, 2 * math.pi, 17, dtype=torch.float64)[:-1]
    ring = torch.stack([turn.cos(), turn.sin()], -1)
    probes = torch.cat([pa.mean(0) + radius * ring for radius in (30.0, 40.0)])
    mids = solve_midpoints(travel, probes, -0.5)
    spline_end = mids + travel(mids) / 2  # where the spline's straight paths take them, A's pixels
    stray = {}
    for lattice in (None, 6):
        settings = NaturalSettings(grid=48, dense=None, lattice=lattice)
        fit, box, _ = fit_natural(pa, pb, (128, 128), settings, None, False)
        assert fit.trajectories.shape[2] == 25 and fit.error.shape == (1, 25)  # the marks alone, either way
        assert float(fit.error.max()) < 0.1
        corner = probes.new_tensor(box[:2])
        with torch.no_grad():
            paths = fit.warp.carry_points((probes - corner)[None].float(), fit.forces)
        stray[lattice] = (paths[0, -1].double() + corner - spline_end).norm(dim=-1)
    # measured: 0.37 px on average without the lattice (1.9 at most), 0.07 with it (0.6 at most)
    assert float(stray[None].mean()) > 0.25
    assert float(stray[6].mean()) < 0.4 * float(stray[None].mean()) and float(stray[6].max()) < 1.0


def test_a_picture_narrower_than_the_lattices_spacing_gets_no_lattice_across_it():
    # 8 px wide, 18 high, 4 fluid cells: the lattice's spacing (6 cells, about 9 px) is wider than the picture, so
    # no column of lattice points fits (the command line's fuzzing found this refused with a torch error)
    pa = torch.tensor([[1.0, 2.0], [6.0, 4.0], [3.0, 9.0], [5.0, 15.0]], dtype=torch.float64)
    pb = pa + torch.tensor([[0.5, 0.5], [-0.5, 1.0], [0.5, -1.0], [0.0, 0.5]], dtype=torch.float64)
    fit, _, _ = fit_natural(pa, pb, (18, 8), NaturalSettings(grid=4, steps=2, dense=None), None, False)
    assert len(fit.forces.midpoints) == 4 and fit.trajectories.shape[2] == 4  # the marks alone


def _zoom(factor: float, centre: tuple[float, float]) -> torch.Tensor:
    """``(3, 3)`` float64: a zoom by ``factor`` about ``centre`` ``(x, y)``."""
    cx, cy = centre
    return torch.tensor(
        [[factor, 0, cx * (1 - factor)], [0, factor, cy * (1 - factor)], [0, 0, 1]], dtype=torch.float64
    )


def test_the_fluid_covers_what_the_last_frame_shows_of_a_when_that_is_small():
    points = torch.tensor([[95.0, 96.0], [101.0, 100.0], [98.0, 104.0]], dtype=torch.float64)
    # a zoom by 4 about (100, 100) shows A's pixels 76 to 124 (the canvas's 200 px / 4, edges at -0.5 and 199.5
    # mapped back: 100 + (-0.5 - 100) / 4 = 74.875 and 100 + 99.5 / 4 = 124.875), grown by a quarter of that
    lo, hi = 100 - 100.5 / 4, 100 + 99.5 / 4
    grow = FOCUS_MARGIN * (hi - lo)
    x0, y0, x1, y1 = focus((200, 200), _zoom(4.0, (100.0, 100.0)), points)
    assert (x0, y0) == (math.floor(lo - grow + 0.5),) * 2 and (x1, y1) == (math.ceil(hi + grow + 0.5),) * 2
    # a mark that ends beyond what the last frame shows is inside the region too
    far = torch.cat([points, points.new_tensor([[40.0, 150.0]])])
    x0, y0, x1, y1 = focus((200, 200), _zoom(4.0, (100.0, 100.0)), far)
    assert x0 <= 40 < x1 and y0 <= 150 < y1
    # no zoom, or a zoom out: the last frame shows all of A, and the fluid covers the whole picture
    assert focus((200, 200), torch.eye(3, dtype=torch.float64), points) is None
    assert focus((200, 200), _zoom(0.5, (100.0, 100.0)), points) is None
    # the region stays within the picture: a zoom about a point near its corner
    x0, y0, x1, y1 = focus((200, 300), _zoom(4.0, (5.0, 5.0)), points.new_tensor([[5.0, 5.0], [8.0, 6.0], [6.0, 9.0]]))
    assert (x0, y0) == (0, 0) and x1 < 300 / 2 and y1 < 200 / 2


def test_square_cells_on_a_wide_picture_meet_marks_that_stretched_cells_blur():
    # a 48 x 240 picture: 21 marks 6 px apart along a row, pushed alternately up and down by 1 px; 576 cells either
    # way. Square cells (about 7 px) resolve the alternation; 24 x 24 cells of 12 x 5 px cannot
    xs = torch.arange(60.0, 181.0, 6.0, dtype=torch.float64)
    row = torch.stack([xs, torch.full_like(xs, 24.0)], -1)
    corners = torch.tensor([[20.0, 10.0], [220.0, 38.0], [20.0, 38.0], [220.0, 10.0]], dtype=torch.float64)
    pa = torch.cat([row, corners])
    pb = pa.clone()
    pb[: len(xs), 0] += 2.0
    pb[: len(xs), 1] += torch.tensor([(-1.0) ** i for i in range(len(xs))], dtype=torch.float64)
    error = {}
    for grid in (SquareCells(24 * 24), 24):
        settings = NaturalSettings(grid=grid, steps=6, dense=None, lattice=None)
        fit, box, _ = fit_natural(pa, pb, (48, 240), settings, None, False)
        h, w = fit.warp.grid.shape
        cell = ((box[3] - box[1]) / h, (box[2] - box[0]) / w)  # pixels per cell (tall, wide)
        if isinstance(grid, SquareCells):
            assert abs(cell[0] / cell[1] - 1) < 0.05  # (more than 576 of them: the margin widened)
        else:
            assert cell[1] / cell[0] > 2
        error[grid] = fit.error[0]
    # measured: 0.18 px on average (0.27 at most) on square cells, 0.74 (1.28) on stretched ones
    assert float(error[SquareCells(576)].mean()) < 0.3 and float(error[SquareCells(576)].max()) < 0.5
    assert float(error[24].mean()) > 2 * float(error[SquareCells(576)].mean())


def test_a_natural_warm_start_after_a_dragged_mark_starts_nearer_and_leaves_the_previous_fit_alone():
    # the studio's case: one mark dragged by 3 px. The lattice between the marks changes in number with the
    # travel, so the corrections are matched by place (they were dropped whenever the counts differed).
    from torchfluidwarp.data import load_sample, load_sample_points

    a, b = load_sample("astronaut"), load_sample("cat")
    pa, pb = load_sample_points("astronaut"), load_sample_points("cat")
    settings = NaturalSettings(dense=None)
    first = morph(a, b, pa, pb, frames=2, progress=False, settings=settings)
    before = first.fit.forces.weight.detach().clone()
    moved = pb.clone()
    moved[0] += 3.0
    cold = morph(a, b, pa, moved, frames=2, progress=False, settings=settings)
    warm = morph(a, b, pa, moved, frames=2, progress=False, settings=settings, warm_start=first.fit)
    assert torch.equal(first.fit.forces.weight, before)  # the previous fit is left as it was
    assert warm.fit.loss_history[0] < 0.5 * cold.fit.loss_history[0]
    assert float(warm.error.mean()) <= float(cold.error.mean()) + 0.05
    # every point of the new fit found its counterpart: the marks within a few pixels, the lattice in place
    forces = copy.deepcopy(cold.fit.forces)
    assert warm_corrections(forces, first.fit.forces) == forces.weight.shape[2]


def test_a_warm_start_matches_marks_to_marks_when_the_box_moves():
    # dragging a mark near the edge widens the fluid's margin, which moves the box's origin: the points are
    # matched in A's pixels, not in each box's own (they were matched to lattice points 20 px away)
    a = torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(0))
    pa = torch.tensor([[16.0, 16.0], [48.0, 16.0], [48.0, 48.0], [16.0, 48.0], [32.0, 32.0]])
    pb = pa + torch.tensor([[-6.0, 4.0], [6.0, 4.0], [6.0, -4.0], [-6.0, -4.0], [0.0, 0.0]])
    settings = NaturalSettings(dense=None, max_iter=5)
    first = morph(a, a, pa, pb, frames=2, progress=False, settings=settings)
    dragged = pb.clone()
    dragged[1] += 3.0
    second = morph(a, a, pa, dragged, frames=2, progress=False, settings=settings)
    assert first.box != second.box  # the case this test is about
    forces = copy.deepcopy(second.fit.forces)
    forces.weight.data.zero_()
    warm_corrections(forces, first.fit.forces)
    torch.testing.assert_close(forces.weight[:, :, :5], first.fit.forces.weight[:, :, :5].detach())


def test_a_natural_warm_start_of_other_steps_is_refused():
    a = torch.rand(1, 3, 48, 48, generator=torch.Generator().manual_seed(0))
    fitted = morph(a, a, PA * 0.7, PA * 0.7 + 3.0, frames=2, progress=False, settings=NaturalSettings(dense=None))
    with pytest.raises(InputError, match="warm_start is a fit of 10 steps and this morph's has 6"):
        morph(a, a, PA * 0.7, PA * 0.7 + 3.0, frames=2, progress=False, warm_start=fitted.fit,
              settings=NaturalSettings(dense=None, steps=6))  # fmt: skip


def test_a_warm_start_of_the_other_method_or_another_control_grid_is_refused():
    a = torch.rand(1, 3, 48, 48, generator=torch.Generator().manual_seed(0))
    pb = PA * 0.7 + 3.0
    natural = morph(a, a, PA * 0.7, pb, frames=2, progress=False, settings=NaturalSettings(dense=None))
    paper = PaperSettings(steps=4, control=(3, 3), max_iter=3)
    with pytest.raises(InputError, match="warm_start is a fit of the natural method and this morph uses the paper's"):
        morph(a, a, PA * 0.7, pb, frames=2, progress=False, settings=paper, warm_start=natural.fit)
    fitted = morph(a, a, PA * 0.7, pb, frames=2, progress=False, settings=paper)
    with pytest.raises(InputError, match="warm_start is a fit of the paper's method"):
        morph(a, a, PA * 0.7, pb, frames=2, progress=False, settings=NaturalSettings(dense=None), warm_start=fitted.fit)
    with pytest.raises(InputError, match=r"control grid is \(4, 2, 3, 3\).*\(4, 2, 4, 4\)"):
        morph(a, a, PA * 0.7, pb, frames=2, progress=False, settings=PaperSettings(steps=4, control=4, max_iter=3),
              warm_start=fitted.fit)  # fmt: skip


def test_marks_whose_midpoints_lie_close_to_one_line_are_warned_about():
    eyes = torch.tensor(  # two eyes' corners and lids: 33 px across, 1 px high
        [[10.0, 20.0], [18.0, 20.5], [25.0, 21.0], [35.0, 21.0], [40.0, 20.5], [43.0, 20.0]], dtype=torch.float64
    )
    with pytest.warns(RuntimeWarning, match=r"midpoints lie close to one line \(their spread across it is [0-4]\.\d%"):
        straight_paths(eyes, eyes + eyes.new_tensor([2.0, 1.0]), (0.0, 0.0, 64.0, 64.0))
    square = torch.tensor([[10.0, 10.0], [40.0, 10.0], [10.0, 40.0], [40.0, 40.0]], dtype=torch.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # marks spread both ways say nothing
        straight_paths(square, square + 1.0, (0.0, 0.0, 64.0, 64.0))


def test_marks_whose_midpoints_lie_on_one_line_are_refused_naming_the_points():
    line = torch.tensor([[10.0, 10.0], [20.0, 20.0], [30.0, 30.0], [40.0, 40.0], [50.0, 50.0]], dtype=torch.float64)
    with pytest.raises(InputError, match="points_a and points_b: the 5 marks' midpoints .* lie on one line") as caught:
        straight_paths(line, line + line.new_tensor([3.0, -2.0]), (0.0, 0.0, 64.0, 64.0))
    assert caught.value.argument == "points_a"
    # A's marks in a row are fine when B's are not: their midpoints are not
    bent = line[:3].clone()
    bent[2, 1] += 1.0
    mids, disp = straight_paths(line[:3], bent, (0.0, 0.0, 64.0, 64.0))
    torch.testing.assert_close(mids - disp / 2, line[:3])
