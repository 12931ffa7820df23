import pytest
import torch
from conftest import gradcheck64

from torchfluidwarp.core.linalg import CGConfig
from torchfluidwarp.warp.forces import Brushes
from torchfluidwarp.warp.frames import identity_map, jacobian_determinant, warp_image
from torchfluidwarp.warp.layer import FluidWarp

TIGHT = CGConfig(rtol=1e-13)


def _random_brushes(gen, n, size, amplitude, frequency=0.0):
    H, W = size
    centers = torch.rand(n, 2, generator=gen) * torch.tensor([W * 0.6, H * 0.6]) + torch.tensor([W * 0.2, H * 0.2])
    directions = torch.randn(n, 2, generator=gen)
    return Brushes(centers, directions, radius=min(H, W) / 6, amplitude=amplitude, frequency=frequency)


def test_gradcheck_image_forces_viscosity(gen):
    h, w, H, W = 5, 6, 6, 7
    image = torch.rand(1, 2, H, W, generator=gen)
    forces = torch.randn(1, 2, 2, h, w, generator=gen) * 0.2
    mu = torch.rand(1, 1, h, w, generator=gen) * 0.3 + 0.1

    def fn(image, forces, mu):
        warp = FluidWarp((h, w), steps=2, viscosity=mu, pressure=TIGHT, diffusion=TIGHT)
        return warp(image, forces)

    assert gradcheck64(fn, image, forces, mu, fast_mode=True)


@pytest.mark.parametrize("dtype,atol", [(torch.float32, 1e-5), (torch.float64, 1e-12)])
def test_zero_forces_give_the_identity(dtype, atol, gen):
    image = torch.rand(2, 3, 37, 53, generator=gen, dtype=dtype)
    warp = FluidWarp((16, 16), steps=4)
    forces = torch.zeros(2, 4, 2, 16, 16, dtype=dtype)
    maps = warp.maps(forces, (37, 53))
    torch.testing.assert_close(maps, identity_map((37, 53), dtype=dtype)[:, None].expand_as(maps), atol=1e-6, rtol=0)
    frames = warp(image, forces)
    for t in range(5):
        # frames differ from the input only by grid_sample's coordinate round-off
        torch.testing.assert_close(frames[:, t], image, atol=atol, rtol=0)


@pytest.mark.parametrize("seed", [0, 1])
def test_forward_and_backward_maps_are_inverse(seed):
    gen = torch.Generator().manual_seed(seed)
    size = (96, 80)
    warp = FluidWarp((32, 32), steps=8)
    brushes = _random_brushes(gen, 3, size, amplitude=0.4)
    back = warp.maps(brushes, size)[:, -1]  # (1, H, W, 2)
    fwd = warp.forward_maps(brushes, size)[:, -1]
    moved = (fwd - identity_map(size)).norm(dim=-1).max()
    assert moved > 4.0, f"the flow should move pixels by several px, moved at most {moved:.2f}"
    # g_T(F_T(x)) = x: read the backward map where each pixel has gone
    round_trip = warp_image(back.permute(0, 3, 1, 2), fwd)  # (1, 2, H, W)
    err = (round_trip.permute(0, 2, 3, 1) - identity_map(size)).norm(dim=-1)[0]
    assert err[10:-10, 10:-10].max() < 0.1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_strong_brushes_never_fold_and_preserve_area(seed):
    gen = torch.Generator().manual_seed(seed)
    size = (128, 128)
    warp = FluidWarp((64, 64), steps=12)
    brushes = _random_brushes(gen, 6, size, amplitude=2.0, frequency=0.05)
    with torch.no_grad():
        maps = warp.maps(brushes, size)
    moved = (maps[:, -1] - identity_map(size)).norm(dim=-1).max()
    assert moved > 10, f"strong forcing should move content by > 10 px, max {moved:.2f}"
    det = jacobian_determinant(maps[:, 1:].reshape(-1, *size, 2))
    assert det.min() > 0
    assert abs(float(det.mean().detach()) - 1) < 0.01


@pytest.mark.parametrize("shape", [(1, 1, 30, 30), (1, 3, 24, 40), (1, 4, 33, 21), (3, 3, 20, 20)])
def test_channels_sizes_and_batches(shape, gen):
    image = torch.rand(*shape, generator=gen)
    forces = torch.randn(shape[0], 3, 2, 12, 10, generator=gen) * 0.3
    frames = FluidWarp((12, 10), steps=3)(image, forces)
    assert frames.shape == (shape[0], 4, *shape[1:])
    torch.testing.assert_close(frames[:, 0], image, atol=1e-6, rtol=0)


def test_force_broadcast_over_a_batch(gen):
    image = torch.rand(3, 1, 20, 20, generator=gen)
    forces = torch.randn(1, 2, 2, 8, 8, generator=gen) * 0.3
    frames = FluidWarp(8, steps=2)(image, forces)
    single = FluidWarp(8, steps=2)(image[1:2], forces)
    torch.testing.assert_close(frames[1:2], single)


