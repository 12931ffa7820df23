"""refine_points: on a textured image warped by a known smooth map, the pairs that the pixels add land where
the map says, the fitted map does not fold, and the given pairs come back unchanged."""

from __future__ import annotations

import math
import warnings

import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.correspond import refine_points
from torchfluidwarp.correspond.refine import extra_points
from torchfluidwarp.data import load_sample
from torchfluidwarp.warp.frames import identity_map, warp_image

S = 96


def phi(y: torch.Tensor) -> torch.Tensor:
    """B(y) = A(phi(y)): sine displacements of 2.4 pixels' amplitude (a fortieth of the side)."""
    u = y / (S - 1) * 2 * math.pi
    d = torch.stack(
        [torch.sin(u[..., 1]) * torch.cos(0.5 * u[..., 0]), torch.sin(u[..., 0]) * torch.cos(0.5 * u[..., 1])], -1
    )
    return y + S / 40 * d


@pytest.fixture(scope="module")
def pair() -> tuple[torch.Tensor, torch.Tensor]:
    a = F.interpolate(load_sample("astronaut"), size=(S, S), mode="bilinear", antialias=True)
    b = warp_image(a.double(), phi(identity_map((S, S), dtype=torch.float64))).float()
    return a, b


def test_pixels_alone_recover_a_known_smooth_map(pair: tuple[torch.Tensor, torch.Tensor]):
    a, b = pair
    none = torch.zeros(0, 2)
    pa, pb, fit = refine_points(a, b, none, none, extra=5)
    assert pa.shape == pb.shape == (25, 2)
    error = (phi(pb.double()) - pa.double()).norm(dim=-1)
    before = (phi(pa.double()) - pa.double()).norm(dim=-1)  # the identity's error at the same points
    # measured at 128 px: median 0.09 px against 1.6 px for the identity; the bound leaves room for 96 px
    assert float(error.median()) < 0.4 * float(before.median())
    assert float(error.median()) < 0.5 and float(error.max()) < 1.5
    assert float(fit.min_det.min()) > 0  # no folds


def test_anchors_come_back_unchanged_and_b_keeps_its_own_pixels(pair: tuple[torch.Tensor, torch.Tensor]):
    a, b = pair
    big_b = F.interpolate(b, scale_factor=2.0, mode="bilinear", align_corners=False)  # B at twice A's size
    anchors_a = torch.tensor([[30.0, 30.0], [65.0, 40.0], [48.0, 70.0]])
    anchors_b = 2 * anchors_a + 0.5  # where B (at twice the size) shows them if the map were the identity
    pa, pb, _ = refine_points(a, big_b, anchors_a, anchors_b, extra=4, levels=None, max_iter=20)
    assert torch.equal(pa[:3], anchors_a) and torch.equal(pb[:3], anchors_b)
    assert bool((torch.cdist(pa[3:], anchors_a) >= 0.5 * S / 4).all())  # no extra point crowds an anchor
    in_b = (pb[3:] + 0.5) / 2 - 0.5  # back to A's size
    assert float((phi(in_b.double()) - pa[3:].double()).norm(dim=-1).median()) < 1.0


def test_extra_points_is_a_lattice_less_the_points_it_avoids():
    lattice = extra_points((40, 80), 4, torch.zeros(0, 2), 5.0)
    assert lattice.shape == (16, 2)
    assert sorted(set(lattice[:, 0].tolist())) == [9.5, 29.5, 49.5, 69.5]
    assert sorted(set(lattice[:, 1].tolist())) == [4.5, 14.5, 24.5, 34.5]
    fewer = extra_points((40, 80), 4, torch.tensor([[10.0, 5.0]]), 5.0)
    assert len(fewer) == 15


def test_bad_points_are_named(pair: tuple[torch.Tensor, torch.Tensor]):
    a, b = pair
    with pytest.raises(ValueError, match=r"points_b must have shape \(2, 2\)"):
        refine_points(a, b, torch.zeros(2, 2), torch.zeros(3, 2))
    with pytest.raises(ValueError, match="extra"):
        refine_points(a, b, torch.zeros(0, 2), torch.zeros(0, 2), extra=-1)


def test_pixels_alone_find_a_shift_larger_than_the_flow_reaches(pair: tuple[torch.Tensor, torch.Tensor]):
    # B = A moved 15 px to the left (a seventh of the side, as the stereo motorcycle's views are apart), then the
    # smooth map: with no pairs to anchor it, the flow alone stops short of such a shift; the best plain shift
    # first, the flow then fitting what is left, places the points where the map says, without a warning
    a, _ = pair
    shift = torch.tensor([15.0, 0.0], dtype=torch.float64)
    b = warp_image(a.double(), phi(identity_map((S, S), dtype=torch.float64)) + shift).float()
    none = torch.zeros(0, 2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no shift or fold warning from the flow inside
        pa, pb, fit = refine_points(a, b, none, none, extra=5)
    seen = pa[:, 0] > 15 + S / 40  # A's points that B shows (its left 15 px leave B's frame)
    error = (phi(pb.double()) + shift - pa.double()).norm(dim=-1)[seen]
    assert float(error.median()) < 0.5 and float(error.max()) < 1.5  # without the shift first: median 10.9 px
    assert float(fit.min_det.min()) > 0


def test_pictures_no_shift_relates_are_not_moved_out_of_the_way():
    # a coffee cup against a cat: the best plain shift moves most of B out of the frame for little (0.77 of the
    # loss, 64% out at full size); used, it threw the points 57 px off where the pictures lie (median, at a
    # quarter size); left out, the flow alone keeps them 13 px off, about where they are in A
    skimage_data = pytest.importorskip("skimage.data")

    def picture(array):
        x = torch.from_numpy(array).permute(2, 0, 1).float()[None] / 255
        return F.interpolate(x, scale_factor=0.25, mode="bilinear", antialias=True)

    a, b = picture(skimage_data.coffee()), picture(skimage_data.chelsea())  # (100, 150) and (75, 112)
    none = torch.zeros(0, 2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the flow between unrelated pictures folds, and says so
        pa, pb, _ = refine_points(a, b, none, none, extra=5)
    scale = torch.tensor([b.shape[-1] / a.shape[-1], b.shape[-2] / a.shape[-2]])
    where_a_is = (pa + 0.5) * scale - 0.5  # A's points at B's size
    assert float((pb - where_a_is).norm(dim=-1).median()) < 0.2 * b.shape[-1]
