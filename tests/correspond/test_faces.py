"""Face landmarks from mediapipe's face mesh: on the bundled astronaut against its hand marks, the pixel
convention under a 2x upsampling, several faces, no face, and the message without the extra."""

from __future__ import annotations

import sys
import warnings

import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.correspond import FACE_LANDMARKS, FACE_MESH_INDICES, auto_points, detect_face_points
from torchfluidwarp.data import POINT_LABELS, load_sample, load_sample_points

# hand-marked label -> the mesh landmark of the same feature (all of them in FACE_MESH_INDICES)
SAME_FEATURE = {
    "left eye, outer corner": 33,
    "left eye, inner corner": 133,
    "right eye, inner corner": 362,
    "right eye, outer corner": 263,
    "left mouth corner": 61,
    "upper lip, centre": 0,
    "right mouth corner": 291,
    "lower lip, centre": 17,
    "chin": 152,
}


@pytest.fixture(scope="module")
def astronaut() -> torch.Tensor:
    return load_sample("astronaut")


@pytest.fixture(scope="module")
def two_faces(astronaut: torch.Tensor) -> torch.Tensor:
    """``(1, 3, 256, 512)``: the astronaut's head at 256 px on the left, at 160 px on the right."""
    crop = astronaut[..., 0:256, 96:352]
    canvas = torch.full((1, 3, 256, 512), 0.5)
    canvas[..., :, :256] = crop
    canvas[..., 48:208, 304:464] = F.interpolate(crop, size=(160, 160), mode="bilinear", antialias=True)
    return canvas


def test_the_subset_is_63_distinct_mesh_points():
    assert len(FACE_MESH_INDICES) == len(set(FACE_MESH_INDICES)) == 63
    assert all(0 <= i < 468 for i in FACE_MESH_INDICES)
    assert set(FACE_LANDMARKS) == {"outline", "brows", "eyes", "nose", "lips"}
    assert set(SAME_FEATURE.values()) <= set(FACE_MESH_INDICES)


def test_the_astronaut_landmarks_land_on_her_hand_marks(astronaut: torch.Tensor):
    points = detect_face_points(astronaut, name="astronaut.png")
    assert points.shape == (63, 2) and points.dtype == astronaut.dtype
    assert bool((points >= 0).all() and (points <= 511).all())
    hand = load_sample_points("astronaut")
    errors = torch.stack(
        [
            (points[FACE_MESH_INDICES.index(mesh)] - hand[POINT_LABELS.index(label)]).norm()
            for label, mesh in SAME_FEATURE.items()
        ]
    )
    # measured: 0.8 to 3.7 px (the face is about 80 px wide; hand marks are whole pixels)
    assert float(errors.max()) < 5.0
    assert float(errors.median()) < 3.0


def test_the_points_follow_the_pixel_convention_under_upsampling(astronaut: torch.Tensor):
    big = F.interpolate(astronaut, scale_factor=2.0, mode="bilinear", align_corners=False)
    small, large = detect_face_points(astronaut), detect_face_points(big)
    # pixel centres at integers: x in the small image is 2 x + 0.5 in the large one
    error = (large - (2 * small + 0.5)).norm(dim=-1)
    assert float(error.median()) < 2.0


def test_a_float64_channel_first_image_gives_float64_points(astronaut: torch.Tensor):
    points = detect_face_points(astronaut[0].double())
    assert points.dtype == torch.float64 and points.shape == (63, 2)


def test_several_faces_warn_and_face_index_picks_by_size(two_faces: torch.Tensor):
    with pytest.warns(UserWarning, match=r"found 2 faces in two\.png.*face_index"):
        largest = detect_face_points(two_faces, name="two.png")
    assert float(largest[:, 0].mean()) < 256  # the big head is on the left
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a chosen face warns about nothing
        smaller = detect_face_points(two_faces, face_index=1, name="two.png")
        assert torch.equal(detect_face_points(two_faces, face_index=0), largest)
    assert float(smaller[:, 0].mean()) > 256
    span = lambda p: float((p.amax(0) - p.amin(0))[0])  # noqa: E731
    assert span(smaller) == pytest.approx(span(largest) * 160 / 256, rel=0.1)
    with pytest.raises(ValueError, match=r"face_index=2, but two\.png has 2 face"):
        detect_face_points(two_faces, face_index=2, name="two.png")


@pytest.mark.parametrize("image", ["blank", "cat"])
def test_no_face_is_a_value_error_naming_the_image(image: str):
    picture = torch.full((3, 64, 96), 0.7) if image == "blank" else load_sample("cat")
    with pytest.raises(ValueError, match=rf"no face found in {image}\.png"):
        detect_face_points(picture, name=f"{image}.png")
    with pytest.raises(ValueError, match=rf"no face found in {image}\.png"):
        auto_points(picture, picture, match="faces", names=(f"{image}.png", "b.png"))


def test_bad_images_and_indices_are_named():
    with pytest.raises(TypeError, match="image must be a floating-point tensor"):
        detect_face_points(torch.zeros(3, 8, 8, dtype=torch.uint8))
    with pytest.raises(ValueError, match=r"image must be one image .* got \(2, 3, 8, 8\)"):
        detect_face_points(torch.zeros(2, 3, 8, 8))
    with pytest.raises(ValueError, match="face_index"):
        detect_face_points(torch.zeros(3, 8, 8), face_index=-1)


def test_without_mediapipe_the_message_says_how_to_install_it(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setitem(sys.modules, "mediapipe", None)  # import mediapipe now raises ImportError
    with pytest.raises(ImportError, match=r'pip install "torchfluidwarp\[faces\]"'):
        detect_face_points(torch.zeros(3, 8, 8))
    with pytest.raises(ImportError, match=r"torchfluidwarp\[faces\]"):
        auto_points(torch.zeros(3, 8, 8), torch.zeros(3, 8, 8), match="faces")
