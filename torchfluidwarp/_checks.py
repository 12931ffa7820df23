"""One small set of validators for user input.

Every public function calls these at its boundary, so errors name the argument and what was received, and
nothing non-finite can travel on to ``grid_sample`` (whose CPU backward crashes the process on NaN). A bad value
raises :class:`~torchfluidwarp.errors.InputError` (a ``ValueError``), a bad type
:class:`~torchfluidwarp.errors.InputTypeError` (a ``TypeError``), each with the argument's name as its
``argument``.
The dtype policy (:func:`compute_dtype`), the memory limit (:data:`MAX_BYTES`, :func:`check_memory`) and the
library's one way to warn (:func:`warn`, pointing at the caller's line) live here too.
"""

from __future__ import annotations

import math
import os
import re
import sys
import warnings
from collections.abc import Sequence

import torch
from torch import Tensor

from torchfluidwarp.errors import Hint, InputError, InputTypeError


def argument_of(name: str) -> str | None:
    """The argument a checked name refers to (the errors' ``argument``): ``"points"`` for ``"points[0]"`` or
    ``"points.x"``; ``None`` for a name that is no identifier (``"the value"``, ``"MapConfig(max_memory=...)"``)."""
    match = re.fullmatch(r"([A-Za-z_]\w*)(?:[\[.].*)?", name, flags=re.DOTALL)
    return match.group(1) if match else None


def describe(x: object) -> str:
    """A short description of a value for error messages: a tensor's or an array's shape and dtype (never its
    values), other values' repr, cut at 80 characters."""
    if isinstance(x, Tensor):
        return f"tensor of shape {tuple(x.shape)} and dtype {x.dtype}"
    shape, dtype = getattr(x, "shape", None), getattr(x, "dtype", None)
    if isinstance(shape, tuple) and dtype is not None:  # a NumPy array and its kin
        return f"{type(x).__module__.split('.')[0]}.{type(x).__name__} of shape {shape} and dtype {dtype}"
    text = repr(x)
    return f"{type(x).__name__} {text if len(text) <= 80 else text[:77] + '...'}"


IMAGE_FORM = (
    "pictures are floating-point tensors (C, H, W) or (B, C, H, W) with values in [0, 1]: "
    "torchfluidwarp.io.read_image reads a file as one, an (H, W, C) uint8 array converts with "
    "torch.from_numpy(array).permute(2, 0, 1).float() / 255, a (C, H, W) uint8 tensor with .float() / 255"
)
"""How to make a picture the library takes, said when it is given something else."""


def check_picture(name: str, x: object, *, ndim: int | Sequence[int] = (3, 4), features: bool = False) -> Tensor:
    """:func:`check_tensor` for a picture ``(C, H, W)`` or ``(B, C, H, W)``: a value that is not a floating-point
    tensor (a NumPy array, a uint8 tensor as a decoder returns it) is refused with how to make one
    (:data:`IMAGE_FORM`), and so is a picture with its channels last (``(H, W, C)``: 1, 3 or 4 along the last
    axis and more than 4 along the channels'). ``features``: the tensor may be a model's feature map, with any
    number of channels over a few pixels (``(B, 256, 4, 4)``), so its layout is not guessed."""
    if not isinstance(x, Tensor) or not x.is_floating_point():
        raise InputTypeError(
            f"{name} must be a floating-point tensor, got {describe(x)}; {IMAGE_FORM}", argument=argument_of(name)
        )
    x = check_tensor(name, x, ndim=ndim)
    if not features and x.ndim >= 3 and x.shape[-1] in (1, 3, 4) and x.shape[-3] > 4:
        raise InputError(
            f"{name} has shape {tuple(x.shape)}: its channels look last, (H, W, C); pictures are (C, H, W) "
            f"({name}.permute(2, 0, 1) for one picture, .permute(0, 3, 1, 2) for a batch)",
            argument=argument_of(name),
        )
    return x


def all_finite(x: Tensor) -> bool:
    """Whether every element of ``x`` is finite.

    A NaN or inf anywhere makes the sum non-finite, and one reduction is several times cheaper than
    ``isfinite(x).all()`` on the small tensors checked once per fluid step. The sum runs in ``x``'s own dtype, so a
    large frame is checked without a converted copy (a float64 sum of a 6000 x 6000 RGB frame would allocate
    0.8 GB). Only when the sum is not finite is the elementwise test run, so a sum that merely overflows cannot
    raise a false alarm.
    """
    x = x.detach()
    if x.is_complex():
        return bool(torch.isfinite(x).all())
    return math.isfinite(float(x.sum())) or bool(torch.isfinite(x).all())


