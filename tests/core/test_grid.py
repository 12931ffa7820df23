"""The coordinate module: pixel <-> fluid cell <-> normalised, and the pixel-centre convention."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from hypothesis import given, settings
from hypothesis import strategies as st

from torchfluidwarp.core.grid import (
    FluidGrid,
    SquareCells,
    cell_centres,
    cell_scale,
    cell_to_pixel,
    inside_picture,
    mean_pixels_per_cell,
    normalized_affine,
    normalized_to_pixel,
    pixel_to_cell,
    pixel_to_normalized,
    rescale_points,
    scale_factor,
)
from torchfluidwarp.warp.frames import identity_map

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
TOL = {torch.float32: 1e-5, torch.float64: 1e-12}

sizes = st.integers(min_value=2, max_value=700)


def _points(size: tuple[int, int], n: int, seed: int, dtype=torch.float64) -> torch.Tensor:
    """``(n, 2)`` points spread over the image rectangle and a little beyond it, in pixels."""
    H, W = size
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 2, generator=g, dtype=dtype) * 1.2 - 0.1
    return u * torch.tensor([W, H], dtype=dtype) - 0.5


@settings(max_examples=60, deadline=None)
@given(H=sizes, W=sizes, h=sizes, w=sizes, seed=st.integers(0, 2**31 - 1))
def test_pixel_cell_round_trip(H: int, W: int, h: int, w: int, seed: int) -> None:
    p = _points((H, W), 16, seed)
    cells = pixel_to_cell(p, (H, W), (h, w))
    torch.testing.assert_close(cell_to_pixel(cells, (H, W), (h, w)), p, rtol=0, atol=1e-9)
    # the rectangle is shared: fractions of the way across agree in both units
    torch.testing.assert_close((cells + 0.5) / torch.tensor([w, h]), (p + 0.5) / torch.tensor([W, H]))


@settings(max_examples=60, deadline=None)
@given(H=st.integers(1, 700), W=st.integers(1, 700), seed=st.integers(0, 2**31 - 1))
def test_pixel_normalized_round_trip(H: int, W: int, seed: int) -> None:
    p = _points((H, W), 16, seed)
    n = pixel_to_normalized(p, (H, W))
    torch.testing.assert_close(normalized_to_pixel(n, (H, W)), p, rtol=0, atol=1e-9)
    scale, shift = normalized_affine((H, W), dtype=torch.float64)
    torch.testing.assert_close(p * scale + shift, n, rtol=0, atol=1e-12)  # the fused form is the same map


@settings(max_examples=40, deadline=None)
@given(Hs=sizes, Ws=sizes, Ht=sizes, Wt=sizes, seed=st.integers(0, 2**31 - 1))
def test_rescale_points_round_trip(Hs: int, Ws: int, Ht: int, Wt: int, seed: int) -> None:
    p = _points((Hs, Ws), 16, seed)
    s = scale_factor((Hs, Ws), (Ht, Wt), dtype=torch.float64)
    there = rescale_points(p, s)
    torch.testing.assert_close(rescale_points(there, s, inverse=True), p, rtol=0, atol=1e-9)
    back = scale_factor((Ht, Wt), (Hs, Ws), dtype=torch.float64)
    torch.testing.assert_close(rescale_points(there, back), p, rtol=0, atol=1e-9)


@pytest.mark.parametrize("size", [(2, 3), (5, 8), (64, 64), (600, 401)])
def test_pixel_centres_same_resolution(size: tuple[int, int]) -> None:
    """With ``W == w`` pixel centres are cell centres: 0 -> 0 and W - 1 -> w - 1, and the edges stay put."""
    H, W = size
    p = torch.tensor([[0.0, 0.0], [W - 1.0, H - 1.0], [-0.5, -0.5], [W - 0.5, H - 0.5]], dtype=torch.float64)
    torch.testing.assert_close(pixel_to_cell(p, (H, W), (H, W)), p, rtol=0, atol=0)


@pytest.mark.parametrize(("image", "grid"), [((600, 600), (64, 64)), ((37, 90), (12, 5)), ((8, 8), (64, 32))])
def test_edges_map_to_edges(image: tuple[int, int], grid: tuple[int, int]) -> None:
    """The image's edges ``-0.5`` and ``W - 0.5`` are the fluid box's ``-0.5`` and ``w - 0.5``, whatever the sizes."""
    (H, W), (h, w) = image, grid
    p = torch.tensor([[-0.5, -0.5], [W - 0.5, H - 0.5]], dtype=torch.float64)
    want = torch.tensor([[-0.5, -0.5], [w - 0.5, h - 0.5]], dtype=torch.float64)
    torch.testing.assert_close(pixel_to_cell(p, image, grid), want, rtol=0, atol=1e-12)
    torch.testing.assert_close(cell_to_pixel(want, image, grid), p, rtol=0, atol=1e-12)
    torch.testing.assert_close(
        pixel_to_normalized(p, image), torch.tensor([[-1.0, -1.0], [1.0, 1.0]], dtype=torch.float64)
    )


def test_scales() -> None:
    torch.testing.assert_close(scale_factor((600, 400), (60, 100)), torch.tensor([0.25, 0.1]))
    torch.testing.assert_close(cell_scale((600, 400), FluidGrid(60, 100)), torch.tensor([0.25, 0.1]))
    torch.testing.assert_close(cell_scale((64, 64), 16), torch.tensor([0.25, 0.25]))
    assert mean_pixels_per_cell((600, 400), (60, 100)) == 0.5 * (10 + 4)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(("H", "W"), [(7, 9), (32, 20)])
def test_grid_sample_reads_pixel_centres(H: int, W: int, dtype: torch.dtype) -> None:
    """``grid_sample(align_corners=False)`` at a pixel's normalised position reads exactly that pixel."""
    g = torch.Generator().manual_seed(1)
    image = torch.rand(2, 3, H, W, generator=g, dtype=dtype)
    pix = identity_map((H, W), batch=2, dtype=dtype)
    scale, shift = normalized_affine((H, W), dtype=dtype)
    for grid in (pixel_to_normalized(pix, (H, W)), pix * scale + shift):
        out = F.grid_sample(image, grid, mode="bilinear", align_corners=False)
        torch.testing.assert_close(out, image, rtol=0, atol=TOL[dtype])
    # a point half way between two pixel centres reads their mean
    mid = pixel_to_normalized(torch.tensor([[[[0.5, 0.0]]]], dtype=dtype).expand(2, 1, 1, 2), (H, W))
    got = F.grid_sample(image, mid, align_corners=False)[..., 0, 0]
    torch.testing.assert_close(got, 0.5 * (image[..., 0, 0] + image[..., 0, 1]), rtol=0, atol=TOL[dtype])


