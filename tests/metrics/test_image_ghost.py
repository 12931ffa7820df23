"""Ghosting seen in the pixels (:func:`torchfluidwarp.metrics.image_ghosting`) and its place in the report.

The figure is the local displacement between A and B warped to the middle frame. It must read a known shift as
that shift whatever the pictures' brightness and contrast, see nothing where a morph follows the true map and the
whole displacement where it does not, and see the doubled parts of a real stereo pair left unaligned.
"""

import json
import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp import metrics
from torchfluidwarp.errors import InputError
from torchfluidwarp.morph import NaturalSettings, morph
from torchfluidwarp.warp import identity_map, warp_image

pytestmark = pytest.mark.usefixtures("one_thread")

N = 96  # the frames' side, pixels
PAD = 12  # the texture extends this far beyond the frames on each side, so that no read holds an edge pixel


def _texture(gen: torch.Generator, size: int, sigma: float = 1.5) -> torch.Tensor:
    """``(1, 1, size, size)`` float64 white noise blurred by a Gaussian of ``sigma`` pixels: structure at every
    pixel, at about the scale of a photograph's fine detail."""
    r = math.ceil(3 * sigma)
    t = torch.arange(-r, r + 1, dtype=torch.float64)
    k = torch.exp(-(t**2) / (2 * sigma**2))
    k = k / k.sum()
    x = torch.rand(1, 1, size + 2 * r, size + 2 * r, generator=gen, dtype=torch.float64)
    return F.conv2d(F.conv2d(x, k.view(1, 1, 1, -1)), k.view(1, 1, -1, 1))


