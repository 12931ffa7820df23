"""The marks' checks: the pose they agree on, and the warning about marks that share the fluid's cells."""

from __future__ import annotations

import math
import re
import warnings

import pytest
import torch

from torchfluidwarp.control.alignment import apply_alignment, estimate_alignment
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.morph import NaturalSettings, morph
from torchfluidwarp.morph.marks import (
    LET_GO,
    MIN_POSE_FIT,
    check_marks,
    mirrored,
    pose,
    warn_coarse_grid,
    warn_missed,
)

PA = torch.tensor([[20.0, 22.0], [44.0, 20.0], [32.0, 40.0], [22.0, 46.0], [44.0, 44.0], [30.0, 12.0]])


def similarity(scale: float, angle: float, shift: tuple[float, float]) -> torch.Tensor:
    c, s = scale * math.cos(angle), scale * math.sin(angle)
    return torch.tensor([[c, -s, shift[0]], [s, c, shift[1]], [0.0, 0.0, 1.0]], dtype=torch.float64)


@pytest.mark.parametrize("kind", ["similarity", "affine"])
def test_a_pose_the_marks_agree_on_is_kept(kind):
    M = similarity(1.3, 0.4, (5.0, -3.0))
    pb = apply_alignment(M, PA.double()) + 0.5 * torch.randn(6, 2, generator=torch.Generator().manual_seed(1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning
        got = pose(PA, pb, kind)
    moved, want = apply_alignment(got, PA.double()), apply_alignment(M, PA.double())
    assert float((moved - want).norm(dim=-1).max()) < 1.0  # pixels, against noise of 0.5 px per coordinate


@pytest.mark.parametrize("kind", ["similarity", "affine"])
def test_marks_in_no_common_pose_get_the_identity_and_a_warning(kind, shuffled_marks):
    with pytest.warns(RuntimeWarning, match=rf"do not agree on a pose: the {kind} pre-alignment explains \d+%"):
        got = pose(*shuffled_marks, kind)
    torch.testing.assert_close(got, torch.eye(3, dtype=torch.float64), atol=0, rtol=0)
    assert 0 < MIN_POSE_FIT < 0.73  # below the worst pair of real faces (see its docstring)


def _grid_marks(n: int = 5) -> torch.Tensor:
    ys, xs = torch.meshgrid(torch.linspace(12.0, 52.0, n), torch.linspace(12.0, 52.0, n), indexing="ij")
    return torch.stack([xs, ys], -1).reshape(-1, 2).double()


@pytest.mark.parametrize("kind", ["similarity", "affine"])
def test_a_mark_placed_far_off_is_outvoted_and_named(kind):
    pa = _grid_marks()
    M = similarity(0.9, 0.3, (4.0, -2.0))
    pb = apply_alignment(M, pa)
    pb[7] = torch.tensor([900.0, -700.0], dtype=torch.float64)  # one mark put in the wrong place
    residual = apply_alignment(estimate_alignment(pa, pb, kind), pa) - pb
    assert 1 - float(residual.square().sum() / (pb - pb.mean(0)).square().sum()) < MIN_POSE_FIT  # least squares fails
    said = r"point 7 \(\d+ px\) of points_a and points_b lies far from .* other 24 marks"
    with pytest.warns(RuntimeWarning, match=said):
        got = pose(pa, pb, kind)
    torch.testing.assert_close(apply_alignment(got, pa), apply_alignment(M, pa), atol=1e-6, rtol=0)


def test_marks_far_off_are_named_by_the_callers_index_and_an_undefined_pose_is_no_pose():
    pa = _grid_marks().double()
    pb = apply_alignment(similarity(1.1, -0.2, (3.0, 5.0)), pa)
    pb[[7, 8]] = torch.tensor([[900.0, -700.0], [-800.0, 650.0]], dtype=torch.float64)
    numbers = torch.arange(25) + 3  # the caller dropped marks 0-2 before (a crop): its 10 and 11 are far off
    said = r"points 1[01] \(\d+ px\), 1[01] \(\d+ px\) of points_a and points_b lie far"
    with pytest.warns(RuntimeWarning, match=said):
        pose(pa, pb, "similarity", numbers=numbers)
    # the marks that agree lie on one line: no affine goes through them, so there is no pose (it was an error)
    line = torch.tensor([[x, 0.0] for x in range(0, 70, 10)] + [[20.0, 30.0], [40.0, -30.0]], dtype=torch.float64)
    far = line.clone()
    far[7:] = torch.tensor([[500.0, 500.0], [500.0, 520.0]], dtype=torch.float64)
    with pytest.warns(RuntimeWarning, match="do not agree on a pose"):
        got = pose(line + 100, far + 100, "affine")
    torch.testing.assert_close(got, torch.eye(3, dtype=torch.float64), atol=0, rtol=0)


def test_a_morph_meets_the_other_marks_when_one_is_put_far_off():
    a, b = load_sample("astronaut"), load_sample("cat")
    pa, pb = load_sample_points("astronaut"), load_sample_points("cat")
    pa[0], pb[0] = torch.tensor([-0.5, -0.5]), torch.tensor([511.5, 511.5])  # one mark clicked in the wrong corner
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = morph(a, b, pa, pb, frames=2, progress=False,
                       settings=NaturalSettings(grid=32, max_iter=10, dense=None))  # fmt: skip
    said = [str(w.message) for w in caught]
    far = [m for m in said if re.match(r"points? 0 \((\d+) px\)(, \d+ \(\d+ px\))* of points_a and points_b", m)]
    assert far and int(re.match(r"points? 0 \((\d+) px\)", far[0]).group(1)) > 1000, said  # named first
    assert not any("do not agree on a pose" in m for m in said), said
    # without the pre-alignment, every one of the 23 marks was let go; with it, most are met
    met = ~result.let_go
    assert bool(result.let_go[0]) and int(met.sum()) >= 15, result.let_go
    assert float(result.error[met].mean()) < 4.0, result.error_summary()  # a coarse fit: 0.7 px with no mark off


def test_a_mark_let_go_around_a_squeeze_is_named_though_it_crosses_none():
    ys, xs = torch.meshgrid(torch.linspace(16.0, 48.0, 3), torch.linspace(16.0, 48.0, 3), indexing="ij")
    pa = torch.stack([xs, ys], -1).reshape(-1, 2)
    pb = pa.clone()
    pb[4] = torch.tensor([47.0, 32.0])  # the middle mark pushed 1 px from its right neighbour: no crossing
    picture = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = morph(picture, picture, pa, pb, frames=2, progress=False,
                       settings=NaturalSettings(grid=24, steps=4, max_iter=15, dense=None))  # fmt: skip
    said = [str(w.message) for w in caught]
    released = result.let_go.nonzero()[:, 0].tolist()
    assert len(released) == 1 and released[0] in (4, 5), result.let_go  # one of the two squeezed together
    pattern = rf"point {released[0]} \((\d+) px\) of points_a and points_b was let go so as not to fold"
    named = [re.match(pattern, m) for m in said]
    assert any(named) and not any("cross" in m for m in said), said
    distance = int(next(m for m in named if m).group(1))
    assert abs(distance - float(result.error[released[0]])) <= 0.5  # the distance said is the one the result holds


def test_marks_that_are_a_mirror_image_are_said_to_be_one():
    pa = _grid_marks(4).double() + torch.tensor([3.0, -2.0], dtype=torch.float64)
    pa[5] += torch.tensor([4.0, 1.0], dtype=torch.float64)  # not symmetric itself
    swapped = pa.flip(-1)  # (y, x) pairs: a reflection about the diagonal
    flipped = pa * torch.tensor([-1.0, 1.0], dtype=torch.float64) + 63  # a mirror image, its points not reordered
    for mirror in (swapped, flipped):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_marks(pa, mirror)
        said = [str(w.message) for w in caught]
        assert len(said) == 1 and said[0].startswith("points_b look mirrored: "), said  # not "the marks cross"
    # marks in a row agree with their own reflection as well as with themselves: not a mirror image
    row = torch.tensor([[10.0, 10.0], [20.0, 20.0], [30.0, 30.0]], dtype=torch.float64)
    assert not mirrored(row, row + 2) and not mirrored(pa, pa + 1)
    # two marks put far off (where a reflection explains the rest better than the least squares): the pose the
    # others agree on outvotes them, so they are not taken for a mirror image
    pa = torch.rand(12, 2, generator=torch.Generator().manual_seed(0)) * 50 + 7
    pb = 2 * pa + 3
    pa[5], pa[6] = torch.tensor([5.0, 60.0]), torch.tensor([60.0, 5.0])
    pb[5], pb[6] = torch.tensor([127.0, 0.0]), torch.tensor([0.0, 127.0])
    flip = pb * torch.tensor([-1.0, 1.0])
    residual = apply_alignment(estimate_alignment(pa, flip), pa) - flip
    assert 1 - float(residual.square().sum() / (flip - flip.mean(0)).square().sum()) > 0.6  # a reflection explains
    assert not mirrored(pa, pb)
    with pytest.warns(RuntimeWarning, match=r"points 5 \(\d+ px\), 6 \(\d+ px\) of points_a and points_b lie far"):
        pose(pa, pb, "similarity")


def test_no_pre_alignment_asked_is_the_identity_without_a_check():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = pose(PA, PA.flip(0), None)
    torch.testing.assert_close(got, torch.eye(3, dtype=torch.float64), atol=0, rtol=0)


def _lattice(spacing: float, n: int = 5) -> torch.Tensor:
    ys, xs = torch.meshgrid(torch.arange(float(n)), torch.arange(float(n)), indexing="ij")
    return 200.0 + spacing * torch.stack([xs, ys], -1).reshape(-1, 2)


@pytest.mark.parametrize(
    "spacing_px, error_px, warns",
    [
        (3.0, 2.0, True),  # 0.3 cells apart (10 px cells) and 2 px off: the slow fit of marks sharing cells
        (20.0, 2.0, False),  # 2 cells apart: whatever left them off, a finer grid is not the remedy
        (3.0, 0.5, False),  # met within LET_GO: nothing to say
    ],
)
def test_marks_closer_than_the_cells_and_missed_get_a_warning_naming_the_remedy(spacing_px, error_px, warns):
    points = _lattice(spacing_px)
    error = torch.full((points.shape[0],), error_px)
    box, grid = (800, 800), 80  # 10 pixels per cell
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warn_coarse_grid(points, error, box, grid)
    messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    if not warns:
        assert messages == []
        return
    assert len(messages) == 1
    assert f"{error_px:.1f} px" in messages[0] and "0.30 fluid cells apart" in messages[0]
    assert "a finer grid (NaturalSettings.grid) or more iterations" in messages[0]  # in Python's terms
    said = [w.message for w in caught][0].explain({"grid": "--grid N"})  # and in the command line's
    assert said.endswith("a finer grid (--grid N) or more iterations meet them closer, at more time")


def test_one_mark_far_off_where_the_marks_share_cells_warns_unless_it_was_let_go():
    # 25 marks 3 px apart on 10-px cells: met within LET_GO on average (0.65 px), but one ends 4 px off
    points = _lattice(3.0)
    error = torch.full((points.shape[0],), 0.5)
    error[7] = 4.0
    box, grid = (800, 800), 80
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warn_coarse_grid(points, error, box, grid)
    messages = [str(w.message) for w in caught]
    assert len(messages) == 1 and "0.6 px from their targets on average, up to 4.0 px" in messages[0]
    # the same mark let go so as not to fold is the morph's choice, not the grid's: nothing to say
    let_go = torch.zeros(points.shape[0], dtype=torch.bool)
    let_go[7] = True
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_coarse_grid(points, error, box, grid, let_go)
    # and a mark 2.9 px off (under FAR_OFF x LET_GO) with the mean met says nothing either
    error[7] = 2.9
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_coarse_grid(points, error, box, grid)


@pytest.mark.parametrize(
    "errors, warns",
    [
        ([0.2, 0.4, 0.3, 0.5], False),  # met
        ([1.5, 1.8, 1.2, 2.0], True),  # 1.6 px on average: above LET_GO
        ([0.2, 0.3, 0.2, 3.5], True),  # one mark far off
        ([0.2, 0.3, 0.2, 30.0], False),  # ... but that one was let go on purpose
    ],
)
def test_the_papers_fit_says_when_it_leaves_the_marks(errors, warns):
    error = torch.tensor(errors)
    let_go = torch.tensor([False, False, False, errors[-1] > 10])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warn_missed(error, let_go)
    if not warns:
        assert caught == []
        return
    (w,) = caught
    kept = error[~let_go]
    assert f"end {float(kept.mean()):.1f} px from their targets on average, up to {float(kept.max()):.1f} px" in str(
        w.message
    )
    assert str(w.message).endswith("a lower PaperSettings.smoothness (or more iterations) meets them closer")
    assert w.message.explain({"smoothness": "--smoothness X"}).endswith(
        "a lower --smoothness X (or more iterations) meets them closer"
    )
    assert LET_GO == 1.0
