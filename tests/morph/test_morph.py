import dataclasses
import importlib
import math
import sys
import warnings

import pytest
import torch
import torch.nn.functional as F
from PIL import Image

from torchfluidwarp.core.spline import tps_interpolate
from torchfluidwarp.correspond.auto import FoundPoints, Note
from torchfluidwarp.io import write_animation
from torchfluidwarp.morph import Blending, NaturalSettings, PaperSettings, Timing
from torchfluidwarp.morph.marks import LET_GO, crossing_pairs
from torchfluidwarp.morph.morphing import morph
from torchfluidwarp.warp import identity_map, jacobian_determinant, warp_image


def _blobs(size, centers, gen):
    H, W = size
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32), indexing="ij")
    img = 0.1 * torch.rand(3, H, W, generator=gen)
    for k, (x, y) in enumerate(centers):
        img[k % 3] += torch.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * 3.0**2))
    return img.clamp(0, 1)


POINTS_A = torch.tensor([[20.0, 22.0], [44.0, 20.0], [32.0, 40.0], [22.0, 46.0], [44.0, 44.0]])
POINTS_B = POINTS_A + torch.tensor([[2.0, 1.0], [-1.0, 2.0], [1.5, -1.5], [-2.0, 0.0], [0.0, 2.0]])
SETTINGS = NaturalSettings(grid=24, steps=6, max_iter=60)
KW = dict(settings=SETTINGS, progress=False)


def _with(**changes):
    """KW with some of the method's settings changed."""
    return {**KW, "settings": dataclasses.replace(SETTINGS, **changes)}


@pytest.fixture
def pair(gen):
    return _blobs((64, 64), POINTS_A.tolist(), gen), _blobs((64, 64), POINTS_B.tolist(), gen)


@pytest.mark.parametrize("inverse", ["flow", "paper"])
def test_first_and_last_frames_are_the_inputs(pair, inverse):
    a, b = pair
    r = morph(a, b, POINTS_A, POINTS_B, frames=7, **_with(inverse=inverse))
    assert r.frames.shape == (7, 3, 64, 64)
    torch.testing.assert_close(r.frames[0], a, atol=1e-5, rtol=0)
    torch.testing.assert_close(r.frames[-1], b, atol=1e-5, rtol=0)
    # the fitted points reach B's points, and the warp never folds
    assert r.error.mean() < 0.3
    assert jacobian_determinant(r.maps).min() > 0 and r.folded == 0


def test_identical_images_and_points_give_a_constant_morph(pair):
    a, _ = pair
    r = morph(a, a, POINTS_A, POINTS_A, frames=5, **KW)
    for k in range(5):
        torch.testing.assert_close(r.frames[k], a, atol=1e-5, rtol=0)


def test_flow_inverse_agrees_with_the_forward_warp(pair):
    a, b = pair
    r = morph(a, b, POINTS_A, POINTS_B, frames=5, **_with(align=None))
    # a pixel x of B's frame read at frame k: maps_b[k](y) = K(y); composing A's backward map g_k and K
    # sends A's points to where the fit carried them
    traj = r.trajectories  # (T + 1, M, 2), frame coordinates
    last = r.maps_b[0]  # frame 0: where B is read for each pixel of A's frame
    at = warp_image(last.permute(2, 0, 1)[None].double(), POINTS_A[None, None].double())[0, :, 0].T  # (M, 2)
    inner = ((POINTS_A > 8) & (POINTS_A < 56)).all(-1)
    assert (at - traj[-1])[inner].norm(dim=-1).max() < 0.1


def test_different_sizes_and_alignment(gen):
    a = _blobs((64, 64), POINTS_A.tolist(), gen)
    b_points = POINTS_B * 2 + 0.5  # B at twice the size: pixel centres scale as (x + 0.5) * 2 - 0.5
    b = torch.nn.functional.interpolate(
        _blobs((64, 64), POINTS_B.tolist(), gen)[None], size=(128, 128), mode="bilinear", align_corners=False
    )[0]
    r = morph(a, b, POINTS_A, b_points, frames=4, **KW)
    assert r.frames.shape == (4, 3, 64, 64)
    assert r.error.mean() < 0.3