@pytest.mark.parametrize(("offset", "n"), [((0.0, 0.0), (5, 7)), ((-0.5, 0.0), (9, 9)), ((0.0, -0.5), (4, 6))])
def test_normalized_affine_align_corners_nodes(offset: tuple[float, float], n: tuple[int, int]) -> None:
    """``align_corners=True``: node ``k`` at ``offset + k`` is read exactly (the staggered faces' layout)."""
    ny, nx = n
    g = torch.Generator().manual_seed(2)
    nodes = torch.rand(1, 1, ny, nx, generator=g, dtype=torch.float64)
    scale, shift = normalized_affine(n, align_corners=True, offset=offset, dtype=torch.float64)
    pos = identity_map(n, dtype=torch.float64) + torch.tensor(offset, dtype=torch.float64)
    out = F.grid_sample(nodes, pos * scale + shift, align_corners=True)
    torch.testing.assert_close(out, nodes, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("image", "grid"), [((64, 48), (16, 12)), ((30, 90), (10, 15))])
def test_cells_average_their_pixels(image: tuple[int, int], grid: tuple[int, int]) -> None:
    """A fluid cell is the area average of its pixels (``F.interpolate(mode="area")``): a linear ramp in pixels
    averages to the ramp at :func:`cell_centres`, and those centres are the integers in cell coordinates."""
    pix = identity_map(image, dtype=torch.float64)[0]  # (H, W, 2)
    ramp = (0.3 * pix[..., 0] - 1.7 * pix[..., 1] + 2.0)[None, None]
    avg = F.interpolate(ramp, size=grid, mode="area")[0, 0]
    centres = cell_centres(grid, image, dtype=torch.float64)  # (h, w, 2) pixels
    torch.testing.assert_close(avg, 0.3 * centres[..., 0] - 1.7 * centres[..., 1] + 2.0)
    torch.testing.assert_close(pixel_to_cell(centres, image, grid), identity_map(grid, dtype=torch.float64)[0])