def test_points_follow_the_forward_map(gen):
    size = (64, 64)
    warp = FluidWarp((32, 32), steps=5)
    brushes = _random_brushes(gen, 2, size, amplitude=0.5)
    fwd = warp.forward_maps(brushes, size)
    pts = torch.tensor([[[10.0, 20.0], [40.0, 33.0]]])
    paths = warp.carry_points(pts, brushes, size)
    assert paths.shape == (1, 6, 2, 2)
    torch.testing.assert_close(paths[0, :, 0], fwd[0, :, 20, 10], atol=1e-5, rtol=0)


def test_nan_forces_raise(gen):
    forces = torch.zeros(1, 2, 2, 8, 8)
    forces[0, 1, 0, 2, 2] = float("nan")
    with pytest.raises(ValueError, match="forces contains non-finite"):
        FluidWarp(8, steps=2)(torch.rand(1, 3, 16, 16), forces)


def test_bad_inputs():
    warp = FluidWarp(8, steps=2)
    with pytest.raises(ValueError, match=r"forces must have shape \(\*, 2, 2, 8, 8\)"):
        warp(torch.rand(1, 3, 16, 16), torch.zeros(1, 3, 2, 8, 8))
    with pytest.raises(ValueError, match="size is needed"):
        warp.carry_points(torch.zeros(1, 1, 2), torch.zeros(1, 2, 2, 8, 8))
    with pytest.raises(ValueError, match="coords contains non-finite"):
        warp_image(torch.rand(1, 1, 4, 4), torch.full((1, 4, 4, 2), float("nan")))
    with pytest.raises(ValueError, match="steps must be >= 1"):
        FluidWarp(8, steps=0)


def test_bicubic_and_nearest_sampling(gen):
    image = torch.rand(1, 1, 9, 11, generator=gen, dtype=torch.float64)
    ident = identity_map((9, 11), dtype=torch.float64)
    for mode in ("bilinear", "bicubic", "nearest"):
        torch.testing.assert_close(warp_image(image, ident, mode), image)
    # half a pixel to the right, bilinear: the mean of neighbours
    shifted = ident + torch.tensor([0.5, 0.0], dtype=torch.float64)
    out = warp_image(image, shifted)
    torch.testing.assert_close(out[..., :-1], 0.5 * (image[..., :-1] + image[..., 1:]))


def test_maps_beyond_the_raster_are_resized_and_frames_match(gen):
    # the image is larger than OVERSAMPLE points per cell: maps are composed on the raster and resized
    size = (90, 70)
    warp = FluidWarp((16, 12), steps=6)
    brushes = _random_brushes(gen, 3, size, amplitude=1.0, frequency=0.1)
    image = torch.rand(2, 3, *size, generator=gen)
    with torch.no_grad():
        frames = warp(image, brushes)
        streamed = torch.stack(list(warp.iter_frames(image, brushes)), dim=1)
        maps = warp.maps(brushes, size)
    torch.testing.assert_close(streamed, frames, atol=1e-4, rtol=0)  # two float32 paths to the same grid
    assert (maps[:, -1] - identity_map(size)).norm(dim=-1).max() > 3
    det = jacobian_determinant(maps[:, 1:].reshape(-1, *size, 2))
    assert det.min() > 0
    assert abs(float(det.mean()) - 1) < 0.01


def test_iter_frames_stops_early_and_its_frames_stay_differentiable(gen):
    size = (40, 30)
    warp = FluidWarp((10, 8), steps=5)
    brushes = _random_brushes(gen, 2, size, amplitude=1.0, frequency=0.1)
    image = torch.rand(1, 3, *size, generator=gen)
    with torch.no_grad():
        plain = torch.stack(list(warp.iter_frames(image, brushes)))
    assert plain.shape[0] == 6
    frames = warp.iter_frames(image, brushes)
    first_two = [next(frames), next(frames)]
    frames.close()  # a consumer that stops early
    torch.testing.assert_close(first_two[1], plain[1], atol=0, rtol=0)
    # the grids are built with the caller's grad mode: frames stay differentiable in the image
    image.requires_grad_(True)
    last = list(warp.iter_frames(image, brushes))[-1]
    last.sum().backward()
    assert image.grad is not None and float(image.grad.abs().sum()) > 0


@pytest.mark.parametrize("grad", [False, True])
def test_forward_is_iter_frames_stacked_bitwise(gen, grad):
    # forward shares iter_frames' machinery: the same grids and one resampling per frame, with or without grad
    size = (37, 52)
    warp = FluidWarp((9, 11), steps=4)
    brushes = _random_brushes(gen, 2, size, amplitude=1.0, frequency=0.1)
    image = torch.rand(2, 3, *size, generator=gen).requires_grad_(grad)
    with torch.set_grad_enabled(grad):
        frames = warp(image, brushes)
        streamed = torch.stack(list(warp.iter_frames(image, brushes)), dim=1)
    assert frames.shape == (2, 5, 3, *size) and frames.is_contiguous()
    torch.testing.assert_close(frames, streamed, atol=0, rtol=0)
    assert frames.requires_grad == grad
    if grad:
        (g,) = torch.autograd.grad(frames[:, -1].sum(), image)
        assert float(g.abs().sum()) > 0
