import math

import pytest
import torch

from torchfluidwarp.core import spectral
from torchfluidwarp.core.fluid import divergence, gradient, vector_laplacian
from torchfluidwarp.core.grid import FluidGrid, interior_mask


@pytest.mark.parametrize("n", [1, 2, 5, 8, 9, 16])
def test_dct_and_dst_match_their_definitions(n, gen):
    x = torch.randn(3, n, generator=gen, dtype=torch.float64)
    k = torch.arange(n, dtype=torch.float64)
    cos = torch.cos(math.pi * (2 * k[None, :] + 1) * k[:, None] / (2 * n))
    sin = torch.sin(math.pi * (k[None, :] + 1) * (k[:, None] + 1) / (n + 1))
    torch.testing.assert_close(spectral.dct(x), x @ cos.T)
    torch.testing.assert_close(spectral.idct(spectral.dct(x)), x)
    torch.testing.assert_close(spectral.dst1(x), x @ sin.T)
    torch.testing.assert_close(spectral.idst1(spectral.dst1(x)), x)


@pytest.mark.parametrize("shape", [(7, 9), (16, 16), (300, 260)])  # 300 > DENSE_MAX: the FFT path
def test_fast_solves_invert_the_grid_operators(shape, gen):
    h, w = shape
    b = torch.randn(2, 1, h, w, generator=gen, dtype=torch.float64)
    b = b - b.mean(dim=(-2, -1), keepdim=True)
    p = spectral.solve_pressure_poisson(b)
    torch.testing.assert_close(-divergence(gradient(p)), b, atol=1e-10, rtol=0)
    assert p.mean(dim=(-2, -1)).abs().max() < 1e-12
    v = torch.randn(2, 2, h + 1, w + 1, generator=gen, dtype=torch.float64)
    v = v * interior_mask(FluidGrid(h, w), dtype=torch.float64)
    alpha = torch.tensor([0.3, 2.5], dtype=torch.float64)
    x = spectral.solve_velocity_helmholtz(v, alpha)
    torch.testing.assert_close(x - alpha.view(-1, 1, 1, 1) * vector_laplacian(x), v, atol=1e-10, rtol=0)