def test_bad_inputs(pair):
    a, b = pair
    with pytest.raises(ValueError, match="points_a has 5 points but points_b has 4"):
        morph(a, b, POINTS_A, POINTS_B[:4], **KW)
    with pytest.raises(ValueError, match="frames must be >= 2"):
        morph(a, b, POINTS_A, POINTS_B, frames=1, **KW)
    with pytest.raises(ValueError, match="inverse must be"):
        morph(a, b, POINTS_A, POINTS_B, **_with(inverse="magic"))
    with pytest.raises(ValueError, match=r"points_b has a point outside the 64 x 64 image") as info:
        morph(a, b, POINTS_A, POINTS_B + 100, **KW)
    assert info.value.argument == "points_b"  # the command line names its flag, --points-b


def test_a_map_that_reads_beyond_its_image_hands_the_frame_to_the_other_image(gen, monkeypatch):
    feather = 4.0  # a narrow hand-over band, so that a 64-pixel frame has room beyond it
    # B's points spread 2.2 times as far as A's: the similarity pre-alignment magnifies, so the middle
    # frames read B far beyond its edges near the frame's borders
    a = _blobs((64, 64), POINTS_A.tolist(), gen)
    centre = POINTS_A.mean(0)
    points_b = (POINTS_A - centre) * 2.2 + centre
    inside = ((points_b > 0) & (points_b < 63)).all()
    assert inside, "the test's points must stay in the image"
    b = _blobs((64, 64), points_b.tolist(), gen)
    r = morph(a, b, POINTS_A, points_b, frames=5, blending=Blending(feather=feather), **_with(compressible=0.5))
    k = 2
    x, y = r.maps_b[k, ..., 0], r.maps_b[k, ..., 1]
    f = feather + 0.5  # B read more than the feather beyond its edge
    far_b = (x < -f) | (x > 63 + f) | (y < -f) | (y > 63 + f)
    xa, ya = r.maps[k, ..., 0], r.maps[k, ..., 1]
    in_a = (xa > -0.5) & (xa < 63.5) & (ya > -0.5) & (ya < 63.5)
    assert (far_b & in_a).sum() > 50, "the set-up must make B's map leave B"
    sel = far_b & in_a
    torch.testing.assert_close(r.frames[k][:, sel], r.forward_frames[k][:, sel], atol=1e-6, rtol=0)
    # where both maps read well inside their images, the frame is the plain cross-dissolve: at least the feather
    # in output pixels, i.e. `feather` times the maps' local scale (at most 3 source pixels per output pixel here)
    depth = 3 * feather - 0.5
    both = (xa > depth) & (xa < 63 - depth) & (ya > depth) & (ya < 63 - depth)
    both &= (x > depth) & (x < 63 - depth) & (y > depth) & (y < 63 - depth)
    scale = torch.maximum(jacobian_determinant(r.maps[k : k + 1]), jacobian_determinant(r.maps_b[k : k + 1]))[0]
    assert bool(scale[both].max() < 9) and both.sum() > 50
    w = float(r.times[k] / r.times[-1])
    plain = torch.lerp(r.forward_frames[k], r.backward_frames[k], w)
    torch.testing.assert_close(r.frames[k][:, both], plain[:, both], atol=1e-5, rtol=0)


# ------------------------------------------------------------------ the natural morph on a known deformation

SIZE = 128
AMPLITUDE, WAVELENGTH = 4.0, 128.0  # pixels


