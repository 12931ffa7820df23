"""Texture-coordinate maps (:mod:`torchfluidwarp.warp.maps`): their settings (:class:`MapConfig`), the one
raster upsample, and their one home."""

import warnings

import pytest
import torch

from torchfluidwarp.core.advection import substeps
from torchfluidwarp.core.simulator import FluidSimulator
from torchfluidwarp.core.staggered import MAX_STRAIN_PER_SUBSTEP, StaggeredGrid
from torchfluidwarp.warp import layer, maps
from torchfluidwarp.warp.forces import Brushes
from torchfluidwarp.warp.frames import identity_map, warp_image
from torchfluidwarp.warp.layer import FluidWarp
from torchfluidwarp.warp.maps import MapConfig, backward_maps, forward_maps, maps_to_end, upsample_raster


def _velocities(gen, grid=(10, 12), steps=3, strength=0.4, dtype=torch.float64):
    forces = torch.randn(1, steps, 2, *grid, generator=gen, dtype=dtype) * strength
    return FluidSimulator(grid)(forces).velocities


def test_the_maps_have_one_home_and_the_layer_module_exports_only_the_layer():
    assert layer.__all__ == ["FluidWarp"]
    assert not {"warp_image", "identity_map", "jacobian_determinant"} & set(maps.__all__)  # their home: frames


def test_the_default_config_is_the_module_constants(gen):
    config = MapConfig()
    assert (config.oversample, config.trace_oversample) == (maps.OVERSAMPLE, maps.TRACE_OVERSAMPLE)
    v = _velocities(gen)
    explicit = MapConfig(oversample=maps.OVERSAMPLE, trace_oversample=maps.TRACE_OVERSAMPLE, max_strain=0.25)
    want = backward_maps(v, (90, 100))
    torch.testing.assert_close(backward_maps(v, (90, 100), config=explicit), want, rtol=0, atol=0)


def test_the_default_rasters_stay_close_to_full_resolution_maps():
    size = (70, 84)  # 7 pixels per cell
    brush = Brushes([[40.0, 30.0]], [[1.0, 0.3]], radius=12.0, amplitude=0.8).to(torch.float64)
    with torch.no_grad():
        v = FluidSimulator((10, 12))(brush((10, 12), 3, 1.0, size)).velocities
        full = backward_maps(v, size, config=MapConfig(oversample=7, trace_oversample=7))  # the image itself
        assert float((full[:, -1] - full[:, 0]).abs().max()) > 1.5  # pixels: the flow moved the maps
        default = float((backward_maps(v, size) - full).abs().max())
        coarse = float((backward_maps(v, size, config=MapConfig(oversample=1, trace_oversample=1)) - full).abs().max())
    assert default < 0.1  # pixels
    assert default < coarse
    for f in (lambda c: maps_to_end(v, size, config=c), lambda c: forward_maps(v, size, config=c)):
        torch.testing.assert_close(f(MapConfig()), f(MapConfig(max_strain=0.25)), rtol=0, atol=0)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"oversample": 0}, "oversample"),
        ({"trace_oversample": 1.5}, "trace_oversample"),
        ({"max_strain": 0}, "max_strain"),
    ],
)
def test_a_bad_config_is_refused_by_name(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        MapConfig(**kwargs)


def test_the_config_must_be_a_map_config(gen):
    with pytest.raises(TypeError, match="config must be a MapConfig"):
        backward_maps(_velocities(gen), (20, 24), config={"oversample": 2})  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="map_config must be a MapConfig"):
        FluidWarp(8, 2, map_config=3)  # type: ignore[arg-type]


def test_upsample_raster_is_exact_on_linear_fields_and_the_identity_at_the_same_size():
    # a field linear in the pixel centres is reproduced wherever bilinear interpolation does not clamp
    Hr, Wr, H, W = 4, 6, 12, 18
    ys, xs = torch.meshgrid(torch.arange(Hr, dtype=torch.float64), torch.arange(Wr, dtype=torch.float64), indexing="ij")
    field = torch.stack([0.5 * xs - 0.25 * ys + 1.0, 2.0 * ys])[None]  # (1, 2, Hr, Wr)
    up = upsample_raster(field, (H, W))
    assert up.shape == (1, 2, H, W)
    pix = identity_map((H, W), dtype=torch.float64)[0]  # (H, W, 2)
    rx = (pix[..., 0] + 0.5) * Wr / W - 0.5  # image pixel centre in raster pixels
    ry = (pix[..., 1] + 0.5) * Hr / H - 0.5
    want = torch.stack([0.5 * rx - 0.25 * ry + 1.0, 2.0 * ry])
    inside = (rx >= 0) & (rx <= Wr - 1) & (ry >= 0) & (ry <= Hr - 1)
    torch.testing.assert_close(up[0][:, inside], want[:, inside], rtol=0, atol=1e-12)
    assert upsample_raster(field, (Hr, Wr)) is field


def test_carry_points_gives_the_paths_from_the_given_points(gen):
    warp = FluidWarp(12, steps=3, image_size=(40, 48))
    brushes = Brushes([[20.0, 20.0]], [[1.0, 0.5]], radius=8.0, amplitude=0.6)
    pts = torch.tensor([[[10.0, 12.0], [30.0, 25.0]]])
    paths = warp.carry_points(pts, brushes)
    assert paths.shape == (1, 4, 2, 2)
    torch.testing.assert_close(paths[:, 0], pts)
    assert not hasattr(warp, "advect_points")  # the deprecated alias is gone