def check_tensor(
    name: str,
    x: object,
    *,
    ndim: int | Sequence[int] | None = None,
    shape: Sequence[int | None] | None = None,
    finite: bool = True,
    floating: bool = True,
) -> Tensor:
    """Validate a tensor argument and return it.

    Args:
        name: the argument's name, quoted in the error.
        x: the value received.
        ndim: required rank (or ranks).
        shape: required shape; ``None`` entries match any size.
        finite: require every element to be finite.
        floating: require a floating-point dtype.

    Raises:
        InputTypeError: ``x`` is not a tensor, or not floating point when required (a ``TypeError``).
        InputError: wrong rank, shape, or non-finite values (a ``ValueError``).
    """
    if not isinstance(x, Tensor):
        make = "torch.as_tensor(value, dtype=torch.float32)" if floating else "torch.as_tensor(value)"
        raise InputTypeError(
            f"{name} must be a torch.Tensor, got {describe(x)}; {make} makes one", argument=argument_of(name)
        )
    if floating and not x.is_floating_point():
        raise InputTypeError(
            f"{name} must be a floating-point tensor, got dtype {x.dtype}; .float() makes one",
            argument=argument_of(name),
        )
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if x.ndim not in allowed:
            ranks = " or ".join(map(str, allowed))
            one = f"; {name}[None] makes a batch of one" if x.ndim + 1 in allowed and x.ndim + 1 == max(allowed) else ""
            raise InputError(
                f"{name} must have {ranks} dimensions, got shape {tuple(x.shape)}{one}", argument=argument_of(name)
            )
    if shape is not None:
        if x.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, x.shape)):
            want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
            raise InputError(f"{name} must have shape {want}, got {tuple(x.shape)}", argument=argument_of(name))
    if finite and x.numel() and not all_finite(x):
        bad = ~torch.isfinite(x.detach())
        flat = bad.flatten().to(torch.uint8).argmax()  # the first, without indexing every bad value
        first = tuple(int(i) for i in torch.unravel_index(flat, tuple(x.shape)))
        raise InputError(
            f"{name} contains non-finite values (NaN or inf): {int(bad.sum())}, the first at index {first}; "
            f"shape {tuple(x.shape)}",
            argument=argument_of(name),
        )
    return x


def check_positive(name: str, value: float, *, allow_zero: bool = False) -> float:
    """Validate a positive (or non-negative) finite number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputTypeError(f"{name} must be a number, got {describe(value)}", argument=argument_of(name))
    ok = value >= 0 if allow_zero else value > 0
    if not ok or value != value or value in (float("inf"), float("-inf")) or value > _FLOAT_MAX:
        bound = ">= 0" if allow_zero else "> 0"
        raise InputError(f"{name} must be finite and {bound}, got {value!r}", argument=argument_of(name))
    return float(value)


_FLOAT_MAX = 1.7976931348623157e308  # an int beyond it cannot become a float


def check_real(name: str, value: object) -> float:
    """Validate a finite real number (of either sign), e.g. a time step that may run backwards."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputTypeError(f"{name} must be a number, got {describe(value)}", argument=argument_of(name))
    try:
        number = float(value)
    except OverflowError:  # an int too large for a float
        number = math.inf
    if not math.isfinite(number):
        raise InputError(f"{name} must be finite, got {value!r}", argument=argument_of(name))
    return number


