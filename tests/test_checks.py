"""The input validators shared by the public functions."""

import numpy as np
import pytest
import torch

from torchfluidwarp._checks import all_finite, check_picture, check_tensor, describe


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), float("-inf")])
def test_all_finite_finds_one_bad_value(bad):
    x = torch.zeros(2, 3, 17, 17)
    assert all_finite(x)
    x[1, 2, 16, 3] = bad
    assert not all_finite(x)
    with pytest.raises(
        ValueError, match=r"velocity contains non-finite values \(NaN or inf\): 1, the first at index \(1, 2, 16, 3\)"
    ):
        check_tensor("velocity", x)


def test_a_single_picture_where_a_batch_goes_is_told_how_to_make_one():
    with pytest.raises(
        ValueError, match=r"image must have 4 dimensions, got shape \(3, 8, 8\); image\[None\] makes a batch of one"
    ):
        check_tensor("image", torch.zeros(3, 8, 8), ndim=4)
    with pytest.raises(ValueError, match=r"got shape \(8, 8\)$"):  # not one short of a batch: no such advice
        check_tensor("image", torch.zeros(8, 8), ndim=4)


def test_all_finite_is_not_fooled_by_a_sum_that_overflows():
    x = torch.full((10,), 1e308, dtype=torch.float64)  # finite values whose sum overflows float64
    assert all_finite(x)
    x[3] = -x[3]  # +inf and -inf cancel into NaN in the sum
    x[0] = float("inf")
    x[1] = float("-inf")
    assert not all_finite(x)


def test_describe_says_an_arrays_shape_and_dtype_never_its_values_and_cuts_long_reprs():
    array = np.zeros((1137, 910, 3), dtype=np.uint8)
    assert describe(array) == "numpy.ndarray of shape (1137, 910, 3) and dtype uint8"
    text = describe(list(range(1000)))
    assert text.startswith("list [0, 1, 2") and text.endswith("...") and len(text) < 100
    assert describe("abc") == "str 'abc'"


@pytest.mark.parametrize(
    "value, match",
    [
        (np.zeros((16, 16, 3), dtype=np.uint8), r"got numpy.ndarray of shape \(16, 16, 3\).*torch.from_numpy"),
        (torch.zeros(3, 16, 16, dtype=torch.uint8), r"dtype torch.uint8.*\.float\(\) / 255"),
        (torch.zeros(16, 16, 3), r"channels look last.*permute\(2, 0, 1\)"),
        (torch.zeros(2, 16, 16, 4), r"channels look last.*permute\(0, 3, 1, 2\)"),
    ],
    ids=["numpy", "uint8", "channels-last", "batch-channels-last"],
)
def test_a_picture_in_another_form_is_refused_with_how_to_make_one(value, match):
    with pytest.raises((TypeError, ValueError), match=match) as caught:
        check_picture("image_a", value)
    assert caught.value.argument == "image_a"


def test_pictures_in_the_librarys_form_pass_whatever_their_channels():
    for shape in [(3, 16, 16), (1, 4, 16, 3), (2, 1, 3, 3), (64, 8, 8)]:  # a picture 3 px wide with 4 channels too
        x = torch.rand(shape)
        assert check_picture("image", x) is x


@pytest.mark.parametrize(
    "value, match",
    [
        ([[10, 12], [40, 8], [25, 30]], r"points_a must be a torch.Tensor, got list .*; torch.as_tensor\(value, "),
        (torch.tensor([[10, 12], [40, 8], [25, 30]]), r"dtype torch.int64; .float\(\) makes one"),
    ],
)
def test_points_in_another_form_are_refused_with_the_conversion_that_works(value, match):
    with pytest.raises(TypeError, match=match):
        check_tensor("points_a", value, shape=[None, 2])
    made = torch.as_tensor(value, dtype=torch.float32) if isinstance(value, list) else value.float()
    assert check_tensor("points_a", made, shape=[None, 2]) is made  # the conversion named passes