def _phi(p):
    """A smooth invertible map of the plane: A's feature at ``p`` shows at ``_phi(p)`` in B (pixels)."""
    x, y = p[..., 0], p[..., 1]
    k = 2 * math.pi / WAVELENGTH
    return torch.stack([x + AMPLITUDE * torch.sin(k * y), y + AMPLITUDE * torch.sin(k * x)], -1)


def _invert(maps, q, iters=60):
    """Where a backward map ``(1, H, W, 2)`` reads the points ``q`` ``(K, 2)``: solves ``maps(y) = q``."""
    y = q.clone()
    for _ in range(iters):
        y = y - (warp_image(maps.permute(0, 3, 1, 2).double(), y[None, None].double())[0, :, 0].T - q)
    return y


def _seam(maps):
    """``(B, H - 2, W - 2)`` Frobenius norm of a map's second derivatives (px/px^2), central differences."""
    m = maps.double()
    d2x = (m[:, 1:-1, 2:] - 2 * m[:, 1:-1, 1:-1] + m[:, 1:-1, :-2]).square().sum(-1)
    d2y = (m[:, 2:, 1:-1] - 2 * m[:, 1:-1, 1:-1] + m[:, :-2, 1:-1]).square().sum(-1)
    dxy = ((m[:, 2:, 2:] - m[:, 2:, :-2] - m[:, :-2, 2:] + m[:, :-2, :-2]) / 4).square().sum(-1)
    return (d2x + d2y + 2 * dxy).sqrt()


@pytest.fixture(scope="module")
def known_deformation():
    """A textured picture A, B = A deformed by ``_phi``, 25 points on a 14-px lattice in the middle (a third held out),
    and the natural morph of the pair from the marked two thirds."""
    gen = torch.Generator().manual_seed(0)
    a = F.interpolate(torch.rand(1, 3, 16, 16, generator=gen), size=(SIZE, SIZE), mode="bicubic").clamp(0, 1)
    ident = identity_map((SIZE, SIZE), dtype=torch.float64)
    inverse = ident.clone()
    for _ in range(50):  # phi^-1 by fixed-point iteration: phi is a small perturbation of the identity
        inverse = ident - (_phi(inverse) - inverse)
    b = warp_image(a.double(), inverse).float()
    ys, xs = torch.meshgrid(torch.linspace(36, 92, 5), torch.linspace(36, 92, 5), indexing="ij")
    points = torch.stack([xs, ys], -1).reshape(-1, 2).double()
    held = torch.arange(25) % 3 == 2
    pa, pb = points[~held].float(), _phi(points[~held]).float()
    result = morph(a[0], b[0], pa, pb, frames=9, progress=False)
    return points, held, result


def test_natural_morph_carries_unmarked_points_like_the_spline(known_deformation):
    points, held, r = known_deformation
    inner = held & ((points > 40) & (points < 88)).all(-1)  # held-out points inside the marks' hull
    last = _invert(r.maps[-1:], points[inner])
    err = (last - _phi(points[inner])).norm(dim=-1)
    # Bound: piecewise-linear interpolation on a lattice of spacing h = 14 px errs by at most
    # h^2 / 8 * max|phi''| per component, |phi''| <= AMPLITUDE (2 pi / WAVELENGTH)^2, so by
    # sqrt(2) * 14^2 / 8 * 0.0096 = 0.33 px; the thin-plate spline does at least as well inside the hull,
    # and the fluid follows the spline (next assertion), so 0.4 px leaves room for the fluid's discretisation.
    assert float(err.max()) < 0.4
    spline = tps_interpolate(points[~held], _phi(points[~held]), points[inner])
    assert float((last - spline).norm(dim=-1).max()) < 0.1  # the fluid moves what nobody marked like the spline
    assert r.folded == 0
    assert jacobian_determinant(r.maps).min() > 0 and jacobian_determinant(r.maps_b).min() > 0


