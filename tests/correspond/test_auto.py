"""auto_points: faces when both images show one, features otherwise (the pixels where too few match), with border
anchors; border_points."""

from __future__ import annotations

import sys

import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.control.alignment import apply_alignment, estimate_alignment, robust_alignment
from torchfluidwarp.control.images import FoldWarning
from torchfluidwarp.correspond import (
    FACE_MESH_INDICES,
    MatchNotice,
    auto,
    auto_points,
    border_points,
    detect_face_points,
)
from torchfluidwarp.correspond.auto import BORDER_SLACK, TRUSTED_MATCHES, border_pairs, find_points, usable_pairs
from torchfluidwarp.data import load_sample
from torchfluidwarp.morph.marks import crossing_pairs
from torchfluidwarp.warp.frames import identity_map, warp_image


def shifted_and_scaled(y: torch.Tensor) -> torch.Tensor:
    """The known map of these tests: scale by 1.05 about (128, 128), then shift by (5, -3) pixels."""
    return 128 + 1.05 * (y - 128) + torch.tensor([5.0, -3.0], dtype=y.dtype)


def warped(image: torch.Tensor) -> torch.Tensor:
    size = (image.shape[-2], image.shape[-1])
    return warp_image(image, shifted_and_scaled(identity_map(size)))


def half(image: torch.Tensor) -> torch.Tensor:
    return F.interpolate(image, scale_factor=0.5, mode="bilinear", antialias=True)


def test_border_points_go_round_the_frame_with_pixel_centres_at_integers():
    points = border_points((30, 50))
    assert points.shape == (8, 2)
    corners = {(0.0, 0.0), (49.0, 0.0), (49.0, 29.0), (0.0, 29.0)}
    assert corners <= set(map(tuple, points.tolist()))
    on_edge = (points[:, 0] == 0) | (points[:, 0] == 49) | (points[:, 1] == 0) | (points[:, 1] == 29)
    assert bool(on_edge.all())
    assert border_points((30, 50), per_side=2).shape == (4, 2)
    assert border_points((30, 50), per_side=5, dtype=torch.float64).dtype == torch.float64
    with pytest.raises(ValueError, match="per_side"):
        border_points((30, 50), per_side=1)


def test_border_pairs_keep_frames_framed_alike_on_each_other():
    # two crops of one scene, 6 px apart and 2% apart in scale: the frames correspond, as a morph tool assumes
    gen = torch.Generator().manual_seed(3)
    pa = 60 + 130 * torch.rand(20, 2, generator=gen)
    pb = 128 + 1.02 * (pa - 128) + torch.tensor([6.0, -4.0])
    ea, eb = border_pairs(pa, pb, (256, 256), (256, 256))
    assert torch.equal(ea, border_points((256, 256))) and torch.equal(eb, border_points((256, 256)))


def test_border_pairs_follow_the_pose_where_the_frames_do_not_correspond():
    # a face that fills a tall portrait A, against the same face at the left edge of a wide group photograph B
    # at 0.4 of its size: B's own corners would pin A's frame onto B's, across the face (the old behaviour)
    gen = torch.Generator().manual_seed(4)
    pa = torch.tensor([400.0, 500.0]) + 250 * torch.rand(30, 2, generator=gen)
    pb = 0.4 * pa + torch.tensor([-100.0, 80.0])  # the face at x 60-160 of B's 1280 px
    size_a, size_b = (2000, 900), (880, 1280)
    ea, eb = border_pairs(pa, pb, size_a, size_b)
    pose = estimate_alignment(pa.double(), pb.double(), "similarity")
    posed = apply_alignment(pose, ea.double()).float()
    own = border_points(size_b)
    far = (posed - own).norm(dim=-1) > BORDER_SLACK * 1280
    assert int(far.sum()) == 6  # only the bottom-left and left-middle ones agree with the pose here
    # those keep B's own; the others go where the pose sends A's
    torch.testing.assert_close(eb, torch.where(far[:, None], posed, own), atol=1e-3, rtol=0)
    # and no border pair crosses a matched one (with B's own border, most of them did)
    kept = usable_pairs(torch.cat([pa, ea]), torch.cat([pb, eb]), size_a, size_b)
    both_a, both_b = torch.cat([pa, ea])[kept], torch.cat([pb, eb])[kept]
    assert crossing_pairs(both_a, both_b).shape[0] == 0
    # with B's own border instead, the border pairs lie far from the pose the face's points agree on (the least
    # squares through them all explains under half of B's spread); with the border pairs, only the two that kept
    # B's own (near the pose, within the slack) may
    moved = {30 + i for i in far.nonzero()[:, 0].tolist()}
    _, agree = robust_alignment(torch.cat([pa, ea]), torch.cat([pb, own]))
    flagged = set((~agree).nonzero()[:, 0].tolist())
    assert flagged >= moved and min(flagged) >= 30, flagged
    _, agree = robust_alignment(torch.cat([pa, ea]), torch.cat([pb, eb]))
    assert not set((~agree).nonzero()[:, 0].tolist()) & moved


