import json

import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp import metrics
from torchfluidwarp.core.grid import rescale_points, scale_factor
from torchfluidwarp.morph import Blending, NaturalSettings, morph
from torchfluidwarp.warp import identity_map

SIZE = 48
POINTS = torch.tensor([[12.0, 14.0], [34.0, 12.0], [24.0, 30.0], [14.0, 36.0], [36.0, 36.0]])
HELD = torch.tensor([[20.0, 20.0], [30.0, 25.0], [18.0, 30.0]])
SHIFT = torch.tensor([5.0, 3.0])
KW = dict(settings=NaturalSettings(grid=16, steps=4, max_iter=30), progress=False)


@pytest.fixture
def image(gen):
    # smooth enough that neighbouring frames differ by motion, not by noise
    noise = torch.rand(1, 3, SIZE // 4, SIZE // 4, generator=gen)
    return F.interpolate(noise, size=(SIZE, SIZE), mode="bilinear", align_corners=False)[0]


def _affine_maps(R: torch.Tensor, t: torch.Tensor, s: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The exact morph's maps at ``s`` for B = A moved by ``p -> R p + t``: frame ``s`` moves A by
    ``F_s = (1 - s) I + s F``; ``(H, W, 2)`` into A and into B."""
    grid = identity_map((SIZE, SIZE), dtype=torch.float64)[0]
    Rs = (1 - s) * torch.eye(2, dtype=torch.float64) + s * R
    back = (grid - s * t) @ torch.linalg.inv(Rs).T
    return back, back @ R.T + t


R = torch.tensor([[1.1, 0.15], [-0.1, 0.95]], dtype=torch.float64)
T = torch.tensor([3.0, -2.0], dtype=torch.float64)


# ----------------------------------------------------------------------------------------------- pure measures


def test_locate_inverts_a_smooth_map(gen):
    grid = identity_map((SIZE, SIZE), dtype=torch.float64)[0]
    m = grid + 2.0 * torch.sin(grid.flip(-1) / 7)  # a smooth, fold-free warp
    y_true = 8 + 30 * torch.rand(10, 2, generator=gen, dtype=torch.float64)
    targets = metrics.read_map(m[None], y_true)
    y, ok = metrics.locate(m, targets)
    assert ok.all()
    torch.testing.assert_close(y, y_true, atol=1e-4, rtol=0)


def test_end_error_and_ghosting_of_an_exact_affine_morph(gen):
    pa = 16 + 16 * torch.rand(8, 2, generator=gen, dtype=torch.float64)
    pb = pa @ R.T + T
    last_a, _ = _affine_maps(R, T, 1.0)
    mid_a, mid_b = _affine_maps(R, T, 0.5)
    end, ok = metrics.end_error(last_a, pa, pb)
    assert ok.all() and end.max() < 1e-4
    ghost, ok = metrics.ghosting(mid_a, mid_b, pa, pb)
    assert ok.all() and ghost.max() < 1e-4
    # B's points moved by d: the end error is |d|; in the middle frame B's copies move by L d, L = R_s R^-1
    d = torch.tensor([3.0, -4.0], dtype=torch.float64)
    end, _ = metrics.end_error(last_a, pa, pb + d)
    torch.testing.assert_close(end, torch.full_like(end, 5.0), atol=1e-4, rtol=0)
    L = (torch.eye(2, dtype=torch.float64) + R) / 2 @ torch.linalg.inv(R)
    ghost, _ = metrics.ghosting(mid_a, mid_b, pa, pb + d)
    torch.testing.assert_close(ghost, torch.full_like(ghost, float((L @ d).norm())), atol=1e-4, rtol=0)


def test_a_point_carried_out_of_the_frame_is_not_located():
    m = identity_map((SIZE, SIZE), dtype=torch.float64)[0]
    _, ok = metrics.locate(m, torch.tensor([[10.0, 10.0], [500.0, 10.0]]))
    assert ok.tolist() == [True, False]


def test_folds_are_counted_on_a_map_built_to_fold():
    ident = identity_map((SIZE, SIZE))[0]
    folded = ident.clone()
    x = folded[..., 0]
    folded[..., 0] = torch.where(x <= 16, x, 32 - x)  # columns beyond 16 fold back over 0..16
    # central differences: column 16 has d x'/dx = 0 (det 0), columns 17.. have -1: all fold
    stack = torch.stack([ident, folded, ident])
    assert metrics.folded_pixels(stack).tolist() == [0, SIZE * (SIZE - 16), 0]
    mirrored = ident.clone()
    mirrored[..., 1] = SIZE - 1 - mirrored[..., 1]
    assert metrics.folded_pixels(mirrored).tolist() == [SIZE * SIZE]


def test_seam_figure_is_zero_for_affine_maps_and_reads_a_kink():
    a, _ = _affine_maps(R, T, 0.5)
    assert metrics.seam_figure(a) < 1e-9
    x = torch.arange(SIZE, dtype=torch.float64)
    kink = torch.where(x <= 20, x, 20 + 1.5 * (x - 20))
    m = torch.stack(torch.broadcast_tensors(kink.view(1, -1), x.view(-1, 1)), dim=-1)
    assert metrics.seam_figure(m) == pytest.approx(0.5, abs=1e-9)


def test_path_of_an_even_dissolve_has_no_variance_and_an_uneven_one_has(gen):
    a, b = torch.rand(2, 3, 16, 16, generator=gen, dtype=torch.float64)
    even = torch.stack([torch.lerp(a, b, s) for s in torch.linspace(0, 1, 9).tolist()])
    uneven = torch.stack([torch.lerp(a, b, s**2) for s in torch.linspace(0, 1, 9).tolist()])
    d_even = metrics.path_distances(even)
    d_uneven = metrics.path_distances(iter(uneven))  # any iterable of (C, H, W) frames
    whole = float((b - a).abs().mean())
    s_even, s_uneven = metrics.path_smoothness(d_even), metrics.path_smoothness(d_uneven)
    assert s_even["total"] == pytest.approx(whole, rel=1e-9)
    assert s_uneven["total"] == pytest.approx(whole, rel=1e-9)  # monotone: the same length, travelled unevenly
    assert s_even["variance"] < 1e-20 < s_uneven["variance"]
    assert metrics.path_distances(torch.stack([a, a, a]), kind="ssim").abs().max() < 1e-6
    assert (metrics.path_distances(even, kind="ssim") > 0).all()


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="kind"):
        metrics.path_distances(torch.zeros(2, 1, 4, 4), kind="lpips")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="targets"):
        metrics.locate(identity_map((8, 8)), torch.zeros(3, 3))
    with pytest.raises(ValueError, match="points_b"):
        metrics.end_error(identity_map((8, 8)), torch.zeros(3, 2), torch.zeros(2, 2))


# ----------------------------------------------------------------------------------------------- whole morphs


def test_a_morph_on_a_canvas_of_another_size_is_reported_in_the_frames_pixels(image):
    # frames at 36 x 36 of a 48 x 48 morph (Blending.size, the command line's --size or --max-size): the report
    # measures them, and still refuses a picture that is not the morph's, by name, before any frame is rendered
    r = morph(image, image, POINTS, POINTS, frames=3, blending=Blending(size=36), **KW)
    rep = metrics.morph_report(r, image, image, POINTS, POINTS, held_out=(HELD, HELD))
    assert rep["size"] == [36, 36] and rep["folds"]["total"] == 0 and rep["landmark_error_px"]["max"] < 1e-4
    for kind in ("marked", "held_out"):
        assert rep[kind]["end"]["located"] == rep[kind]["end"]["of"] and rep[kind]["end"]["max"] < 1e-3
    assert r.sizes == ((48, 48), (48, 48))
    for args, name in (((image[:, :24], image), "image_a"), ((image, image[:, :, :40]), "image_b")):
        with pytest.raises(ValueError, match=rf"{name} must be the morph's image ., of size \(48, 48\), got"):
            metrics.morph_report(r, *args, POINTS, POINTS)


def test_an_identity_morph_scores_zero(image):
    r = morph(image, image, POINTS, POINTS, frames=5, **KW)
    rep = metrics.morph_report(r, image, image, POINTS, POINTS, held_out=(HELD, HELD))
    assert rep["folds"]["total"] == 0 and rep["folds"]["a"] == [0] * 5
    assert rep["landmark_error_px"]["max"] < 1e-4
    for kind in ("marked", "held_out"):
        for figure in ("end", "ghost"):
            assert rep[kind][figure]["located"] == rep[kind][figure]["of"]
            assert rep[kind][figure]["max"] < 1e-4
    assert rep["path"]["total"] < 1e-5
    assert rep["seam"]["max"] < 1e-6
    again = json.loads(json.dumps(rep, allow_nan=False))
    assert again == rep


def test_held_out_points_that_follow_a_translation_land_on_their_targets(image):
    b = torch.roll(image, (3, 5), (1, 2))  # B is A moved by (5, 3)
    r = morph(image, b, POINTS, POINTS + SHIFT, frames=5, **KW)
    good = metrics.morph_report(r, image, b, POINTS, POINTS + SHIFT, held_out=(HELD, HELD + SHIFT))
    assert good["held_out"]["end"]["max"] < 0.05
    assert good["held_out"]["ghost"]["max"] < 0.05
    wrong = metrics.morph_report(r, image, b, POINTS, POINTS + SHIFT, held_out=(HELD, HELD + SHIFT + 4))
    assert wrong["held_out"]["end"]["mean"] == pytest.approx(4 * 2**0.5, abs=0.05)
    assert wrong["held_out"]["ghost"]["mean"] > 5


def test_points_of_a_larger_image_b_are_measured_in_the_frame(image):
    big = F.interpolate(image[None], scale_factor=2, mode="bilinear", align_corners=False)[0]
    scale = scale_factor((SIZE, SIZE), (2 * SIZE, 2 * SIZE), dtype=torch.float32)
    pb, hb = rescale_points(POINTS, scale), rescale_points(HELD, scale)
    r = morph(image, big, POINTS, pb, frames=3, **KW)
    rep = metrics.morph_report(r, image, big, POINTS, pb, held_out=(HELD, hb))
    assert rep["size"] == [SIZE, SIZE]
    assert rep["held_out"]["end"]["max"] < 0.05 and rep["marked"]["ghost"]["max"] < 0.05


def test_more_frames_make_shorter_steps_on_the_same_path(image):
    b = torch.roll(image, (3, 5), (1, 2))
    coarse = metrics.morph_path(morph(image, b, POINTS, POINTS + SHIFT, frames=5, **KW))
    fine = metrics.morph_path(morph(image, b, POINTS, POINTS + SHIFT, frames=9, **KW), chunk=3)
    assert coarse.shape == (4,) and fine.shape == (8,)
    assert fine.mean() < 0.7 * coarse.mean()
    # the frames at 0, 1/4, ... are the same: by the triangle inequality the finer path is no shorter
    assert fine.sum() >= coarse.sum() - 1e-6


def test_streamed_and_materialised_results_report_the_same(image):
    b = torch.roll(image, (3, 5), (1, 2))
    r = morph(image, b, POINTS, POINTS + SHIFT, frames=5, **KW)
    streamed = metrics.morph_report(r, image, b, POINTS, POINTS + SHIFT, chunk=2)
    folds_a, folds_b = metrics.morph_folds(r)
    r.materialize()
    assert metrics.morph_report(r, image, b, POINTS, POINTS + SHIFT) == streamed
    assert folds_a.tolist() == streamed["folds"]["a"] and folds_b.tolist() == streamed["folds"]["b"]
    torch.testing.assert_close(metrics.landmark_error(r.fit), r.fit.error[0].double())


def test_a_report_yields_its_frames_as_it_goes_and_measures_the_same(image):
    # a writer reading report_frames gets the frames the result streams, in order, and the same report
    b = torch.roll(image, (3, 5), (1, 2))
    r = morph(image, b, POINTS, POINTS + SHIFT, frames=5, **KW)
    alone = metrics.morph_report(r, image, b, POINTS, POINTS + SHIFT, chunk=2)
    got: list[dict] = []

    def writer():
        report = yield from metrics.report_frames(r, image, b, POINTS, POINTS + SHIFT, chunk=2)
        got.append(report)

    frames = list(writer())
    assert got == [alone]
    want = list(r.iter_frames())
    assert len(frames) == len(want) == 5
    for frame, expected in zip(frames, want):
        assert frame.dtype == expected.dtype
        torch.testing.assert_close(frame, expected, rtol=0, atol=0)
    with pytest.raises(ValueError, match="held_out"):  # checked before any frame is rendered
        metrics.report_frames(r, image, b, POINTS, POINTS + SHIFT, held_out=(HELD, HELD[:1]))


def _blobs(centers: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """``(3, 64, 64)``: a Gaussian blob (3 px) at each of ``centers`` ``(M, 2)``, in turn on each channel, on faint
    noise."""
    ys, xs = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
    img = 0.1 * torch.rand(3, 64, 64, generator=gen)
    for k, (x, y) in enumerate(centers.tolist()):
        img[k % 3] += torch.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * 3.0**2))
    return img.clamp(0, 1)


def test_the_report_gives_the_landmark_error_over_the_marks_met_and_names_those_let_go(gen):
    # a 3 x 3 lattice of blobs whose first two marks swap places in B: the morph lets one or both go so as not to
    # fold, and the report's mean and max are over the rest, as result.met_error is; every mark keeps its figure
    ys, xs = torch.meshgrid(torch.tensor([14.0, 32.0, 50.0]), torch.tensor([14.0, 32.0, 50.0]), indexing="ij")
    pa = torch.stack([xs, ys], -1).reshape(-1, 2)
    pb = pa + torch.tensor([1.0, 1.5])
    a, b = _blobs(pa, gen), _blobs(pb, gen)
    pb[[0, 1]] = pb[[1, 0]]  # after drawing B: its marks 0 and 1 now name each other's blob
    with pytest.warns(RuntimeWarning, match="marks cross"):
        r = morph(a, b, pa, pb, frames=3, **KW)
    rep = metrics.morph_report(r, a, b, pa, pb)["landmark_error_px"]
    gone = r.let_go.nonzero()[:, 0].tolist()
    assert gone and set(gone) <= {0, 1} and rep["let_go"] == gone
    assert rep["met"] == 9 - len(gone)
    assert rep["mean"] == pytest.approx(float(r.met_error.mean()), abs=1e-9)
    assert rep["max"] == pytest.approx(float(r.met_error.max()), abs=1e-9)
    assert rep["max"] < min(rep["per_point"][i] for i in gone)  # the marks let go end farther than any met
    assert rep["per_point"] == pytest.approx(r.error.tolist(), abs=1e-9)
    json.dumps(rep)  # JSON-ready