def test_natural_morph_has_no_seam_in_any_frame(known_deformation):
    _, _, r = known_deformation
    # phi's own second derivatives are at most sqrt(2) * 0.0096 px/px^2; resampling the maps adds about 0.07
    # (measured); the edge of a fluid box inside the picture (method="paper", margin=0.5: its box edge lies at
    # 12 px from the image edge here) measured 1.3 to 2.9 px/px^2. The bound sits between the two.
    for k in range(r.maps.shape[0]):
        for maps in (r.maps[k : k + 1], r.maps_b[k : k + 1]):
            assert float(torch.quantile(_seam(maps).flatten(), 0.999)) < 0.2, k


def test_paper_method_is_one_option_away(pair):
    # B's marks spread 1.2 times as far as A's and no pre-alignment absorbs it: the natural morph grows the
    # marked region (areas x 1.44); the paper's incompressible fluid keeps every area (it spreads the marks by
    # squeezing the fluid around them instead)
    a, b = pair
    centre = POINTS_A.mean(0)
    pb = (POINTS_A - centre) * 1.2 + centre
    kw = dict(frames=3, progress=False)
    natural = morph(a, b, POINTS_A, pb, settings=NaturalSettings(align=None), **kw)
    paper = morph(a, b, POINTS_A, pb, settings=PaperSettings(grid=24, steps=6, max_iter=60, align=None), **kw)
    middle = (slice(24, 40), slice(24, 40))
    assert float(jacobian_determinant(natural.maps_b[:1])[0][middle].mean()) > 1.3  # B read 1.2 x 1.2 wider
    det = jacobian_determinant(paper.maps[-1:])[0][middle]
    assert float((det - 1).abs().max()) < 0.1
    assert float(natural.error.mean()) < 0.3


def test_natural_morph_of_identical_inputs_is_constant(pair):
    a, _ = pair
    r = morph(a, a, POINTS_A, POINTS_A, frames=4, progress=False)
    for k in range(4):
        torch.testing.assert_close(r.frames[k], a, atol=1e-5, rtol=0)


def test_repeated_points_raise_naming_their_indices(pair):
    a, b = pair
    pa = POINTS_A.clone()
    pa[3] = pa[1]
    with pytest.raises(ValueError, match="points_a repeats points: indices 1 and 3"):
        morph(a, b, pa, POINTS_B, **KW)


def _swapped_lattice(gen: torch.Generator) -> tuple[torch.Tensor, ...]:
    """Two 64 x 64 pictures marked on a 3 x 3 lattice, B's marks shifted, and marks 0 and 1 (18 px apart) swapped
    between A and B: ``(a, b, pa, pb)``."""
    ys, xs = torch.meshgrid(torch.tensor([14.0, 32.0, 50.0]), torch.tensor([14.0, 32.0, 50.0]), indexing="ij")
    pa = torch.stack([xs, ys], -1).reshape(-1, 2)
    pb = pa + torch.tensor([1.0, 1.5])
    a, b = _blobs((64, 64), pa.tolist(), gen), _blobs((64, 64), pb.tolist(), gen)
    pb[[0, 1]] = pb[[1, 0]]
    return a, b, pa, pb


