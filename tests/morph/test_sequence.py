"""Morphing through several images and averaging them (:mod:`torchfluidwarp.morph.sequence`, issue #23)."""

from __future__ import annotations

import re
import warnings

import pytest
import torch
from discs import aspect, crop, crop_offset, disc_marks, disc_picture

from torchfluidwarp.control.alignment import apply_alignment
from torchfluidwarp.errors import InputError
from torchfluidwarp.io import resize_image, write_animation
from torchfluidwarp.morph import NaturalSettings, average, morph_sequence
from torchfluidwarp.morph.morphing import placement

KW = dict(settings=NaturalSettings(grid=24, steps=4, max_iter=15), progress=False)
BASE = torch.tensor([[20.0, 20.0], [44.0, 20.0], [32.0, 44.0], [22.0, 40.0]])


def _blobs(points: torch.Tensor, size: int = 64) -> torch.Tensor:
    yy, xx = torch.meshgrid(
        torch.arange(size, dtype=torch.float32), torch.arange(size, dtype=torch.float32), indexing="ij"
    )
    img = torch.zeros(3, size, size)
    for i, (x, y) in enumerate(points.tolist()):
        img[i % 3] += torch.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 18.0)
    return img.clamp(0, 1)


def test_a_sequence_passes_through_every_image_at_one_speed():
    sets = [BASE, BASE + torch.tensor([2.0, 0.0]), BASE + torch.tensor([6.0, 0.0])]  # travels of 2 and 4 pixels
    images = [_blobs(p) for p in sets]
    seq = morph_sequence(images, sets, frames=19, **KW)
    assert len(seq) == 19 and seq.frames.shape == (19, 3, 64, 64)
    torch.testing.assert_close(seq.frame(0.0), images[0])
    torch.testing.assert_close(seq.frame(1.0), images[2])
    joint = seq.counts[0] - 1  # the middle image is shown exactly, once
    torch.testing.assert_close(seq.frames[joint], images[1])
    # the frames are shared out by travel, so the points move as fast before the joint as after it
    speeds = [2.0 / (seq.counts[0] - 1), 4.0 / (seq.counts[1] - 1)]
    assert abs(speeds[1] / speeds[0] - 1) < 0.15, (seq.counts, speeds)  # an even split would give 2.0
    streamed = torch.stack(list(seq.iter_frames(chunk=3)))
    torch.testing.assert_close(streamed, seq.frames)


def test_a_sequence_saves_the_animation_its_frames_make(tmp_path):
    sets = [BASE, BASE + torch.tensor([2.0, 0.0]), BASE + torch.tensor([6.0, 0.0])]
    seq = morph_sequence([_blobs(p) for p in sets], sets, frames=7, **KW)
    saved = seq.save(tmp_path / "seq.gif", fps=20)
    written = write_animation(tmp_path / "frames.gif", seq.frames, fps=20)
    assert saved == tmp_path / "seq.gif" and saved.read_bytes() == written.read_bytes()
    folder = seq.save(tmp_path / "seq/")
    assert sorted(q.name for q in folder.iterdir()) == [f"frame_{k:04d}.png" for k in range(7)]
    with pytest.raises(FileExistsError):
        seq.save(tmp_path / "seq.gif")  # overwrite=False, as write_animation


def test_sequence_arguments_are_checked():
    with pytest.raises(ValueError, match="one point set per image"):
        morph_sequence([_blobs(BASE)] * 3, [BASE] * 2, **KW)
    with pytest.raises(ValueError, match="at least 2 images"):
        morph_sequence([_blobs(BASE)], [BASE], **KW)
    with pytest.raises(TypeError, match="frames"):  # average renders each warp's end only: it takes no frames
        average([_blobs(BASE)] * 2, [BASE, BASE + 1], frames=5, **KW)
    with pytest.raises(ValueError, match=r"frames must be at least the number of images \(3: each is a frame"):
        morph_sequence([_blobs(BASE)] * 3, [BASE, BASE + 1, BASE + 2], frames=2, **KW)

    # an error of one segment's morph names the sequence's own arguments, not that morph's points_a and points_b
    row = torch.tensor([[10.0, 10.0], [20.0, 20.0], [30.0, 30.0], [40.0, 40.0]])
    with pytest.raises(InputError, match=r"^points\[1\] and points\[2\]: the 4 marks' midpoints") as caught:
        morph_sequence([_blobs(BASE)] * 3, [BASE, row, row + 1], frames=5, **KW)
    assert caught.value.argument == "points" and "points_a" not in str(caught.value)
    with pytest.raises(InputError, match=r"points\[0\] and points\[1\]: the 4 marks' midpoints"):
        morph_sequence([_blobs(BASE)] * 2, [row, row + 1], names=["a.png", "b.png"], frames=3, **KW)


