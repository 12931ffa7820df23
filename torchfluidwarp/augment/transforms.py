"""Random fluid warps as a torchvision v2 transform, over tv_tensors and plain tensors.

Importing this module imports torchvision (``pip install torchfluidwarp[vision]``); the rest of the library
never does. Reach the transform as ``torchfluidwarp.RandomFluidWarp`` (imported lazily, on first access) or
``from torchfluidwarp.augment.transforms import RandomFluidWarp``. This module imports
:mod:`torchfluidwarp.augment.tensor`
(the tensor-level :class:`~torchfluidwarp.augment.tensor.FluidWarpAugment` draws the warp), never the reverse.

One draw of random forces per call (:meth:`RandomFluidWarp.make_params`) serves every input of the sample,
each moved by the kernel for its type (:func:`fluid_warp`); with ``p < 1`` the draw first decides, with probability
``p``, whether the sample is warped at all:

==========================================  =====================================================================
``tv_tensors.Image``, ``Video``, plain       resampled bilinearly through the backward map, ``(..., C, H, W)``;
tensors, PIL images                          integer images are rounded back to their dtype
``tv_tensors.Mask``                          nearest sampling, so labels and binary masks keep their values
``tv_tensors.KeyPoints``                     carried by the forward map: RK2 particles through the same velocities
``tv_tensors.BoundingBoxes``                 outline (corners and ``edge_points`` per edge) carried like keypoints;
                                             axis-aligned formats get the box around it, rotated formats the box
                                             with the original orientation around it; format, ``canvas_size`` and
                                             ``clamping_mode`` are kept
anything else (labels, strings, ...)         passed through untouched
==========================================  =====================================================================

Conventions: torchvision's keypoints have pixel centres at integers, like the library's; its boxes have pixel
*edges* at integers (a box around the whole image is ``[0, 0, W, H]``), so boxes are shifted by half a pixel
on their way through the fluid and back. Keypoints and boxes are carried in their own ``canvas_size``: the
fluid covers the canvas whatever its resolution.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any, TypeVar

import PIL.Image
import torch
from torch import Tensor
from torchvision import tv_tensors
from torchvision.transforms import v2
from torchvision.transforms.v2 import functional as TF

from torchfluidwarp._checks import check_tensor
from torchfluidwarp.augment.carry import _resample, carry_boxes, carry_points, fluid_warp_map, polygon_outline
from torchfluidwarp.augment.draw import FluidWarpParams
from torchfluidwarp.augment.tensor import FluidWarpAugment

__all__ = ["RandomFluidWarp", "fluid_warp", "register_fluid_kernel"]

Kernel = Callable[..., Any]
_KERNELS: dict[type, Kernel] = {}
_T = TypeVar("_T")


def register_fluid_kernel(cls: type) -> Callable[[Kernel], Kernel]:
    """Register ``kernel(inpt, params, *, edge_points)`` as :func:`fluid_warp`'s kernel for ``cls``.

    The library registers kernels for plain tensors, ``Image``, ``Video``, ``Mask``, ``KeyPoints``,
    ``BoundingBoxes`` and PIL images; use this for your own ``TVTensor`` subclasses (which otherwise pass
    through), like ``torchvision.transforms.v2.functional.register_kernel``.
    """

    def decorator(kernel: Kernel) -> Kernel:
        _KERNELS[cls] = kernel
        return kernel

    return decorator


def fluid_warp(inpt: _T, params: FluidWarpParams, *, edge_points: int = 8) -> _T:
    """Move one input through a drawn warp (batch 1), dispatching on its type; unknown types pass through.

    Args:
        inpt: an image-like tensor ``(..., C, H, W)``, a ``tv_tensors`` object, a PIL image, or anything else.
        params: a draw for batch 1 (:meth:`RandomFluidWarp.make_params`).

    Raises:
        ValueError: an image, video, mask, keypoint or box tensor holding NaN or inf, naming its kind.
        edge_points: points carried per box edge.

    Returns:
        the moved input, of the same type (tv_tensor metadata kept).
    """
    for cls in type(inpt).__mro__:
        if cls in _KERNELS:
            return _KERNELS[cls](inpt, params, edge_points=edge_points)
        if cls is tv_tensors.TVTensor:  # a TVTensor we do not know is not an image: leave it alone
            break
    return inpt


def _images(x: Tensor, params: FluidWarpParams, mode: str) -> Tensor:
    """Warp ``(..., C, H, W)`` (every leading index with the same map)."""
    H, W = x.shape[-2:]
    flat = x.reshape(-1, *x.shape[-3:]) if x.ndim >= 3 else x.reshape(1, 1, H, W)
    coords = fluid_warp_map(params, (H, W))  # (1, H, W, 2)
    out = _resample(flat, coords.expand(flat.shape[0], -1, -1, -1), mode)  # type: ignore[arg-type]
    return out.reshape(x.shape)


@register_fluid_kernel(Tensor)
def _plain_kernel(x: Tensor, params: FluidWarpParams, **_: Any) -> Tensor:
    return _images(x, params, "bilinear")


def _finite(kind: str, x: Tensor) -> Tensor:
    """``x`` as a plain tensor, refused with a ``ValueError`` naming its kind when it holds NaN or inf."""
    return check_tensor(kind, x.as_subclass(Tensor), floating=False)


@register_fluid_kernel(tv_tensors.Image)
def _image_kernel(x: tv_tensors.Image, params: FluidWarpParams, **_: Any) -> tv_tensors.Image:
    return tv_tensors.wrap(_images(x.as_subclass(Tensor), params, "bilinear"), like=x)


@register_fluid_kernel(tv_tensors.Video)
def _video_kernel(x: tv_tensors.Video, params: FluidWarpParams, **_: Any) -> tv_tensors.Video:
    return tv_tensors.wrap(_images(_finite("video (tv_tensors.Video)", x), params, "bilinear"), like=x)


@register_fluid_kernel(tv_tensors.Mask)
def _mask_kernel(x: tv_tensors.Mask, params: FluidWarpParams, **_: Any) -> tv_tensors.Mask:
    m = _finite("mask (tv_tensors.Mask)", x)
    if m.numel() == 0:  # no objects, (0, H, W): nothing to move
        return x
    flat = m.reshape(1, -1, *m.shape[-2:])  # every mask a channel: (1, K, H, W)
    return tv_tensors.wrap(_images(flat, params, "nearest").reshape(m.shape), like=x)


@register_fluid_kernel(PIL.Image.Image)
def _pil_kernel(x: PIL.Image.Image, params: FluidWarpParams, **_: Any) -> PIL.Image.Image:
    return TF.to_pil_image(_images(TF.pil_to_tensor(x), params, "bilinear"), mode=x.mode)


def _as_float(x: Tensor, params: FluidWarpParams) -> Tensor:
    return x.to(params.velocities.dtype)


def _back(x: Tensor, like: Tensor) -> Tensor:
    return x.to(like.dtype) if like.is_floating_point() else x.round().to(like.dtype)


@register_fluid_kernel(tv_tensors.KeyPoints)
def _keypoints_kernel(x: tv_tensors.KeyPoints, params: FluidWarpParams, **_: Any) -> tv_tensors.KeyPoints:
    p = _finite("keypoints (tv_tensors.KeyPoints)", x)
    if p.numel() == 0:
        return x
    moved = carry_points(params, _as_float(p, params).reshape(1, -1, 2), tuple(x.canvas_size))
    return tv_tensors.wrap(_back(moved.reshape(p.shape), p), like=x)


def _oriented_box(corners: Tensor, moved: Tensor) -> Tensor:
    """The box with the orientation of ``corners`` ``(N, 4, 2)`` around ``moved`` ``(N, P, 2)``: ``(N, 4, 2)``."""
    top, side = corners[:, 1] - corners[:, 0], corners[:, 3] - corners[:, 0]
    eps = torch.finfo(corners.dtype).eps * 100
    # the box's own axes: along its top edge, and the perpendicular that points down its side
    a = torch.where(top.norm(dim=-1, keepdim=True) > eps, top, torch.stack([side[:, 1], -side[:, 0]], -1))
    a = torch.where(a.norm(dim=-1, keepdim=True) > eps, a, torch.tensor([1.0, 0.0], dtype=a.dtype, device=a.device))
    a = a / a.norm(dim=-1, keepdim=True)
    b = torch.stack([-a[:, 1], a[:, 0]], -1)
    b = torch.where(((b * side).sum(-1, keepdim=True) < 0), -b, b)
    s, t = (moved * a[:, None]).sum(-1), (moved * b[:, None]).sum(-1)  # (N, P)
    s0, s1, t0, t1 = s.amin(1), s.amax(1), t.amin(1), t.amax(1)

    def at(u: Tensor, v: Tensor) -> Tensor:
        return u[:, None] * a + v[:, None] * b

    return torch.stack([at(s0, t0), at(s1, t0), at(s1, t1), at(s0, t1)], dim=1)


@register_fluid_kernel(tv_tensors.BoundingBoxes)
def _boxes_kernel(
    x: tv_tensors.BoundingBoxes, params: FluidWarpParams, *, edge_points: int = 8
) -> tv_tensors.BoundingBoxes:
    data = _finite("boxes (tv_tensors.BoundingBoxes)", x)
    if data.numel() == 0:
        return x
    fmt, canvas = x.format, tuple(x.canvas_size)
    boxes = _as_float(data, params)
    # both branches: torchvision's box edges at integers -> library pixels (centres at integers), -0.5, and back
    if not tv_tensors.is_rotated_bounding_format(fmt):
        xyxy = TF.convert_bounding_box_format(boxes, old_format=fmt, new_format=tv_tensors.BoundingBoxFormat.XYXY)
        moved = carry_boxes(params, xyxy.reshape(1, -1, 4) - 0.5, canvas, edge_points, clip=False)[0] + 0.5
        work_fmt = tv_tensors.BoundingBoxFormat.XYXY
    else:
        work_fmt = tv_tensors.BoundingBoxFormat.XYXYXYXY
        corners = TF.convert_bounding_box_format(boxes, old_format=fmt, new_format=work_fmt).reshape(-1, 4, 2)
        outline = polygon_outline(corners[None] - 0.5, edge_points)  # (1, N, 4E, 2)
        carried = carry_points(params, outline.reshape(1, -1, 2), canvas).reshape(corners.shape[0], -1, 2) + 0.5
        moved = _oriented_box(corners, carried).reshape(-1, 8)
    moved = TF.clamp_bounding_boxes(moved, format=work_fmt, canvas_size=canvas, clamping_mode=x.clamping_mode)
    if not data.is_floating_point() and work_fmt == tv_tensors.BoundingBoxFormat.XYXY:
        # integer boxes: round outwards, so that they still hold what they held
        moved = torch.cat([moved[:, :2].floor(), moved[:, 2:].ceil()], dim=-1)
    out = TF.convert_bounding_box_format(moved, old_format=work_fmt, new_format=fmt)
    return tv_tensors.wrap(_back(out.reshape(data.shape), data), like=x)


class RandomFluidWarp(v2.Transform):
    """Random fluid warp as a torchvision v2 transform: one random incompressible flow per call moves every
    image, video, mask, keypoint set and box set of the sample consistently.

    It takes tv_tensors, PIL images and plain tensors alike: a plain tensor ``(..., C, H, W)`` is treated as an
    image, as by every v2 transform (``RandomFluidWarp()(torch.rand(3, 64, 64))``). For per-sample draws over a
    batch of plain tensors, with keypoints, masks and boxes as keyword tensors, use the tensor-level
    :class:`~torchfluidwarp.augment.tensor.FluidWarpAugment`, which this transform draws through.

    Args:
        count, strength, radius, steps, grid, dt, viscosity, edge_points, max_retries: the settings, as for
            :class:`~torchfluidwarp.augment.tensor.FluidWarpAugment` and documented once in
            :class:`~torchfluidwarp.augment.settings.FluidWarpSettings` (ranges ``(min, max)`` or a number; the
            grid covers the canvas whatever its size).
        settings: a ready :class:`~torchfluidwarp.augment.settings.FluidWarpSettings` instead.
        p: the probability that a call warps its sample, in ``[0, 1]`` (torchvision's ``p``, drawn with
            ``generator``); a call that does not returns its inputs as they came. Default 1: always, and nothing
            drawn for it.
        generator: ``torch.Generator`` or ``None`` (torch's global RNG, which ``DataLoader`` seeds per worker).
            A generator is pickled into each ``DataLoader`` worker and re-seeded there from its seed and the
            worker's seed, so workers draw different warps; either way a loader seeded with
            ``generator=torch.Generator().manual_seed(s)`` draws the same warps on every run (see
            :class:`~torchfluidwarp.augment.tensor.FluidWarpAugment`).

    A sample is warped as one: batched images ``(B, C, H, W)`` in one call share one warp, as for every
    torchvision transform. Works in ``v2.Compose``, on dicts and tuples, and in ``DataLoader`` workers.

    Raises:
        ValueError: on a call, an image, video, mask, keypoint or box tensor holding NaN or inf; the message
            names which (e.g. ``mask (tv_tensors.Mask)``).

    Example:
        >>> from torchvision import tv_tensors
        >>> from torchvision.transforms import v2
        >>> t = v2.Compose([RandomFluidWarp(generator=torch.Generator().manual_seed(0)),
        ...                 v2.ToDtype(torch.float32, scale=True)])
        >>> sample = {"image": tv_tensors.Image(torch.zeros(3, 64, 64, dtype=torch.uint8)),
        ...           "boxes": tv_tensors.BoundingBoxes([[8, 8, 40, 30]], format="XYXY", canvas_size=(64, 64)),
        ...           "label": 3}
        >>> out = t(sample)
        >>> type(out["image"]).__name__, out["boxes"].canvas_size, out["label"]
        ('Image', (64, 64), 3)
    """

    _transformed_types = (
        tv_tensors.Image,
        tv_tensors.Video,
        tv_tensors.Mask,
        tv_tensors.KeyPoints,
        tv_tensors.BoundingBoxes,
        PIL.Image.Image,
        TF.is_pure_tensor,
    )

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__()
        self.sampler = FluidWarpAugment(*args, **kwargs)  # the settings are checked there, once

    __init__.__signature__ = inspect.signature(FluidWarpAugment.__init__)  # type: ignore[attr-defined]

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.sampler.extra_repr()})"

    @property
    def p(self) -> float:
        """The probability that a call warps its sample."""
        return self.sampler.p

    def make_params(self, flat_inputs: list[Any]) -> dict[str, Any]:
        try:
            size = v2.query_size(flat_inputs)
        except (TypeError, ValueError) as exc:  # torchvision's own message, which names no argument
            raise type(exc)(f"sample: {exc}") from exc
        chosen = self.sampler._chosen(1)
        if chosen is not None and chosen.numel() == 0:  # not this time: transform passes every input through
            return {"fluid": None}
        device, dtype = torch.device("cpu"), torch.float32
        for inpt in flat_inputs:
            if isinstance(inpt, Tensor) and not isinstance(inpt, (tv_tensors.KeyPoints, tv_tensors.BoundingBoxes)):
                device = inpt.device
                dtype = inpt.dtype if inpt.dtype == torch.float64 else torch.float32
                break
        return {"fluid": self.sampler.make_params(1, size, device=device, dtype=dtype)}

    def transform(self, inpt: Any, params: dict[str, Any]) -> Any:
        if params["fluid"] is None:
            return inpt
        return fluid_warp(inpt, params["fluid"], edge_points=self.sampler.settings.edge_points)