def test_bilinear_upsampling_follows_pixel_to_cell() -> None:
    """``F.interpolate(bilinear, align_corners=False)`` from cells to pixels reads the cell field at
    :func:`pixel_to_cell` of each pixel centre (away from the border, where it clamps)."""
    (H, W), (h, w) = (60, 84), (10, 12)
    cells = identity_map((h, w), dtype=torch.float64).permute(0, 3, 1, 2)  # (1, 2, h, w): each cell's (x, y)
    up = F.interpolate(cells, size=(H, W), mode="bilinear", align_corners=False)[0].permute(1, 2, 0)
    want = pixel_to_cell(identity_map((H, W), dtype=torch.float64)[0], (H, W), (h, w))
    inside = (want[..., 0] >= 0) & (want[..., 0] <= w - 1) & (want[..., 1] >= 0) & (want[..., 1] <= h - 1)
    assert inside.float().mean() > 0.8
    torch.testing.assert_close(up[inside], want[inside])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_device_and_dtype_follow_inputs(device: str, dtype: torch.dtype) -> None:
    p = torch.zeros(3, 2, device=device, dtype=dtype)
    for out in (
        pixel_to_cell(p, (40, 30), (8, 6)),
        cell_to_pixel(p, (40, 30), (8, 6)),
        pixel_to_normalized(p, (40, 30)),
        normalized_to_pixel(p, (40, 30)),
        rescale_points(p, scale_factor((40, 30), (8, 6), device=device, dtype=dtype)),
        scale_factor((40, 30), (8, 6), device=device, dtype=dtype),
        cell_scale((40, 30), (8, 6), device=device, dtype=dtype),
        cell_centres((8, 6), (40, 30), device=device, dtype=dtype),
        *normalized_affine((40, 30), device=device, dtype=dtype),
        *normalized_affine((40, 30), align_corners=True, device=device, dtype=dtype),
    ):
        assert out.device.type == device and out.dtype == dtype


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="points"):
        pixel_to_cell(torch.zeros(3, 3), (10, 10), (4, 4))
    with pytest.raises(ValueError, match="points"):
        pixel_to_normalized(torch.tensor([[float("nan"), 0.0]]), (10, 10))
    with pytest.raises(ValueError, match="size"):
        normalized_affine((1, 5), align_corners=True)
    with pytest.raises(ValueError, match="grid"):
        cell_scale((10, 10), (1, 4))


def test_inside_picture_holds_the_pixel_edges_and_nothing_beyond():
    # a 20 x 10 picture covers x in [-0.5, 9.5], y in [-0.5, 19.5]: its outer pixel edges count, a hair beyond
    # does not, on either axis, for any leading shape
    eps = 1e-4
    edges = torch.tensor([[-0.5, -0.5], [9.5, 19.5], [4.0, 7.0]])
    beyond = torch.tensor([[-0.5 - eps, 3.0], [9.5 + eps, 3.0], [3.0, -0.5 - eps], [3.0, 19.5 + eps]])
    assert inside_picture(edges, (20, 10)).all()
    assert not inside_picture(beyond, (20, 10)).any()
    batched = torch.stack([edges[:3], beyond[:3]])  # (2, 3, 2)
    assert inside_picture(batched, (20, 10)).tolist() == [[True, True, True], [False, False, False]]


@settings(max_examples=60, deadline=None)
@given(st.integers(16, 4000), st.integers(16, 4000), st.integers(64, 20000))
def test_square_cells_are_square_and_as_many_as_asked(H: int, W: int, count: int) -> None:
    h, w = SquareCells(count).over((H, W)).shape
    # each axis is the exact square grid's side rounded (at least 2): its cells' aspect and the count are off by at
    # most that half a cell on each axis
    exact_h, exact_w = (count * H / W) ** 0.5, (count * W / H) ** 0.5
    assert abs(h - max(2.0, exact_h)) <= 0.5 + 1e-9 and abs(w - max(2.0, exact_w)) <= 0.5 + 1e-9
    if min(exact_h, exact_w) >= 8:
        aspect = (H / h) / (W / w)  # a cell's height over its width
        assert abs(aspect - 1) <= 0.5 / min(exact_h, exact_w) * 2.2
        assert abs(h * w / count - 1) <= 0.5 / min(exact_h, exact_w) * 2.2


def test_square_cells_keep_a_square_picture_s_grid_and_refuse_bad_counts() -> None:
    assert SquareCells(6400).over((512, 512)) == FluidGrid(80, 80)
    assert SquareCells(6400).over((970, 2204)).shape == (53, 121)
    with pytest.raises(ValueError, match="SquareCells.count"):
        SquareCells(3)
    with pytest.raises(TypeError, match="SquareCells.count"):
        SquareCells(80.0)  # type: ignore[arg-type]