def test_the_layer_passes_its_map_config_on(gen):
    config = MapConfig(oversample=2, trace_oversample=2, max_strain=0.1)
    forces = torch.randn(1, 3, 2, 10, 12, generator=gen) * 0.4
    warp = FluidWarp((10, 12), steps=3, map_config=config)
    v = warp.rollout(forces, (60, 72)).velocities
    torch.testing.assert_close(warp.maps(forces, (60, 72)), backward_maps(v, (60, 72), config=config), rtol=0, atol=0)
    image = torch.rand(1, 1, 60, 72, generator=gen)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frames = warp(image, forces)
        streamed = torch.stack(list(warp.iter_frames(image, forces)), dim=1)
    torch.testing.assert_close(streamed, frames, rtol=0, atol=1e-4)  # two float32 paths
    assert not torch.equal(frames, FluidWarp((10, 12), steps=3)(image, forces))  # the config mattered


@pytest.mark.parametrize("to_end", [False, True])
def test_raster_displacements_read_at_the_pixel_centres_are_the_maps(to_end):
    size = (70, 84)  # larger than the 4-per-cell raster of a 10 x 12 fluid
    brush = Brushes([[40.0, 30.0]], [[1.0, 0.3]], radius=12.0, amplitude=0.8).to(torch.float64)
    with torch.no_grad():
        v = FluidSimulator((10, 12))(brush((10, 12), 3, 1.0, size)).velocities
    times = [0.0, 1.5, 3.0]
    full = (maps_to_end if to_end else backward_maps)(v, size, times=times)  # (1, 3, H, W, 2)
    disp = maps.raster_displacements(v, size, times=times, to_end=to_end)
    assert disp.shape == (1, 3, 2, 40, 48)  # the raster, not the image
    ident = identity_map(size, dtype=torch.float64)
    assert float((full[0] - ident).abs().max()) > 1.0  # pixels: the maps moved
    for k in range(len(times)):
        read = ident + maps.read_displacement(disp[:, k], size, ident)
        torch.testing.assert_close(read, full[:, k], rtol=0, atol=1e-9)


def test_read_displacement_is_bilinear_inside_and_held_beyond_the_raster():
    # a linear field is reproduced exactly between the samples and held at the outermost ones beyond them
    size = (40, 60)
    ident = identity_map((4, 6), dtype=torch.float64)  # raster pixel centres
    field = (ident * ident.new_tensor([0.5, -2.0])).permute(0, 3, 1, 2)  # linear in the raster's pixels
    at = torch.tensor([[[[12.3, 7.9], [55.0, 38.0], [-30.0, 50.0]]]], dtype=torch.float64)  # image pixels
    got = maps.read_displacement(field, size, at)[0, 0]
    on_raster = (at[0, 0] + 0.5) / 10 - 0.5
    held = torch.stack([on_raster[:, 0].clamp(0, 5), on_raster[:, 1].clamp(0, 3)], dim=-1)
    torch.testing.assert_close(got, held * held.new_tensor([0.5, -2.0]), rtol=0, atol=1e-12)
    assert float(on_raster[0, 0]) == pytest.approx(0.78) and float(held[2, 0]) == 0.0


@pytest.mark.parametrize(
    "field,size,at,match",
    [
        (torch.zeros(1, 3, 4, 6), (40, 60), torch.zeros(1, 2, 2, 2), "2 channels"),
        (torch.zeros(2, 4, 6), (40, 60), torch.zeros(1, 2, 2, 2), "displacement must have 4 dimensions"),
        (torch.zeros(1, 2, 4, 6), (40, 60), torch.zeros(2, 2, 2, 2), r"at must have shape \(1, "),
        (torch.zeros(1, 2, 4, 6), (0, 60), torch.zeros(1, 2, 2, 2), "size must be"),
        (torch.zeros(1, 2, 4, 6), (40, 60), torch.full((1, 2, 2, 2), float("nan")), "non-finite .* from at"),
    ],
)
def test_read_displacement_refuses_bad_input_by_name(field, size, at, match):
    with pytest.raises(ValueError, match=match):
        maps.read_displacement(field, size, at)


@pytest.mark.parametrize("duration", [1.0, -1.0])  # backward maps and maps to the end share the composer
def test_a_step_of_several_substeps_is_its_substeps_composed_one_by_one(gen, duration):
    # a strong flow: several sub-steps per step. The composer traces the step's velocity once for all of them;
    # here each sub-step is traced and composed on its own, as the definition reads: g <- g(x - d_sub(x))
    v = _velocities(gen, strength=3.0)
    size = (50, 60)
    n = [substeps(v[:, t], duration, MAX_STRAIN_PER_SUBSTEP) for t in range(v.shape[1])]
    assert max(n) >= 3
    compose, _, raster = maps._map_composer(v, size, 1.0)
    grid = StaggeredGrid.of(v)
    pix = identity_map(raster, dtype=v.dtype).permute(0, 3, 1, 2)  # (1, 2, Hr, Wr) raster pixels
    lo = torch.tensor([-0.5, -0.5], dtype=v.dtype).view(1, 2, 1, 1)
    hi = torch.tensor([raster[1] - 0.5, raster[0] - 0.5], dtype=v.dtype).view(1, 2, 1, 1)
    disp = want = torch.zeros(1, 2, *raster, dtype=v.dtype)
    for t in range(v.shape[1]):
        disp = compose(disp, t, duration)
        for _ in range(n[t]):
            at = torch.clamp(pix - maps._displacement(grid, v[:, t], raster, duration / n[t]), lo, hi)
            want = at - pix + warp_image(want, at.permute(0, 2, 3, 1))
        torch.testing.assert_close(disp, want, rtol=0, atol=1e-12)
