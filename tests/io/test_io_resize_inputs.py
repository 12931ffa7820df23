"""resize_image refuses non-finite images by name instead of smearing them (#19)."""

from __future__ import annotations

import pytest
import torch

from torchfluidwarp.io import resize_image


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_a_non_finite_image_is_refused(bad):
    image = torch.rand(1, 3, 8, 8)
    image[0, 1, 4, 4] = bad
    with pytest.raises(ValueError, match="image contains non-finite"):
        resize_image(image, (5, 11))
    assert resize_image(torch.rand(1, 3, 8, 8), (5, 11)).isfinite().all()


def test_shrink_image_refuses_a_non_finite_image_even_when_it_is_small_enough():
    from torchfluidwarp.io import shrink_image

    image = torch.rand(1, 3, 8, 8)
    image[0, 0, 0, 0] = float("inf")
    with pytest.raises(ValueError, match="image contains non-finite"):
        shrink_image(image, 10**9)
