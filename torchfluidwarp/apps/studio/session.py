"""One studio server's state: its images, points, the newest fit (for warm starts) and the newest previews.

Handlers read and change it under :attr:`Session.lock`; fits and renders run through :attr:`Session.worker`
(:class:`~torchfluidwarp.apps.studio.jobs.LatestOnly`). Points are ``(x, y)`` in each image's pixels, pixel
centres at integers (as in :mod:`torchfluidwarp.io`).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from torchfluidwarp.apps.studio.config import StudioConfig
from torchfluidwarp.apps.studio.inputs import BadInput, choice
from torchfluidwarp.apps.studio.jobs import LatestOnly
from torchfluidwarp.control.keyframes import KeyframeFit
from torchfluidwarp.morph import MorphResult

__all__ = ["IMAGE_SLOTS", "Slot", "Session"]

IMAGE_SLOTS = ("a", "b")


@dataclass
class Slot:
    """An image the page loaded: ``image`` ``(1, C, H, W)``, its file name, and a version that grows."""

    image: Tensor
    name: str
    version: int


class Session:
    """The state behind one :func:`~torchfluidwarp.apps.studio.create_app`.

    Args:
        config: the studio's settings.
        images: optional start images ``{"a": (tensor (1, C, H, W), file name), "b": ...}``.
        points: optional start points ``{"a": (M, 2), "b": (M, 2)}`` in each image's pixels.
    """

    def __init__(
        self,
        config: StudioConfig,
        images: dict[str, tuple[Tensor, str]] | None = None,
        points: dict[str, Tensor] | None = None,
    ) -> None:
        self.config = config
        self.worker = LatestOnly()
        self.lock = threading.Lock()
        self.images: dict[str, Slot] = {}
        self.points: dict[str, Tensor] = {}  # (M, 2) pixels, the last ones the page sent
        self.fit: KeyframeFit | None = None  # the newest fit, for warm starts
        self.fit_key: tuple = ()
        self.morph_gen = 0  # numbers the previews; the page asks for frames of its generation
        self.morph_result: MorphResult | None = None
        self.animate_gen = 0
        self.animate_frames: Tensor | None = None  # (T + 1, C, H, W)
        self.versions = 0
        for key, (img, name) in (images or {}).items():
            self.set_image(choice("image slot", key, IMAGE_SLOTS), img, name)
        for key, pts in (points or {}).items():
            self.points[key] = pts.to(torch.float64)

    def image(self, slot: str) -> Tensor:
        """Image ``slot`` ``(1, C, H, W)``.

        Raises:
            BadInput: the page has not loaded it yet.
        """
        if slot not in self.images:
            raise BadInput(f"load image {slot.upper()} first")
        return self.images[slot].image

    def set_image(self, slot: str, image: Tensor, name: str) -> None:
        """Load ``image`` into ``slot``; its points and the fits made for the old image are dropped."""
        with self.lock:
            self.versions += 1
            self.images[slot] = Slot(image, name, self.versions)
            self.points.pop(slot, None)
            self.fit, self.fit_key, self.morph_result = None, (), None

    def describe(self) -> dict[str, Any]:
        """The state the page starts from: image sizes and names, points, whether saving is possible."""
        out: dict[str, Any] = {
            "images": {},
            "points": {},
            "save_dir": self.config.save_dir is not None,
            "preview_frames": self.config.preview_frames,
        }
        for key in IMAGE_SLOTS:
            slot = self.images.get(key)
            out["images"][key] = None
            if slot is not None:
                _, C, H, W = slot.image.shape
                out["images"][key] = {
                    "width": W,
                    "height": H,
                    "channels": C,
                    "name": slot.name,
                    "version": slot.version,
                }
            out["points"][key] = self.points[key].tolist() if key in self.points else []
        return out

    def warm(self, key: tuple) -> KeyframeFit | None:
        """The newest fit if it was made with settings ``key``, to start the next fit from (``morph`` leaves the
        fit it starts from as it was)."""
        with self.lock:
            if self.fit is None or self.fit_key != key:
                return None
            return self.fit

    def keep_fit(self, key: tuple, fit: KeyframeFit) -> None:
        """Remember ``fit``, made with settings ``key``, for warm starts."""
        with self.lock:
            self.fit, self.fit_key = fit, key
