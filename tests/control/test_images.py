import warnings

import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.control.images import _level_grids, fit_images
from torchfluidwarp.control.losses import image_loss, mse_loss, ncc_loss, ssim_loss
from torchfluidwarp.core.grid import FluidGrid
from torchfluidwarp.data import load_sample
from torchfluidwarp.errors import InputError, InputTypeError
from torchfluidwarp.warp.forces import Brushes
from torchfluidwarp.warp.frames import jacobian_determinant
from torchfluidwarp.warp.layer import FluidWarp

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def astronaut64():
    return F.interpolate(
        load_sample("astronaut"), size=(64, 64), mode="bilinear", antialias=True, align_corners=False
    ).double()


def _blob(cx, cy, n=32, sigma=5.0):
    yy, xx = torch.meshgrid(torch.arange(n, dtype=torch.float64), torch.arange(n, dtype=torch.float64), indexing="ij")
    return torch.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * sigma**2))[None, None]


def test_recovers_a_known_brush_warp(astronaut64):
    brushes = Brushes([[24.0, 30.0], [44.0, 36.0]], [[1.0, 0.3], [-0.2, -1.0]], radius=9.0, amplitude=0.3).double()
    with torch.no_grad():
        target = FluidWarp(32, 6).double()(astronaut64, brushes)[:, -1]
    fit = fit_images(
        astronaut64,
        target,
        loss="mse",
        compressible=False,  # the warp was made in the incompressible fluid: the paper's setting recovers it
        grid=32,
        levels=(16,),
        steps=6,
        control=(6, 6),
        max_iter=(20, 40),
        progress=False,
    )
    assert fit.initial_loss == pytest.approx(float(mse_loss(astronaut64, target)))
    assert fit.final_loss < 0.01 * fit.initial_loss, fit.message
    assert [lv.grid for lv in fit.levels] == [(16, 16), (32, 32)]
    assert [lv.image_size for lv in fit.levels] == [(32, 32), (64, 64)]
    assert fit.evaluations == len(fit.loss_history) == sum(lv.evaluations for lv in fit.levels)
    with torch.no_grad():
        torch.testing.assert_close(fit.warp(astronaut64, fit.forces)[:, -1], fit.warped)
        maps = fit.warp.maps(fit.forces, (64, 64))
    assert jacobian_determinant(maps[:, -1]).amin() > 0
    assert fit.min_det.amin() > 0


def test_ncc_ignores_brightness_and_contrast():
    source = _blob(14.0, 16.0)
    target = 0.6 * _blob(18.0, 15.0) + 0.2
    fit = fit_images(source, target, loss="ncc", grid=16, levels=None, steps=4, control=3, max_iter=40, progress=False)
    assert fit.final_loss < 0.05 * fit.initial_loss, fit.message
    assert float(ncc_loss(2 * source + 0.5, source)) == pytest.approx(0.0, abs=1e-9)


def test_landmarks_pull_points_onto_their_targets():
    image = _blob(16.0, 16.0)
    src = torch.tensor([[10.0, 12.0], [20.0, 18.0]], dtype=torch.float64)
    tgt = src + torch.tensor([2.0, -1.0], dtype=torch.float64)
    fit = fit_images(
        image,
        image,
        points=(src, tgt),
        point_weight=1.0,
        grid=16,
        levels=None,
        steps=4,
        control=3,
        max_iter=30,
        progress=False,
    )
    with torch.no_grad():
        moved = fit.warp.carry_points(src[None], fit.forces, (32, 32))[0, -1]
    assert (moved - tgt).norm(dim=-1).max() < 0.3
    assert fit.loss_history[-1] < 0.05 * fit.loss_history[0]


def test_ssim_is_zero_for_identical_images_and_grows_with_a_shift():
    gen = torch.Generator().manual_seed(3)
    image = torch.rand(2, 3, 24, 24, generator=gen, dtype=torch.float64)
    assert image_loss("ssim") is ssim_loss
    assert float(ssim_loss(image, image)) == pytest.approx(0.0, abs=1e-9)  # kornia's eps in the ratio
    blob = _blob(14.0, 16.0)
    near, far = float(ssim_loss(_blob(15.0, 16.0), blob)), float(ssim_loss(_blob(18.0, 16.0), blob))
    assert 0 < near < far