def test_crossing_marks_warn_and_show_in_the_fit_error(gen):
    # the morph lets one of two swapped marks go so as not to fold, and result.error says how far it ended from
    # the user's target, not from where it was let go
    a, b, pa, pb = _swapped_lattice(gen)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = morph(a, b, pa, pb, frames=3, **KW)
    crossing = [w for w in caught if "marks cross" in str(w.message)]
    assert len(crossing) == 1 and "0 and 1" in str(crossing[0].message)
    assert crossing[0].filename == __file__  # the warning points at the caller's line, not the library's
    torch.testing.assert_close(r.targets, pb.double(), atol=1e-9, rtol=0)  # the user's targets, as given
    missed = (r.error > LET_GO).nonzero()[:, 0].tolist()
    assert missed and set(missed) <= {0, 1}  # the swapped points, and only they, are not reached
    end = r.trajectories[-1]
    torch.testing.assert_close(r.error, (end - pb.double()).norm(dim=-1))  # measured against B's marks
    assert float(r.error[missed].min()) > 10  # let go by most of the 18 px they swap across
    assert r.let_go.tolist() == [i in missed for i in range(9)]  # the result names the marks it let go
    kept = r.met_error
    torch.testing.assert_close(kept, r.error[[i for i in range(9) if i not in missed]])
    said = r.error_summary()  # the marks met and those let go, apart
    met = f"mean point error {float(kept.mean()):.2f} px (max {float(kept.max()):.2f}) over the {9 - len(missed)} marks"
    assert said.startswith(met + " met; ")
    far = f"{float(r.error[missed].min()):.2f} px from its target" if len(missed) == 1 else "px from their targets"
    named = f"(point {missed[0]})" if len(missed) == 1 else f"(points {', '.join(map(str, missed))})"
    assert f"{len(missed)} let go so as not to fold {named}, " in said and said.endswith(far)  # which, by index
    assert float(kept.max()) <= LET_GO  # the rest are met


def test_a_morph_that_lets_no_mark_go_says_its_error_as_one_figure(pair):
    a, b = pair
    r = morph(a, b, POINTS_A, POINTS_B, frames=3, progress=False)
    assert not bool(r.let_go.any()) and r.let_go.shape == r.error.shape
    assert r.error_summary() == f"mean point error {float(r.error.mean()):.2f} px (max {float(r.error.max()):.2f})"
    assert r.message.endswith(r.error_summary(4))  # the fit's summary says the same


