"""Worker side: each entry point's valid base arguments (small) and its call.

``BASE[entry](dims, gen, folder)`` returns the arguments by name; ``CALL[entry](args)`` runs the entry point on
them (a value of :data:`~fuzz_build.MISSING` leaves the argument out) and returns what it returned.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from fuzz_build import MISSING, png_bytes, points_json
from torch import Tensor

Args = dict[str, Any]


def kw(args: Args, *names: str) -> Args:
    return {n: args[n] for n in names if n in args and args[n] is not MISSING}


def spread_points(m: int, h: int, w: int, gen: torch.Generator) -> Tensor:
    """``m`` points well inside an ``h x w`` image, not collinear."""
    ring = torch.linspace(0, 6.283, m + 1)[:m]
    centre = torch.tensor([(w - 1) / 2, (h - 1) / 2])
    radius = torch.tensor([w / 4, h / 4])
    jitter = torch.rand(m, 2, generator=gen) * 0.5
    return centre + radius * torch.stack([ring.cos(), ring.sin()], 1) + jitter


def inside(points: Tensor, h: int, w: int) -> Tensor:
    """``points`` clamped into an ``h x w`` image."""
    return points.clamp(min=0.0).minimum(torch.tensor([w - 1.0, h - 1.0]))


def _sim(d: dict, g: torch.Generator, f: Path) -> Args:
    B, T, n, M = d["B"], d["T"], d["g"], d["M"]
    return {"grid": n, "dt": 1.0, "viscosity": 0.1, "compressible": False,
            "forces": torch.randn(B, T, 2, n, n, generator=g) * 0.1,
            "points": torch.rand(B, M, 2, generator=g) * (n - 1),
            "velocity": torch.randn(B, 2, n + 1, n + 1, generator=g) * 0.05}  # fmt: skip


def _warp(d: dict, g: torch.Generator, f: Path) -> Args:
    B, C, H, W, T, n, M = (d[k] for k in "BCHWTgM")
    return {"grid": n, "steps": T, "dt": 1.0, "viscosity": 0.0, "compressible": False, "mode": "bilinear",
            "image": torch.rand(B, C, H, W, generator=g), "forces": torch.randn(B, T, 2, n, n, generator=g) * 0.1,
            "points": torch.stack([spread_points(M, H, W, g) for _ in range(B)]), "size": (H, W)}  # fmt: skip


def _layer(a: Args) -> Any:
    from torchfluidwarp import FluidWarp

    return FluidWarp(a.get("grid", 8), a.get("steps", 1), **kw(a, "dt", "viscosity", "compressible", "mode"))


def _coords(d: dict, g: torch.Generator, f: Path) -> Args:
    B, C, H, W = (d[k] for k in "BCHW")
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32), indexing="ij")
    coords = torch.stack([xs, ys], -1).expand(B, H, W, 2) + torch.randn(B, H, W, 2, generator=g) * 0.3
    return {"image": torch.rand(B, C, H, W, generator=g), "coords": coords, "mode": "bilinear"}


def _keyframes(d: dict, g: torch.Generator, f: Path) -> Args:
    H, W, M = d["H"], d["W"], d["M"]
    src = spread_points(M, H, W, g)
    return {"source": src, "target": src + 1.0, "image_size": (H, W), "grid": d["g"], "steps": d["T"],
            "control": 2, "dt": 1.0, "regularization": 0.0, "smoothness": 0.0, "max_iter": 1, "tolerance": 0.01,
            "compressible": False, "dtype": torch.float32, "weights": torch.ones(M), "forces": MISSING,
            "method": "auto"}  # fmt: skip


def _images(d: dict, g: torch.Generator, f: Path) -> Args:
    C, H, W = d["C"], d["H"], d["W"]
    src = torch.rand(1, C, H, W, generator=g)
    return {"source": src, "target": src.roll(1, -1), "loss": "mse", "grid": d["g"], "steps": d["T"],
            "control": 2, "max_iter": 1, "compressible": False, "dtype": torch.float32, "regularization": 0.0,
            "point_weight": 0.001, "viscosity": 0.0}  # fmt: skip


def _morph(d: dict, g: torch.Generator, f: Path) -> Args:
    C, H, W, M = d["C"], d["H"], d["W"], d["M"]
    pa = spread_points(M, H, W, g)
    return {"image_a": torch.rand(C, H, W, generator=g), "image_b": torch.rand(C, H, W, generator=g),
            "points_a": pa, "points_b": inside(pa + torch.randn(M, 2, generator=g), H, W), "frames": 3,
            "method": "natural", "grid": d["g"], "steps": d["T"], "control": 2, "inverse": "flow", "blend": "linear",
            "compressible": MISSING, "max_iter": 1, "margin": 0.5, "smoothness": MISSING, "feather": 8.0,
            "align": "similarity", "tolerance": 0.05, "warm_start": MISSING}  # fmt: skip


def _augment(d: dict, g: torch.Generator, f: Path) -> Args:
    B, C, H, W, M = (d[k] for k in "BCHWM")
    boxes = torch.tensor([[1.0, 1.0, W / 2, H / 2]]).expand(B, 1, 4).clone()
    return {"image": torch.rand(B, C, H, W, generator=g), "keypoints": torch.rand(B, M, 2, generator=g) * (W - 1),
            "masks": (torch.rand(B, 2, H, W, generator=g) > 0.5).float(), "boxes": boxes,
            "mask": torch.zeros(0, H, W, dtype=torch.uint8), "count": (1, 2), "strength": (0.1, 0.2),
            "radius": (2.0, 4.0), "steps": (1, 2), "grid": d["g"], "dt": 1.0, "viscosity": 0.0,
            "edge_points": 2, "max_retries": 1, "generator": torch.Generator().manual_seed(0)}  # fmt: skip


def _io(d: dict, g: torch.Generator, f: Path) -> Args:
    C, H, W, M, T = (d[k] for k in "CHWMT")
    (f / "image.png").write_bytes(png_bytes(H, W, int(torch.randint(0, 999, (1,), generator=g))))
    pts = spread_points(M, H, W, g)
    (f / "points.json").write_text(points_json(pts))
    return {"path": f / "image.png", "channels": MISSING, "dtype": torch.float32, "max_pixels": 1 << 20,
            "data": png_bytes(H, W), "image": torch.rand(1, C, H, W, generator=g), "size": (H + 3, W - 2),
            "max_memory": MISSING, "longest": 6, "points": pts, "max_bytes": 1 << 16,
            "frames": torch.rand(T + 1, C, H, W, generator=g), "fps": 10.0, "loop": 0, "overwrite": False,
            "fmt": "gif"}  # fmt: skip


def _tv_sample(a: Args) -> Any:
    from torchvision import tv_tensors

    image = a["image"]
    img = image[0] if isinstance(image, Tensor) and image.ndim == 4 and len(image) else image
    h, w = (img.shape[-2], img.shape[-1]) if isinstance(img, Tensor) and img.ndim >= 2 else (8, 8)
    # tv_tensors.Image itself refuses tensors under 2-D: such an image goes in as a plain tensor
    as_image = isinstance(img, Tensor) and img.ndim >= 2
    sample: dict[str, Any] = {"image": tv_tensors.Image(img) if as_image else img, "label": 3}
    mask, boxes = a["mask"], a["boxes"]
    sample["mask"] = tv_tensors.Mask(mask) if isinstance(mask, Tensor) else mask
    if isinstance(boxes, Tensor) and boxes.ndim in (2, 3):  # tv_tensors.BoundingBoxes itself refuses other ranks
        boxes = boxes[0] if boxes.ndim == 3 else boxes
        sample["boxes"] = tv_tensors.BoundingBoxes(boxes, format="XYXY", canvas_size=(h, w))
    else:
        sample["boxes"] = boxes
    return sample


def _random_fluid_warp_v2(a: Args) -> Any:
    import torchfluidwarp

    t = torchfluidwarp.RandomFluidWarp(**kw(a, "count", "strength", "radius", "steps", "grid", "dt", "generator"))
    return t(_tv_sample(a))


PATHS = {
    "read_points": "points.json",
    "write_image": "out.png",
    "write_points": "out.json",
    "write_animation": "out.gif",
}
"""The base ``path`` of the entries that do not read ``image.png``."""

BASE: dict[str, Callable[[dict, torch.Generator, Path], Args]] = {
    "FluidSimulator": _sim, "FluidWarp.forward": _warp, "FluidWarp.iter_frames": _warp,
    "FluidWarp.carry_points": _warp, "FluidWarp.maps": _warp, "warp_image": _coords, "jacobian_determinant": _coords,
    "fit_keyframes": _keyframes, "fit_images": _images, "morph": _morph, "RandomFluidWarp": _augment,
    "random_fluid_warp": _augment, "FluidWarpAugment": _augment, "estimate_alignment": _morph,
}  # fmt: skip
for _name in ("read_image", "read_image_bytes", "write_image", "resize_image", "shrink_image", "read_points",
              "write_points", "write_animation", "encode_animation"):  # fmt: skip
    BASE[_name] = _io


def call(entry: str, a: Args, folder: Path) -> Any:
    import torchfluidwarp as tfw
    from torchfluidwarp import augment, control
    from torchfluidwarp import io as tio

    if entry == "FluidSimulator":
        sim = tfw.FluidSimulator(a["grid"], **kw(a, "dt", "viscosity", "compressible"))
        return sim(a["forces"], **kw(a, "points", "velocity"))
    if entry == "FluidWarp.forward":
        return _layer(a)(a["image"], a["forces"])
    if entry == "FluidWarp.iter_frames":
        return list(_layer(a).iter_frames(a["image"], a["forces"]))
    if entry == "FluidWarp.carry_points":
        return _layer(a).carry_points(a["points"], a["forces"], a["size"])
    if entry == "FluidWarp.maps":
        layer = _layer(a)
        return layer.maps(a["forces"], a["size"]), layer.forward_maps(a["forces"], a["size"])
    if entry == "warp_image":
        return tfw.warp_image(a["image"], a["coords"], a["mode"])
    if entry == "jacobian_determinant":
        return tfw.jacobian_determinant(a["coords"])
    if entry == "fit_keyframes":
        names = ("image_size", "grid", "steps", "control", "dt", "regularization", "smoothness", "max_iter",
                 "tolerance", "compressible", "dtype", "weights", "forces", "method")  # fmt: skip
        return tfw.fit_keyframes(a["source"], a["target"], **kw(a, *names), progress=False)
    if entry == "fit_images":
        names = ("loss", "grid", "steps", "control", "max_iter", "compressible", "dtype", "regularization",
                 "point_weight", "viscosity")  # fmt: skip
        return tfw.fit_images(a["source"], a["target"], levels=None, **kw(a, *names), progress=False)
    if entry == "morph":
        names = ("frames", "method", "grid", "steps", "control", "inverse", "blend", "compressible", "max_iter",
                 "margin", "smoothness", "feather", "align", "tolerance", "warm_start")  # fmt: skip
        result = tfw.morph(a["image_a"], a["image_b"], a["points_a"], a["points_b"], **kw(a, *names), progress=False)
        return result, result.frames
    if entry == "RandomFluidWarp":
        return _random_fluid_warp_v2(a)
    if entry == "random_fluid_warp":
        names = ("keypoints", "masks", "boxes", "count", "strength", "radius", "steps", "grid", "viscosity",
                 "edge_points", "max_retries", "generator")  # fmt: skip
        return augment.random_fluid_warp(a["image"], **kw(a, *names))
    if entry == "FluidWarpAugment":
        module = augment.FluidWarpAugment(**kw(a, "strength", "radius", "dt", "generator", "count", "steps", "grid"))
        return module(a["image"], keypoints=a["keypoints"])
    if entry == "estimate_alignment":
        return control.estimate_alignment(a["points_a"], a["points_b"], **kw(a, "kind"))
    if entry == "read_image":
        return tio.read_image(a["path"], **kw(a, "channels", "dtype", "max_pixels"))
    if entry == "read_image_bytes":
        return tio.read_image_bytes(a["data"], **kw(a, "channels", "max_pixels"))
    if entry == "write_image":
        return tio.write_image(a["path"], a["image"])
    if entry == "resize_image":
        return tio.resize_image(a["image"], a["size"], **kw(a, "max_memory"))
    if entry == "shrink_image":
        return tio.shrink_image(a["image"], a["longest"])
    if entry == "read_points":
        return tio.read_points(a["path"], **kw(a, "dtype", "max_bytes"))
    if entry == "write_points":
        return tio.write_points(a["path"], a["points"])
    if entry == "write_animation":
        return tio.write_animation(a["path"], a["frames"], **kw(a, "fps", "loop", "overwrite"))
    if entry == "encode_animation":
        return tio.encode_animation(a["frames"], **kw(a, "fmt", "fps", "loop"))
    raise KeyError(entry)