def test_two_faces_give_the_face_landmarks_and_the_border():
    a = load_sample("astronaut")
    b = warped(a)
    pa, pb = auto_points(a, b)
    assert pa.shape == pb.shape == (len(FACE_MESH_INDICES) + 8, 2)
    assert torch.equal(pa[:-8], detect_face_points(a))
    assert torch.equal(pa[-8:], border_points((512, 512))) and torch.equal(pb[-8:], pa[-8:])
    # B(y) = A(phi(y)): the face points of B map onto A's (the mesh is a network's estimate: a few pixels)
    error = (shifted_and_scaled(pb[:-8]) - pa[:-8]).norm(dim=-1)
    assert float(error.median()) < 3.0


def test_no_face_falls_back_to_matched_features():
    a = half(load_sample("cat"))
    b = warped(a)
    with pytest.warns(MatchNotice, match=r"no face found in image_a \(256 x 256 pixels\); matched image features"):
        pa, pb = auto_points(a, b, border=None, max_points=40)
    assert 20 <= len(pa) <= 40
    error = (shifted_and_scaled(pb) - pa).norm(dim=-1)
    assert float(error.median()) < 1.5


def test_without_mediapipe_auto_uses_features(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setitem(sys.modules, "mediapipe", None)
    a = half(load_sample("astronaut"))  # a face, but no detector
    b = a[..., 4:, 6:]  # b = a - (6, 4)
    with pytest.warns(MatchNotice, match=r"no face detector \(.*pip install .*\); matched image features instead"):
        pa, pb = auto_points(a, b, border=2)
    assert len(pa) > 20 + 4 and len(pa) != len(FACE_MESH_INDICES) + 4
    assert float((pa[:-4] - pb[:-4] - torch.tensor([6.0, 4.0])).norm(dim=-1).median()) < 0.5
    assert torch.equal(pb[-4:], border_points((252, 250), per_side=2))  # B's own frame


def test_nothing_to_match_is_a_value_error_naming_both_images():
    blank = torch.full((3, 48, 48), 0.5)
    with pytest.raises(ValueError, match=r"found 0 matching features between a\.png and b\.png"):
        auto_points(blank, blank, match="features", names=("a.png", "b.png"))
    with pytest.raises(ValueError, match="match must be 'auto', 'faces', 'features' or 'pixels', got 'optical'"):
        auto_points(blank, blank, match="optical")  # type: ignore[arg-type]


def test_usable_pairs_drops_points_outside_and_repeats():
    pa = torch.tensor([[1.0, 1.0], [5.0, 5.0], [-0.6, 3.0], [5.3, 5.2], [8.0, 2.0], [9.0, 9.0]])
    pb = torch.tensor([[2.0, 2.0], [6.0, 6.0], [1.0, 1.0], [20.0, 20.0], [8.0, 2.0], [9.5, 9.5]])
    keep = usable_pairs(pa, pb, (10, 10), (10, 10))
    # 2: A's point left of the image; 3: within a pixel of pair 1 in A; 5: B's (9.5, 9.5) is on the edge of a
    # 10 x 10 image (kept) and outside a 9 x 9 one (dropped)
    assert keep.tolist() == [True, True, False, False, True, True]
    assert usable_pairs(pa, pb, (10, 10), (9, 9)).tolist() == [True, True, False, False, True, False]


def test_pixels_place_a_lattice_where_no_feature_is_needed():
    a = F.interpolate(load_sample("cat"), size=(64, 64), mode="bilinear", antialias=True)
    b = warped(a)  # scale 1.05 about (128, 128), shift (5, -3): here, a shift of about -1.4 and -9.4 pixels
    pa, pb = auto_points(a, b, match="pixels", pixels=4, border=None)
    # B is first moved back by its best plain shift (mostly vertical here), whose replicated edge then fills its
    # bottom rows: a lattice point there may be carried out of B, and is dropped
    assert pa.shape == pb.shape and 15 <= len(pa) <= 16
    # the cat's fur at 64 px: the fitted flow places the lattice within a few tenths of a pixel of the map
    assert float((shifted_and_scaled(pb) - pa).norm(dim=-1).median()) < 0.5


def test_the_pixels_place_a_large_pairs_lattice_on_shrunk_copies_in_each_pictures_own_pixels(monkeypatch):
    # the flow is fitted to copies shrunk to PIXELS_SIDE (here 32 of a 64-px pair): the points come back in each
    # picture's own pixels, spread over A and following the known map within about a pixel of the full size
    a = F.interpolate(load_sample("cat"), size=(64, 64), mode="bilinear", antialias=True)
    b = warped(a)
    full_a, full_b = auto_points(a, b, match="pixels", pixels=4, border=None)
    monkeypatch.setattr(auto, "PIXELS_SIDE", 32)
    pa, pb = auto_points(a, b, match="pixels", pixels=4, border=None)
    assert len(pa) >= 12 and float(pa.max()) > 40  # A's pixels, not the 32-px copy's
    assert float((shifted_and_scaled(pb) - pa).norm(dim=-1).median()) < 1.0
    assert float((shifted_and_scaled(full_b) - full_a).norm(dim=-1).median()) < 0.5  # at full size, closer


def test_the_pixels_matcher_says_in_its_own_terms_that_its_flow_folds(recwarn):
    # two unrelated smooth pictures: the flow that places the lattice crushes part of A onto itself (min det < 0).
    # That flow only places points, so fit_images' advice (raise its regularization, which a matcher's caller
    # cannot reach) is not passed on; the matcher's note says it, and is notable, so that morph() warns with it
    gen = torch.Generator().manual_seed(0)
    a, b = (
        F.interpolate(torch.rand(1, 3, 8, 8, generator=gen), size=(48, 48), mode="bicubic").clamp(0, 1) for _ in "ab"
    )
    found = find_points(a, b, match="pixels", pixels=4, border=None)
    assert found.matcher == "pixels" and 3 <= len(found.points_a) <= 16  # those the flow pushed out are dropped
    assert found.reason.notable and "that flow folds in places" in found.reason.message
    assert not [w for w in recwarn if issubclass(w.category, FoldWarning)]
    # a pair the flow relates without a fold: the plain note, not notable
    cat = F.interpolate(load_sample("cat"), size=(64, 64), mode="bilinear", antialias=True)
    plain = find_points(cat, warped(cat), match="pixels", pixels=4, border=None)
    assert not plain.reason.notable and "folds" not in plain.reason.message


def test_pictures_too_small_for_features_are_refused_with_their_size_and_the_way_out():
    # kornia's SIFT pads its scale pyramid past a picture under 32 px a side and raised a bare RuntimeError from
    # inside torch; the features matcher now finds nothing there, and the refusal says why and what to do
    a = F.interpolate(load_sample("cat"), size=(24, 40), mode="bilinear", antialias=True)
    with pytest.raises(ValueError) as caught:
        find_points(a, a, match="features", border=None)
    message = str(caught.value)
    assert "found 0 matching features" in message and "needs 32 px on each side" in message
    assert "image_a is 40 x 24 px and image_b is 40 x 24 px" in message and "match='pixels'" in message
    found = find_points(a, a, match="pixels", pixels=3, border=None)  # the way out it names works
    assert len(found.points_a) == len(found.points_b) >= 3


def test_unrelated_pictures_are_placed_by_the_pixels_not_by_chance_features(monkeypatch: pytest.MonkeyPatch):
    # a person against a cat matches 2 features by chance at 256 px; a morph on them would twist the picture. The
    # automatic mode lets the pixels place the points, says so, and warns; asked for features, it refuses 2
    monkeypatch.setitem(sys.modules, "mediapipe", None)  # the same path with or without the faces extra
    person, cat = half(load_sample("astronaut")), half(load_sample("cat"))
    found = find_points(person, cat, names=("person.png", "cat.png"), pixels=4, border=None)
    assert found.matcher == "pixels" and found.reason.notable
    text = found.reason.explain({"match": "--match"})
    assert text.startswith("no face detector (") and "image features match between person.png and cat.png" in text
    assert "(chance level): placed " in text and "lattice of 4 x 4" in text and len(text) < 340
    assert found.reason.hint is None  # fewer than 3: nothing to fall back on
    assert len(found.points_a) == len(found.points_b) >= 3
    with pytest.warns(MatchNotice, match=r"image features match between image_a and image_b \(chance level\)"):
        auto_points(person, cat, pixels=4, border=None)
    with pytest.raises(ValueError, match=r"between image_a and image_b \(need 3 or more\)"):
        find_points(person, cat, match="features", border=None)


def test_a_few_features_are_trusted_only_when_asked_for(monkeypatch: pytest.MonkeyPatch):
    # 5 pairs (3 <= 5 < TRUSTED_MATCHES): the automatic mode places points with the pixels and names the way
    # back to the 5; match="features" keeps them with a notable note that names the pixels
    monkeypatch.setitem(sys.modules, "mediapipe", None)
    five = torch.tensor([[10.0, 10.0], [50.0, 12.0], [30.0, 40.0], [12.0, 50.0], [52.0, 52.0]])
    monkeypatch.setattr(auto, "match_features", lambda a, b, max_points: (five, five + 2))
    assert 3 <= len(five) < TRUSTED_MATCHES
    cat = F.interpolate(load_sample("cat"), size=(64, 64), mode="bilinear", antialias=True)
    found = find_points(cat, warped(cat), pixels=4, border=None)
    assert found.matcher == "pixels" and found.reason.notable
    assert str(found.reason).endswith("use match='features' to morph on those 5")
    assert found.reason.explain({"match": "--match"}).endswith("use --match features to morph on those 5")
    # the lattice follows the map, not the 5 pairs' shift of (2, 2)
    assert float((shifted_and_scaled(found.points_b) - found.points_a).norm(dim=-1).median()) < 0.5
    asked = find_points(cat, warped(cat), match="features", border=None)
    assert asked.matcher == "features" and torch.equal(asked.points_a, five) and asked.reason.notable
    assert str(asked.reason).startswith("matched image features (5 pairs), as asked; unrelated pictures")
    assert str(asked.reason).endswith("match='pixels' places points that follow the pixels")