def test_points_the_library_placed_that_cross_are_not_the_users_order_to_check(gen):
    a, b, pa, pb = _swapped_lattice(gen)
    placed = FoundPoints(pa, pb, "faces", Note("face landmarks"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = morph(a, b, placed=placed, frames=3, **KW)
    texts = [str(w.message) for w in caught if "cross" in str(w.message)]
    assert len(texts) == 1 and "the points the faces matcher placed cross: points " in texts[0]
    assert "0 and 1" in texts[0] and "check their order" not in texts[0]
    assert [w.filename for w in caught if "cross" in str(w.message)] == [__file__]  # the caller's line
    missed = (r.error > LET_GO).nonzero()[:, 0].tolist()
    assert missed and set(missed) <= {0, 1}  # the crossing pair was let go, and only it


def test_placed_points_that_cross_but_are_met_say_nothing(pair):
    # a matcher's two points 0.4 px apart whose order flips between A and B (a face mesh's noise): the morph lets
    # one go so as not to fold, and it still ends within LET_GO of its target (0.78 px), so the user hears nothing
    # about an order nobody gave (1.5 px apart it ends 2.3 px off, and the morph says so)
    a, b = pair
    pa = torch.cat([POINTS_A, torch.tensor([[30.0, 30.0], [30.4, 30.0]])])
    pb = torch.cat([POINTS_B, torch.tensor([[30.9, 30.0], [30.5, 30.0]])])
    assert crossing_pairs(pa, pb).tolist() == [[5, 6]]  # the rule sees them cross
    placed = FoundPoints(pa, pb, "faces", Note("face landmarks"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = morph(a, b, placed=placed, frames=3, progress=False)
    assert [str(w.message) for w in caught] == []
    assert float(r.error.max()) <= LET_GO


def test_points_the_library_placed_twice_are_used_once_not_refused(pair):
    # a matcher that puts a point where an earlier one is: the library's doing, so the morph drops the repeat and
    # says so, instead of telling the user to mark each feature once
    a, b = pair
    pa = torch.cat([POINTS_A, POINTS_A[1:2]])
    pb = torch.cat([POINTS_B, POINTS_B[1:2] + 3.0])  # the same position in A only
    placed = FoundPoints(pa, pb, "features", Note("image features"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = morph(a, b, placed=placed, frames=3, progress=False)
    said = [str(w.message) for w in caught if "placed" in str(w.message)]
    assert said == [
        "the features matcher placed 1 point(s) where an earlier one already is (indices 5); the morph uses each "
        "position once"
    ]
    assert r.error.shape == (POINTS_A.shape[0],)
    given = morph(a, b, placed=FoundPoints(POINTS_A, POINTS_B, "features", Note("image features")), frames=3,
                  progress=False)  # fmt: skip
    torch.testing.assert_close(r.frames, given.frames, atol=1e-5, rtol=0)  # the same morph as without the repeat


def test_marks_that_swap_places_meet_halfway_and_are_morphed_without_a_pre_alignment(pair):
    # without a pre-alignment, swapped marks' straight paths share their midpoint: no spline interpolates both,
    # and the interpolating spline's singular system used to end the morph with an error about its centres
    a, b = pair
    pb = POINTS_A.clone()
    pb[[0, 4]] = pb[[4, 0]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the marks cross, and the maps fold: both expected
        r = morph(a, b, POINTS_A, pb, frames=3, progress=False, settings=NaturalSettings(align=None))
    assert torch.isfinite(r.frames).all()
    err = r.error
    assert float(err[[0, 4]].min()) > float(err[[1, 2, 3]].max())  # the swapped marks are the ones missed


def test_marks_in_a_shuffled_order_are_morphed_without_the_pre_alignment_and_say_so(gen, shuffled_marks):
    # marks of no common pose: the least-squares similarity shrinks towards a point, and B's marks taken back
    # through its inverse landed hundreds of pixels outside the picture, where the fluid blew up
    pa, pb = shuffled_marks  # a similarity explains 7% of their spread
    a = _blobs((64, 64), pa.tolist(), gen)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = morph(a, a.flip(-1), pa, pb, frames=3, progress=False, settings=NaturalSettings(max_iter=10))
    pose_warnings = [w for w in caught if "do not agree on a pose" in str(w.message)]
    assert len(pose_warnings) == 1 and "similarity pre-alignment" in str(pose_warnings[0].message)
    assert torch.isfinite(r.frames).all()
    assert float(r.trajectories.abs().max()) < 200  # every path stays near the 64 x 64 picture


def test_the_fold_warning_counts_pixels_once(pair, monkeypatch):
    a, b = pair
    morph_module = sys.modules["torchfluidwarp.morph.render"]  # where the frames are rendered
    real = morph_module.jacobian_determinant
    calls = []

    def folding(maps):  # pretend that exactly 3 pixels of A's map of the first frame fold (the first call)
        det = real(maps).clone()
        if not calls:
            calls.append(1)
            det.view(-1)[:3] = -1.0
        return det

    monkeypatch.setattr(morph_module, "jacobian_determinant", folding)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = morph(a, b, POINTS_A, POINTS_B, frames=3, progress=False)
        r.frames  # noqa: B018  (frames render on demand: the fold count comes with them)
    folds = [w for w in caught if "fold" in str(w.message)]
    assert len(folds) == 1
    assert "fold on 3 of" in str(folds[0].message)
    assert r.folded == pytest.approx(3 / (2 * 3 * 64 * 64))


def test_feather_is_an_argument_checked_by_name(pair):
    a, b = pair
    with pytest.raises(ValueError, match="feather"):
        morph(a, b, POINTS_A, POINTS_B, blending=Blending(feather=-1.0), **KW)
    # no band at all: where both images are read inside their edges the dissolve is the plain lerp
    r0 = morph(a, b, POINTS_A, POINTS_B, frames=3, blending=Blending(feather=0.0), **KW)
    assert torch.isfinite(r0.frames).all()


def test_frames_render_on_demand_and_agree_every_way(pair):
    a, b = pair
    r = morph(a, b, POINTS_A, POINTS_B, frames=5, **KW)
    streamed = torch.stack(list(r.iter_frames(chunk=2)))  # chunks that do not divide the count
    assert r._all is None  # streaming kept nothing
    torch.testing.assert_close(streamed, r.frames, atol=1e-6, rtol=0)
    for k in range(5):  # any t renders the frame at that time; the frames' times are k / (N - 1)
        torch.testing.assert_close(r.frame(k / 4), r.frames[k], atol=1e-6, rtol=0)
    torch.testing.assert_close(r.frame(0.0), a)
    torch.testing.assert_close(r.frame(1.0), b)
    middle = r.frame(0.5)
    torch.testing.assert_close(middle, r.frames[2], atol=1e-6, rtol=0)
    between = r.frame(0.6)  # a time between two frames differs from both
    assert float((between - r.frames[2]).abs().max()) > 1e-4 and float((between - r.frames[3]).abs().max()) > 1e-4
    with pytest.raises(ValueError, match=r"t must be in \[0, 1\], got 1.5"):
        r.frame(1.5)


def test_the_shape_can_lead_the_colour(pair):
    a, b = pair
    led = morph(
        a, b, POINTS_A, POINTS_B, frames=5, timing=Timing(motion="ease-out", blend="ease-in"),
        blending=Blending(feather=0.0), **KW,
    )  # fmt: skip
    plain = morph(a, b, POINTS_A, POINTS_B, frames=5, **KW)
    # at t = 1/4 the shape is 1 - (3/4)^2 = 7/16 of the way, the colour (1/4)^2 = 1/16
    steps = SETTINGS.steps
    torch.testing.assert_close(led.times, torch.tensor([0, 7 / 16, 3 / 4, 15 / 16, 1], dtype=torch.float64) * steps)
    k = 1
    weight = 1 / 16  # where both images are read inside (no feather band), the frame is the lerp with this weight
    want = torch.lerp(led.forward_frames[k], led.backward_frames[k], weight)
    centre = (slice(None), slice(16, 48), slice(16, 48))
    torch.testing.assert_close(led.frames[k][centre], want[centre], atol=1e-5, rtol=0)
    # the same t with the linear schedules: the shape is less far along, the colour further
    assert float(led.times[k]) > float(plain.times[k])
    # control points work as schedules too, and bad ones are refused by name
    points = morph(a, b, POINTS_A, POINTS_B, frames=3, timing=Timing(motion=[(0, 0), (0.5, 0.9), (1, 1)]), **KW)
    torch.testing.assert_close(points.times, torch.tensor([0, 0.9, 1], dtype=torch.float64) * steps)
    with pytest.raises(ValueError, match="motion's control points must run from"):
        morph(a, b, POINTS_A, POINTS_B, frames=3, timing=Timing(motion=[(0, 0), (0.5, 0.9)]), **KW)
    with pytest.raises(ValueError, match="blend must be one of"):
        morph(a, b, POINTS_A, POINTS_B, frames=3, timing=Timing(blend="bouncy"), **KW)


@pytest.mark.parametrize("inverse", ["flow", "paper"])
def test_a_box_over_map_pixels_reads_the_map_rasters_and_stays_close(pair, inverse, monkeypatch):
    # large pictures read each frame's maps from their rasters instead of maps resized to the fluid box (memory);
    # grid 8 makes a raster (4 points a cell) coarser than the box, so the two ways really differ
    render_module = importlib.import_module("torchfluidwarp.morph.render")  # the package's `morph` is a function
    a = pair[0]
    turn = torch.tensor([[math.cos(0.3), -math.sin(0.3)], [math.sin(0.3), math.cos(0.3)]])
    points_b = (POINTS_B - 32.0) @ turn.T * 1.2 + 32.0  # B turned and magnified: the frames read between pixels
    b = _blobs((64, 64), points_b.tolist(), torch.Generator().manual_seed(1))
    kw = {**_with(grid=8, inverse=inverse), "frames": 3}
    box = morph(a, b, POINTS_A, points_b, **kw)
    box_maps, box_folded = box.maps, box.folded  # rendered now: the result renders on demand
    monkeypatch.setattr(render_module, "MAP_PIXELS", 0)
    raster = morph(a, b, POINTS_A, points_b, **kw)
    torch.testing.assert_close(raster.error, box.error, rtol=0, atol=0)  # the same fit
    diff = (raster.maps - box_maps).abs()
    assert 0 < float(diff.max()) < 0.1  # pixels (0.03 here): another interpolation of the same maps
    assert float(diff.mean()) < 0.005
    assert raster.folded == box_folded == 0


def test_an_edge_that_travels_towards_the_walls_widens_the_margin_and_nothing_is_crushed(gen):
    # the marks stretch the middle of the picture 2.5 times across and squeeze it to half its height: no
    # similarity explains that, and the spline carries the stretch on to the picture's left and right edges,
    # about 24 px towards the walls of a 12-px margin (PAD of 96 px). The margin then shrinks by up to
    # pi / 2 * 24 / 12 = 3.1 times its width: the particles between the edge and the walls are crushed. With the
    # travel held beyond the edges and the margin widened to WALL_CLEARANCE times it, the margin keeps
    # 1 - pi / 2 / WALL_CLEARANCE = 0.1 of its area in the worst case. Measured, B's map keeps 0.73 of its area
    # at least, in every frame (0.13 before the margin widened).
    fit = importlib.import_module("torchfluidwarp.morph.fit")
    ys, xs = torch.meshgrid(torch.linspace(34.0, 62.0, 5), torch.linspace(34.0, 62.0, 5), indexing="ij")
    pa = torch.stack([xs, ys], -1).reshape(-1, 2)
    pb = (pa - 48.0) * torch.tensor([2.5, 0.5]) + 48.0
    a = _blobs((96, 96), pa.tolist(), gen)
    b = _blobs((96, 96), pb.tolist(), gen)
    r = morph(a, b, pa, pb, frames=7, settings=NaturalSettings(grid=32, steps=6), progress=False)
    x0, _, x1, _ = r.box
    assert -x0 > 2 * fit.PAD * 96 and x1 - 96 > 2 * fit.PAD * 96  # the walls moved out
    h, w = r.fit.warp.grid.shape  # and the cells kept their size: 120 px over 32 cells before
    assert abs((x1 - x0) / w - 120 / 32) < 0.1 and h == w
    assert r.folded == 0 and jacobian_determinant(r.maps).min() > 0
    assert jacobian_determinant(r.maps_b).min() > 3 * fit.MIN_AREA
    assert float(r.error.mean()) < 0.5  # and the marks are met
    # a viscosity field is given over the user's grid: the margin is kept, and the morph still runs
    field = torch.zeros(1, 1, 32, 32)
    kept = morph(a, b, pa, pb, frames=3, settings=NaturalSettings(grid=32, steps=6, viscosity=field), progress=False)
    assert kept.box == (-12, -12, 108, 108)  # PAD of 96 px on each side
    assert kept.fit.warp.grid.shape == (32, 32)


def test_a_result_saves_the_animation_its_frames_make(pair, tmp_path):
    a, b = pair
    r = morph(a, b, POINTS_A, POINTS_B, frames=5, **KW)
    saved = r.save(tmp_path / "m.gif")
    written = write_animation(tmp_path / "w.gif", r.frames, fps=15)  # the same frames, the default rate
    assert saved.read_bytes() == written.read_bytes()
    assert r.save(tmp_path / "m.gif", overwrite=True, fps=5, loop=2) == tmp_path / "m.gif"
    with Image.open(tmp_path / "m.gif") as gif:
        assert gif.n_frames == 5 and gif.info["duration"] == 200 and gif.info["loop"] == 2
