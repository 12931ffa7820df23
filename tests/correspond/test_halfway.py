"""Dense correspondence on the halfway domain: known deformations with structure between the marks."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.core.spline import tps_fit
from torchfluidwarp.correspond.halfway import HalfwaySettings, halfway_alignment, least_area
from torchfluidwarp.data import load_sample
from torchfluidwarp.errors import InputError
from torchfluidwarp.metrics import folded_pixels
from torchfluidwarp.morph import morph
from torchfluidwarp.morph.fit import straight_paths
from torchfluidwarp.morph.settings import NaturalSettings

SIZE = 96
FAST = HalfwaySettings(levels=(24, 48, 96), iterations=30)
EYE = torch.eye(3, dtype=torch.float64)


def _pixels(size: int) -> torch.Tensor:
    yy, xx = torch.meshgrid(
        torch.arange(size, dtype=torch.float64), torch.arange(size, dtype=torch.float64), indexing="ij"
    )
    return torch.stack([xx, yy], -1)  # (H, W, 2)


def _read(field: torch.Tensor, points: torch.Tensor, size: int) -> torch.Tensor:
    """A ``(1, C, H, W)`` raster over a ``size``-pixel square read at pixels ``(N, 2)``: ``(N, C)``."""
    g = ((2 * points + 1) / size - 1).view(1, 1, -1, 2).to(field.dtype)
    return F.grid_sample(field, g, mode="bilinear", padding_mode="border", align_corners=False)[0, :, 0].T


def _picture() -> torch.Tensor:
    a = load_sample("astronaut").double()
    return F.interpolate(a, size=(SIZE, SIZE), mode="bilinear", antialias=True, align_corners=False)


def _known_pair(brightness=(0.8, 0.1), spread: bool = False) -> dict[str, torch.Tensor]:
    """B(x) = A(x + u(x)), ``u`` four Gaussian bumps of 5 px, and marks on a 3 x 3 lattice: ``spread`` over the
    picture (the bumps fall between the marks), or in its middle (a face's marks; the bumps fall outside them, in
    the "hair" and the "background")."""
    a = _picture()
    px = _pixels(SIZE)
    u = torch.zeros(SIZE, SIZE, 2, dtype=torch.float64)
    centres = ((30, 30), (66, 30), (30, 66), (66, 66)) if spread else ((14, 14), (82, 14), (14, 82), (82, 82))
    for (cx, cy), amp in zip(centres, ((4, -3), (-3, -4), (3, 4), (-4, 3))):
        bump = torch.exp(-((px[..., 0] - cx) ** 2 + (px[..., 1] - cy) ** 2) / (2 * 9.0**2))
        u = u + bump[..., None] * torch.tensor(amp, dtype=torch.float64)
    field = u.permute(2, 0, 1)[None]
    b = F.grid_sample(a, ((2 * (px + u) + 1) / SIZE - 1)[None], padding_mode="border", align_corners=False)
    gain, offset = brightness
    lattice = torch.tensor([12.0, 48.0, 84.0] if spread else [36.0, 48.0, 60.0], dtype=torch.float64)
    pb = torch.stack(torch.meshgrid(lattice, lattice, indexing="xy"), -1).reshape(-1, 2)
    held = torch.tensor([20.0, 30.0, 40.0, 56.0, 66.0, 76.0] if spread else [8.0, 14.0, 20.0, 76.0, 82.0, 88.0])
    hb = torch.stack(torch.meshgrid(held.double(), held.double(), indexing="xy"), -1).reshape(-1, 2)
    return {
        "a": a, "b": gain * b + offset, "pa": pb + _read(field, pb, SIZE), "pb": pb,
        "ha": hb + _read(field, hb, SIZE), "hb": hb,
    }  # fmt: skip


def _end_error(total: torch.Tensor, ha: torch.Tensor, hb: torch.Tensor) -> float:
    """Mean distance from where the field ``total`` (the middle frame's travel) takes A's points ``ha`` to B's."""
    m = ha.clone()
    for _ in range(60):  # m - T(m) / 2 = ha, by fixed-point iteration (T is smooth and small)
        m = ha + _read(total, m, SIZE) / 2
    return float((m + _read(total, m, SIZE) / 2 - hb).norm(dim=1).mean())


def _errors(pair: dict[str, torch.Tensor], settings: HalfwaySettings = FAST) -> tuple[float, float, torch.Tensor]:
    inside = (-0.5, -0.5, SIZE - 0.5, SIZE - 0.5)
    mids, disp = straight_paths(pair["pa"], pair["pb"], inside)
    found = halfway_alignment(pair["a"], pair["b"], EYE, EYE, (SIZE, SIZE), mids, disp, settings)
    px = _pixels(SIZE).reshape(-1, 2)
    spline = tps_fit(mids, disp)(px).view(SIZE, SIZE, 2).permute(2, 0, 1)[None]
    dense = spline + found(px).view(SIZE, SIZE, 2).permute(2, 0, 1)[None]
    return _end_error(spline, pair["ha"], pair["hb"]), _end_error(dense, pair["ha"], pair["hb"]), dense


def test_the_pixels_align_what_the_marks_leave_open() -> None:
    # the spline through 9 marks in the middle cannot know the bumps around them; the pictures can. Bound: under
    # half the spline's error, and no fold on the paths
    spline, dense, total = _errors(_known_pair())
    assert spline > 1.0
    assert dense < 0.5 * spline
    assert float(least_area(total, (1.0, 1.0)).min()) > 0


def test_the_pixels_align_between_the_marks_when_trusted() -> None:
    # bumps between marks spread over the picture: the default holds the marks' spline within about half their
    # spacing (it improves a little); a weak anchor lets the pictures decide there too
    pair = _known_pair(spread=True)
    spline, dense, _ = _errors(pair)
    assert dense < spline
    trusting = HalfwaySettings(levels=FAST.levels, iterations=FAST.iterations, anchor=0.01)
    spline, dense, total = _errors(pair, trusting)
    assert dense < 0.3 * spline
    assert float(least_area(total, (1.0, 1.0)).min()) > 0


@pytest.mark.parametrize("brightness", [(0.5, 0.3), (-0.7, 0.9)], ids=["contrast", "inverted"])
def test_brightness_contrast_and_contrast_sign_do_not_matter(brightness: tuple[float, float]) -> None:
    plain = _errors(_known_pair())
    changed = _errors(_known_pair(brightness))
    assert changed[1] < 0.5 * changed[0]
    assert abs(changed[1] - plain[1]) < 0.25  # px
    assert float((changed[2] - plain[2]).abs().mean()) < 0.25


def test_a_picture_with_no_counterpart_leaves_the_marks_in_place() -> None:
    pair = _known_pair()
    b = pair["b"].clone()
    b[..., 40:70, 20:60] = torch.rand(1, 3, 30, 40, generator=torch.Generator().manual_seed(0), dtype=b.dtype)
    result = morph(pair["a"].float(), b.float(), pair["pa"].float(), pair["pb"].float(), frames=3, progress=False,
                   settings=NaturalSettings(grid=48, dense=FAST))  # fmt: skip
    assert float(result.error.mean()) < 1.0  # px
    assert result.frames.shape == (3, 3, SIZE, SIZE)


def _held_error(result, pair: dict[str, torch.Tensor]) -> float:
    """Mean distance from where the last map reads B's held-out points in A to where they truly are, pixels."""
    last = result.maps[-1].double().permute(2, 0, 1)[None]  # output pixel (B's) -> A's pixel
    return float((_read(last, pair["hb"], SIZE) - pair["ha"]).norm(dim=1).mean())


def test_the_morph_carries_the_dense_alignment_without_folding() -> None:
    pair = _known_pair()
    args = (pair["a"].float(), pair["b"].float(), pair["pa"].float(), pair["pb"].float())
    errors = {}
    for name, dense in (("spline", None), ("dense", FAST)):
        result = morph(*args, frames=3, progress=False, settings=NaturalSettings(grid=48, dense=dense))
        errors[name] = _held_error(result, pair)
        assert int(folded_pixels(result.maps).sum() + folded_pixels(result.maps_b).sum()) == 0
        assert float(result.error.mean()) < 1.0
    assert errors["dense"] < 0.6 * errors["spline"]


def test_points_the_pixels_placed_follow_the_pixels() -> None:
    # B's points as a feature matcher might place them, 3 px off in a random direction each: given as marks
    # (anchored, each one met), the morph lands every one 3 px wrong; placed by a matcher other than the face
    # landmarks, they only start the pixels' alignment, which moves B's side to where the pictures agree
    from torchfluidwarp.correspond import FoundPoints, Note

    pair = _known_pair(spread=True)
    angle = torch.rand(9, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 2 * math.pi
    wrong_b = pair["pb"] + 3.0 * torch.stack([angle.cos(), angle.sin()], -1)
    pa, pb = pair["pa"].float(), wrong_b.float()
    settings = NaturalSettings(grid=48, dense=HalfwaySettings(levels=(24, 48, 96), iterations=30))
    a, b = pair["a"].float(), pair["b"].float()
    run = lambda **kw: morph(a, b, frames=3, progress=False, settings=settings, **kw)  # noqa: E731
    given = run(points_a=pa, points_b=pb)
    features = run(placed=FoundPoints(pa, pb, "features", Note("matched image features (9 pairs), as asked")))
    faces = run(placed=FoundPoints(pa, pb, "faces", Note("face landmarks")))
    assert float(given.error.mean()) < 1.0  # the wrong marks are met
    assert torch.allclose(faces.points, given.points, atol=1e-4)  # face landmarks are held like given points
    # A's points keep their places; where they end (B's side) moves from 3 px off to within 1.5 px of the truth
    assert torch.allclose(features.trajectories[0].double(), pair["pa"], atol=1e-3)
    assert float((features.points.double() - pair["pb"]).norm(dim=1).mean()) < 1.5
    assert float((features.targets.double() - pair["pb"]).norm(dim=1).mean()) < 1.5
    assert float(features.error.mean()) < 1.0  # measured against where the pixels placed B's side
    assert _held_error(features, pair) < 0.6 * _held_error(given, pair)
    for result in (given, features):
        assert int(folded_pixels(result.maps).sum() + folded_pixels(result.maps_b).sum()) == 0


def test_placed_points_and_given_points_do_not_mix() -> None:
    from torchfluidwarp.correspond import FoundPoints, Note

    a = _picture().float()
    pts = torch.tensor([[10.0, 10.0], [80.0, 12.0], [40.0, 70.0]])
    placed = FoundPoints(pts, pts, "features", Note("matched image features (3 pairs), as asked"))
    with pytest.raises(InputError, match="not both") as caught:
        morph(a, a, pts, pts, placed=placed, frames=2, progress=False)
    assert caught.value.argument == "placed"


def test_least_area_of_a_known_field() -> None:
    # u = (k x, 0): det(I + sigma J) = 1 + sigma k, least at sigma = -1/2
    k = 0.8
    px = _pixels(8)
    field = torch.stack([k * px[..., 0], 0 * px[..., 1]])[None]
    assert torch.allclose(least_area(field, (1.0, 1.0)), torch.full((1, 8, 8), 1 - k / 2, dtype=torch.float64))
    assert math.isclose(float(least_area(-3 * field, (1.0, 1.0)).min()), 1 - 3 * k / 2)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"levels": (64, 32)}, "levels"),
        ({"window": 4}, "window"),
        ({"smoothness": -1.0}, "smoothness"),
        ({"reach": 0.0}, "reach"),
        ({"iterations": -1}, "iterations"),
    ],  # fmt: skip
)
def test_settings_name_the_field(kwargs: dict, field: str) -> None:
    with pytest.raises(InputError, match=f"HalfwaySettings.{field}"):
        HalfwaySettings(**kwargs)