def check_int(name: str, value: object, *, minimum: int = 1) -> int:
    """Validate an integer at least ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputTypeError(f"{name} must be an int, got {describe(value)}", argument=argument_of(name))
    if value < minimum:
        raise InputError(f"{name} must be >= {minimum}, got {value}", argument=argument_of(name))
    return value


def check_size(name: str, value: object, *, minimum: int = 1) -> tuple[int, int]:
    """Validate an ``(h, w)`` pair of integers (an int means square)."""
    if isinstance(value, int) and not isinstance(value, bool):
        value = (value, value)
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise InputTypeError(
            f"{name} must be an int or a pair (h, w) of ints, got {describe(value)}", argument=argument_of(name)
        )
    h, w = value
    for v in (h, w):
        if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
            raise InputError(
                f"{name} must be a pair of ints >= {minimum}, got {tuple(value)!r}", argument=argument_of(name)
            )
    return int(h), int(w)


def check_fraction(name: str, value: object) -> float:
    """Validate a weight in ``[0, 1]``; ``True`` means 1 and ``False`` 0 (e.g. ``compressible``)."""
    if isinstance(value, bool):
        return float(value)
    if not isinstance(value, (int, float)):
        raise InputTypeError(
            f"{name} must be a bool or a number in [0, 1], got {describe(value)}", argument=argument_of(name)
        )
    if not 0 <= value <= 1:  # also refuses NaN
        raise InputError(f"{name} must be in [0, 1], got {value!r}", argument=argument_of(name))
    return float(value)


def check_instance(name: str, value: object, kind: type | tuple[type, ...], *, optional: bool = False) -> object:
    """Validate that ``value`` is an instance of ``kind`` (or ``None`` when ``optional``)."""
    if (value is None and optional) or isinstance(value, kind):
        return value
    kinds = kind if isinstance(kind, tuple) else (kind,)
    names = " or ".join(k.__name__ for k in kinds) + (" or None" if optional else "")
    raise InputTypeError(f"{name} must be a {names}, got {describe(value)}", argument=argument_of(name))


def check_float_dtype(name: str, value: object) -> torch.dtype:
    """Validate a floating-point ``torch.dtype`` argument (``dtype="float32"`` and complex dtypes are refused)."""
    if not isinstance(value, torch.dtype):
        raise InputTypeError(
            f"{name} must be a torch.dtype such as torch.float32, got {describe(value)}", argument=argument_of(name)
        )
    if not value.is_floating_point:
        raise InputTypeError(
            f"{name} must be a floating-point dtype (float16, bfloat16, float32 or float64), got {value}",
            argument=argument_of(name),
        )
    return value


def check_returned_loss(name: str, value: object, *, graph: bool = True) -> Tensor:
    """Validate what a caller's function ``name`` (a loss, an objective) returned, and return it.

    Args:
        name: the function's argument name, quoted in the error (``"loss"``).
        value: what it returned.
        graph: require an autograd graph (``requires_grad``), as when its inputs require grad: a value that was
            detached or computed under ``torch.no_grad()`` cannot be differentiated, and autograd's own
            ``RuntimeError`` would not say whose value it was.

    Raises:
        InputTypeError: ``value`` is not a tensor.
        InputError: it has more than one element, or no graph when ``graph``.
    """
    if not isinstance(value, Tensor):
        raise InputTypeError(f"{name} must return a tensor, got {describe(value)}", argument=argument_of(name))
    if value.numel() != 1:
        raise InputError(
            f"{name} must return a scalar (a tensor of one element), got shape {tuple(value.shape)}",
            argument=argument_of(name),
        )
    if graph and not value.requires_grad:
        raise InputError(
            f"{name} returned a tensor without an autograd graph (requires_grad=False: detached, or computed under "
            "torch.no_grad()), so it cannot be differentiated; compute it from its inputs with autograd on",
            argument=argument_of(name),
        )
    return value


# The dtype policy. Images, points and forces of different float dtypes are promoted to the wider one
# (torch.promote_types); half precision (float16, bfloat16) is computed in float32 and returned in the
# input's dtype. Non-float and complex inputs are refused by check_tensor.
def compute_dtype(*dtypes: torch.dtype) -> torch.dtype:
    """The dtype to compute in for inputs of ``dtypes``: their promotion, at least float32."""
    out = dtypes[0]
    for d in dtypes[1:]:
        out = torch.promote_types(out, d)
    return torch.float32 if out in (torch.float16, torch.bfloat16) else out


MAX_BYTES = 8 * 2**30
"""The memory one call may set out to hold for its results, in bytes (8 GiB), unless its ``max_memory``
argument says otherwise. A request above it is refused before any work starts."""


def format_bytes(n: float) -> str:
    """``n`` bytes, in the largest binary unit that keeps it >= 1 (``'1.5 GiB'``)."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"  # unreachable


def check_memory(what: str, nbytes: float, limit: float | None, setting: str, *, name: str = "max_memory") -> None:
    """Refuse a request whose estimated memory ``nbytes`` exceeds ``limit`` (default :data:`MAX_BYTES`).

    Args:
        what: the request, as the message names it (``"morph(frames=30, steps=10, grid=(80, 80))"``).
        nbytes: its estimated memory, in bytes.
        limit: the caller's limit in bytes, or ``None`` for :data:`MAX_BYTES`.
        setting: how a Python caller raises the limit (``"MapConfig(max_memory=...)"``).
        name: the limit's argument name (``"max_memory"``), the :class:`~torchfluidwarp.errors.Hint`'s setting.

    Raises:
        InputError: the estimate is above the limit. The message gives the estimate and the limit; its hint,
            ``setting``.
    """
    limit = MAX_BYTES if limit is None else check_positive(setting, limit)
    if nbytes > limit:
        raise InputError(
            f"{what} would need about {format_bytes(nbytes)}, above the limit of {format_bytes(limit)}",
            hint=Hint(
                "ask for less, or raise the limit with {setting}", name, spelling=setting, otherwise="ask for less"
            ),
        )


_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn(message: str | Warning, category: type[Warning] = UserWarning) -> None:
    """``warnings.warn`` pointing at the line that called the library: the first frame outside torchfluidwarp.

    A fixed ``stacklevel`` lands in library source whenever the warning is raised a call deeper than planned;
    this walks out of the package instead, so ``file:line`` names the user's code and a filter by ``module``
    matches the user's module. (Python 3.12's ``skip_file_prefixes`` does the same; this works on 3.10.)

    Example:
        >>> import warnings
        >>> with warnings.catch_warnings(record=True) as caught:
        ...     warnings.simplefilter("always")
        ...     warn("the marks cross")
        >>> str(caught[0].message)
        'the marks cross'
    """
    level, frame = 2, sys._getframe(1).f_back  # stacklevel 2 is warn's caller; look at the frames above it
    caller = sys._getframe(1)
    while frame is not None and os.path.abspath(caller.f_code.co_filename).startswith(_PACKAGE):
        caller, frame, level = frame, frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level)