@pytest.mark.parametrize("size", [2, 5, 16])
def test_ssim_gradient_flows_on_any_image_size(size):
    gen = torch.Generator().manual_seed(4)
    target = torch.rand(1, 1, size, size, generator=gen, dtype=torch.float64)
    warped = torch.rand(1, 1, size, size, generator=gen, dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(ssim_loss(warped, target), warped)
    assert torch.isfinite(grad).all() and grad.abs().sum() > 0


def test_ssim_gradcheck():
    gen = torch.Generator().manual_seed(5)
    target = torch.rand(1, 1, 8, 8, generator=gen, dtype=torch.float64)
    warped = torch.rand(1, 1, 8, 8, generator=gen, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: ssim_loss(x, target, window_size=5), (warped,))


def test_an_ssim_fit_reduces_the_loss():
    source, target = _blob(14.0, 16.0), _blob(18.0, 16.0)
    fit = fit_images(source, target, loss="ssim", grid=16, levels=(8,), steps=4, control=3, max_iter=20, progress=False)
    assert fit.initial_loss == pytest.approx(float(ssim_loss(source, target)))
    assert fit.final_loss < 0.2 * fit.initial_loss, fit.message


def test_a_callable_loss_and_a_batch():
    source = torch.cat([_blob(14.0, 16.0), _blob(16.0, 14.0)])
    target = torch.cat([_blob(17.0, 16.0), _blob(16.0, 17.0)])
    fit = fit_images(
        source,
        target,
        loss=lambda a, b: (a - b).abs().mean() * 2,
        grid=16,
        levels=(8,),
        steps=3,
        control=3,
        max_iter=10,
        progress=False,
    )
    assert fit.warped.shape == (2, 1, 32, 32) and fit.forces.weight.shape == (2, 3, 2, 3, 3)
    assert fit.final_loss < fit.initial_loss


@pytest.mark.parametrize(
    "grid, sides",
    [(64, [16, 32, 64]), (128, [16, 32, 64, 128]), ((20, 40), [20, 40]), (22, [22]), (8, [8])],
)
def test_auto_levels_halve_the_grid_down_to_the_coarsest_level(grid, sides):
    grids = _level_grids(FluidGrid.of(grid), "auto")
    assert [max(g.shape) for g in grids] == sides and grids[-1] == FluidGrid.of(grid)


def test_a_grid_set_without_levels_fits_on_levels_that_suit_it():
    # the default levels used to be (16, 32, 64) whatever the grid, so any grid under 64 cells was refused
    # the MSE: a lone blob leaves most windows flat, where the local correlation (the default loss) cannot improve
    blob = dict(loss="mse", grid=12, steps=4, control=3, progress=False, max_iter=20)
    fit = fit_images(_blob(14.0, 16.0), _blob(16.0, 16.0), **blob)
    assert [lv.grid for lv in fit.levels] == [(12, 12)]
    assert fit.final_loss < 0.5 * fit.initial_loss


def test_a_fit_whose_map_folds_warns_with_the_count_and_regularization_calms_it():
    # a blob pulled across the picture in an incompressible fluid: the flow swirls until the map folds
    source, target = _blob(8.0, 8.0, sigma=4.0), _blob(24.0, 24.0, sigma=4.0)
    kw = dict(loss="mse", compressible=False, grid=16, levels=None, steps=4, control=4, max_iter=40, progress=False)
    # the swirl misses the blob's travel too, and says so (a shift by it matches far better)
    with pytest.warns(RuntimeWarning, match=r"fit_images: moving source's content by \(\+16, \+16\) px \(x, y\)"):
        with pytest.warns(RuntimeWarning, match=r"fit_images: the fitted map folds on \d+ of 1024 pixels") as caught:
            fit = fit_images(source, target, **kw)
    folded = int(str(caught[0].message).split("folds on ")[1].split()[0])
    with torch.no_grad():
        det = jacobian_determinant(fit.warp.maps(fit.forces, (32, 32))[:, -1])  # the map fit_images judged
    assert folded == int((det <= 0).sum()) > 0 and float(fit.min_det) <= 0
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        warnings.filterwarnings("error", message="fit_images: the fitted map folds")  # a calmer flow: no fold
        calm = fit_images(source, target, regularization=1e-2, **kw)
    assert float(calm.min_det) > 0
    # but it barely moves the blob, and says so: a plain shift by the blob's travel matches far better
    assert calm.final_loss > 0.9 * calm.initial_loss
    shift = "fit_images: moving source's content by (+16, +16) px (x, y)"  # the blob's travel, (8, 8) to (24, 24)
    assert [str(w.message).split(" matches")[0] for w in said] == [shift]


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"loss": "l1"}, "loss"),
        ({"levels": (16, 8)}, "levels"),
        ({"levels": (32,)}, "levels"),
        ({"levels": "coarse"}, "levels"),
        ({"target": torch.zeros(1, 1, 16, 16)}, "target"),
        ({"source": torch.full((1, 1, 32, 32), float("nan"))}, "source"),
        ({"max_iter": (5, 5, 5)}, "max_iter"),
        ({"points": (torch.tensor([[40.0, 3.0]]), torch.tensor([[3.0, 3.0]]))}, "points"),
        ({"points": (torch.zeros(2, 2), torch.zeros(3, 2))}, "points"),
        ({"steps": 0}, "steps"),
        ({"control": (1, 3)}, "control"),
    ],
)
def test_bad_inputs_name_the_argument(kwargs, name):
    args = {
        "source": _blob(14.0, 16.0),
        "target": _blob(16.0, 16.0),
        "grid": 16,
        "levels": (8,),
        "progress": False,
        **kwargs,
    }
    with pytest.raises(ValueError, match=name):
        fit_images(args.pop("source"), args.pop("target"), **args)