def _read(texture: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """The texture read at frame coordinates ``(1, N, N, 2)`` (frame pixel ``x`` is texture pixel ``x + PAD``)."""
    return warp_image(texture, coords + PAD)


def _field(amplitude: float) -> torch.Tensor:
    """A smooth displacement field ``(1, N, N, 2)``, pixels: a few slow waves, at most ``amplitude`` per axis."""
    grid = identity_map((N, N), dtype=torch.float64)
    x, y = grid[..., 0] / N, grid[..., 1] / N
    ux = torch.sin(2 * math.pi * (0.8 * y + 0.3 * x) + 0.4)
    uy = torch.cos(2 * math.pi * (0.6 * x - 0.5 * y) + 1.1)
    return amplitude * torch.stack([ux, uy], dim=-1)


def _inverse(u: torch.Tensor, sign: float, iters: int = 40) -> torch.Tensor:
    """The map ``m`` with ``m + sign * u(m) / 2 = y`` for every frame pixel ``y`` (fixed-point iteration, which
    converges since ``|grad u| / 2 < 1``): ``(1, N, N, 2)``."""
    y = identity_map((N, N), dtype=torch.float64)
    m = y.clone()
    for _ in range(iters):
        m = y - sign * warp_image(u.permute(0, 3, 1, 2), m).permute(0, 2, 3, 1) / 2
    return m


def _inside(coords: torch.Tensor) -> torch.Tensor:
    x, y = coords[0, ..., 0], coords[0, ..., 1]
    return (x >= 0) & (x <= N - 1) & (y >= 0) & (y <= N - 1)


# ------------------------------------------------------------------------------------------------ the pure function


def test_a_morph_through_the_true_map_shows_less_ghosting_than_the_identity(gen):
    # A shows the texture moved by -u/2 and B by +u/2: a smooth, known map relates them, and B's copy of each of
    # A's structures stands u away (to first order in grad u). The true middle frame reads A through the inverse
    # of x -> x + u(x)/2 and B through that of x -> x - u(x)/2: both then show the texture itself, no ghost; the
    # identity morph shows A and B as they are, ghosts |u| apart.
    texture = _texture(gen, N + 2 * PAD)
    u = _field(3.0)
    grid = identity_map((N, N), dtype=torch.float64)
    a, b = _read(texture, grid + u / 2), _read(texture, grid - u / 2)
    m_a, m_b = _inverse(u, 1.0), _inverse(u, -1.0)
    warped_a, warped_b = warp_image(a, m_a), warp_image(b, m_b)
    true = metrics.image_ghosting(warped_a[0], warped_b[0], _inside(m_a) & _inside(m_b))
    identity = metrics.image_ghosting(a[0], b[0])
    magnitude = float(u.norm(dim=-1).median())  # 3.0 px
    assert true["covered"] > 0.9 and true["textured"] > 0.7 and identity["textured"] > 0.7
    # what is left of the true morph's ghost is resampling (each picture read twice): well under a pixel
    assert true["median"] < 0.25 and true["p90"] < 0.5
    # the copies stand u apart up to O(|u| |grad u|), and |grad u| < 0.2 here
    assert 0.85 * magnitude < identity["median"] < 1.15 * magnitude
    assert identity["median"] > 10 * true["median"]


@pytest.mark.parametrize("shift", [(3.0, 0.0), (2.5, -1.5), (0.0, 0.5), (-6.0, 4.0)])
def test_a_constant_shift_is_measured_whatever_the_brightness_and_contrast(gen, shift):
    texture = _texture(gen, N + 2 * PAD)
    grid = identity_map((N, N), dtype=torch.float64)
    d = torch.tensor(shift, dtype=torch.float64)
    a, b = _read(texture, grid), _read(texture, grid + d)  # B shows at x what A shows at x + d: ghosts |d| apart
    plain = metrics.image_ghosting(a[0], b[0])
    assert plain["median"] == pytest.approx(float(d.norm()), abs=0.05)
    assert plain["p90"] < float(d.norm()) + 0.15
    assert plain["covered"] == 1 and plain["scale"] == 1
    # a brighter, flatter B; a darker, stronger A; a B in negative: the same structures, the same figure
    for pa, pb in ((a, 0.3 * b + 0.6), (2.5 * a - 0.4, b), (a, 1 - b), (1 - 2 * a, 0.5 * b)):
        other = metrics.image_ghosting(pa[0], pb[0])
        for key in ("median", "p90", "textured"):
            assert other[key] == pytest.approx(plain[key], abs=1e-6)


def test_a_large_frame_is_measured_on_a_copy_and_reported_in_its_own_pixels(gen):
    n = 2 * N
    texture = _texture(gen, n + 2 * PAD, sigma=3.0)
    grid = identity_map((n, n), dtype=torch.float64)
    d = torch.tensor([5.0, -3.0], dtype=torch.float64)
    a, b = warp_image(texture, grid + PAD), warp_image(texture, grid + PAD + d)
    r = metrics.image_ghosting(a, b, max_side=N)
    assert r["scale"] == 2
    assert r["median"] == pytest.approx(float(d.norm()), abs=0.1)  # 0.05 px of the copy


def test_uncovered_pixels_are_left_out_and_dtype_follows(gen):
    texture = _texture(gen, N + 2 * PAD)
    grid = identity_map((N, N), dtype=torch.float64)
    a, b = _read(texture, grid), _read(texture, grid + torch.tensor([2.0, 1.0], dtype=torch.float64))
    valid = torch.zeros(N, N, dtype=torch.bool)
    valid[:, : N // 2] = True
    half = metrics.image_ghosting(a[0], b[0], valid)
    assert half["covered"] == 0.5 and 0.3 < half["textured"] < 0.5
    assert half["median"] == pytest.approx(5**0.5, abs=0.05)
    single = metrics.image_ghosting(a.float().expand(1, 3, N, N), b.half())  # colour A, half-precision grey B
    assert single["median"] == pytest.approx(5**0.5, abs=0.05)
    nothing = metrics.image_ghosting(a[0], b[0], torch.zeros(N, N, dtype=torch.bool))
    assert nothing["covered"] == 0 and nothing["median"] is None and nothing["textured"] == 0


def test_bad_arguments_are_named():
    a = torch.rand(3, 32, 32)
    with pytest.raises(InputError) as err:
        metrics.image_ghosting(a, torch.rand(3, 32, 31))
    assert err.value.argument == "warped_b"
    with pytest.raises(InputError) as err:
        metrics.image_ghosting(a, a, torch.ones(32, 31, dtype=torch.bool))
    assert err.value.argument == "valid"
    with pytest.raises(InputError) as err:
        metrics.image_ghosting(a, a, window=6)
    assert err.value.argument == "window"
    with pytest.raises(InputError) as err:
        metrics.image_ghosting(torch.rand(2, 3, 32, 32), a)
    assert err.value.argument == "warped_a"
    with pytest.raises(InputError) as err:
        metrics.image_ghosting(a.clone().fill_(float("nan")), a)
    assert err.value.argument == "warped_a"


# ---------------------------------------------------------------------------------------------------- in a report

SIZE = 64
POINTS = torch.tensor([[14.0, 16.0], [48.0, 14.0], [32.0, 34.0], [16.0, 48.0], [48.0, 48.0], [32.0, 20.0]])
SHIFT = torch.tensor([5.0, 3.0])
KW = dict(settings=NaturalSettings(grid=16, steps=4, max_iter=30), frames=5, progress=False)


def test_the_report_sees_the_ghost_a_morph_leaves_and_not_the_one_it_removes(gen):
    image = _texture(gen, SIZE, sigma=1.0).float().expand(1, 3, SIZE, SIZE)[0].contiguous()
    b = torch.roll(image, (3, 5), (1, 2))  # B is A moved by SHIFT
    aligned = morph(image, b, POINTS, POINTS + SHIFT, **KW)  # the true map: a translation
    report = metrics.morph_report(aligned, image, b, POINTS, POINTS + SHIFT)
    ghost = report["image_ghost"]
    assert set(ghost) == {"median", "p90", "mean", "covered", "textured", "scale"}
    assert ghost["covered"] > 0.6 and ghost["median"] < 0.25 and ghost["p90"] < 0.5
    # marks that do not move, and no alignment by the pixels: the identity
    unaligned = morph(image, b, POINTS, POINTS, **{**KW, "settings": NaturalSettings(grid=16, steps=4, dense=None)})
    other = metrics.morph_report(unaligned, image, b, POINTS, POINTS)
    doubled = other["image_ghost"]
    assert doubled["covered"] == 1
    assert doubled["median"] == pytest.approx(float(SHIFT.norm()), abs=0.25)
    # the marks' own ghosting cannot see it: the flow put A's and B's copies of each mark together
    assert other["marked"]["ghost"]["max"] < 0.05
    assert json.loads(json.dumps(report, allow_nan=False))["image_ghost"] == ghost


# ------------------------------------------------------------------------------------------------ a real stereo pair


def _stereo() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """scikit-image's motorcycle pair at half size, ``(3, 250, 370)`` each, and the left view's disparity
    ``(250, 370)`` in half-size pixels (NaN where unknown): the left pixel ``x`` shows in the right view at
    ``x - d``."""
    data = pytest.importorskip("skimage.data", reason="scikit-image (the bench extra) holds the stereo pair")
    left, right, disp = data.stereo_motorcycle()

    def half(x: np.ndarray) -> torch.Tensor:
        image = torch.from_numpy(np.ascontiguousarray(x)).permute(2, 0, 1)[None].float() / 255
        return F.interpolate(image, scale_factor=0.5, mode="area")

    d = torch.from_numpy(np.where(np.isfinite(disp), disp, np.nan)).float()[None, None]
    known = F.interpolate(d.isfinite().float(), scale_factor=0.5, mode="area") > 0.999
    d = F.interpolate(torch.nan_to_num(d), scale_factor=0.5, mode="area") / 2
    return half(left)[0], half(right)[0], torch.where(known, d, torch.nan)[0, 0]


def test_a_stereo_pair_left_unaligned_shows_its_doubled_parts():
    left, right, disp = _stereo()
    H, W = disp.shape
    true = float(disp.nanmedian())  # 20 px: the views stand far apart, as the doubled rim and fork show
    doubled = metrics.image_ghosting(left, right)
    assert 0.8 * true < doubled["median"] < 1.2 * true and doubled["textured"] > 0.5
    # the right view read through the true disparity stands where the left one does, but for what one view hides
    known = disp.isfinite()
    coords = identity_map((H, W)) - torch.stack([torch.nan_to_num(disp), torch.zeros_like(disp)], dim=-1)
    aligned = warp_image(right[None], coords)[0]
    valid = known & (coords[0, ..., 0] >= 0)
    seen = metrics.image_ghosting(left, aligned, valid)
    assert seen["median"] < 0.5 and seen["covered"] > 0.7
    assert doubled["median"] > 20 * seen["median"]
