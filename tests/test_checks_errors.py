"""The error taxonomy (:mod:`torchfluidwarp.errors`) and the validators' use of it (:mod:`torchfluidwarp._checks`)."""

import pickle

import pytest
import torch

from torchfluidwarp._checks import (
    argument_of,
    check_int,
    check_memory,
    check_positive,
    check_returned_loss,
    check_size,
    check_tensor,
)
from torchfluidwarp.errors import FlowBlewUp, Hint, InputError, InputTypeError

HINT = Hint(
    "ask for less, or raise the limit with {setting}",
    "max_memory",
    spelling="f(max_memory=...)",
    otherwise="ask for less",
)


def test_whose_fault_each_error_is():
    assert issubclass(InputError, ValueError) and not issubclass(InputError, TypeError)
    assert issubclass(InputTypeError, TypeError) and not issubclass(InputTypeError, ValueError)
    # a blown-up flow is arithmetic, not a bad value: code that catches ValueError for the caller's input must not
    # swallow it, and a fit that steps back on it catches it alone
    assert issubclass(FlowBlewUp, ArithmeticError)
    assert not issubclass(FlowBlewUp, (ValueError, FloatingPointError, TypeError))


@pytest.mark.parametrize("kind", [InputError, InputTypeError, FlowBlewUp])
def test_errors_keep_their_parts_through_pickle(kind):
    error = kind("n must be >= 1, got 0", argument="n", hint=HINT)
    back = pickle.loads(pickle.dumps(error))  # e.g. raised in a DataLoader worker
    assert type(back) is kind and str(back) == str(error)
    assert (back.message, back.argument, back.hint) == ("n must be >= 1, got 0", "n", HINT)


def test_a_hint_is_said_in_the_callers_terms():
    error = InputError("f needs 9 GiB, above the limit of 8 GiB", hint=HINT)
    assert (
        str(error) == "f needs 9 GiB, above the limit of 8 GiB; ask for less, or raise the limit with f(max_memory=...)"
    )
    assert error.explain({"max_memory": "--max-memory GIB"}).endswith("raise the limit with --max-memory GIB")
    assert error.explain({"steps": "--steps"}) == "f needs 9 GiB, above the limit of 8 GiB; ask for less"
    assert InputError("bad").explain({"x": "--x"}) == str(InputError("bad")) == "bad"
    assert str(FlowBlewUp("blew", hint=Hint("lower {setting}", "dt"))) == "blew; lower dt"


@pytest.mark.parametrize(
    ("call", "kind", "argument"),
    [
        (lambda: check_tensor("points[0]", [1.0]), InputTypeError, "points"),
        (lambda: check_tensor("velocity", torch.zeros(2, 3), ndim=4), InputError, "velocity"),
        (lambda: check_tensor("image", torch.full((2,), float("nan"))), InputError, "image"),
        (lambda: check_int("max_iter", 0), InputError, "max_iter"),
        (lambda: check_int("max_iter", 1.5), InputTypeError, "max_iter"),
        (lambda: check_positive("dt", -1.0), InputError, "dt"),
        (lambda: check_size("control", (1, 3), minimum=2), InputError, "control"),
        (lambda: check_positive("the value", 0.0), InputError, None),  # the command line's name: no argument
    ],
)
def test_validators_raise_input_errors_with_the_argument(call, kind, argument):
    with pytest.raises(kind) as info:
        call()
    assert info.value.argument == argument


@pytest.mark.parametrize(
    ("name", "argument"),
    [
        ("max_iter", "max_iter"),
        ("points[0]", "points"),
        ("brushes[0].radius", "brushes"),
        ("the value", None),
        ("MapConfig(max_memory=...)", None),
        ("--points-b", None),
    ],
)
def test_argument_of(name, argument):
    assert argument_of(name) == argument


def test_check_memory_gives_the_limit_as_a_hint():
    check_memory("f()", 1024.0, 2048.0, "f(max_memory=...)")
    with pytest.raises(InputError, match=r"f\(\) would need about 2.0 KiB, above the limit of 1.0 KiB") as info:
        check_memory("f()", 2048.0, 1024.0, "f(max_memory=...)")
    assert info.value.hint.setting == "max_memory" and info.value.argument is None
    assert str(info.value).endswith("; ask for less, or raise the limit with f(max_memory=...)")


def test_check_returned_loss():
    x = torch.ones(3, requires_grad=True)
    assert check_returned_loss("loss", (x**2).sum()) is not None
    with pytest.raises(InputError, match="loss returned a tensor without an autograd graph") as info:
        check_returned_loss("loss", (x**2).sum().detach())
    assert info.value.argument == "loss"
    with torch.no_grad():
        with pytest.raises(InputError, match="without an autograd graph"):
            check_returned_loss("loss", (x**2).sum())
    check_returned_loss("loss", torch.tensor(1.0), graph=False)
    with pytest.raises(InputError, match=r"loss must return a scalar .* shape \(3,\)"):
        check_returned_loss("loss", x * 2)
    with pytest.raises(InputTypeError, match="loss must return a tensor, got float 1.0"):
        check_returned_loss("loss", 1.0, graph=False)
