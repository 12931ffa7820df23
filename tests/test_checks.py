"""The input validators shared by the public functions."""

import pytest
import torch

from torchfluidwarp._checks import all_finite, check_tensor


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), float("-inf")])
def test_all_finite_finds_one_bad_value(bad):
    x = torch.zeros(2, 3, 17, 17)
    assert all_finite(x)
    x[1, 2, 16, 3] = bad
    assert not all_finite(x)
    with pytest.raises(ValueError, match="non-finite"):
        check_tensor("velocity", x)


def test_all_finite_is_not_fooled_by_a_sum_that_overflows():
    x = torch.full((10,), 1e308, dtype=torch.float64)  # finite values whose sum overflows float64
    assert all_finite(x)
    x[3] = -x[3]  # +inf and -inf cancel into NaN in the sum
    x[0] = float("inf")
    x[1] = float("-inf")
    assert not all_finite(x)