def test_a_sequences_warnings_name_its_own_arguments():
    ys, xs = torch.meshgrid(torch.linspace(24.0, 36.0, 3), torch.linspace(24.0, 36.0, 3), indexing="ij")
    marks = torch.stack([xs, ys], -1).reshape(-1, 2)
    off = marks + torch.tensor([1.0, 0.5])
    off[4] = torch.tensor([62.0, 2.0])  # the middle mark put far off in the third picture
    pictures = [_blobs(p) for p in (marks, marks + 1, off)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        morph_sequence(pictures, [marks, marks + 1, off], frames=5, names=["a.png", "b.png", "c.png"], **KW)
    said = [str(w.message) for w in caught]
    assert any(re.match(r"point 4 \(\d+ px\) of points\[1\] and points\[2\] lies far", m) for m in said), said
    assert not any("points_a" in m or "points_b" in m or "image_a" in m for m in said), said


def test_an_average_passes_on_each_pictures_warnings():
    swapped = BASE[[1, 0, 2, 3]]  # the first two marks listed the other way round in the second picture
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        average([_blobs(BASE), _blobs(BASE)], [BASE, swapped], names=["a.png", "b.png"], **KW)
    said = [str(w.message) for w in caught]
    assert any(m.startswith("the marks cross: points 0 and 1") for m in said), said  # it was silenced
    assert any("tear apart between b.png and the mean shape" in m for m in said), said
    assert not any("points_a" in m or "image_a" in m or "A and B" in m for m in said), said
    # a warning that names the morph's points is said with the picture's points and the mean shape
    ys, xs = torch.meshgrid(torch.linspace(24.0, 40.0, 3), torch.linspace(24.0, 40.0, 3), indexing="ij")
    marks = torch.stack([xs, ys], -1).reshape(-1, 2)
    off = marks.clone()
    off[4] = torch.tensor([62.0, 2.0])  # the middle mark of the second picture put in a corner
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        average([_blobs(marks), _blobs(off)], [marks, off], **KW)
    said = [str(w.message) for w in caught]
    assert any(re.match(r"point 4 \(\d+ px\) of points\[[01]\] and the mean shape", m) for m in said), said


def test_a_segments_warnings_are_said_when_it_then_fails():
    flipped = BASE * torch.tensor([-1.0, 1.0]) + torch.tensor([63.0, 0.0])  # midpoints on the line x = 31.5
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(InputError, match=r"points\[0\] and points\[1\]: the 4 marks' midpoints"):
            morph_sequence([_blobs(BASE), _blobs(flipped)], [BASE, flipped], frames=3, **KW)
    assert any("the marks cross" in str(w.message) for w in caught), [str(w.message) for w in caught]


def test_an_average_says_itself_in_one_line():
    result = average([_blobs(BASE), _blobs(BASE + 1)], [BASE, BASE + 1], **KW)
    text = repr(result)
    assert text.startswith("AverageResult((3, 64, 64) mean of 2 images, 4 points, mean point error ")
    assert "\n" not in text and len(text) < 120


def test_the_average_of_two_shifted_images_sits_halfway_without_folds():
    left, right = BASE - torch.tensor([3.0, 0.0]), BASE + torch.tensor([3.0, 0.0])
    result = average([_blobs(left), _blobs(right)], [left, right], **KW)
    torch.testing.assert_close(result.points, BASE, atol=0.05, rtol=0)  # the mean shape
    assert result.folded == 0
    assert float(result.errors.max()) < 0.5  # each image's points reached the mean shape (pixels)
    # both warped images put their blobs on the mean shape, so the average is sharp there: it matches the blobs
    # drawn at the mean shape far better than the plain average of the two inputs does
    want = _blobs(BASE)
    plain = 0.5 * (_blobs(left) + _blobs(right))
    assert float((result.image - want).abs().mean()) < 0.5 * float((plain - want).abs().mean())


# ------------------------------------------------------------------ pictures of another aspect ratio (#31)
# a bright disc marked by its centre and four rim points (tests/morph/discs.py, as test_morph_pictures.py uses)


SQUARE = ((64, 64), (32.0, 30.0), 14.0)
TALL = ((160, 80), (40.0, 84.0), 20.0)  # 2:1; on the square canvas: scale 0.8, radius 16, its marks centred
FAST = dict(settings=NaturalSettings(grid=16, steps=4, max_iter=30), progress=False)


def test_a_later_picture_of_another_aspect_ratio_is_placed_on_the_first_canvas_not_stretched(gen):
    (size_a, centre_a, r_a), (size_b, centre_b, r_b) = SQUARE, TALL
    centre_c, r_c = (30.0, 32.0), 13.0
    images = [disc_picture(size_a, centre_a, r_a, [0.9] * 3, gen), disc_picture(size_b, centre_b, r_b, [0.9] * 3, gen)]
    images.append(disc_picture(size_a, centre_c, r_c, [0.9] * 3, gen))
    sets = [disc_marks(centre_a, r_a), disc_marks(centre_b, r_b), disc_marks(centre_c, r_c)]
    seq = morph_sequence(images, sets, frames=7, **FAST)
    frames = seq.frames
    assert frames.shape == (7, 3, 64, 64)  # every segment on the first picture's canvas
    joint = frames[seq.counts[0] - 1]  # where the tall picture is shown
    # it is the tall picture scaled by one factor, the smallest that covers the canvas, and cropped around its marks
    s = max(64 / 160, 64 / 80)
    h, w = round(160 * s), round(80 * s)
    top, left = -crop_offset(sets[1], s, 160, 64, 1), -crop_offset(sets[1], s, 80, 64, 0)  # centred on its marks
    scaled = crop(resize_image(images[1][None], (h, w))[0], top, left, (64, 64))
    torch.testing.assert_close(joint, scaled, atol=1e-4, rtol=0)
    # so its disc is a disc (resized to the canvas, it was an ellipse twice as wide as tall)
    assert aspect(joint) == pytest.approx(1.0, abs=0.04)
    for segment in seq.segments:  # and on the way to and from it
        assert aspect(segment.frame(0.5)) == pytest.approx(1.0, abs=0.06)
    # the segments meet the marks in the canvas's pixels, where the tall picture's are placed
    placed = apply_alignment(placement(size_b, size_a, sets[1])[0], sets[1].double())
    torch.testing.assert_close(seq.segments[0].points.double(), placed, atol=1.0, rtol=0)


def test_the_average_places_each_picture_on_the_first_canvas_without_stretching(gen):
    (size_a, centre_a, r_a), (size_b, centre_b, r_b) = SQUARE, TALL
    images = [disc_picture(size_a, centre_a, r_a, [0.9] * 3, gen), disc_picture(size_b, centre_b, r_b, [0.9] * 3, gen)]
    sets = [disc_marks(centre_a, r_a), disc_marks(centre_b, r_b)]
    result = average(images, sets, **FAST)
    assert result.warped.shape == (2, 3, 64, 64) and result.image.shape == (3, 64, 64)
    # the mean shape, in the first picture's pixels, of the square's marks and the tall one's as placed on the
    # canvas: the two rim patterns are similar, so it is their plain mean (centre (31.95, 32.55), radius 15)
    placed = apply_alignment(placement(size_b, size_a, sets[1])[0], sets[1].double()).float()
    torch.testing.assert_close(result.points, 0.5 * (sets[0] + placed), atol=1e-4, rtol=0)
    assert float(result.errors.max()) < 0.5  # each picture's marks reached it (pixels)
    # the tall picture's disc stays a disc, warped to the mean shape, and so does the average's
    assert aspect(result.warped[1]) == pytest.approx(1.0, abs=0.04)
    assert aspect(result.image) == pytest.approx(1.0, abs=0.04)


def test_without_points_each_images_face_landmarks_are_used():
    pytest.importorskip("mediapipe")
    from torchfluidwarp.correspond import detect_face_points
    from torchfluidwarp.data import load_sample

    a = torch.nn.functional.interpolate(load_sample("astronaut"), size=(160, 160), mode="bilinear", antialias=True)
    b = torch.roll(a, shifts=(4, -6), dims=(-2, -1))  # the same face 6 px left and 4 px down
    marks = [detect_face_points(a), detect_face_points(b)]
    torch.testing.assert_close(marks[1] - marks[0], torch.tensor([-6.0, 4.0]).expand_as(marks[0]), atol=1.0, rtol=0)
    found, given = average([a, b], **KW), average([a, b], marks, **KW)
    torch.testing.assert_close(found.image, given.image)
    torch.testing.assert_close(found.points, given.points)
    with pytest.raises(ValueError, match=r"no face found in images\[1\].*; give every picture's points \(points\)"):
        average([a, torch.full_like(a, 0.5)], **KW)
    # a sequence of found landmarks morphs as a two-image face morph does: the border pairs added per segment
    seq = morph_sequence([a, b], frames=3, **KW)
    torch.testing.assert_close(seq.points[0], marks[0])
    torch.testing.assert_close(seq.points[1], marks[1])
    # 63 landmarks and up to 8 border pairs (3 a side), less those whose partner the shift puts outside B
    assert 63 < seq.segments[0].error.shape[0] <= 63 + 8


def test_a_sequence_says_each_pictures_range_once_by_its_name():
    images = [_blobs(BASE) * 255, _blobs(BASE + 1) * 255, _blobs(BASE + 2) * 255]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        morph_sequence(images, [BASE, BASE + 1, BASE + 2], frames=5, **KW)
    said = [str(w.message).split("'s values")[0] for w in caught if "values span" in str(w.message)]
    assert said == ["images[0]", "images[1]", "images[2]"]