def _detached_mse(warped, target):
    return ((warped - target) ** 2).mean().detach()


def _no_grad_mse(warped, target):
    with torch.no_grad():
        return ((warped - target) ** 2).mean()


@pytest.mark.parametrize("loss", [_detached_mse, _no_grad_mse])
@pytest.mark.parametrize("regularization", [0.0, 1e-3])  # with it, the objective has a graph without the loss's
def test_a_loss_without_a_graph_is_an_input_error_naming_loss(loss, regularization):
    with pytest.raises(InputError, match="loss returned a tensor without an autograd graph") as info:
        fit_images(
            _blob(14.0, 16.0),
            _blob(16.0, 16.0),
            loss=loss,
            regularization=regularization,
            grid=16,
            levels=None,
            steps=2,
            control=3,
            max_iter=2,
            progress=False,
        )
    assert info.value.argument == "loss"


def test_a_loss_that_returns_no_scalar_tensor_is_the_callers_error():
    args = {"grid": 16, "levels": None, "steps": 2, "control": 3, "max_iter": 2, "progress": False}
    with pytest.raises(InputTypeError, match="loss must return a tensor, got float") as info:
        fit_images(_blob(14.0, 16.0), _blob(16.0, 16.0), loss=lambda w, t: float(((w - t) ** 2).mean()), **args)
    assert info.value.argument == "loss"
    with pytest.raises(InputError, match="loss must return a scalar") as info:
        fit_images(_blob(14.0, 16.0), _blob(16.0, 16.0), loss=lambda w, t: (w - t) ** 2, **args)
    assert info.value.argument == "loss"


@pytest.mark.parametrize("empty", ["source", "target", "both"])
def test_an_empty_batch_is_an_input_error_naming_it(empty):
    blob = _blob(14.0, 16.0)
    source = blob[:0] if empty in ("source", "both") else blob
    target = blob[:0] if empty in ("target", "both") else blob
    with pytest.raises(InputError, match="must hold at least one image, got an empty batch") as info:
        fit_images(source, target, grid=16, levels=None, steps=2, control=3, max_iter=2, progress=False)
    assert info.value.argument == ("target" if empty == "target" else "source")
