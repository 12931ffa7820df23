"""Random fluid warps for data augmentation, over plain tensors.

One call draws random brush forces per sample (how many brushes, how strong, how wide, for how many steps),
rolls the fluid out once for the whole batch (:mod:`~torchfluidwarp.augment.draw`), and then moves every input
of the call through that same flow (:mod:`~torchfluidwarp.augment.carry`). With ``p < 1`` each sample is warped
with probability ``p`` (like torchvision's random transforms), and only the chosen ones are rolled out:

* images are resampled bilinearly through the **backward map** (where each output pixel reads from);
* masks are resampled by nearest sampling, so label values survive unchanged;
* keypoints are carried by the **forward map**: RK2 particles through the very same velocities
  (:meth:`~torchfluidwarp.warp.layer.FluidWarp.carry_points`), not an approximate inverse;
* boxes become the axis-aligned box around their carried corners *and* points along their edges.

Conventions (as everywhere in the library, see :mod:`torchfluidwarp.core.grid`): images are ``(B, C, H, W)``;
points and boxes are in **pixels** ``(x, y)`` with pixel centres at integers, so the image covers
``[-0.5, W - 0.5] x [-0.5, H - 0.5]``; boxes are ``(x1, y1, x2, y2)`` in the same coordinates.

Two names, one augmentation, one set of settings (:class:`~torchfluidwarp.augment.settings.FluidWarpSettings`):

* :class:`FluidWarpAugment` (this module) is the tensor-level ``nn.Module``: it warps a batch ``(B, C, H, W)``
  with one independent draw per sample, and takes keypoints, masks and boxes as keyword tensors;
  :func:`random_fluid_warp` is the same as a one-shot function.
* ``torchfluidwarp.RandomFluidWarp`` (:class:`torchfluidwarp.augment.transforms.RandomFluidWarp`) is the torchvision v2
  ``Transform`` over tv_tensors (boxes with edges at ``0`` and ``W``) and plain tensors; it draws through a
  :class:`FluidWarpAugment`. torchvision is imported there only: this module never imports it.

Every warp is fold-free: the settings refuse strengths past :data:`~torchfluidwarp.augment.settings.MAX_SHEAR`,
and a drawn sample whose map would fold is rolled out again with half the force
(:func:`~torchfluidwarp.augment.draw.draw_fluid_warp`).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from torchfluidwarp._checks import check_fraction, check_instance, check_tensor, describe
from torchfluidwarp.augment.carry import apply_fluid_warp
from torchfluidwarp.augment.draw import FluidWarpParams, draw_fluid_warp, make_simulator
from torchfluidwarp.augment.settings import FIELDS, FluidWarpSettings, make_settings, settings_signature
from torchfluidwarp.errors import InputError, InputTypeError

__all__ = ["FluidWarpAugment", "random_fluid_warp"]


class FluidWarpAugment(nn.Module):
    """Random fluid warp augmentation over plain tensors: Gaussian brushes push an incompressible fluid that
    carries the image, one independent draw per sample of the batch.

    This is the tensor-level module (formerly ``torchfluidwarp.augment.tensor.RandomFluidWarp``); for a torchvision v2
    pipeline over tv_tensors use ``torchfluidwarp.RandomFluidWarp``
    (:class:`~torchfluidwarp.augment.transforms.RandomFluidWarp`), which draws through this module.

    The draw happens once per call (:meth:`make_params`), and all inputs of the call share it. The whole batch is
    rolled out in one call of the module's :class:`~torchfluidwarp.core.simulator.FluidSimulator` (made once, with
    the module) with per-sample forces, on the input's device and in its floating dtype (float32 for integer
    images); each sample's warp depends on its own brushes only. A seed fixes the warps of a call for its batch
    size: sample ``b`` of a batch is not the warp that the ``b``-th of a run of single-image calls would draw (see
    :func:`~torchfluidwarp.augment.draw.draw_fluid_warp`).

    Args:
        count, strength, radius, steps, grid, dt, viscosity, edge_points, max_retries: the settings, by name
            (the four ranges also by position), documented once in
            :class:`~torchfluidwarp.augment.settings.FluidWarpSettings`; ranges are ``(min, max)`` or a number.
        settings: a ready :class:`~torchfluidwarp.augment.settings.FluidWarpSettings` instead; settings given by
            name next to it replace its fields.
        p: the probability that a sample is warped, in ``[0, 1]``, like ``p`` of torchvision's random transforms
            but drawn per sample of the batch (with ``generator``). The chosen samples are rolled out together; the
            others come back as they were given, and so do all inputs when none is chosen. With ``p = 1`` (the
            default) nothing is drawn for it, so a seed gives the same warps as without it.
        generator: a ``torch.Generator`` for the draws; ``None`` uses torch's default RNG (which ``DataLoader``
            seeds in each worker from its base seed). In a ``DataLoader`` worker a generator is replaced, on the
            first draw there, by a fresh one seeded from its ``initial_seed()`` and the worker's seed
            (``get_worker_info().seed``): workers draw different warps, each epoch new ones, and a loader
            seeded with ``generator=torch.Generator().manual_seed(s)`` draws the same warps on every run. (Its
            state in the main process does not carry over: a copy pickled into each worker would repeat the
            same warps in every worker.)

    Attributes:
        settings: the validated :class:`~torchfluidwarp.augment.settings.FluidWarpSettings` (its fields also read
            as attributes of the module, ``aug.strength``).
        p: the probability that a sample is warped.

    Raises:
        TypeError, ValueError: as :class:`~torchfluidwarp.augment.settings.FluidWarpSettings` (a bad range, or a
            setting strong enough to fold, past :data:`~torchfluidwarp.augment.settings.MAX_SHEAR`), naming the
            argument; a ``p`` outside ``[0, 1]``; a generator that is not one.

    Folds: within that bound, stacked brushes fold no map unless they are wider than about a tenth of the
    image. Each drawn map is checked anyway (:func:`~torchfluidwarp.augment.draw.min_quad_determinant` on the
    composition raster, at least :data:`~torchfluidwarp.augment.draw.MIN_DET`); a sample that fails is rolled out
    again with half its force, up to ``max_retries`` times (``params.force_scale`` records it). So no warp this
    module returns folds.

    Conventions: images ``(B, C, H, W)`` or ``(C, H, W)``; keypoints ``(B, M, 2)`` and boxes ``(B, N, 4)``
    ``(x1, y1, x2, y2)`` in pixels, pixel centres at integers (the image covers ``[-0.5, W - 0.5]``);
    masks ``(B, K, H, W)``. Unbatched inputs drop the leading ``B`` everywhere.

    Example:
        >>> aug = FluidWarpAugment(strength=(0.2, 0.4), generator=torch.Generator().manual_seed(0))
        >>> image = torch.rand(2, 3, 64, 64)
        >>> aug(image).shape
        torch.Size([2, 3, 64, 64])
        >>> out = aug(image, keypoints=torch.tensor([[[20.0, 30.0]], [[40.0, 10.0]]]),
        ...           masks=(image[:, :1] > 0.5), boxes=torch.tensor([[[10.0, 10.0, 30.0, 40.0]]] * 2))
        >>> sorted(out), out["masks"].dtype
        (['boxes', 'image', 'keypoints', 'masks'], torch.bool)
        >>> FluidWarpAugment(p=0.0)(image) is image  # no sample chosen: the input as it was
        True
    """

    @settings_signature
    def __init__(
        self,
        *ranges: Any,
        settings: FluidWarpSettings | None = None,
        p: float = 1.0,
        generator: torch.Generator | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__()
        self.settings = make_settings(settings, *ranges, **kwargs)
        self.p = check_fraction("p", p)
        check_instance("generator", generator, torch.Generator, optional=True)
        self.generator = generator
        self._worker: int | None = None
        self.simulator = make_simulator(self.settings)  # one fluid for every draw: no set-up per call

    def __getattr__(self, name: str) -> Any:
        # the settings' fields read as the module's attributes (aug.strength), as when they were stored on it
        settings = self.__dict__.get("settings")
        if settings is not None and name in FIELDS:
            return getattr(settings, name)
        return super().__getattr__(name)

    def extra_repr(self) -> str:
        return self.settings.describe() + ("" if self.p == 1.0 else f", p={self.p}")

    def _rng(self) -> torch.Generator | None:
        """The generator for this call; a DataLoader worker re-seeds its own copy once."""
        if self.generator is None:
            return None
        info = torch.utils.data.get_worker_info()
        if info is not None and self._worker != info.id:
            # every worker starts from the same pickled state: mix in the worker's seed
            seed = (self.generator.initial_seed() * 6364136223846793005 + info.seed) % (2**63)
            self.generator = torch.Generator(self.generator.device).manual_seed(seed)
            self._worker = info.id
        return self.generator

    def _chosen(self, batch: int) -> Tensor | None:
        """The samples of a batch that this call warps, ``(k,)`` indices in order on the generator's device (the
        CPU without one), each drawn with probability ``p``; ``None`` when ``p`` is 1 (all of them, nothing drawn)."""
        if self.p == 1.0:
            return None
        g = self._rng()
        coins = torch.rand(batch, generator=g, device=g.device if g is not None else torch.device("cpu"))
        return (coins < self.p).nonzero().flatten()

    def make_params(
        self,
        batch: int,
        size: tuple[int, int],
        *,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> FluidWarpParams:
        """Draw the random brushes of one call and roll the fluid out for the whole batch.

        :func:`~torchfluidwarp.augment.draw.draw_fluid_warp` with this module's settings and generator: draws
        happen on the generator's device (CPU without one), so a seed gives the same warp on any device; the
        roll-out then runs on ``device`` in ``dtype`` without autograd.

        Args:
            batch: ``B``.
            size: ``(H, W)`` of the images in pixels.
            device, dtype: where and in which floating dtype to roll out.

        Returns:
            a :class:`FluidWarpParams`.
        """
        return draw_fluid_warp(
            self.settings, batch, size, generator=self._rng(), device=device, dtype=dtype, simulator=self.simulator
        )

    def forward(
        self,
        image: Tensor,
        *,
        keypoints: Tensor | None = None,
        masks: Tensor | None = None,
        boxes: Tensor | None = None,
    ) -> Tensor | dict[str, Tensor]:
        """Warp ``image`` and, through the same draw, the optional keypoints, masks and boxes.

        Args:
            image: ``(B, C, H, W)`` or ``(C, H, W)``, any dtype (integers are rounded back).
            keypoints: ``(B, M, 2)`` (``(M, 2)`` unbatched) pixels ``(x, y)``.
            masks: ``(B, K, H, W)`` (``(K, H, W)`` unbatched), any dtype; nearest sampling.
            boxes: ``(B, N, 4)`` (``(N, 4)`` unbatched) ``(x1, y1, x2, y2)`` pixels.

        Returns:
            the warped image when only an image is given; otherwise a dict with the keys ``"image"`` and those
            of the other inputs given. With ``p < 1`` the samples not chosen are copied through unchanged, and when
            none is, the inputs themselves are returned.

        Raises:
            TypeError, ValueError: inputs that are not tensors or whose shapes do not match the image.
        """
        check_tensor("image", image, ndim=(3, 4), floating=False)
        unbatched = image.ndim == 3
        img = image.unsqueeze(0) if unbatched else image
        B, _, H, W = img.shape
        if image.is_complex() or min(H, W) < 2 or B < 1:
            raise InputError(f"image must be real, non-empty and at least 2 x 2 pixels to warp, got {describe(image)}")

        def batched(name: str, x: Tensor | None, tail: list[int | None], floating: bool) -> Tensor | None:
            if x is None:
                return None
            check_tensor(name, x, floating=floating)
            if x.is_complex():
                raise InputTypeError(f"{name} must be real, got dtype {x.dtype}")
            if x.ndim != len(tail) + (0 if unbatched else 1):
                raise InputError(
                    f"{name} must have {len(tail) + (0 if unbatched else 1)} dimensions to go with an image of shape "
                    f"{tuple(image.shape)}, got shape {tuple(x.shape)}"
                )
            x = x.unsqueeze(0) if unbatched else x
            if x.shape[0] != B:
                raise InputError(
                    f"{name} has a batch of {x.shape[0]} but image has {B}: {name} must have shape "
                    f"({B}, {', '.join('*' if t is None else str(t) for t in tail)}) to go with an image of shape "
                    f"{tuple(image.shape)}, got shape {tuple(x.shape)}"
                )
            return check_tensor(name, x, shape=[B, *tail], floating=floating)

        kp = batched("keypoints", keypoints, [None, 2], True)
        mk = batched("masks", masks, [None, H, W], False)
        bx = batched("boxes", boxes, [None, 4], True)
        given = {k: v for k, v in (("image", img), ("keypoints", kp), ("masks", mk), ("boxes", bx)) if v is not None}
        chosen = self._chosen(B)
        if chosen is not None and chosen.numel() == 0:  # nothing to warp: the inputs as they came
            as_given = {"image": image, "keypoints": keypoints, "masks": masks, "boxes": boxes}
            return image if len(given) == 1 else {k: v for k, v in as_given.items() if v is not None}
        if chosen is not None and chosen.numel() < B:  # roll out the chosen samples only
            pick = {k: v.index_select(0, chosen.to(v.device)) for k, v in given.items()}
        else:
            pick, chosen = given, None
        dtype = img.dtype if img.is_floating_point() else torch.float32
        params = self.make_params(pick["image"].shape[0], (H, W), device=img.device, dtype=dtype)
        edge_points = self.settings.edge_points
        out = apply_fluid_warp(
            params,
            pick["image"],
            keypoints=pick.get("keypoints"),
            masks=pick.get("masks"),
            boxes=pick.get("boxes"),
            edge_points=edge_points,
        )
        if chosen is not None:  # the others as they were given
            out = {k: given[k].index_copy(0, chosen.to(v.device), v) for k, v in out.items()}
        if unbatched:
            out = {k: v.squeeze(0) for k, v in out.items()}
        return out["image"] if len(out) == 1 else out


@settings_signature
def random_fluid_warp(
    image: Tensor,
    *,
    keypoints: Tensor | None = None,
    masks: Tensor | None = None,
    boxes: Tensor | None = None,
    settings: FluidWarpSettings | None = None,
    p: float = 1.0,
    generator: torch.Generator | None = None,
    **kwargs: Any,
) -> Tensor | dict[str, Tensor]:
    """One random fluid warp of a batch of tensors: ``FluidWarpAugment(**settings)(image, ...)`` in one call.

    Each sample gets its own draw; the optional keypoints, masks and boxes of a sample follow its image. Use
    :class:`FluidWarpAugment` to keep the settings (and a generator) across calls, and
    ``torchfluidwarp.RandomFluidWarp`` (:class:`~torchfluidwarp.augment.transforms.RandomFluidWarp`) in a torchvision
    pipeline.

    Args:
        image: ``(B, C, H, W)`` or ``(C, H, W)``, any dtype (integers are rounded back).
        keypoints: ``(B, M, 2)`` (``(M, 2)`` unbatched) pixels ``(x, y)``, pixel centres at integers.
        masks: ``(B, K, H, W)`` (``(K, H, W)`` unbatched), any dtype; nearest sampling.
        boxes: ``(B, N, 4)`` (``(N, 4)`` unbatched) ``(x1, y1, x2, y2)`` pixels.
        count, strength, radius, steps, grid, dt, viscosity, edge_points, max_retries, settings, p, generator: as
            for :class:`FluidWarpAugment` (by name only here).

    Returns:
        the warped image when only an image is given; otherwise a dict with the keys ``"image"`` and those of
        the other inputs given.

    Raises:
        TypeError, ValueError: as :class:`FluidWarpAugment` and its ``forward``.

    Example:
        >>> out = random_fluid_warp(torch.rand(3, 32, 32), keypoints=torch.tensor([[10.0, 12.0]]),
        ...                         strength=(0.1, 0.2), radius=(8.0, 12.0), generator=torch.Generator().manual_seed(0))
        >>> out["image"].shape, out["keypoints"].shape
        (torch.Size([3, 32, 32]), torch.Size([1, 2]))
    """
    aug = FluidWarpAugment(settings=settings, p=p, generator=generator, **kwargs)
    return aug(image, keypoints=keypoints, masks=masks, boxes=boxes)
